"""File formats, one module per family (as trimesh keeps its formats in ``exchange/``).

Every command reads and writes its files through these modules, so every command
accepts what any other writes.

- :mod:`resection.io.meshes`: surface meshes (trimesh formats, Plot3D, Cart3D).
- :mod:`resection.io.markers`: 3-D marker files and 2-D point files.
- :mod:`resection.io.images`: single images (PNG, TIFF, NPY).
"""
