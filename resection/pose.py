"""Point of View (camera pose) from markers, without a user guess.

:func:`solve_pose` finds the rotation and translation of a camera of known intrinsics from
three or more markers with known model coordinates and measured pixel positions:

1. starts: the P3P solutions (up to four) of several well-spread marker triplets, the
   linear DLT for six or more non-coplanar markers, a homography for coplanar ones;
2. the best distinct starts (lowest reprojection cost) are refined together by a
   vectorised Levenberg-Marquardt on the reprojection error (analytic Jacobian,
   distortion included, IRLS weights for a robust loss), the best one and any competitor
   close to it polished by ``scipy.optimize.least_squares`` (MINPACK LM, or TRF with a
   robust loss);
3. the best minimum is kept only if no *distinct* pose fits the markers about as well,
   judged against the marker noise (``ambiguity_px``, or less when the residuals prove the
   markers better measured; with 3 markers, or 4 in some layouts, several poses reproject
   exactly: that is reported as a :class:`~resection.errors.SolveError`, never resolved by
   chance), all markers lie in front of the camera, the solver converged and the RMS is
   acceptable;
4. optionally the intrinsics are refined jointly with the pose from there.

Rotations are handled as left perturbations ``R = exp([w]x) R0``; reported covariances are
for the rotation vector ``rvec`` (OpenCV's Rodrigues vector) and ``t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from itertools import combinations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from ._checks import as_points
from .acceptance import (
    DEFAULT_MARKER_ACCURACY,
    DEFAULT_MAX_RMS,
    Acceptance,
    check_accuracy,
    drop_outliers,
    judge,
    require,
)
from .camera import Camera, max_monotonic_radius, undistort_normalized
from .dlt import COLLINEAR_RTOL, COPLANAR_RTOL, coplanarity, fit_dlt, fit_homography
from .errors import DegenerateError, InputError, SolveError

__all__ = ["PoseResult", "solve_pose", "p3p", "INTRINSIC_NAMES"]

#: Names of the intrinsic parameters that :func:`solve_pose` and ``calibrate`` can refine.
#: ``f`` is a common focal length keeping the aspect ratio ``fy / fx`` (and the skew ratio).
INTRINSIC_NAMES = ("f", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
_PRESETS = {
    "focal": ("f",),
    "center": ("f", "cx", "cy"),
    "all": ("f", "cx", "cy", "k1", "k2", "p1", "p2", "k3"),
}


# --------------------------------------------------------------------------- geometry
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


def _rotvec_from_left(rvec: np.ndarray) -> np.ndarray:
    """``d rvec / d w`` for a left perturbation ``w`` at rotation vector ``rvec``."""
    return np.linalg.inv(_left_jacobian(rvec))


def _rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(math.acos(min(1.0, max(-1.0, c))))


def _kabsch(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation with ``Y ~ R X + t`` (least squares, no scale)."""
    cx, cy = X.mean(axis=0), Y.mean(axis=0)
    H = (X - cx).T @ (Y - cy)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return R, cy - R @ cx


def _pmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Products of polynomials, row by row (ascending coefficients on the last axis)."""
    out = np.zeros(a.shape[:-1] + (a.shape[-1] + b.shape[-1] - 1,))
    for i in range(a.shape[-1]):
        out[..., i:i + b.shape[-1]] += a[..., i:i + 1] * b
    return out


def _pval(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Values of polynomials ``c (T, k)`` at ``x (T, m)`` (Horner)."""
    out = np.zeros(x.shape, dtype=np.result_type(c, x))
    for i in range(c.shape[-1] - 1, -1, -1):
        out = out * x + c[..., i:i + 1]
    return out


