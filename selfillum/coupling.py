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

import inspect
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import trimesh
from scipy.sparse.csgraph import breadth_first_order

from resection.errors import InputError

from .mesh import check_mesh, face_normals
from .viewfactors import view_factors

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
    F = sp.csr_matrix(F)
    n = F.shape[0]
    mask = np.asarray(seen, dtype=bool)
    if mask.shape != (n,):
        raise InputError(f"seen: expected shape ({n},), got {mask.shape}")
    # a super-source (node n) linked to every seen face; one breadth-first search
    src = np.flatnonzero(mask)
    pattern = sp.csr_matrix(
        (np.ones(F.nnz, dtype=np.int8), F.indices, F.indptr), shape=(n, n)
    )
    link = sp.csr_matrix(
        (np.ones(src.size, dtype=np.int8), (np.zeros(src.size, dtype=np.int64), src)),
        shape=(1, n),
    )
    graph = sp.bmat([[pattern, sp.csr_matrix((n, 1), dtype=np.int8)],
                     [link, sp.csr_matrix((1, 1), dtype=np.int8)]], format="csr")
    order = breadth_first_order(graph, n, directed=True, return_predecessors=False)
    out = np.zeros(n + 1, dtype=bool)
    out[order] = True
    return out[:n] | mask


def _supports_rows() -> bool:
    return "rows" in inspect.signature(view_factors).parameters


def coupled_view_factors(
    mesh: trimesh.Trimesh,
    seen,
    rays_per_face: int = 256,
    seed: int = 0,
    *,
    progress: bool | Callable | None = False,
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
    if not _supports_rows():  # pragma: no cover - only before view_factors has `rows`
        F = view_factors(mesh, rays_per_face=rays_per_face, seed=seed, progress=progress)
        return F, coupled_faces(F, mask)
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=int(mask.sum()), desc="view factors (coupled rows)", unit="face",
                   leave=False)
    with _Rounds(mesh, rays_per_face, seed) as trace:
        done = np.zeros(n, dtype=bool)
        todo = mask.copy()
        parts = []
        while todo.any():
            rows = np.flatnonzero(todo)
            part = trace(rows)  # (N, N) with the rows of this round filled
            parts.append(part)
            done |= todo
            hit = np.zeros(n, dtype=bool)
            hit[part.indices] = True  # columns hit by this round's rays
            todo = hit & ~done
            if bar is not None:
                bar.total = int((done | todo).sum())
                bar.update(rows.size)
            elif callable(progress):
                progress(int(done.sum()), int((done | todo).sum()))
    if bar is not None:
        bar.close()
    F = parts[0] if len(parts) == 1 else sp.csr_matrix(sum(parts[1:], parts[0]))
    return F.tocsr(), done


class _Rounds:
    """Rows of ``F`` traced round after round with one Embree scene (or one pool of
    worker processes, each with its scene) for all rounds.

    :func:`selfillum.view_factors` with ``rows=`` builds its scene (and starts its pool)
    at every call: over the 3 to 5 rounds of a closure that cost more than the rays of
    the later rounds themselves (a 600,000-face scene takes seconds to build). The rows
    are traced by :mod:`selfillum.viewfactors`'s own per-chunk function, so each is the
    one ``view_factors`` gives (tests/test_unseen.py checks it against the full matrix).
    Where that module offers no such function, each round calls ``view_factors``.
    """

    def __init__(self, mesh, k: int, seed: int):
        from . import viewfactors as vf

        self.mesh, self.k, self.seed = mesh, int(k), int(seed)
        self.n = len(mesh.faces)
        self.pool = self.scene = self.job = None
        needed = ("_Job", "_trace_rows", "_worker_init", "_worker_trace", "_assemble",
                  "_workers", "_RAYS_PER_CHUNK", "_OFFSET", "RayScene")
        self.vf = vf if all(hasattr(vf, a) for a in needed) else None

    def __enter__(self):
        vf = self.vf
        if vf is None:
            return self._per_call
        check_mesh(self.mesh)
        if self.k < 1 or self.seed < 0:
            raise InputError(f"rays_per_face must be >= 1 and seed >= 0, got {self.k}, "
                             f"{self.seed}")
        vertices = np.asarray(self.mesh.vertices, dtype=np.float64)
        faces = np.asarray(self.mesh.faces, dtype=np.int64)
        size = float(np.ptp(vertices, axis=0).max())
        self.job = self._job(vertices, faces, size)
        if self.job is None:  # a job this module does not know how to fill
            self.vf = None
            return self._per_call
        self.chunk = max(1, vf._RAYS_PER_CHUNK // self.k)
        nproc = vf._workers(None, 4)  # the usable CPUs (one scene each), once
        if nproc > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            self.pool = ProcessPoolExecutor(nproc, mp_context=mp.get_context("fork"),
                                            initializer=vf._worker_init,
                                            initargs=(self.job,))
        else:
            self.scene = vf.RayScene(vertices, faces)
        return self._traced

    def _job(self, vertices, faces, size):
        """The per-chunk job of :mod:`selfillum.viewfactors`, filled by field name as
        ``view_factors`` fills it (one-sided faces); None for an unknown field."""
        import dataclasses

        normals = face_normals(self.mesh)
        values = {"vertices": vertices, "faces": faces, "normals": normals,
                  "normals32": normals.astype(np.float32), "k": self.k, "seed": self.seed,
                  "offset": self.vf._OFFSET * size, "two_sided": False}
        names = [f.name for f in dataclasses.fields(self.vf._Job)]
        if any(name not in values for name in names):
            return None
        return self.vf._Job(**{name: values[name] for name in names})

    def __exit__(self, *exc):
        if self.pool is not None:
            self.pool.shutdown()
        return False

    def _per_call(self, rows):
        return view_factors(self.mesh, rays_per_face=self.k, seed=self.seed, rows=rows)

    def _traced(self, rows):
        vf = self.vf
        chunks = [rows[i:i + self.chunk] for i in range(0, rows.size, self.chunk)]
        if self.pool is not None:  # the workers hold their scenes: even for one chunk
            results = list(self.pool.map(vf._worker_trace, chunks))
        else:
            if self.scene is None:
                self.scene = vf.RayScene(self.job.vertices, self.job.faces)
            results = [vf._trace_rows(self.job, self.scene, c) for c in chunks]
        counts = np.zeros(self.n, dtype=np.int64)
        hits = []
        for part, (c, h) in zip(chunks, results, strict=True):
            counts[part] = c
            hits.append((part, h))
        return vf._assemble(self.n, self.k, counts, hits)
