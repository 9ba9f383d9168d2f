"""resection: camera model, Point of View, DLT, calibration, markers and image <-> surface
mapping for wind-tunnel optical measurements (PSP, TSP, IRT).

Conventions are those of DESIGN.md: OpenCV camera frame (x right, y down, z forward),
``x_cam = R @ X + t``, pixel centres at integer coordinates with (0, 0) the centre of the
top-left pixel, images indexed ``img[v, u]``.
"""

from .align import ViewWarp, warp_image
from .calibrate import CalibrationResult, calibrate
from .camera import Camera, effective_focal_length
from .deformation import displacements_3d, marker_displacements, triangulate
from .dlt import (
    apply_homography,
    camera_from_dlt,
    decompose_projection,
    dewarp,
    dlt_project,
    fit_dlt,
    fit_homography,
)
from .errors import DegenerateError, InputError, SolveError
from .io.images import read_image, write_image
from .io.markers import MarkerSet, read_markers, read_points, write_markers, write_points
from .io.meshes import load_mesh, read_plot3d, write_plot3d, write_surface
from .markers import Candidates, detect_markers, read_candidates, write_candidates
from .match import MatchResult, match_markers
from .motion_plots import plot_motion
from .pipeline import pose_from_image
from .plots import plot_resection, plot_surface, virtual_camera
from .pose import PoseResult, solve_pose
from .sequence import TrackResult, read_track, relative_motion, track
from .surface import SurfaceMap, SurfaceSample, vertex_values
from .visibility import RayCaster, visible_faces

__all__ = [
    "Camera",
    "effective_focal_length",
    "InputError",
    "DegenerateError",
    "SolveError",
    "solve_pose",
    "PoseResult",
    "calibrate",
    "CalibrationResult",
    "fit_dlt",
    "dlt_project",
    "decompose_projection",
    "camera_from_dlt",
    "fit_homography",
    "apply_homography",
    "dewarp",
    "MarkerSet",
    "read_markers",
    "write_markers",
    "read_points",
    "write_points",
    "SurfaceMap",
    "plot_surface",
    "plot_resection",
    "virtual_camera",
    "ViewWarp",
    "warp_image",
    "load_mesh",
    "read_plot3d",
    "write_plot3d",
    "write_surface",
    "SurfaceSample",
    "vertex_values",
    "RayCaster",
    "visible_faces",
    "read_image",
    "write_image",
    "Candidates",
    "detect_markers",
    "read_candidates",
    "write_candidates",
    "MatchResult",
    "match_markers",
    "pose_from_image",
    "track",
    "read_track",
    "relative_motion",
    "TrackResult",
    "plot_motion",
    "triangulate",
    "marker_displacements",
    "displacements_3d",
]