def _p3p_batch(X: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P3P for T triplets at once: ``X (T, 3, 3)`` model points, ``b (T, 3, 3)`` unit
    bearings. Returns ``R (M, 3, 3)``, ``t (M, 3)`` and the triplet index ``(M,)`` of the
    solutions that put their three points in front of the camera."""
    T = len(X)
    ca = np.einsum("ti,ti->t", b[:, 1], b[:, 2])
    cb = np.einsum("ti,ti->t", b[:, 0], b[:, 2])
    cg = np.einsum("ti,ti->t", b[:, 0], b[:, 1])
    a = np.linalg.norm(X[:, 1] - X[:, 2], axis=1)
    bb = np.linalg.norm(X[:, 0] - X[:, 2], axis=1)
    c = np.linalg.norm(X[:, 0] - X[:, 1], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        a2, c2 = (a / bb) ** 2, (c / bb) ** 2
    one = np.ones(T)
    # Grunert: s2 = u s1, s3 = v s1; eliminating s1 and u leaves a quartic in v
    W = np.stack([one, -2.0 * cb, one], axis=1)
    Q = np.stack([-one, 0 * one, one], axis=1) + (c2 - a2)[:, None] * W
    D = np.stack([2.0 * cg, -2.0 * ca], axis=1)
    quartic = (_pmul(Q, Q) + np.pad(2.0 * cg[:, None] * _pmul(Q, D), ((0, 0), (0, 1)))
               + _pmul(np.stack([1 - c2, 2 * c2 * cb, -c2], axis=1), _pmul(D, D)))
    lead = quartic[:, 4]
    ok = (np.isfinite(quartic).all(axis=1) & (np.abs(lead) > 1e-12 * np.abs(quartic).max(1))
          & (a > 0) & (bb > 0) & (c > 0))
    roots = np.full((T, 4), np.nan + 0j)
    if ok.any():
        comp = np.zeros((int(ok.sum()), 4, 4))
        comp[:, 1:, :3] = np.eye(3)
        comp[:, :, 3] = -quartic[ok, :4] / lead[ok, None]
        roots[ok] = np.linalg.eigvals(comp)
    real = np.abs(roots.imag) <= 1e-3 * (1.0 + np.abs(roots))
    v = roots.real
    with np.errstate(divide="ignore", invalid="ignore"):
        d = _pval(D, v)
        u = -_pval(Q, v) / d
        den = 1.0 + u * u - 2.0 * u * cg[:, None]
        s1 = c[:, None] / np.sqrt(den)
    good = real & (v > 0) & (np.abs(d) > 1e-12) & (u > 0) & (den > 0) & np.isfinite(s1)
    ti, ri = np.nonzero(good)
    if ti.size == 0:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, int)
    s = s1[ti, ri]
    P = np.stack([s[:, None] * b[ti, 0], (u[ti, ri] * s)[:, None] * b[ti, 1],
                  (v[ti, ri] * s)[:, None] * b[ti, 2]], axis=1)  # (M, 3, 3) camera frame
    Xs = X[ti]
    cx, cp = Xs.mean(axis=1), P.mean(axis=1)
    Hm = np.einsum("mki,mkj->mij", Xs - cx[:, None], P - cp[:, None])
    U, _, Vt = np.linalg.svd(Hm)
    det = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    det[det == 0] = 1.0
    Dg = np.zeros((len(ti), 3, 3))
    Dg[:, 0, 0] = Dg[:, 1, 1] = 1.0
    Dg[:, 2, 2] = det
    R = np.swapaxes(Vt, 1, 2) @ Dg @ np.swapaxes(U, 1, 2)
    t = cp - np.einsum("mij,mj->mi", R, cx)
    z = np.einsum("mkj,mij->mki", Xs, R)[..., 2] + t[:, None, 2]
    front = np.all(z > 0, axis=1)
    return R[front], t[front], ti[front]


def p3p(points3d, bearings) -> list[tuple[np.ndarray, np.ndarray]]:
    """All poses that put three model points on three lines of sight (perspective-3-point).

    Eliminates the three distances along the rays (Grunert's formulation) down to a quartic,
    solved as a companion-matrix eigenproblem, then aligns the model triangle with the
    camera-frame triangle.

    Parameters
    ----------
    points3d : (3, 3) array
        Model points.
    bearings : (3, 3) array
        Directions of their lines of sight in the camera frame (need not be unit).

    Returns
    -------
    list of ``(R, t)`` with ``x_cam = R X + t`` and the three points in front of the camera
    (up to four).
    """
    X = as_points(points3d, 3, "points3d")
    b = as_points(bearings, 3, "bearings")
    if len(X) != 3 or len(b) != 3:
        raise InputError("p3p: needs exactly three points and three bearings")
    if min(np.linalg.norm(X[1] - X[2]), np.linalg.norm(X[0] - X[2]),
           np.linalg.norm(X[0] - X[1])) <= 0:
        raise DegenerateError("p3p: two of the three points coincide")
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    R, t, _ = _p3p_batch(X[None], b[None])
    return list(zip(R, t, strict=True))


# --------------------------------------------------------------------------- projection
def _intrinsic_params(names: tuple[str, ...], K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    vals = {"f": K[0, 0], "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
            "k1": dist[0], "k2": dist[1], "p1": dist[2], "p2": dist[3], "k3": dist[4]}
    return np.array([vals[n] for n in names], dtype=float)


def _apply_intrinsics(names, theta, K0, dist0):
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


def _project_jac(K, dist, R, t, X, names=(), K0=None, w=None, jac=True):
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


def _batch_refine(X, uv, Rs, ts, K, dist, robust, scale, iterations=40):
    """Damped Gauss-Newton (Levenberg-Marquardt) on many starts at once (pose only),
    with IRLS weights for a robust loss. Returns refined ``R (C,3,3)``, ``t (C,3)`` and
    the (robust) costs ``(C,)``."""
    R = np.array(Rs, dtype=float)
    t = np.array(ts, dtype=float)
    C = len(R)

    def evaluate(Rc, tc):
        proj, Jp, _, z = _project_jac(K, dist, Rc, tc, X)
        res = proj - uv
        c = np.array(_sq_cost(np.sum(res**2, axis=-1), robust, scale), dtype=float)
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


# --------------------------------------------------------------------------- result
@dataclass(frozen=True)
class PoseResult:
    """Result of :func:`solve_pose`.

    Attributes
    ----------
    camera : Camera
        The input camera with the solved pose (and refined intrinsics if asked).
    residuals : (N, 2) ndarray
        Observed minus projected pixel coordinates, px.
    errors : (N,) ndarray
        Reprojection error of each marker, px.
    rms : float
        RMS reprojection error over the used markers (gross outliers dropped), px.
    covariance : (6, 6) ndarray
        Covariance of ``[rvec, t]`` (radians, model units), scaled by the residual variance
        ``sum(res**2) / (2 N - p)`` (inliers only with a robust loss); marginal over the
        intrinsics when they are refined (so larger). NaN when ``2 N = p`` (three markers).
    n_solutions : int
        Number of distinct poses found that put every marker in front of the camera (local
        minima of the reprojection error; 1 means no competitor was found).
    alternative_rms : float
        RMS of the best-fitting *other* pose, px (``inf`` when there is none): how clearly
        the solution is singled out.
    inliers : (N,) bool ndarray
        Markers with an error below ``3 * robust_scale`` (all True without a robust loss).
    refined : tuple of str
        Names of the refined intrinsic parameters (``INTRINSIC_NAMES``).
    intrinsics_std : (len(refined),) ndarray
        Standard deviations of the refined intrinsic parameters.
    message : str
        A one-line summary.
    used : (N,) bool ndarray
        Markers used by the final solve (False: dropped as gross outliers).
    acceptance : Acceptance
        The acceptance rule's decision: tested statistic, threshold, outliers dropped.
    """

    camera: Camera
    residuals: np.ndarray
    errors: np.ndarray
    rms: float
    covariance: np.ndarray
    n_solutions: int
    alternative_rms: float
    inliers: np.ndarray
    refined: tuple[str, ...] = ()
    intrinsics_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    message: str = ""
    used: np.ndarray | None = None
    acceptance: Acceptance | None = None

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of ``[rvec (rad), t (model units)]``."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def rvec(self) -> np.ndarray:
        return self.camera.rvec

    @property
    def t(self) -> np.ndarray:
        return np.array(self.camera.t)


# --------------------------------------------------------------------------- solver
def _resolve_refine(refine, n: int) -> tuple[str, ...]:
    if refine in (None, False):
        return ()
    if refine is True:
        refine = "all"
    if isinstance(refine, str):
        if refine not in _PRESETS:
            raise InputError(
                f"refine_intrinsics: unknown option {refine!r}; use one of "
                f"{', '.join(_PRESETS)} or a tuple of {', '.join(INTRINSIC_NAMES)}"
            )
        names = _PRESETS[refine]
    else:
        names = tuple(refine)
        bad = [x for x in names if x not in INTRINSIC_NAMES]
        if bad or len(set(names)) != len(names):
            raise InputError(f"refine_intrinsics: invalid or repeated names {names}; allowed "
                             f"{', '.join(INTRINSIC_NAMES)}")
        if "f" in names and ("fx" in names or "fy" in names):
            raise InputError("refine_intrinsics: 'f' cannot be combined with 'fx'/'fy'")
    p = 6 + len(names)
    if 2 * n <= p:
        need = p // 2 + 1
        raise InputError(
            f"refine_intrinsics: refining {len(names)} intrinsic parameter(s) with the pose "
            f"needs at least {need} markers, got {n}"
        )
    return names


def _pick_triplets(X: np.ndarray, uv: np.ndarray, max_triplets: int,
                   rng: np.random.Generator) -> list[tuple[int, int, int]]:
    n = len(X)
    scale = np.linalg.norm(X - X.mean(axis=0), axis=1).max()

    def ok(tri):
        a, b, c = X[list(tri)]
        return np.linalg.norm(np.cross(b - a, c - a)) > 1e-6 * scale**2

    if math.comb(n, 3) <= max_triplets:
        return [tri for tri in combinations(range(n), 3) if ok(tri)]
    d = uv - uv.mean(axis=0)
    i0 = int(np.argmax(np.einsum("ij,ij->i", d, d)))
    e = uv - uv[i0]
    i1 = int(np.argmax(np.einsum("ij,ij->i", e, e)))
    a, b = uv[i1] - uv[i0], uv - uv[i0]
    area = np.abs(a[0] * b[:, 1] - a[1] * b[:, 0])
    i2 = int(np.argmax(area))
    out = []
    if len({i0, i1, i2}) == 3 and ok((i0, i1, i2)):
        out.append(tuple(sorted((i0, i1, i2))))
    tries = 0
    while len(out) < max_triplets and tries < 20 * max_triplets:
        tries += 1
        tri = tuple(sorted(rng.choice(n, 3, replace=False).tolist()))
        if tri not in out and ok(tri):
            out.append(tri)
    return out


def _initial_poses(X, xy, planar: bool, max_triplets: int):
    """Candidate (R, t) from P3P triplets, the DLT and the homography (normalised image
    coordinates ``xy``)."""
    n = len(X)
    bear = np.column_stack([xy, np.ones(n)])
    cands = []
    rng = np.random.default_rng(12345)
    tris = _pick_triplets(X, xy, max_triplets, rng)
    if tris:
        idx = np.array(tris)
        bu = bear / np.linalg.norm(bear, axis=1, keepdims=True)
        Rs, ts, _ = _p3p_batch(X[idx], bu[idx])
        cands.extend(zip(Rs, ts, strict=True))
    if n >= 6 and not planar:
        try:
            P = fit_dlt(X, xy)
            U, S, Vt = np.linalg.svd(P[:, :3])
            R = U @ Vt
            if np.linalg.det(R) > 0:
                cands.append((R, P[:, 3] / S.mean()))
        except InputError:
            pass
    if n >= 4 and planar:
        try:
            cands.append(_pose_from_plane(X, xy))
        except (InputError, SolveError):
            pass
    return cands


def _pose_from_plane(X: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose of coplanar model points ``X`` from their normalised image coordinates ``xy``
    through the plane's homography (``H ~ [R e1, R e2, R c + t]`` in plane axes)."""
    c = X.mean(axis=0)
    _, _, Vt = np.linalg.svd(X - c, full_matrices=False)
    E = Vt.T.copy()  # columns e1, e2, normal
    if np.linalg.det(E) < 0:
        E[:, 2] *= -1
    H = fit_homography((X - c) @ E[:, :2], xy)
    lam = 0.5 * (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    if H[2, 2] < 0:  # the centroid must be in front of the camera
        lam = -lam
    r1, r2, tc = H[:, 0] / lam, H[:, 1] / lam, H[:, 2] / lam
    U, _, Vt2 = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    Rc = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt2))]) @ Vt2
    R = Rc @ E.T
    return R, tc - R @ c


