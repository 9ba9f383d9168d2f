"""Which faces can change the correction of the seen ones: coupling through ``F``.

The correction of a seen face ``i`` is ``B_i - E_i = rho_i sum_j F_ij B_j``. It needs the
radiosity of every face ``j`` in row ``i`` of ``F``; the radiosity of a hidden face ``j``
obeys ``B_j = E_j + rho_j sum_k F_jk B_k`` and so needs the faces of row ``j``, and so on.
The hidden faces that matter are therefore exactly those *reachable* from the seen faces
along the non-zeros of ``F`` (``i -> j`` where ``F_ij > 0``), the closure of the sparsity
graph, whatever its depth:

* Claim. Let ``S`` be the seen faces and ``R`` the hidden faces reachable from ``S``.
  Every non-zero ``F_ij`` with ``i`` in ``S u R`` has ``j`` in ``S u R`` (by definition
  of reachability). So the equations of ``E_{S u R}`` involve only ``B_{S u R}``, and the
  hidden faces outside ``R`` enter neither the transport of the seen faces nor that of
  ``R``: whatever they emit, the seen faces' correction is the same. Dropping them from
  the solve is exact (:func:`selfillum.correct` with every row of ``F`` and with only
  these rows gives the same seen-face emission; tests/test_unseen.py checks it).
* The underside of a plate, the inside of a closed body, faces facing away from every
  seen face are outside ``R``: light cannot go from them to a seen face, even by
  bounces over other hidden faces.

Only the rows of ``S u R`` of ``F`` are needed. :func:`coupled_view_factors` finds them
round by round, casting rays from the seen faces first, then from the hidden faces that
those rays hit, and so on until no new face is hit: the rays cast are those of
``S u R``, not of the whole mesh.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numba
import numpy as np

from resection.errors import InputError
from selfillum.transport.viewfactors import RowTracer

if TYPE_CHECKING:
    import scipy.sparse as sp
    import trimesh

__all__ = ["coupled_faces", "coupled_view_factors"]


def coupled_faces(F, seen) -> np.ndarray:
    """Faces reachable from the seen ones along the non-zeros of ``F``.

    Parameters
    ----------
    F : (N, N) sparse matrix
        Form factors (only the sparsity pattern is used; rows not computed may be empty).
    seen : (N,) array_like of bool
        Faces with a measured radiosity.

    Returns
    -------
    (N,) bool ndarray
        ``True`` for the seen faces and every hidden face whose radiosity can reach a seen
        face through ``F`` (directly or by bounces over hidden faces).
    """
    import scipy.sparse as sp
    F = sp.csr_matrix(F)
    n = F.shape[0]
    mask = np.asarray(seen, dtype=bool)
    if mask.shape != (n,):
        raise InputError(f"seen: expected shape ({n},), got {mask.shape}")
    # one compiled breadth-first search from every seen face at once (SciPy's needs the
    # graph with a super-source appended: two copies of the pattern)
    return _reach(F.indptr, F.indices, np.ascontiguousarray(mask))


@numba.njit(cache=True, nogil=True)
def _reach(indptr, indices, seen):  # pragma: no cover - compiled
    """Nodes reachable from the ``seen`` ones along the stored entries of a CSR pattern
    (the seen ones included)."""
    out = seen.copy()
    queue = np.empty(seen.size, np.int64)
    tail = 0
    for i in range(seen.size):
        if seen[i]:
            queue[tail] = i
            tail += 1
    head = 0
    while head < tail:
        i = queue[head]
        head += 1
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            if not out[j]:
                out[j] = True
                queue[tail] = j
                tail += 1
    return out


def coupled_view_factors(
    mesh: trimesh.Trimesh,
    seen,
    rays_per_face: int = 256,
    seed: int = 0,
    *,
    progress: bool | Callable | None = False,
    caster=None,
    checked: bool = False,
) -> tuple[sp.csr_matrix, np.ndarray]:
    """The rows of ``F`` that the correction of the seen faces needs, and no others.

    Round 1 casts rays from the seen faces; each further round casts rays from the hidden
    faces hit in the previous round that have no row yet; it stops when a round hits no
    new hidden face. Each row is the estimate :func:`selfillum.view_factors` gives for it
    in the full computation (same ``rays_per_face`` and ``seed``).

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The model.
    seen : (N,) array_like of bool
        Faces with a measured radiosity (for a stack of frames: seen in any frame).
    rays_per_face, seed : int
        As for :func:`selfillum.view_factors`.
    progress : bool or callable
        ``True``: a ``tqdm`` bar over the faces traced; a callable is called after each
        round with ``(faces traced, faces known to need a row)``.
    caster : resection.surface.visibility.RayCaster, optional
        An Embree scene of ``mesh`` already built (the surface map's): traced in, not
        built again (the rows are the same: see
        :class:`~selfillum.transport.viewfactors.RowTracer`).
    checked : bool
        ``mesh`` has passed :func:`selfillum.mesh.check_mesh` already.

    Returns
    -------
    F : (N, N) scipy.sparse.csr_matrix
        Rows of the seen and coupled faces filled; the other rows empty.
    rows : (N,) bool ndarray
        Faces whose row was computed: the seen faces and the hidden faces coupled to them
        (:func:`coupled_faces` of ``F`` and ``seen``).

    Notes
    -----
    When :func:`selfillum.view_factors` cannot restrict its rows (no ``rows`` argument),
    the whole ``F`` is computed and ``rows`` is still the coupled set.
    """
    n = len(mesh.faces)
    mask = np.asarray(seen, dtype=bool)
    if mask.shape != (n,):
        raise InputError(f"seen: expected shape ({n},), got {mask.shape}")
    if not mask.any():
        raise InputError("seen: no face is seen, nothing to correct")
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=int(mask.sum()), desc="view factors (coupled rows)", unit="face",
                   leave=False)
    with RowTracer(mesh, rays_per_face, seed, caster=caster, checked=checked) as tracer:
        # one tracer (one Embree scene, one set of threads) for every round: building a
        # 600,000-face scene and starting the threads at every round cost more than the
        # rays of the later rounds; the hits of all rounds assembled into F once
        done = np.zeros(n, dtype=bool)
        todo = mask.copy()
        counts = np.zeros(n, dtype=np.int64)
        parts = []
        while todo.any():
            rows = np.flatnonzero(todo)
            c, p = tracer.hits(rows)  # the rows of this round: disjoint from the others'
            counts += c
            parts += p
            done |= todo
            hit = np.zeros(n, dtype=bool)
            for _, h in p:
                hit[h] = True  # faces hit by this round's rays
            todo = hit & ~done
            if bar is not None:
                bar.total = int((done | todo).sum())
                bar.update(rows.size)
            elif callable(progress):
                progress(int(done.sum()), int((done | todo).sum()))
        F = tracer.assemble(counts, parts)
    if bar is not None:
        bar.close()
    return F, done
