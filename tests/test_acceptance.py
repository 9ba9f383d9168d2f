"""The acceptance rule (resection.pose.acceptance): its threshold against Monte Carlo draws of
markers of the stated accuracy, and the cases of issue 12: a correct camera whose targets
are surveyed to about 1 px is accepted end to end (``pose --image``), swapped and mirrored
point sets are refused by ``pose --points`` (exit 2, nothing written)."""
import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resection import Camera, write_markers, write_points
from resection.cli.main import main
from resection.errors import InputError, SolveError
from resection.io.cameras import read_camera, write_camera
from resection.io.images import write_image
from resection.pose.acceptance import judge, outlier_gate, outlier_limit, rms_threshold
from resection.pose.solve import solve_pose
from scenes.marker_images import render_markers

W, H = 1024, 800
K = np.array([[2000.0, 0, 511.5], [0, 2000.0, 399.5], [0, 0, 1.0]])


def _plate(rng, n=15):
    """Markers on a plate, four of them on a block's top (as in the issue)."""
    X = np.column_stack([rng.uniform(-0.22, 0.22, n), rng.uniform(-0.16, 0.16, n),
                         np.zeros(n)])
    X[:4, 2] = 0.06
    return X


def _truth():
    return Camera.look_at([0.3, -1.0, 1.3], [0, 0, 0.02], [0, 0, 1], K=K, width=W,
                          height=H)


# ------------------------------------------------------------------ the rule itself
def test_threshold_passes_markers_of_the_stated_accuracy_at_its_confidence():
    """Independent check of the chi-square bound: errors drawn as isotropic Gaussian
    noise with an RMS length of exactly the stated accuracy (1.3 px) are refused about
    once in a thousand (binomial limits), and twice worse markers almost always."""
    rng = np.random.default_rng(1)
    n, trials, a = 15, 4000, 1.3
    e = np.hypot(*rng.normal(scale=a / math.sqrt(2), size=(2, trials, n)))
    refused = sum(not judge(row, 0, a, None).accepted for row in e)
    assert refused <= 15  # expected 4; P(>15) < 1e-5
    worse = sum(not judge(2.0 * row, 0, a, None).accepted for row in e[:400])
    assert worse >= 0.95 * 400  # power about 0.98
    # the threshold is the closed form a sqrt(chi2_q(dof) / 2n), capped by max_rms
    assert rms_threshold(15, 6, 1.0, None) == pytest.approx(math.sqrt(51.179 / 30), rel=1e-4)
    assert rms_threshold(15, 6, 5.0, 2.0) == 2.0
    assert rms_threshold(3, 6, 1.0, None) == math.inf


def test_outlier_gate_and_limit():
    # Rayleigh law: P(one of n exceeds g) = 1 - (1 - exp(-g^2 / 2 s^2))^n ~ 1e-3
    s = 1.0 / math.sqrt(2)
    g = outlier_gate(15, 1.0)
    assert 1 - (1 - math.exp(-g**2 / (2 * s * s))) ** 15 == pytest.approx(1e-3, rel=1e-2)
    assert outlier_limit(15) == 3 and outlier_limit(6) == 1 and outlier_limit(5) == 0
    with pytest.raises(InputError, match="marker_accuracy must be positive"):
        judge([1.0, 1.0], 0, marker_accuracy=-1)


def test_gross_outliers_named_dropped_and_limited():
    rng = np.random.default_rng(2)
    truth = _truth()
    X = _plate(rng, 15)
    ids = [f"T{i}" for i in range(15)]
    uv = truth.project(X) + rng.normal(scale=0.2, size=(15, 2))
    bad = uv.copy()
    bad[[3, 9]] += [[12.0, -7.0], [-9.0, 6.0]]
    res = solve_pose(truth, X, bad, ids=ids)
    assert set(res.acceptance.outliers) == {"T3", "T9"}
    assert res.used.sum() == 13 and not res.used[3] and not res.used[9]
    assert res.errors[3] > 10 and res.errors[9] > 8  # reported, not hidden
    assert res.acceptance.accepted and res.acceptance.statistic < 0.5
    # the pose is OpenCV's on the 13 clean markers
    keep = res.used
    _, rv, tv = cv2.solvePnP(X[keep], uv[keep], K, np.zeros(5), flags=cv2.SOLVEPNP_ITERATIVE)
    np.testing.assert_allclose(res.camera.rvec, rv.ravel(), atol=1e-6)
    np.testing.assert_allclose(res.camera.t, tv.ravel(), atol=1e-6)
    # four gross outliers out of 15 exceed the limit (3): refused, and named
    worse = bad.copy()
    worse[[0, 5]] += [[8.0, 8.0], [-10.0, 4.0]]
    with pytest.raises(SolveError, match="gross outlier.*at most 3 of 15"):
        solve_pose(truth, X, worse, ids=ids)