#: Probability that the noise bound of :func:`_ambiguity_sigma` is below the true noise.
_NOISE_CONFIDENCE = 1e-4
#: Smallest marker noise (px) the ambiguity test assumes: below any marker measurement,
#: above the solvers' numerical precision.
_MIN_SIGMA_PX = 1e-3


def _ambiguity_sigma(cost: float, dof: int, ambiguity_px: float) -> float:
    """Marker noise (px) against which competing poses are judged.

    ``ambiguity_px`` is the assumed (upper) marker uncertainty. When the residuals of the
    best pose prove the markers better measured - the upper ``1 - _NOISE_CONFIDENCE``
    confidence bound ``sqrt(cost / chi2_dof.ppf(_NOISE_CONFIDENCE))`` on the noise lies
    below ``ambiguity_px`` - that bound is used instead (not below ``_MIN_SIGMA_PX``);
    when they show it worse measured (residual standard deviation ``sqrt(cost / dof)``
    above ``ambiguity_px``), the residual standard deviation. Three markers (``dof = 0``)
    give no noise estimate: ``ambiguity_px``.
    """
    if dof <= 0:
        return ambiguity_px
    s = math.sqrt(max(cost, 0.0) / dof)
    s_up = math.sqrt(max(cost, 0.0) / chi2.ppf(_NOISE_CONFIDENCE, dof))
    return max(s, min(ambiguity_px, max(s_up, _MIN_SIGMA_PX)))


