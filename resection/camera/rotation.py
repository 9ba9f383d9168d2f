"""Rotation vectors and rotation matrices (OpenCV's Rodrigues convention), in NumPy.

A rotation vector is the rotation's unit axis times its angle in radians (right-hand
rule), the angle in ``[0, pi]``; the matrix rotates column vectors (``x' = R x``). These
are the conversions of ``cv2.Rodrigues`` and of SciPy's
``Rotation.from_rotvec(...).as_matrix()`` / ``Rotation.from_matrix(...).as_rotvec()``,
written out so that the camera model does not import ``scipy.spatial`` (0.1 s of imports
in every command that reads a camera).
"""

from __future__ import annotations

import numpy as np

__all__ = ["rotvec_to_matrix", "rotvecs_to_matrices", "matrix_to_rotvec", "euler_zyx"]


def _sin_terms(a2):
    """``sin(a) / a`` and ``(1 - cos(a)) / a^2`` of the squared angles ``a2`` (radians^2),
    by their Taylor series below 1e-4 rad, so that small angles keep full precision."""
    a = np.sqrt(a2)
    small = a < 1e-4
    safe = np.where(small, 1.0, a)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, np.sin(safe) / safe)
        c = np.where(small, 0.5 - a2 / 24.0 + a2 * a2 / 720.0,
                     (1.0 - np.cos(safe)) / (safe * safe))
    return s, c


def rotvec_to_matrix(rvec) -> np.ndarray:
    """The rotation matrix of a rotation vector.

    Parameters
    ----------
    rvec : (3,) array_like
        Axis times angle (radians).

    Returns
    -------
    (3, 3) float64
        ``R = I + sin(a) [k]x + (1 - cos(a)) [k]x^2`` for the unit axis ``k`` and angle
        ``a``; written with ``sin(a) / a`` and ``(1 - cos(a)) / a^2`` (their Taylor series
        below 1e-4 rad), so that small angles keep full precision
        (:func:`rotvecs_to_matrices` of the one row).
    """
    return rotvecs_to_matrices(np.asarray(rvec, dtype=np.float64).reshape(1, 3))[0]


def rotvecs_to_matrices(rvecs) -> np.ndarray:
    """The rotation matrices of ``N`` rotation vectors at once.

    Parameters
    ----------
    rvecs : (N, 3) array_like
        Axes times angles (radians).

    Returns
    -------
    (N, 3, 3) float64
        :func:`rotvec_to_matrix` of each row (the same formulas, series included).
    """
    r = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
    a2 = np.einsum("ij,ij->i", r, r)
    s, c = _sin_terms(a2)
    # R = (1 - c a^2) I + s [r]x + c r r^T  (with [r]x^2 = r r^T - a^2 I)
    R = c[:, None, None] * (r[:, :, None] * r[:, None, :])
    d = 1.0 - c * a2
    sr = s[:, None] * r
    R[:, 0, 0] += d
    R[:, 1, 1] += d
    R[:, 2, 2] += d
    R[:, 0, 1] -= sr[:, 2]
    R[:, 1, 0] += sr[:, 2]
    R[:, 0, 2] += sr[:, 1]
    R[:, 2, 0] -= sr[:, 1]
    R[:, 1, 2] -= sr[:, 0]
    R[:, 2, 1] += sr[:, 0]
    return R


def euler_zyx(R) -> np.ndarray:
    """Yaw, pitch and roll of rotation matrices, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Parameters
    ----------
    R : (N, 3, 3) array_like
        Rotation matrices.

    Returns
    -------
    (N, 3) float64
        ``(yaw, pitch, roll)`` in radians, pitch in ``[-pi/2, pi/2]``, the others in
        ``(-pi, pi]`` (SciPy's ``Rotation.as_euler("ZYX")``). At pitch +-90 degrees
        (gimbal lock) yaw and roll are one angle: roll is set to 0, as SciPy does.
    """
    m = np.asarray(R, dtype=np.float64).reshape(-1, 3, 3)
    cp = np.hypot(m[:, 0, 0], m[:, 1, 0])
    pitch = np.arctan2(-m[:, 2, 0], cp)
    lock = cp < 1e-7
    yaw = np.where(lock, np.arctan2(-m[:, 0, 1], m[:, 1, 1]),
                   np.arctan2(m[:, 1, 0], m[:, 0, 0]))
    roll = np.where(lock, 0.0, np.arctan2(m[:, 2, 1], m[:, 2, 2]))
    return np.column_stack([yaw, pitch, roll])


def matrix_to_rotvec(R) -> np.ndarray:
    """The rotation vector of a rotation matrix (angle in ``[0, pi]``).

    Parameters
    ----------
    R : (3, 3) array_like
        A rotation matrix (orthonormal, determinant +1).

    Returns
    -------
    (3,) float64
        Through the unit quaternion of ``R`` (Shepperd's method: from the largest of the
        trace and the diagonal, stable at every angle), then
        ``2 atan2(|v|, w) v / |v|`` (its series below 1e-3 rad).
    """
    m = np.asarray(R, dtype=np.float64).reshape(3, 3)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    pick = int(np.argmax([tr, m[0, 0], m[1, 1], m[2, 2]]))
    if pick == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        f = 0.25 / w
        v = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) * f
    else:
        i = pick - 1
        j, k = (i + 1) % 3, (i + 2) % 3
        v = np.empty(3)
        v[i] = 0.5 * np.sqrt(1.0 + 2.0 * m[i, i] - tr)
        f = 0.25 / v[i]
        w = (m[k, j] - m[j, k]) * f
        v[j] = (m[j, i] + m[i, j]) * f
        v[k] = (m[k, i] + m[i, k]) * f
    if w < 0:  # the quaternion with w >= 0: the angle in [0, pi]
        w, v = -w, -v
    n = float(np.sqrt(v @ v))
    angle = 2.0 * np.arctan2(n, w)
    if angle < 1e-3:
        scale = 2.0 + angle**2 / 12.0 + 7.0 * angle**4 / 2880.0  # angle / sin(angle / 2)
    else:
        scale = angle / np.sin(angle / 2.0)
    return scale * v
