"""Reprojection of markers and its derivatives, for the pose and calibration solvers.

Projection with Brown-Conrady distortion (OpenCV order) and its analytic Jacobians with
respect to the pose (left rotation perturbation ``R = exp([w]x) R0`` and translation) and to
the intrinsic parameters (:data:`resection.pose.solve.INTRINSIC_NAMES`), for one pose or a batch;
IRLS weights of the robust losses; a vectorised Levenberg-Marquardt refining many pose
starts at once. Used by :mod:`resection.pose.solve` and :mod:`resection.pose.calibration`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from resection.errors import InputError


# --------------------------------------------------------------------------- rotations
def _skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices of (..., 3) vectors: (..., 3, 3)."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1),
                     np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], axis=-2)


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3): ``exp(w + d) = exp(J_l(w) d) exp(w)`` to first order."""
    th = float(np.linalg.norm(w))
    W = _skew(w[None])[0]
    if th < 1e-8:
        return np.eye(3) + 0.5 * W
    return (np.eye(3) + (1.0 - math.cos(th)) / th**2 * W
            + (th - math.sin(th)) / th**3 * (W @ W))


def rotvec_from_left(rvec: np.ndarray) -> np.ndarray:
    """``d rvec / d w`` for a left perturbation ``w`` at rotation vector ``rvec``."""
    return np.linalg.inv(_left_jacobian(rvec))


