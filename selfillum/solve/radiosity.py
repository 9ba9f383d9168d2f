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
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from resection.errors import InputError, SolveError
from resection.trisurface import TriSurface
from selfillum.solve.csr import column_blocks, identity_minus
from selfillum.solve.fields import check_reflectance, per_face_field
from selfillum.transport.coupling import coupled_faces

__all__ = [
    "forward", "correct", "SolveInfo", "check_reflectance", "check_form_factors", "UNSEEN_CHOICES",
    "load_kernels",
]

#: Vectors at least this long are where OpenBLAS starts threading its dot products.
_BLAS_THREADED_SIZE = 10_000


def single_blas_thread(size: int):
    """Context manager keeping BLAS on one thread while an iterative solver runs on
    vectors of length ``size`` (a no-op for short vectors).

    The Krylov solvers of SciPy (CG, LSMR, BiCGSTAB, GMRES) alternate sparse products, which
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
        ``"neumann"``, ``"bicgstab"``, ``"direct"`` or ``"pcg"`` (the least squares of
        the smooth continuation, :func:`correct`).
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
    n_coupled : int
        Hidden faces coupled to the seen ones through ``F`` (reachable from them along
        its non-zeros, :func:`selfillum.transport.coupling.coupled_faces`): those that entered the
        solve. The other hidden faces cannot change the seen faces' emission.
    assumption : str
        What the hidden faces were taken to emit (``"continue"``, ``"none"``,
        ``"given"``), ``""`` when every face is seen.
    unseen_share : (N,) ndarray or None
        For each seen face, the share of its correction ``B_i - E_i = rho_i (F B)_i``
        that comes from hidden faces, ``rho_i (F B_hidden)_i / (rho_i (F B)_i)`` (0 where
        the correction is 0, NaN on hidden faces); ``None`` when every face is seen.
    """

    method: str
    iterations: int
    residual: float
    n_seen: int
    n_hidden: int
    n_coupled: int = 0
    assumption: str = ""
    unseen_share: np.ndarray | None = field(default=None, repr=False, compare=False)


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
    E = per_face_field(emission, n, "emission")
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

        with single_blas_thread(n):
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


#: What hidden faces may be taken to emit (see :func:`correct`).
UNSEEN_CHOICES = ("continue", "none", "given")


