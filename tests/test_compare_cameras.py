"""``resection compare-cameras`` (issue 34 item 11): NASA uPSP's camera 1 against the same
camera turned by 0.2 degree and moved; the pixel distances from OpenCV's projection of the
real targets and grid, the rotation from SciPy, the centres in closed form."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resection.cli.main import main
from resection.io.cameras import read_camera, write_camera
from resection.io.markers import read_markers
from resection.io.meshes import load_mesh


def _opencv_spread(cam_a, cam_b, pts):
    """Mean and largest distance of the points in front of both cameras and in the image of
    either, projected by OpenCV."""
    uvs, front = [], np.ones(len(pts), bool)
    for cam in (cam_a, cam_b):
        K, dist, rvec, tvec = cam.to_opencv()
        uv, _ = cv2.projectPoints(np.asarray(pts, float), rvec, tvec, K, dist)
        uvs.append(uv.reshape(-1, 2))
        front &= (pts @ cam.R.T + cam.t)[:, 2] > 0
    inside = [(u[:, 0] >= -0.5) & (u[:, 0] <= cam_a.width - 0.5) & (u[:, 1] >= -0.5)
              & (u[:, 1] <= cam_a.height - 0.5) for u in uvs]
    sel = front & (inside[0] | inside[1])
    d = np.linalg.norm(uvs[1][sel] - uvs[0][sel], axis=1)
    return int(sel.sum()), d.mean(), d.max()


def test_compare_cameras_on_upsps_camera(upsp_samples, tmp_path, capsys):
    a_path = upsp_samples / "camera-tunnel-calibration" / "camera01_35_6.json"
    cam_a = read_camera(a_path)
    turn = Rotation.from_rotvec(np.radians(0.2) * np.array([0.3, -0.8, 0.52])
                                / np.linalg.norm([0.3, -0.8, 0.52]))
    shift = np.array([0.05, -0.02, 0.03])  # inches, as the grid
    R_b = turn.as_matrix() @ cam_a.R
    centre_b = cam_a.center + shift
    cam_b = cam_a.with_pose(R=R_b, t=-R_b @ centre_b)
    b_path = tmp_path / "b.json"
    write_camera(b_path, cam_b)
    out = tmp_path / "cmp.json"
    tgts = upsp_samples / "fml_tc3_volume.tgts"
    grid = upsp_samples / "fml_tc3_volume.grid"
    assert main(["compare-cameras", str(a_path), str(b_path), "--markers", str(tgts),
                 "--mesh", str(grid), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "rotation apart: 0.2000 deg" in text
    d = json.loads(out.read_text())
    assert d["rotation_deg"] == pytest.approx(np.degrees(turn.magnitude()), abs=1e-9)
    np.testing.assert_allclose(d["centre_a"], -cam_a.R.T @ cam_a.t, atol=1e-9)
    assert d["centre_distance"] == pytest.approx(np.linalg.norm(shift), rel=1e-9)
    assert d["focal_change_px"] == [0.0, 0.0]
    ms = read_markers(tgts)
    for name, pts in (("targets", ms.xyz), ("grid nodes", load_mesh(grid).vertices)):
        n, mean, top = _opencv_spread(cam_a, cam_b, np.asarray(pts, float))
        got = d["points"][name]
        assert got["n"] == n and n > 15
        assert got["mean_px"] == pytest.approx(mean, rel=1e-6)
        assert got["largest_px"] == pytest.approx(top, rel=1e-6)


def test_compare_cameras_refusals(upsp_samples, tmp_path, capsys):
    a = upsp_samples / "camera-tunnel-calibration" / "camera01_35_6.json"
    inner = upsp_samples / "internal-calibration" / "camera01_35_6.json"
    assert main(["compare-cameras", str(a), str(inner)]) == 2
    err = capsys.readouterr().err
    assert "holds no pose" in err and str(inner) in err and len(err.splitlines()) == 1
    small = tmp_path / "small.json"
    write_camera(small, read_camera(a).replace(width=640, height=400))
    assert main(["compare-cameras", str(a), str(small)]) == 2
    assert "1280x800 and 640x400" in capsys.readouterr().err
