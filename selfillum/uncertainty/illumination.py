"""Self-illumination: what the removal of the reflected light leaves uncertain.

The emission of a seen face is ``E_i = B_i - rho_i (F B)_i``; the PSP ratio is
``R = E_off / E_on``. Three sources, each as a relative error of ``R``:

* **the view factors' ray sampling** (:func:`rays_variance`). Row ``i`` of ``F`` is
  estimated from ``K`` rays (``--rays``): ``(F x)_i`` is the mean over the rays of ``x`` at
  the face each ray hits (0 for a ray that escapes). For independent rays its variance is
  ``((F x^2)_i - (F x)_i^2) / K``. Wind-off and wind-on are corrected with the same ``F``,
  so the two errors are correlated: the ratio's relative error is
  ``-rho_i sum_j dF_ij x_ij`` with ``x_ij = B_off,j / E_off,i - B_on,j / E_on,i``, and its
  variance needs three sparse products. The rays are randomised quasi-Monte Carlo
  (:func:`selfillum.transport.viewfactors.view_factors`), whose error is smaller than that
  of independent rays: the formula is an upper bound. It is scaled by the ratio ``kappa``
  the quasi-random rays achieve on this mesh (:func:`rqmc_ratio`): ``ROWS_CHECKED`` rows
  cast again with another seed, ``kappa = mean((dF x)^2) / 2 / mean(bound)``. Independent
  between faces (each row its own rays).
* **the reflectance** (:func:`reflectance_vector`): a stated standard uncertainty
  ``u_rho`` of one paint, shared by every face: ``dR / R = -u_rho ((F B_off) / E_off -
  (F B_on) / E_on)`` (first order, the hidden faces' radiosity held).
* **the unseen faces' assumption** (:func:`unseen_vector`): what faces no camera sees emit
  is taken as the smooth continuation times ``1 + eps``, ``eps`` uniform in ``[-r, r]``
  (``--u unseen=50%``; default 100 %: from nothing to twice the continuation). The
  ratio at ``eps = r`` gives the sensitivity; standard uncertainty ``r / sqrt(3)``.
  Shared by every face.

Left out: the reflectance's spatial variation (a per-face reflectance file is taken as
exact, up to the one shared ``u_rho``), the paint's BRDF (Lambertian), and the noise of
the seen faces' radiosity through ``F`` (averaged over many faces: small next to the face's
own noise).
"""

from __future__ import annotations

import numpy as np

__all__ = ["rays_variance", "rqmc_ratio", "reflectance_vector", "unseen_vector",
           "ROWS_CHECKED"]

#: Rows of ``F`` cast again to measure the quasi-random rays' variance ratio.
ROWS_CHECKED = 256


def rays_variance(F, b_off, b_on, e_off, e_on, reflectance, rays: int) -> np.ndarray:
    """(F,) variance of ``dR / R`` from the sampling of each row of ``F`` by ``rays`` rays
    (NaN radiosities count as 0; faces with a non-positive emission get NaN)."""
    a = np.nan_to_num(np.asarray(b_off, np.float64))
    b = np.nan_to_num(np.asarray(b_on, np.float64))
    al = np.asarray(e_off, np.float64)
    be = np.asarray(e_on, np.float64)
    rho = np.broadcast_to(np.asarray(reflectance, np.float64), al.shape)
    Fa, Fb = F @ a, F @ b
    Faa, Fbb, Fab = F @ (a * a), F @ (b * b), F @ (a * b)
    with np.errstate(invalid="ignore", divide="ignore"):
        ex2 = Faa / al**2 - 2.0 * Fab / (al * be) + Fbb / be**2
        ex = Fa / al - Fb / be
        var = rho**2 * np.maximum(ex2 - ex * ex, 0.0) / float(rays)
    return np.where((al > 0) & (be > 0), var, np.nan)


def rqmc_ratio(F, F_again, rows, b_off, b_on, e_off, e_on, reflectance,
               bound) -> float:
    """``kappa``: the variance of ``dR / R`` the rays actually give over ``rows`` (``F`` and
    ``F_again``, the same rows cast with another seed: their difference has twice the
    variance of one) against the independent-ray ``bound`` there."""
    a = np.nan_to_num(np.asarray(b_off, np.float64))
    b = np.nan_to_num(np.asarray(b_on, np.float64))
    rho = np.broadcast_to(np.asarray(reflectance, np.float64), np.shape(e_off))[rows]
    dF = (F_again - F)[rows]
    with np.errstate(invalid="ignore", divide="ignore"):
        d = rho * ((dF @ a) / np.asarray(e_off)[rows] - (dF @ b) / np.asarray(e_on)[rows])
    ok = np.isfinite(d) & np.isfinite(bound[rows])
    den = float(np.mean(bound[rows][ok])) if ok.any() else 0.0
    return float(np.mean(d[ok] ** 2) / 2.0 / den) if den > 0 else 1.0


def reflectance_vector(F, b_off, b_on, e_off, e_on, u_rho: float) -> np.ndarray:
    """(F,) relative change of ``R`` for one standard uncertainty of the reflectance."""
    a = np.nan_to_num(np.asarray(b_off, np.float64))
    b = np.nan_to_num(np.asarray(b_on, np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        return -float(u_rho) * ((F @ a) / np.asarray(e_off, np.float64)
                                - (F @ b) / np.asarray(e_on, np.float64))


def unseen_vector(ratio, ratio_shifted) -> np.ndarray:
    """(F,) relative change of ``R`` for one standard uncertainty of the unseen faces'
    emission: ``ratio_shifted`` is the ratio with their emission at the range's end
    ``(1 + r)`` times the continuation; uniform over ``[-r, r]``: ``/ sqrt(3)``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return (np.asarray(ratio_shifted, np.float64) / np.asarray(ratio, np.float64)
                - 1.0) / np.sqrt(3.0)