def correct(
    F,
    radiosity,
    reflectance,
    seen=None,
    *,
    mesh=None,
    unseen="continue",
    unpainted=None,
    regularization: float = 1e-6,
    tol: float = 1e-8,
    maxiter: int | None = None,
    return_info: bool = False,
):
    """Emission of the faces from their measured radiosity: remove self-illumination.

    With every face seen (``seen is None`` or all ``True``) the inverse is direct and
    exact: ``E = B - rho * (F B)``.

    With a camera seeing only part of the surface (``seen`` a boolean mask), the radiosity
    ``B_h`` of the hidden faces is unknown and the emission ``E = (I - rho F) B`` of the
    seen faces depends on it. What the hidden faces emit is an assumption, stated with
    ``unseen``:

    * ``"continue"`` (default): the hidden faces' emission is the *smoothest continuation*
      of the seen emission. ``B_h`` minimises the Dirichlet energy ``|D E|^2`` of ``E``
      over the seen and coupled faces (``D`` the face-adjacency difference operator of
      :func:`selfillum.mesh.face_adjacency_weights`, edges between painted faces only),
      plus a small Tikhonov term ``regularization * |B_h - mean(B_seen)|^2`` that fixes
      what the smoothness leaves free. A sparse least-squares problem, solved by
      conjugate gradients on its normal equations, preconditioned by the same problem
      written in the hidden faces' emission, with the light between them and the seen
      faces on the diagonal only (a sparse graph Laplacian, factored once, between two
      truncated Neumann series of ``(I - rho F)`` over the hidden faces): tens to a few
      hundred iterations where plain LSMR needs hundreds to thousands.
    * ``"none"``: hidden faces emit nothing (``E_h = 0``);
    * an ``(N,)`` array: hidden faces emit these values (``"given"``; values of seen faces
      are ignored).

    With ``"none"`` or given values, ``B_h`` solves the forward problem of the hidden
    faces, ``(I - rho F)_hh B_h = E_h + rho_h F_hs B_s``, a square well-conditioned system.

    ``unpainted`` faces emit nothing, seen or not (``E = 0`` on them whatever ``unseen``
    says); they still reflect with their ``reflectance``.

    Only the hidden faces coupled to the seen ones through ``F`` (reachable from them along
    its non-zeros, :func:`selfillum.transport.coupling.coupled_faces`) enter the solve: the others
    cannot change the seen faces' emission, so ``F`` needs only the rows of the seen and
    coupled faces. Their emission is the assumption itself (0, or the given values) and
    NaN under ``"continue"`` (not estimated).

    Parameters
    ----------
    F : (N, N) sparse matrix
        Form factors. Rows of faces neither seen nor coupled may be empty.
    radiosity : (N,) array_like
        ``B``, measured radiosity per face. Values of hidden faces are ignored (may be NaN).
    reflectance : float or (N,) array_like
        ``rho`` in ``[0, 1)``.
    seen : (N,) array_like of bool, optional
        Faces whose radiosity is measured. ``None``: all.
    mesh : trimesh.Trimesh, optional
        The mesh of ``F``: required under ``"continue"`` when some faces are hidden.
    unseen : {"continue", "none"} or (N,) array_like
        What hidden faces emit (units of ``B``).
    unpainted : (N,) array_like of bool, optional
        Faces that emit nothing (unpainted parts of the model).
    regularization : float
        Weight of the Tikhonov term relative to the smoothness term (``> 0``).
    tol : float
        Relative residual of the iterative solves (normal equations of the least
        squares, Neumann series of unpainted faces; a hundredth of it for the forward
        problem of the hidden faces).
    maxiter : int, optional
        Largest number of CG iterations (default ``10 * n_hidden``, at least 1000).
    return_info : bool
        Also return a :class:`SolveInfo` (with the per-face ``unseen_share``).

    Returns
    -------
    E : (N,) ndarray
        Emission per face (units of ``B``); on hidden faces the model's estimate.
    info : SolveInfo
        Only with ``return_info=True``.

    Raises
    ------
    InputError
        Bad shapes, NaN in seen radiosity, reflectance outside ``[0, 1)``, no seen face,
        ``mesh`` missing or not matching ``F``, an unknown ``unseen``.
    SolveError
        An iterative solve stopped before reaching ``tol``.
    """
    F = check_form_factors(F)
    n = F.shape[0]
    rho = check_reflectance(reflectance, n)
    mask = _mask(seen, n, "seen", default=True)
    paint_off = _mask(unpainted, n, "unpainted", default=False)
    kind, given = _unseen_choice(unseen, n)
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
        E[paint_off] = 0.0
        info = SolveInfo("direct", 0, 0.0, n, 0)
        return (E, info) if return_info else E
    if kind == "continue":
        if mesh is None:
            raise InputError("mesh: required when some faces are hidden (seen has False "
                             "values) and their emission is continued")
        if len(mesh.faces) != n:
            raise InputError(f"mesh: has {len(mesh.faces)} faces but F is {n} x {n}")
        if not regularization > 0:
            raise InputError(f"regularization: must be > 0, got {regularization!r}")

    reach = coupled_faces(F, mask)
    sub = np.flatnonzero(reach)  # seen + coupled hidden faces, the whole problem
    # the sub-problem first: I - rho F over its faces only (one compiled pass each, in
    # place of SciPy's F[sub][:, sub], a sparse product and a sparse difference)
    Fs = column_blocks(F, sub, np.where(reach, 0, -1), 1)[0]
    M = identity_minus(Fs, rho[sub])
    loc_seen = mask[sub]
    Bsub = np.where(loc_seen, B[sub], 0.0)
    hid = np.flatnonzero(~loc_seen)
    method, itn, rel = "direct", 0, 0.0
    if hid.size and kind == "continue":
        # BLAS on one thread for the whole continuation, not only its CG: the norms,
        # the Laplacian's factorisation and its solves are short calls too, and OpenBLAS's
        # threads spun on the other core (the solve's CPU was 1.3-1.9x its wall time)
        with single_blas_thread(sub.size):
            Bsub[hid], itn, rel = _continue_hidden(
                M, Bsub, loc_seen, paint_off[sub], mesh, sub, regularization, tol, maxiter
            )
        method = "pcg"
    elif hid.size:
        target = np.zeros(n) if given is None else given.copy()
        target[paint_off] = 0.0
        rho_h = rho[sub][hid]
        Fh = Fs[hid].tocsc()
        s_loc = np.flatnonzero(loc_seen)
        # the forward problem of the hidden faces, lit by the seen ones:
        # (I - rho F)_hh B_h = E_h + rho_h F_hs B_s
        rhs = target[sub][hid] + rho_h * (Fh[:, s_loc] @ Bsub[s_loc])
        Bsub[hid], finfo = forward(Fh[:, hid].tocsr(), rhs, rho_h, tol=1e-2 * tol,
                                   return_info=True)
        method, itn, rel = finfo.method, finfo.iterations, finfo.residual
    E = np.full(n, np.nan) if kind == "continue" else (
        np.zeros(n) if given is None else given.copy())
    E[sub] = M @ Bsub
    E[paint_off] = 0.0
    # a seen face's row of F reaches faces of sub only (they are what it couples to):
    # its sums over sub's columns are its sums over all of them
    total = rho[sub] * (Fs @ Bsub)
    from_hidden = rho[sub] * (Fs @ np.where(loc_seen, 0.0, Bsub))
    share = np.full(n, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        share[sub[loc_seen]] = np.where(total != 0, from_hidden / total, 0.0)[loc_seen]
    info = SolveInfo(method, int(itn), float(rel), n_seen, n - n_seen,
                     int(hid.size), kind, share)
    return (E, info) if return_info else E


def load_kernels(unseen: str = "continue") -> None:
    """Load the compiled kernels that :func:`correct` runs (from numba's cache, or compile
    them) by correcting a strip of 4 faces, 2 seen, 1 hidden and painted, 1 hidden and
    unpainted, with ``unseen`` (``"continue"`` or ``"none"``).

    ``selfillum correct`` calls it on a thread while its rays run, so that the solve after
    them does not wait for numba to load its kernels (about 30 ms on 2 cores).
    The strip's ``F`` has the index types of the traced ones (int32 indices and index
    pointers): the same compiled signatures.
    """
    vertices = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0]],
                        dtype=np.float64)
    faces = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    indices = np.array([1, 2, 3, 0, 2, 3, 0, 1, 3, 0, 1, 2], dtype=np.int32)
    F = sp.csr_matrix((np.full(12, 0.1), indices, np.arange(0, 13, 3, dtype=np.int32)),
                      shape=(4, 4))
    correct(F, np.ones(4), 0.5, np.array([True, True, False, False]),
            mesh=TriSurface(vertices, faces), unseen=unseen,
            unpainted=np.array([False, False, False, True]))


