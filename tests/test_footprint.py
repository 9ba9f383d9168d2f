"""The camera checked against the frame when no markers are given (issue 34 item 7): a
camera in mm on an inch (or m) grid mapped silently, the model a dot of a few thousand
pixels. The model's footprint is compared with the frame's lit part: a unit mismatch is
refused naming the units, a poor match warned. The footprint shares are checked against
OpenCV's projection of the grid (the convex hull of the projected nodes)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from resection.cli.main import main
from resection.io.cameras import write_camera
from resection.io.images import write_image
from scenes.real_traits import real_traits, write_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("footprint")
    sc = real_traits()
    return sc, write_scene(sc, d), d


def _hull_share(cam, X) -> float:
    """Share of the frame inside the convex hull of the nodes OpenCV projects (those in
    front of the camera, within the lens's monotonic radius)."""
    X = np.asarray(X, float)
    Xc = X @ cam.R.T + cam.t
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.hypot(Xc[:, 0], Xc[:, 1]) / Xc[:, 2]
    # in front, and inside the radius where the lens polynomial folds back (beyond it
    # OpenCV maps far points back into the image)
    X = X[(Xc[:, 2] > 0) & (r <= cam.max_radius)]
    K, dist, rvec, tvec = cam.to_opencv()
    uv, _ = cv2.projectPoints(X, rvec, tvec, K, dist)
    hull = cv2.convexHull(uv.reshape(-1, 1, 2).astype(np.float32))
    mask = np.zeros((cam.height, cam.width), np.uint8)
    cv2.fillConvexPoly(mask, np.rint(hull).astype(np.int32), 1)
    return float(mask.mean())


def _map(paths, d, camera, capsys, name):
    rc = main(["map", "--mesh", paths["grid"], "--camera", str(camera), "--image",
               paths["image0"], "--out", str(d / f"{name}.csv")])
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize("factor, reading", [
    (1000.0, r"scaled by 1000 \(the grid in m and the camera in mm\?\)"),
    (25.4, r"scaled by 25\.4 \(the grid in inch and the camera in mm\?\) or 39\.37"),
])
def test_a_camera_in_other_units_is_refused(scene, capsys, factor, reading):
    import re

    sc, paths, d = scene
    cam = sc.cameras[0]
    wrong = cam.with_pose(R=cam.R, t=cam.t * factor)  # its translation in smaller units
    write_camera(d / f"units{factor:g}.json", wrong)
    share = _hull_share(wrong, sc.mesh.vertices)
    assert share < 0.01  # the model a dot: what map wrote with exit 0
    rc, _, err = _map(paths, d, d / f"units{factor:g}.json", capsys, f"u{factor:g}")
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert re.search(reading, err), err
    m = re.search(r"footprint covers ([\d.]+)% of the frame", err)
    assert m and float(m.group(1)) == pytest.approx(100 * share, abs=0.6)
    assert not (d / f"u{factor:g}.csv").exists()


def test_the_right_camera_passes_and_a_far_off_pose_is_warned(scene, capsys):
    from scipy.spatial.transform import Rotation

    sc, paths, d = scene
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*footprint")
        rc, out, err = _map(paths, d, paths["camera0"], capsys, "right")
    assert rc == 0, err
    cam = sc.cameras[0]
    # turned 42 degrees about its own vertical axis: the plate covers a strip of the frame
    turn = Rotation.from_rotvec([0.0, np.radians(42.0), 0.0]).as_matrix()
    R = turn @ cam.R
    off = cam.with_pose(R=R, t=-R @ cam.center)
    share = _hull_share(off, sc.mesh.vertices)
    assert 0.01 < share < 0.3
    write_camera(d / "off.json", off)
    with pytest.warns(UserWarning, match=r"off\.json on .*cam0\.png: the model's footprint "
                      r"covers [\d.]+% of the frame .* the wrong camera file, or a pose far "
                      r"off\?"):
        rc, out, err = _map(paths, d, d / "off.json", capsys, "off")
    assert rc == 0


def test_upsps_camera_in_mm_on_the_inch_grid(upsp_samples, tmp_path, capsys):
    """The issue's case on NASA's grid (inches) and camera 1: a frame of the model as
    camera 1 sees it (lit paint, dark tunnel, 12 bit, speckle), mapped with the camera's
    translation written in mm."""
    from resection.io.cameras import read_camera
    from resection.io.meshes import load_mesh
    from resection.surface.surface_map import SurfaceMap

    grid = upsp_samples / "fml_tc3_volume.grid"
    cal = upsp_samples / "camera-tunnel-calibration" / "camera01_35_6.json"
    cam = read_camera(cal)
    mesh = load_mesh(grid)
    smap = SurfaceMap(mesh, cam)
    rng = np.random.default_rng(5)
    v, u = np.mgrid[0:cam.height, 0:cam.width]
    lamp = 2600.0 - 900.0 * ((u - 700) ** 2 + (v - 350) ** 2) / cam.width ** 2
    frame = np.where(smap.mask, lamp, 60.0) * rng.gamma(30.0, 1 / 30.0, lamp.shape)
    write_image(tmp_path / "frame.png", np.clip(np.rint(frame), 0, 4095).astype(np.uint16),
                dtype=np.uint16)
    mm = cam.with_pose(R=cam.R, t=cam.t * 25.4)
    write_camera(tmp_path / "mm.json", mm)
    rc = main(["map", "--mesh", str(grid), "--camera", str(tmp_path / "mm.json"), "--image",
               str(tmp_path / "frame.png"), "--out", str(tmp_path / "o.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "scaled by 25.4 (the grid in inch and the camera in mm?)" in err, err
    write_camera(tmp_path / "right.json", cam)
    assert main(["map", "--mesh", str(grid), "--camera", str(tmp_path / "right.json"),
                 "--image", str(tmp_path / "frame.png"), "--out",
                 str(tmp_path / "o.csv")]) == 0


def test_frames_without_a_lit_model_are_not_judged():
    """A uniform frame, a ramp, a signed field (not light): no lit part to compare the
    footprint with, nothing checked; a lit model on a dark ground (or the reverse): the
    part Otsu's threshold gives."""
    from resection.pose.footprint import lit_mask

    rng = np.random.default_rng(2)
    assert lit_mask(np.full((60, 80), 7.0) + rng.normal(0, 0.1, (60, 80))) is None
    assert lit_mask(np.linspace(1.0, 2.0, 4800).reshape(60, 80)) is None
    assert lit_mask(np.linspace(-0.5, 0.5, 4800).reshape(60, 80)) is None
    model = np.zeros((60, 80), bool)
    model[10:40, 20:70] = True
    frame = np.where(model, 2000.0, 60.0) * rng.gamma(30.0, 1 / 30.0, model.shape)
    assert np.mean(lit_mask(frame) == model) > 0.995  # speckle: a pixel or two below
    backlit = np.where(model, 200.0, 3000.0) * rng.gamma(30.0, 1 / 30.0, model.shape)
    assert np.mean(lit_mask(backlit) == ~model) > 0.995