def _sq_cost(res2: np.ndarray, robust: str | None, scale: float):
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


def _refine(X, uv, R0, t0, K0, dist0, names, robust, scale, max_nfev):
    """Levenberg-Marquardt (or trust-region with a robust loss) from ``(R0, t0)``."""
    p0 = np.concatenate([np.zeros(3), t0, _intrinsic_params(names, K0, dist0)])
    cache = {}

    def evaluate(p):
        key = p.tobytes()
        if key not in cache:
            cache.clear()
            R = Rotation.from_rotvec(p[:3]).as_matrix() @ R0
            K, dist = _apply_intrinsics(names, p[6:], K0, dist0) if names else (K0, dist0)
            proj, Jp, Ji, _ = _project_jac(K, dist, R, p[3:6], X, names, K0, w=p[:3])
            J = np.concatenate([Jp, Ji], axis=2).reshape(-1, 6 + len(names))
            cache[key] = ((proj - uv).ravel(), J)
        return cache[key]

    kw = dict(xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=max_nfev, x_scale="jac")
    if robust is None:
        sol = least_squares(lambda p: evaluate(p)[0], p0, jac=lambda p: evaluate(p)[1],
                            method="lm", **kw)
    else:
        sol = least_squares(lambda p: evaluate(p)[0], p0, jac=lambda p: evaluate(p)[1],
                            method="trf", loss=robust, f_scale=scale, **kw)
    R = Rotation.from_rotvec(sol.x[:3]).as_matrix() @ R0
    K, dist = _apply_intrinsics(names, sol.x[6:], K0, dist0) if names else (K0, dist0)
    return R, sol.x[3:6].copy(), K, dist, sol


