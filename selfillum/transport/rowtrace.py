"""Rows of the view factors in one compiled pass: each face's rays made, traced in Embree
and filtered, on numba's threads.

:func:`trace_rows` makes the RQMC rays of each face (the rays of
:func:`selfillum.transport.sampling.sample_rays` for the same face index and seed, bit for
bit: the same per-ray code, :func:`~selfillum.transport.sampling._rqmc_ray`), traces each
one as it is made (:func:`resection.surface.embree.first_hit`, ``rtcIntersect1``) and keeps
the hits that count (not a miss, not the ray's own face, and, one-sided, not the back of a
face). No ``(M, 3)`` ray arrays are made and no Python thread pool runs: the faces of a
call are split over numba's threads (``numba.set_num_threads``), and Python's GIL is
released throughout.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from resection.surface.embree import first_hit, ray_buffer
from selfillum.transport.sampling import _U, _centroid, _frame, _rqmc_ray, _shift

if TYPE_CHECKING:
    import scipy.sparse as sp

__all__ = ["trace_rows", "assemble_rows", "interleaved"]

#: Blocks of consecutive faces a thread, taken interleaved (:func:`interleaved`): small
#: enough for every thread to sample the whole mesh, large enough to keep each block's
#: faces (and their BVH nodes) together.
_BLOCKS_PER_THREAD = 32


@numba.njit(cache=True, nogil=True, parallel=True)
def _trace_faces(fn, scene, rows, vertices, faces, origin, scale, normals, normals32, rbase,
                 seed, two_sided, offset, order, hits, counts, totals):  # pragma: no cover
    """The kept hits of faces ``rows``, in ``len(totals)`` blocks of consecutive faces:
    block ``b`` (faces ``b n // nb <= j < (b + 1) n // nb``) writes its hits, grouped by
    face, from ``hits[(b n // nb) K]`` on, face ``rows[j]``'s count into ``counts[j]`` and
    the block's into ``totals[b]``. The parallel loop takes the blocks in the order
    ``order`` (see :func:`interleaved`).

    ``fn`` is ``rtcIntersect1`` and ``scene`` the Embree scene's handle, in the frame where
    a model point ``x`` is at ``(x - origin) * scale``; ``vertices`` (float64, model
    units), ``faces``, ``normals`` (unit, float64) and ``normals32`` (float32) cover the
    whole mesh; ``rbase`` is the bit-reversed Sobol base (``(K, dims)``, dims 5 when
    ``two_sided``); ``offset`` (float32, scene units) lifts the origins."""
    n, k = rows.shape[0], rbase.shape[0]
    dims = rbase.shape[1]
    nb = totals.shape[0]
    for q in numba.prange(nb):
        b = order[q]
        buf, ib = ray_buffer()  # the block's scratch RTCRayHit
        tri = np.empty((3, 3), dtype=np.float32)
        c = np.empty(3, dtype=np.float32)
        nrm = np.empty(3, dtype=np.float32)
        t1 = np.empty(3, dtype=np.float32)
        t2 = np.empty(3, dtype=np.float32)
        ro = np.empty(3, dtype=np.float32)
        rd = np.empty(3, dtype=np.float32)
        key = np.zeros(5, dtype=np.uint64)
        m = (b * n // nb) * k
        for j in range(b * n // nb, (b + 1) * n // nb):
            f = rows[j]
            for a in range(3):
                vi = faces[f, a]
                for x in range(3):
                    tri[a, x] = np.float32((vertices[vi, x] - origin[x]) * scale)
            _centroid(tri, c)
            a0, a1, a2, b0, b1, b2 = _frame(normals[f, 0], normals[f, 1], normals[f, 2])
            t1[0], t1[1], t1[2] = a0, a1, a2
            t2[0], t2[1], t2[2] = b0, b1, b2
            for x in range(3):
                nrm[x] = normals32[f, x]
            for x in range(dims):
                key[x] = _shift(seed, f, x)
            m0 = m
            for i in range(k):
                _rqmc_ray(rbase, i, key, two_sided, tri, c, nrm, t1, t2, offset, ro, rd)
                h = first_hit(fn, scene, buf, ib, ro[0], ro[1], ro[2], rd[0], rd[1], rd[2])
                if h < 0 or h == f:
                    continue
                if not two_sided:
                    dn = (rd[0] * normals32[h, 0] + rd[1] * normals32[h, 1]
                          + rd[2] * normals32[h, 2])
                    if dn >= 0:
                        continue
                hits[m] = h
                m += 1
            counts[j] = m - m0
        totals[b] = m - (b * n // nb) * k


def interleaved(blocks: int, threads: int) -> np.ndarray:
    """The order in which a parallel loop takes ``blocks`` consecutive blocks of faces so
    that each of ``threads`` threads gets blocks from all over the mesh.

    numba splits a ``prange`` into one contiguous share of iterations a thread (static
    scheduling). Faces next to each other cost alike and faces far apart do not (rays
    that escape against rays that hit: on the 610k-face grid, sixteen contiguous shares
    took from 0.4 to 1.6 times their mean), so contiguous shares leave threads idle.
    Iteration ``q`` takes block ``order[q]``: thread ``t``'s share is blocks
    ``t, t + threads, t + 2 threads, ...``.

    Returns
    -------
    (blocks,) int64
        A permutation of ``range(blocks)``.
    """
    threads = max(1, min(int(threads), int(blocks)))
    per = -(-blocks // threads)
    grid = np.arange(per * threads, dtype=np.int64).reshape(per, threads).T.ravel()
    return grid[grid < blocks]


def trace_rows(scene, rows: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
               normals: np.ndarray, normals32: np.ndarray, rbase: np.ndarray, seed: int,
               two_sided: bool, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """The kept hits of the rays of faces ``rows``.

    Parameters
    ----------
    scene : selfillum.transport.viewfactors.RayScene
        The Embree scene (its ``scene`` a :class:`resection.surface.embree.Scene`) and its
        frame (``origin``, ``scale``).
    rows : (n,) int64
        Faces whose rays are traced.
    vertices, faces, normals, normals32
        The whole mesh: float64 vertices (model units), int64 faces, unit normals float64
        and float32.
    rbase : (K, dims) uint64
        Bit-reversed Sobol base points (``sampling._reversed_base``), dims 5 two-sided.
    seed : int
        Seed of the RQMC scramble.
    two_sided : bool
        Rays leave both sides (``rbase``'s 5th column picks the side) and hits count on
        either side of a face.
    offset : float
        Lift of the ray origins off their face (model units).

    Returns
    -------
    counts : (n,) int32
        Kept hits of each face.
    hits : (counts.sum(),) int32
        The hit faces, grouped by face in the order of ``rows``.
    """
    k = rbase.shape[0]
    n = rows.shape[0]
    counts = np.zeros(n, dtype=np.int32)
    padded = np.empty(n * k, dtype=np.int32)
    threads = numba.get_num_threads()
    nb = max(1, min(n, _BLOCKS_PER_THREAD * threads))  # blocks of faces, a scratch ray each
    totals = np.zeros(nb, dtype=np.int64)
    scale = float(scene.scale)
    _trace_faces(scene.scene.intersect, scene.scene.handle, rows, vertices, faces,
                 np.asarray(scene.origin, dtype=np.float64), scale, normals, normals32,
                 rbase, _U(seed), bool(two_sided), np.float32(offset * scale),
                 interleaved(nb, threads), padded, counts, totals)
    first = np.arange(nb) * n // nb * k  # where each block's hits start
    return counts, np.concatenate([padded[a:a + t] for a, t in zip(first, totals, strict=True)])


@numba.njit(cache=True, nogil=True, parallel=True)
def _sort_rows(hits, starts, counts, unique):  # pragma: no cover - compiled
    """Sort each row's hits in place (row ``i``: ``hits[starts[i]:starts[i] + counts[i]]``)
    and count its distinct faces into ``unique[i]``."""
    for i in numba.prange(counts.shape[0]):
        c = counts[i]
        if c == 0:
            unique[i] = 0
            continue
        a = starts[i]
        hits[a:a + c] = np.sort(hits[a:a + c])
        u = 1
        for j in range(a + 1, a + c):
            if hits[j] != hits[j - 1]:
                u += 1
        unique[i] = u


@numba.njit(cache=True, nogil=True, parallel=True)
def _fill_rows(hits, starts, counts, out_start, weight, indices, data):  # pragma: no cover
    """Each row's distinct faces (sorted) into ``indices`` from ``out_start[i]`` on, and
    in ``data`` the sum of ``weight`` once for every hit on that face (summed one hit at a
    time, as ``scipy.sparse``'s ``sum_duplicates`` does)."""
    for i in numba.prange(counts.shape[0]):
        c = counts[i]
        if c == 0:
            continue
        a = starts[i]
        o = out_start[i]
        indices[o] = hits[a]
        data[o] = weight
        for j in range(a + 1, a + c):
            if hits[j] == hits[j - 1]:
                data[o] += weight
            else:
                o += 1
                indices[o] = hits[j]
                data[o] = weight


def assemble_rows(n: int, k: int, counts: np.ndarray, hits: list) -> sp.csr_matrix:
    """``F`` (``(n, n)`` CSR, sorted distinct columns) from the kept hits: ``counts`` the
    hits of every face (``(n,)``), ``hits`` a list of ``(faces, hit faces)`` arrays (the
    hits grouped by face in the order of ``faces``; the faces of different parts
    distinct). Each hit adds ``1 / k``. Sorted and summed per row on numba's threads."""
    import scipy.sparse as sp
    faces = (np.concatenate([p for p, _ in hits]) if hits else np.zeros(0, np.int64))
    flat = (np.concatenate([h for _, h in hits]) if hits else np.zeros(0, np.int32))
    c = np.ascontiguousarray(counts[faces], dtype=np.int64)
    starts = np.zeros(c.size, dtype=np.int64)
    np.cumsum(c[:-1], out=starts[1:])
    unique = np.empty(c.size, dtype=np.int64)
    _sort_rows(flat, starts, c, unique)
    per_row = np.zeros(n, dtype=np.int64)
    per_row[faces] = unique
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(per_row, out=indptr[1:])
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    data = np.empty(indices.size, dtype=np.float64)
    _fill_rows(flat, starts, c, indptr[faces], 1.0 / k, indices, data)
    F = sp.csr_matrix((data, indices, indptr), shape=(n, n))
    F.has_sorted_indices = True
    F.has_canonical_format = True
    return F
