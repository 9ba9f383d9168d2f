"""Small input checks shared by the modules (internal)."""

from __future__ import annotations

import numpy as np

from .errors import InputError


def as_points(a, dim: int, name: str, *, allow_nan: bool = False) -> np.ndarray:
    """Return ``a`` as a float64 ``(N, dim)`` array or raise :class:`InputError`.

    A single point of shape ``(dim,)`` is accepted and returned as ``(1, dim)``.
    """
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: not a numeric array ({exc})") from None
    if arr.ndim == 1 and arr.shape[0] == dim:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise InputError(f"{name}: expected shape (N, {dim}), got {arr.shape}")
    if not allow_nan and not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
        raise InputError(
            f"{name}: {bad.size} row(s) contain NaN or infinite values (first at index {bad[0]})"
        )
    return arr


def as_matrix(a, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Return ``a`` as a finite float64 array of exactly ``shape`` or raise."""
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: not a numeric array ({exc})") from None
    if arr.shape != shape:
        raise InputError(f"{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: contains NaN or infinite values")
    return arr
