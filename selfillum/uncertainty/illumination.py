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
           "hidden_response", "ROWS_CHECKED"]

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
    # one pass over F for the five products
    Fa, Fb, Faa, Fbb, Fab = (F @ np.column_stack([a, b, a * a, b * b, a * b])).T
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


def hidden_response(F, reflectance, seen, radiosities, emissions, scale: float,
                    tol: float = 1e-10, maxiter: int = 5000) -> tuple[list, list]:
    """The hidden faces' radiosity, and the seen faces' emission change when the hidden
    faces emit ``1 + scale`` times what the chain took, for several images at once.

    With ``RF = diag(rho) F`` split into seen ``s`` and hidden ``h`` faces, the hidden
    radiosity of emission ``E_h`` is ``B_h = (I - RF_hh)^-1 (E_h + RF_hs B_s)`` and the seen
    emission ``E_s = B_s - RF_ss B_s - RF_sh B_h``: linear in ``E_h``, so ``E_h (1 + r)``
    changes ``E_s`` by ``-RF_sh (I - RF_hh)^-1 (r E_h)`` exactly (what the chain re-run with
    that emission gives, :func:`selfillum.solve.radiosity.correct` with given values). One
    block Neumann series for every image and both right-hand sides (it converges:
    ``|RF_hh|_inf <= max rho < 1``).

    Parameters
    ----------
    radiosities : sequence of (N,)
        Measured ``B`` (used on the seen faces).
    emissions : sequence of (N,)
        The chain's emission (on the hidden faces: its continuation; NaN counts as 0).

    Returns
    -------
    full : list of (N,)
        ``B`` measured on the seen faces, ``B_h`` on the hidden ones.
    change : list of (N,)
        The seen faces' emission change (0 on the hidden faces).
    """
    import scipy.sparse as sp

    from resection.errors import SolveError

    seen = np.asarray(seen, bool)
    h, s = np.flatnonzero(~seen), np.flatnonzero(seen)
    n = len(seen)
    rho = np.broadcast_to(np.asarray(reflectance, np.float64), (n,))
    RF = (sp.diags(rho) @ F).tocsr()
    RFh = RF[h]
    RF_hh, RF_hs = RFh[:, h], RFh[:, s]
    k = len(radiosities)
    bs = np.column_stack([np.nan_to_num(np.asarray(b, np.float64)[s]) for b in radiosities])
    eh = np.column_stack([np.nan_to_num(np.asarray(e, np.float64)[h]) for e in emissions])
    rhs = np.hstack([eh + RF_hs @ bs, float(scale) * eh])
    X = rhs.copy()
    norm = np.maximum(np.linalg.norm(rhs, axis=0), 1e-300)
    for _ in range(maxiter):
        nxt = rhs + RF_hh @ X
        done = np.all(np.linalg.norm(nxt - X, axis=0) <= tol * norm)
        X = nxt
        if done:
            break
    else:
        raise SolveError(f"hidden faces' radiosity: no convergence in {maxiter} terms")
    dE = -(RF[s][:, h] @ X[:, k:])
    full, change = [], []
    for j, b in enumerate(radiosities):
        f = np.array(b, np.float64, copy=True)
        f[h] = X[:, j]
        full.append(f)
        d = np.zeros(n)
        d[s] = dE[:, j]
        change.append(d)
    return full, change
