"""The stated uncertainties of a run's inputs, parsed and checked: :class:`Stated`.

Given on the command line as ``--u KEY=VALUE[UNIT]`` (repeatable), the same keys on both
``selfillum psp`` and ``selfillum unsteady``. Each key takes one unit (or none); a value
with another unit, a negative value or NaN is a one-line :class:`InputError`.

=====================  ========================  =============================================
key                    unit                      what it is
=====================  ========================  =============================================
``camera_gain``        ``e/count``               the camera's conversion gain (a parameter of
                                                 the shot-noise model, not an uncertainty)
``read_noise``         ``e``                     the camera's read noise, electrons RMS
``marker``             ``px``                    standard uncertainty of a marker's image
                                                 position, per coordinate (pose covariance)
``reflectance``        (none)                    standard uncertainty of the reflectance
``unseen``             ``%``                     half-width of the uniform range of what the
                                                 unseen faces emit, relative to the
                                                 continuation
``taps``               (pressure, or none)       standard uncertainty of a tap's pressure
                                                 (``psf``/``Pa``/``psi`` accepted as labels:
                                                 the taps' own unit)
``paint_temperature``  ``%/K``                   the paint's temperature sensitivity (a
                                                 parameter)
``temperature``        ``K`` or ``F``            standard uncertainty of the model surface
                                                 temperature
``t0``, ``tinf``       ``K`` or ``F``            standard uncertainty of T0 and Tinf
``q``, ``p_inf``       ``psf``                   standard uncertainty of the dynamic and the
                                                 free-stream static pressure
``gain_a`` .. ``gain_f``  (none)                 standard uncertainty of uPSP's gain
                                                 coefficients ``a`` .. ``f`` (their units)
=====================  ========================  =============================================

Temperatures are kept in kelvin (a difference: 1 F = 1/1.8 K).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields

from resection.errors import InputError

__all__ = ["Stated", "parse_stated", "KEYS"]

_PRESSURE = ("psf", "pa", "psi", "")
#: key -> accepted units (lower case; "" = a bare number).
KEYS: dict[str, tuple[str, ...]] = {
    "camera_gain": ("e/count", "e-/count"),
    "read_noise": ("e", "e-"),
    "marker": ("px",),
    "reflectance": ("",),
    "unseen": ("%",),
    "taps": _PRESSURE,
    "paint_temperature": ("%/k",),
    "temperature": ("k", "f"),
    "t0": ("k", "f"),
    "tinf": ("k", "f"),
    "q": ("psf",),
    "p_inf": ("psf",),
    **{f"gain_{c}": ("",) for c in "abcdef"},
}

_NUMBER = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|nan|inf|-inf)\s*(.*)$",
                     re.IGNORECASE)


@dataclass(frozen=True)
class Stated:
    """Stated uncertainties (None: not stated). Units: see the module notes; temperatures
    in kelvin, ``unseen`` and ``paint_temperature`` as fractions (``%`` / 100)."""

    camera_gain: float | None = None
    read_noise: float | None = None
    marker: float | None = None
    reflectance: float | None = None
    unseen: float | None = None
    taps: float | None = None
    paint_temperature: float | None = None
    temperature: float | None = None
    t0: float | None = None
    tinf: float | None = None
    q: float | None = None
    p_inf: float | None = None
    gain_a: float | None = None
    gain_b: float | None = None
    gain_c: float | None = None
    gain_d: float | None = None
    gain_e: float | None = None
    gain_f: float | None = None
    given: tuple = field(default=(), compare=False)

    def get(self, key: str, default=None):
        v = getattr(self, key)
        return default if v is None else v

    def gain_coefficients(self) -> tuple | None:
        """``(u_a, .., u_f)`` (unstated ones 0), or None when none is stated."""
        u = [getattr(self, f"gain_{c}") for c in "abcdef"]
        return None if all(v is None for v in u) else tuple(v or 0.0 for v in u)

    def to_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "given" and getattr(self, f.name) is not None}


def _value(item: str) -> tuple[str, float]:
    if "=" not in item:
        raise InputError(f"--u {item}: expected KEY=VALUE[UNIT] (keys: {', '.join(KEYS)})")
    key, text = (s.strip() for s in item.split("=", 1))
    key = key.lower().replace("-", "_")
    if key not in KEYS:
        raise InputError(f"--u {item}: unknown key {key!r} (keys: {', '.join(KEYS)})")
    m = _NUMBER.match(text)
    if not m:
        raise InputError(f"--u {item}: {text!r} is not a number with a unit")
    v, unit = float(m.group(1)), m.group(2).strip().lower().replace(" ", "")
    units = KEYS[key]
    if unit not in units:
        shown = " or ".join(repr(u) if u else "no unit" for u in units)
        raise InputError(f"--u {item}: {key} is given in {shown}, not {unit or 'no unit'!r}")
    if not math.isfinite(v):
        raise InputError(f"--u {item}: {key} must be a finite number, got {v}")
    if v < 0:
        raise InputError(f"--u {item}: {key} must be >= 0, got {v}")
    if key in ("camera_gain",) and v == 0:
        raise InputError(f"--u {item}: camera_gain must be > 0")
    if unit in ("%", "%/k"):
        v /= 100.0
    elif unit == "f":
        v /= 1.8  # a temperature difference in deg F, to kelvin
    return key, v


def parse_stated(items) -> Stated:
    """:class:`Stated` from ``KEY=VALUE[UNIT]`` strings (a key given twice is refused)."""
    vals: dict[str, float] = {}
    for item in items or ():
        k, v = _value(str(item))
        if k in vals:
            raise InputError(f"--u {item}: {k} given twice")
        vals[k] = v
    return Stated(**vals, given=tuple(vals))
