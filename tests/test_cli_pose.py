"""``resection pose`` and ``resection calibrate`` end to end on temporary files."""
import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from resection import Camera, write_markers, write_points
from resection.cli.main import main
from resection.io.cameras import read_camera, write_camera

W, H = 1280, 960
K = np.array([[1300.0, 0, 641.0], [0, 1300.0, 478.0], [0, 0, 1.0]])
DIST = np.array([-0.12, 0.03, 0.0004, -0.0002, 0.0])


@pytest.fixture
def scene(tmp_path):
    rng = np.random.default_rng(0)
    truth = Camera.look_at([0.6, -1.6, 0.9], [0, 0, 0], [0, 0, 1], K=K, width=W, height=H,
                           dist=DIST)
    X = rng.uniform(-0.3, 0.3, (14, 3))
    ids = [f"P{i:02d}" for i in range(14)]
    uv = truth.project(X) + rng.normal(scale=0.1, size=(14, 2))
    write_markers(tmp_path / "markers.csv", ids, X, np.full(14, 0.005))
    write_points(tmp_path / "points.csv", ids[::-1], uv[::-1])  # order does not matter
    write_camera(tmp_path / "cam.json", truth.replace(R=np.eye(3), t=np.zeros(3)))
    return tmp_path, truth, ids, X, uv


def test_pose_command(scene, capsys):
    d, truth, ids, X, uv = scene
    rc = main(["pose", "--camera", str(d / "cam.json"), "--markers", str(d / "markers.csv"),
               "--points", str(d / "points.csv"), "--out", str(d / "out.json"),
               "--residuals", str(d / "res.csv")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "rms" in out and all(i in out for i in ids)
    cam = read_camera(d / "out.json")
    assert np.linalg.norm(cam.center - truth.center) < 2e-3
    # independent check with OpenCV's solvePnP on the same data
    _, rv, tv = cv2.solvePnP(X, uv, K, DIST, flags=cv2.SOLVEPNP_ITERATIVE)
    np.testing.assert_allclose(cam.rvec, rv.ravel(), atol=1e-6)
    np.testing.assert_allclose(cam.t, tv.ravel(), atol=1e-6)
    rms_line = [ln for ln in out.splitlines() if ln.startswith("rms")][0]
    proj, _ = cv2.projectPoints(X, rv, tv, K, DIST)
    rms_cv = np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1)))
    assert float(rms_line.split()[1]) == pytest.approx(rms_cv, abs=1e-4)
    rows = (d / "res.csv").read_text().splitlines()
    assert len(rows) == 15 and rows[1].startswith("P13,")


def test_pose_command_ambiguity_px(scene, capsys):
    """Four coplanar markers measured to 0.002 px: refused by default (two degrees of
    freedom cannot prove that precision), solved right with --ambiguity-px 0.01."""
    d, truth, ids, _, _ = scene
    sq = 0.2 * np.array([[-0.2, -0.15, 0], [0.25, -0.1, 0], [0.15, 0.2, 0], [-0.1, 0.1, 0]])
    uv = truth.project(sq) + np.random.default_rng(3).normal(scale=0.002, size=(4, 2))
    write_markers(d / "sq.csv", ids[:4], sq)
    write_points(d / "sq_pts.csv", ids[:4], uv)
    argv = ["pose", "--camera", str(d / "cam.json"), "--markers", str(d / "sq.csv"),
            "--points", str(d / "sq_pts.csv"), "--out", str(d / "sq.json")]
    err = _err(capsys, argv)
    assert "ambiguous" in err and "ambiguity_px" in err
    assert main([*argv, "--ambiguity-px", "0.01"]) == 0
    cam = read_camera(d / "sq.json")
    assert np.linalg.norm(cam.center - truth.center) < 1e-3