# ------------------------------------------------------------------ issue 12's cases
def _points_case(tmp_path):
    rng = np.random.default_rng(5)
    truth = _truth()
    X = _plate(rng)
    ids = [f"P{i:02d}" for i in range(len(X))]
    uv = truth.project(X) + rng.normal(scale=0.1, size=X.shape[:1] + (2,))
    assert np.all(uv.max(axis=0) < H)  # swapped u, v stay inside the image
    write_camera(tmp_path / "cam.json", truth.replace(R=np.eye(3), t=np.zeros(3)))
    return truth, X, ids, uv


@pytest.mark.parametrize("case", ["swapped", "mirrored"])
def test_swapped_or_mirrored_points_are_refused(tmp_path, capsys, case):
    truth, X, ids, uv = _points_case(tmp_path)
    if case == "swapped":  # u and v exchanged in the points file
        Xc, uvc = X, uv[:, ::-1]
    else:  # markers mirrored through the camera centre: behind it, same lines of sight
        Xc, uvc = 2.0 * truth.center - X, uv
    write_markers(tmp_path / "m.csv", ids, Xc)
    write_points(tmp_path / "p.csv", ids, uvc)
    argv = ["pose", "--camera", str(tmp_path / "cam.json"), "--markers",
            str(tmp_path / "m.csv"), "--points", str(tmp_path / "p.csv"), "--out",
            str(tmp_path / "out.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "refused by the acceptance rule" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "out.json").exists()
    # the same data with the pairing right is accepted, the statistic reported
    write_markers(tmp_path / "m.csv", ids, X)
    write_points(tmp_path / "p.csv", ids, uv)
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "accepted: rms" in out and "threshold 1.31 px" in out


@pytest.mark.slow  # 12-18 s; the acceptance rule's other tests stay in the default run
def test_camera5_case_accepted_end_to_end(tmp_path, capsys):
    """Issue 12's camera 5, synthetic: 15 targets whose surveyed coordinates are off by
    about 1 px as imaged, a start 0.4 degree and 2 % of the distance off; ``pose
    --image`` with default options matches, accepts and reports the statistic."""
    rng = np.random.default_rng(11)
    truth = _truth()
    X = _plate(rng)
    ids = [f"T{i:02d}" for i in range(15)]
    z = truth.to_camera_frame(X)[:, 2]
    # survey error: 3-D offsets across the lines of sight whose image displacement has an
    # RMS length of 1.13 px (what uPSP left on camera 5's targets)
    d = rng.normal(size=(15, 2))
    d *= 1.13 / np.sqrt(np.mean(np.sum(d**2, axis=1)))
    lateral = np.column_stack([d * (z / K[0, 0])[:, None], np.zeros(15)])
    survey = X + lateral @ truth.R  # camera-frame offsets to model axes
    shift = np.hypot(*(truth.project(survey) - truth.project(X)).T)
    assert np.sqrt(np.mean(shift**2)) == pytest.approx(1.13, rel=0.02)
    diam = 0.004  # ~7 px as imaged
    img = render_markers((H, W), truth.project(X), K[0, 0] * diam / z, contrast=80.0,
                         background=600.0, snr=40, rng=rng)
    write_image(tmp_path / "frame.tif", img.astype(np.uint16))
    write_markers(tmp_path / "m.csv", ids, survey, np.full(15, diam))
    dist = np.linalg.norm(truth.center)
    Rs = Rotation.from_rotvec(np.radians(0.4) * np.array([0.6, 0.0, 0.8])).as_matrix()
    start_center = truth.center + 0.02 * dist * np.array([0.6, -0.64, 0.48])
    R0 = Rs @ truth.R
    start = truth.replace(R=R0, t=-R0 @ start_center)
    write_camera(tmp_path / "start.json", start)
    rc = main(["pose", "--camera", str(tmp_path / "start.json"), "--markers",
               str(tmp_path / "m.csv"), "--image", str(tmp_path / "frame.tif"),
               "--out", str(tmp_path / "out.json")])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "15 markers linked" in out.out
    line = [ln for ln in out.out.splitlines() if ln.startswith("pose:")][0]
    stat = float(line.split("accepted: rms ")[1].split()[0])
    assert 0.7 < stat < 1.4  # the residuals are the survey error, not a wrong match
    cam = read_camera(tmp_path / "out.json")
    # the reference: OpenCV's pose from the surveyed targets at their true image positions
    # (the best that these targets allow); detection noise (snr 40) moves it only a little
    _, rv, tv = cv2.solvePnP(survey, truth.project(X), K, np.zeros(5),
                             flags=cv2.SOLVEPNP_ITERATIVE)
    ref = truth.replace(R=Rotation.from_rotvec(rv.ravel()).as_matrix(), t=tv.ravel())
    assert np.linalg.norm(cam.center - ref.center) < 1e-3 * dist
    assert np.degrees(Rotation.from_matrix(cam.R @ ref.R.T).magnitude()) < 0.02  # 0.006 measured


def test_track_judges_every_frame_with_the_same_option(tmp_path, capsys):
    """``resection track --marker-accuracy`` reaches each frame's pose and the matcher's
    verifying solves: markers claimed good to 0.001 px cannot leave the frames' few
    hundredths of a pixel, every frame fails with the rule's statistic in its reason."""
    from resection.sequence import read_track
    from scenes.moving_model import pitch_oscillation, write_sequence

    files = write_sequence(pitch_oscillation(3), tmp_path / "frames")
    base = ["track", *files["frames"], "--camera", files["camera"], "--markers",
            files["markers"], "--diameter", "5.6", "--no-progress", "--workers", "1"]
    assert main([*base, "--out", str(tmp_path / "ok")]) == 0
    good = read_track(tmp_path / "ok")
    assert (good.status == "ok").all() and np.nanmax(good.rms) < 0.1
    assert main([*base, "--out", str(tmp_path / "strict"), "--marker-accuracy", "0.001"]) == 1
    back = read_track(tmp_path / "strict")
    assert (back.status == "failed").all()
    assert all("acceptance rule" in r and "marker accuracy 0.001 px" in r
               for r in back.reason), back.reason


def test_calibrate_is_judged_by_the_same_rule():
    """Four views of an 11 x 8 board with 0.1 px noise: accepted at the default accuracy
    with ``2 N - 6 V - p`` degrees of freedom; refused when the markers are claimed good
    to 0.05 px, or when two board points are exchanged in one view."""
    from resection import calibrate

    K0 = np.array([[1150.0, 0, 640.0], [0, 1150.0, 480.0], [0, 0, 1.0]])
    gx, gy = np.meshgrid(np.arange(11) * 0.03, np.arange(8) * 0.03)
    board = np.column_stack([gx.ravel() - 0.15, gy.ravel() - 0.105, np.zeros(88)])
    rng = np.random.default_rng(4)
    views = []
    for eye in ([0.2, -0.15, -0.6], [-0.25, 0.1, -0.55], [0.05, 0.3, -0.6],
                [-0.1, -0.3, -0.5]):
        cam = Camera.look_at(eye, [0, 0, 0], [0, -1, 0.3], K=K0, width=1280, height=960,
                             dist=[-0.2, 0.08, 0, 0, 0])
        views.append((board, cam.project(board) + rng.normal(scale=0.1, size=(88, 2))))
    res = calibrate(views, (1280, 960), fix=("k3",))
    acc = res.acceptance
    assert acc.accepted and acc.what == "calibration"
    assert acc.dof == 2 * 4 * 88 - 6 * 4 - len(res.parameters)
    assert acc.statistic == pytest.approx(res.rms) and "accepted: rms" in res.message
    with pytest.raises(SolveError, match="calibrate: refused by the acceptance rule.*"
                                         "marker accuracy 0.05 px"):
        calibrate(views, (1280, 960), fix=("k3",), marker_accuracy=0.05)
    # two board points exchanged in one view: both named, dropped, the rest accepted and
    # the intrinsics those of OpenCV's calibration without them
    swapped = views[2][1].copy()
    swapped[[12, 13]] = swapped[[13, 12]]
    bad = [*views[:2], (board, swapped), views[3]]
    ids = [[f"B{i}" for i in range(88)]] * 4
    res2 = calibrate(bad, (1280, 960), fix=("k3",), ids=ids)
    assert set(res2.acceptance.outliers) == {"2:B12", "2:B13"}
    assert res2.used[2].sum() == 86 and all(u.all() for k, u in enumerate(res2.used) if k != 2)
    assert np.hypot(*res2.residuals[2][12]) > 20  # reported for every marker
    keep = np.ones(88, bool)
    keep[[12, 13]] = False
    obj = [board.astype(np.float32)] * 2 + [board[keep].astype(np.float32), board.astype(
        np.float32)]
    img = [v[1].astype(np.float32) for v in views[:2]] + [
        swapped[keep].astype(np.float32), views[3][1].astype(np.float32)]
    _, Kcv, dcv, _, _ = cv2.calibrateCamera(
        obj, img, (1280, 960), K0.copy(), np.zeros(5),
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 200, 1e-12))
    np.testing.assert_allclose(res2.camera.K, Kcv, rtol=0, atol=1e-3)


def test_commands_share_the_option(tmp_path, capsys):
    """``--marker-accuracy`` has the same name and meaning in pose and calibrate: markers
    claimed good to 0.02 px cannot leave 0.1 px of noise: exit 2, one line with the rule's
    statistic and threshold, nothing written."""
    rng = np.random.default_rng(6)
    truth = _truth()
    X = _plate(rng)
    ids = [f"Q{i}" for i in range(len(X))]
    uv = truth.project(X) + rng.normal(scale=0.1, size=(len(X), 2))
    write_markers(tmp_path / "m.csv", ids, X)
    write_points(tmp_path / "p.csv", ids, uv)
    write_camera(tmp_path / "cam.json", truth.replace(R=np.eye(3), t=np.zeros(3)))
    pose = ["pose", "--camera", str(tmp_path / "cam.json"), "--markers",
            str(tmp_path / "m.csv"), "--points", str(tmp_path / "p.csv")]
    cal = ["calibrate", "--markers", str(tmp_path / "m.csv"), "--points",
           str(tmp_path / "p.csv"), "--size", f"{W}x{H}", "--camera", str(tmp_path / "cam.json"),
           "--fix", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "aspect"]
    for argv in (pose, cal):
        assert main([*argv, "--out", str(tmp_path / "ok.json")]) == 0
        capsys.readouterr()
        rc = main([*argv, "--out", str(tmp_path / "no.json"), "--marker-accuracy", "0.02"])
        err = capsys.readouterr().err
        assert rc == 2 and "refused by the acceptance rule" in err, err
        assert "marker accuracy 0.02 px" in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "no.json").exists()


def test_track_frame_keeps_only_the_markers_the_rule_used():
    """A tracked frame whose pose drops a gross outlier records the markers used only
    (ids, positions and residuals agree), the outlier's 9 px no part of its RMS."""
    from resection.sequence.process import Setup, _solve

    rng = np.random.default_rng(8)
    truth = _truth()
    X = _plate(rng)
    ids = np.array([f"S{i}" for i in range(len(X))])
    uv = truth.project(X) + rng.normal(scale=0.1, size=(len(X), 2))
    uv[6] += [7.0, 5.5]
    setup = Setup(camera=truth, ids=ids, points3d=X, diameter=6.0, polarity="dark",
                   detect_kw={}, match_kw={}, pose_kw={}, min_markers=4)
    fr = _solve(ids, uv, setup, frame=0, file="f0")
    assert "S6" not in fr.ids and len(fr.ids) == len(fr.uv) == len(fr.residuals) == 14
    assert fr.rms < 0.3
    np.testing.assert_allclose(fr.uv, np.delete(uv, 6, axis=0))
