"""A datapoint's first frame calibrated from the tunnel, camera by camera:

1. the camera-to-tunnel calibration carried by the ``.wtd``'s attitude about the centre
   of rotation (:func:`selfillum.entry.tunnel.camera_to_model`): the predicted pose;
2. the targets detected in the first frame and matched to the predictions
   (:func:`resection.markers.from_image.pose_from_image`: the statistical matcher, verified
   by a pose), every target in view looked for again (``refind``, hidden ones skipped on
   the grid), and the pose solved under the project's acceptance rule
   (:mod:`resection.pose.acceptance`: gross outliers named and dropped, the RMS residual
   tested against its chi-square bound and ``max_rms``);
3. the accepted camera written as uPSP's camera-to-model file ``camNN-to-model.json``
   (what ``psp_process`` reads), with the Figure-20 residual picture ``camNN-pose.png``.

A camera whose pose fails the rule gives its reason (the matcher's or the rule's message)
and no file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError, SolveError

__all__ = ["CameraCalibration", "calibrate_camera", "prediction_shift"]


@dataclass(frozen=True)
class CameraCalibration:
    """One camera's first frame of a datapoint.

    ``camera``: the accepted camera-to-model camera (None when it failed, ``reason`` then
    says why); ``predicted``: the camera from the tunnel; ``used`` / ``expected``: targets
    used / predicted in view; ``rms``: RMS residual, px; ``shift``: median distance
    between the predicted and the accepted projections of the targets in view, px;
    ``files``: written."""

    number: int
    camera: Camera | None
    predicted: Camera
    used: int = 0
    expected: int = 0
    rms: float = math.nan
    grade: str = ""
    shift: float = math.nan
    reason: str | None = None
    files: tuple = ()


def prediction_shift(a: Camera, b: Camera, X) -> float:
    """Median pixel distance between the projections of ``X`` by ``a`` and ``b``, over
    the points both put in their image."""
    ua, va = a.project(X, return_valid=True)
    ub, vb = b.project(X, return_valid=True)
    ok = va & vb & a.in_image(np.where(va[:, None], ua, 0.0)) & \
        b.in_image(np.where(vb[:, None], ub, 0.0))
    if not ok.any():
        return math.inf
    return float(np.median(np.linalg.norm(ua[ok] - ub[ok], axis=1)))


def calibrate_camera(number: int, image, markers, mesh, predicted: Camera, folder: Path, *,
                     marker_accuracy: float = 1.0, max_rms: float = 2.0,
                     search_radius: float = 25.0, plot: bool = True) -> CameraCalibration:
    """Calibrate camera ``number`` on ``image`` (its first frame) from ``predicted``
    (module notes); writes ``camNN-to-model.json`` (and ``camNN-pose.png``) in ``folder``.
    """
    from resection.io.cameras import write_camera
    from resection.markers.from_image import pose_from_image

    try:
        res, pts = pose_from_image(image, markers, predicted, refind=True, mesh=mesh,
                                   marker_accuracy=marker_accuracy, max_rms=max_rms,
                                   match_options={"search_radius": search_radius})
    except SolveError as e:
        return CameraCalibration(number, None, predicted, reason=str(e).splitlines()[0])
    except InputError as e:
        return CameraCalibration(number, None, predicted, reason=str(e).splitlines()[0])
    cam = res.camera
    from resection.pose.acceptance import grade as rms_grade

    grade = rms_grade(float(res.rms))
    used = int(np.sum(res.used))
    expected = int(pts.refind.n_expected) if pts.refind is not None else used
    js = folder / f"cam{number:02d}-to-model.json"
    write_camera(js, cam, format="upsp-model")
    files = [js]
    if plot:
        from resection.io.outputs import atomic_path
        from resection.pose.figure20 import write_pose_plot

        png = folder / f"cam{number:02d}-pose.png"
        with atomic_path(png) as tmp:
            write_pose_plot(tmp, res, pts.points3d, pts.points2d, image=image, ids=pts.ids,
                            title=f"camera {number}: {used} targets, RMS {res.rms:.2f} px")
        files.append(png)
    return CameraCalibration(number, cam, predicted, used, expected, float(res.rms),
                             str(grade), prediction_shift(predicted, cam, markers.xyz),
                             None, tuple(files))
