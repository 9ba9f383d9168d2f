"""resection: camera model, Point of View, DLT, calibration, markers and image <-> surface
mapping for wind-tunnel optical measurements (PSP, TSP, IRT).

Conventions are those of DESIGN.md: OpenCV camera frame (x right, y down, z forward),
``x_cam = R @ X + t``, pixel centres at integer coordinates with (0, 0) the centre of the
top-left pixel, images indexed ``img[v, u]``.
"""

from .camera import Camera, effective_focal_length
from .errors import DegenerateError, InputError, SolveError
from .meshio import load_mesh, read_plot3d, write_plot3d, write_surface
from .surface import SurfaceMap, SurfaceSample, vertex_values
from .visibility import RayCaster, visible_faces

__all__ = [
    "Camera",
    "effective_focal_length",
    "InputError",
    "DegenerateError",
    "SolveError",
    "SurfaceMap",
    "load_mesh",
    "read_plot3d",
    "write_plot3d",
    "write_surface",
    "SurfaceSample",
    "vertex_values",
    "RayCaster",
    "visible_faces",
]
