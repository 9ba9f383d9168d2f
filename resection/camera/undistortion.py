"""The undistortion map: every pixel centre's line of sight, computed once per camera.

Undistorting a pixel (inverting Brown-Conrady distortion) takes Newton iterations. The
lines of sight of a whole image depend only on the intrinsics (``K``, ``dist``, image
size), not on the pose, so they are computed once and every later map of the image (a new
frame, a new pose of the model) only rotates them into the model frame: a (H*W, 3) x (3, 3)
product.

:meth:`resection.Camera.rays` with no points uses this map, cached on the camera instance
(and handed on by :meth:`Camera.with_pose`, which keeps the intrinsics).

Conventions (docs/design.md): camera frame x right, y down, z forward; pixel centres at integer
``(u, v)``, pixels flattened row-major (``v * W + u``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from resection._threads import run_blocks, split_range

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


def undistortion_map(camera, *, workers: int | None = None) -> UndistortionMap:
    """Compute the lines of sight of every pixel centre of ``camera`` (its intrinsics only).

    Parameters
    ----------
    camera : resection.Camera
    workers : int, optional
        Threads over blocks of image rows (the compiled kernel releases the GIL). Default:
        the cores this process may use.

    Returns
    -------
    UndistortionMap
    """
    from resection.camera.distortion import max_monotonic_radius

    H, W = camera.height, camera.width
    K = np.asarray(camera.K, dtype=np.float64)
    dist = np.asarray(camera.dist, dtype=np.float64)
    d = np.empty((H * W, 3))
    rmax = float(max_monotonic_radius(dist))
    run_blocks(lambda b: _undistort_rows(W, b[0], b[1], K, dist, rmax, d),
               split_range(H, workers, min_size=max(1, 65536 // max(W, 1))), workers)
    d.setflags(write=False)
    return UndistortionMap(W, H, d)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _undistort_rows(W, v0, v1, K, dist, rmax, out):  # pragma: no cover (compiled)
    """Unit camera-frame direction of every pixel centre of rows ``v0 <= v < v1`` into
    ``out`` (H*W, 3): the Newton inversion of :func:`resection.camera.model.undistort_normalized`,
    point by point (its residual check and monotonic-radius limit; NaN where they fail).

    Each pixel starts from the cubic extrapolation of its three left neighbours' solutions
    along the row (the map is smooth: the start is within about ``h^3 |d3x/du3|`` of the
    root, ``h = 1/fx``, around 1e-9), from fewer neighbours near the row's start, and from
    the distorted point itself for the row's first pixel. Newton stops once a step is
    below 1e-8 (relative): the error left after that step is of order
    ``|x''| / |x'| * 1e-16``, far under the 1e-12 the rays are good to, since the root
    within the monotonic radius is simple and unique (the start does not change the
    answer). About one Jacobian and one residual evaluation a pixel, against four."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    for v in range(v0, v1):
        yd = (v - K[1, 2]) / K[1, 1]
        # the last three accepted solutions of this row, n_prev of them valid
        x1 = y1 = x2 = y2 = x3 = y3 = 0.0
        n_prev = 0
        for u in range(W):
            xd = (u - K[0, 2] - K[0, 1] * yd) / K[0, 0]
            if n_prev >= 3:
                x, y = 3.0 * (x1 - x2) + x3, 3.0 * (y1 - y2) + y3
            elif n_prev == 2:
                x, y = 2.0 * x1 - x2, 2.0 * y1 - y2
            elif n_prev == 1:
                x, y = x1 + 1.0 / K[0, 0], y1
            else:
                x, y = xd, yd
            for _ in range(50):
                r2 = x * x + y * y
                radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
                dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
                rx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
                ry = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
                j11 = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
                j12 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y
                j22 = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x
                det = j11 * j22 - j12 * j12
                dx = (j22 * rx - j12 * ry) / det
                dy = (j11 * ry - j12 * rx) / det
                x -= dx
                y -= dy
                if max(abs(dx), abs(dy)) <= 1e-8 * (1.0 + max(abs(x), abs(y))):
                    break
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            ex = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
            ey = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
            i = v * W + u
            if max(abs(ex), abs(ey)) < 1e-9 and np.sqrt(r2) <= rmax:
                x3, y3, x2, y2, x1, y1 = x2, y2, x1, y1, x, y
                n_prev += 1
                n = np.sqrt(r2 + 1.0)
                out[i, 0] = x / n
                out[i, 1] = y / n
                out[i, 2] = 1.0 / n
            else:
                n_prev = 0
                out[i, 0] = np.nan
                out[i, 1] = np.nan
                out[i, 2] = np.nan
