"""File formats, one module per family (as trimesh keeps its formats in ``exchange/``).

Every command reads and writes its files through these modules, so every command
accepts what any other writes.

- :mod:`resection.io.meshes`: surface meshes (trimesh formats, Plot3D, Cart3D).
- :mod:`resection.io.markers`: 3-D marker files and 2-D point files
  (:class:`~resection.io.marker_set.MarkerSet`).
- :mod:`resection.io.images`: single images (PNG, TIFF, NPY).
- :mod:`resection.io.plot3d`: Plot3D grids (by content) and function files (``.f``).
- :mod:`resection.io.tgts`: uPSP ``.tgts`` target files, every section (``read_tgts``;
  their targets read by ``read_markers``).
- :mod:`resection.io.fields`: per-face / per-node fields (meshio VTK/VTU/XDMF, PLY, CSV,
  NPY, Plot3D ``.f``).
- :mod:`resection.io.cameras`: camera files (native JSON, uPSP JSON, OpenCV FileStorage).
- :mod:`resection.io.video`: frame sequences read lazily (image lists, TIFF/NPY stacks,
  Photron .mraw/.cih, Phantom .cine): :func:`~resection.io.video.iter_frames`.
- :mod:`resection.io.wtd`: uPSP wind-tunnel data (``.wtd``: conditions, ``# Tap CP``).
- :mod:`resection.io.upsp_inputs`: uPSP ``psp_process`` input decks and paint gain files.
- :mod:`resection.io.triq`: Cart3D annotated triangulations (``.triq``, scalars per vertex).
- :mod:`resection.io.history`: time histories (HDF5 + XDMF sidecar), written through
  :mod:`resection.io.journal` (an undo journal: committed frames survive a full disk,
  ``kill -9`` and crashes).

How files are written, for every command: :mod:`resection.io.outputs` (temporary name and
rename, never over an input), :mod:`resection.io.marks` (side files and output folders
marked as ours; the user's never replaced), :mod:`resection.io.paths` (paths checked before
anything is written; special files refused; temporaries of killed runs swept).
"""
