"""Lambertian self-illumination: forward (emission -> radiosity) and inverse (correction).

Faces ``i = 1..N`` emit an exitance ``E_i`` (what the paint really emits, which carries the
pressure or temperature), reflect a fraction ``rho_i`` of what reaches them and leave with
a radiosity ``B_i`` (what a camera sees: radiance ``B_i / pi``):

``B = E + diag(rho) F B``

with ``F`` the form factors of :func:`selfillum.view_factors` (row sums ``<= 1``).
Units of ``E`` and ``B`` are the caller's (W/m^2, counts, ...), the same for both.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from resection.errors import InputError, SolveError

__all__ = ["forward", "correct", "SolveInfo", "check_reflectance", "check_form_factors"]

#: Vectors at least this long are where OpenBLAS starts threading its dot products.
_BLAS_THREADED_SIZE = 10_000


def _single_blas_thread(size: int):
    """Context manager keeping BLAS on one thread while an iterative solver runs on
    vectors of length ``size`` (a no-op for short vectors).

    The Krylov solvers of SciPy (LSMR, BiCGSTAB, GMRES) alternate sparse products, which
    never use BLAS, with vector norms and dot products, which do. OpenBLAS threads those
    above about 10,000 entries, and waking its threads for each of these microsecond-long
    calls costs far more than it gains: measured on 2 shared cores, the partial
    correction of 100,000 faces took 12 s with OpenBLAS's default threads and 1.7 s with
    one (bench/README.md). The limit is process-wide while it lasts (other threads'
    BLAS calls run on one thread too) and the previous limits are restored on exit.
    """
    if size < _BLAS_THREADED_SIZE:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


@dataclass(frozen=True)
class SolveInfo:
    """What a solve did.

    Attributes
    ----------
    method : str
        ``"neumann"``, ``"bicgstab"``, ``"direct"`` or ``"lsmr"``.
    iterations : int
        Iterations used (0 for the direct inverse).
    residual : float
        Relative residual of the equations solved: ``|(I - rho F) B - E| / |E|`` for
        :func:`forward`; for a partial :func:`correct`, the relative residual of the
        least-squares problem (the normal equations' ``|A^T r| / (|A| |r|)``).
    n_seen : int
        Faces with a measured radiosity.
    n_hidden : int
        Faces without one.
    """

    method: str
    iterations: int
    residual: float
    n_seen: int
    n_hidden: int


def check_form_factors(F) -> sp.csr_matrix:
    """Return ``F`` as float64 CSR after checking it is square, finite and non-negative
    with row sums ``<= 1`` (within ``1e-9``)."""
    if not sp.issparse(F):
        try:
            F = np.asarray(F, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("F: not a numeric matrix") from None
        if F.ndim != 2:
            raise InputError(f"F: expected a 2-D matrix, got shape {F.shape}")
    F = sp.csr_matrix(F, dtype=np.float64)
    if F.shape[0] != F.shape[1]:
        raise InputError(f"F: expected a square matrix, got shape {F.shape}")
    if F.nnz and not np.all(np.isfinite(F.data)):
        raise InputError("F: contains NaN or infinite values")
    if F.nnz and F.data.min() < 0:
        raise InputError("F: contains negative form factors")
    rows = np.asarray(F.sum(axis=1)).ravel()
    if rows.size and rows.max() > 1.0 + 1e-9:
        i = int(np.argmax(rows))
        raise InputError(f"F: row {i} sums to {rows[i]:.6g} > 1 (not a form-factor matrix)")
    return F


def check_reflectance(reflectance, n: int) -> np.ndarray:
    """Reflectance as an ``(n,)`` float64 array in ``[0, 1)``: a scalar is broadcast."""
    rho = _field(reflectance, n, "reflectance")
    bad = np.flatnonzero((rho < 0) | (rho >= 1))
    if bad.size:
        raise InputError(
            f"reflectance: must lie in [0, 1), got {rho[bad[0]]:.6g} at face {int(bad[0])}"
        )
    return rho


def _field(values, n: int, name: str) -> np.ndarray:
    """``values`` as a finite ``(n,)`` float64 array (a scalar is broadcast) or InputError."""
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: not a numeric array") from None
    if x.ndim == 0:
        x = np.full(n, float(x))
    if x.shape != (n,):
        raise InputError(f"{name}: expected shape ({n},), got {x.shape}")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise InputError(f"{name}: NaN or infinite value at face {int(bad[0])}")
    return x


def forward(
    F,
    emission,
    reflectance,
    *,
    tol: float = 1e-10,
    maxiter: int = 1000,
    return_info: bool = False,
):
    """Radiosity of the faces from their emission: solve ``(I - diag(rho) F) B = E``.

    Parameters
    ----------
    F : (N, N) sparse matrix
        Form factors (row sums ``<= 1``).
    emission : (N,) array_like or float
        ``E``, emitted exitance per face.
    reflectance : float or (N,) array_like
        ``rho``, diffuse reflectance in ``[0, 1)``.
    tol : float
        Relative residual ``|(I - rho F) B - E| / |E|`` to reach.
    maxiter : int
        Largest number of iterations.
    return_info : bool
        Also return a :class:`SolveInfo`.

    Returns
    -------
    B : (N,) ndarray
        Radiosity (same units as ``E``).
    info : SolveInfo
        Only with ``return_info=True``.

    Raises
    ------
    InputError
        Shapes that do not match, NaN, reflectance outside ``[0, 1)``, invalid ``F``.
    SolveError
        No convergence to ``tol`` within ``maxiter`` iterations.

    Notes
    -----
    The Neumann series ``B = sum_k (rho F)^k E`` converges since ``|rho F|_inf <= max rho
    < 1``; it is used when ``max rho <= 0.5`` (few iterations); otherwise BiCGSTAB,
    started from a few Neumann terms, converges much faster. The residual is checked
    explicitly at the end in both cases.
    """
    F = check_form_factors(F)
    n = F.shape[0]
    E = _field(emission, n, "emission")
    rho = check_reflectance(reflectance, n)
    if not (tol > 0) or int(maxiter) < 1:
        raise InputError(f"tol must be > 0 and maxiter >= 1 (got {tol!r}, {maxiter!r})")
    maxiter = int(maxiter)
    RF = (sp.diags(rho) @ F).tocsr()
    norm_e = float(np.linalg.norm(E))
    if norm_e == 0.0:
        B = np.zeros(n)
        info = SolveInfo("neumann", 0, 0.0, n, 0)
        return (B, info) if return_info else B

    def residual(b):
        return float(np.linalg.norm(b - RF @ b - E)) / norm_e

    # Neumann / Jacobi: B <- E + rho F B
    B = E.copy()
    it = 0
    n_neumann = maxiter if rho.max() <= 0.5 else min(maxiter, 5)
    res = residual(B)
    while res > tol and it < n_neumann:
        B = E + RF @ B
        it += 1
        res = residual(B)
    method = "neumann"
    if res > tol and it < maxiter:
        A = sp.identity(n, format="csr") - RF
        counter = {"k": 0}

        def cb(_x):
            counter["k"] += 1

        with _single_blas_thread(n):
            B2, _ = spla.bicgstab(
                A, E, x0=B, rtol=tol * 0.5, atol=0.0, maxiter=maxiter - it, callback=cb
            )
        it += counter["k"]
        method = "bicgstab"
        res2 = residual(B2)
        if np.all(np.isfinite(B2)) and res2 < res:
            B, res = B2, res2
    if not res <= tol:
        raise SolveError(
            f"radiosity did not converge: relative residual {res:.3g} > tol {tol:.3g} "
            f"after {it} iterations"
        )
    info = SolveInfo(method, it, res, n, 0)
    return (B, info) if return_info else B


def correct(
    F,
    radiosity,
    reflectance,
    seen=None,
    *,
    mesh=None,
    regularization: float = 1e-6,
    tol: float = 1e-8,
    maxiter: int | None = None,
    return_info: bool = False,
):
    """Emission of the faces from their measured radiosity: remove self-illumination.

    With every face seen (``seen is None`` or all ``True``) the inverse is direct and
    exact: ``E = B - rho * (F B)``.

    With a camera seeing only part of the surface (``seen`` a boolean mask), the radiosity
    ``B_h`` of the hidden faces is unknown and the emission ``E = (I - rho F) B`` depends
    on it. Assumption for the hidden faces: their radiosity obeys the same transport
    equation and their emission is the *smoothest continuation* of the seen emission:
    ``B_h`` minimises the Dirichlet energy of ``E`` over the whole surface,
    ``|D E|^2`` (``D`` the face-adjacency difference operator of
    :func:`selfillum.mesh.face_adjacency_weights`), plus a small Tikhonov term
    ``regularization * |B_h - mean(B_seen)|^2`` that fixes what the smoothness leaves
    free (hidden parts with no edge-connection to seen ones). The measured ``B`` of seen
    faces is honoured exactly. This is a sparse linear least-squares problem in
    ``B_h``, solved with LSMR; ``E`` follows for every face (hidden faces' ``E`` are the
    model's estimate, not a measurement).

    Parameters
    ----------
    F : (N, N) sparse matrix
        Form factors.
    radiosity : (N,) array_like
        ``B``, measured radiosity per face. Values of hidden faces are ignored (may be NaN).
    reflectance : float or (N,) array_like
        ``rho`` in ``[0, 1)``.
    seen : (N,) array_like of bool, optional
        Faces whose radiosity is measured. ``None``: all.
    mesh : trimesh.Trimesh, optional
        The mesh of ``F``: required when some faces are hidden (for the adjacency).
    regularization : float
        Weight of the Tikhonov term relative to the smoothness term (``> 0``).
    tol : float
        Tolerance of LSMR (``atol`` and ``btol``).
    maxiter : int, optional
        Largest number of LSMR iterations (default ``10 * n_hidden``, at least 1000).
    return_info : bool
        Also return a :class:`SolveInfo`.

    Returns
    -------
    E : (N,) ndarray
        Emission per face (units of ``B``).
    info : SolveInfo
        Only with ``return_info=True``.

    Raises
    ------
    InputError
        Bad shapes, NaN in seen radiosity, reflectance outside ``[0, 1)``, no seen face,
        ``mesh`` missing or not matching ``F``.
    SolveError
        LSMR stopped before reaching ``tol``.
    """
    F = check_form_factors(F)
    n = F.shape[0]
    rho = check_reflectance(reflectance, n)
    if seen is None:
        mask = np.ones(n, dtype=bool)
    else:
        mask = np.asarray(seen)
        if mask.shape != (n,) or mask.dtype != bool:
            raise InputError(
                f"seen: expected a boolean array of shape ({n},), got {mask.dtype} {mask.shape}"
            )
    try:
        B = np.asarray(radiosity, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("radiosity: not a numeric array") from None
    if B.shape != (n,):
        raise InputError(f"radiosity: expected shape ({n},), got {B.shape}")
    bad = np.flatnonzero(mask & ~np.isfinite(B))
    if bad.size:
        raise InputError(f"radiosity: NaN or infinite value at seen face {int(bad[0])}")
    n_seen = int(mask.sum())
    if n_seen == 0:
        raise InputError("seen: no face is seen, nothing to correct")
    if n_seen == n:
        E = B - rho * (F @ B)
        info = SolveInfo("direct", 0, 0.0, n, 0)
        return (E, info) if return_info else E

    if mesh is None:
        raise InputError("mesh: required when some faces are hidden (seen has False values)")
    if len(mesh.faces) != n:
        raise InputError(f"mesh: has {len(mesh.faces)} faces but F is {n} x {n}")
    if not regularization > 0:
        raise InputError(f"regularization: must be > 0, got {regularization!r}")
    from .mesh import face_adjacency_weights

    hidden = np.flatnonzero(~mask)
    seen_idx = np.flatnonzero(mask)
    M = (sp.identity(n, format="csr") - sp.diags(rho) @ F).tocsc()
    Bs = B[seen_idx]
    e0 = M[:, seen_idx] @ Bs  # E with B_h = 0
    Mh = M[:, hidden].tocsr()  # E = e0 + Mh @ B_h
    MhT = Mh.T.tocsr()
    D = face_adjacency_weights(mesh)
    DT = D.T.tocsr()
    # Tikhonov weight relative to the typical size of the smoothness columns (the columns
    # of D Mh are those of D up to the small rho F terms: M has a unit diagonal)
    col_norm = np.sqrt(np.asarray(D.multiply(D).sum(axis=0)).ravel())[hidden]
    scale = float(np.median(col_norm[col_norm > 0])) if np.any(col_norm > 0) else 1.0
    lam = np.sqrt(regularization) * scale
    p_rows, nh = D.shape[0], hidden.size

    def matvec(x):
        x = np.ravel(x)
        return np.concatenate([D @ (Mh @ x), lam * x])

    def rmatvec(y):
        y = np.ravel(y)
        return MhT @ (DT @ y[:p_rows]) + lam * y[p_rows:]

    A = spla.LinearOperator((p_rows + nh, nh), matvec=matvec, rmatvec=rmatvec, dtype=float)
    prior = float(np.mean(Bs))
    # unknown: the deviation of B_h from the prior, so that x = 0 is a fair start
    rhs0 = np.concatenate([-(D @ (e0 + Mh @ np.full(nh, prior))), np.zeros(nh)])
    limit = maxiter if maxiter is not None else max(1000, 10 * hidden.size)
    with _single_blas_thread(p_rows + nh):
        out = spla.lsmr(A, rhs0, atol=tol, btol=tol, maxiter=limit)
    x, istop, itn, normr, normar, norma = out[0], out[1], out[2], out[3], out[4], out[5]
    if istop not in (0, 1, 2, 4, 5):
        raise SolveError(
            f"correction least squares did not converge (LSMR stop {istop} after {itn} "
            f"iterations, residual {normr:.3g})"
        )
    Bh = prior + x
    Bfull = B.copy()
    Bfull[hidden] = Bh
    E = M @ Bfull
    rel = float(normar / max(norma * normr, np.finfo(float).tiny)) if normr > 0 else 0.0
    info = SolveInfo("lsmr", int(itn), rel, n_seen, int(hidden.size))
    return (E, info) if return_info else E
