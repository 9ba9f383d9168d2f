"""The camera stage: the camera model and nothing else.

Takes in intrinsics, distortion and a pose (from a file through :mod:`resection.io.cameras`,
or from :mod:`resection.pose`); gives out :class:`Camera` (pinhole + Brown-Conrady
distortion in OpenCV order + out-of-focus refocus) with ``project`` / ``distort`` /
``undistort`` / ``rays``, undistortion maps and unit checks (m vs mm vs inch).

- :mod:`~resection.camera.model`: :class:`Camera`, :func:`effective_focal_length`,
  :func:`project_with_poses` (many poses at once);
- :mod:`~resection.camera.undistortion`: tabulated undistortion maps for fast ``rays``;
- :mod:`~resection.camera.units`: model units guessed from a camera and a scene.
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "Camera": ".model",
    "UNIT_FACTORS": ".units",
    "UndistortionMap": ".undistortion",
    "camera_scale_hint": ".units",
    "distort_normalized": ".model",
    "effective_focal_length": ".model",
    "max_monotonic_radius": ".model",
    "nothing_seen_causes": ".units",
    "project_with_poses": ".model",
    "require_seen": ".units",
    "spread_hint": ".units",
    "undistort_normalized": ".model",
    "undistortion_map": ".undistortion",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
