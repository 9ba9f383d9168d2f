"""The graph of a triangle mesh in compiled passes: coincident vertices, shared edges,
repeated faces.

Each is one pass over the vertices or the faces (a hash table, or a counting sort by the
smallest vertex index followed by a sort inside each small bucket), in place of
trimesh's and NumPy's sorts of whole row arrays (``np.unique(axis=0)``, ``argsort`` of
hashed rows), which take 0.1-0.2 s each on a 600,000-face grid. The results are those of
the NumPy and trimesh functions they replace (the tests compare them):

* :func:`vertex_classes`: the vertices that ``trimesh.Trimesh.merge_vertices`` merges
  (equal coordinates once scaled by ``10**digits`` and rounded to integers), each given
  the index of the first referenced vertex of its class;
* :func:`shared_edges`: ``trimesh.graph.face_adjacency`` (pairs of faces sharing an edge
  that exactly two faces use) with its edges;
* :func:`repeated_faces`: the faces that are the same triangle as an earlier face (the
  same three vertex indices in the same cyclic order);
* :func:`pair_weights`: the finite-volume weight ``sqrt(l / d)`` of each pair of faces
  sharing an edge (``l`` the edge length, ``d`` the distance between the face
  centroids), the NumPy gathers and norms of ``selfillum.mesh.face_adjacency_weights``
  in one pass;
* :func:`cross_squares`: the squared length of each face's edge cross product (four
  times its squared area), what the mesh checks compare with their size limits, without
  the ``(F, 3, 3)`` gather and the cross products of NumPy.

Indices are int64; no Python loop runs over vertices, edges or faces.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["vertex_classes", "shared_edges", "repeated_faces", "cross_squares", "pair_weights"]

_SMALL = 24  # buckets up to this size are sorted by insertion, larger ones by argsort


def vertex_classes(vertices, faces, digits: int) -> tuple[np.ndarray, int, bool]:
    """Coincident vertices, as trimesh's ``merge_vertices`` groups them.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Coordinates (model units).
    faces : (F, 3) array_like of int
        Vertex indices of the triangles, in ``[0, V)``.
    digits : int
        Two vertices are the same when ``round(x * 10**digits)`` are equal integers in
        each coordinate (trimesh: ``digits = util.decimal_to_digits(tol.merge)``).

    Returns
    -------
    rep : (V,) int64 ndarray
        For a vertex that a face uses, the smallest index of a used vertex with the same
        rounded coordinates (itself when it has no twin); -1 for an unused vertex.
    classes : int
        Number of distinct used vertices (what merging would keep).
    all_used : bool
        Every vertex is used by a face (merging would drop none).
    """
    q = (np.asarray(vertices, dtype=np.float64) * (10 ** int(digits))).round() \
        .astype(np.int64)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1)
    rep, classes, unused = _vertex_classes(np.ascontiguousarray(q), f)
    return rep, int(classes), bool(unused == 0)


def shared_edges(faces) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of faces that share an edge used by exactly two faces.

    The same pairs as ``trimesh.graph.face_adjacency(faces, return_edges=True)``: edges
    as unordered vertex pairs; an edge used by one face (a border) or by three or more
    (a non-manifold junction) gives no pair, nor does one face using an edge twice.

    Parameters
    ----------
    faces : (F, 3) array_like of int
        Vertex indices (merge coincident vertices first, e.g. through
        :func:`vertex_classes`: ``rep[faces]``).

    Returns
    -------
    pairs : (P, 2) int64 ndarray
        Face indices, the smaller first; rows ordered by edge (smaller vertex index,
        then larger), not in trimesh's order.
    edges : (P, 2) int64 ndarray
        The shared edge of each pair: its vertex indices, the smaller first.
    """
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"faces: expected shape (F, 3), got {f.shape}")
    nv = int(f.max()) + 1 if f.size else 0
    return _shared_edges(f, nv)


def repeated_faces(faces) -> np.ndarray:
    """Pairs ``(first, copy)`` of faces that are the same triangle with the same winding.

    Parameters
    ----------
    faces : (F, 3) array_like of int
        Vertex indices, ``>= 0``.

    Returns
    -------
    (M, 2) int64 ndarray
        For every face that repeats an earlier one (the same vertex indices in the same
        cyclic order), the index of the earliest such face and its own; rows in the
        order of the copies. Opposite windings of the same vertices are not repeats.
    """
    f = np.ascontiguousarray(faces, dtype=np.int64)
    if len(f) < 2:
        return np.empty((0, 2), np.int64)
    return _repeated_faces(f, int(f.max()) + 1)


