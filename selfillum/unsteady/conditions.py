"""Tunnel conditions and the Phase 2 formulas of NASA uPSP's ``psp_process``.

uPSP's Software Design Document ("Phase 2 processing"), per grid node ``n`` and frame ``f``:

* ``I'_{f,n} = mean_f(I_{f,n}) / I_{f,n}``;
* a 6th-order polynomial in time fitted to ``I'_n`` and subtracted;
* ``P_{f,n} = (I'_{f,n} - fit_{f,n}) Gain_n`` with
  ``Gain = a + b T + c T^2 + (d + e T + f T^2) Pss`` (the paint calibration file);
* ``T = r (T0 - Tinf) + Tinf``, ``r = 0.896`` (turbulent recovery factor, Schlichting),
  temperatures in deg F: the model's surface at its adiabatic-wall temperature;
* ``Pss = Cp_steady q + p_inf`` (psf), the steady pressure at the node;
* ``dCp = P 144 / q`` (``P`` in psi, ``q`` in psf).

Conditions come from the ``.wtd`` (:mod:`resection.io.wtd`): ``MACH``, ``Q`` (psf), ``PS``
(psf, the free-stream static pressure) and the stagnation temperature ``TTF`` (deg F; also
accepted under ``T0``, ``TT`` or ``TTOT``). The free-stream static temperature ``Tinf`` is
not in the file: it follows from ``T0`` and the Mach number by the isentropic relation
``T0 / Tinf = 1 + (gamma - 1) / 2 M^2`` (gamma = 1.4), on absolute temperatures (Rankine,
``R = F + 459.67``), unless the user gives it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from resection.errors import InputError

__all__ = ["Conditions", "RECOVERY_FACTOR", "GAMMA", "RANKINE", "MAX_MACH",
           "MAX_TEMPERATURE_F", "freestream_temperature", "recovery_temperature",
           "steady_pressure", "T0_COLUMNS"]

#: Turbulent boundary-layer recovery factor (Schlichting), as uPSP.
RECOVERY_FACTOR = 0.896
#: Ratio of specific heats of air.
GAMMA = 1.4
#: deg F to Rankine.
RANKINE = 459.67
#: The largest Mach number accepted (hypersonic tunnels reach about 25).
MAX_MACH = 50.0
#: The largest temperature accepted, deg F.
MAX_TEMPERATURE_F = 10000.0
#: Column names of the stagnation temperature (deg F) in a ``.wtd``, in order of preference.
T0_COLUMNS = ("TTF", "T0", "TT", "TTOT")


def freestream_temperature(t0_f, mach, gamma: float = GAMMA):
    """Static free-stream temperature (deg F) from the stagnation temperature (deg F) and
    the Mach number: ``T0 / Tinf = 1 + (gamma - 1) / 2 M^2`` on absolute temperatures."""
    t0_r = np.asarray(t0_f, dtype=np.float64) + RANKINE
    return t0_r / (1.0 + 0.5 * (gamma - 1.0) * np.asarray(mach, dtype=np.float64) ** 2) \
        - RANKINE


def recovery_temperature(t0_f, tinf_f, r: float = RECOVERY_FACTOR):
    """Surface (adiabatic-wall) temperature ``r (T0 - Tinf) + Tinf``, deg F."""
    return r * (np.asarray(t0_f, dtype=np.float64) - tinf_f) + tinf_f


def steady_pressure(cp, q, p_inf):
    """Steady pressure ``Cp q + p_inf`` (the units of ``q`` and ``p_inf``, psf in uPSP)."""
    return np.asarray(cp, dtype=np.float64) * q + p_inf


def _check_mach(mach: float, source) -> None:
    if not 0.0 <= mach <= MAX_MACH:  # NaN fails too
        raise InputError(f"{source}: MACH = {mach:g} is out of range (0 to {MAX_MACH:g})")


@dataclass(frozen=True)
class Conditions:
    """The tunnel's conditions for a run.

    Attributes
    ----------
    mach : float
    q : float
        Dynamic pressure, psf.
    p_inf : float
        Free-stream static pressure, psf.
    t0 : float
        Stagnation temperature, deg F.
    tinf : float
        Free-stream static temperature, deg F.
    tinf_source : str
        How ``tinf`` was found (``"isentropic from T0 and MACH"`` or ``"given"``).
    source : str
        The file they come from (or ``"given"``).
    """

    mach: float
    q: float
    p_inf: float
    t0: float
    tinf: float
    tinf_source: str = "isentropic from T0 and MACH"
    source: str = "given"

    def __post_init__(self):
        for k in ("mach", "q", "p_inf", "t0", "tinf"):
            v = getattr(self, k)
            if not np.isfinite(v):
                raise InputError(f"{self.source}: {k} is not finite ({v})")
        if not self.q > 0:
            raise InputError(f"{self.source}: Q must be > 0, got {self.q}")
        _check_mach(self.mach, self.source)
        if not self.p_inf > 0:
            raise InputError(f"{self.source}: PS = {self.p_inf:g}: the free-stream static "
                             "pressure must be > 0 psf")
        for k, name in (("t0", "the stagnation temperature (TTF)"),
                        ("tinf", "the free-stream static temperature (Tinf, "
                         + self.tinf_source + ")")):
            v = getattr(self, k)
            if not -RANKINE < v <= MAX_TEMPERATURE_F:
                raise InputError(f"{self.source}: {name} = {v:g} deg F is "
                                 + ("at or below absolute zero (-459.67 deg F)" if v <= -RANKINE
                                    else f"above {MAX_TEMPERATURE_F:g} deg F"))

    @property
    def surface_temperature(self) -> float:
        """``T = 0.896 (T0 - Tinf) + Tinf``, deg F."""
        return float(recovery_temperature(self.t0, self.tinf))

    @classmethod
    def from_wtd(cls, wtd, *, tinf: float | None = None) -> Conditions:
        """From a :class:`resection.io.wtd.WindTunnelData` (``MACH``, ``Q``, ``PS`` and the
        stagnation temperature, see :data:`T0_COLUMNS`); ``tinf`` (deg F) overrides the
        isentropic estimate."""
        if wtd.wind_off:
            raise InputError(f"{wtd.path}: PS = Q = 0, a wind-off point ({wtd.label}); "
                             "dCp needs the wind-on point's dynamic pressure")
        mach = wtd.value("MACH")
        _check_mach(mach, wtd.path)  # before Tinf is computed from it
        q = wtd.value("Q")
        ps = wtd.value("PS")
        t0 = wtd.value(*T0_COLUMNS)
        if tinf is None:
            return cls(mach, q, ps, t0, float(freestream_temperature(t0, mach)),
                       source=wtd.path)
        return cls(mach, q, ps, t0, float(tinf), "given", wtd.path)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["surface_temperature"] = self.surface_temperature
        return d
