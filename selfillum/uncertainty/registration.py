"""Registration: the error of a camera's pose, carried to each face as a pixel displacement
times the local image gradient.

Model. The pose is a least-squares fit to the markers' image positions, each coordinate
with the stated standard uncertainty ``sigma_m`` (``--u marker=0.04px``, Liu and Sullivan's
order of magnitude). Its covariance is ``sigma_m^2 (J^T J)^-1`` with ``J`` (2M, 6) the
derivatives of the M markers' projections with respect to the pose perturbation
``theta = (w, dt)``: ``R' = exp([w]x) R``, ``t' = t + dt`` (:func:`pose_covariance`,
central differences of :meth:`resection.Camera.project`). A perturbed pose moves the image
point of a surface point by ``du = (du/dtheta) theta`` pixels; the face value then reads
the images ``du`` away, so its error is the merge-weighted mean over its pixels of
``grad I . du``. Wind-off and wind-on share the camera's pose, so the ratio's relative
error is ``du . grad ln(I_off / I_on)``: only the gradient of the pressure's signature,
not of the paint texture, matters (:func:`ratio_sensitivity`). The six components are
shared by every face of the camera (correlated), and independent between cameras.

Left out: the intrinsics' uncertainty (taken as known), the markers' 3-D positions'
uncertainty, and second-order terms (the displacement is small against the image's
curvature scale).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["perturbed", "pose_covariance", "face_jacobian", "pixel_jacobian",
           "ratio_sensitivity", "switching_variance", "normal_points"]



def perturbed(camera, theta):
    """The camera with its pose perturbed by ``theta = (w, dt)`` (rad, model units)."""
    from resection.camera.rotation import rotvec_to_matrix

    th = np.asarray(theta, dtype=np.float64)
    return camera.with_pose(R=rotvec_to_matrix(th[:3]) @ camera.R, t=camera.t + th[3:])


def _jacobian(camera, points) -> np.ndarray:
    """(P, 2, 6) derivatives of the projections of ``points`` w.r.t. ``theta``.

    ``x = R X + t`` moves by ``w x (R X) + dt``: the projection's derivative in the camera
    frame (three central differences of the camera at the origin, distortion included)
    chained with ``[-[R X]x | I]``."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    RX = P @ camera.R.T
    x = RX + camera.t
    cam0 = camera.with_pose(R=np.eye(3), t=np.zeros(3))
    h = 1e-6 * np.maximum(np.abs(x[:, 2]), 1e-9)[:, None]
    D = np.empty((len(P), 2, 3))
    for k in range(3):  # d uv / d x_cam
        e = np.zeros(3)
        e[k] = 1.0
        D[:, :, k] = (cam0.project(x + h * e) - cam0.project(x - h * e)) / (2 * h)
    J = np.empty((len(P), 2, 6))
    # d x / d w_k = e_k x RX: columns (0, -z, y), (z, 0, -x), (-y, x, 0), RX = (x, y, z)
    a, b, c = RX[:, 0], RX[:, 1], RX[:, 2]
    z0 = np.zeros_like(a)
    dxdw = np.stack([np.stack([z0, -c, b], 1), np.stack([c, z0, -a], 1),
                     np.stack([-b, a, z0], 1)], 2)  # (P, 3, 3): column k = d x / d w_k
    J[:, :, :3] = np.einsum("pij,pjk->pik", D, dxdw)
    J[:, :, 3:] = D
    return J


