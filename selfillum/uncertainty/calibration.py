"""Paint calibration: the Stern-Volmer fit on the taps, or uPSP's gain coefficients.

**In-situ fit** (``selfillum psp``). ``I_ref / I = R = A + B x``, ``x = p / p_ref``, is fitted
by (unweighted) least squares to the ratios at the taps: ``(A, B) = G R_t``,
``G = (M^T M)^-1 M^T``, ``M = [1, x_t]``. Every face's pressure is
``p = p_ref (R - A) / B``, so an error ``dR`` of the ratios moves a face's pressure by

``dp_i = (p_ref / B) (dR_i - m_i^T G dR_t)``,  ``m_i = (1, p_i / p_ref)``:

the refit on the taps takes out of every face what the taps see of the same error. A
source shared by every face (registration, reflectance, unseen faces) is propagated with
this projection (:func:`propagate_shared`): a uniform relative error of the ratio (the
wind-on model temperature, the lamp) is absorbed by ``A`` and ``B`` exactly. A source
independent between faces (noise, ray sampling, the model temperature's non-uniformity)
gives the face its own ``(p_ref / B)^2 v_i`` and, through the taps, the fit's covariance

``C_AB = G diag(v_t + (B u_tap / p_ref)^2) G^T``

(:func:`fit_covariance`, ``u_tap`` the taps' stated pressure uncertainty): the
**calibration** part ``(p_ref / B)^2 m_i^T C_AB m_i`` (:func:`pressure_u`). When no source
of the taps' scatter is known (no noise model), the classical estimate from the fit's
residuals, ``s^2 (M^T M)^-1`` with ``s^2 = RSS / (n - 2)``, is used instead
(:func:`residual_covariance`). Either way the ratio of the residuals' sum of squares to
the one the stated sources predict (:func:`scatter_ratio`) is reported: well above 1, the
taps scatter more than the budget explains.

**uPSP's gain** (``selfillum unsteady``): ``Gain = a + bT + cT^2 + (d + eT + fT^2) Pss``
with stated standard uncertainties of ``a .. f`` taken as independent
(:func:`gain_coefficients_u`; their covariance, when the calibration gives one, is not
read).

Left out: a tap's position error on the surface (its face is taken as exact), and the
correlation of a tap face's own error with the fit (the face of a tap is counted twice,
a small over-estimate there).
"""

from __future__ import annotations

import numpy as np

__all__ = ["design", "propagate_shared", "fit_covariance", "residual_covariance",
           "pressure_u", "scatter_ratio", "gain_coefficients_u", "gain_temperature_slope",
           "gain_pressure_slope"]


def design(tap_pressure, p_ref: float) -> tuple[np.ndarray, np.ndarray]:
    """``M`` (T, 2) and ``G = (M^T M)^-1 M^T`` (2, T) of the fit."""
    x = np.asarray(tap_pressure, np.float64) / float(p_ref)
    M = np.column_stack([np.ones_like(x), x])
    return M, np.linalg.pinv(M)


def propagate_shared(D, ratio, tap_faces, G, law, pressure) -> np.ndarray:
    """(F,) pressure uncertainty of shared sources: ``D`` (K, F) relative ratio errors (one
    standard deviation of each of ``K`` independent components)."""
    D = np.atleast_2d(np.asarray(D, np.float64))
    if D.shape[0] == 0:
        return np.zeros(np.shape(ratio))
    dR = np.nan_to_num(D) * np.asarray(ratio, np.float64)[None]
    dab = dR[:, tap_faces] @ G.T  # (K, 2)
    m1 = np.asarray(pressure, np.float64) / law.p_ref
    dp = (law.p_ref / law.B) * (dR - dab[:, :1] - dab[:, 1:] * m1[None])
    return np.sqrt((dp * dp).sum(axis=0))


def fit_covariance(G, var_ratio_taps, law, u_tap: float = 0.0) -> np.ndarray:
    """(2, 2) covariance of ``(A, B)`` from independent ratio variances at the taps and the
    taps' pressure uncertainty."""
    v = np.nan_to_num(np.asarray(var_ratio_taps, np.float64)) \
        + (law.B * float(u_tap) / law.p_ref) ** 2
    return (G * v[None]) @ G.T


def residual_covariance(M, residuals) -> np.ndarray:
    """``s^2 (M^T M)^-1``, ``s^2 = RSS / (n - 2)`` (ratio residuals at the taps)."""
    r = np.asarray(residuals, np.float64)
    n = r.size
    s2 = float(r @ r) / max(n - 2, 1)
    return s2 * np.linalg.inv(M.T @ M)


def scatter_ratio(M, G, residuals, var_ratio_taps, D_taps=None, u_tap_ratio2=0.0) -> float:
    """Residual sum of squares over its expectation from the stated sources (1 when they
    explain the taps' scatter)."""
    r = np.asarray(residuals, np.float64)
    H = M @ G
    Q = np.eye(len(r)) - H
    exp = float(np.sum(np.diag(Q) * (np.nan_to_num(var_ratio_taps) + u_tap_ratio2)))
    if D_taps is not None and np.size(D_taps):
        exp += float(np.sum((np.nan_to_num(D_taps) @ Q.T) ** 2))
    return float(r @ r) / exp if exp > 0 else float("inf")


def pressure_u(C, law, pressure) -> np.ndarray:
    """(F,) ``(p_ref / B) sqrt(m^T C m)``, ``m = (1, p / p_ref)``."""
    m1 = np.asarray(pressure, np.float64) / law.p_ref
    v = C[0, 0] + 2 * C[0, 1] * m1 + C[1, 1] * m1 * m1
    return (law.p_ref / law.B) * np.sqrt(np.maximum(v, 0.0))


def gain_coefficients_u(u_coeffs, T, pss) -> np.ndarray:
    """Standard uncertainty of ``Gain`` from independent ``u_a .. u_f``; ``T`` deg F,
    ``pss`` psf (arrays broadcast)."""
    ua, ub, uc, ud, ue, uf = (float(v) for v in u_coeffs)
    T = np.asarray(T, np.float64)
    pss = np.asarray(pss, np.float64)
    return np.sqrt(ua**2 + (ub * T) ** 2 + (uc * T**2) ** 2
                   + (pss * ud) ** 2 + (pss * ue * T) ** 2 + (pss * uf * T**2) ** 2)


def gain_temperature_slope(coeffs, T, pss) -> np.ndarray:
    """``dGain / dT`` (per deg F)."""
    a, b, c, d, e, f = (float(v) for v in coeffs)
    return b + 2 * c * np.asarray(T) + (e + 2 * f * np.asarray(T)) * np.asarray(pss)


def gain_pressure_slope(coeffs, T) -> np.ndarray:
    """``dGain / dPss`` (per psf)."""
    a, b, c, d, e, f = (float(v) for v in coeffs)
    return d + e * np.asarray(T) + f * np.asarray(T) ** 2
