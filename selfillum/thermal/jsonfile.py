"""The thermal run's small JSON input files (radiometry, TSP calibration, substrate), read
and their numbers checked the same way: :func:`read_object` (the file's JSON object, or one
line naming the file and the problem) and :func:`number` (a value of it as a finite float,
optionally positive)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["read_object", "number", "kelvin", "kelvin_range"]


def read_object(path, what: str) -> dict:
    """The JSON object held in ``path`` (a ``what``, e.g. ``"radiometry file"``).

    Raises
    ------
    InputError
        One line naming the file: missing, unreadable, not JSON, not an object.
    """
    p = Path(path)
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{p}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{p}: not a JSON {what} ({exc})") from None
    if not isinstance(d, dict):
        raise InputError(f"{p}: expected a JSON object")
    return d


def number(d: dict, key: str, where: str, *, positive: bool = False) -> float:
    """``d[key]`` as a finite float (a positive one with ``positive``).

    Raises
    ------
    InputError
        ``"{where}: missing {key}"``, ``"... is not a number"``, ``"... is not finite"``,
        ``"... must be positive"``: one line naming the file (``where``) and the value.
    """
    if key not in d:
        raise InputError(f"{where}: missing {key}")
    try:
        v = float(d[key])
    except (TypeError, ValueError):
        raise InputError(f"{where}: {key} = {d[key]!r} is not a number") from None
    if not np.isfinite(v):
        raise InputError(f"{where}: {key} = {d[key]!r} is not finite")
    if positive and not v > 0:
        raise InputError(f"{where}: {key} = {d[key]!r} must be positive")
    return v


def kelvin(d: dict, key: str, where: str) -> float:
    """``d[key]``, a temperature (K): a finite number above 0 K (:func:`number`; else
    ``"{where}: {key} {v} K is below 0 K"``)."""
    v = number(d, key, where)
    if v <= 0:
        raise InputError(f"{where}: {key} {v} K is below 0 K")
    return v


def kelvin_range(d: dict, key: str, where: str) -> tuple[float, float] | None:
    """``d[key]``, a temperature range ``[Tmin, Tmax]`` (K) with ``0 < Tmin < Tmax``; None
    when the file has no ``key``."""
    if key not in d:
        return None
    r = d[key]
    if not (isinstance(r, list) and len(r) == 2):
        raise InputError(f"{where}: {key} must be [Tmin, Tmax] in K")
    lo, hi = (number({key: x}, key, where) for x in r)
    if lo <= 0:
        raise InputError(f"{where}: {key} {lo} K is below 0 K")
    if not lo < hi:
        raise InputError(f"{where}: {key} [{lo}, {hi}] K must have Tmin < Tmax")
    return lo, hi