def _mask(values, n: int, name: str, *, default: bool) -> np.ndarray:
    """A boolean ``(n,)`` mask, or ``default`` everywhere for ``None``."""
    if values is None:
        return np.full(n, default)
    mask = np.asarray(values)
    if mask.shape != (n,) or mask.dtype != bool:
        raise InputError(
            f"{name}: expected a boolean array of shape ({n},), got {mask.dtype} {mask.shape}"
        )
    return mask


def _unseen_choice(unseen, n: int) -> tuple[str, np.ndarray | None]:
    """``("continue" | "none" | "given", given values or None)``."""
    if isinstance(unseen, str):
        if unseen not in ("continue", "none"):
            raise InputError(
                f"unseen: expected 'continue', 'none' or per-face values, got {unseen!r}"
            )
        return unseen, None
    return "given", per_face_field(unseen, n, "unseen emission")


def _neumann(RF: sp.csr_matrix, rhs: np.ndarray, tol: float) -> np.ndarray:
    """``x = (I - RF)^-1 rhs`` by the Neumann series (``|RF|_inf < 1``)."""
    x = rhs.copy()
    scale = float(np.linalg.norm(rhs))
    if RF.nnz == 0 or scale == 0.0:
        return x
    for _ in range(10_000):
        nxt = rhs + RF @ x
        step = float(np.linalg.norm(nxt - x))
        x = nxt
        if step <= 1e-3 * tol * scale:
            return x
    raise SolveError("unpainted faces: the Neumann series did not converge")


