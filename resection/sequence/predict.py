"""Tracking by prediction: the markers of a frame located where the previous poses put them.

Between two frames of a run (50 frames/s or more) the model moves by a fraction of a pixel
to a few pixels, smoothly. :func:`track_predicted` uses that:

1. **Motion model.** The pose of frame ``k`` is extrapolated from the last two good frames
   ``i < j < k`` at constant velocity, ``R_k = (R_j R_i^T)^s R_j`` and
   ``t_k = t_j + s (t_j - t_i)`` with ``s = (k - j) / (j - i)`` (the rotation power through
   its rotation vector), or held at frame ``j``'s pose when there is only one.
2. **Gated association.** The markers *expected* in the frame (:func:`expected_markers`:
   those found in the reference or the previous good frame, plus those whose normal, from
   the marker file or the mesh, faces the camera; never one whose normal faces away) are
   projected with the predicted pose, and the pixel-integrated disk model
   (:func:`resection.markers.detect.refine_markers`) is fitted in a small window around each
   prediction only; no search of the image, no candidate list. A marker never seen (the
   far side of a body with markers all around) is not counted missing; the markers not
   expected are looked for every :data:`PROBE_EVERY` frames in the same batch of windows,
   and one is taken when found where the pose solved from the others puts it (within the
   residual gate of step 3 and :data:`PROBE_GATE`, its fitted size and contrast like
   the tracked markers': :func:`_probed`), so a marker
   coming into view is picked up within that many frames.
   A fit is kept when it converged, lies within the *gate* of its prediction, has the
   expected size (``diameter_range``), enough contrast (``min_snr`` times the fit's own
   residual RMS: a noise estimate local to the marker, and pessimistic) and few masked
   pixels (``max_masked``). The gate is at most ``R + 1.5`` px (``R`` the marker radius)
   and at most 0.3 times the distance to the nearest other predicted marker, so that a
   window can catch another marker only if the prediction is off by more than 0.7 times the
   marker spacing, a jump that leaves the gate failing elsewhere (below).
3. **One pose solve**: Gauss-Newton from the predicted pose, then the same statistical
   residual gate as :func:`resection.markers.match.match_markers` (6 sigma of the position noise
   estimated from the median residual, at least 0.25 px, at most the matcher's
   ``tolerance``), markers outside it dropped once and the pose solved again, and the
   package's acceptance rule (:func:`resection.pose.acceptance.judge`, with the
   ``marker_accuracy`` and ``max_rms`` that the matcher and ``solve_pose`` get).

The frame is refused (None: the caller runs the statistical matcher instead) when fewer
than ``max(min_markers, min_matches, 0.8 n)`` of the ``n`` markers expected in the image
are found, or when the residual gate or the acceptance rule fails: a jump, lost or hidden
markers, the first frame of a run or of a chunk. A frame is thus right or refused as with
the matcher: what the gate accepts, the matcher's own final tests would accept too.
"""

from __future__ import annotations

import functools
import inspect
import math

import numpy as np

from resection.camera.model import Camera, project_with_poses
from resection.camera.rotation import matrix_to_rotvec, rotvec_to_matrix, rotvecs_to_matrices
from resection.pose.acceptance import judge
from resection.sequence.results import FrameResult

__all__ = ["expected_markers", "predict_pose", "project_poses", "refine_pose",
           "track_predicted"]

#: fraction of the markers predicted in the image that must be found
MIN_FOUND_FRACTION = 0.8
#: the gate, as a fraction of the distance to the nearest other predicted marker
GATE_SPACING_FRACTION = 0.3
#: markers not expected in a frame (never seen, or lost) are looked for in the frames whose
#: index is a multiple of this
PROBE_EVERY = 5
#: markers at least this many pixels across are fitted as ellipses by the tracker (``detect_kw``
#: ``shape`` overrides it): round markers seen obliquely are ellipses, which the disk model
#: fits slowly and off centre (a median of 31 evaluations a window and 0.08 px on a 35 px
#: marker at an aspect of 0.6); on smaller ones its bias is a few 0.01 px, and the two
#: parameters more let a 5 px marker near the limb, on speckled paint, take a speckle along
#: (1 px off in tests/test_track_revolution.py)
ELLIPSE_MIN_DIAMETER = 12.0
#: the tracker's fits stop once a step leaves under this error in the centre (pixels; the
#: detector's default is 1e-4). On the obliquely seen, point-sampled 35 px targets of the
#: 609,000-face uPSP run (a large residual: :mod:`resection.markers._ellipsefit`) 1e-3 left
#: the centres 4e-4 px (median; 3e-3 at most) from the converged ones, for 5.0
#: evaluations a window (7.2 before session 18). The start (the window's centroid) does not
#: depend on the frames before, so neither does the result
TRACK_FIT_TOL = 1e-3