def pose_covariance(camera, markers, sigma_px: float, name: str = "markers") -> np.ndarray:
    """(6, 6) covariance of ``theta`` from the markers the camera sees.

    Parameters
    ----------
    camera : resection.Camera
    markers : (M, 3) array_like
        Marker positions (model units); those that project outside the image are left out.
    sigma_px : float
        Standard uncertainty of a marker's image position, per coordinate (pixels).
    """
    X = np.asarray(markers, dtype=np.float64).reshape(-1, 3)
    uv = camera.project(X)
    ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] > -0.5) & (uv[:, 1] > -0.5) \
        & (uv[:, 0] < camera.width - 0.5) & (uv[:, 1] < camera.height - 0.5)
    if ok.sum() < 3:
        raise InputError(f"{name}: {int(ok.sum())} markers in the camera's image; the pose's "
                         "covariance needs at least 3")
    J = _jacobian(camera, X[ok]).reshape(-1, 6)
    N = J.T @ J
    if np.linalg.cond(N) > 1e14:
        raise InputError(f"{name}: the markers the camera sees do not determine its pose "
                         "(collinear or too few)")
    return float(sigma_px) ** 2 * np.linalg.inv(N)


def face_jacobian(smap) -> np.ndarray:
    """(F, 2, 6) pixel displacement of each face's centroid per unit ``theta`` (NaN for the
    faces no pixel sees); kept on the map."""
    cached = getattr(smap, "_uncertainty_face_jacobian", None)
    if cached is not None:
        return cached
    f = smap.face_index.ravel()
    used = np.unique(f[f >= 0])
    Jf = np.full((smap.n_faces, 2, 6), np.nan)
    Jf[used] = _jacobian(smap.camera, np.asarray(smap.mesh.triangles_center)[used])
    smap._uncertainty_face_jacobian = Jf
    return Jf


def pixel_jacobian(smap) -> np.ndarray:
    """(6, H, W, 2) pixel displacement of each pixel's surface point per unit ``theta``
    (NaN off the model): the Jacobian at the centroid of the pixel's face
    (:func:`face_jacobian`; it varies over a face by the face's share of the image)."""
    H, W = smap.shape
    f = smap.face_index.ravel()
    hit = f >= 0
    J = np.full((H * W, 2, 6), np.nan)
    J[hit] = face_jacobian(smap)[f[hit]]
    return np.moveaxis(J, 2, 0).reshape(6, H, W, 2)


def ratio_sensitivity(weights, off_images, on_images, covariances) -> np.ndarray:
    """Shared sensitivity vectors of the ratio: (6 C, F) relative errors ``dR / R`` of the
    faces for one standard deviation of each camera's pose components (its covariance's
    Cholesky factor's columns).

    Parameters
    ----------
    weights : selfillum.uncertainty.faces.MergeWeights
    off_images, on_images : sequence of (H, W)
    covariances : sequence of (6, 6)
        Each camera's pose covariance.
    """
    rows = []
    C = len(weights.maps)
    for c, (m, off, on, S) in enumerate(zip(weights.maps, off_images, on_images,
                                            covariances, strict=True)):
        with np.errstate(invalid="ignore", divide="ignore"):
            lr = np.log(np.asarray(off, np.float64) / np.asarray(on, np.float64))
        gy, gx = np.gradient(lr)  # d/dv, d/du, pixels
        fidx = m.face_index.ravel()
        hit = np.flatnonzero(fidx >= 0)
        f = fidx[hit]
        Jf = face_jacobian(m)[f]  # (P, 2, 6): the pixel's face's Jacobian
        s = Jf[:, 0] * gx.ravel()[hit, None] + Jf[:, 1] * gy.ravel()[hit, None]  # d ln R / d th
        L = np.linalg.cholesky(S + 1e-30 * np.eye(6))
        x = np.nan_to_num(s) @ L  # (P, 6): one standard deviation of each component
        # the merge's mean of the camera's pixels on each face, its share of the face
        pw = weights.pixel[c].ravel()[hit]
        nf = m.n_faces
        den = np.bincount(f, weights=pw, minlength=nf)
        num = np.stack([np.bincount(f, weights=pw * x[:, j], minlength=nf) for j in range(6)])
        with np.errstate(invalid="ignore", divide="ignore"):
            v = np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)
        rows.append(v * weights.share[c])
    return np.concatenate(rows) if C else np.zeros((0, weights.camera.shape[1]))