def test_pose_command_options_and_console_script(scene):
    d, truth, *_ = scene
    proc = subprocess.run(
        [sys.executable, "-m", "resection.cli.main", "pose", "--camera", str(d / "cam.json"),
         "--markers", str(d / "markers.csv"), "--points", str(d / "points.csv"),
         "--out", str(d / "out2.json"), "--robust", "--refine-intrinsics"],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "refined f" in proc.stdout
    cam = read_camera(d / "out2.json")
    assert cam.K[0, 0] == pytest.approx(1300.0, rel=0.02)


def _err(capsys, argv):
    rc = main(argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1, err
    return err


def test_pose_command_bad_input(scene, capsys):
    d, *_ = scene
    base = ["pose", "--camera", str(d / "cam.json"), "--markers", str(d / "markers.csv"),
            "--points", str(d / "points.csv"), "--out", str(d / "o.json")]
    err = _err(capsys, [*base[:2], str(d / "nope.json"), *base[3:]])
    assert "not found" in err and "nope.json" in err
    (d / "bad.csv").write_text("id,x,y,z\nP00,1,2,3\nP01,1,,3\n")
    err = _err(capsys, [*base[:4], str(d / "bad.csv"), *base[5:]])
    assert "bad.csv:3" in err and "column y" in err
    (d / "few.csv").write_text("id,u,v\nP00,1,2\nP01,3,4\n")
    err = _err(capsys, [*base[:6], str(d / "few.csv"), *base[7:]])
    assert "at least 3" in err
    (d / "typo.csv").write_text("id,u,v\nP00,1,2\nQ01,3,4\nP02,5,6\n")
    err = _err(capsys, [*base[:6], str(d / "typo.csv"), *base[7:]])
    assert "Q01" in err
    cam = json.loads((d / "cam.json").read_text())
    cam["focal"] = 3
    (d / "cam2.json").write_text(json.dumps(cam))
    err = _err(capsys, [*base[:2], str(d / "cam2.json"), *base[3:]])
    assert "unknown key" in err and "focal" in err
    cam["width"], cam["height"] = 640, 480
    del cam["focal"]
    (d / "cam3.json").write_text(json.dumps(cam))
    err = _err(capsys, [*base[:2], str(d / "cam3.json"), *base[3:]])
    assert "outside the camera's 640x480 image" in err
    err = _err(capsys, [*base, "--ambiguity-px", "-1"])
    assert "ambiguity_px must be positive" in err
    err = _err(capsys, [*base, "--max-rms", "0.01"])
    assert "max_rms" in err


def test_calibrate_command(tmp_path, capsys):
    rng = np.random.default_rng(1)
    gx, gy = np.meshgrid(np.arange(10) * 0.03, np.arange(7) * 0.03)
    board = np.column_stack([gx.ravel() - 0.135, gy.ravel() - 0.09, np.zeros(70)])
    ids = [f"c{i}" for i in range(70)]
    write_markers(tmp_path / "board.csv", ids, board)
    paths, obj, img = [], [], []
    while len(paths) < 6:
        e = rng.normal(size=3)
        e[2] = -abs(e[2]) - 1.0
        cam = Camera.look_at(e / np.linalg.norm(e) * 0.55, [0, 0, 0], [0, -1, 0.3], K=K,
                             width=W, height=H, dist=DIST)
        uv, ok = cam.project(board, return_valid=True)
        if not (ok.all() and cam.in_image(uv, margin=3).all()):
            continue
        uv = uv + rng.normal(scale=0.1, size=uv.shape)
        p = tmp_path / "views" / f"view{len(paths)}.csv"
        p.parent.mkdir(exist_ok=True)
        write_points(p, ids, uv)
        paths.append(str(p))
        obj.append(board.astype(np.float32))
        img.append(uv.astype(np.float32))
    rc = main(["calibrate", "--markers", str(tmp_path / "board.csv"), "--points", *paths,
               "--size", f"{W}x{H}", "--fix", "k3", "--out", str(tmp_path / "cal.json"),
               "--residuals", str(tmp_path / "cal_res.csv")])
    assert rc == 0
    out = capsys.readouterr().out
    assert "view0.csv" in out and "fx" in out and "k1" in out
    cam = read_camera(tmp_path / "cal.json")
    rms_cv, Kc, dc, _, _ = cv2.calibrateCamera(obj, img, (W, H), None, None,
                                               flags=cv2.CALIB_FIX_K3)
    np.testing.assert_allclose(cam.K, Kc, atol=0.1)
    np.testing.assert_allclose(cam.dist, dc.ravel()[:5], atol=1e-3)
    table = np.genfromtxt(tmp_path / "cal_res.csv", delimiter=",", names=True, dtype=None,
                          encoding="utf-8")
    assert len(table) == 6 * 70 and set(table["view"]) == set(range(6))
    np.testing.assert_allclose(table["error"], np.hypot(table["du"], table["dv"]), atol=2e-6)
    rms_line = [ln for ln in out.splitlines() if ln.startswith("rms")][0]
    assert float(rms_line.split()[1]) == pytest.approx(
        np.sqrt(np.mean(table["error"] ** 2)), abs=1e-4)
    assert float(rms_line.split()[1]) == pytest.approx(rms_cv, abs=1e-4)
    # every marker's residual is printed too: view, id, du, dv, error
    rows = [ln.split() for ln in out.splitlines()
            if len(ln.split()) == 5 and ln.split()[1] in ids]
    assert len(rows) == 6 * 70
    printed = np.array([[float(x) for x in r[2:]] for r in rows])
    np.testing.assert_allclose(printed[:, 0], table["du"], atol=1e-4)
    np.testing.assert_allclose(printed[:, 2], table["error"], atol=1e-4)
    assert [int(r[0]) for r in rows] == list(table["view"])
    # the --views form gives the same answer
    rc = main(["calibrate", "--views", *[f"{tmp_path / 'board.csv'}:{p}" for p in paths],
               "--size", f"{W}x{H}", "--fix", "k3", "--out", str(tmp_path / "cal2.json")])
    assert rc == 0
    np.testing.assert_allclose(read_camera(tmp_path / "cal2.json").K, cam.K, atol=1e-6)
    # and so does a directory of points files
    rc = main(["calibrate", "--markers", str(tmp_path / "board.csv"), "--points-dir",
               str(tmp_path / "views"), "--size", f"{W}x{H}", "--fix", "k3", "--out",
               str(tmp_path / "cal3.json")])
    assert rc == 0
    np.testing.assert_allclose(read_camera(tmp_path / "cal3.json").K, cam.K, atol=1e-6)


def test_calibrate_command_bad_input(tmp_path, capsys):
    write_markers(tmp_path / "b.csv", ["a", "b", "c", "d"],
                  [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    write_points(tmp_path / "p.csv", ["a", "b", "c", "d"], [[1, 1], [9, 1], [1, 9], [9, 9]])
    base = ["calibrate", "--markers", str(tmp_path / "b.csv"), "--points",
            str(tmp_path / "p.csv"), "--out", str(tmp_path / "c.json")]
    err = _err(capsys, [*base, "--size", "1280by960"])
    assert "WxH" in err
    err = _err(capsys, [*base, "--size", "8x8"])
    assert "outside the 8x8 image" in err
    write_camera(tmp_path / "small.json", Camera(640, 480, K))
    err = _err(capsys, [*base, "--size", "1280x960", "--camera", str(tmp_path / "small.json")])
    assert "640x480" in err
    err = _err(capsys, [*base, "--size", "1280x960", "--fix", "k7"])
    assert "k7" in err
    err = _err(capsys, ["calibrate", "--size", "10x10", "--out", "x.json"])
    assert "no views" in err
    err = _err(capsys, ["calibrate", "--views", "onlyone.csv", "--size", "10x10", "--out",
                        "x.json"])
    assert "MARKERS.csv:POINTS.csv" in err
    err = _err(capsys, [*base, "--size", "1280x960"])
    assert "observations" in err
    err = _err(capsys, ["calibrate", "--markers", str(tmp_path / "b.csv"), "--points-dir",
                        str(tmp_path / "nodir"), "--size", "10x10", "--out", "x.json"])
    assert "not a directory" in err


def test_argument_errors_are_one_line(capsys):
    for argv, what in ((["pose", "--camera", "c.json"], "--markers, --out"),
                       (["calibrate", "--size"], "--size"),
                       (["pose", "--camera", "c", "--markers", "m", "--points", "p", "--out",
                         "o", "--robust", "tukey"], "tukey")):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and what in err and "error" in err, err
