"""Rotation vectors (OpenCV's Rodrigues vectors), matrices and unit quaternions, in plain
NumPy for the tracker's few poses a frame.

``scipy.spatial.transform.Rotation`` does the same for any number of rotations, but costs
40-50 microseconds a call in argument handling, and tracking by prediction makes about ten
such calls a frame (a tenth of a frame's time). These functions take and return arrays:

* a rotation vector ``r`` is the axis times the angle (radians), the angle in ``[0, pi]``
  on output;
* a quaternion is ``(x, y, z, w)`` (scalar last, as SciPy's), ``w >= 0`` on output;
* ``matrix(r) @ X`` rotates the column vector ``X`` (``x_cam = R X + t``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["compose", "matrix", "quaternion", "rotvec"]

#: below this angle (radians) the series of sin(a/2)/a and a/sin(a/2) are used
_SMALL = 1e-4


def quaternion(rvecs) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` ``(x, y, z, w)`` of rotation vectors ``(..., 3)``."""
    r = np.asarray(rvecs, float)
    a = np.sqrt(np.einsum("...i,...i->...", r, r))
    small = a < _SMALL
    # sin(a/2)/a, its series 1/2 - a^2/48 near 0
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(small, 0.5 - a * a / 48.0, np.sin(0.5 * a) / np.where(small, 1.0, a))
    return np.concatenate([r * f[..., None], np.cos(0.5 * a)[..., None]], axis=-1)


def rotvec(quats) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (angle in ``[0, pi]``) of unit quaternions
    ``(..., 4)``."""
    q = np.asarray(quats, float)
    q = np.where(q[..., 3:4] < 0.0, -q, q)  # the same rotation, w >= 0: angle <= pi
    v, w = q[..., :3], q[..., 3]
    s = np.sqrt(np.einsum("...i,...i->...", v, v))
    a = 2.0 * np.arctan2(s, w)
    small = a < _SMALL
    # a / sin(a/2), its series 2 + a^2/12 near 0 (w ~ 1 there)
    with np.errstate(invalid="ignore", divide="ignore"):
        f = np.where(small, (2.0 + a * a / 12.0) / np.where(small, w, 1.0),
                     a / np.where(small, 1.0, s))
    return v * f[..., None]


def compose(q1, q2) -> np.ndarray:
    """The quaternion of the rotation ``q1`` after ``q2`` (matrix ``R1 @ R2``)."""
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    x1, y1, z1, w1 = np.moveaxis(q1, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(q2, -1, 0)
    return np.stack([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
                     w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2], axis=-1)


def matrix(rvecs) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of rotation vectors ``(..., 3)``."""
    x, y, z, w = np.moveaxis(quaternion(rvecs), -1, 0)
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    R = np.stack([1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy),
                  2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx),
                  2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)], axis=-1)
    return R.reshape(*R.shape[:-1], 3, 3)
