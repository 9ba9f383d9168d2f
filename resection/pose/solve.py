"""Point of View (camera pose) from markers, without a user guess.

:func:`solve_pose` finds the rotation and translation of a camera of known intrinsics from
three or more markers with known model coordinates and measured pixel positions:

1. starts (:mod:`resection.pose.starts`): the P3P solutions (up to four) of several
   well-spread marker triplets, the linear DLT for six or more non-coplanar markers, a
   homography for coplanar ones;
2. the best distinct starts (lowest reprojection cost) are refined together by a
   vectorised Levenberg-Marquardt on the reprojection error (analytic Jacobian,
   distortion included, IRLS weights for a robust loss), the best one and any competitor
   close to it polished by ``scipy.optimize.least_squares`` (MINPACK LM, or TRF with a
   robust loss);
3. the best minimum is kept only if no *distinct* pose fits the markers about as well,
   judged against the marker noise (``ambiguity_px``, or less when the residuals prove the
   markers better measured; with 3 markers, or 4 in some layouts, several poses reproject
   exactly: that is reported as a :class:`~resection.errors.SolveError`, never resolved by
   chance), all markers lie in front of the camera and the solver converged;
4. optionally the intrinsics are refined jointly with the pose from there;
5. the acceptance rule (:mod:`resection.pose.acceptance`, ``marker_accuracy``): gross outliers
   are named and dropped within limits (the pose solved again without them), and the RMS
   of the used markers is tested against its chi-square bound; ``PoseResult.acceptance``
   reports the statistic and its threshold.

Rotations are handled as left perturbations ``R = exp([w]x) R0``; reported covariances are
for the rotation vector ``rvec`` (OpenCV's Rodrigues vector) and ``t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.special import gammaincinv

from resection._checks import as_points
from resection.camera.model import Camera, max_monotonic_radius, undistort_normalized
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
from resection.pose.dlt import COLLINEAR_RTOL, COPLANAR_RTOL, coplanarity
from resection.pose.reprojection import (
    apply_intrinsics,
    batch_refine,
    intrinsic_params,
    project_with_jacobians,
    rotvec_from_left,
    squared_cost,
)
from resection.pose.starts import initial_poses
from resection.pose.three_point import p3p

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
def _rotation_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    c = (np.trace(Ra.T @ Rb) - 1.0) / 2.0
    return float(math.acos(min(1.0, max(-1.0, c))))



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
    # chi2.ppf(q, dof) = 2 gammaincinv(dof / 2, q) (scipy.stats costs 0.2 s to import)
    s_up = math.sqrt(max(cost, 0.0) / (2.0 * gammaincinv(0.5 * dof, _NOISE_CONFIDENCE)))
    return max(s, min(ambiguity_px, max(s_up, _MIN_SIGMA_PX)))


def _refine(X, uv, R0, t0, K0, dist0, names, robust, scale, max_nfev):
    """Levenberg-Marquardt (or trust-region with a robust loss) from ``(R0, t0)``."""
    p0 = np.concatenate([np.zeros(3), t0, intrinsic_params(names, K0, dist0)])
    cache = {}

    def evaluate(p):
        key = p.tobytes()
        if key not in cache:
            cache.clear()
            R = Rotation.from_rotvec(p[:3]).as_matrix() @ R0
            K, dist = apply_intrinsics(names, p[6:], K0, dist0) if names else (K0, dist0)
            proj, Jp, Ji, _ = project_with_jacobians(K, dist, R, p[3:6], X, names, K0, w=p[:3])
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
    K, dist = apply_intrinsics(names, sol.x[6:], K0, dist0) if names else (K0, dist0)
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
    cands = initial_poses(X, xy, planar, max_triplets)
    if not cands:
        raise SolveError(f"solve_pose: no pose puts the {n} markers in front of the camera "
                         "(wrong marker/point pairing?)")
    Rc = np.array([c[0] for c in cands])
    tc = np.array([c[1] for c in cands])
    proj, _, _, z = project_with_jacobians(K0, dist0, Rc, tc, X, jac=False)
    costs = squared_cost(np.sum((proj - uv) ** 2, axis=-1), robust, scale)
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
    Rr, tr, cr = batch_refine(X, uv, Rc[starts], tc[starts], K0, dist0, robust, scale)
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
                 cost=float(squared_cost(np.sum(res**2, axis=-1), robust, scale)))

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
    _, Jp, Ji, _ = project_with_jacobians(K, dist, R, t, X, names, K0 if names else None)
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
    G[:3, :3] = rotvec_from_left(cam.rvec)
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
        acceptance rule (:mod:`resection.pose.acceptance`): gross outliers (errors beyond
        :func:`~resection.pose.acceptance.outlier_gate`) are dropped, the worst first and the
        pose solved again, up to :func:`~resection.pose.acceptance.outlier_limit`; then the RMS
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
