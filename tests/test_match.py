"""Automatic marker matching: right or refused.

The truth is known by construction: candidates are the true projections (through an
independently perturbed camera) of a random subset of markers, plus noise, plus uniformly
scattered spurious candidates, shuffled.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resection.camera.model import Camera
from resection.errors import InputError, SolveError
from resection.markers.match import MatchResult, match_markers

K = [[1500.0, 0, 512], [0, 1500.0, 384], [0, 0, 1]]
BASE = Camera.look_at([0.2, -0.3, 1.6], [0, 0, 0], [0, 1, 0], K=K, width=1024, height=768)


def _model(rng, n=30):
    """Markers on a wing (z = 0) with a fuselage bump: not coplanar."""
    x = rng.uniform(-0.4, 0.4, n)
    y = rng.uniform(-0.25, 0.25, n)
    z = 0.08 * np.exp(-((y / 0.08) ** 2))
    return tuple(f"M{k:02d}" for k in range(n)), np.column_stack([x, y, z])


def _frame(rng, ids, X, *, rot_sigma=0.004, t_sigma=0.004, missing=0.3, spurious=1.0,
           noise=0.05):
    """Perturbed camera, candidates with truth labels (None for spurious)."""
    dR = Rotation.from_rotvec(rng.normal(0, rot_sigma, 3)).as_matrix()
    cam = BASE.with_pose(R=dR @ BASE.R, t=BASE.t + rng.normal(0, t_sigma, 3))
    uv = cam.project(X)
    vis = cam.in_image(uv, margin=8) & (rng.random(len(X)) > missing)
    real = uv[vis] + rng.normal(0, noise, (vis.sum(), 2))
    nsp = int(round(spurious * vis.sum()))
    spur = np.column_stack([rng.uniform(5, 1019, nsp), rng.uniform(5, 763, nsp)])
    Q = np.vstack([real, spur])
    perm = rng.permutation(len(Q))
    truth = np.array([ids[i] for i in np.flatnonzero(vis)] + [None] * nsp, dtype=object)
    return Q[perm], truth[perm], cam


@pytest.mark.slow  # 8-11 s
def test_200_frames_from_approximate_camera_all_correct():
    rng = np.random.default_rng(1)
    ids, X = _model(rng)
    n_ok = 0
    shifts, n_hyp = [], []
    for _ in range(200):
        Q, truth, cam = _frame(rng, ids, X)
        res = match_markers(Q, (ids, X), BASE)
        n_ok += np.array_equal(np.array(res.ids, dtype=object), truth)
        assert res.second_score < 0.7 * res.score
        shifts.append(np.nanmax(np.hypot(*(cam.project(X) - BASE.project(X)).T)))
        n_hyp.append(res.n_hypotheses)
    assert n_ok == 200
    # the model really moved by several pixels against the reference
    assert np.median(shifts) > 5 and max(shifts) > 10
    # prefiltered hypotheses: a few dozen, where all triples of markers times all ordered
    # triples of candidates would be C(30, 3) * 40 * 39 * 38 ~ 2.4e8
    assert max(n_hyp) <= 500


def test_approximate_camera_off_by_tens_of_pixels():
    rng = np.random.default_rng(5)
    ids, X = _model(rng)
    shifts = []
    for _ in range(30):
        Q, truth, cam = _frame(rng, ids, X, rot_sigma=0.008, t_sigma=0.008)
        shifts.append(np.nanmax(np.hypot(*(cam.project(X) - BASE.project(X)).T)))
        res = match_markers(Q, (ids, X), BASE, search_radius=40)
        assert np.array_equal(np.array(res.ids, dtype=object), truth)
    assert max(shifts) > 20  # the approximate camera really was that far off


def test_sequence_from_previous_frame_with_hidden_and_appearing_markers():
    # each frame is matched against the previous frame's result: markers hidden there must
    # be recovered through the pose (not-yet-visible markers)
    rng = np.random.default_rng(2)
    ids, X = _model(rng)
    Q, truth, cam = _frame(rng, ids, X)
    ref = match_markers(Q, (ids, X), BASE)
    for _ in range(30):
        Q, truth, cam = _frame(rng, ids, X)
        res = match_markers(Q, (ids, X), ref, camera=BASE)
        assert np.array_equal(np.array(res.ids, dtype=object), truth)
        assert res.pose.rms < 0.2
        # the solved pose is the true one to within the candidate noise
        assert np.allclose(res.pose.camera.project(X), cam.project(X), atol=0.1)
        ref = res


def test_large_motion_between_frames_2d_only():
    # 15 px of translation and 3 degrees of rotation between frames, no camera: affine check
    rng = np.random.default_rng(3)
    P = np.column_stack([rng.uniform(50, 950, 25), rng.uniform(50, 700, 25)])
    ids = tuple(f"P{k}" for k in range(25))
    c, s = np.cos(0.05), np.sin(0.05)
    Qt = (P - 500) @ np.array([[c, -s], [s, c]]).T + 500 + [12.0, -9.0]
    keep = rng.random(25) > 0.3
    spur = np.column_stack([rng.uniform(0, 1000, 25), rng.uniform(0, 750, 25)])
    Q = np.vstack([Qt[keep], spur])
    res = match_markers(Q, None, (ids, P), search_radius=50)
    expected = [ids[i] for i in np.flatnonzero(keep)] + [None] * 25
    assert list(res.ids) == expected
    assert res.pose is None and res.rms < 1e-6


def test_symmetric_layout_is_refused():
    # a regular grid, and candidates shifted by half a spacing: shifting left or right
    # explains as many markers; the answer must be a refusal, not a guess
    g = np.stack(np.meshgrid(np.arange(6), np.arange(5)), -1).reshape(-1, 2) * 40.0 + 100
    ids = tuple(f"G{k}" for k in range(len(g)))
    Q = g + [20.0, 0.0]
    with pytest.raises(SolveError, match="ambiguous"):
        match_markers(Q, None, (ids, g), search_radius=25)
    # with a search radius that excludes the wrong shift it is not ambiguous any more
    res = match_markers(g + [5.0, 0.0], None, (ids, g), search_radius=25)
    assert list(res.ids) == list(ids)


def test_wrong_camera_is_refused_by_residual_test():
    # the candidates come from a camera with another focal length and strong distortion;
    # the pose verification cannot explain them within max_rms
    rng = np.random.default_rng(4)
    ids, X = _model(rng)
    true = BASE.replace(K=np.array([[1650.0, 0, 512], [0, 1650.0, 384], [0, 0, 1]]),
                        dist=np.array([-0.6, 0.0, 0, 0, 0]))
    Q = true.project(X)
    with pytest.raises(SolveError, match="acceptance rule: rms .* > threshold 0.3 px"):
        match_markers(Q, (ids, X), BASE, search_radius=40, max_rms=0.3)
    # the same through the stated marker accuracy: markers claimed good to 0.2 px cannot
    # leave 1 px residuals (the option reaches the verifying pose solves)
    with pytest.raises(SolveError, match="marker accuracy 0.2 px"):
        match_markers(Q, (ids, X), BASE, search_radius=40, marker_accuracy=0.2)


def test_too_few_candidates_and_bad_input():
    rng = np.random.default_rng(5)
    ids, X = _model(rng)
    with pytest.raises(SolveError, match="candidate"):
        match_markers(np.zeros((2, 2)), (ids, X), BASE)
    # only spurious candidates: no hypothesis explains enough markers
    Q = np.column_stack([rng.uniform(0, 1000, 40), rng.uniform(0, 750, 40)])
    with pytest.raises(SolveError):
        match_markers(Q, (ids, X), BASE)
    with pytest.raises(InputError, match="candidates"):
        match_markers(np.array([[1.0, np.nan], [2, 3], [4, 5]]), (ids, X), BASE)
    with pytest.raises(InputError, match="markers3d"):
        match_markers(np.zeros((5, 2)), (ids[:3], X), BASE)
    with pytest.raises(InputError, match="reference"):
        match_markers(np.zeros((5, 2)), (ids, X), "previous")
    with pytest.raises(InputError, match="search_radius"):
        match_markers(np.zeros((5, 2)), (ids, X), BASE, search_radius=-1)
    with pytest.raises(InputError, match="markers3d"):
        match_markers(np.zeros((5, 2)), None, BASE)
    Q, truth, cam = _frame(rng, ids, X)
    ref = match_markers(Q, (ids, X), BASE)
    with pytest.raises(InputError, match="not in markers3d: ZM"):
        match_markers(Q, (ids, X), (tuple("Z" + k for k in ref.marker_ids), ref.uv),
                      camera=BASE)
    with pytest.raises(InputError, match="camera"):
        match_markers(Q, (ids, X), ref, camera="approx.json")
    with pytest.raises(InputError, match="ids but"):
        match_markers(Q, (ids, X), (ref.marker_ids, ref.uv[:-1]))
    with pytest.raises(InputError, match="max_rms"):
        match_markers(Q, (ids, X), ref, max_rms=float("nan"))


def test_result_fields():
    rng = np.random.default_rng(6)
    ids, X = _model(rng)
    Q, truth, cam = _frame(rng, ids, X, missing=0.0, spurious=0.5)
    res = match_markers(Q, (ids, X), BASE)
    assert isinstance(res, MatchResult)
    assert len(res) == sum(t is not None for t in truth)
    assert np.allclose(res.uv, Q[res.candidate_index])
    assert [res.ids[i] for i in res.candidate_index] == list(res.marker_ids)
    assert res.residuals.shape == (len(res), 2)
    assert res.rms == pytest.approx(np.sqrt(np.mean(np.sum(res.residuals**2, 1))))


@pytest.mark.slow
def test_1000_frames_more_spurious_slow():
    # heavier variant: 1000 frames, 40 % hidden, twice as many spurious candidates as real
    rng = np.random.default_rng(11)
    ids, X = _model(rng, 40)
    n_ok = 0
    for _ in range(1000):
        Q, truth, cam = _frame(rng, ids, X, missing=0.4, spurious=2.0)
        res = match_markers(Q, (ids, X), BASE)
        n_ok += np.array_equal(np.array(res.ids, dtype=object), truth)
    assert n_ok == 1000


def test_pose_options_reach_the_verifying_solve():
    # pose_kw goes through to solve_pose: its refusals, checks and options are seen here
    rng = np.random.default_rng(7)
    ids, X = _model(rng)
    Q, truth, cam = _frame(rng, ids, X)
    plain = match_markers(Q, (ids, X), BASE)
    same = match_markers(Q, (ids, X), BASE, pose_kw={"ambiguity_px": 0.5})  # the default
    assert same.ids == plain.ids and same.rms == pytest.approx(plain.rms, abs=1e-12)
    with pytest.raises(SolveError, match="max_rms"):
        match_markers(Q, (ids, X), BASE, pose_kw={"max_rms": 0.2 * plain.rms})
    with pytest.raises(InputError, match="ambiguity_px"):
        match_markers(Q, (ids, X), BASE, pose_kw={"ambiguity_px": -1.0})
    res = match_markers(Q, (ids, X), BASE, pose_kw={"refine_intrinsics": "focal"})
    assert "refined" in res.pose.message and res.pose.camera.K[0, 0] != BASE.K[0, 0]
    assert np.array_equal(np.array(res.ids, dtype=object), truth)
    with pytest.raises(InputError, match="bogus"):
        match_markers(Q, (ids, X), BASE, pose_kw={"bogus": 1})
    with pytest.raises(InputError, match="pose_kw"):
        match_markers(Q, (ids, X), BASE, pose_kw=["ambiguity_px"])