def marker_shape(detect_kw: dict, diameter: float) -> str:
    """The model of the tracker's fits: ``detect_kw``'s ``shape`` if it names one, else
    "ellipse" for markers of at least ``ELLIPSE_MIN_DIAMETER`` pixels, "disk" below."""
    if detect_kw.get("shape") is not None:
        return str(detect_kw["shape"])
    return "ellipse" if diameter >= ELLIPSE_MIN_DIAMETER else "disk"
#: a marker never seen is expected when its normal is within this angle of the line of
#: sight (degrees): beyond it a disk is an ellipse of aspect under 1/2, which the disk model
#: may not fit; such a marker is probed instead
EXPECT_MAX_ANGLE = 60.0
#: fitted diameter of a marker picked up by a probe, as factors of the expected one (a
#: marker seen obliquely fits as a smaller disk)
PROBE_DIAMETER = (0.5, 1.5)
#: largest distance (px) of a probed marker from where the solved pose puts it
PROBE_GATE = 0.5
#: a probed marker's fitted radius and contrast, at least this fraction of the tracked
#: markers' medians
PROBE_LIKE = 0.7


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(len(a), len(b))`` distances between two small sets of image points (a frame's
    markers: all pairs at once is cheaper than a k-d tree at these sizes)."""
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=-1))


def predict_pose(reference: FrameResult, previous: FrameResult | None,
                 index: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera pose ``(rvec, tvec)`` of frame ``index`` at constant velocity from the two
    last good frames (``previous`` before ``reference``), or ``reference``'s pose."""
    r1, t1 = np.asarray(reference.rvec, float), np.asarray(reference.tvec, float)
    if previous is None or previous.frame >= reference.frame or not previous.ok:
        return r1.copy(), t1.copy()
    s = (index - reference.frame) / float(reference.frame - previous.frame)
    R0 = rotvec_to_matrix(np.asarray(previous.rvec, float))
    R1 = rotvec_to_matrix(r1)
    step = matrix_to_rotvec(R1 @ R0.T)
    rvec = matrix_to_rotvec(rotvec_to_matrix(s * step) @ R1)
    return rvec, t1 + s * (t1 - np.asarray(previous.tvec, float))


def project_poses(camera: Camera, rvecs, tvecs, points3d, *,
                  max_radius: float | None = None) -> np.ndarray:
    """Pixel positions ``(P, N, 2)`` of ``N`` model points under ``P`` poses given as
    rotation vectors and translations (:func:`resection.camera.model.project_with_poses`)."""
    R = rotvecs_to_matrices(np.asarray(rvecs, float).reshape(-1, 3))
    return project_with_poses(camera, R, tvecs, points3d, max_radius=max_radius)


