"""Camera files (uPSP JSON, OpenCV FileStorage YAML/XML, native JSON): one reader, checked
against OpenCV's own FileStorage and projectPoints (independent references)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from resection import Camera, InputError
from resection.cli.main import main as resection_main
from resection.io.cameras import read_camera, read_camera_file, write_camera

W, H = 1280, 800
K = np.array([[1630.5, 0.0, 652.25], [0.0, 1628.75, 391.5], [0.0, 0.0, 1.0]])
DIST = np.array([-0.12, 0.05, 0.0008, -0.0004, 0.01])
RVEC = np.array([0.3, -0.2, 0.1])
TVEC = np.array([0.1, -0.05, 2.5])


def _camera() -> Camera:
    return Camera.from_opencv(K, DIST, RVEC, TVEC, W, H)


def _upsp_dict(with_pose=True) -> dict:
    """A uPSP camera-to-tunnel file, built as uPSP documents it (not with our writer)."""
    Ku = K.copy()
    Ku[0, 2] -= W / 2  # principal point relative to the image centre
    Ku[1, 2] -= H / 2
    d = {"uPSP_cameraMatrix": Ku.tolist(), "distCoeffs": [DIST.tolist()],
         "sensor_resolution": [H, W, 1], "sensor_size": [1.0, 0.625]}
    if with_pose:
        d["rmat"] = cv2.Rodrigues(RVEC)[0].tolist()
        d["tvec"] = TVEC.tolist()
    return d


def test_upsp_file_projects_as_opencv(tmp_path):
    p = tmp_path / "camera01.json"
    p.write_text(json.dumps(_upsp_dict()))
    cam = read_camera(p)  # the ordinary reader recognises uPSP by its keys
    assert (cam.width, cam.height) == (W, H)
    X = np.random.default_rng(0).uniform(-0.4, 0.4, (50, 3))
    ref, _ = cv2.projectPoints(X, RVEC, TVEC, K, DIST)
    np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), atol=1e-6, rtol=0)


def test_upsp_round_trip_exact(tmp_path):
    src = tmp_path / "in.json"
    src.write_text(json.dumps(_upsp_dict()))
    cf = read_camera_file(src)
    assert cf.format == "upsp" and cf.has_pose and cf.sensor_size == (1.0, 0.625)
    out = tmp_path / "out.json"
    write_camera(out, cf.camera, format="upsp", sensor_size=cf.sensor_size,
                 channels=cf.channels)
    a, b = json.loads(src.read_text()), json.loads(out.read_text())
    assert set(a) == set(b)
    for k in a:
        np.testing.assert_allclose(np.array(b[k], float), np.array(a[k], float),
                                   rtol=1e-15, atol=1e-12, err_msg=k)
    assert read_camera(out) == cf.camera


def test_upsp_internal_calibration(tmp_path):
    p = tmp_path / "incal.json"
    p.write_text(json.dumps(_upsp_dict(with_pose=False)))
    cf = read_camera_file(p)
    assert not cf.has_pose
    np.testing.assert_allclose(cf.camera.K, K, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(cf.camera.R, np.eye(3))


@pytest.mark.parametrize("ext", ["yml", "xml"])
def test_opencv_filestorage_written_by_opencv(tmp_path, ext):
    p = str(tmp_path / f"cam.{ext}")
    fs = cv2.FileStorage(p, cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", DIST.reshape(1, 5))
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    cf = read_camera_file(p)
    assert cf.format == f"opencv-{'yaml' if ext == 'yml' else 'xml'}" and not cf.has_pose
    np.testing.assert_array_equal(cf.camera.K, K)
    np.testing.assert_array_equal(cf.camera.dist, DIST)
    assert (cf.camera.width, cf.camera.height) == (W, H)


@pytest.mark.parametrize("ext", ["yml", "xml"])
def test_opencv_filestorage_read_by_opencv(tmp_path, ext):
    cam = _camera()
    p = tmp_path / f"cam.{ext}"
    write_camera(p, cam)  # the extension picks OpenCV's FileStorage
    fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    np.testing.assert_array_equal(fs.getNode("camera_matrix").mat(), cam.K)
    np.testing.assert_array_equal(fs.getNode("distortion_coefficients").mat().ravel(), cam.dist)
    np.testing.assert_allclose(fs.getNode("rvec").mat().ravel(), RVEC, atol=1e-12)
    assert int(fs.getNode("image_width").real()) == W
    fs.release()
    back = read_camera(p)
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-14)
    np.testing.assert_array_equal(back.t, cam.t)


def test_convert_camera_cli(tmp_path, capsys):
    src = tmp_path / "cam.json"
    write_camera(src, _camera())
    out = tmp_path / "cam_upsp.json"
    assert resection_main(["convert-camera", str(src), "--out", str(out), "--format",
                           "upsp"]) == 0
    d = json.loads(out.read_text())
    np.testing.assert_allclose(d["uPSP_cameraMatrix"][0][2], K[0, 2] - W / 2, atol=1e-12)
    assert d["sensor_resolution"][:2] == [H, W]
    assert resection_main(["convert-camera", str(src), "--out", str(src)]) == 2
    assert "overwrite" in capsys.readouterr().err


@pytest.mark.parametrize(
    "change, match",
    [
        ({"distCoefs": [DIST.tolist()]}, r"unknown key 'distCoefs' \(did you mean 'distCoeffs'"),
        ({"sensor_resolution": None}, r"no key 'sensor_resolution' and no image"),
        ({"distCoeffs": [[0.1, 0.2]]}, "distCoeffs"),
        ({"tvec": ["0.1", 0, 2]}, "not a number"),
        ({"rmat": None}, "rmat"),
    ],
)
def test_upsp_bad_content(tmp_path, change, match):
    d = _upsp_dict()
    d.update(change)
    d = {k: v for k, v in d.items() if v is not None}
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=match) as err:
        read_camera(p)
    assert str(p) in str(err.value)


def test_bad_camera_files(tmp_path):
    good = tmp_path / "c.yml"
    write_camera(good, _camera())
    text = good.read_text()
    cases = {
        "trunc.yml": text[: len(text) // 2],  # cut inside a matrix
        "unknown.yml": text + "focus_mm: 3\n",
        "trunc.json": json.dumps(_upsp_dict())[:-20],
        "empty.json": "",
        "trunc.xml": '<?xml version="1.0"?>\n<opencv_storage>\n<camera_matrix type_id=',
    }
    for name, body in cases.items():
        p = tmp_path / name
        p.write_text(body)
        with pytest.raises(InputError) as err:
            read_camera(p)
        msg = str(err.value)
        assert msg.startswith(str(p)) and "\n" not in msg, (name, msg)


def _model_dict(with_pose=True) -> dict:
    """A uPSP camera-to-model file (camNN-to-model.json) as upsp-external-calibration writes
    it: absolute principal point, flat distCoeffs, imageSize [w, h] (not our writer)."""
    d = {"cameraMatrix": K.tolist(), "distCoeffs": DIST.tolist(), "imageSize": [W, H]}
    if with_pose:
        d["rmat"] = cv2.Rodrigues(RVEC)[0].tolist()
        d["tvec"] = [[v] for v in TVEC]  # a 3x1 column, as cv2 gives it
    d["Updated"] = "2021-03-04 10:11:12"
    return d


def test_upsp_camera_to_model_read_everywhere(tmp_path):
    p = tmp_path / "cam01-to-model.json"
    p.write_text(json.dumps(_model_dict()))
    cf = read_camera_file(p)
    assert cf.format == "upsp-model" and cf.has_pose and cf.extra == {
        "Updated": "2021-03-04 10:11:12"}
    cam = read_camera(p)  # what every command calls
    assert (cam.width, cam.height) == (W, H)
    X = np.random.default_rng(1).uniform(-0.4, 0.4, (50, 3))
    ref, _ = cv2.projectPoints(X, RVEC, TVEC, K, DIST)
    np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), atol=1e-6, rtol=0)


def test_convert_camera_writes_camera_to_model(tmp_path):
    src = tmp_path / "cam.json"
    write_camera(src, _camera())
    out = tmp_path / "cam01-to-model.json"
    assert resection_main(["convert-camera", str(src), "--out", str(out), "--format",
                           "upsp-model"]) == 0
    d = json.loads(out.read_text())
    assert set(d) == {"cameraMatrix", "distCoeffs", "imageSize", "rmat", "tvec"}
    assert d["imageSize"] == [W, H] and len(d["distCoeffs"]) == 5
    np.testing.assert_allclose(d["cameraMatrix"], K, rtol=0, atol=1e-12)  # absolute
    np.testing.assert_allclose(d["rmat"], cv2.Rodrigues(RVEC)[0], atol=1e-14)
    np.testing.assert_allclose(d["tvec"], TVEC, atol=1e-14)


@pytest.mark.parametrize("fmt, make", [("upsp", _upsp_dict), ("upsp-model", _model_dict)])
def test_upsp_unknown_keys_kept_on_round_trip(tmp_path, fmt, make):
    d = make()
    d["Updated"] = "03/04/2021"
    d["tunnel"] = {"name": "11-ft TWT", "run": 412}
    src = tmp_path / "in.json"
    src.write_text(json.dumps(d))
    out = tmp_path / "out.json"
    assert resection_main(["convert-camera", str(src), "--out", str(out), "--format",
                           fmt]) == 0
    back = json.loads(out.read_text())
    assert back["Updated"] == "03/04/2021"
    assert back["tunnel"] == {"name": "11-ft TWT", "run": 412}
    assert set(back) == set(d)


@pytest.mark.parametrize("fmt, make, key", [("upsp", _upsp_dict, "sensor_resolution"),
                                             ("upsp-model", _model_dict, "imageSize")])
def test_upsp_image_size_optional(tmp_path, fmt, make, key, capsys):
    d = make()
    del d[key]
    p = tmp_path / "nosize.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=f"no key '{key}'") as err:
        read_camera(p)
    assert str(err.value).startswith(str(p))
    cf = read_camera_file(p, image_size=(W, H))  # the size comes from the image
    assert not cf.size_from_file
    X = np.random.default_rng(2).uniform(-0.4, 0.4, (20, 3))
    ref, _ = cv2.projectPoints(X, RVEC, TVEC, K, DIST)
    np.testing.assert_allclose(cf.camera.project(X), ref.reshape(-1, 2), atol=1e-6, rtol=0)
    img = tmp_path / "frame.npy"
    np.save(img, np.zeros((H, W), np.float32))
    out = tmp_path / "native.json"
    assert resection_main(["convert-camera", str(p), "--image", str(img), "--out",
                           str(out)]) == 0
    assert read_camera(out) == cf.camera
    assert resection_main(["convert-camera", str(p), "--out", str(tmp_path / "x.json")]) == 2
    assert key in capsys.readouterr().err


def _opencv_reach(dist, Kmat) -> float:
    """The largest distorted normalised radius OpenCV's projection reaches along the image's
    diagonal before it folds back (points out to 20 normalised units)."""
    r = np.linspace(0.0, 20.0, 200_001)
    d = np.array([W, H], float) / np.hypot(W, H)
    pts = np.column_stack([r * d[0], r * d[1], np.ones_like(r)])
    with np.errstate(all="ignore"):
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), np.eye(3), np.asarray(dist))
        rd = np.hypot(*uv.reshape(-1, 2).T)
    ok = np.isfinite(rd)
    grow = np.flatnonzero(ok[1:] & (np.diff(np.where(ok, rd, 0.0)) <= 0))
    end = grow[0] + 1 if grow.size else len(rd)
    return float(rd[:end].max())


@pytest.mark.parametrize("dist, refused", [
    ([1e300, 0, 0, 0, 0], True),  # issue 34: accepted
    ([0, 0, 0, 0, -1e300], True),
    ([0, 0, 1e300, 0, 0], True),
    ([-0.5, 0, 0, 0, 0], True),  # folds back just inside the corners
    ([-0.09098491035825468, 0, 0, 0, 0], False),  # uPSP's camera 1
    ([-0.12, 0.03, 0.001, -0.0005, 0.0], False),
])
def test_convert_camera_refuses_a_distortion_that_is_no_lens(tmp_path, capsys, dist, refused):
    """Issue 34 item 19: distortion coefficients of 1e300 were converted. A lens whose
    polynomial folds back inside the image is refused, one line, exit 2; the fold is
    OpenCV's projection's, and real lenses pass."""
    from resection.camera.model import Camera

    Kmat = np.array([[0.55 * np.hypot(W, H), 0, (W - 1) / 2],
                     [0, 0.55 * np.hypot(W, H), (H - 1) / 2], [0, 0, 1.0]])
    cam = Camera(width=W, height=H, K=Kmat, dist=np.asarray(dist, float), R=np.eye(3),
                 t=np.array([0.0, 0.0, 5.0]))
    src = tmp_path / "cam.json"
    write_camera(src, cam)
    corner = np.hypot(W / 2, H / 2) / Kmat[0, 0]
    if dist[2] == 0:  # radial only: OpenCV's projection says it: the corner is not reached
        # before the fold, or a tenth of its radius is projected beyond it
        tenth, _ = cv2.projectPoints(np.array([[corner / 10, 0.0, 1.0]]), np.zeros(3),
                                     np.zeros(3), np.eye(3), np.asarray(dist, float))
        beyond = not np.abs(tenth[0, 0, 0]) <= corner
        assert (_opencv_reach(dist, Kmat) < corner or beyond) == refused
    rc = resection_main(["convert-camera", str(src), "--out", str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    if refused:
        assert rc == 2 and len(err.splitlines()) == 1 and "not a lens" in err
        assert str(src) in err and not (tmp_path / "o.json").exists()
    else:
        assert rc == 0, err
