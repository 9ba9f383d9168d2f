"""Attitude and position change of every frame relative to a reference frame."""

from __future__ import annotations

import numpy as np

from resection._checks import as_points
from resection.camera.rotation import euler_zyx, rotvec_to_matrix, rotvecs_to_matrices
from resection.errors import InputError


def relative_motion(rvecs, tvecs, reference: int = 0, *,
                    fixed_camera: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Attitude and position change of every frame relative to a reference frame.

    Parameters
    ----------
    rvecs, tvecs : (F, 3) array_like
        Camera poses (``x_cam = R(rvec) X + t``), NaN rows for failed frames.
    reference : int
        Index of the reference frame (must have a finite pose).
    fixed_camera : bool
        True: the model moves in front of a fixed camera; return the model's attitude
        ``M = R_0^T R_k`` and origin displacement ``R_0^T (t_k - t_0)``. False: the camera
        moves around a fixed model; return ``R_k^T R_0`` and ``C_k - C_0``.

    Returns
    -------
    angles : (F, 3) ndarray
        ``(roll, pitch, yaw)`` in degrees with ``M = Rz(yaw) Ry(pitch) Rx(roll)``.
    translation : (F, 3) ndarray
        Model units; NaN rows for failed frames.
    """
    rv = as_points(rvecs, 3, "rvecs", allow_nan=True)
    tv = as_points(tvecs, 3, "tvecs", allow_nan=True)
    if len(rv) != len(tv):
        raise InputError(f"relative_motion: {len(rv)} rvecs but {len(tv)} tvecs")
    if not (0 <= reference < len(rv)) or not np.all(np.isfinite(rv[reference])):
        raise InputError(f"relative_motion: reference frame {reference} has no pose")
    good = np.all(np.isfinite(rv), axis=1) & np.all(np.isfinite(tv), axis=1)
    angles = np.full((len(rv), 3), np.nan)
    trans = np.full((len(rv), 3), np.nan)
    if not good.any():
        return angles, trans
    R = rotvecs_to_matrices(rv[good])
    R0 = rotvec_to_matrix(rv[reference])
    t0 = tv[reference]
    if fixed_camera:
        M = np.einsum("ji,njk->nik", R0, R)
        d = (tv[good] - t0) @ R0  # R0^T (t - t0) per row
    else:
        M = np.einsum("nji,jk->nik", R, R0)
        C = -np.einsum("nji,nj->ni", R, tv[good])
        d = C - (-R0.T @ t0)
    ypr = euler_zyx(M)
    angles[good] = np.degrees(ypr[:, ::-1])
    trans[good] = d
    return angles, trans
