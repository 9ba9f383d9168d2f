"""Counts to temperature for an IR camera: the Planck form with FLIR's constants, the
emissivity (a number, or a stated model of its fall at grazing angles), the reflected
radiation of the tunnel's walls and of the model's own parts.

The camera's signal (counts) of a black body at ``T`` kelvin (FLIR's calibration form, as
FLIR's cameras and ATS/ResearchIR state it)::

    S(T) = R / (exp(B / T) - F) + O

``U = S - O`` is proportional to the radiance in the camera's band: the radiometric
balance is linear in ``U``. A FLIR file's own metadata (exiftool's and flirpy's names
``PlanckR1``, ``PlanckR2``, ``PlanckB``, ``PlanckF``, ``PlanckO``) writes the same form as
``S = R1 / (R2 (exp(B / T) - F)) - O``: ``R = R1 / R2`` and ``O = -PlanckO``
(:meth:`Planck.from_exif`).

A grey, opaque surface seen at the view angle ``theta`` (from its normal) sends the camera

    U_meas = eps(theta) U(T) + (1 - eps(theta)) H

where ``H`` is the irradiance on it in signal units: the walls at the reflected temperature
where the surface sees the tunnel, and the model's own radiosity where it sees itself
(:mod:`selfillum.thermal.balance`). With no atmosphere between camera and model
(transmission 1, no window), this is FLIR's own formula (flirpy's ``raw2temp`` at object
distance 0 and window transmission 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.thermal.jsonfile import kelvin, kelvin_range, number, read_object

__all__ = ["Planck", "TableCalibration", "Emissivity", "Radiometry", "read_radiometry",
           "fresnel_emissivity"]


@dataclass(frozen=True)
class Planck:
    """FLIR's calibration ``S = R / (exp(B / T) - F) + O`` (counts; ``T`` in K).

    ``t_range`` (K): the black-body range the calibration was made over, when known;
    signals outside it are refused (:meth:`check_counts`)."""

    R: float
    B: float
    F: float
    O: float  # noqa: E741
    t_range: tuple[float, float] | None = None
    source: str = "radiometry"

    def __post_init__(self):
        for k in ("R", "B", "F", "O"):
            v = getattr(self, k)
            if not np.isfinite(v):
                raise InputError(f"{self.source}: {k} = {v} is not a finite number")
        if self.R <= 0 or self.B <= 0:
            raise InputError(f"{self.source}: R = {self.R}, B = {self.B} must be positive")
        if self.t_range is not None:
            lo, hi = self.t_range
            if not 0 < lo < hi:
                raise InputError(f"{self.source}: range {lo}..{hi} K must be 0 < Tmin < Tmax")

    @classmethod
    def from_exif(cls, meta: dict, source: str = "metadata") -> Planck:
        """From a FLIR file's tags (``Planck R1`` or ``PlanckR1`` ...): ``R = R1 / R2``,
        ``O = -PlanckO``."""
        def get(name):
            for key in (f"Planck {name}", f"Planck{name}"):
                if key in meta:
                    return float(meta[key])
            raise InputError(f"{source}: no Planck{name}")
        return cls(get("R1") / get("R2"), get("B"), get("F"), -get("O"), source=source)

    def signal(self, T) -> np.ndarray:
        """Counts of a black body at ``T`` (K)."""
        return self.R / (np.exp(self.B / np.asarray(T, float)) - self.F) + self.O

    def radiance(self, T) -> np.ndarray:
        """``U(T) = S(T) - O`` (counts)."""
        return self.R / (np.exp(self.B / np.asarray(T, float)) - self.F)

    def temperature(self, U) -> np.ndarray:
        """``T = B / ln(R / U + F)`` (K) of the black-body signal ``U = S - O``; NaN where
        ``U <= 0`` or the logarithm's argument is not above 1 (no temperature)."""
        U = np.asarray(U, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            a = self.R / U + self.F
            T = self.B / np.log(a)
        return np.where((U > 0) & (a > 1), T, np.nan)

    def signal_range(self) -> tuple[float, float] | None:
        """Counts of the calibration's range ends (None when not stated)."""
        if self.t_range is None:
            return None
        return float(self.signal(self.t_range[0])), float(self.signal(self.t_range[1]))

    def to_dict(self) -> dict:
        return {"form": "planck", "R": self.R, "B": self.B, "F": self.F, "O": self.O,
                "range_K": self.t_range}


@dataclass(frozen=True)
class TableCalibration:
    """A camera's counts of a black body at tabulated temperatures (``temperature_K``
    increasing, ``counts`` increasing), with ``O`` the counts of no radiance. Between the
    rows, ``ln(S - O)`` is linear in ``1 / T`` (exact for Wien's law, the Planck form's
    ``F = 0``); no extrapolation: outside the table there is no temperature (NaN) and
    counts outside it are refused before a run (``t_range`` is the table's span)."""

    temperature_K: tuple
    counts: tuple
    O: float = 0.0  # noqa: E741
    source: str = "radiometry"

    def __post_init__(self):
        T = np.asarray(self.temperature_K, float)
        S = np.asarray(self.counts, float)
        if T.ndim != 1 or T.size < 2 or T.shape != S.shape:
            raise InputError(f"{self.source}: table needs as many temperature_K as counts, "
                             "2 or more")
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(S))):
            raise InputError(f"{self.source}: table holds a value that is not a number")
        if T[0] <= 0:
            raise InputError(f"{self.source}: table temperature {T[0]} K is below 0 K")
        if np.any(np.diff(T) <= 0) or np.any(np.diff(S) <= 0):
            raise InputError(f"{self.source}: table temperatures and counts must both "
                             "increase")
        if S[0] <= self.O:
            raise InputError(f"{self.source}: table counts {S[0]} at or below O = "
                             f"{self.O} (the counts of no radiance)")

    @property
    def t_range(self) -> tuple[float, float]:
        return float(self.temperature_K[0]), float(self.temperature_K[-1])

    def _xy(self):
        T = np.asarray(self.temperature_K, float)
        return -1.0 / T, np.log(np.asarray(self.counts, float) - self.O)

    def radiance(self, T) -> np.ndarray:
        """``U(T) = S(T) - O`` (counts), NaN outside the table."""
        x, y = self._xy()
        xt = -1.0 / np.asarray(T, float)
        return np.exp(np.interp(xt, x, y, left=np.nan, right=np.nan))

    def signal(self, T) -> np.ndarray:
        return self.radiance(T) + self.O

    def temperature(self, U) -> np.ndarray:
        """Temperature (K) of the black-body signal ``U = S - O``; NaN outside the table."""
        x, y = self._xy()
        U = np.asarray(U, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            lu = np.where(U > 0, np.log(np.where(U > 0, U, 1.0)), np.nan)
        return -1.0 / np.interp(lu, y, x, left=np.nan, right=np.nan)

    def signal_range(self) -> tuple[float, float]:
        return float(self.counts[0]), float(self.counts[-1])

    def to_dict(self) -> dict:
        return {"form": "table", "temperature_K": list(self.temperature_K),
                "counts": list(self.counts), "O": self.O}


def fresnel_emissivity(theta, n: float) -> np.ndarray:
    """Directional emissivity of a smooth, opaque dielectric of refractive index ``n``
    (Kirchhoff: ``1 -`` Fresnel's unpolarised reflectance from air), ``theta`` radians
    from the normal: ``4 n / (n + 1)^2`` at normal view, falling to 0 at 90 deg."""
    return _fresnel_of_cosine(np.cos(np.clip(np.asarray(theta, float), 0.0, np.pi / 2)), n)


def _fresnel_of_cosine(c, n: float) -> np.ndarray:
    """:func:`fresnel_emissivity` from the cosine ``c`` (in [0, 1]) of the view angle."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    s2 = 1.0 - c * c
    ct = np.sqrt(np.maximum(n * n - s2, 0.0)) / n  # cos of the refracted angle
    rs = ((c - n * ct) / (c + n * ct)) ** 2
    rp = ((ct - n * c) / (ct + n * c)) ** 2
    return 1.0 - 0.5 * (rs + rp)


@dataclass(frozen=True)
class Emissivity:
    """The surface's emissivity ``eps(theta)``.

    ``model``: ``"constant"`` (``value`` in every direction), ``"fresnel"`` (a smooth
    dielectric, :func:`fresnel_emissivity`, whose index ``n`` is given or found from the
    normal emissivity ``value = 4 n / (n + 1)^2``), or ``"table"`` (``angles`` in degrees
    and ``values``, linear between, the last value held to 90 deg)."""

    model: str = "constant"
    value: float = 1.0
    n: float | None = None
    angles: tuple = ()
    values: tuple = ()

    def __call__(self, theta) -> np.ndarray:
        """``eps`` at the view angle ``theta`` (radians from the normal)."""
        th = np.asarray(theta, dtype=np.float64)
        if self.model == "constant":
            return np.full(th.shape, self.value)
        if self.model == "fresnel":
            return fresnel_emissivity(th, self.n)
        return np.interp(np.degrees(th), self.angles, self.values)

    def of_cosine(self, cos) -> np.ndarray:
        """``eps`` at the view angle whose cosine is ``cos`` (no angle computed where the
        model does not need one)."""
        c = np.asarray(cos, dtype=np.float64)
        if self.model == "constant":
            return np.full(c.shape, self.value)
        if self.model == "fresnel":
            return _fresnel_of_cosine(c, self.n)
        return self(np.arccos(np.clip(c, -1.0, 1.0)))

    @property
    def directional(self) -> bool:
        return self.model != "constant"

    def hemispherical(self) -> float:
        """``2 int_0^{pi/2} eps(theta) cos(theta) sin(theta) d(theta)``: the emissivity of
        the surface's exchange with its surroundings (Gauss-Legendre, 64 points)."""
        if self.model == "constant":
            return float(self.value)
        x, w = np.polynomial.legendre.leggauss(64)
        th = 0.25 * np.pi * (x + 1.0)
        return float(np.sum(w * 0.25 * np.pi * 2.0 * self(th) * np.cos(th) * np.sin(th)))


def _emissivity(spec, where: str) -> Emissivity:
    """An :class:`Emissivity` from a number or ``{"model": ..., parameters}``."""
    def in_range(v, what):
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{where}: {what} {v!r} is not a number") from None
        if not 0 < v <= 1:
            raise InputError(f"{where}: {what} {v} is outside (0, 1]")
        return v

    if not isinstance(spec, dict):
        return Emissivity("constant", in_range(spec, "emissivity"))
    model = spec.get("model")
    if model == "constant":
        return Emissivity("constant", in_range(spec.get("value"), "emissivity value"))
    if model == "fresnel":
        if "n" in spec:
            n = float(spec["n"])
            if not n > 1:
                raise InputError(f"{where}: emissivity n = {n} must be > 1")
        elif "normal" in spec:
            e = in_range(spec["normal"], "emissivity normal")
            if e == 1:
                raise InputError(f"{where}: a fresnel emissivity of 1 at normal view has no "
                                 "fall; give a number instead")
            n = (2.0 - e + 2.0 * np.sqrt(1.0 - e)) / e
        else:
            raise InputError(f"{where}: emissivity model fresnel needs n or normal")
        e0 = float(fresnel_emissivity(0.0, n))
        return Emissivity("fresnel", e0, n=float(n))
    if model == "table":
        a = np.asarray(spec.get("angles_deg", []), float)
        v = np.asarray(spec.get("values", []), float)
        if a.ndim != 1 or a.size < 2 or a.shape != v.shape or np.any(np.diff(a) <= 0) \
                or a[0] != 0 or a[-1] > 90:
            raise InputError(f"{where}: emissivity table needs increasing angles_deg from 0 "
                             "to at most 90 and as many values")
        for x in v:
            in_range(x, "emissivity table value")
        return Emissivity("table", float(v[0]), angles=tuple(a), values=tuple(v))
    raise InputError(f"{where}: emissivity model {model!r} unknown (a number, or model "
                     "constant, fresnel, table)")


@dataclass(frozen=True)
class Radiometry:
    """What turns an IR camera's counts into temperature: the :class:`Planck` form, the
    :class:`Emissivity` and the walls' (reflected) temperature ``reflected_temperature``
    (K)."""

    planck: Planck | TableCalibration
    emissivity: Emissivity = field(default_factory=Emissivity)
    reflected_temperature: float = 293.15
    source: str = "radiometry"

    def object_radiance(self, U_meas, eps, H) -> np.ndarray:
        """``U(T) = (U_meas - (1 - eps) H) / eps`` (counts)."""
        return (np.asarray(U_meas, float) - (1.0 - eps) * H) / eps

    def temperature(self, counts, theta=0.0, H=None) -> np.ndarray:
        """Surface temperature (K) from the camera's counts seen at ``theta`` (radians)
        with irradiance ``H`` (signal units; default the walls at the reflected
        temperature)."""
        eps = self.emissivity(theta)
        H = self.planck.radiance(self.reflected_temperature) if H is None else H
        U = self.object_radiance(np.asarray(counts, float) - self.planck.O, eps, H)
        return self.planck.temperature(U)


_REQUIRED = ("R", "B", "F", "O")
_EXIF = ("PlanckR1", "PlanckR2", "PlanckB", "PlanckF", "PlanckO")


def read_radiometry(path) -> Radiometry:
    """A radiometry file (JSON): FLIR's ``R``, ``B``, ``F``, ``O`` (or a FLIR file's
    ``PlanckR1``, ``PlanckR2``, ``PlanckB``, ``PlanckF``, ``PlanckO``; or ``"table":
    {"temperature_K": [...], "counts": [...]}`` with ``O``: :class:`TableCalibration`),
    ``emissivity`` (a
    number in (0, 1], or ``{"model": "fresnel", "normal": 0.95}``, ``{"model": "fresnel",
    "n": 1.5}``, ``{"model": "table", "angles_deg": [...], "values": [...]}``),
    ``reflected_temperature`` (K), optionally ``range_K``: ``[Tmin, Tmax]``.

    Raises
    ------
    InputError
        One line naming the file and the missing or bad value.
    """
    d = read_object(path, "radiometry file")
    where = str(Path(path))

    def num(key):
        return number(d, key, where)

    rng = kelvin_range(d, "range_K", where)
    if "table" in d:
        t = d["table"]
        if not isinstance(t, dict) or "temperature_K" not in t or "counts" not in t:
            raise InputError(f"{where}: table needs temperature_K and counts")
        try:
            tt = tuple(float(v) for v in t["temperature_K"])
            cc = tuple(float(v) for v in t["counts"])
        except (TypeError, ValueError):
            raise InputError(f"{where}: table values must be numbers") from None
        if "O" not in d:
            raise InputError(f"{where}: a table needs O, the counts of no radiance")
        planck = TableCalibration(tt, cc, num("O"), source=where)
    elif all(k in d for k in _EXIF) and not any(k in d for k in _REQUIRED):
        planck = Planck(num("PlanckR1") / num("PlanckR2"), num("PlanckB"), num("PlanckF"),
                        -num("PlanckO"), t_range=rng, source=where)
    else:
        missing = [k for k in _REQUIRED if k not in d]
        if missing:
            raise InputError(f"{where}: missing the calibration constant {missing[0]} "
                             "(R, B, F, O: FLIR's S = R / (exp(B / T) - F) + O)")
        planck = Planck(num("R"), num("B"), num("F"), num("O"), t_range=rng, source=where)
    if "emissivity" not in d:
        raise InputError(f"{where}: missing emissivity")
    eps = _emissivity(d["emissivity"], where)
    tr = kelvin(d, "reflected_temperature", where)
    unknown = set(d) - set(_REQUIRED) - set(_EXIF) - {"emissivity", "reflected_temperature",
                                                     "range_K", "table"}
    if unknown:
        raise InputError(f"{where}: unknown key {sorted(unknown)[0]!r}")
    return Radiometry(planck, eps, tr, source=where)
