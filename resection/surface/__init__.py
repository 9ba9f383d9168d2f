"""The surface stage: image <-> model grid for a known camera.

Takes in a :class:`~resection.camera.Camera` and a triangle mesh; gives out which faces are
seen (Embree visibility, the obliqueness cut-off), :class:`SurfaceMap` (a sparse face x pixel
matrix: images onto faces and back), several cameras merged onto the grid, images aligned to
each other, outlines and pictures.

- :mod:`~resection.surface.visibility`: :class:`RayCaster`, :func:`visible_faces`;
- :mod:`~resection.surface.surface_map`: :class:`SurfaceMap`;
- :mod:`~resection.surface.vertex_fit`: :func:`vertex_values` (face values to vertex values);
- :mod:`~resection.surface.merge`: multi-camera merge (feathered weights, matched gains);
- :mod:`~resection.surface.align`: wind-on onto wind-off (:func:`warp_image`);
- :mod:`~resection.surface.outline`, :mod:`~resection.surface.plots`: outlines, virtual
  views and pictures of surface fields.
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "DEFAULT_MAX_OBLIQUENESS": ".surface_map",
    "MergedViews": ".merge",
    "Overlap": ".merge",
    "RayCaster": ".visibility",
    "SurfaceMap": ".surface_map",
    "SurfaceSample": ".surface_map",
    "ViewWarp": ".align",
    "angle_weights": ".merge",
    "boundary_pixels": ".merge",
    "default_feather": ".merge",
    "face_sample_points": ".visibility",
    "frame_camera": ".plots",
    "match_gains": ".merge",
    "merge_views": ".merge",
    "oblique_faces": ".surface_map",
    "outline_edges": ".outline",
    "pixel_weights": ".merge",
    "plot_resection": ".plots",
    "plot_surface": ".plots",
    "vertex_values": ".vertex_fit",
    "virtual_camera": ".plots",
    "visible_faces": ".visibility",
    "visible_segments": ".outline",
    "warp_image": ".align",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