def _edge_neighbours(mesh) -> np.ndarray:
    """(F, 3) the face across each local edge (v0v1, v1v2, v2v0), -1 on a border; vertices
    at the same place count as one (grids repeat their seams' points)."""
    V = np.asarray(mesh.vertices, np.float64)
    tol = 1e-9 * max(float(np.ptp(V, axis=0).max()), 1e-300)
    _, vid = np.unique(np.round(V / tol), axis=0, return_inverse=True)
    vid = vid.ravel().astype(np.int64)
    f = vid[np.asarray(mesh.faces, dtype=np.int64)]
    nf = len(f)
    e = np.stack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]], axis=1).reshape(-1, 2)
    e.sort(axis=1)
    key = e[:, 0] * (int(vid.max()) + 1) + e[:, 1]  # one integer an edge
    owner = np.repeat(np.arange(nf), 3)
    order = np.argsort(key, kind="stable")
    s_key, s_own = key[order], owner[order]
    out = np.full(3 * nf, -1, np.int64)
    pair = np.flatnonzero(s_key[1:] == s_key[:-1])  # consecutive slots of one edge
    out[order[pair]] = s_own[pair + 1]
    out[order[pair + 1]] = s_own[pair]
    return out.reshape(nf, 3)


#: Quasi-random pose draws of :func:`switching_variance`.
SWITCH_DRAWS = 256
_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19)


def normal_points(n: int, dim: int, seed: int = 0) -> np.ndarray:
    """(n, dim) quasi-random standard normal points: a Halton sequence with a random
    shift modulo 1 (seeded), through the normal quantile."""
    from scipy.special import ndtri

    if dim > len(_PRIMES):
        raise ValueError(f"normal_points: at most {len(_PRIMES)} dimensions")
    i = np.arange(1, n + 1)
    u = np.empty((n, dim))
    for d, b in enumerate(_PRIMES[:dim]):
        x, f, k = np.zeros(n), 1.0 / b, i.copy()
        while k.any():
            x += f * (k % b)
            k //= b
            f /= b
        u[:, d] = x
    u = (u + np.random.default_rng(seed).random(dim)) % 1.0
    return ndtri(np.clip(u, 1e-12, 1 - 1e-12))


