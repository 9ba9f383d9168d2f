"""A camera without a pose, named as such, with the way forward.

An internal calibration (uPSP's camera file without ``rmat``/``tvec``, an OpenCV file
without ``rvec``/``tvec``) holds intrinsics only: read, it gets the identity pose, which
puts the model's origin at the perspective centre. Automatic matching needs an approximate
pose to predict where the targets fall; without one, what went wrong used to be reported as
"marker diameter unknown" or "camera facing away?". :func:`require_pose` says what it is:
this camera has no pose, link a few targets by hand (``resection link --serve``, see
``docs/linking.md``), then solve the pose from those links.
"""

from __future__ import annotations

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError

__all__ = ["targets_in_view", "is_identity_pose", "has_usable_pose", "require_pose",
           "no_pose_message", "MIN_IN_VIEW"]

#: Fewest targets an approximate pose must put in the image for automatic matching.
MIN_IN_VIEW = 3


def targets_in_view(camera: Camera, xyz) -> int:
    """Number of points in front of ``camera`` whose projection falls in its image."""
    X = np.asarray(xyz, dtype=float).reshape(-1, 3)
    if not len(X):
        return 0
    uv, valid = camera.project(X, return_valid=True)
    return int(np.count_nonzero(valid & camera.in_image(np.where(valid[:, None], uv, 0.0))))


def no_pose_message(why: str, *, camera: str | None = None, image: str | None = None,
                    markers: str | None = None, what: str = "the targets cannot be "
                    "predicted in the image, so they cannot be matched automatically",
                    way_forward: bool = True) -> str:
    """One line: ``CAMERA: this camera has no pose (why): what`` and, with
    ``way_forward``, how to link a few targets by hand and solve the pose from them."""
    cam = camera or "CAMERA"
    img = image or "IMAGE"
    mk = markers or "MARKERS"
    text = f"{cam}: this camera has no pose ({why}): {what}"
    if not way_forward:
        return text
    return (f"{text}. Link a few targets by hand first: resection link --serve {img} "
            f"--markers {mk} --camera {cam} --diameter PX --save-links LINKS.csv, then "
            f"resection pose --image {img} --markers {mk} --camera {cam} --links LINKS.csv "
            "--diameter PX (docs/linking.md)")


def has_usable_pose(camera: Camera, xyz, has_pose: bool = True) -> bool:
    """False when the camera holds no pose to predict the points ``xyz`` from: its file has
    none (``has_pose`` False), or its pose is the identity and puts fewer than
    :data:`MIN_IN_VIEW` of them in the image (what an intrinsics-only camera reads as)."""
    if not has_pose:
        return False
    return not (is_identity_pose(camera) and targets_in_view(camera, xyz) < MIN_IN_VIEW)


def is_identity_pose(camera: Camera) -> bool:
    """True when the camera's pose is the identity (``R = I``, ``t = 0``): what an
    intrinsics-only file reads as."""
    return bool(np.allclose(camera.R, np.eye(3), atol=1e-12)
                and np.allclose(camera.t, 0.0, atol=1e-12))


def require_pose(camera: Camera, markers, *, has_pose: bool = True,
                 camera_path: str | None = None, image_path: str | None = None,
                 markers_path: str | None = None) -> None:
    """Raise :class:`InputError` when ``camera`` holds no pose to match ``markers`` from:
    its file holds none (``has_pose`` False: uPSP or OpenCV intrinsics only), or its pose
    is the identity and puts fewer than :data:`MIN_IN_VIEW` targets in the image (an
    intrinsics-only camera written as the package's JSON). Any other pose is left to the
    matcher, whose message gives the likely causes (units, facing away). The message names
    the camera file and the way forward: link a few targets by hand with ``resection link
    --serve``."""
    names = dict(camera=camera_path, image=image_path, markers=markers_path)
    if not has_pose:
        raise InputError(no_pose_message("intrinsics only, e.g. an internal calibration",
                                         **names))
    if is_identity_pose(camera):
        tg = markers.targets if hasattr(markers, "targets") else markers
        n = targets_in_view(camera, tg.xyz)
        if n < MIN_IN_VIEW:
            raise InputError(no_pose_message(
                f"the identity pose, which puts {n} of the {len(tg.xyz)} targets in the "
                "image", **names))
