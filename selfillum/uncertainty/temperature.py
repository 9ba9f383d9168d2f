"""Temperature: the paint's temperature sensitivity times the model temperature's
uncertainty.

* ``selfillum psp`` (in-situ fit on the taps): the paint's emission changes by
  ``s`` (``--u paint_temperature=1%/K``, about 0.5-1.5 %/K for common paints) per kelvin of
  surface temperature. A temperature change common to the whole model (the wind-on
  recovery temperature from ``T0`` and ``Tinf``, the tunnel's warm-up) scales every ratio
  alike and is absorbed by the fit's ``A`` and ``B`` exactly (see
  :mod:`selfillum.uncertainty.calibration`); what remains is each face's departure from the
  taps' temperature, stated as ``u_T`` (``--u temperature=0.3K``) and taken as independent
  between faces: ``u(R) / R = s u_T`` (:func:`ratio_variance`). Left out: a spatially
  smooth temperature field (a gradient along the model) that the taps could partly see.
* ``selfillum unsteady`` (uPSP's gain): the gain is a polynomial in the surface
  temperature ``T = r (T0 - Tinf) + Tinf`` (``r = 0.896``), so
  ``u_T^2 = (r u_T0)^2 + ((1 - r) u_Tinf)^2 + u_model^2`` (:func:`surface_u`) enters
  through ``dGain / dT`` (:mod:`selfillum.uncertainty.calibration`). ``Tinf`` from the
  isentropic relation inherits ``T0``'s error: with ``u_tinf`` not stated it is taken as
  fully correlated with ``T0`` (``T`` then moves by ``u_T0 T / T0`` on absolute scales,
  bounded here by ``u_T0``). Shared by every node.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ratio_variance", "surface_u", "RECOVERY"]

#: Turbulent recovery factor (uPSP's, Schlichting).
RECOVERY = 0.896


def ratio_variance(sensitivity_per_k: float, u_temperature_k: float, n: int) -> np.ndarray:
    """(n,) variance of ``dR / R``: ``(s u_T)^2`` per face, independent."""
    return np.full(n, (float(sensitivity_per_k) * float(u_temperature_k)) ** 2)


def surface_u(u_t0=None, u_tinf=None, u_model=None) -> float | None:
    """Standard uncertainty (K) of the recovery temperature; None when nothing is stated."""
    if u_t0 is None and u_tinf is None and u_model is None:
        return None
    u0 = float(u_t0 or 0.0)
    ui = u0 if u_tinf is None else float(u_tinf)  # isentropic Tinf: correlated with T0
    if u_tinf is None:
        uT = u0  # r dT0 + (1 - r) dTinf with dTinf ~ dT0: bounded by u_T0
    else:
        uT = float(np.hypot(RECOVERY * u0, (1 - RECOVERY) * ui))
    return float(np.hypot(uT, float(u_model or 0.0)))
