"""Blocks of a CSR matrix and ``I - diag(r) A`` in compiled passes, for the solves.

SciPy's fancy indexing ``A[rows][:, cols]`` goes through a row gather, a column
re-indexing and, for column blocks, a CSC copy; ``identity - diags(r) @ A`` through a
sparse product and a sparse difference. The smooth continuation of
:func:`selfillum.correct` cuts the sub-problem's ``I - rho F`` into blocks by seen,
hidden painted and hidden unpainted faces. Here a cut is one kernel (a count pass and a
fill pass over the rows taken, every block at once) and the difference one pass:

* :func:`column_blocks`: ``A[rows][:, cols_g]`` for several disjoint column sets ``g``;
* :func:`identity_minus`: ``I - diag(r) A`` of a square matrix.

The passes run on one thread. On numba's threads, the solve's sparse passes and products
(0.2-20 ms each on the 610,704-face grid) were slower on a busy machine: a parallel
launch waits for every thread of the team, and a thread whose core another process holds
waits for its turn (asv's ``bench_transport.SparseProductThreadsVsScipy``, formerly
``bench/bench_launch.py``: 0.67-0.86x SciPy's one-thread product
with no process beside, 1.1-3.2x with 2 CPU-bound processes beside, on 2 cores).
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

__all__ = ["column_blocks", "identity_minus"]


def _csr(A) -> sp.csr_matrix:
    """``A`` as float64 CSR with sorted indices and no duplicates (a copy only if not),
    its index arrays int32 where they fit (SciPy's choice; one compiled signature of the
    kernels to load from numba's cache, not one per index type)."""
    A = sp.csr_matrix(A, dtype=np.float64)
    if not A.has_canonical_format:
        A = A.copy()
        A.sum_duplicates()
    if A.indices.dtype != np.int32 and max(A.nnz, *A.shape) < np.iinfo(np.int32).max:
        A = sp.csr_matrix((A.data, A.indices.astype(np.int32), A.indptr.astype(np.int32)),
                          shape=A.shape, copy=False)
    return A


def column_blocks(A, rows, groups, n_groups: int) -> list[sp.csr_matrix]:
    """The blocks ``A[rows][:, cols_g]`` for ``g`` in ``range(n_groups)``, in one pass.

    Parameters
    ----------
    A : sparse matrix
        ``(n, m)``, converted to float64 CSR (sorted indices) if it is not.
    rows : (r,) array_like of int or None
        The rows taken, in this order (``None``: all).
    groups : (m,) array_like of int
        The block of each column (``-1``: in none). Block ``g``'s columns are the columns
        of group ``g`` in increasing order (``np.flatnonzero(groups == g)``).
    n_groups : int
        Number of blocks.

    Returns
    -------
    list of scipy.sparse.csr_matrix
        Block ``g``, ``(r, count of group g)``, the same as ``A[rows][:, cols_g]``.
    """
    C = _csr(A)
    g = np.asarray(groups)
    if g.shape != (C.shape[1],):
        raise ValueError(f"groups: expected shape ({C.shape[1]},), got {g.shape}")
    if n_groups > 127 or (g.size and (g.min() < -1 or g.max() >= n_groups)):
        raise ValueError(f"groups: values must lie in [-1, {n_groups}) (at most 127 groups)")
    g = g.astype(np.int8)  # small: the random reads stay in cache
    r = np.arange(C.shape[0]) if rows is None else np.asarray(rows, dtype=np.int64)
    wide = C.nnz >= np.iinfo(np.int32).max or C.shape[1] >= np.iinfo(np.int32).max
    ptrs, out_idx, out_data, offsets, sizes = _blocks(
        C.indptr, C.indices, C.data, r, g, int(n_groups), np.int64(0) if wide else np.int32(0))
    return [sp.csr_matrix((out_data[offsets[k]:offsets[k + 1]],
                           out_idx[offsets[k]:offsets[k + 1]], ptrs[k]),
                          shape=(r.size, int(sizes[k])), copy=False)
            for k in range(n_groups)]


def identity_minus(A, scale) -> sp.csr_matrix:
    """``I - diag(scale) A`` of a square sparse matrix in one compiled pass.

    The diagonal entry of row ``i`` is ``1 - scale_i A_ii`` (stored even where ``A_ii``
    is not); every other entry is ``-scale_i A_ij``, stored where it is not 0 (as SciPy
    stores the products: the same sparsity as ``identity - diags(scale) @ A``).

    Parameters
    ----------
    A : (n, n) sparse matrix
        Converted to float64 CSR (sorted indices) if it is not.
    scale : (n,) array_like of float
        The row factors (the reflectance for ``I - rho F``).

    Returns
    -------
    (n, n) scipy.sparse.csr_matrix
        With sorted indices.
    """
    C = _csr(A)
    n = C.shape[0]
    if C.shape[1] != n:
        raise ValueError(f"identity_minus: A must be square, got {C.shape}")
    s = np.ascontiguousarray(scale, dtype=np.float64)
    if s.shape != (n,):
        raise ValueError(f"scale: expected shape ({n},), got {s.shape}")
    wide = C.nnz + n >= np.iinfo(np.int32).max
    indptr, indices, data = _identity_minus(C.indptr, C.indices, C.data, s,
                                            np.int64(0) if wide else np.int32(0))
    return sp.csr_matrix((data, indices, indptr), shape=(n, n), copy=False)


# --------------------------------------------------------------------------- kernels
@numba.njit(cache=True, nogil=True)
def _blocks(indptr, indices, data, rows, groups, n_groups, like):  # pragma: no cover
    """``(ptrs, indices, data, offsets, sizes)`` of the column blocks: block ``g`` is
    ``data[offsets[g]:offsets[g + 1]]`` (and its indices) with row pointers ``ptrs[g]``;
    ``like`` gives the index dtype."""
    m = groups.size
    local = np.empty(m, type(like))  # each column's rank within its group
    sizes = np.zeros(n_groups, np.int64)
    for j in range(m):
        g = groups[j]
        if g >= 0:
            local[j] = sizes[g]
            sizes[g] += 1
    nr = rows.size
    ptrs = np.zeros((n_groups, nr + 1), type(like))
    for r in range(nr):
        i = rows[r]
        for k in range(indptr[i], indptr[i + 1]):
            g = groups[indices[k]]
            if g >= 0:
                ptrs[g, r + 1] += 1
    offsets = np.zeros(n_groups + 1, np.int64)
    for g in range(n_groups):
        for r in range(nr):
            ptrs[g, r + 1] += ptrs[g, r]
        offsets[g + 1] = offsets[g] + ptrs[g, nr]
    out_idx = np.empty(offsets[n_groups], type(like))
    out_data = np.empty(offsets[n_groups])
    pos = np.empty(n_groups, np.int64)
    for r in range(nr):
        i = rows[r]
        for g in range(n_groups):
            pos[g] = offsets[g] + ptrs[g, r]
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            g = groups[j]
            if g >= 0:
                p = pos[g]
                out_idx[p] = local[j]
                out_data[p] = data[k]
                pos[g] = p + 1
    return ptrs, out_idx, out_data, offsets, sizes


@numba.njit(cache=True, nogil=True)
def _identity_minus(indptr, indices, data, s, like):  # pragma: no cover - compiled
    """``(indptr, indices, data)`` of ``I - diag(s) A`` in one pass (room for ``nnz + n``
    entries, trimmed); ``like`` gives the index dtype."""
    n = s.size
    out_ptr = np.zeros(n + 1, type(like))
    out_idx = np.empty(indptr[n] + n, type(like))
    out_data = np.empty(indptr[n] + n)
    p = 0
    for i in range(n):
        done = False  # the diagonal written
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            if j == i:
                out_idx[p] = i
                out_data[p] = 1.0 - s[i] * data[k]
                p += 1
                done = True
                continue
            if not done and j > i:
                out_idx[p] = i
                out_data[p] = 1.0
                p += 1
                done = True
            v = s[i] * data[k]
            if v != 0.0:
                out_idx[p] = j
                out_data[p] = -v
                p += 1
        if not done:
            out_idx[p] = i
            out_data[p] = 1.0
            p += 1
        out_ptr[i + 1] = p
    return out_ptr, out_idx[:p], out_data[:p]
