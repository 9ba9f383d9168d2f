"""No silent wrong camera (issue 20 items 10-11): ``pose`` records the image and marker file
a camera was solved on; ``map``, the merge and ``selfillum correct`` warn on another image,
refuse a units mismatch, and with ``--markers`` refuse a camera whose targets do not land
on dark spots of the image. Scenes: two cameras of a plate with dark targets
(``scenes.real_traits``, true poses) and exact marker projections (``scenes.marker_images``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from resection.camera import Camera
from resection.cli import main
from resection.io.cameras import read_camera_file, write_camera
from resection.io.images import read_image, write_image
from resection.io.markers import read_markers, write_markers
from resection.pose.camera_fit import image_fingerprint, marker_fit, solved_on_record
from scenes.marker_images import render_markers
from scenes.real_traits import real_traits, write_scene


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """Two cameras, two 8-bit images, the surveyed targets; camera files that carry the
    record of the image each was solved on (as ``pose`` writes them)."""
    d = tmp_path_factory.mktemp("camera_fit")
    sc = real_traits()
    p = write_scene(sc, d)
    markers = read_markers(p["markers"])
    for c in range(2):
        rec = solved_on_record(p[f"image{c}"], read_image(p[f"image{c}"]), p["markers"],
                               markers)
        write_camera(p[f"camera{c}"], sc.cameras[c], solved_on=rec)
    return sc, p


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_pose_records_image_and_markers(tmp_path, capsys):
    K = [[1200.0, 0, 320], [0, 1200.0, 240], [0, 0, 1]]
    rng = np.random.default_rng(4)
    n = 16
    xyz = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.14, 0.14, n),
                           rng.uniform(0.0, 0.05, n)])
    true = Camera.look_at([0.05, -0.1, 1.0], [0, 0, 0], [0, 1, 0], K=K, width=640, height=480)
    img = render_markers((480, 640), true.project(xyz), 6.0, contrast=80, background=600,
                         blur=0.7, snr=40, rng=1, dtype=np.uint16)
    write_image(tmp_path / "frame.tif", img)
    write_markers(tmp_path / "model.csv", [f"T{k}" for k in range(n)], xyz, np.full(n, 0.005))
    write_camera(tmp_path / "cam.json", true)
    rc, _, err = _run(["pose", "--camera", tmp_path / "cam.json", "--markers",
                       tmp_path / "model.csv", "--image", tmp_path / "frame.tif", "--out",
                       tmp_path / "posed.json"], capsys)
    assert rc == 0, err
    rec = json.loads((tmp_path / "posed.json").read_text())["solved_on"]
    assert rec["image"] == {"name": "frame.tif", "width": 640, "height": 480,
                            "fingerprint": image_fingerprint(read_image(tmp_path / "frame.tif"))}
    assert rec["markers"]["name"] == "model.csv" and rec["markers"]["count"] == n
    np.testing.assert_allclose(rec["markers"]["xyz"], xyz, rtol=1e-8)
    cf = read_camera_file(tmp_path / "posed.json")  # the record is kept, the camera reads
    assert cf.solved_on == rec and cf.format == "json"
    # the same from a uPSP camera-to-tunnel file without sensor_resolution (optional in
    # uPSP's docs): the size comes from the image
    write_camera(tmp_path / "cam_upsp.json", true, format="upsp")
    d = json.loads((tmp_path / "cam_upsp.json").read_text())
    del d["sensor_resolution"]
    (tmp_path / "cam_upsp.json").write_text(json.dumps(d))
    rc, _, err = _run(["pose", "--camera", tmp_path / "cam_upsp.json", "--markers",
                       tmp_path / "model.csv", "--image", tmp_path / "frame.tif", "--out",
                       tmp_path / "posed2.json"], capsys)
    assert rc == 0, err
    again = read_camera_file(tmp_path / "posed2.json").camera
    np.testing.assert_allclose(again.project(xyz), true.project(xyz), atol=0.05)


def test_fingerprint_follows_the_pixels_not_the_file(tmp_path):
    img = np.arange(300 * 200, dtype=np.uint16).reshape(200, 300)
    write_image(tmp_path / "a.png", img)
    write_image(tmp_path / "a.tif", img)
    fa, ft = (image_fingerprint(read_image(tmp_path / n)) for n in ("a.png", "a.tif"))
    assert fa == ft
    other = img.copy()
    other[100, 150] += 1  # one pixel on the 64 x 64 sampling grid
    rows = np.linspace(0, 199, 64).round().astype(int)
    cols = np.linspace(0, 299, 64).round().astype(int)
    other[rows[10], cols[20]] += 1
    assert image_fingerprint(other.astype(np.float32)) != fa


def test_marker_fit_tells_right_camera_from_swapped(plate):
    sc, p = plate
    ms = read_markers(p["markers"])
    right = [marker_fit(sc.cameras[c], sc.images[c], ms) for c in range(2)]
    swapped = [marker_fit(sc.cameras[c], sc.images[1 - c], ms) for c in range(2)]
    assert all(len(f.expected) >= 8 and f.share > 0.9 for f in right)
    assert all(f.share < 0.2 for f in swapped)


def test_map_refuses_another_cameras_file_with_markers(plate, tmp_path, capsys):
    sc, p = plate
    base = ["map", "--mesh", p["grid"], "--markers", p["markers"]]
    rc, out, err = _run([*base, "--camera", p["camera0"], "--image", p["image0"], "--out",
                         tmp_path / "ok.csv"], capsys)
    assert rc == 0, err
    assert "land on a spot" in out
    # camera 1's file with camera 0's image: refused, nothing written
    with pytest.warns(UserWarning, match=r"cam1.json: solved on cam1.png"):
        rc, _, err = _run([*base, "--camera", p["camera1"], "--image", p["image0"], "--out",
                           tmp_path / "bad.csv"], capsys)
    assert rc == 2 and "does not fit" in err and "cam0.png" in err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "bad.csv").exists()
    # the merge with the camera files swapped: refused
    with pytest.warns(UserWarning):
        rc, _, err = _run([*base, "--camera", p["camera1"], "--image", p["image0"],
                           "--camera", p["camera0"], "--image", p["image1"], "--out",
                           tmp_path / "merged.csv"], capsys)
    assert rc == 2 and "does not fit" in err and not (tmp_path / "merged.csv").exists()


def test_map_warns_on_another_image_only(plate, tmp_path, capsys, recwarn):
    sc, p = plate
    rc, _, err = _run(["map", "--mesh", p["grid"], "--camera", p["camera0"], "--image",
                       p["image0"], "--out", tmp_path / "a.csv"], capsys)
    assert rc == 0, err
    assert not [w for w in recwarn if "solved on" in str(w.message)]
    with pytest.warns(UserWarning, match=r"cam0.json: solved on cam0.png \(320x240, "
                                         r"sha1:[0-9a-f]{16}\), used with cam1.png"):
        rc, _, _ = _run(["map", "--mesh", p["grid"], "--camera", p["camera0"], "--image",
                         p["image1"], "--out", tmp_path / "b.csv"], capsys)
    assert rc == 0  # another frame of the same camera is legitimate: a warning only


def test_units_mismatch_refused_by_map_and_correct(plate, tmp_path, capsys):
    """A camera solved on markers in mm (its translation in mm too), used on the grid in
    inches: it still sees some faces (on today's main: 'N of M faces seen', exit 0); map
    and correct refuse it, as pose does (resection.camera.units.spread_hint)."""
    from resection.io.meshes import load_mesh, write_plot3d

    sc, p = plate
    cam = sc.cameras[0]
    cam_mm = Camera(cam.width, cam.height, cam.K, cam.dist, cam.R, np.asarray(cam.t) * 1000.0)
    ms = read_markers(p["markers"])
    write_markers(tmp_path / "targets.csv", ms.ids, ms.xyz * 1000.0, ms.diameter * 1000.0)
    rec = solved_on_record(p["image0"], read_image(p["image0"]), tmp_path / "targets.csv",
                           read_markers(tmp_path / "targets.csv"))
    write_camera(tmp_path / "cam_mm.json", cam_mm, solved_on=rec)
    write_plot3d(tmp_path / "grid_in.xyz", [b * (1000.0 / 25.4) for b in sc.blocks])
    from resection.surface import SurfaceMap

    seen = SurfaceMap(load_mesh(tmp_path / "grid_in.xyz"), cam_mm).seen_faces.sum()
    assert seen > 0  # the silent case: the wrong-unit camera sees part of the grid
    rc, _, err = _run(["map", "--mesh", tmp_path / "grid_in.xyz", "--camera",
                       tmp_path / "cam_mm.json", "--image", p["image0"], "--out",
                       tmp_path / "u.csv"], capsys)
    assert rc == 2 and "different units" in err, err
    assert "cam_mm.json" in err and not (tmp_path / "u.csv").exists()
    from selfillum.cli import main as si_main

    rc = si_main(["correct", "--mesh", str(tmp_path / "grid_in.xyz"), "--camera",
                  str(tmp_path / "cam_mm.json"), "--image", p["image0"], "--reflectance",
                  "0.3", "--out", str(tmp_path / "c.tif"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "different units" in err and not (tmp_path / "c.tif").exists()


def test_correct_refuses_another_cameras_file_with_markers(plate, tmp_path, capsys):
    from selfillum.cli import main as si_main

    sc, p = plate
    base = ["correct", "--mesh", p["grid"], "--reflectance", "0.3", "--rays", "16",
            "--markers", p["markers"], "--quiet", "--image", p["image0"]]
    with pytest.warns(UserWarning, match="solved on cam1.png"):
        rc = si_main([*base, "--camera", p["camera1"], "--out", str(tmp_path / "bad.tif")])
    err = capsys.readouterr().err
    assert rc == 2 and "does not fit" in err and not (tmp_path / "bad.tif").exists()


def test_upsp_camera_without_size_used_with_its_image(plate, tmp_path, capsys):
    """A uPSP camera-to-tunnel file without sensor_resolution (optional in uPSP's docs):
    map takes the size from the image and maps as with the native file."""
    sc, p = plate
    write_camera(tmp_path / "cam0_upsp.json", sc.cameras[0], format="upsp")
    d = json.loads((tmp_path / "cam0_upsp.json").read_text())
    del d["sensor_resolution"]
    (tmp_path / "cam0_upsp.json").write_text(json.dumps(d))
    outs = []
    for cam in (p["camera0"], tmp_path / "cam0_upsp.json"):
        out = tmp_path / f"m{len(outs)}.csv"
        rc, _, err = _run(["map", "--mesh", p["grid"], "--camera", cam, "--image", p["image0"],
                           "--out", out], capsys)
        assert rc == 0, err
        outs.append(np.genfromtxt(out, delimiter=",", names=True)["cam0"])
    np.testing.assert_allclose(outs[1], outs[0], rtol=1e-9, equal_nan=True)
