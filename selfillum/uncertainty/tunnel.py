"""Tunnel conditions: the stated uncertainties of the dynamic pressure ``q`` and the
free-stream static pressure ``p_inf`` (``--u q=..psf``, ``--u p_inf=..psf``).

* ``selfillum psp`` with taps from a ``.wtd`` (``p_tap = PS + Cp_tap Q``): the fit maps the
  taps' pressures linearly, so an error of ``PS`` moves every face's pressure by the same
  amount and an error of ``Q`` scales ``p - PS`` alike: ``Cp = (p - PS) / Q`` does not
  change at all (no ``cp_u`` part: the taps' Cp anchor it), while the pressure has
  ``u(p)^2 = u_PS^2 + (Cp u_Q)^2`` (:func:`pressure_u`), shared by every face. The
  wind-off pressure ``p_ref`` cancels the same way (it only scales ``x = p / p_ref``).
* ``selfillum unsteady``: ``dCp = P 144 / q`` with ``Gain(Pss)``, ``Pss = Cp q + p_inf``;
  the relative uncertainty of the factor ``Gain / q`` (:func:`gain_factor_relative_u`)
  is ``(dGain/dPss (Cp u_q))/Gain - u_q / q`` and ``dGain/dPss u_pinf / Gain`` in
  quadrature. Shared by every node and frame.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pressure_u", "gain_factor_relative_u"]


def pressure_u(cp, u_ps: float | None, u_q: float | None) -> np.ndarray:
    """(F,) ``sqrt(u_PS^2 + (Cp u_Q)^2)``."""
    cp = np.asarray(cp, np.float64)
    return np.hypot(float(u_ps or 0.0), cp * float(u_q or 0.0))


def gain_factor_relative_u(gain, dgain_dpss, cp, q: float, u_q, u_pinf) -> np.ndarray:
    """Relative standard uncertainty of ``Gain / q`` from ``u_q`` and ``u_pinf`` (psf)."""
    g = np.asarray(gain, np.float64)
    s = np.asarray(dgain_dpss, np.float64)
    uq, up = float(u_q or 0.0), float(u_pinf or 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = (s * np.asarray(cp, np.float64) / g - 1.0 / q) * uq
        b = s / g * up
    return np.hypot(a, b)