def cross_squares(vertices, faces) -> np.ndarray:
    """``|(v1 - v0) x (v2 - v0)|^2`` of every face, ``(F,)`` float64 (model units to the
    fourth): the same products and sums, in the same order, as ``np.cross`` followed by
    ``np.einsum("ij,ij->i", c, c)``.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
    faces : (F, 3) array_like of int
        Indices in ``[0, V)`` (not checked here).
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    return _cross_squares(v, f)


def pair_weights(vertices, faces, pairs, edges) -> np.ndarray:
    """``sqrt(l / max(d, tiny))`` of each pair of faces sharing an edge, ``(P,)`` float64.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Coordinates (model units).
    faces : (F, 3) array_like of int
        Vertex indices (those the pairs were found on, e.g. merged ones).
    pairs, edges : (P, 2) array_like of int
        Faces of each pair and their shared edge's vertices (:func:`shared_edges`).

    Returns
    -------
    (P,) float64 ndarray
        ``l`` the edge's length, ``d`` the distance between the two faces' centroids
        (the mean of their three vertices, summed in vertex order and divided by 3, as
        trimesh's ``triangles_center``), ``tiny`` the smallest normal float64 (square
        root of model units).
    """
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    p = np.ascontiguousarray(pairs, dtype=np.int64)
    e = np.ascontiguousarray(edges, dtype=np.int64)
    return _pair_weights(v, f, p, e, np.finfo(np.float64).tiny)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _pair_weights(v, f, pairs, edges, tiny):  # pragma: no cover - compiled
    out = np.empty(pairs.shape[0])
    for q in range(pairs.shape[0]):
        a, b = edges[q, 0], edges[q, 1]
        dx, dy, dz = v[a, 0] - v[b, 0], v[a, 1] - v[b, 1], v[a, 2] - v[b, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        i, j = pairs[q, 0], pairs[q, 1]
        d2 = 0.0
        for k in range(3):
            ci = (v[f[i, 0], k] + v[f[i, 1], k] + v[f[i, 2], k]) / 3.0
            cj = (v[f[j, 0], k] + v[f[j, 1], k] + v[f[j, 2], k]) / 3.0
            d2 += (ci - cj) * (ci - cj)
        out[q] = np.sqrt(length / max(np.sqrt(d2), tiny))
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def edge_cross(v, a, b, c):  # pragma: no cover - compiled
    """The edges ``e1 = v[b] - v[a]``, ``e2 = v[c] - v[a]`` of a triangle and their cross
    product ``n = e1 x e2`` (not normalised), as nine scalars ``e1x, e1y, e1z, e2x, e2y,
    e2z, nx, ny, nz``: the one arithmetic of every compiled face pass (areas, normals,
    plane duals), so that they agree to the last bit."""
    e1x, e1y, e1z = v[b, 0] - v[a, 0], v[b, 1] - v[a, 1], v[b, 2] - v[a, 2]
    e2x, e2y, e2z = v[c, 0] - v[a, 0], v[c, 1] - v[a, 1], v[c, 2] - v[a, 2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    return e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _cross_squares(v, f):  # pragma: no cover - compiled
    out = np.empty(f.shape[0])
    for i in range(f.shape[0]):
        cx, cy, cz = edge_cross(v, f[i, 0], f[i, 1], f[i, 2])[6:]
        out[i] = cx * cx + cy * cy + cz * cz
    return out


@numba.njit(cache=True, nogil=True, inline="always")
def _mix(a, b, c):
    h = np.uint64(a) * np.uint64(0x9E3779B97F4A7C15)
    h ^= np.uint64(b) * np.uint64(0xC2B2AE3D27D4EB4F) + (h >> np.uint64(29))
    h ^= np.uint64(c) * np.uint64(0x165667B19E3779F9) + (h >> np.uint64(32))
    h ^= h >> np.uint64(31)
    return h


@numba.njit(cache=True, nogil=True)
def _vertex_classes(q, flat_faces):
    """``(rep, classes, unused)``: open addressing on the rounded coordinates, vertices
    inserted in index order, so a class is named by its first used vertex."""
    nv = q.shape[0]
    used = np.zeros(nv, np.bool_)
    for k in range(flat_faces.size):
        used[flat_faces[k]] = True
    size = 1
    while size < 2 * nv + 2:
        size *= 2
    mask = np.uint64(size - 1)
    table = np.full(size, -1, np.int64)
    rep = np.full(nv, -1, np.int64)
    classes = 0
    unused = 0
    for v in range(nv):
        if not used[v]:
            unused += 1
            continue
        slot = _mix(q[v, 0], q[v, 1], q[v, 2]) & mask
        while True:
            w = table[slot]
            if w < 0:
                table[slot] = v
                rep[v] = v
                classes += 1
                break
            if q[w, 0] == q[v, 0] and q[w, 1] == q[v, 1] and q[w, 2] == q[v, 2]:
                rep[v] = w
                break
            slot = (slot + np.uint64(1)) & mask
    return rep, classes, unused


@numba.njit(cache=True, nogil=True)
def _bucket_order(low, n_keys):
    """Stable counting sort of ``low`` (values in ``[0, n_keys)``): ``(start, order)``,
    the items of key ``u`` at ``order[start[u]:start[u + 1]]`` in their original order."""
    start = np.zeros(n_keys + 1, np.int64)
    for k in range(low.size):
        start[low[k] + 1] += 1
    for u in range(n_keys):
        start[u + 1] += start[u]
    fill = start[:-1].copy()
    order = np.empty(low.size, np.int64)
    for k in range(low.size):
        order[fill[low[k]]] = k
        fill[low[k]] += 1
    return start, order


@numba.njit(cache=True, nogil=True)
def _sort_bucket(items, key):
    """Sort ``items`` in place by ``key[items]``, stably (equal keys keep their order)."""
    m = items.size
    if m <= _SMALL:
        for a in range(1, m):
            it = items[a]
            kv = key[it]
            b = a - 1
            while b >= 0 and key[items[b]] > kv:
                items[b + 1] = items[b]
                b -= 1
            items[b + 1] = it
    else:
        keys = np.empty(m, np.int64)
        for a in range(m):
            keys[a] = key[items[a]]
        o = np.argsort(keys, kind="mergesort")
        items[:] = items[o]


@numba.njit(cache=True, nogil=True)
def _shared_edges(f, nv):
    nf = f.shape[0]
    ne = 3 * nf
    lo = np.empty(ne, np.int64)
    hi = np.empty(ne, np.int64)
    for i in range(nf):
        for k in range(3):
            a = f[i, k]
            b = f[i, (k + 1) % 3]
            lo[3 * i + k] = min(a, b)
            hi[3 * i + k] = max(a, b)
    start, order = _bucket_order(lo, nv)
    pairs = np.empty((ne // 2, 2), np.int64)
    edges = np.empty((ne // 2, 2), np.int64)
    m = 0
    for u in range(nv):
        s, e = start[u], start[u + 1]
        if e - s < 2:
            continue
        items = order[s:e]
        _sort_bucket(items, hi)
        g = 0
        while g < items.size:
            h = g + 1
            while h < items.size and hi[items[h]] == hi[items[g]]:
                h += 1
            if h - g == 2:
                f1 = items[g] // 3
                f2 = items[g + 1] // 3
                if f1 != f2:
                    pairs[m, 0] = min(f1, f2)
                    pairs[m, 1] = max(f1, f2)
                    edges[m, 0] = u
                    edges[m, 1] = hi[items[g]]
                    m += 1
            g = h
    return pairs[:m].copy(), edges[:m].copy()


@numba.njit(cache=True, nogil=True)
def _repeated_faces(f, nv):
    nf = f.shape[0]
    first = np.empty(nf, np.int64)  # each face's rotation: smallest index first
    key = np.empty(nf, np.int64)  # the other two, in cyclic order, as one integer
    for i in range(nf):
        r = 0
        if f[i, 1] < f[i, r]:
            r = 1
        if f[i, 2] < f[i, r]:
            r = 2
        first[i] = f[i, r]
        key[i] = f[i, (r + 1) % 3] * nv + f[i, (r + 2) % 3]
    start, order = _bucket_order(first, nv)
    copy = np.zeros(nf, np.bool_)
    of = np.empty(nf, np.int64)
    for u in range(nv):
        s, e = start[u], start[u + 1]
        if e - s < 2:
            continue
        items = order[s:e]  # face order; the sort is stable: the earliest face leads
        _sort_bucket(items, key)
        for a in range(1, items.size):
            if key[items[a]] == key[items[a - 1]]:
                copy[items[a]] = True
                of[items[a]] = of[items[a - 1]] if copy[items[a - 1]] else items[a - 1]
    n = 0
    for i in range(nf):
        n += copy[i]
    out = np.empty((n, 2), np.int64)
    k = 0
    for i in range(nf):
        if copy[i]:
            out[k, 0] = of[i]
            out[k, 1] = i
            k += 1
    return out
