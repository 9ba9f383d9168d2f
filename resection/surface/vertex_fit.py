"""Per-face values to per-vertex values: the area-weighted fit behind
:meth:`SurfaceMap.to_image <resection.surface.surface_map.SurfaceMap.to_image>` and
:func:`vertex_values`.

Each vertex gets the area-weighted mean of the valued faces around it, corrected (with
``linear``) by an area-weighted least-squares gradient fitted to their centroids, which
makes the reconstruction exact for fields linear in space (:func:`_vertex_matrix`);
each vertex value is then held within the values of the faces it is built from
(:func:`_clamp_to_support`), so a jump in the field never overshoots. The
result is a sparse (vertices x faces) matrix per pattern of valued faces; its per-vertex
sums run in one compiled pass over the (vertex, face) pairs and over the vertices those
pairs touch only, so a camera that sees a fraction of a large grid pays for that fraction.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from resection.errors import InputError

if TYPE_CHECKING:
    import scipy.sparse as sp
    import trimesh

__all__ = ["vertex_values"]


def _as_float(a, name: str) -> np.ndarray:
    """float64 array of real numbers, or InputError naming ``name``."""
    arr = np.asarray(a)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                   or arr.dtype == bool) \
            or np.issubdtype(arr.dtype, np.complexfloating):
        raise InputError(f"{name}: expected real numbers, got dtype {arr.dtype}")
    return arr.astype(np.float64, copy=False)


def _face_geometry(mesh: trimesh.Trimesh):
    """Face centroids and areas, from trimesh's cache (computed once per mesh state)."""
    return (np.asarray(mesh.triangles_center, dtype=np.float64),
            np.asarray(mesh.area_faces, dtype=np.float64))


