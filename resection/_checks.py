"""Small input checks shared by the modules (internal)."""

from __future__ import annotations

import numpy as np

from resection.errors import InputError


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


def json_array(v, shapes: tuple[tuple[int, ...], ...] | None, name: str) -> np.ndarray:
    """A nested list of JSON numbers with one of ``shapes`` (None: any), as float64, or raise.

    Stricter than :func:`as_matrix`, for values read from files: strings (``"1.5"``),
    booleans (``true``) and shapes other than those listed (``t`` as 3x1) are errors that
    name the entry, never silently converted.
    """
    def walk(x, where):
        if isinstance(x, (list, tuple)):
            return [walk(y, f"{where}[{i}]") for i, y in enumerate(x)]
        return json_number(x, f"{name}{where}")

    if not isinstance(v, (list, tuple)):
        raise InputError(f"{name}: must be a list of numbers, got {v!r}")
    nested = walk(v, "")
    try:
        arr = np.array(nested, dtype=np.float64)
    except ValueError:
        raise InputError(f"{name}: rows of unequal length") from None
    if shapes is not None and arr.shape not in shapes:
        want = " or ".join("x".join(map(str, s)) for s in shapes)
        got = "x".join(map(str, arr.shape))
        raise InputError(f"{name}: expected shape {want}, got {got}")
    return arr


def json_number(v, name: str) -> float:
    """A JSON number (int or float; not a bool, not a string), finite, as float."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError(f"{name}: not a number, got {v!r}")
    if not np.isfinite(v):
        raise InputError(f"{name}: contains NaN or infinite values ({v!r})")
    return float(v)


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
