"""Mapping: the error of a node value from the pixels it averages, for a field that varies
over the node's support (``/dcp_u_mapping`` of ``selfillum unsteady --uncertainty``).

Model. A node's value is a weighted mean of pixels (:mod:`selfillum.unsteady.phase1`:
each face's pixels averaged, the faces around the node averaged with their areas, the dark
spots masked or patched). The pixels' surface points ``X_p`` with those weights ``w_p``
(times the pixel's intensity: its share of the node's intensity) have, about the node
``x``, a first moment ``delta = sum w_p (X_p - x)`` and a second moment ``Q = sum w_p (X_p
- x)(X_p - x)^T``, taken through Phase 1 itself
(:func:`selfillum.unsteady.uncertainty_images.support_moments`). A field ``s`` smooth over
the support then reads ``s(x) + delta . grad s + Q : H / 2`` (``H`` its Hessian): a shift
of the node by ``delta`` and a smoothing of the field's curvature. Both are errors of the
node value against the field at the node, proportional to the signal's spatial variation
(a convected wave, a shock), at the signal's own frequencies: the run's white noise floor
does not see them.

The field's gradient and Hessian at the node come from the measured dCp of the frame
itself: a quartic in the node's tangent plane fitted by least squares to its three rings
of neighbours (:func:`mapping_operator`: one sparse (V, V) operator ``D``, ``e = D s``).
Each neighbour's value is the field over its own pixels, so it is sampled at their
centroid ``x_j + delta_j`` and its quadratic terms are spread by their covariance. The
node's mapping error of a frame is ``e``, and ``/dcp_u_mapping`` its RMS over the frames
(up to :data:`MAX_FRAMES` of them, spread over the run), with the part of the noise that
``D`` carries removed (:func:`carried_noise`: the node noises made of their faces'
independent noises, shared between neighbours): :func:`mapping_u`.

Left out: the field's fifth and higher derivatives over the rings, the support's third and
higher moments (the cubic and quartic terms taken at the centroid), the change of the
support with the model's motion (frame 0's maps), and a variation of the faces' noise
around a node.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["mapping_operator", "mapping_u", "node_weights", "carried_noise", "MAX_FRAMES",
           "RINGS"]

#: Frames the RMS of the mapping error is taken over (spread over the run).
MAX_FRAMES = 256
#: Rings of neighbours the field's derivatives are fitted over.
RINGS = 3
#: Vertices fitted at once (the batched least squares' memory).
_BATCH = 20_000
#: Neighbours a quartic needs (else a cubic: its 15 terms, with some to spare).
_QUARTIC_MIN = 21


def _tangent_frames(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) two unit vectors spanning each vertex's tangent plane."""
    nrm = np.asarray(mesh.vertex_normals, np.float64)
    ref = np.where(np.abs(nrm[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(nrm, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(nrm, t1)


def mapping_operator(mesh, delta, Q, use=None, rings: int = RINGS) -> sp.csr_matrix:
    """(V, V) sparse ``D``: ``(D s)_n = dot(delta_n, grad s) + Q_n : H / 2`` with the
    gradient and Hessian of ``s`` from a quartic in vertex ``n``'s tangent plane fitted by
    least squares over its ``rings`` rings of neighbours among the ``use`` vertices
    (default all: those with a value); a cubic where fewer than 21 neighbours have a
    value. Rows of vertices without moments or outside ``use`` are empty."""
    nv = len(mesh.vertices)
    fv = np.asarray(mesh.faces)
    e = np.concatenate([fv[:, [0, 1]], fv[:, [1, 2]], fv[:, [2, 0]]])
    A = sp.csr_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                      shape=(nv, nv))
    A1 = (A + sp.identity(nv, format="csr")).astype(bool).astype(np.float64)
    R2 = A1
    for _ in range(rings - 1):  # the rings and the vertex itself
        R2 = (R2 @ A1).astype(bool).astype(np.float64)
    R2 = R2.tocsr()
    R2.sort_indices()
    counts = np.diff(R2.indptr)
    kmax = int(counts.max()) if nv else 0
    V = np.asarray(mesh.vertices, np.float64)
    t1, t2 = _tangent_frames(mesh)
    ok = np.all(np.isfinite(delta), axis=1) & np.all(np.isfinite(Q), axis=(1, 2))
    use = np.ones(nv, bool) if use is None else np.asarray(use, bool)
    ok &= use
    rows, cols, vals = [], [], []
    batch = max(1, _BATCH * 20 // max(kmax, 1))
    for a in range(0, nv, batch):  # blocks of vertices (memory)
        b = min(a + batch, nv)
        idx = np.arange(a, b)
        k = counts[idx]
        slot = np.arange(kmax)[None, :]
        valid = slot < k[:, None]
        nb = np.where(valid, R2.indices[np.minimum(R2.indptr[idx][:, None] + slot,
                                                   len(R2.indices) - 1)], 0)
        valid &= use[nb] & ok[nb]
        # each neighbour's value is the field over its own pixels: sampled at their
        # centroid x_j + delta_j, and its quadratic terms spread by their covariance
        dj = np.nan_to_num(delta[nb])
        Cj = np.nan_to_num(Q[nb]) - dj[:, :, :, None] * dj[:, :, None, :]
        d = V[nb] + dj - V[idx][:, None, :]  # (B, kmax, 3)
        u = np.einsum("bkd,bd->bk", d, t1[idx])
        v = np.einsum("bkd,bd->bk", d, t2[idx])
        cuu = np.einsum("bd,bkde,be->bk", t1[idx], Cj, t1[idx])
        cuv = np.einsum("bd,bkde,be->bk", t1[idx], Cj, t2[idx])
        cvv = np.einsum("bd,bkde,be->bk", t2[idx], Cj, t2[idx])
        h = np.sqrt(np.max(np.where(valid, u * u + v * v, 0.0), axis=1))
        h = np.where(h > 0, h, 1.0)  # a vertex without neighbours: an empty row
        us, vs = u / h[:, None], v / h[:, None]  # scaled: a well-conditioned fit
        h2 = (h * h)[:, None]
        # a quartic: its gradient and curvature at the node are unbiased by the field's
        # third and fourth derivatives (a cubic over two rings read a wave of 14 edges'
        # length 10 % low); the quartic's terms are zero columns (left out) where the
        # neighbours are too few
        quart = (valid.sum(axis=1) >= _QUARTIC_MIN)[:, None].astype(np.float64)
        M = np.stack([np.ones_like(us), us, vs, 0.5 * (us * us + cuu / h2),
                      us * vs + cuv / h2, 0.5 * (vs * vs + cvv / h2),
                      us**3, us * us * vs, us * vs * vs, vs**3,
                      quart * us**4, quart * us**3 * vs, quart * us * us * vs * vs,
                      quart * us * vs**3, quart * vs**4], -1)
        M = np.where(valid[..., None], M, 0.0)
        Pinv = np.linalg.pinv(M)  # (B, 15, kmax)
        du = np.einsum("bd,bd->b", delta[idx], t1[idx])
        dv = np.einsum("bd,bd->b", delta[idx], t2[idx])
        quu = np.einsum("bd,bde,be->b", t1[idx], Q[idx], t1[idx])
        quv = np.einsum("bd,bde,be->b", t1[idx], Q[idx], t2[idx])
        qvv = np.einsum("bd,bde,be->b", t2[idx], Q[idx], t2[idx])
        # coefficients of the scaled fit: c1 = h s_u, c3 = h^2 s_uu, c4 = h^2 s_uv
        z = np.zeros_like(du)
        g = np.stack([z, du / h, dv / h, 0.5 * quu / h**2, quv / h**2, 0.5 * qvv / h**2]
                     + [z] * 9, -1)
        row = np.einsum("bc,bck->bk", np.nan_to_num(g), Pinv)
        keep = valid & ok[idx][:, None]
        rows.append(np.broadcast_to(idx[:, None], keep.shape)[keep])
        cols.append(nb[keep])
        vals.append(row[keep])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(nv, nv))


def node_weights(mesh, seen_faces) -> sp.csr_matrix:
    """(V, F) sparse: the node value's weights of the faces around each vertex (their areas
    over the ``seen_faces``, each row summing to 1; empty where none is seen)."""
    nf, nv = len(mesh.faces), len(mesh.vertices)
    a = np.where(np.asarray(seen_faces, bool), np.asarray(mesh.area_faces, np.float64), 0.0)
    fv = np.asarray(mesh.faces)
    W = sp.csr_matrix((np.repeat(a, 3), (fv.ravel(), np.repeat(np.arange(nf), 3))),
                      shape=(nv, nf))
    s = np.asarray(W.sum(axis=1)).ravel()
    with np.errstate(divide="ignore"):
        return sp.csr_matrix(sp.diags(np.where(s > 0, 1.0 / s, 0.0)) @ W)


def carried_noise(D, W, sigma) -> np.ndarray:
    """(V,) variance of ``D n`` for a node noise ``n = W e`` made of independent face noises
    ``e`` (a pixel belongs to one face): the faces' variances from the vertices' ``sigma``
    (V,), each face taking the mean over its three vertices of ``sigma_v^2 / sum_f
    W_vf^2`` (the faces around a vertex taken as equally noisy). Neighbouring nodes share
    faces: their noises are correlated, and a difference of them carries less noise than
    independent nodes would."""
    s2 = np.nan_to_num(np.asarray(sigma, np.float64)) ** 2
    w2 = np.asarray(W.multiply(W).sum(axis=1)).ravel()
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(w2 > 0, s2 / w2, 0.0)
    cnt = np.asarray((W > 0).astype(np.float64).sum(axis=0)).ravel()
    Wb = (W > 0).astype(np.float64).T.tocsr()  # (F, V): a face's vertices with a value
    with np.errstate(invalid="ignore", divide="ignore"):
        face = np.where(cnt > 0, (Wb @ r) / cnt, 0.0)
    K = sp.csr_matrix(D @ W)
    return np.asarray(K.multiply(K) @ face)


def mapping_u(D, frames, sigma, W=None) -> tuple[np.ndarray, int]:
    """``(u, used)``: per vertex the RMS over ``frames`` (an iterable of (k, V) blocks of
    dCp per vertex, NaN unseen; a frame where a neighbour is unseen left out of the vertex's
    RMS) of ``D dCp``, less the noise ``sigma`` (V,) it carries
    (:func:`carried_noise` through the faces' weights ``W``, :func:`node_weights`; None:
    the vertices' noises taken as independent); ``used`` the number of frames."""
    acc = np.zeros(D.shape[0])
    cnt = np.zeros(D.shape[0])
    used = 0
    Dn = abs(D).astype(bool).astype(np.float64)  # the vertices a row reads
    for blk in frames:
        x = np.asarray(blk, np.float64)
        e = np.asarray(D @ np.nan_to_num(x).T)  # (V, k)
        ok = np.asarray(Dn @ np.isnan(x).T.astype(np.float64)) == 0  # no neighbour unseen
        acc += np.sum(np.where(ok, e * e, 0.0), axis=1)
        cnt += ok.sum(axis=1)
        used += x.shape[0]
    if W is not None:
        noise = carried_noise(D, W, sigma)
    else:
        noise = np.asarray(D.multiply(D) @ np.nan_to_num(np.asarray(sigma, np.float64)) ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        ms = np.where(cnt > 0, acc / cnt, 0.0) - noise
    return np.sqrt(np.maximum(ms, 0.0)), used