def _fit_pairs(vid, fid, w, cen, verts, nv, linear):
    """Coefficients of the (vertex, face) pairs and the number of directions the centroids
    span around each vertex (see :func:`_vertex_matrix`).

    The per-vertex work runs over the vertices the pairs touch only (numbered 0..n-1
    here), not over every vertex of the mesh: a camera sees a fraction of a large grid."""
    present = np.zeros(nv, dtype=bool)
    present[vid] = True
    ids = np.flatnonzero(present)  # compact vertex number -> mesh vertex
    loc = (np.cumsum(present) - 1)[vid]
    n = ids.size
    rank_c = np.zeros(n, dtype=np.int64)
    if linear:  # the same sums, in pair order, as one bincount per entry
        W_c, cbar, cov = _vertex_moments(loc, fid, w, cen, n)
    else:
        W_c = np.bincount(loc, weights=w, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        coef = w / W_c[loc]
    if linear:
        dc = cen[fid] - cbar[loc]  # (P, 3)
        evals = np.zeros((n, 3))
        evecs = np.zeros((n, 3, 3))
        act = W_c > 0  # vertices with no weighted face keep a zero covariance: no gradient
        evals[act], evecs[act] = np.linalg.eigh(cov[act])
        scale = evals[:, -1:]
        # a spread below the round-off of the coordinates is none (one valued face around a
        # vertex far from the origin: its centroid minus their mean is round-off, and its
        # inverse would blow the gradient up to 1e17)
        reach = np.abs(verts).max() if len(verts) else 0.0
        floor = W_c[:, None] * (1e-8 * reach) ** 2
        keep = (evals > 1e-2 * scale) & (evals > floor)
        rank_c = keep.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(keep, 1.0 / evals, 0.0)
        cinv = np.einsum("vij,vj,vkj->vik", evecs[act], inv[act], evecs[act])
        lever = np.zeros((n, 3))  # (x_v - cbar)^T C^+
        lever[act] = np.einsum("vi,vij->vj", verts[ids[act]] - cbar[act], cinv)
        coef = coef + w * np.einsum("pj,pj->p", lever[loc], dc)
    coef = np.where(np.isfinite(coef) & (w > 0), coef, 0.0)
    rank = np.zeros(nv, dtype=np.int64)
    rank[ids] = rank_c
    W = np.zeros(nv)
    W[ids] = W_c
    return coef, rank, W


@numba.njit(cache=True, nogil=True)
def _vertex_moments(loc, fid, w, cen, n):  # pragma: no cover - compiled
    """Weight ``W``, weighted mean centroid ``cbar`` and weighted covariance of the
    centroids about it, ``(n, 3, 3)``, of each vertex from its pairs, summed in pair
    order with NumPy's operations (``bincount`` of ``w * c``, then of
    ``w * dc_i * dc_j``): the same floats as those bincounts."""
    W = np.zeros(n)
    sums = np.zeros((n, 3))
    for p in range(loc.size):
        v = loc[p]
        W[v] += w[p]
        for k in range(3):
            sums[v, k] += w[p] * cen[fid[p], k]
    cbar = np.empty((n, 3))
    for v in range(n):
        ws = W[v] if W[v] > 0 else 1.0
        for k in range(3):
            cbar[v, k] = sums[v, k] / ws
    cov = np.zeros((n, 3, 3))
    for p in range(loc.size):
        v = loc[p]
        d0 = cen[fid[p], 0] - cbar[v, 0]
        d1 = cen[fid[p], 1] - cbar[v, 1]
        d2 = cen[fid[p], 2] - cbar[v, 2]
        cov[v, 0, 0] += w[p] * d0 * d0
        cov[v, 0, 1] += w[p] * d0 * d1
        cov[v, 0, 2] += w[p] * d0 * d2
        cov[v, 1, 1] += w[p] * d1 * d1
        cov[v, 1, 2] += w[p] * d1 * d2
        cov[v, 2, 2] += w[p] * d2 * d2
    for v in range(n):
        cov[v, 1, 0] = cov[v, 0, 1]
        cov[v, 2, 0] = cov[v, 0, 2]
        cov[v, 2, 1] = cov[v, 1, 2]
    return W, cbar, cov


def _vertex_matrix(mesh: trimesh.Trimesh, face_weight: np.ndarray, linear: bool,
                   centroids=None) -> sp.csr_matrix:
    """Sparse (V, F) matrix turning face values into vertex values.

    Each vertex gets the area-weighted mean of the face values around it; with ``linear``
    it is corrected by an area-weighted least-squares gradient fitted to the face centroids
    (``f_v = mean + g . (x_v - c_mean)``), which makes the reconstruction exact for fields
    linear in space wherever the centroids around a vertex span the needed directions.
    Directions in which the centroids spread less than a tenth of their largest spread
    (eigenvalue ratio 1e-2 of the weighted covariance) get no gradient: the normal
    direction of a smooth curved fan, where a fitted normal gradient would only amplify
    noise. Across a crease (e.g. a 90-degree corner) the centroids spread in 3-D and the
    full gradient is used. Vertices whose faces span fewer than 2 directions (a grid
    corner with one or two faces) use the faces around their neighbours too (2-ring).
    """
    import scipy.sparse as sp  # here: a command imports it while its rays run

    faces = np.asarray(mesh.faces, dtype=np.int64)
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    nv, nf = len(verts), len(faces)
    cen = np.asarray(mesh.triangles_center if centroids is None else centroids,
                     dtype=np.float64)
    vid = faces.ravel()  # incidence pairs (vertex, face)
    fid = np.repeat(np.arange(nf), 3)
    w = face_weight[fid]
    on = w > 0  # pairs of weightless (NaN) faces add nothing and get no coefficient: out
    coef, rank, W = _fit_pairs(vid[on], fid[on], w[on], cen, verts, nv, linear)
    vid_on, fid_on = vid[on], fid[on]
    M = sp.csr_matrix((coef, (vid_on, fid_on)), shape=(nv, nf))
    poor = np.flatnonzero((rank < 2) & (W > 0)) if linear else np.array([], dtype=int)
    if poor.size:
        inc = sp.csr_matrix((np.ones(vid.size), (vid, fid)), shape=(nv, nf))
        ring2 = (inc[poor] @ inc.T) @ inc  # faces around the neighbours of poor vertices
        ring2 = ring2.tocoo()
        v2, f2 = poor[ring2.row], ring2.col
        c2, r2, _ = _fit_pairs(v2, f2, face_weight[f2], cen, verts, nv, True)
        better = r2[poor] >= 2
        if better.any():
            sel = np.isin(v2, poor[better])
            keep_rows = np.ones(nv)
            keep_rows[poor[better]] = 0.0
            M = sp.diags(keep_rows) @ M + sp.csr_matrix(
                (c2[sel], (v2[sel], f2[sel])), shape=(nv, nf))
    return M.tocsr()


def vertex_values(
    mesh: trimesh.Trimesh, face_values, *, interpolation: str = "linear"
) -> np.ndarray:
    """Per-vertex values from per-face values (see :meth:`SurfaceMap.to_image`).

    Parameters
    ----------
    face_values : (F,) or (F, K) array_like
        NaN faces are left out of the vertex values.
    interpolation : {"linear", "mean"}
        ``"mean"``: area-weighted mean of the faces around the vertex; ``"linear"``: that
        mean corrected by an area-weighted least-squares gradient (exact for linear fields
        wherever the vertex lies among its faces' centroids), held within the values of
        the faces it is built from.

    Returns
    -------
    (V,) or (V, K) float64, NaN for vertices whose faces are all NaN.
    """
    fv = _as_float(face_values, "face_values")
    nf = len(mesh.faces)
    if fv.ndim not in (1, 2) or fv.shape[0] != nf:
        raise InputError(f"face_values: expected ({nf},) or ({nf}, K) for the mesh's {nf} "
                         f"faces, got shape {fv.shape}")
    if interpolation not in ("linear", "mean"):
        raise InputError(f"interpolation must be 'linear' or 'mean', got {interpolation!r}")
    _, area = _face_geometry(mesh)
    return _apply_vertex(mesh, area, fv, interpolation == "linear", cache=None)


def prepare_pattern(mesh, area, valued, linear, cache: dict, centroids=None) -> None:
    """Build the vertex matrix of face values valued exactly on ``valued`` into ``cache``
    (the all-valued pattern under ``linear``, any other under ``("prepared", linear)``,
    one kept at a time), for :func:`_apply_vertex` to find."""
    valued = np.asarray(valued, dtype=bool)
    if valued.all():
        if linear not in cache:
            cache[linear] = _vertex_matrix(mesh, area * valued, linear, centroids)
        return
    cache[("prepared", linear)] = (valued.copy(),
                                   _vertex_matrix(mesh, area * valued, linear, centroids))


def _cached(cache, pattern, linear):
    """The vertex matrix of ``pattern`` from ``cache`` (None when it is not there)."""
    if cache is None:
        return None
    if pattern.all():
        return cache.get(linear)
    kept = cache.get(("prepared", linear))
    if kept is not None and np.array_equal(kept[0], pattern):
        return kept[1]
    return None


def _apply_vertex(mesh, area, fv, linear, cache, centroids=None):
    """Vertex values of (F,) or (F, K) face values; columns are handled in groups sharing
    the same set of NaN faces (each group gets its own reconstruction matrix)."""
    flat = fv.reshape(len(fv), -1)
    finite = np.isfinite(flat)
    faces = np.asarray(mesh.faces)
    nv = len(mesh.vertices)
    out = np.empty((nv, flat.shape[1]))
    if finite.all():  # the usual case: one group, no sorting of NaN patterns
        patterns, group = np.ones((1, len(flat)), dtype=bool), np.zeros(flat.shape[1], int)
    else:  # distinct NaN patterns as byte strings (np.unique(axis=0) on F-wide boolean
        # rows builds an F-field dtype: 28 s for one 600,000-face frame)
        packed = np.ascontiguousarray(np.packbits(finite.T, axis=1))
        keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
        _, first, group = np.unique(keys, return_index=True, return_inverse=True)
        patterns = finite.T[first]
    for g, pattern in enumerate(patterns):  # loop over distinct NaN patterns, not faces
        cols = np.flatnonzero(group.ravel() == g)
        M = _cached(cache, pattern, linear)
        if M is None:
            M = _vertex_matrix(mesh, area * pattern, linear, centroids)
            if pattern.all() and cache is not None:
                cache[linear] = M
        X = np.where(pattern[:, None], flat[:, cols], 0.0)
        res = M @ X
        if linear:  # the gradient term may reach past the data: limit it
            _clamp_to_support(M, pattern, X, res)
        has = np.bincount(faces[pattern].ravel(), minlength=nv) > 0
        res[~has] = np.nan  # vertices with no finite face around them
        out[:, cols] = res
    return out.reshape((nv,) + fv.shape[1:])




def _clamp_to_support(M, pattern, X, res) -> None:
    """Limit each vertex value ``res[v]`` to the range of the valued face values its row of
    ``M`` combines (in place).

    The gradient correction of ``linear`` extrapolates from the face centroids to the
    vertex: across a jump of the field it overshoots (a field of 1..165 gave -17.9 to 174).
    Clamping each vertex to the smallest and largest value of the faces it is built from
    (a limiter, as finite-volume schemes limit reconstructed gradients) keeps every
    interpolated pixel within the values around it; the barycentric interpolation of
    three vertex values stays within their range. Linear fields stay exact wherever the
    vertex lies among the centroids of its faces (every interior vertex of a fan); on the
    edge of a grid the extrapolated value is cut to the values of the faces beside it.

    Parameters
    ----------
    M : (V, F) scipy.sparse.csr_matrix
        Vertex matrix; its stored entries name the faces of each vertex.
    pattern : (F,) bool
        The valued faces; the others are not in any range.
    X : (F, K) float64
        Face values (0 where not valued).
    res : (V, K) float64
        ``M @ X``, clamped in place.
    """
    _clamp_rows(M.indptr, M.indices, M.data, np.ascontiguousarray(pattern, dtype=np.bool_),
                np.ascontiguousarray(X), res)


@numba.njit(cache=True, nogil=True)
def _clamp_rows(indptr, indices, data, pattern, X, res):  # pragma: no cover - compiled
    """One pass over the rows of a CSR matrix: ``res[v, k]`` clipped to the smallest and
    largest ``X[f, k]`` of the valued faces ``f`` with a non-zero entry in row ``v``."""
    for v in range(indptr.size - 1):
        a, b = indptr[v], indptr[v + 1]
        for k in range(X.shape[1]):
            lo, hi, seen = np.inf, -np.inf, False
            for p in range(a, b):
                f = indices[p]
                if pattern[f] and data[p] != 0.0:
                    x = X[f, k]
                    lo = min(lo, x)
                    hi = max(hi, x)
                    seen = True
            if seen:
                res[v, k] = min(max(res[v, k], lo), hi)
