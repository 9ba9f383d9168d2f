"""Camera calibration: intrinsics and distortion from one or several views of a target.

:func:`calibrate` estimates the focal lengths, the perspective centre (principal point)
and the Brown-Conrady distortion ``[k1, k2, p1, p2, k3]`` shared by all views, together
with one pose per view, by minimising the reprojection error of all views jointly
(Levenberg-Marquardt with an analytic Jacobian; its pose columns are block-sparse, so each
damped step is solved through the Schur complement of the 6x6 pose blocks, with a cost
linear in the number of views, as in bundle adjustment).

Starts, without a user guess:

* planar target (calibration card): per-view homographies and Zhang's closed form for the
  image of the absolute conic (three or more views), else focal lengths with the
  principal point at the image centre;
* non-coplanar target: the 11-parameter DLT of each view with six or more markers,
  decomposed into ``K`` (:mod:`resection.pose.dlt`) - which also covers the single-image case;

then the pose of each view from its homography or DLT with those intrinsics (else
:func:`resection.solve_pose`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from resection._checks import as_points
from resection.camera.model import Camera, undistort_normalized
from resection.errors import DegenerateError, InputError, SolveError
from resection.pose.acceptance import (
    DEFAULT_MARKER_ACCURACY,
    DEFAULT_MAX_RMS,
    Acceptance,
    check_accuracy,
    drop_outliers,
    judge,
    require,
)
from resection.pose.dlt import (
    COLLINEAR_RTOL,
    COPLANAR_RTOL,
    coplanarity,
    decompose_projection,
    fit_dlt,
    fit_homography,
)
from resection.pose.reprojection import apply_intrinsics, intrinsic_params, project_with_jacobians
from resection.pose.solve import solve_pose
from resection.pose.starts import pose_from_plane

__all__ = ["CalibrationResult", "calibrate", "CALIBRATION_PARAMETERS"]

#: Parameters :func:`calibrate` estimates; any of them can be held fixed with ``fix``,
#: plus ``"aspect"`` to keep ``fy / fx`` fixed (one focal length).
CALIBRATION_PARAMETERS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class CalibrationResult:
    """Result of :func:`calibrate`.

    Attributes
    ----------
    camera : Camera
        The calibrated intrinsics, with the pose of the first view.
    poses : list of Camera
        One camera (same intrinsics) per view, with that view's pose.
    residuals : list of (N_i, 2) ndarray
        Observed minus projected pixel coordinates of each view, px.
    rms : float
        RMS reprojection error over all markers of all views, px.
    view_rms : (V,) ndarray
        RMS of each view, px.
    parameters : tuple of str
        Names of the estimated intrinsic parameters (``f`` when the aspect is fixed).
    std : dict
        Standard deviation of each estimated intrinsic parameter (px for ``f, fx, fy, cx,
        cy``, dimensionless for distortion), from the Jacobian at the solution scaled by the
        residual variance.
    message : str
    acceptance : Acceptance
        The acceptance rule's decision (:mod:`resection.pose.acceptance`): statistic, threshold,
        gross outliers dropped.
    used : list of (N_i,) bool ndarray
        Markers of each view used by the final fit (False: dropped as gross outliers;
        ``residuals`` covers every marker, ``rms`` and ``view_rms`` the used ones).
    """

    camera: Camera
    poses: list
    residuals: list
    rms: float
    view_rms: np.ndarray
    parameters: tuple
    std: dict
    message: str = ""
    acceptance: Acceptance | None = None
    used: list | None = None


def _check_views(views):
    try:
        views = list(views)
    except TypeError:
        raise InputError("calibrate: views must be a list of (points3d, points2d) pairs") \
            from None
    if not views:
        raise InputError("calibrate: no views given")
    out = []
    for i, v in enumerate(views):
        try:
            X, uv = v
        except (TypeError, ValueError):
            raise InputError(f"calibrate: view {i} is not a (points3d, points2d) pair") \
                from None
        X = as_points(X, 3, f"view {i} points3d")
        uv = as_points(uv, 2, f"view {i} points2d")
        if len(X) != len(uv):
            raise InputError(f"calibrate: view {i}: {len(X)} markers but {len(uv)} image points")
        if len(X) < 4:
            raise InputError(f"calibrate: view {i}: at least 4 markers are needed, got {len(X)}")
        s2, s3 = coplanarity(X)
        if s2 < COLLINEAR_RTOL:
            raise DegenerateError(f"calibrate: view {i}: the markers are collinear")
        out.append((X, uv, s3 < COPLANAR_RTOL))
    return out


def _check_determined(vw, names) -> None:
    """Refuse intrinsics that the views cannot determine, before solving.

    Each view of a planar target gives two constraints on the focal lengths and the
    principal point (Zhang 2000; zero skew assumed), whatever the number of markers; a
    view of a 3-D target with >= 6 markers determines all of them (DLT). So with planar
    views only, at most ``2 V`` of ``f`` (or ``fx, fy``), ``cx, cy`` can be estimated: one
    planar view with the principal point free gives a focal length that only looks
    determined (a few % off with a small reported error), so it is refused here.
    """
    if any(not planar and len(X) >= 6 for X, _, planar in vw):
        return
    free = [n for n in ("f", "fx", "fy", "cx", "cy") if n in names]
    n_planar = sum(planar for _, _, planar in vw)
    if n_planar and len(free) > 2 * n_planar:
        undetermined = [n for n in ("cx", "cy") if n in free] or free
        raise SolveError(
            f"calibrate: {n_planar} view(s) of a planar target do not determine "
            f"{', '.join(free)} together (each planar view fixes only 2 of them): "
            f"{', '.join(undetermined)} not determined; add views at other angles or a "
            "3-D target, or fix " + " ".join(undetermined)
            + (" (and aspect)" if len(free) - len(undetermined) > 2 * n_planar else ""))


def _zhang(Hs: list[np.ndarray], w: int, h: int) -> np.ndarray | None:
    """Intrinsics from plane homographies (image of the absolute conic), or None."""
    N = np.array([[2.0 / max(w, h), 0, -1.0 * w / max(w, h)],
                  [0, 2.0 / max(w, h), -1.0 * h / max(w, h)], [0, 0, 1.0]])
    rows = []
    for H in Hs:
        Hn = N @ H
        Hn = Hn / np.linalg.norm(Hn)

        def v(i, j, Hn=Hn):
            a, b = Hn[:, i], Hn[:, j]
            return np.array([a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[1] * b[1],
                             a[2] * b[0] + a[0] * b[2], a[2] * b[1] + a[1] * b[2],
                             a[2] * b[2]])

        rows.append(v(0, 1))
        rows.append(v(0, 0) - v(1, 1))
    rows.append(np.array([0, 1.0, 0, 0, 0, 0]))  # zero skew
    A = np.array(rows)
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    b = vt[-1]
    if b[0] < 0:
        b = -b
    B11, B12, B22, B13, B23, B33 = b
    den = B11 * B22 - B12**2
    if B11 <= 0 or den <= 0:
        return None
    v0 = (B12 * B13 - B11 * B23) / den
    lam = B33 - (B13**2 + v0 * (B12 * B13 - B11 * B23)) / B11
    if lam / B11 <= 0:
        return None
    alpha = math.sqrt(lam / B11)
    beta = math.sqrt(lam * B11 / den)
    u0 = -B13 * alpha**2 / lam
    Kn = np.array([[alpha, 0, u0], [0, beta, v0], [0, 0, 1.0]])
    K = np.linalg.solve(N, Kn)
    K /= K[2, 2]
    K[0, 1] = 0.0
    if not (0 < K[0, 0] < 100 * max(w, h) and 0 < K[1, 1] < 100 * max(w, h)
            and -0.5 * w < K[0, 2] < 1.5 * w and -0.5 * h < K[1, 2] < 1.5 * h):
        return None
    return K


def _focal_from_planes(Hs, w, h) -> np.ndarray:
    """Focal lengths with the principal point at the image centre and zero skew."""
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    T = np.array([[1.0, 0, -cx], [0, 1.0, -cy], [0, 0, 1.0]])
    f0 = float(max(w, h))
    S = np.diag([1 / f0, 1 / f0, 1.0])
    rows, rhs = [], []
    for H in Hs:
        Hp = S @ T @ H
        Hp = Hp / np.linalg.norm(Hp)
        rows.append([Hp[0, 0] * Hp[0, 1], Hp[1, 0] * Hp[1, 1]])
        rhs.append(-Hp[2, 0] * Hp[2, 1])
        rows.append([Hp[0, 0] ** 2 - Hp[0, 1] ** 2, Hp[1, 0] ** 2 - Hp[1, 1] ** 2])
        rhs.append(-(Hp[2, 0] ** 2 - Hp[2, 1] ** 2))
    A, r = np.array(rows), np.array(rhs)
    ab = np.linalg.lstsq(A, r, rcond=None)[0]
    if np.all(ab > 0):
        fx, fy = f0 / math.sqrt(ab[0]), f0 / math.sqrt(ab[1])
    else:
        a = float(np.linalg.lstsq(A.sum(axis=1, keepdims=True), r, rcond=None)[0][0])
        fx = fy = f0 / math.sqrt(a) if a > 0 else f0
    if not (0 < fx < 100 * f0 and 0 < fy < 100 * f0):
        fx = fy = f0
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def _initial_K(views, w, h) -> np.ndarray:
    Ks = []
    for X, uv, planar in views:
        if not planar and len(X) >= 6:
            try:
                K, _, _ = decompose_projection(fit_dlt(X, uv))
                Ks.append(K)
            except InputError:
                pass
    if Ks:
        K = np.median(np.array(Ks), axis=0)
        K[0, 1] = 0.0
        if K[0, 0] > 0 and K[1, 1] > 0:
            return K
    Hs = []
    for X, uv, planar in views:
        if planar:
            c = X.mean(axis=0)
            _, _, Vt = np.linalg.svd(X - c, full_matrices=False)
            try:
                Hs.append(fit_homography((X - c) @ Vt[:2].T, uv))
            except InputError:
                pass
    if not Hs:
        f0 = float(max(w, h))
        return np.array([[f0, 0, (w - 1) / 2], [0, f0, (h - 1) / 2], [0, 0, 1.0]])
    K = _zhang(Hs, w, h) if len(Hs) >= 3 else None
    return K if K is not None else _focal_from_planes(Hs, w, h)


def _initial_pose(cam: Camera, X, uv, planar):
    """A start for one view: homography (plane) or DLT (>= 6 non-coplanar markers) with the
    initial intrinsics, else :func:`solve_pose`."""
    xy = undistort_normalized(cam.pixels_to_normalized(uv), cam.dist)
    try:
        if planar:
            return pose_from_plane(X, xy)
        if len(X) >= 6:
            P = fit_dlt(X, xy)
            U, S, Vt = np.linalg.svd(P[:, :3])
            if np.linalg.det(U @ Vt) > 0:
                return U @ Vt, P[:, 3] / S.mean()
    except InputError:
        pass
    r = solve_pose(cam, X, uv)
    return np.array(r.camera.R), np.array(r.camera.t)


def _normal_blocks(vw, names, K, dist, K0, Rs, ts, *, schur=True):
    """Residuals and the block structure of the normal equations of the joint problem.

    The Jacobian is block-sparse: intrinsic columns dense, each view's 6 pose columns
    (left rotation perturbation, translation) non-zero only on that view's rows. Returns
    the sum of squares, the Schur complement ``S = U - sum W V^-1 W^T`` (m, m), the pose
    blocks ``V`` (V, 6, 6), the couplings ``W`` (V, m, 6), and the gradients ``g_theta``
    (m,) and ``g_pose`` (V, 6) (undamped)."""
    m = len(names)
    U = np.zeros((m, m))
    g_t = np.zeros(m)
    Vb = np.zeros((len(vw), 6, 6))
    Wb = np.zeros((len(vw), m, 6))
    g_p = np.zeros((len(vw), 6))
    ss = 0.0
    for v, (X, uv, _) in enumerate(vw):
        proj, Jp, Ji, _ = project_with_jacobians(K, dist, Rs[v], ts[v], X, names, K0)
        r = (proj - uv).ravel()
        A = Ji.reshape(-1, m)
        B = Jp.reshape(-1, 6)
        ss += float(r @ r)
        U += A.T @ A
        g_t += A.T @ r
        Vb[v] = B.T @ B
        Wb[v] = A.T @ B
        g_p[v] = B.T @ r
    S = None
    if schur:
        S = U - np.einsum("vij,vjk,vlk->il", Wb, np.linalg.inv(Vb), Wb) if m else U
    return ss, S, Vb, Wb, g_t, g_p, U


def _schur_lm(vw, names, K0, dist0, Rs, ts, max_iter):
    """Levenberg-Marquardt on intrinsics + view poses, solving each damped step through
    the Schur complement of the 6x6 pose blocks (cost linear in the number of views)."""
    m = len(names)
    theta = intrinsic_params(names, K0, dist0)

    def sumsq(theta, Rs, ts):
        K, dist = apply_intrinsics(names, theta, K0, dist0)
        total = 0.0
        for v, (X, uv, _) in enumerate(vw):
            proj, _, _, z = project_with_jacobians(K, dist, Rs[v], ts[v], X, jac=False)
            if np.any(z <= 0):
                return math.inf
            total += float(np.sum((proj - uv) ** 2))
        return total

    lam = 1e-3
    for it in range(1, max_iter + 1):
        K, dist = apply_intrinsics(names, theta, K0, dist0)
        ss, _, Vb, Wb, g_t, g_p, U = _normal_blocks(vw, names, K, dist, K0, Rs, ts,
                                                    schur=False)
        while True:
            Ud = U + lam * np.diag(np.maximum(np.diag(U), 1e-12))
            dV = np.maximum(np.einsum("vii->vi", Vb), 1e-12)
            Vd = Vb + lam * dV[:, :, None] * np.eye(6)
            Vinv = np.linalg.inv(Vd)
            if m:
                WVi = np.einsum("vij,vjk->vik", Wb, Vinv)
                Sd = Ud - np.einsum("vik,vlk->il", WVi, Wb)
                rhs = -g_t + np.einsum("vik,vk->i", WVi, g_p)
                try:
                    d_t = np.linalg.solve(Sd, rhs)
                except np.linalg.LinAlgError:
                    d_t = np.zeros(m)
                d_p = np.einsum("vij,vj->vi", Vinv, -g_p - np.einsum("vik,i->vk", Wb, d_t))
            else:
                d_t = np.zeros(0)
                d_p = np.einsum("vij,vj->vi", Vinv, -g_p)
            th_n = theta + d_t
            Rs_n = Rotation.from_rotvec(d_p[:, :3]).as_matrix() @ Rs
            ts_n = ts + d_p[:, 3:]
            ss_n = sumsq(th_n, Rs_n, ts_n)
            if ss_n < ss:
                rel = (ss - ss_n) / max(ss, 1e-300)
                theta, Rs, ts = th_n, Rs_n, ts_n
                lam = max(lam / 5.0, 1e-12)
                break
            lam *= 10.0
            if lam > 1e12:
                return theta, Rs, ts, it
        step = np.concatenate([d_t / np.maximum(np.abs(theta), 1e-3), d_p.ravel()])
        if rel < 1e-14 or np.abs(step).max() < 1e-13:
            return theta, Rs, ts, it
    return theta, Rs, ts, None  # not converged: the caller names the cause


def _calibrate_once(
    views,
    image_size: tuple[int, int],
    *,
    fix=(),
    initial: Camera | None = None,
    max_iter: int = 200,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    max_rms: float | None = DEFAULT_MAX_RMS,
) -> CalibrationResult:
    """One calibration on all the given markers (no outlier loop, no acceptance test)."""
    try:
        w, h = (int(x) for x in image_size)
    except (TypeError, ValueError):
        raise InputError(f"calibrate: image_size must be (width, height), got {image_size!r}") \
            from None
    if w <= 0 or h <= 0:
        raise InputError(f"calibrate: image size must be positive, got {w}x{h}")
    fix = tuple(fix)
    unknown = [f for f in fix if f not in CALIBRATION_PARAMETERS + ("aspect",)]
    if unknown:
        raise InputError(f"calibrate: unknown parameter(s) to fix: {', '.join(unknown)}; "
                         f"allowed: {', '.join(CALIBRATION_PARAMETERS)}, aspect")
    vw = _check_views(views)
    for i, (_, uv, _) in enumerate(vw):
        out = np.flatnonzero((uv[:, 0] < -0.5) | (uv[:, 0] > w - 0.5)
                             | (uv[:, 1] < -0.5) | (uv[:, 1] > h - 0.5))
        if out.size:
            raise InputError(
                f"calibrate: view {i}: image point(s) at index {out[:10].tolist()} lie outside "
                f"the {w}x{h} image (e.g. u, v = {uv[out[0], 0]:.1f}, {uv[out[0], 1]:.1f}): "
                "wrong image size?")
    if initial is not None:
        if not isinstance(initial, Camera):
            raise InputError("calibrate: initial must be a resection.Camera")
        if (initial.width, initial.height) != (w, h):
            raise InputError(f"calibrate: image size {w}x{h} differs from the initial "
                             f"camera's {initial.width}x{initial.height}")
        K0, dist0 = np.array(initial.K), np.array(initial.dist)
    else:
        K0, dist0 = _initial_K(vw, w, h), np.zeros(5)
        if "cx" in fix:
            K0[0, 2] = (w - 1) / 2.0
        if "cy" in fix:
            K0[1, 2] = (h - 1) / 2.0
    names = [p for p in CALIBRATION_PARAMETERS if p not in fix]
    if "aspect" in fix:
        if "fx" in fix or "fy" in fix:
            names = [p for p in names if p not in ("fx", "fy")]
        else:
            names = ["f"] + [p for p in names if p not in ("fx", "fy")]
    names = tuple(names)
    m = len(names)
    check_accuracy(marker_accuracy, "calibrate")
    V = len(vw)
    n_obs = 2 * sum(len(X) for X, _, _ in vw)
    n_par = m + 6 * V
    if n_obs <= n_par:
        raise InputError(f"calibrate: {n_obs} observations for {n_par} parameters; add markers "
                         "or views, or fix parameters")
    _check_determined(vw, names)

    cam0 = Camera(w, h, K0, dist0)
    R0s, t0s = [], []
    for X, uv, planar in vw:
        R, t = _initial_pose(cam0, X, uv, planar)
        R0s.append(R)
        t0s.append(t)

    theta, Rs, ts, niter = _schur_lm(vw, names, K0, dist0, np.array(R0s), np.array(t0s),
                                     max_iter)
    converged = niter is not None
    K, dist = apply_intrinsics(names, theta, K0, dist0)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise SolveError("calibrate: the refinement gave a negative focal length")
    # marginal covariance of the intrinsics: inverse of the Schur complement at the solution
    try:
        ss, S, Vb, _, _, _, _ = _normal_blocks(vw, names, K, dist, K0, Rs, ts)
    except np.linalg.LinAlgError:
        raise SolveError("calibrate: the pose of some view is not determined") from None
    scale = np.sqrt(np.maximum(np.diag(S), 1e-300))
    if m:
        ev, evec = np.linalg.eigh(S / np.outer(scale, scale))
        if ev[0] < 1e-12 * ev[-1]:
            bad = [names[i] for i in np.flatnonzero(np.abs(evec[:, 0]) > 0.3)]
            raise SolveError(
                "calibrate: the views do not determine "
                + (", ".join(bad) if bad else "the intrinsics")
                + f" (condition number {math.sqrt(ev[-1] / max(ev[0], 1e-300)):.1e}); add "
                "views at other angles, a deeper target, or fix those parameters")
    if not converged:
        weak = ""
        if m:
            bad = [names[i] for i in np.flatnonzero(np.abs(evec[:, 0]) > 0.3)]
            weak = (f"; the least determined parameters are {', '.join(bad)} (condition "
                    f"number {math.sqrt(ev[-1] / max(ev[0], 1e-300)):.1e})")
        raise SolveError(f"calibrate: did not converge in {max_iter} iterations{weak}: fix "
                         "them, or add views at other angles")
    for v, Bv in enumerate(Vb):
        d = np.sqrt(np.maximum(np.diag(Bv), 1e-300))
        evv = np.linalg.eigvalsh(Bv / np.outer(d, d))
        if evv[0] < 1e-12 * evv[-1]:
            raise SolveError(f"calibrate: the pose of view {v} is not determined")
    dof = n_obs - n_par
    s2 = ss / dof
    cov = s2 * np.linalg.inv(S) if m else np.zeros((0, 0))
    std = {nm: float(math.sqrt(cov[i, i])) for i, nm in enumerate(names)}

    poses, residuals, vrms = [], [], []
    for v, (X, uv, _) in enumerate(vw):
        try:
            c = Camera(w, h, K, dist, Rs[v], ts[v])
        except InputError as exc:
            raise SolveError(f"calibrate: view {v}: invalid camera ({exc})") from None
        proj, valid = c.project(X, return_valid=True)
        if not valid.all():
            raise SolveError(f"calibrate: view {v}: marker(s) {np.flatnonzero(~valid).tolist()} "
                             "end up behind the camera or beyond the distortion's valid radius")
        poses.append(c)
        r = uv - proj
        residuals.append(r)
        vrms.append(float(np.sqrt(np.mean(np.sum(r**2, axis=1)))))
    allr = np.concatenate(residuals)
    rms = float(np.sqrt(np.mean(np.sum(allr**2, axis=1))))
    msg = (f"{V} view(s), {n_obs // 2} markers, rms {rms:.3f} px ({niter} iterations); "
           f"fx {K[0, 0]:.2f} "
           f"fy {K[1, 1]:.2f} cx {K[0, 2]:.2f} cy {K[1, 2]:.2f} px")
    return CalibrationResult(
        camera=poses[0], poses=poses, residuals=residuals, rms=rms,
        view_rms=np.array(vrms), parameters=names, std=std, message=msg,
    )


def calibrate(
    views,
    image_size: tuple[int, int],
    *,
    fix=(),
    initial: Camera | None = None,
    max_iter: int = 200,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    max_rms: float | None = DEFAULT_MAX_RMS,
    ids=None,
) -> CalibrationResult:
    """Calibrate a camera from one or more views of a planar or 3-D target.

    Parameters
    ----------
    views : sequence of (points3d, points2d)
        For each image, the target's marker coordinates ``(N_i, 3)`` (model units; a
        planar target may lie in any plane) and their measured pixel positions
        ``(N_i, 2)`` (pixel centres at integers).
    image_size : (width, height)
        Image size in pixels.
    fix : iterable of str
        Parameters held at their initial value: any of ``fx, fy, cx, cy, k1, k2, p1, p2,
        k3``, and ``"aspect"`` to estimate one focal length with ``fy / fx`` fixed.
        ``fix=("k3",)`` is common; a single view of a planar target needs ``("cx", "cy")``.
    initial : Camera, optional
        Starting (and fixed-parameter) intrinsics ``K`` and ``dist``. By default the
        intrinsics come from the data and the distortion starts at zero.
    max_iter : int
        Maximum number of Levenberg-Marquardt iterations of the joint refinement.
    marker_accuracy, max_rms : float
        The acceptance rule's options (px, :mod:`resection.pose.acceptance`): gross outliers are
        dropped, the worst first and the calibration repeated, within
        :func:`~resection.pose.acceptance.outlier_limit` (and never below 4 markers in a view);
        then the RMS of the used residuals must not exceed its 99.9 % bound for markers of
        this accuracy (``2 N - 6 V - len(parameters)`` degrees of freedom), nor ``max_rms``.
    ids : list of sequences of str, optional
        Marker names of each view, for messages and ``acceptance.outliers`` (default: their
        indices); outliers are named ``view:name``.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError, DegenerateError
        No views, fewer than 4 markers in a view, NaN, collinear markers, bad sizes,
        image points outside the ``image_size`` image (pixel edges at ``-0.5`` and
        ``W - 0.5``), an ``initial`` camera of another size, unknown parameter names,
        fewer observations than parameters.
    SolveError
        Non-convergence, parameters the views do not determine (the message names them:
        e.g. the principal point from one planar view), too many gross outliers, or
        residuals that fail the acceptance rule (message with the statistic and threshold).
    """
    a = check_accuracy(marker_accuracy, "calibrate")
    vw = _check_views(views)
    sizes = [len(X) for X, _, _ in vw]
    ends = np.cumsum(sizes)
    starts = ends - np.array(sizes)
    n = int(ends[-1])
    if ids is None:
        ids = [range(k) for k in sizes]
    ids = [list(v) for v in ids]
    if len(ids) != len(vw) or any(len(i) != k for i, k in zip(ids, sizes, strict=False)):
        raise InputError("calibrate: ids must give one name per marker of every view")
    names = [f"{v}:{k}" for v, i in enumerate(ids) for k in i]
    opts = dict(fix=fix, initial=initial, max_iter=max_iter)

    def fit(used):
        parts = [used[s0:s1] for s0, s1 in zip(starts, ends, strict=True)]
        short = [v for v, m in enumerate(parts) if m.sum() < 4]
        if short:
            raise SolveError(f"calibrate: dropping gross outliers would leave view(s) {short} "
                             "with fewer than 4 markers: a bad view or a wrong pairing?")
        res = _calibrate_once([(X[m], uv[m]) for (X, uv, _), m in zip(vw, parts, strict=True)],
                              image_size, **opts)
        err = np.concatenate([np.hypot(*(uv - c.project(X)).T)
                              for (X, uv, _), c in zip(vw, res.poses, strict=True)])
        return res, err

    n_free = len(CALIBRATION_PARAMETERS) - len(set(fix) - {"aspect"})
    res, used, dropped, derr = drop_outliers(fit, n, 6 * len(vw) + n_free, a, names,
                                             "calibrate")
    n_params = 6 * len(vw) + len(res.parameters)
    acc = judge(np.sqrt(np.sum(np.concatenate(res.residuals) ** 2, axis=1)), n_params, a,
                max_rms, outliers=dropped, outlier_errors=derr, n_total=n, what="calibration")
    require(acc, "calibrate", "wrong pairing, wrong image size or a bad marker?")
    if not dropped:
        return replace(res, acceptance=acc, used=[np.ones(k, bool) for k in sizes],
                       message=f"{res.message}; accepted: {acc.describe()}")
    residuals = [uv - c.project(X) for (X, uv, _), c in zip(vw, res.poses, strict=True)]
    return replace(res, residuals=residuals, acceptance=acc,
                   used=[used[s0:s1] for s0, s1 in zip(starts, ends, strict=True)],
                   message=f"{res.message}; accepted: {acc.describe()}")