# --------------------------------------------------------------------------- projection
def intrinsic_params(names: tuple[str, ...], K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    vals = {"f": K[0, 0], "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
            "k1": dist[0], "k2": dist[1], "p1": dist[2], "p2": dist[3], "k3": dist[4]}
    return np.array([vals[n] for n in names], dtype=float)


def apply_intrinsics(names, theta, K0, dist0):
    """K, dist with the refined parameters ``theta`` substituted."""
    K = np.array(K0, dtype=float)
    dist = np.array(dist0, dtype=float)
    aspect, skew_ratio = K0[1, 1] / K0[0, 0], K0[0, 1] / K0[0, 0]
    idx = {"k1": 0, "k2": 1, "p1": 2, "p2": 3, "k3": 4}
    for n, v in zip(names, theta, strict=True):
        if n == "f":
            K[0, 0], K[1, 1], K[0, 1] = v, aspect * v, skew_ratio * v
        elif n == "fx":
            K[0, 0] = v
        elif n == "fy":
            K[1, 1] = v
        elif n == "cx":
            K[0, 2] = v
        elif n == "cy":
            K[1, 2] = v
        else:
            dist[idx[n]] = v
    return K, dist


def project_with_jacobians(K, dist, R, t, X, names=(), K0=None, w=None, jac=True):
    """Projection with distortion and its Jacobians, for one pose or a batch.

    ``R`` (3, 3) or (C, 3, 3), ``t`` (3,) or (C, 3). Returns ``uv (.., N, 2)``,
    ``J_pose (.., N, 2, 6)`` w.r.t. ``(w, t)`` where ``w`` is a left rotation perturbation
    evaluated at ``w`` (``R`` already includes it; ``None`` means 0), ``J_intr
    (.., N, 2, len(names))`` and the depths ``z (.., N)``.
    """
    single = np.ndim(R) == 2
    R = np.asarray(R).reshape(-1, 3, 3)
    t = np.asarray(t).reshape(-1, 3)
    Xc = np.einsum("nj,cij->cni", X, R) + t[:, None, :]
    z = Xc[..., 2]
    zs = np.where(z > 1e-12, z, 1e-12)
    x, y = Xc[..., 0] / zs, Xc[..., 1] / zs
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    uv = np.empty(x.shape + (2,))
    uv[..., 0] = fx * xd + s * yd + cx
    uv[..., 1] = fy * yd + cy
    if not jac:
        return (uv[0], None, None, z[0]) if single else (uv, None, None, z)
    # d(xd, yd) / d(x, y)
    a11 = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
    a12 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y
    a22 = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x
    # d(u, v) / d(x, y) = [[fx, s], [0, fy]] @ A
    b11, b12 = fx * a11 + s * a12, fx * a12 + s * a22
    b21, b22 = fy * a12, fy * a22
    iz = 1.0 / zs
    # d(u, v) / d(Xc) with d(x, y)/d(Xc) = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
    J_pose = np.empty(uv.shape + (6,))
    a = J_pose[..., 3:]  # d(u, v) / d(t) = d(u, v) / d(Xc)
    a[..., 0, 0] = b11 * iz
    a[..., 0, 1] = b12 * iz
    a[..., 0, 2] = -(b11 * x + b12 * y) * iz
    a[..., 1, 0] = b21 * iz
    a[..., 1, 1] = b22 * iz
    a[..., 1, 2] = -(b21 * x + b22 * y) * iz
    # d(Xc)/dw = -[P]x with P = R X (left perturbation at 0): row a -> P x a
    P = Xc - t[:, None, :]
    P0, P1, P2 = P[..., 0, None], P[..., 1, None], P[..., 2, None]
    J_pose[..., 0] = P1 * a[..., 2] - P2 * a[..., 1]
    J_pose[..., 1] = P2 * a[..., 0] - P0 * a[..., 2]
    J_pose[..., 2] = P0 * a[..., 1] - P1 * a[..., 0]
    if w is not None:
        J_pose[..., :3] = J_pose[..., :3] @ _left_jacobian(w)
    J_intr = np.empty(uv.shape + (len(names),))
    if names:
        K0 = K if K0 is None else K0
        aspect, skew_ratio = K0[1, 1] / K0[0, 0], K0[0, 1] / K0[0, 0]
        dxy = {
            "k1": (x * r2, y * r2),
            "k2": (x * r2 * r2, y * r2 * r2),
            "k3": (x * r2**3, y * r2**3),
            "p1": (2.0 * x * y, r2 + 2.0 * y * y),
            "p2": (r2 + 2.0 * x * x, 2.0 * x * y),
        }
        for j, nm in enumerate(names):
            if nm == "f":
                J_intr[..., 0, j] = xd + skew_ratio * yd
                J_intr[..., 1, j] = aspect * yd
            elif nm == "fx":
                J_intr[..., 0, j], J_intr[..., 1, j] = xd, 0.0
            elif nm == "fy":
                J_intr[..., 0, j], J_intr[..., 1, j] = 0.0, yd
            elif nm == "cx":
                J_intr[..., 0, j], J_intr[..., 1, j] = 1.0, 0.0
            elif nm == "cy":
                J_intr[..., 0, j], J_intr[..., 1, j] = 0.0, 1.0
            else:
                ddx, ddy = dxy[nm]
                J_intr[..., 0, j] = fx * ddx + s * ddy
                J_intr[..., 1, j] = fy * ddy
    if single:
        return uv[0], J_pose[0], J_intr[0], z[0]
    return uv, J_pose, J_intr, z


def _robust_weights(e2: np.ndarray, robust: str | None, scale: float) -> np.ndarray:
    """IRLS weights ``rho'(e^2 / scale^2)`` of the squared errors (1 without a loss)."""
    if robust is None:
        return np.ones_like(e2)
    z = e2 / scale**2
    if robust == "huber":
        return np.where(z <= 1, 1.0, 1.0 / np.sqrt(np.maximum(z, 1e-300)))
    if robust == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    if robust == "cauchy":
        return 1.0 / (1.0 + z)
    return 1.0 / (1.0 + z * z)  # arctan


def squared_cost(res2: np.ndarray, robust: str | None, scale: float):
    """Sum over the last axis of (robustified) squared errors, px^2, from the squared
    per-marker errors ``res2``."""
    if robust is None:
        return res2.sum(axis=-1)
    z = res2 / scale**2
    if robust == "huber":
        rho = np.where(z <= 1, z, 2 * np.sqrt(z) - 1)
    elif robust == "soft_l1":
        rho = 2 * (np.sqrt(1 + z) - 1)
    elif robust == "cauchy":
        rho = np.log1p(z)
    elif robust == "arctan":
        rho = np.arctan(z)
    else:
        raise InputError(f"robust: unknown loss {robust!r}")
    return scale**2 * rho.sum(axis=-1)


def batch_refine(X, uv, Rs, ts, K, dist, robust, scale, iterations=40):
    """Damped Gauss-Newton (Levenberg-Marquardt) on many starts at once (pose only),
    with IRLS weights for a robust loss. Returns refined ``R (C,3,3)``, ``t (C,3)`` and
    the (robust) costs ``(C,)``."""
    R = np.array(Rs, dtype=float)
    t = np.array(ts, dtype=float)
    C = len(R)

    def evaluate(Rc, tc):
        proj, Jp, _, z = project_with_jacobians(K, dist, Rc, tc, X)
        res = proj - uv
        c = np.array(squared_cost(np.sum(res**2, axis=-1), robust, scale), dtype=float)
        c[np.any(z <= 0, axis=1)] = np.inf
        return c, res, Jp

    lam = np.full(C, 1e-3)
    cost, RES, JAC = evaluate(R, t)
    active = np.isfinite(cost)
    for _ in range(iterations):
        if not active.any():
            break
        idx = np.flatnonzero(active)
        res, Jp = RES[idx], JAC[idx]  # (c, N, 2), (c, N, 2, 6) at the current poses
        wgt = _robust_weights(np.sum(res**2, axis=-1), robust, scale)[..., None]
        JTJ = np.einsum("cnki,cnk,cnkj->cij", Jp, np.broadcast_to(wgt, res.shape), Jp)
        g = np.einsum("cnki,cnk->ci", Jp, wgt * res)
        diag = np.einsum("cii->ci", JTJ)
        A = JTJ + (lam[idx, None] * np.maximum(diag, 1e-12))[:, :, None] * np.eye(6)
        try:
            delta = -np.linalg.solve(A, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        Rn = Rotation.from_rotvec(delta[:, :3]).as_matrix() @ R[idx]
        tn = t[idx] + delta[:, 3:]
        cn, rn, jn = evaluate(Rn, tn)
        better = cn < cost[idx]
        acc = idx[better]
        R[acc], t[acc] = Rn[better], tn[better]
        RES[acc], JAC[acc] = rn[better], jn[better]
        rel = np.where(better, (cost[idx] - cn) / np.maximum(cost[idx], 1e-300), 0.0)
        cost[acc] = cn[better]
        lam[acc] = np.maximum(lam[acc] / 5.0, 1e-9)
        lam[idx[~better]] *= 10.0
        small = np.linalg.norm(delta, axis=1) < 1e-12 * (1 + np.linalg.norm(t[idx], axis=1))
        done = (better & (rel < 1e-9)) | small | (lam[idx] > 1e8)
        active[idx[done]] = False
    return R, t, cost

