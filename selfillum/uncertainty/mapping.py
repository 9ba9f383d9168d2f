"""Mapping: the error of a node value from the pixels it averages, for a field that varies
over the node's support (``/dcp_u_mapping`` of ``selfillum unsteady --uncertainty``).

Model. A node's value is a weighted mean of pixels: each face's pixels averaged, the faces
around the node averaged with their areas (:mod:`selfillum.unsteady.phase1`). The pixels'
surface points ``X_p`` with those weights ``w_p`` have, about the node ``x``, a first
moment ``delta = sum w_p (X_p - x)`` and a second moment ``Q = sum w_p (X_p - x)(X_p -
x)^T`` (plus each pixel's own footprint: ``side^2 / 12`` per axis, stretched along the view
by its obliqueness):
:func:`support_moments`, from frame 0's maps. A field ``s`` smooth over the support then
reads ``s(x) + delta . grad s + Q : H / 2`` (``H`` its Hessian): a shift of the node by
``delta`` (pixels that fall unevenly on the faces around it, an oblique view) and a
smoothing of the field's curvature. Both are errors of the node value against the field at
the node, proportional to the signal's spatial variation (a convected wave, a shock), at
the signal's own frequencies: the run's white noise floor does not see them.

The field's gradient and Hessian come from the measured dCp of the frame itself: per node,
a cubic in the tangent plane fitted by least squares to the node's two rings of
neighbours (:func:`mapping_operator`: one sparse (V, V) operator ``D``, ``e = D s``).
The node's mapping error of a frame is ``e``, and ``/dcp_u_mapping`` its RMS over the
frames (up to :data:`MAX_FRAMES` of them, spread over the run), with the part of the noise
that ``D`` carries removed (``sum_j D_nj^2 sigma_j^2``, taken as independent between
nodes): :func:`mapping_u`.

Left out: the curvature of the field within one face beyond the cubic fit, the change
of the support with the model's motion (frame 0's maps), the dark spots' pixels (patched
or left out by Phase 1, counted here as seen), and the part of the cubic fit's own error
that is not noise.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["support_moments", "mapping_operator", "mapping_u", "MAX_FRAMES"]

#: Frames the RMS of the mapping error is taken over (spread over the run).
MAX_FRAMES = 256
#: Vertices fitted at once (the batched least squares' memory).
_BATCH = 20_000


def support_moments(mesh, maps, images=None) -> tuple[np.ndarray, np.ndarray]:
    """``(delta, Q)``: (V, 3) and (V, 3, 3) first and second moments about each vertex of
    the pixels its value averages: every camera's pixels of frame 0 on the faces around
    it, each face's pixels averaged and the faces weighted by their areas (as the node
    value), and each pixel by its intensity in ``images`` (one a camera, e.g. frame 0;
    None: equal): the signal of a pixel enters the node's mean intensity in proportion to
    it (paint, lamp and texture non-uniformity). NaN where no pixel sees a face around
    the vertex."""
    from resection.surface.merge import pixel_weights

    nf, nv = len(mesh.faces), len(mesh.vertices)
    n = np.zeros(nf)  # pixels a face
    sw = np.zeros(nf)  # their weights' sum
    s1 = np.zeros((nf, 3))
    s2 = np.zeros((nf, 6))
    iu = np.triu_indices(3)
    for c, m in enumerate(maps):  # cameras
        fi = m.face_index.ravel()
        hit = fi >= 0
        f = fi[hit]
        X = np.asarray(m.points, np.float64).reshape(-1, 3)[hit]
        # the merge's pixel weights (feathered near the outline, 0 at its edge)
        w = pixel_weights(m).ravel()[hit]
        if images is not None:
            w = w * np.nan_to_num(np.maximum(np.asarray(images[c], np.float64).ravel()[hit],
                                             0.0))
        n += np.bincount(f, weights=(w > 0).astype(np.float64), minlength=nf)
        sw += np.bincount(f, w, nf)
        for k in range(3):
            s1[:, k] += np.bincount(f, w * X[:, k], nf)
        XX = X[:, iu[0]] * X[:, iu[1]] + _footprint(m, X, f)
        for k in range(6):
            s2[:, k] += np.bincount(f, w * XX[:, k], nf)
    a = np.asarray(mesh.area_faces, np.float64)
    seen = (n > 0) & (sw > 0)
    # a face's pixels enter the node's value as their mean (weight a_f / n_f each)
    cf = np.where(seen, a / np.maximum(n, 1), 0.0)
    fv = np.asarray(mesh.faces)
    W = sp.csr_matrix((np.repeat(cf, 3), (fv.ravel(), np.repeat(np.arange(nf), 3))),
                      shape=(nv, nf))
    ws = W @ sw
    with np.errstate(invalid="ignore", divide="ignore"):
        mu1 = (W @ s1) / ws[:, None]
        mu2 = (W @ s2) / ws[:, None]
    V = np.asarray(mesh.vertices, np.float64)
    delta = mu1 - V
    Q = np.empty((nv, 3, 3))
    Q[:, iu[0], iu[1]] = mu2
    Q[:, iu[1], iu[0]] = mu2
    # about the vertex: E[(X - x)(X - x)^T] = E[X X^T] - x mu^T - mu x^T + x x^T
    Q = Q - V[:, :, None] * mu1[:, None, :] - mu1[:, :, None] * V[:, None, :] \
        + V[:, :, None] * V[:, None, :]
    return delta, Q


def _footprint(smap, X, faces) -> np.ndarray:
    """(P, 6) second moment (upper triangle of the 3 x 3) of each pixel's own footprint
    on its face: a square pixel of side ``d / f`` at distance ``d`` (focal length ``f``
    pixels), stretched by ``1 / cos`` of the view's angle along the ray's direction in the
    face's plane; ``side^2 / 12`` per axis."""
    cam = smap.camera
    fpx = float(np.sqrt(abs(np.linalg.det(np.asarray(cam.K, np.float64)[:2, :2]))))
    r = X - cam.center[None, :]
    d = np.linalg.norm(r, axis=1)
    r = r / d[:, None]
    nrm = np.asarray(smap.mesh.face_normals, np.float64)[faces]
    c = np.abs(np.sum(r * nrm, axis=1))
    e = r - np.sum(r * nrm, axis=1)[:, None] * nrm  # the ray in the plane
    en = np.linalg.norm(e, axis=1)
    e = np.where(en[:, None] > 1e-12, e / np.maximum(en, 1e-300)[:, None], 0.0)
    side2 = (d / fpx) ** 2 / 12.0
    P = np.eye(3)[None] - nrm[:, :, None] * nrm[:, None, :]  # the face's plane
    stretch = 1.0 / np.maximum(c, 0.05) ** 2 - 1.0  # along e: side / cos
    M = side2[:, None, None] * (P + stretch[:, None, None] * e[:, :, None] * e[:, None, :])
    iu = np.triu_indices(3)
    return M[:, iu[0], iu[1]]


