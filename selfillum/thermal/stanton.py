"""The Stanton number and the heat-transfer coefficient from the tunnel's conditions.

From the ``.wtd`` (:class:`selfillum.unsteady.conditions.Conditions`: Mach number, dynamic
pressure ``Q`` and static pressure in psf, stagnation temperature ``T0`` in deg F, the
free-stream static temperature isentropic from them):

- adiabatic-wall (recovery) temperature ``T_aw = T_inf + r (T0 - T_inf)`` with the stated
  recovery factor ``r`` (default ``Pr^(1/3) = 0.896``, turbulent, as uPSP);
- heat-transfer coefficient ``h = q / (T_aw - T_w)`` (W/m^2/K);
- Stanton number ``St = q / (rho_inf u_inf c_p (T_aw - T_w))``, with
  ``rho_inf u_inf = 2 Q / u_inf`` and ``u_inf = M sqrt(gamma R T_inf)`` (air: gamma 1.4,
  ``R = 287.05`` J/kg/K, ``c_p = gamma R / (gamma - 1)``).

``h`` and ``St`` are NaN where ``|T_aw - T_w|`` is under ``min_dt`` (0.5 K): near the
adiabatic-wall temperature they carry no information.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.errors import InputError
from selfillum.unsteady.conditions import GAMMA, RANKINE, RECOVERY_FACTOR, Conditions

__all__ = ["FlowReference", "PSF", "R_AIR"]

#: Pa per psf.
PSF = 47.880258889
#: Gas constant of air, J/kg/K.
R_AIR = 287.05


def _kelvin(deg_f: float) -> float:
    return (float(deg_f) + RANKINE) * 5.0 / 9.0


@dataclass(frozen=True)
class FlowReference:
    """``T_aw`` (K) and ``rho_u_cp`` (W/m^2/K) for the conditions: :meth:`from_conditions`.
    """

    t_aw: float
    t_inf: float
    t0: float
    rho_u_cp: float
    recovery_factor: float
    min_dt: float = 0.5

    @classmethod
    def from_conditions(cls, cond: Conditions,
                        recovery_factor: float = RECOVERY_FACTOR) -> FlowReference:
        if not 0 < recovery_factor <= 1:
            raise InputError(f"recovery factor {recovery_factor} must be in (0, 1]")
        if not cond.mach > 0:
            raise InputError(f"{cond.source}: MACH {cond.mach} must be > 0 for a Stanton "
                             "number")
        t0, tinf = _kelvin(cond.t0), _kelvin(cond.tinf)
        if tinf <= 0 or t0 <= 0:
            raise InputError(f"{cond.source}: temperature below 0 K (T0 {t0:.2f} K, "
                             f"Tinf {tinf:.2f} K)")
        u = cond.mach * np.sqrt(GAMMA * R_AIR * tinf)
        rho_u = 2.0 * cond.q * PSF / u
        cp = GAMMA * R_AIR / (GAMMA - 1.0)
        t_aw = tinf + recovery_factor * (t0 - tinf)
        return cls(float(t_aw), float(tinf), float(t0), float(rho_u * cp),
                   float(recovery_factor))

    def coefficient(self, q, T_w) -> np.ndarray:
        """``h = q / (T_aw - T_w)`` (W/m^2/K)."""
        d = self.t_aw - np.asarray(T_w, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(np.abs(d) >= self.min_dt, np.asarray(q) / d, np.nan)

    def stanton(self, q, T_w) -> np.ndarray:
        """``St = h / (rho_inf u_inf c_p)``."""
        return self.coefficient(q, T_w) / self.rho_u_cp

    def to_dict(self) -> dict:
        return {"T_aw_K": self.t_aw, "T_inf_K": self.t_inf, "T0_K": self.t0,
                "rho_u_cp_W_m2K": self.rho_u_cp, "recovery_factor": self.recovery_factor,
                "min_dt_K": self.min_dt}
