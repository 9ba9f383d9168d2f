"""Tracking by prediction (``resection.sequence.predict``): the motion model against closed
forms, the batched projection and the pose solve against OpenCV, and the gated tracker
on sequences with a known motion (scenes.moving_model) where it must be right or refuse:
jumps and hidden markers go to the statistical matcher."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resection import Camera
from resection.io.cameras import read_camera
from resection.sequence import track
from resection.sequence.predict import predict_pose, project_poses, refine_pose
from resection.sequence.results import FrameResult
from scenes.moving_model import pitch_oscillation, write_sequence


def _camera():
    K = np.array([[900.0, 0.0, 511.5], [0.0, 905.0, 383.5], [0.0, 0.0, 1.0]])
    return Camera(1024, 768, K, dist=[-0.08, 0.02, 0.001, -0.0005, 0.0])


def _points(n=30, seed=0):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.15, 0.15, n),
                            rng.uniform(-0.05, 0.05, n)])


def test_predict_pose_is_exact_at_constant_velocity():
    """A rotation at a constant rate about a fixed axis and a constant translation rate:
    the extrapolation from frames 3 and 5 to frame 8 is the motion itself."""
    w = np.array([0.01, -0.02, 0.005])  # rad per frame
    R0 = Rotation.from_rotvec([0.3, -1.2, 0.4])
    t0, v = np.array([0.02, -0.01, 0.9]), np.array([1e-3, -2e-3, 5e-4])

    def frame(k):
        R = Rotation.from_rotvec(k * w) * R0
        return FrameResult(frame=k, file="", status="ok", rvec=R.as_rotvec(), tvec=t0 + k * v)

    rvec, tvec = predict_pose(frame(5), frame(3), 8)
    truth = frame(8)
    assert np.degrees((Rotation.from_rotvec(rvec) * Rotation.from_rotvec(truth.rvec).inv())
                      .magnitude()) < 1e-9
    np.testing.assert_allclose(tvec, truth.tvec, atol=1e-12)
    # one good frame only (the first frame of a chunk): held at its pose
    r1, t1 = predict_pose(frame(5), None, 8)
    np.testing.assert_allclose(r1, frame(5).rvec)
    np.testing.assert_allclose(t1, frame(5).tvec)


def test_project_poses_matches_opencv():
    cam, X = _camera(), _points()
    rng = np.random.default_rng(1)
    rv = rng.normal(scale=0.1, size=(4, 3))
    tv = np.column_stack([rng.normal(scale=0.02, size=(4, 2)), np.full(4, 1.0)])
    uv = project_poses(cam, rv, tv, X)
    K, dist, _, _ = cam.to_opencv()
    for k in range(4):
        ref, _ = cv2.projectPoints(X, rv[k], tv[k], K, dist)
        np.testing.assert_allclose(uv[k], ref.reshape(-1, 2), atol=1e-8)


def test_refine_pose_agrees_with_opencv_least_squares():
    """From a start 0.5 degree and 1 cm off, on noisy points: the least-squares pose is
    OpenCV's (solvePnP, then its Levenberg-Marquardt refinement to convergence)."""
    cam, X = _camera(), _points()
    rv_true, tv_true = np.array([0.1, -0.2, 0.05]), np.array([0.01, -0.02, 1.0])
    uv = project_poses(cam, rv_true, tv_true, X)[0]
    uv = uv + np.random.default_rng(2).normal(scale=0.05, size=uv.shape)
    start_r = (Rotation.from_rotvec([0.0, 0.0087, 0.0]) * Rotation.from_rotvec(rv_true))
    rv, tv, res = refine_pose(cam, start_r.as_rotvec(), tv_true + 0.01, X, uv)
    K, dist, _, _ = cam.to_opencv()
    ok, rv_cv, tv_cv = cv2.solvePnP(X, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    assert ok  # then OpenCV's LM refinement, run to convergence (its default stops early)
    rv_cv, tv_cv = cv2.solvePnPRefineLM(
        X, uv, K, dist, rv_cv, tv_cv,
        criteria=(cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-15))
    ang = (Rotation.from_rotvec(rv) * Rotation.from_rotvec(rv_cv.ravel()).inv()).magnitude()
    # both stop on their own step rules: 1.1e-6 degrees apart on one machine (1e-3 degrees
    # is the pose's own scatter from the 0.05 px noise), so 1e-5 degrees and 1e-7 m
    assert np.degrees(ang) < 1e-5
    np.testing.assert_allclose(tv, tv_cv.ravel(), atol=1e-7)
    # the residuals are the observed minus the reprojected positions
    np.testing.assert_allclose(res, uv - project_poses(cam, rv, tv, X)[0], atol=1e-12)
    assert 0.02 < np.sqrt(np.mean(np.sum(res**2, axis=1))) < 0.1


def _methods(out, n):
    return [json.load(open(out / "frames" / f"frame_{i:06d}.json"))["method"] for i in range(n)]


@pytest.fixture(scope="module")
def seq40(tmp_path_factory):
    base = tmp_path_factory.mktemp("pred40")
    model = pitch_oscillation(40)
    files = write_sequence(model, base / "frames")
    return model, files, read_camera(files["camera"])


def test_smooth_motion_is_tracked_by_prediction(seq40, tmp_path):
    """On a smooth run every frame after the first is tracked by prediction (no
    statistical matcher), as accurately as the matcher: attitude within 0.01 degree of
    the truth, every marker found within 0.02 px of its true projection (RMS)."""
    model, files, cam = seq40
    n = 40
    res = track(files["frames"], cam, files["markers"], diameter=5.6, out_dir=tmp_path / "o",
                workers=1, progress=False, chunk_size=20)
    assert res.ok.all()
    methods = _methods(tmp_path / "o", n)
    assert methods[0] == "matched" and set(methods[1:]) == {"predicted"}
    assert np.abs(res.angles - np.degrees(model.angles)).max() < 0.01
    truth = np.stack([model.uv(k) for k in range(n)])
    got = res.marker_positions(model.ids)
    assert np.isfinite(got).all()
    assert np.sqrt(np.mean(np.sum((got - truth) ** 2, axis=-1))) < 0.02


def test_a_jump_goes_to_the_matcher_and_is_right(tmp_path):
    """Frames out of order (a jump of 10 px between two frames, and back, with a model
    pitching 6 degrees): the prediction's gate fails there and on the next frame (whose
    constant-velocity prediction carries the jump on), the statistical matcher decides, and
    every frame is right, never matched wrong."""
    model = pitch_oscillation(40, amplitude_deg=6.0)
    files = write_sequence(model, tmp_path / "frames", frames=[*range(0, 14), 30, 31, 32])
    cam = read_camera(files["camera"])
    order = [*range(0, 8), 30, 31, 32, *range(8, 14)]
    paths = {int(Path(p).stem.split("_")[1]): p for p in files["frames"]}
    res = track([paths[i] for i in order], cam, files["markers"], diameter=5.6,
                out_dir=tmp_path / "o", workers=1, progress=False)
    assert np.abs(model.uv(30) - model.uv(7)).max() > 8.0  # the jump is real
    methods = _methods(tmp_path / "o", len(order))
    assert methods[8] == "matched" and methods[11] == "matched"  # 7 -> 30, 32 -> 8
    assert methods[10] == "predicted" and methods[13] == "predicted"
    assert res.ok.all(), res.reason
    assert np.abs(res.angles - np.degrees(model.angles[order])).max() < 0.01


def test_hidden_markers_go_to_the_matcher(seq40, tmp_path):
    """A frame where half of the markers are hidden (painted over with the background):
    fewer than 80 % of the predicted markers are found, the matcher decides, and the
    pose from the remaining markers is right."""
    model, files, cam = seq40
    frames = list(files["frames"][:12])
    img = np.load(frames[6])
    uv = model.uv(6)
    hide = np.arange(0, len(uv), 2)
    vv, uu = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    for u, v in uv[hide]:
        img[(uu - u) ** 2 + (vv - v) ** 2 <= 6.0**2] = model.background
    np.save(tmp_path / "f6.npy", img)
    frames[6] = str(tmp_path / "f6.npy")
    res = track(frames, cam, files["markers"], diameter=5.6, out_dir=tmp_path / "o",
                workers=1, progress=False)
    methods = _methods(tmp_path / "o", 12)
    assert methods[6] == "matched" and methods[7] == "predicted"
    if res.ok[6]:  # right or refused
        assert res.n_markers[6] <= len(uv) - len(hide)
        assert set(res.marker_id[res.marker_frame == 6]).isdisjoint(model.ids[hide])
    good = res.ok
    assert good.sum() >= 11
    assert np.abs(res.angles[good] - np.degrees(model.angles[:12][good])).max() < 0.01