def _solve_once(
    camera: Camera,
    points3d,
    points2d,
    *,
    robust: str | None = None,
    robust_scale: float = 1.0,
    refine_intrinsics=False,
    max_rms: float | None = None,
    ambiguity_px: float = 0.5,
    max_triplets: int = 8,
    max_refine: int = 4,
    max_nfev: int = 200,
) -> PoseResult:
    """One solve of :func:`solve_pose` on all the given markers (no outlier loop, no
    acceptance test)."""
    if not isinstance(camera, Camera):
        raise InputError(f"solve_pose: camera must be a resection.Camera, got "
                         f"{type(camera).__name__}")
    X = as_points(points3d, 3, "points3d")
    uv = as_points(points2d, 2, "points2d")
    n = len(X)
    if len(uv) != n:
        raise InputError(f"solve_pose: {n} 3-D markers but {len(uv)} image points")
    if n < 3:
        raise InputError(f"solve_pose: at least 3 markers are needed, got {n}")
    if robust in ("linear", False):
        robust = None
    if robust is not None and robust not in ("huber", "soft_l1", "cauchy", "arctan"):
        raise InputError(f"solve_pose: unknown robust loss {robust!r}; use huber, soft_l1, "
                         "cauchy or arctan")
    if not (np.isfinite(ambiguity_px) and ambiguity_px > 0):
        raise InputError(f"solve_pose: ambiguity_px must be positive, got {ambiguity_px}")
    if min(max_triplets, max_refine, max_nfev) < 1:
        raise InputError("solve_pose: max_triplets, max_refine and max_nfev must be >= 1")
    scale = float(robust_scale)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(f"solve_pose: robust_scale must be positive, got {robust_scale}")
    if max_rms is not None and not (np.isfinite(max_rms) and max_rms > 0):
        raise InputError(f"solve_pose: max_rms must be positive, got {max_rms}")
    names = _resolve_refine(refine_intrinsics, n)
    outside = np.flatnonzero(~camera.in_image(uv, margin=-1.0))
    if outside.size:
        i0 = outside[0]
        raise InputError(
            f"solve_pose: image point(s) at index {outside[:10].tolist()} lie outside the "
            f"camera's {camera.width}x{camera.height} image (e.g. u, v = {uv[i0, 0]:.1f}, "
            f"{uv[i0, 1]:.1f}): wrong camera file or image size?")
    s2, s3 = coplanarity(X)
    if s2 < COLLINEAR_RTOL:
        raise DegenerateError(f"solve_pose: the {n} markers are collinear (or coincide): the "
                              "rotation about their line is undetermined")
    planar = s3 < COPLANAR_RTOL
    K0, dist0 = np.array(camera.K), np.array(camera.dist)
    xy = undistort_normalized(camera.pixels_to_normalized(uv), dist0)
    bad = ~np.isfinite(xy).all(axis=1)
    if bad.any():
        raise InputError(f"solve_pose: image point(s) at index {np.flatnonzero(bad).tolist()} "
                         "lie outside the range where the lens distortion can be inverted")

    # ---- starts, screened by their reprojection cost
    cands = _initial_poses(X, xy, planar, max_triplets)
    if not cands:
        raise SolveError(f"solve_pose: no pose puts the {n} markers in front of the camera "
                         "(wrong marker/point pairing?)")
    Rc = np.array([c[0] for c in cands])
    tc = np.array([c[1] for c in cands])
    proj, _, _, z = _project_jac(K0, dist0, Rc, tc, X, jac=False)
    costs = _sq_cost(np.sum((proj - uv) ** 2, axis=-1), robust, scale)
    costs[np.any(z <= 0, axis=1)] = np.inf
    order = np.argsort(costs)
    depth = float(np.median(np.linalg.norm(X @ Rc[order[0]].T + tc[order[0]], axis=1)))
    starts = []
    for i in order:
        if not np.isfinite(costs[i]):
            break
        C = -Rc[i].T @ tc[i]
        if any(_rotation_angle(Rc[i], Rc[j]) < 0.02
               and np.linalg.norm(C + Rc[j].T @ tc[j]) < 0.02 * depth for j in starts):
            continue
        starts.append(i)
        if len(starts) >= max_refine:
            break
    if not starts:
        raise SolveError("solve_pose: no start puts all markers in front of the camera")

    # ---- refine every start (pose only, all at once), keep distinct minima in front
    Rr, tr, cr = _batch_refine(X, uv, Rc[starts], tc[starts], K0, dist0, robust, scale)
    rmax = max_monotonic_radius(dist0)
    minima = []
    for k in np.argsort(cr):
        R, t, cost = Rr[k], tr[k], float(cr[k])
        Xc = X @ R.T + t
        if not np.isfinite(cost) or np.any(Xc[:, 2] <= 0):
            continue
        if np.any(np.hypot(Xc[:, 0], Xc[:, 1]) / Xc[:, 2] > rmax):
            continue
        C = -R.T @ t
        if any(_rotation_angle(R, m["R"]) < 1e-3 and np.linalg.norm(C - m["C"]) < 1e-3 * depth
               for m in minima):
            continue
        minima.append(dict(R=R, t=t, C=C, cost=cost))
    if not minima:
        raise SolveError("solve_pose: every candidate pose puts markers behind the camera or "
                         "outside the lens' valid field (wrong marker/point pairing?)")
    # polish the best with MINPACK's LM (convergence test), and every competitor that could
    # come close to it (so that an unfinished batch refinement cannot hide an ambiguity)
    def polish(m, check_valid=True):
        R, t, _, _, sol = _refine(X, uv, m["R"], m["t"], K0, dist0, (), robust, scale,
                                  max_nfev)
        Xc = X @ R.T + t
        if check_valid and (np.any(Xc[:, 2] <= 0)
                            or np.any(np.hypot(Xc[:, 0], Xc[:, 1]) / Xc[:, 2] > rmax)):
            return  # a competitor: keep its valid batch minimum
        res = sol.fun.reshape(-1, 2)
        m.update(R=R, t=t, C=-R.T @ t, converged=sol.status != 0,
                 cost=float(_sq_cost(np.sum(res**2, axis=-1), robust, scale)))

    best_cost0 = minima[0]["cost"]
    polish(minima[0], check_valid=False)  # validity checked on the final camera below
    dof = 2 * n - 6
    s_res = math.sqrt(max(minima[0]["cost"], 0.0) / dof) if dof > 0 else 0.0
    window = 16.0 * max(ambiguity_px, s_res) ** 2  # the widest threshold that can apply
    for m in minima[1:]:
        if m["cost"] - min(best_cost0, minima[0]["cost"]) < window:
            polish(m)
    minima.sort(key=lambda m: m["cost"])
    distinct = []
    for m in minima:  # polishing can bring two starts to the same minimum
        if not any(_rotation_angle(m["R"], d["R"]) < 1e-3
                   and np.linalg.norm(m["C"] - d["C"]) < 1e-3 * depth for d in distinct):
            distinct.append(m)
    minima = distinct
    best = minima[0]
    if not best.get("converged", False):
        raise SolveError(f"solve_pose: Levenberg-Marquardt did not converge in {max_nfev} "
                         "evaluations")
    sigma = _ambiguity_sigma(best["cost"], dof, ambiguity_px)
    alt_cost = min((m["cost"] for m in minima[1:]), default=math.inf)
    alt_rms = math.sqrt(alt_cost / n) if np.isfinite(alt_cost) else math.inf
    if alt_cost - best["cost"] < 16.0 * sigma**2:
        close = [m for m in minima if m["cost"] - best["cost"] < 16.0 * sigma**2]
        desc = "; ".join(
            f"centre {np.array2string(m['C'], precision=4)} rms {math.sqrt(m['cost'] / n):.3g} px"
            for m in close[:4])
        raise SolveError(
            f"solve_pose: ambiguous pose: {len(close)} distinct poses fit the {n} markers "
            f"about equally well ({desc}; marker noise taken as {sigma:.2g} px); add markers, "
            "spread them in depth, or give ambiguity_px if they are measured better")

    R, t, K, dist = best["R"], best["t"], K0, dist0
    # ---- joint refinement of intrinsics
    if names:
        R, t, K, dist, sol = _refine(X, uv, R, t, K0, dist0, names, robust, scale, max_nfev)
        if sol.status == 0:
            raise SolveError(f"solve_pose: joint refinement of {', '.join(names)} did not "
                             f"converge in {max_nfev} evaluations")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise SolveError("solve_pose: intrinsics refinement gave a negative focal length")
    try:
        cam = camera.replace(K=K, dist=dist, R=R, t=t)
    except InputError as exc:
        raise SolveError(f"solve_pose: refined camera is invalid ({exc})") from None
    proj, valid = cam.project(X, return_valid=True)
    if not valid.all():
        raise SolveError(
            f"solve_pose: marker(s) {np.flatnonzero(~valid).tolist()} end up behind the camera "
            "or outside the lens' valid field")
    residuals = uv - proj
    errors = np.hypot(residuals[:, 0], residuals[:, 1])
    rms = float(np.sqrt(np.mean(errors**2)))
    inliers = errors < 3.0 * scale if robust is not None else np.ones(n, bool)

    # ---- covariance from the Jacobian at the solution (w = 0 around the final R)
    _, Jp, Ji, _ = _project_jac(K, dist, R, t, X, names, K0 if names else None)
    J = np.concatenate([Jp, Ji], axis=2)[inliers].reshape(-1, 6 + len(names))
    p = 6 + len(names)
    m_obs = 2 * int(inliers.sum())
    colnorm = np.linalg.norm(J, axis=0)
    # a column at rounding level next to the largest is a parameter with no effect (the
    # legitimate spread of column norms, px/rad to px per k3, is about 1e-6)
    if np.any(colnorm <= 1e-12 * colnorm.max()):
        raise SolveError("solve_pose: some parameters do not affect the projection")
    Jn = J / colnorm
    sv = np.linalg.svd(Jn, compute_uv=False)
    if sv[-1] < 1e-8 * sv[0]:
        what = "pose and intrinsics are" if names else "pose is"
        raise SolveError(f"solve_pose: the {what} not determined by these markers "
                         f"(condition number {sv[0] / max(sv[-1], 1e-300):.1e})")
    if m_obs > p:
        s2_res = float(np.sum(errors[inliers] ** 2)) / (m_obs - p)
        cov_full = s2_res * np.linalg.inv(J.T @ J)
    else:
        cov_full = np.full((p, p), np.nan)
    G = np.eye(6)
    G[:3, :3] = _rotvec_from_left(cam.rvec)
    cov = G @ cov_full[:6, :6] @ G.T
    istd = np.sqrt(np.diag(cov_full)[6:])
    in_rms = float(np.sqrt(np.mean(errors[inliers] ** 2))) if inliers.any() else math.inf
    msg = (f"{n} markers, rms {rms:.3f} px"
           + (f" ({int(inliers.sum())} inliers, rms {in_rms:.3f} px)" if robust else "")
           + (f", refined {', '.join(names)}" if names else "")
           + (f", next distinct pose rms {alt_rms:.3g} px" if np.isfinite(alt_rms)
              else ", no other pose found"))
    return PoseResult(
        camera=cam, residuals=residuals, errors=errors, rms=rms, covariance=cov,
        n_solutions=len(minima), alternative_rms=alt_rms, inliers=inliers, refined=names,
        intrinsics_std=istd, message=msg,
    )