def _neumann_terms(RF: sp.csr_matrix, target: float = 1e-3, most: int = 30) -> int:
    """Terms of the Neumann series of ``(I - RF)^-1`` that bring its remainder under
    ``target`` (``|RF|_inf^k``), at most ``most`` (0 for an empty ``RF``)."""
    if RF.nnz == 0:
        return 0
    q = float(np.abs(RF).sum(axis=1).max())
    if q <= 0.0:
        return 0
    if q >= 1.0:
        return most
    return int(min(most, max(1, np.ceil(np.log(target) / np.log(q)))))


def _neumann_fixed(RF: sp.csr_matrix, rhs: np.ndarray, terms: int) -> np.ndarray:
    """``sum_{k <= terms} RF^k rhs``: a fixed linear approximation of ``(I - RF)^-1 rhs``."""
    x = rhs
    for _ in range(terms):
        x = rhs + RF @ x
    return x


def _continue_hidden(M, Bsub, loc_seen, paint_off, mesh, sub, regularization, tol, maxiter):
    """Radiosity of the coupled hidden faces under the smooth-continuation model.

    Works on the sub-problem of the seen + coupled faces (``M = (I - rho F)`` restricted to
    them). Hidden painted faces ``P`` are the unknowns of the least squares; hidden unpainted faces
    ``U`` follow from ``E_U = 0`` exactly: ``B_U = -M_UU^-1 (M_Us B_s + M_UP B_P)``,
    ``M_UU^-1`` applied by its Neumann series. Returns ``(B_hidden, iterations,
    relative residual)`` in the order of the hidden faces of ``sub``.
    """
    from selfillum.mesh import face_adjacency_weights

    hid = np.flatnonzero(~loc_seen)
    P = hid[~paint_off[hid]]
    U = hid[paint_off[hid]]
    s_idx = np.flatnonzero(loc_seen)
    # the blocks of M by columns (seen, P, U) in one compiled pass; by rows, gathers
    group = np.where(loc_seen, 0, np.where(paint_off, 2, 1))
    M_Ss, M_SP, M_SU = column_blocks(M, None, group, 3)
    e_s = M_Ss @ Bsub[s_idx]
    M_Us, M_UP, M_UU = M_Ss[U], M_SP[U], M_SU[U]
    M_PP = M_SP[P]
    C_sP = M_SP[s_idx]
    RF_UU = (sp.identity(U.size, format="csr") - M_UU).tocsr()
    RF_UUt = RF_UU.T
    # which rows of sub the hidden faces reach (what the smoothness terms below keep)
    moves = (np.diff(M_SP.indptr) > 0) | (np.diff(M_SU.indptr) > 0)

    def u_of(bp):  # B_U from B_P with E_U = 0
        return _neumann(RF_UU, -(M_Us @ Bsub[s_idx] + M_UP @ bp), tol)

    if P.size == 0:
        return u_of(np.zeros(0)), 0, 0.0
    u0 = u_of(np.zeros(P.size)) if U.size else np.zeros(0)
    e0 = e_s + M_SU @ u0 if U.size else e_s

    def g(x):  # E over sub from the deviation x of B_P: linear part
        out = M_SP @ x
        if U.size:
            out = out - M_SU @ _neumann(RF_UU, M_UP @ x, tol)
        return out

    def gt(y):
        out = M_SP.T @ y
        if U.size:
            out = out - M_UP.T @ _neumann(RF_UUt, M_SU.T @ y, tol)
        return out

    # smoothness over edges between painted faces of the sub-problem
    submesh = TriSurface(mesh.vertices, np.asarray(mesh.faces)[sub])
    D = face_adjacency_weights(submesh)
    if D.shape[0]:
        touches_unpainted = (abs(D) @ paint_off.astype(float)) > 0
        D = D[np.flatnonzero(~touches_unpainted)]
    D = D.tocsr()
    # only the edges touching a face whose emission depends on B_P (the rows of G) change
    # with it; the others add a constant to the objective: left out (the same minimiser)
    D = D[np.flatnonzero(abs(D) @ moves.astype(np.float64) > 0)]
    col_norm = np.sqrt(np.asarray(D.multiply(D).sum(axis=0)).ravel())[P]
    scale = float(np.median(col_norm[col_norm > 0])) if np.any(col_norm > 0) else 1.0
    lam = np.sqrt(regularization) * scale
    nh = P.size

    DT = D.T.tocsr()

    def normal(x):  # (G^T D^T D G + lam^2) x
        return gt(DT @ (D @ g(np.ravel(x)))) + lam**2 * np.ravel(x)

    # preconditioner: the problem in the hidden faces' emission y = M_PP x instead of
    # their radiosity x, with the light between hidden and seen faces kept only on the
    # diagonal (C = D_s M_sP: the seen faces lit by hidden ones): a sparse SPD graph
    # Laplacian L (+ diag(C^T C)) over the hidden painted faces, factored once, and
    # P = M_PP^-1 L^-1 M_PP^-T (M_PP^-1 by a fixed number of Neumann terms, so that P is
    # linear and symmetric). The Laplacian alone (P = L^-1) left the interreflection
    # among the hidden faces (rho F_PP, noisy with few rays a face) out of the
    # preconditioner: smooth radiosity is rough emission there, and CG took thousands
    # of iterations on a real grid (bench/README.md, "Unsteady run").
    D_s, DP = column_blocks(D, None, np.where(loc_seen, 0, np.where(paint_off, -1, 1)), 2)
    C = D_s @ C_sP  # the seen faces lit by the hidden ones: its diagonal
    lap = (DP.T @ DP + sp.diags(np.asarray(C.multiply(C).sum(axis=0)).ravel() + lam**2)
           ).tocsc()
    lu = spla.splu(lap)
    RF_PP = (sp.identity(nh, format="csr") - M_PP).tocsr()
    RF_PPt = RF_PP.T.tocsr()
    n_terms = _neumann_terms(RF_PP)

    def precondition(r):
        return _neumann_fixed(RF_PP, lu.solve(_neumann_fixed(RF_PPt, np.ravel(r), n_terms)),
                              n_terms)

    painted_seen = s_idx[~paint_off[s_idx]]
    prior = float(np.mean(Bsub[painted_seen] if painted_seen.size else Bsub[s_idx]))
    base = np.full(nh, prior)
    rhs = -gt(DT @ (D @ (e0 + g(base))))
    limit = maxiter if maxiter is not None else max(1000, 10 * nh)
    counter = {"k": 0}

    def count(_x):
        counter["k"] += 1

    N = spla.LinearOperator((nh, nh), matvec=normal, dtype=float)
    prec = spla.LinearOperator((nh, nh), matvec=precondition, dtype=float)
    norm_rhs = float(np.linalg.norm(rhs))
    x = np.zeros(nh)
    if norm_rhs > 0:
        x, flag = spla.cg(N, rhs, x0=x, rtol=tol, atol=0.0, maxiter=limit, M=prec,
                          callback=count)  # BLAS on one thread (the caller's limit)
        res = float(np.linalg.norm(normal(x) - rhs)) / norm_rhs
        if flag != 0 and not res <= 10 * tol:
            raise SolveError(
                f"correction least squares did not converge (preconditioned CG, relative "
                f"residual {res:.3g} after {counter['k']} iterations)"
            )
    else:
        res = 0.0
    itn, rel = counter["k"], res
    bp = base + x
    Bh = np.empty(hid.size)
    Bh[~paint_off[hid]] = bp
    if U.size:
        Bh[paint_off[hid]] = u_of(bp)
    return Bh, itn, rel
