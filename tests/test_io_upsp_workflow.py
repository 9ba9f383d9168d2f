"""The uPSP workflow as a user runs it (README): an 8-bit PNG frame, a uPSP camera file, a
uPSP ``.tgts`` target file (targets and taps, one target surveyed under the surface) and a
binary multi-block Plot3D ``.grid``; ``resection pose`` then ``resection map --out P.f``.
Checked against the scene's true camera (scenes.real_traits)."""

from __future__ import annotations

import numpy as np
import pytest

from resection.cli.main import main
from resection.io.cameras import read_camera, write_camera
from resection.io.images import write_image
from resection.io.markers import MarkerSet
from resection.io.plot3d import read_plot3d_function, write_plot3d
from resection.io.tgts import write_tgts
from scenes.real_traits import TAP_D, TARGET_D, real_traits


@pytest.fixture(scope="module")
def upsp_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("upsp")
    sc = real_traits(scale=1.0)
    write_plot3d(d / "model.grid", sc.blocks)
    n, ntap = len(sc.marker_ids), len(sc.taps)
    xyz = np.vstack([sc.surveyed, sc.taps])
    xyz[0, 2] -= 0.002  # T01 surveyed 2 mm under the plate (the uPSP trap)
    ids = tuple(sc.marker_ids) + tuple(f"P{k + 1:02d}" for k in range(ntap))
    ms = MarkerSet(ids, xyz, np.r_[np.full(n, TARGET_D), np.full(ntap, TAP_D)],
                   np.tile([0.0, 0.0, 1.0], (n + ntap, 1)),
                   np.r_[np.zeros(n, bool), np.ones(ntap, bool)])
    write_tgts(d / "model.tgts", ms)
    write_camera(d / "cam.json", sc.cameras[0], format="upsp", sensor_size=(0.5, 0.375))
    write_image(d / "frame.png", sc.images[0])
    return d, sc


def test_pose_then_map_to_plot3d_function(upsp_files, capsys):
    d, sc = upsp_files
    with pytest.warns(UserWarning, match=r"T01 \(0\.002\)"):
        rc = main(["pose", "--image", str(d / "frame.png"), "--camera", str(d / "cam.json"),
                   "--markers", str(d / "model.tgts"), "--mesh", str(d / "model.grid"),
                   "--out", str(d / "pose.json")])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert not any(line.split()[0].startswith("P") for line in out.splitlines()[3:-1]
                   if line.split())  # no tap was taken for a target
    cam = read_camera(d / "pose.json")
    ok = np.all(np.isfinite(sc.uv[0]), axis=1)
    err = np.linalg.norm(cam.project(sc.markers[ok]) - sc.uv[0][ok], axis=1)
    assert np.median(err) < 0.6  # survey errors are 0.5 to 1.5 px
    rc = main(["map", "--mesh", str(d / "model.grid"), "--camera", str(d / "pose.json"),
               "--image", str(d / "frame.png"), "--out", str(d / "P.f")])
    assert rc == 0
    vals = read_plot3d_function(d / "P.f")
    assert [v.shape[:3] for v in vals] == [b.shape[:3] for b in sc.blocks]
    seen = np.concatenate([np.isfinite(v[..., 0]).ravel() for v in vals])
    assert seen.mean() > 0.3


def test_format_option_on_an_unknown_extension(upsp_files, capsys):
    d, _ = upsp_files
    (d / "model.dat").write_bytes((d / "model.grid").read_bytes())
    rc = main(["map", "--mesh", str(d / "model.dat"), "--format", "plot3d", "--camera",
               str(d / "cam.json"), "--image", str(d / "frame.png"), "--out",
               str(d / "p.vtu")])
    assert rc == 0
    capsys.readouterr()  # that run's own report (its frame has saturated pixels)
    rc = main(["map", "--mesh", str(d / "model.dat"), "--format", "stl", "--camera",
               str(d / "cam.json"), "--image", str(d / "frame.png"), "--out",
               str(d / "q.vtu")])
    err = capsys.readouterr().err
    assert rc == 2 and "model.dat" in err and "STL" in err and len(err.splitlines()) == 1