def solve_pose(
    camera: Camera,
    points3d,
    points2d,
    *,
    robust: str | None = None,
    robust_scale: float = 1.0,
    refine_intrinsics=False,
    max_rms: float | None = DEFAULT_MAX_RMS,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    ids=None,
    ambiguity_px: float = 0.5,
    max_triplets: int = 8,
    max_refine: int = 4,
    max_nfev: int = 200,
) -> PoseResult:
    """Camera pose (Point of View) from three or more markers, without an initial guess.

    Parameters
    ----------
    camera : Camera
        Intrinsics (``K``, ``dist``) and image size; its pose is ignored and replaced.
    points3d : (N, 3) array_like
        Marker coordinates in the model frame, model units, N >= 3, not collinear.
    points2d : (N, 2) array_like
        Their measured pixel positions as imaged (distorted), same order.
    robust : {None, "huber", "soft_l1", "cauchy", "arctan"}
        Robust loss of the reprojection errors (``scipy.optimize.least_squares`` losses),
        to limit the pull of a wrong marker.
    robust_scale : float
        Error (px) where the robust loss starts to bend (``f_scale``); markers with errors
        above three times this are reported as outliers in ``inliers``.
    refine_intrinsics : False, "focal", "center", "all" or tuple of names
        Also refine intrinsic parameters jointly with the pose: ``"focal"`` one focal length
        (aspect ratio kept), ``"center"`` focal and perspective centre, ``"all"`` focal,
        centre and distortion ``k1, k2, p1, p2, k3``, or a tuple from ``INTRINSIC_NAMES``.
        Needs ``2 N > 6 + len(names)`` and a marker layout that determines them (deep,
        spread over the image); an undetermined parameter raises :class:`SolveError`.
    max_rms : float or None
        Upper limit of the RMS residual of the used markers whatever their accuracy, px
        (default 2: the paper's "over 2 px something is wrong"; None: no limit).
    marker_accuracy : float
        Stated accuracy of a marker position, px (RMS length; survey error of the model
        coordinates as imaged plus detection noise; default 1). The pose is judged by the
        acceptance rule (:mod:`resection.acceptance`): gross outliers (errors beyond
        :func:`~resection.acceptance.outlier_gate`) are dropped, the worst first and the
        pose solved again, up to :func:`~resection.acceptance.outlier_limit`; then the RMS
        of the used markers must not exceed its 99.9 % chi-square bound for this accuracy
        nor ``max_rms``. ``PoseResult.acceptance`` reports the statistic and threshold.
    ids : sequence of str, optional
        Marker names for messages and ``acceptance.outliers`` (default: indices).
    ambiguity_px : float
        Assumed (upper) marker position uncertainty (px) used to decide whether two distinct
        poses can be told apart: the pose is ambiguous when another pose's sum of squared
        errors exceeds the best one's by less than ``16 sigma^2`` (a 4-sigma separation).
        ``sigma`` is ``ambiguity_px``, except that it follows the measured noise: when the
        best pose's residuals prove the markers better measured (their 99.99 % upper
        confidence bound on the noise, from the ``2 N - 6`` degrees of freedom, lies below
        ``ambiguity_px``) ``sigma`` is that bound (at least 0.001 px), so that markers
        measured to a few thousandths of a pixel are not refused for a competitor a
        fraction of a pixel away; when they show them worse measured, ``sigma`` is the
        residual standard deviation. With three markers there is no noise estimate and
        ``sigma = ambiguity_px``.
    max_triplets, max_refine, max_nfev : int
        Number of marker triplets tried by P3P, of distinct starts refined, and of
        function evaluations per refinement.

    Returns
    -------
    PoseResult

    Raises
    ------
    InputError, DegenerateError
        Fewer than 3 markers, NaN, mismatched lengths, collinear markers, pixel positions
        more than 1 px outside the camera's image (``width x height``; a wrong camera
        file) or outside the range where the lens distortion can be inverted.
    SolveError
        Several poses fit (the message names them), the best pose puts markers behind the
        camera, the solver did not converge, the pose is not determined, too many gross
        outliers, or the residuals fail the acceptance rule (message with the statistic and
        its threshold).
    """
    a = check_accuracy(marker_accuracy, "solve_pose")
    if max_rms is not None and not (np.isfinite(max_rms) and max_rms > 0):
        raise InputError(f"solve_pose: max_rms must be positive, got {max_rms}")
    X = as_points(points3d, 3, "points3d")
    uv = as_points(points2d, 2, "points2d")
    if len(uv) != len(X):
        raise InputError(f"solve_pose: {len(X)} 3-D markers but {len(uv)} image points")
    names = None if ids is None else [str(k) for k in ids]
    if names is not None and len(names) != len(X):
        raise InputError(f"solve_pose: {len(names)} ids for {len(X)} markers")
    opts = dict(robust=robust, robust_scale=robust_scale, refine_intrinsics=refine_intrinsics,
                ambiguity_px=ambiguity_px, max_triplets=max_triplets, max_refine=max_refine,
                max_nfev=max_nfev)

    def fit(used):
        res = _solve_once(camera, X[used], uv[used], **opts)
        if used.all():
            return res, res.errors
        proj = res.camera.project(X)
        return res, np.hypot(*(uv - proj).T)

    n = len(X)
    n_params = 6 + len(_resolve_refine(refine_intrinsics, n))
    res, used, dropped, derr = drop_outliers(fit, n, n_params, a, names, "solve_pose")
    if not dropped:
        used_err = res.errors[res.inliers]
        residuals, errors, inliers = res.residuals, res.errors, res.inliers
    else:
        used_err = res.errors[res.inliers]
        with np.errstate(invalid="ignore"):
            residuals = uv - res.camera.project(X)
        errors = np.hypot(residuals[:, 0], residuals[:, 1])
        inliers = np.zeros(n, bool)
        inliers[used] = res.inliers
    acc = judge(used_err, n_params, a, max_rms, outliers=dropped, outlier_errors=derr,
                n_total=n, what="pose")
    require(acc, "solve_pose")
    rms = float(np.sqrt(np.mean(res.errors ** 2)))
    return replace(res, residuals=residuals, errors=errors, inliers=inliers, rms=rms,
                   used=used, acceptance=acc,
                   message=f"{res.message}; accepted: {acc.describe()}")
