"""Automatic matching of detected candidates to the model's markers.

The statistical method (after the paper): take three reference markers, pair them with
three candidates, fit a transform, apply it to the other markers and count those that land
on a candidate; keep the hypothesis that explains most markers, then verify it with a full
Point-of-View solve and a residual test. The answer is right or refused:
:class:`~resection.errors.SolveError` says why (two distinct hypotheses score alike, too
few markers explained, residual too large, pose ambiguous).

Reference positions of the markers come either from an earlier matched frame (their pixel
positions there) or from an approximate camera (their projections). Between the reference
and the image the markers may move by up to ``search_radius`` pixels, rotate by up to
``max_rotation`` and change scale by ``max_scale_change``; markers may be hidden, appear
(not yet visible in the reference frame) and spurious candidates may outnumber real ones.

How the hypotheses are kept few (no search over all triples of triples):

* a few dozen well-spread *basis* triples of reference markers are drawn;
* each basis marker is paired only with candidates within ``search_radius`` of it
  (k-d tree);
* candidate pairs must reproduce the basis side lengths (within the scale tolerance) and
  directions (within ``max_rotation``), and the three pairs must close into a triangle
  (boolean tensors, no Python loop over candidates);
* the surviving triples give a 2-D similarity each, whose three-point residual must be small;
* all hypotheses are scored at once with one k-d tree query.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from resection.camera.model import Camera
from resection.camera.units import nothing_seen_causes
from resection.errors import InputError, SolveError
from resection.pose.acceptance import (
    DEFAULT_MARKER_ACCURACY,
    DEFAULT_MAX_RMS,
    check_accuracy,
    judge,
    require,
)

__all__ = ["MatchResult", "match_markers", "reference_frame"]


@dataclass(frozen=True)
class MatchResult:
    """Result of :func:`match_markers`.

    Attributes
    ----------
    ids : tuple of (str or None)
        Marker id of every candidate, in the candidates' order; None for unmatched ones.
    marker_ids : tuple of str
        The matched markers.
    candidate_index : (M,) int array
        Index of each matched marker's candidate.
    uv : (M, 2) array
        Pixel positions of the matched markers (the candidates'), px.
    pose : PoseResult or None
        Full Point-of-View solve on the matched markers (None without a camera).
    residuals : (M, 2) array
        Observed minus predicted (reprojected, or affine-mapped without a camera), px.
    rms : float
        RMS of the residual norms, px.
    score : int
        Markers explained by the best hypothesis.
    second_score : int
        Markers explained by the best *distinct* competing hypothesis (0 if none).
    n_hypotheses : int
        Hypotheses scored.
    message : str
    extra : dict
        ``{"affine": (2, 3) array}``: the image-to-image affine map of the hypothesis.
    acceptance : Acceptance
        The acceptance rule's decision (:mod:`resection.pose.acceptance`): statistic,
        threshold, markers dropped as gross outliers.
    """

    ids: tuple
    marker_ids: tuple
    candidate_index: np.ndarray
    uv: np.ndarray
    pose: object
    residuals: np.ndarray
    rms: float
    score: int
    second_score: int
    n_hypotheses: int
    message: str = ""
    extra: dict = field(default_factory=dict)
    acceptance: object = None

    def __len__(self) -> int:
        return len(self.marker_ids)


# ----------------------------------------------------------------------------- inputs
def marker_table(markers3d):
    """(ids, xyz) from a MarkerSet, a dict {id: xyz} or a pair (ids, xyz); None passes."""
    if markers3d is None:
        return None, None
    if hasattr(markers3d, "ids") and hasattr(markers3d, "xyz"):
        ids, xyz = markers3d.ids, markers3d.xyz
    elif isinstance(markers3d, dict):
        ids, xyz = list(markers3d.keys()), list(markers3d.values())
    elif isinstance(markers3d, tuple | list) and len(markers3d) == 2:
        ids, xyz = markers3d
    else:
        raise InputError("markers3d: expected a MarkerSet, a dict {id: (x, y, z)} or (ids, xyz)")
    ids = tuple(str(k) for k in ids)
    xyz = np.asarray(xyz, dtype=float)
    if xyz.ndim != 2 or xyz.shape != (len(ids), 3):
        raise InputError(f"markers3d: {len(ids)} ids but coordinates of shape {xyz.shape}")
    if not np.all(np.isfinite(xyz)):
        raise InputError("markers3d: coordinates contain NaN or infinite values")
    if len(set(ids)) != len(ids):
        raise InputError("markers3d: duplicate ids")
    return ids, xyz


def _candidates_uv(candidates) -> np.ndarray:
    uv = candidates.uv if hasattr(candidates, "uv") else candidates
    try:
        uv = np.asarray(uv, dtype=float)
    except (TypeError, ValueError):
        raise InputError("candidates: not numeric") from None
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"candidates: expected (N, 2) positions, got shape {uv.shape}")
    if not np.all(np.isfinite(uv)):
        raise InputError("candidates: positions contain NaN or infinite values")
    return uv


def reference_frame(ids, uv) -> tuple[tuple[str, ...], np.ndarray]:
    """A reference frame (marker ids and their pixel positions) for :func:`match_markers`."""
    ids = tuple(str(k) for k in ids)
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    if len(ids) != len(uv):
        raise InputError(f"reference: {len(ids)} ids but {len(uv)} positions")
    if not np.all(np.isfinite(uv)):
        raise InputError("reference: positions contain NaN")
    return ids, uv


def _predictions(reference, ids3d, xyz, margin):
    """Reference ids and positions; the camera (if the reference is one)."""
    if isinstance(reference, Camera):
        if ids3d is None:
            raise InputError("match_markers: a camera reference needs markers3d")
        uv, valid = reference.project(xyz, return_valid=True)
        valid &= reference.in_image(uv, margin=-margin)
        return tuple(np.array(ids3d)[valid]), uv[valid], reference
    if isinstance(reference, MatchResult):
        return tuple(reference.marker_ids), np.asarray(reference.uv, float), None
    if isinstance(reference, tuple | list) and len(reference) == 2:
        ids, uv = reference_frame(*reference)
        return ids, uv, None
    raise InputError("reference: expected an approximate Camera, a MatchResult or (ids, uv) of "
                     "an earlier matched frame")


# ----------------------------------------------------------------------------- geometry
def _fit_affine(P, Q):
    """Least-squares affine map ``Q ~ P @ A.T + b``; returns (2, 3) ``[A | b]``."""
    X = np.column_stack([P, np.ones(len(P))])
    sol, *_ = np.linalg.lstsq(X, Q, rcond=None)
    return sol.T


def _apply_affine(T, P):
    return P @ T[:, :2].T + T[:, 2]


def _basis_triples(P, n_bases, rng):
    """Well-spread, well-shaped triples of reference points (indices)."""
    n = len(P)
    if n < 3:
        return np.zeros((0, 3), int)
    spread = np.sqrt(np.sum(np.var(P, axis=0)))
    ntry = max(20 * n_bases, 200)
    T = np.argsort(rng.random((ntry, n)), axis=1)[:, :3] if n > 3 else np.array([[0, 1, 2]])
    T = np.unique(np.sort(T, axis=1), axis=0)
    a, b, c = P[T[:, 0]], P[T[:, 1]], P[T[:, 2]]
    sides = np.stack([np.linalg.norm(a - b, axis=1), np.linalg.norm(b - c, axis=1),
                      np.linalg.norm(a - c, axis=1)], 1)
    area = 0.5 * np.abs((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0])
    # shape quality: area relative to the longest side squared (1/2 for a right isoceles)
    quality = area / np.maximum(sides.max(axis=1) ** 2, 1e-12)
    good = (quality > 0.15) & (sides.min(axis=1) > 0.15 * spread)
    if good.sum() < min(n_bases, len(T)):
        good = quality > 0.05
    T = T[good]
    # random order among the good triangles (np.unique sorted them): variety, so that
    # hidden markers cannot sink every basis
    return T[rng.permutation(len(T))[:n_bases]]


def _hypotheses(P, Q, tree, basis, radius, tol, max_scale, max_rot):
    """Similarities (complex a, b: q = a p + b) from candidate triples consistent with a basis."""
    out_a, out_b = [], []
    lists = tree.query_ball_point(P[basis], radius)
    for (ia, ib, ic), (La, Lb, Lc) in zip(basis, lists, strict=True):  # a few dozen bases
        if not (La and Lb and Lc):
            continue
        La, Lb, Lc = np.array(La), np.array(Lb), np.array(Lc)

        def consistent(Li, Lj, pi, pj):
            dp = P[pj] - P[pi]
            dq = Q[Lj][None, :, :] - Q[Li][:, None, :]
            lp = np.hypot(*dp)
            lq = np.hypot(dq[..., 0], dq[..., 1])
            slack = max_scale + 2.0 * tol / lp
            ok = np.abs(lq / lp - 1.0) <= slack
            ang = np.arctan2(dq[..., 1], dq[..., 0]) - math.atan2(dp[1], dp[0])
            ang = np.abs((ang + np.pi) % (2 * np.pi) - np.pi)
            return ok & (ang <= max_rot + 2.0 * tol / lp)

        ok = (consistent(La, Lb, ia, ib)[:, :, None] & consistent(Lb, Lc, ib, ic)[None, :, :]
              & consistent(La, Lc, ia, ic)[:, None, :])
        i, j, k = np.nonzero(ok)
        if i.size == 0:
            continue
        p = P[[ia, ib, ic]] @ np.array([1.0, 1j])
        q = np.stack([Q[La[i]], Q[Lb[j]], Q[Lc[k]]], axis=1) @ np.array([1.0, 1j])
        pc = p - p.mean()
        qc = q - q.mean(axis=1, keepdims=True)
        a = (np.conj(pc)[None, :] * qc).sum(axis=1) / np.sum(np.abs(pc) ** 2)
        b = q.mean(axis=1) - a * p.mean()
        res = np.abs(q - (a[:, None] * p[None, :] + b[:, None])).max(axis=1)
        keep = res <= 2.0 * tol
        out_a.append(a[keep])
        out_b.append(b[keep])
    if not out_a:
        return np.zeros(0, complex), np.zeros(0, complex)
    return np.concatenate(out_a), np.concatenate(out_b)


def assign_nearest(pred, tree, tol):
    """Assignment of predicted points to their nearest candidate within ``tol``; a candidate
    claimed by several predictions goes to the nearest. Returns (candidate index or -1,
    distance)."""
    d, j = tree.query(pred, distance_upper_bound=tol)
    ok = np.isfinite(d)
    jj = np.where(ok, j, -1)
    order = np.argsort(np.where(ok, d, np.inf), kind="stable")
    cs = jj[order]
    first = np.zeros(len(pred), bool)
    first[np.unique(cs, return_index=True)[1]] = True
    keep = np.zeros(len(pred), bool)
    keep[order] = first & (cs >= 0)
    return np.where(keep, jj, -1), np.where(keep, d, np.inf)


def _gate(errors, tolerance: float) -> float:
    """Acceptance radius around a reprojection: 6 sigma of the position noise, sigma
    estimated robustly from the median reprojection error (Rayleigh: median = 1.1774 sigma;
    6 rather than ~4 because this estimate from ~20 residuals that the pose has partly
    fitted is low by up to 30 %), at least 0.25 px, at most ``tolerance``. A true marker
    falls outside with probability < 1e-5; the area where a spurious candidate could be
    taken for a hidden marker stays as small as the noise allows."""
    e = np.asarray(errors, float)
    e = e[np.isfinite(e)]
    sigma = float(np.median(e)) / 1.1774 if e.size else tolerance
    return float(min(tolerance, max(6.0 * sigma, 0.25)))


def _pose_options(pose_kw) -> dict:
    """Checked copy of the ``solve_pose`` options: keyword names of solve_pose only."""
    if pose_kw is None:
        return {}
    if not isinstance(pose_kw, dict):
        raise InputError(f"pose_kw: expected a dict of solve_pose options, got "
                         f"{type(pose_kw).__name__}")
    import inspect

    from resection.pose.solve import solve_pose

    params = inspect.signature(solve_pose).parameters
    allowed = {k for k, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    unknown = sorted(set(pose_kw) - allowed)
    if unknown:
        raise InputError(f"pose_kw: unknown solve_pose option(s) {unknown}; expected some of "
                         f"{sorted(allowed)}")
    return dict(pose_kw)


# ----------------------------------------------------------------------------- main
def match_markers(
    candidates,
    markers3d,
    reference,
    camera: Camera | None = None,
    *,
    search_radius: float = 25.0,
    tolerance: float = 3.0,
    max_rotation: float = math.radians(20.0),
    max_scale_change: float = 0.15,
    n_bases: int = 40,
    min_matches: int = 5,
    ambiguity_ratio: float = 0.7,
    max_rms: float | None = DEFAULT_MAX_RMS,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    gate: float | None = None,
    seed: int = 0,
    pose_kw: dict | None = None,
) -> MatchResult:
    """Link candidates to markers, or refuse with the reason.

    Parameters
    ----------
    candidates : Candidates or (N, 2) array
        Detected candidates (pixels).
    markers3d : MarkerSet, dict {id: xyz}, (ids, xyz) or None
        The model's markers. May be None when the reference is a frame and no camera is
        given (2-D matching only).
    reference : Camera, MatchResult or (ids, uv)
        An approximate camera (the markers are predicted by projection; those projecting
        more than ``search_radius`` outside the image are left out), or an earlier matched
        frame.
    camera : Camera, optional
        Intrinsics for the Point-of-View verification (default: the reference camera).
        Without a camera (frame reference), the verification is an affine fit.
    search_radius : float
        Largest displacement of a marker between the reference and the image, px.
    tolerance : float
        Distance (px) within which a transformed marker "lands" on a candidate.
    max_rotation : float
        Largest image rotation between reference and image, radians.
    max_scale_change : float
        Largest relative change of image scale.
    n_bases : int
        Basis triples tried.
    min_matches : int
        Fewest markers the result must explain.
    ambiguity_ratio : float
        Refuse when a distinct hypothesis explains at least this fraction of the best
        one's markers.
    max_rms : float or None
        Upper limit of the final RMS residual whatever the accuracy, px (default 2).
    marker_accuracy : float
        Stated accuracy of a marker position (survey + detection, RMS length, px; default
        1). The match is judged by the acceptance rule (:mod:`resection.pose.acceptance`), and
        this accuracy and ``max_rms`` go down to the verifying pose solves (unless
        ``pose_kw`` sets them): gross outliers are dropped within limits, and the RMS of
        the matched markers must not exceed its 99.9 % bound for this accuracy.
    gate : float, optional
        Largest residual of a matched marker after the pose solve (px); default 6 times
        the position noise estimated from the median residual, at least 0.25 px, at most
        ``tolerance``.
    seed : int
        Seed of the basis choice (the result is deterministic).
    pose_kw : dict, optional
        Further keyword arguments of :func:`resection.pose.solve.solve_pose` for the verifying
        pose solves (e.g. ``ambiguity_px``, ``max_triplets``, ``max_nfev``). The first solve,
        on the hypothesis' pairs, uses ``robust="huber", robust_scale=0.5`` unless
        ``pose_kw`` sets them; the final solves use ``pose_kw`` as given. Ignored without a
        camera. Unknown keys are an :class:`~resection.errors.InputError`.

    Returns
    -------
    MatchResult

    Raises
    ------
    InputError
        Bad candidates, markers or reference.
    SolveError
        No hypothesis, too few markers explained, ambiguity, pose failure, residual too
        large. The message says which.
    """
    Q = _candidates_uv(candidates)
    ids3d, xyz = marker_table(markers3d)
    pose_kw = _pose_options(pose_kw)
    for name, val in (("search_radius", search_radius), ("tolerance", tolerance),
                      ("max_rms", 1.0 if max_rms is None else max_rms)):
        if not (np.isfinite(val) and val > 0):
            raise InputError(f"match_markers: {name} must be positive, got {val}")
    # one stated accuracy for the matcher and its pose solves (pose_kw may set it)
    accuracy = check_accuracy(pose_kw.get("marker_accuracy", marker_accuracy), "match_markers")
    max_rms = pose_kw.get("max_rms", max_rms)
    pose_kw = {**pose_kw, "marker_accuracy": accuracy, "max_rms": max_rms}
    ref_ids, P, ref_cam = _predictions(reference, ids3d, xyz, search_radius)
    cam = camera if camera is not None else ref_cam
    if cam is not None and not isinstance(cam, Camera):
        raise InputError("camera: expected a resection.Camera")
    if cam is not None and ids3d is None:
        raise InputError("match_markers: the pose verification needs markers3d")
    if len(P) < 3:
        why = "" if ref_cam is None else \
            "; likely causes: " + nothing_seen_causes(ref_cam, xyz, "the markers")
        raise SolveError(f"match_markers: only {len(P)} reference marker(s) in view; 3 are "
                         f"needed{why}")
    if len(Q) < 3:
        raise SolveError(f"match_markers: only {len(Q)} candidate(s); 3 are needed")
    tree = cKDTree(Q)
    rng = np.random.default_rng(seed)
    basis = _basis_triples(P, n_bases, rng)
    a, b = _hypotheses(P, Q, tree, basis, search_radius, tolerance, max_scale_change,
                       max_rotation)
    if a.size == 0:  # every basis had a hidden marker: try more of them once
        basis = _basis_triples(P, 5 * n_bases, rng)
        a, b = _hypotheses(P, Q, tree, basis, search_radius, tolerance, max_scale_change,
                           max_rotation)
    nh = int(a.size)
    if nh == 0:
        raise SolveError("match_markers: no hypothesis: no three candidates reproduce a "
                         "triangle of reference markers within the search radius")
    # ---- score every hypothesis at once
    pc = P @ np.array([1.0, 1j])
    T = a[:, None] * pc[None, :] + b[:, None]
    pts = np.stack([T.real, T.imag], axis=-1).reshape(-1, 2)
    d, j = tree.query(pts, distance_upper_bound=tolerance)
    j = np.where(np.isfinite(d), j, -1).reshape(nh, -1)
    score = (j >= 0).sum(axis=1)
    best = int(np.argmax(score))
    s1 = int(score[best])
    same = ((j == j[best][None, :]) & (j[best][None, :] >= 0)).sum(axis=1)
    distinct = same < 0.5 * s1
    s2 = int(score[distinct].max()) if distinct.any() else 0
    if s1 < min_matches:
        raise SolveError(f"match_markers: the best hypothesis explains only {s1} markers "
                         f"(min_matches={min_matches})")
    if s2 >= ambiguity_ratio * s1:
        raise SolveError(f"match_markers: ambiguous: two distinct hypotheses explain {s1} and "
                         f"{s2} markers (symmetric layout or too large search radius)")
    # ---- refine the best: affine on its inliers, reassign (twice)
    jb = j[best]
    mk = jb >= 0
    A = _fit_affine(P[mk], Q[jb[mk]]) if mk.sum() >= 4 else np.array(
        [[a[best].real, -a[best].imag, b[best].real], [a[best].imag, a[best].real, b[best].imag]])
    for _ in range(2):
        jb, _ = assign_nearest(_apply_affine(A, P), tree, tolerance)
        mk = jb >= 0
        if mk.sum() < max(min_matches, 4):
            raise SolveError(f"match_markers: only {mk.sum()} markers left after refinement")
        A = _fit_affine(P[mk], Q[jb[mk]])
    matched_ids = [ref_ids[i] for i in np.flatnonzero(mk)]
    cand_idx = jb[mk]
    pose = None
    if cam is None:
        # the same statistical gate as after a pose solve, on the affine residuals
        err = np.hypot(*(Q[cand_idx] - _apply_affine(A, P[mk])).T)
        g = gate if gate is not None else _gate(err, tolerance)
        keep = err <= g
        if keep.sum() < max(min_matches, 4):
            raise SolveError(f"match_markers: only {keep.sum()} markers within {g:.2g} px of "
                             "the fitted affine map")
        sel = np.flatnonzero(mk)[keep]
        A = _fit_affine(P[sel], Q[jb[sel]])
        matched_ids = [ref_ids[i] for i in sel]
        cand_idx = jb[sel]
        res = Q[cand_idx] - _apply_affine(A, P[sel])
    else:
        from resection.pose.solve import solve_pose

        pos3 = {k: i for i, k in enumerate(ids3d)}
        unknown = [k for k in matched_ids if k not in pos3]
        if unknown:
            raise InputError(f"reference: id(s) not in markers3d: {', '.join(unknown[:10])}")
        X = xyz[[pos3[k] for k in matched_ids]]
        # the first solve is a start (its pairs may be wrong): no acceptance test on it
        pose = solve_pose(cam, X, Q[cand_idx],
                          **{"robust": "huber", "robust_scale": 0.5, **pose_kw,
                             "marker_accuracy": 1e6, "max_rms": None})
        # reproject every marker (also those absent from the reference), keep those within
        # a statistical gate of their reprojection, resolve (twice: the first pose may
        # still carry a wrong pair)
        for _ in range(2):
            proj = pose.camera.project(xyz)
            inview = np.isfinite(proj).all(axis=1)
            g = gate if gate is not None else _gate(pose.errors, tolerance)
            jj = np.full(len(xyz), -1)
            jj[inview], _ = assign_nearest(proj[inview], tree, g)
            sel = np.flatnonzero(jj >= 0)
            if sel.size < max(min_matches, 4):
                raise SolveError(f"match_markers: only {sel.size} markers within {g:.2g} px of "
                                 "their reprojection after the pose solve")
            pose = solve_pose(cam, xyz[sel], Q[jj[sel]], ids=[ids3d[i] for i in sel],
                              **pose_kw)
        if not pose.used.all():  # gross outliers dropped by the acceptance rule: the
            u = pose.used        # match and its pose keep the used markers only
            sel = sel[u]
            pose = replace(pose, residuals=pose.residuals[u], errors=pose.errors[u],
                           inliers=pose.inliers[u], used=pose.used[u])
        matched_ids = [ids3d[i] for i in sel]
        cand_idx = jj[sel]
        res = pose.residuals
    err = np.hypot(res[:, 0], res[:, 1])
    rms = float(np.sqrt(np.mean(err**2)))
    if pose is not None and pose.acceptance is not None:
        acc = pose.acceptance
    else:
        acc = judge(err, 6, accuracy, max_rms, what="match")
    require(acc, "match_markers", "wrong match or wrong camera")
    ids = [None] * len(Q)
    for k, c in zip(matched_ids, cand_idx, strict=True):
        ids[int(c)] = k
    msg = (f"matched {len(cand_idx)} of {len(Q)} candidates, rms {rms:.3g} px, "
           f"score {s1} vs {s2}, {nh} hypotheses")
    return MatchResult(tuple(ids), tuple(matched_ids), np.asarray(cand_idx, int),
                       Q[cand_idx], pose, res, rms, s1, s2, nh,
                       f"{msg}; accepted: {acc.describe()}", {"affine": A}, acc)