def switching_variance(weights, off_images, on_images, covariances,
                       draws: int = SWITCH_DRAWS) -> np.ndarray:
    """(F,) variance of the faces' ``dR / R`` from pixels that change face.

    A face's value is the mean of the pixels whose centre falls in its projected triangle.
    A pose error ``theta`` moves the triangle's edges: pixel ``k``, at distance ``d_k``
    inside the edge nearest to it (outward normal ``n_k``), goes to the face across that
    edge when ``-n_k . J_k theta > d_k`` (``J_k`` its pixel Jacobian), and the face's
    ``ln R`` changes by ``-(w_k / W_i) (r_k - r_i)`` (``r = ln(I_off / I_on)``, ``w`` the
    merge's pixel weights) while the face across gains ``+(w_k / W_j) (r_k - r_j)``. The
    pixels of one face switch together (a shift moves all its edges alike; an edge along a
    pixel row or column moves a whole line of pixels at once), so the variance is taken
    over ``draws`` quasi-random poses ``theta ~ N(0, Sigma)`` (:func:`normal_points`),
    the pixels within 5 ``sigma`` of an edge only. For a
    small pose error this term is the larger one: it grows with ``sqrt(sigma)`` (whole
    pixels, with a small probability) where the gradient term grows with ``sigma``.
    Taken as independent between faces; edges on the model's outline (no face across)
    are left out.
    """
    import scipy.sparse as sp

    nf = weights.camera.shape[1]
    out = np.zeros(nf)
    for c, (m, off, on, S) in enumerate(zip(weights.maps, off_images, on_images, covariances,
                                            strict=True)):
        fidx = m.face_index.ravel()
        hit = np.flatnonzero(fidx >= 0)
        f = fidx[hit]
        H, W = m.shape
        pu, pv = (hit % W).astype(np.float64), (hit // W).astype(np.float64)
        uvv = m.camera.project(np.asarray(m.mesh.vertices, np.float64))
        tri = uvv[np.asarray(m.mesh.faces)[f]]  # (P, 3, 2)
        a, b = tri, np.roll(tri, -1, axis=1)  # edges v0v1, v1v2, v2v0
        ev = b - a
        ln = np.hypot(ev[..., 0], ev[..., 1])
        third = np.roll(tri, -2, axis=1)  # the vertex opposite each edge
        with np.errstate(invalid="ignore", divide="ignore"):
            cr = ev[..., 0] * (pv[:, None] - a[..., 1]) - ev[..., 1] * (pu[:, None] - a[..., 0])
            side = np.sign(ev[..., 0] * (third[..., 1] - a[..., 1])
                           - ev[..., 1] * (third[..., 0] - a[..., 0]))
            d = np.abs(cr) / ln
        d = np.where(np.isfinite(d), d, np.inf)
        k = np.argmin(d, axis=1)
        rows = np.arange(len(k))
        dk = d[rows, k]
        # outward normal of the nearest edge: away from the opposite vertex
        nvec = -side[rows, k][:, None] * np.stack([-ev[rows, k, 1], ev[rows, k, 0]], 1) \
            / ln[rows, k][:, None]
        Jf = np.nan_to_num(face_jacobian(m))  # (F, 2, 6)
        Jn = Jf[f, 0] * nvec[:, :1] + Jf[f, 1] * nvec[:, 1:]  # (P, 6)
        sig = np.sqrt(np.maximum(np.sum((Jn @ S) * Jn, axis=1), 0.0))
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.log(np.asarray(off, np.float64).ravel()[hit]
                       / np.asarray(on, np.float64).ravel()[hit])
        nb = _edge_neighbours(m.mesh)[f, k]
        pw = weights.pixel[c].ravel()[hit]
        Wsum = np.bincount(f, weights=pw, minlength=nf)
        with np.errstate(invalid="ignore", divide="ignore"):
            rf = np.bincount(f, weights=pw * np.nan_to_num(r), minlength=nf) / Wsum
        sel = np.flatnonzero((nb >= 0) & np.isfinite(r) & (pw > 0) & (sig > 0)
                             & (dk < 5.0 * sig))
        if not sel.size:
            continue
        z = normal_points(draws, 6, seed=c)
        theta = z @ np.linalg.cholesky(S + 1e-30 * np.eye(6)).T  # (M, 6)
        # the triangle moves by J theta: the pixel's place in it by -J theta
        # (single precision: the displacements are a few pixels, compared with d)
        leave = (Jn[sel].astype(np.float32) @ (-theta.T).astype(np.float32)
                 > dk[sel, None].astype(np.float32))  # (Psel, M)
        faces = np.concatenate([f[sel], nb[sel]])
        uniq, loc = np.unique(faces, return_inverse=True)
        lumps = []
        for part, face in ((0, f[sel]), (1, nb[sel])):  # losing, gaining face
            with np.errstate(invalid="ignore", divide="ignore"):
                lump = pw[sel] / Wsum[face] * (r[sel] - rf[face]) * weights.share[c][face]
            lumps.append(np.nan_to_num(lump) * (-1.0 if part == 0 else 1.0))
        # E (faces, draws) = sum over the pixels of each face's lump where the pixel left
        A = sp.csr_matrix((np.concatenate(lumps), (loc.ravel(), np.tile(np.arange(len(sel)),
                                                                         2))),
                          shape=(len(uniq), len(sel)), dtype=np.float32)
        E = (A @ leave.astype(np.float32)).astype(np.float64)
        out[uniq] += np.mean(E * E, axis=1)  # the variance about 0 (no error: 0)
    return out