def refine_pose(camera: Camera, rvec, tvec, points3d, points2d, *, iterations: int = 10,
                tol: float = 1e-7, max_radius: float | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares camera pose from a close start (Gauss-Newton on the 6 pose parameters,
    central-difference Jacobian, all perturbed poses projected in one batch).

    Parameters
    ----------
    camera : Camera
        Intrinsics and distortion (its pose is not used).
    rvec, tvec : (3,) array_like
        Starting pose (a prediction within a few pixels of the truth).
    points3d : (N, 3) array_like
        Model points, model units.
    points2d : (N, 2) array_like
        Measured pixel positions.
    iterations : int
        Most Gauss-Newton steps.
    tol : float
        Stop when the largest step component falls below this (radians, model units),
        after taking that step. The iteration converges linearly, by a factor of about 200
        a step on tracked frames (steps of 1e-3, 5e-6, 2e-8, 1e-10): the pose is then
        within about ``tol / 200`` of the least-squares one (1e-7 rad moves a marker by
        2e-4 px at a focal length of 2,000 px), one iteration sooner than with 1e-9.
    max_radius : float, optional
        ``camera.max_radius``, when the caller has it.

    Returns
    -------
    rvec, tvec : (3,) ndarrays
    residuals : (N, 2) ndarray
        Observed minus reprojected, pixels (NaN where a point cannot be projected).
    """
    p = np.concatenate([np.asarray(rvec, float), np.asarray(tvec, float)])
    X = np.asarray(points3d, float).reshape(-1, 3)
    rmax = camera.max_radius if max_radius is None else max_radius
    uv = np.asarray(points2d, float).reshape(-1, 2)
    scale = max(float(np.linalg.norm(p[3:])), 1e-3)
    h = np.r_[np.full(3, 1e-6), np.full(3, 1e-6 * scale)]
    E = np.eye(6) * h
    for _ in range(iterations):
        P = np.vstack([p, p + E, p - E])
        proj = project_poses(camera, P[:, :3], P[:, 3:], X, max_radius=rmax)
        r = (uv - proj[0]).ravel()
        J = ((proj[1:7] - proj[7:13]).reshape(6, -1) / (2.0 * h[:, None])).T
        if not (np.isfinite(r).all() and np.isfinite(J).all()):
            break
        step = np.linalg.lstsq(J, r, rcond=None)[0]
        p = p + step
        if np.abs(step).max() < tol:
            break
    res = uv - project_poses(camera, p[None, :3], p[None, 3:], X, max_radius=rmax)[0]
    return p[:3].copy(), p[3:].copy(), res


def _match_default(name: str, match_kw: dict):
    """The matcher's option ``name``: as given in ``match_kw``, else its default."""
    return match_kw[name] if name in match_kw else _matcher_defaults()[name]


@functools.lru_cache(maxsize=1)
def _matcher_defaults() -> dict:
    from resection.markers.match import match_markers

    return {k: p.default for k, p in inspect.signature(match_markers).parameters.items()}


def residual_gate(errors, tolerance: float) -> float:
    """The matcher's acceptance radius (px) around a reprojection: 6 sigma of the position
    noise estimated from the median error (Rayleigh: median = 1.1774 sigma), at least
    0.25 px, at most ``tolerance`` (as :func:`resection.markers.match.match_markers` uses it)."""
    e = np.asarray(errors, float)
    e = e[np.isfinite(e)]
    sigma = float(np.median(e)) / 1.1774 if e.size else tolerance
    return float(min(tolerance, max(6.0 * sigma, 0.25)))


def expected_markers(setup, reference: FrameResult, previous: FrameResult | None,
                     center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which markers a frame should show: ``(expected, facing_away)``, (N,) bool each.

    Expected: found in the reference frame or the previous good frame, or facing the
    camera by their normal (``setup.normals``: from the marker file's ``nx,ny,nz`` or
    ``.tgts`` columns, or from the mesh) within :data:`EXPECT_MAX_ANGLE` between the
    normal and the line of sight;
    a marker whose normal faces away from the predicted perspective centre ``center`` is
    never expected. A marker that was never
    seen and has no normal is not expected (never counted missing): it is looked for every
    :data:`PROBE_EVERY` frames.
    """
    ids = setup.ids
    seen = np.isin(ids, np.asarray(reference.ids, str))
    if previous is not None and previous.ok:
        seen |= np.isin(ids, np.asarray(previous.ids, str))
    normals = getattr(setup, "normals", None)
    if normals is None:
        return seen, np.zeros(len(ids), bool)
    known = np.isfinite(normals).all(axis=1)
    view = center[None, :] - setup.points3d
    with np.errstate(invalid="ignore"):
        cosine = np.einsum("ij,ij->i", normals, view) / np.linalg.norm(view, axis=1)
    # facing within the obliqueness cut-off: expected even if never seen; beyond it (a
    # grazing view) only if seen, and probed otherwise; facing away: never
    facing = known & (cosine >= math.cos(math.radians(EXPECT_MAX_ANGLE)))
    away = known & ~(cosine > 0)
    return (seen | facing) & ~away, away


def _survey_offsets(ids: np.ndarray, reference: FrameResult) -> np.ndarray:
    """(N, 2) pixels: each marker's residual in ``reference`` (observed minus reprojected),
    zero where it was not found there. A marker's surveyed position is off by its own
    error (0.5-1.5 px on real models), the same from frame to frame: its window is placed
    where the reference saw it, moved by the predicted pose, not where the survey puts it.
    Without this a window's start and its fit fell on different pixels for nearly every
    marker of every frame, and each was fitted twice (see :func:`track_predicted`)."""
    off = np.zeros((len(ids), 2))
    res = np.asarray(reference.residuals, float).reshape(-1, 2)
    if res.size:
        row = {m: i for i, m in enumerate(np.asarray(ids).tolist())}
        at = np.array([row.get(m, -1) for m in np.asarray(reference.ids).tolist()], int)
        ok = (at >= 0) & np.isfinite(res).all(axis=1)
        off[at[ok]] = res[ok]
    return off


def track_predicted(img: np.ndarray, setup, reference: FrameResult,
                    previous: FrameResult | None, index: int, name: str) -> FrameResult | None:
    """One frame tracked by prediction from ``reference`` (and ``previous``), or None when
    the gate fails and the statistical matcher must decide (see the module docstring).

    ``setup`` is the tracker's setup (camera, markers, diameter, polarity, options).
    """
    from resection.markers.detect import refine_markers

    cam, X = setup.camera, setup.points3d
    kw = setup.detect_kw
    rvec0, tvec0 = predict_pose(reference, previous, index)
    rmax = cam.max_radius
    pred = project_poses(cam, rvec0, tvec0, X, max_radius=rmax)[0]
    pred += _survey_offsets(setup.ids, reference)
    d = setup.diameter
    R = d / 2.0
    blur = float(kw.get("blur", 0.6))
    half = int(np.ceil(1.25 * R + 3.0 * blur + 3.0))
    H, W = img.shape
    u0, v0, u1, v1 = kw.get("roi") or (0, 0, W - 1, H - 1)
    with np.errstate(invalid="ignore"):
        inside = ((pred[:, 0] >= u0 + half + 1) & (pred[:, 0] <= u1 - half - 1)
                  & (pred[:, 1] >= v0 + half + 1) & (pred[:, 1] <= v1 - half - 1))
    center = -rotvec_to_matrix(rvec0).T @ tvec0
    expected, away = expected_markers(setup, reference, previous, center)
    vis = np.flatnonzero(inside & expected)
    min_matches = int(_match_default("min_matches", setup.match_kw))
    need = max(setup.min_markers, min_matches, math.ceil(MIN_FOUND_FRACTION * vis.size))
    if vis.size < need or vis.size < 4:
        return None
    # markers not expected (never seen, or lost) are looked for every PROBE_EVERY frames,
    # where their window cannot hold an expected marker
    probe = np.zeros(0, int)
    if index % PROBE_EVERY == 0:
        probe = np.flatnonzero(inside & ~expected & ~away)
        if probe.size:
            dist_to_expected = _distances(pred[probe], pred[vis]).min(axis=1)
            probe = probe[dist_to_expected > 2.0 * half]
    look = np.concatenate([vis, probe])
    pv = pred[look]
    between = _distances(pv, pv)
    np.fill_diagonal(between, np.inf)
    nn = between.min(axis=1)  # each window's nearest other
    gate = np.minimum(R + 1.5, GATE_SPACING_FRACTION * nn)
    # only the box around the predicted markers is read (and negated, for dark markers)
    c0 = np.maximum(np.floor(pv.min(axis=0)).astype(int) - half - 1, 0)
    c1 = np.minimum(np.ceil(pv.max(axis=0)).astype(int) + half + 2, (W, H))
    box = img[c0[1]:c1[1], c0[0]:c1[0]]
    signal = -box if setup.polarity == "dark" else box
    bad = ~np.isfinite(signal)
    if kw.get("mask") is not None:
        bad |= np.asarray(kw["mask"], bool)[c0[1]:c1[1], c0[0]:c1[0]]
    start = pv - c0
    shape = marker_shape(kw, d)
    fit = refine_markers(signal, start, d, bad=bad, blur=blur, half=half, shape=shape,
                         tol=TRACK_FIT_TOL, workers=setup.fit_workers)
    # a window is centred on the pixel of its start: fits that moved to another pixel are
    # fitted again in the window centred on theirs, so that the result does not depend on
    # how far off the prediction was (the window is then the one detection would use)
    moved = np.flatnonzero(fit["ok"] & np.any(np.rint(start) != np.rint(
        np.column_stack([fit["u"], fit["v"]])), axis=1))
    if moved.size:
        again = refine_markers(signal, np.column_stack([fit["u"], fit["v"]])[moved], d,
                               bad=bad, blur=blur, half=half, shape=shape,
                               tol=TRACK_FIT_TOL, workers=setup.fit_workers)
        for k in fit:
            fit[k][moved] = again[k]
    lo_d, hi_d = kw.get("diameter_range", (0.5, 2.0))
    found = np.column_stack([fit["u"], fit["v"]]) + c0
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = (fit["ok"] & (np.hypot(*(found - pv).T) <= gate)
              & (fit["depth"] >= float(kw.get("min_snr", 3.0)) * fit["rms"])
              & (2.0 * fit["radius"] >= lo_d * d) & (2.0 * fit["radius"] <= hi_d * d)
              & (fit["masked_fraction"] <= float(kw.get("max_masked", 0.75))))
    n_vis = vis.size
    sel = np.flatnonzero(ok[:n_vis])
    if sel.size > 1:  # two windows on one blob: neither is trusted
        near = _distances(found[sel], found[sel]) <= max(0.75 * d, 1.5)
        np.fill_diagonal(near, False)
        sel = sel[~near.any(axis=1)]
    if sel.size < need:
        return None
    idx, uv = vis[sel], found[sel]
    tolerance = float(_match_default("tolerance", setup.match_kw))
    fixed_gate = setup.match_kw.get("gate")
    rvec, tvec, res = refine_pose(cam, rvec0, tvec0, X[idx], uv, max_radius=rmax)
    for attempt in range(2):
        err = np.hypot(res[:, 0], res[:, 1])
        g = float(fixed_gate) if fixed_gate is not None else residual_gate(err, tolerance)
        keep = err <= g
        if keep.all():
            break
        if attempt == 1 or keep.sum() < need:
            return None
        idx, uv = idx[keep], uv[keep]
        rvec, tvec, res = refine_pose(cam, rvec, tvec, X[idx], uv, max_radius=rmax)
    # the package's acceptance rule, with the accuracy and max_rms the matcher would use
    accuracy = setup.pose_kw.get("marker_accuracy",
                                 _match_default("marker_accuracy", setup.match_kw))
    max_rms = setup.pose_kw.get("max_rms", _match_default("max_rms", setup.match_kw))
    acc = judge(err, 6, accuracy, max_rms, what="track")
    if not acc.accepted:
        return None
    if probe.size:  # markers coming into view: those found where the solved pose puts them
        got = _probed(fit, found, ok, n_vis, probe, sel, uv, cam, rvec, tvec, X, g, d,
                      rmax)
        if got is not None:
            idx2, uv2 = np.concatenate([idx, got[0]]), np.vstack([uv, got[1]])
            r2, t2, res2 = refine_pose(cam, rvec, tvec, X[idx2], uv2, max_radius=rmax)
            err2 = np.hypot(res2[:, 0], res2[:, 1])
            acc2 = judge(err2, 6, accuracy, max_rms, what="track")
            if acc2.accepted and (err2 <= g).all():
                idx, uv, rvec, tvec, res, acc = idx2, uv2, r2, t2, res2, acc2
    rms = acc.statistic
    return FrameResult(frame=index, file=name, status="ok", rvec=rvec, tvec=tvec, rms=rms,
                       ids=setup.ids[idx].astype(str), uv=uv, residuals=res,
                       method="predicted")


def _probed(fit, found, ok, n_vis, probe, tracked, uv_tracked, cam, rvec, tvec, X, gate,
            d, rmax):
    """The probed markers (never seen or lost) found within the residual ``gate`` (at most
    :data:`PROBE_GATE`) of where the pose solved from the tracked markers puts them, with
    a diameter within :data:`PROBE_DIAMETER` of the expected one and a fitted diameter and
    contrast at least :data:`PROBE_LIKE` times the median of the tracked markers' (fits
    ``tracked``: a pressure tap or a speckle grain is smaller or fainter), and not on a
    tracked marker: ``(indices, uv)`` or None. (Without normals, a marker on the far side
    projects onto the near side's paint: these tests keep it from taking a blob there.)"""
    j = np.flatnonzero(ok[n_vis:])
    if j.size == 0:
        return None
    at = n_vis + j
    proj = project_poses(cam, rvec, tvec, X[probe[j]], max_radius=rmax)[0]
    r_med = float(np.median(fit["radius"][tracked]))
    a_med = float(np.median(fit["depth"][tracked]))
    with np.errstate(invalid="ignore"):
        good = ((np.hypot(*(found[at] - proj).T) <= min(gate, PROBE_GATE))
                & (2.0 * fit["radius"][at] >= PROBE_DIAMETER[0] * d)
                & (2.0 * fit["radius"][at] <= PROBE_DIAMETER[1] * d)
                & (fit["radius"][at] >= PROBE_LIKE * r_med)
                & (fit["depth"][at] >= PROBE_LIKE * a_med))
    if uv_tracked.size:
        good &= _distances(found[at], uv_tracked).min(axis=1) > max(1.5 * d, 3.0)
    if not good.any():
        return None
    return probe[j[good]], found[at[good]]