def _tangent_frames(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) two unit vectors spanning each vertex's tangent plane."""
    nrm = np.asarray(mesh.vertex_normals, np.float64)
    ref = np.where(np.abs(nrm[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(nrm, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(nrm, t1)


def mapping_operator(mesh, delta, Q, use=None) -> sp.csr_matrix:
    """(V, V) sparse ``D``: ``(D s)_n = delta_n · grad s + Q_n : H / 2`` with the gradient
    and Hessian of ``s`` from a cubic in vertex ``n``'s tangent plane, least squares
    over its two rings of neighbours among the ``use`` vertices (default all: those with a
    value); rows of vertices without moments or outside ``use`` are empty."""
    nv = len(mesh.vertices)
    fv = np.asarray(mesh.faces)
    e = np.concatenate([fv[:, [0, 1]], fv[:, [1, 2]], fv[:, [2, 0]]])
    A = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                      shape=(nv, nv))
    A1 = (A + sp.identity(nv, format="csr")).astype(bool).astype(np.float64)
    R2 = (A1 @ A1).tocsr()  # the two rings and the vertex itself
    R2.sort_indices()
    counts = np.diff(R2.indptr)
    kmax = int(counts.max()) if nv else 0
    V = np.asarray(mesh.vertices, np.float64)
    t1, t2 = _tangent_frames(mesh)
    ok = np.all(np.isfinite(delta), axis=1) & np.all(np.isfinite(Q), axis=(1, 2))
    use = np.ones(nv, bool) if use is None else np.asarray(use, bool)
    ok &= use
    rows, cols, vals = [], [], []
    for a in range(0, nv, _BATCH):  # blocks of vertices (memory)
        b = min(a + _BATCH, nv)
        idx = np.arange(a, b)
        k = counts[idx]
        slot = np.arange(kmax)[None, :]
        valid = slot < k[:, None]
        nb = np.where(valid, R2.indices[np.minimum(R2.indptr[idx][:, None] + slot,
                                                   len(R2.indices) - 1)], 0)
        valid &= use[nb]
        d = V[nb] - V[idx][:, None, :]  # (B, kmax, 3)
        u = np.einsum("bkd,bd->bk", d, t1[idx])
        v = np.einsum("bkd,bd->bk", d, t2[idx])
        h = np.sqrt(np.max(np.where(valid, u * u + v * v, 0.0), axis=1))
        h = np.where(h > 0, h, 1.0)  # a vertex without neighbours: an empty row
        us, vs = u / h[:, None], v / h[:, None]  # scaled: a well-conditioned fit
        # a cubic: its curvature at the node is unbiased by the field's third derivatives
        M = np.stack([np.ones_like(us), us, vs, 0.5 * us * us, us * vs, 0.5 * vs * vs,
                      us**3, us * us * vs, us * vs * vs, vs**3], -1)
        M = np.where(valid[..., None], M, 0.0)
        Pinv = np.linalg.pinv(M)  # (B, 10, kmax)
        du = np.einsum("bd,bd->b", delta[idx], t1[idx])
        dv = np.einsum("bd,bd->b", delta[idx], t2[idx])
        quu = np.einsum("bd,bde,be->b", t1[idx], Q[idx], t1[idx])
        quv = np.einsum("bd,bde,be->b", t1[idx], Q[idx], t2[idx])
        qvv = np.einsum("bd,bde,be->b", t2[idx], Q[idx], t2[idx])
        # coefficients of the scaled fit: c1 = h s_u, c3 = h^2 s_uu, c4 = h^2 s_uv
        z = np.zeros_like(du)
        g = np.stack([z, du / h, dv / h, 0.5 * quu / h**2, quv / h**2, 0.5 * qvv / h**2,
                      z, z, z, z], -1)
        row = np.einsum("bc,bck->bk", np.nan_to_num(g), Pinv)
        keep = valid & ok[idx][:, None]
        rows.append(np.broadcast_to(idx[:, None], keep.shape)[keep])
        cols.append(nb[keep])
        vals.append(row[keep])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(nv, nv))


def mapping_u(D, frames, sigma) -> tuple[np.ndarray, int]:
    """``(u, used)``: per vertex the RMS over ``frames`` (an iterable of (k, V) blocks of
    dCp per vertex, NaN unseen) of ``D dCp``, less the noise ``sigma`` (V,) it carries;
    ``used`` the number of frames."""
    acc = np.zeros(D.shape[0])
    used = 0
    for blk in frames:
        x = np.asarray(blk, np.float64)
        e = np.asarray(D @ np.nan_to_num(x).T)  # (V, k)
        acc += np.sum(e * e, axis=1)
        used += x.shape[0]
    noise = np.asarray(D.multiply(D) @ np.nan_to_num(np.asarray(sigma, np.float64)) ** 2)
    ms = acc / max(used, 1) - noise
    return np.sqrt(np.maximum(ms, 0.0)), used
