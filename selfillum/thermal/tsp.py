"""Temperature-sensitive paint: the wind-on over wind-off intensity ratio to temperature
through the paint's calibration.

``r = I_on / I_off`` per node (both with the self-illumination removed as for PSP, the
wind-off image taken at the uniform temperature ``T_ref``). Calibrations:

- ``arrhenius``: ``ln(I(T) / I(T_ref)) = (E_nr / R_gas) (1 / T - 1 / T_ref)``, so
  ``T = 1 / (1 / T_ref + ln(r) / (E_nr / R_gas))``; ``E_nr`` (J/mol, the activation energy
  of the thermal quenching) or ``E_over_R`` (K);
- ``polynomial``: ``T = sum_k c_k r^k`` (K), ``coefficients`` ``c_0, c_1, ...``, fitted by
  the user on the paint's calibration over ``range_K``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.thermal.jsonfile import kelvin, kelvin_range, number, read_object

__all__ = ["TSPCalibration", "read_tsp_calibration", "GAS_CONSTANT"]

#: J/mol/K.
GAS_CONSTANT = 8.314462618


@dataclass(frozen=True)
class TSPCalibration:
    """``model`` (``arrhenius`` or ``polynomial``), ``T_ref`` (K, the wind-off image's
    temperature), ``E_over_R`` (K) or ``coefficients``; ``range_K`` where the calibration
    holds (temperatures outside are NaN and counted)."""

    model: str
    T_ref: float
    E_over_R: float | None = None
    coefficients: tuple = ()
    range_K: tuple[float, float] | None = None
    source: str = "tsp calibration"

    def temperature(self, ratio) -> np.ndarray:
        """Temperature (K) from ``I_on / I_off``; NaN where the ratio is not positive or
        the temperature falls outside ``range_K``."""
        r = np.asarray(ratio, dtype=np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.model == "arrhenius":
                T = 1.0 / (1.0 / self.T_ref + np.log(r) / self.E_over_R)
                T = np.where((r > 0) & (T > 0), T, np.nan)
            else:
                T = np.polynomial.polynomial.polyval(r, self.coefficients)
                T = np.where(r > 0, T, np.nan)
        if self.range_K is not None:
            T = np.where((T >= self.range_K[0]) & (T <= self.range_K[1]), T, np.nan)
        return T

    def ratio(self, T) -> np.ndarray:
        """``I(T) / I(T_ref)`` (Arrhenius only: the forward law, for synthetic runs)."""
        if self.model != "arrhenius":
            raise InputError(f"{self.source}: the forward ratio is for arrhenius only")
        T = np.asarray(T, dtype=np.float64)
        return np.exp(self.E_over_R * (1.0 / T - 1.0 / self.T_ref))


def read_tsp_calibration(path) -> TSPCalibration:
    """A TSP calibration (JSON): ``{"model": "arrhenius", "E_nr": J/mol | "E_over_R": K,
    "T_ref": K}`` or ``{"model": "polynomial", "coefficients": [...], "T_ref": K}``, each
    with an optional ``range_K: [Tmin, Tmax]``."""
    d = read_object(path, "TSP calibration")
    p = Path(path)

    def num(key):
        return number(d, key, str(p))

    model = d.get("model")
    t_ref = kelvin(d, "T_ref", str(p))
    rng = kelvin_range(d, "range_K", str(p))
    if model == "arrhenius":
        if "E_over_R" in d:
            eor = num("E_over_R")
        elif "E_nr" in d:
            eor = num("E_nr") / GAS_CONSTANT
        else:
            raise InputError(f"{p}: arrhenius needs E_nr (J/mol) or E_over_R (K)")
        if eor <= 0:
            raise InputError(f"{p}: the activation energy must be positive, got {eor} K")
        return TSPCalibration("arrhenius", t_ref, E_over_R=eor, range_K=rng, source=str(p))
    if model == "polynomial":
        c = d.get("coefficients")
        if not isinstance(c, list) or not c:
            raise InputError(f"{p}: polynomial needs coefficients [c0, c1, ...]")
        try:
            cs = tuple(float(x) for x in c)
        except (TypeError, ValueError):
            raise InputError(f"{p}: coefficients must be numbers") from None
        return TSPCalibration("polynomial", t_ref, coefficients=cs, range_K=rng,
                              source=str(p))
    raise InputError(f"{p}: model {model!r} unknown (arrhenius, polynomial)")
