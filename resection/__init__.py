"""resection: camera model, Point of View, DLT, calibration, markers and image <-> surface
mapping for wind-tunnel optical measurements (PSP, TSP, IRT).

Conventions are those of DESIGN.md: OpenCV camera frame (x right, y down, z forward),
``x_cam = R @ X + t``, pixel centres at integer coordinates with (0, 0) the centre of the
top-left pixel, images indexed ``img[v, u]``.
"""

from __future__ import annotations

import importlib

#: Public name -> the submodule that defines it. Submodules are imported on first use
#: (PEP 562), so a command pays only for what it calls (as scikit-image's lazy loading).
_EXPORTS: dict[str, str] = {
    "ViewWarp": ".align",
    "warp_image": ".align",
    "CalibrationResult": ".calibrate",
    "calibrate": ".calibrate",
    "Camera": ".camera",
    "effective_focal_length": ".camera",
    "displacements_3d": ".deformation",
    "marker_displacements": ".deformation",
    "triangulate": ".deformation",
    "apply_homography": ".dlt",
    "camera_from_dlt": ".dlt",
    "decompose_projection": ".dlt",
    "dewarp": ".dlt",
    "dlt_project": ".dlt",
    "fit_dlt": ".dlt",
    "fit_homography": ".dlt",
    "DegenerateError": ".errors",
    "InputError": ".errors",
    "SolveError": ".errors",
    "read_image": ".io.images",
    "write_image": ".io.images",
    "MarkerSet": ".io.markers",
    "read_markers": ".io.markers",
    "read_points": ".io.markers",
    "write_markers": ".io.markers",
    "write_points": ".io.markers",
    "load_mesh": ".io.meshes",
    "read_plot3d": ".io.meshes",
    "write_plot3d": ".io.meshes",
    "write_surface": ".io.meshes",
    "Candidates": ".markers",
    "detect_markers": ".markers",
    "read_candidates": ".markers",
    "write_candidates": ".markers",
    "MatchResult": ".match",
    "match_markers": ".match",
    "plot_motion": ".motion_plots",
    "pose_from_image": ".pipeline",
    "plot_resection": ".plots",
    "plot_surface": ".plots",
    "virtual_camera": ".plots",
    "PoseResult": ".pose",
    "solve_pose": ".pose",
    "TrackResult": ".sequence",
    "read_track": ".sequence",
    "relative_motion": ".sequence",
    "track": ".sequence",
    "SurfaceMap": ".surface",
    "SurfaceSample": ".surface",
    "vertex_values": ".surface",
    "RayCaster": ".visibility",
    "visible_faces": ".visibility",
}

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


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value  # later lookups do not come back here
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
