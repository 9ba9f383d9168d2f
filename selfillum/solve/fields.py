"""Per-face inputs of the solves, checked: a reflectance or any other per-face field given
as a scalar or an ``(N,)`` array.

NumPy only, so that a command checks its inputs before it imports the sparse solvers
(``selfillum correct`` imports them on a thread while its rays run).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["check_reflectance", "per_face_field"]


def check_reflectance(reflectance, n: int) -> np.ndarray:
    """Reflectance as an ``(n,)`` float64 array in ``[0, 1)``: a scalar is broadcast."""
    rho = per_face_field(reflectance, n, "reflectance")
    bad = np.flatnonzero((rho < 0) | (rho >= 1))
    if bad.size:
        raise InputError(
            f"reflectance: must lie in [0, 1), got {rho[bad[0]]:.6g} at face {int(bad[0])}"
        )
    return rho


def per_face_field(values, n: int, name: str) -> np.ndarray:
    """``values`` as a finite ``(n,)`` float64 array (a scalar is broadcast) or InputError."""
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: not a numeric array") from None
    if x.ndim == 0:
        x = np.full(n, float(x))
    if x.shape != (n,):
        raise InputError(f"{name}: expected shape ({n},), got {x.shape}")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise InputError(f"{name}: NaN or infinite value at face {int(bad[0])}")
    return x
