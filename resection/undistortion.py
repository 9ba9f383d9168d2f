"""The undistortion map: every pixel centre's line of sight, computed once per camera.

Undistorting a pixel (inverting Brown-Conrady distortion) takes Newton iterations. The
lines of sight of a whole image depend only on the intrinsics (``K``, ``dist``, image
size), not on the pose, so they are computed once and every later map of the image (a new
frame, a new pose of the model) only rotates them into the model frame: a (H*W, 3) x (3, 3)
product.

:meth:`resection.Camera.rays` with no points uses this map, cached on the camera instance
(and handed on by :meth:`Camera.with_pose`, which keeps the intrinsics).

Conventions (DESIGN.md): camera frame x right, y down, z forward; pixel centres at integer
``(u, v)``, pixels flattened row-major (``v * W + u``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["UndistortionMap", "undistortion_map"]


@dataclass(frozen=True)
class UndistortionMap:
    """Unit lines of sight of every pixel centre, camera frame.

    Attributes
    ----------
    width, height : int
        Image size, pixels.
    directions : (H*W, 3) float64, read-only
        Unit direction of pixel ``(u, v)`` at row ``v * W + u``, camera frame; NaN rows
        for pixels that cannot be undistorted (beyond the monotonic range of the
        distortion polynomial).
    """

    width: int
    height: int
    directions: np.ndarray

    def rays(self, R) -> np.ndarray:
        """Directions in the model frame for a camera rotation ``R`` (``x_cam = R X + t``).

        Returns
        -------
        (H*W, 3) float64
            ``R^T d`` for every pixel, unit length (NaN rows kept).
        """
        R = np.ascontiguousarray(R, dtype=np.float64)
        return _rotate_rows(self.directions, R, np.empty_like(self.directions))


@numba.njit(cache=True, nogil=True)
def _rotate_rows(d, R, out):  # pragma: no cover (compiled)
    """out[i] = R^T d[i]: one pass, no BLAS (whose threads fight over 2 shared cores)."""
    for i in range(d.shape[0]):
        x, y, z = d[i, 0], d[i, 1], d[i, 2]
        out[i, 0] = x * R[0, 0] + y * R[1, 0] + z * R[2, 0]
        out[i, 1] = x * R[0, 1] + y * R[1, 1] + z * R[2, 1]
        out[i, 2] = x * R[0, 2] + y * R[1, 2] + z * R[2, 2]
    return out


def undistortion_map(camera) -> UndistortionMap:
    """Compute the lines of sight of every pixel centre of ``camera`` (its intrinsics only).

    Parameters
    ----------
    camera : resection.Camera

    Returns
    -------
    UndistortionMap
    """
    from .camera import undistort_normalized

    H, W = camera.height, camera.width
    uv = np.empty((H * W, 2))
    uv[:, 0] = np.tile(np.arange(W, dtype=np.float64), H)
    uv[:, 1] = np.repeat(np.arange(H, dtype=np.float64), W)
    xy = undistort_normalized(camera.pixels_to_normalized(uv), camera.dist)
    d = np.empty((H * W, 3))
    d[:, :2] = xy
    d[:, 2] = 1.0
    d /= np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
    d.setflags(write=False)
    return UndistortionMap(W, H, d)
