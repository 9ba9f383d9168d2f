"""Readers on uPSP's own test data as shipped (tests/data/upsp): the grid against the
independent ``plot3d`` package, the ``.tgts`` against uPSP's ``parsers.read_tgts`` and
``kulite_utilities.read_tgts`` reading logic, the calibrations against uPSP's
``read_camera_tunnel_cal`` / ``read_internal_params`` / ``convert_uPSP_cm_to_cv2_cm``,
``test_config.json``, and the tunnel transform against uPSP's ``tunnel_transform`` and
``tf_camera_tgts_thru_tunnel`` (each written out below from uPSP's source, in the test
only)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from resection import InputError
from resection.io.cameras import read_camera, read_camera_file
from resection.io.tgts import read_tgts
from resection.io.wtd import read_wtd
from selfillum.entry.tunnel import (
    Attitude,
    attitude_from_wtd,
    camera_to_model,
    read_camera_tunnel,
    read_test_config,
    tunnel_config,
)

CALS = ("camera01_35_6.json", "camera05_35_6.json")


# ---------------------------------------------------------------- uPSP's logic, written out
def _upsp_read_tgts(path):
    """uPSP parsers.read_tgts: only the *Targets rows; type from the name's suffix."""
    out, section = [], None
    with open(path) as f:
        for row in csv.reader(f, delimiter=" "):
            line = [x for x in row if x != ""]
            if len(line) > 1:
                if section != "*Targets":
                    continue
                name = line[-1]
                kind = "dot" if "st" in name else "kulite" if "mK" in name else \
                    "painted_kulite" if "pK" in name else name
                out.append({"target_type": kind, "tvec": [float(x) for x in line[1:4]],
                            "norm": [float(x) for x in line[4:7]], "size": float(line[7]),
                            "name": name, "idx": int(line[0]),
                            "zones": tuple(int(x) for x in line[8:11])})
            else:
                section = line[0] if len(line) == 1 else None
    return out


def _upsp_kulite_positions(path):
    """uPSP kulite_utilities.read_tgts: a row of > 11 fields whose name holds 'K' (not
    'pK' nor 'mK')."""
    pos = {}
    with open(path) as f:
        for line in f:
            v = line.strip().split()
            if len(v) > 11 and "K" in v[11] and "pK" not in v[11] and "mK" not in v[11]:
                pos[v[11]] = [float(v[1]), float(v[2]), float(v[3])]
    return pos


def _upsp_cv2_cm(upsp_cm, dims):
    """uPSP convert_uPSP_cm_to_cv2_cm: dims = (height, width) of the image."""
    cm = np.array(upsp_cm, float)
    cm[0][2] = dims[1] / 2 + cm[0][2]
    cm[1][2] = dims[0] / 2 + cm[1][2]
    return cm


def _rot(angle, axis):
    a = np.deg2rad(angle)
    c, s = np.cos(a), np.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _upsp_tunnel_transform(ALPHA, BETA, PHI, STRUTZ, cor_tgts):
    pitch, yaw, roll = _rot(-ALPHA, "y"), _rot(-BETA, "z"), _rot(PHI, "x")
    R = np.linalg.inv(pitch @ (yaw @ roll))
    t = R @ np.asarray(cor_tgts, float).reshape(3, 1) + np.array([[0], [0], [STRUTZ]])
    return R, t


def _upsp_camera_tgts(rmat_ct, tvec_ct, wtd, cfg):
    R_tt, t_tt = _upsp_tunnel_transform(wtd["ALPHA"], wtd["BETA"], wtd["PHI"],
                                        wtd["STRUTZ"], cfg["tunnel-cor_to_tgts_tvec"])
    R_tgts_tunnel = np.linalg.inv(R_tt)
    R = rmat_ct @ np.linalg.inv(R_tgts_tunnel)
    t = np.asarray(tvec_ct, float).reshape(3, 1) + rmat_ct @ t_tt
    return R, t


def _upsp_read_wtd(path, items=("ALPHA", "BETA", "PHI", "STRUTZ")):
    """uPSP parsers.read_wind_tunnel_data: skip the first line, tab-separated header."""
    with open(path) as f:
        f.readline()
        vals = next(csv.DictReader(f, delimiter="\t"))
    return {k.strip(): float(v) for k, v in vals.items() if k.strip() in items}


# ---------------------------------------------------------------- the readers
def test_real_grid_against_plot3d_package(upsp_samples):
    import plot3d

    from resection.io.plot3d import read_plot3d
    from selfillum.unsteady.grid import load_run_grid

    p = upsp_samples / "fml_tc3_volume.grid"
    ref = plot3d.read_plot3D(str(p), binary=True, big_endian=False, read_double=False)
    ours = read_plot3d(p)
    assert len(ours) == len(ref) > 1
    for (xyz, iblank), b in zip(ours, ref, strict=True):
        assert iblank is None
        assert xyz.shape[:3] == b.X.shape
        np.testing.assert_array_equal(xyz[..., 0], b.X)
        np.testing.assert_array_equal(xyz[..., 1], b.Y)
        np.testing.assert_array_equal(xyz[..., 2], b.Z)
    grid = load_run_grid(p)  # the nodes in file order, block by block, i fastest
    nodes = np.concatenate([np.stack([b.X, b.Y, b.Z], -1).reshape(-1, 3, order="F")
                            for b in ref])
    np.testing.assert_allclose(grid.points, nodes, rtol=0, atol=0)


def test_real_tgts_as_upsp_reads_it(upsp_samples):
    p = upsp_samples / "fml_tc3_volume.tgts"
    ref = _upsp_read_tgts(p)
    f = read_tgts(p)
    t = f.targets
    assert len(ref) == 24 and all(r["target_type"] == "dot" for r in ref)
    assert list(t.ids) == [r["name"] for r in ref]
    np.testing.assert_array_equal(t.xyz, [r["tvec"] for r in ref])
    n = np.array([r["norm"] for r in ref])
    np.testing.assert_allclose(t.normals, n / np.linalg.norm(n, axis=1)[:, None])
    np.testing.assert_array_equal(t.diameter, [r["size"] for r in ref])
    tg = [s for s in f.sections if s.kind == "targets"][0]
    np.testing.assert_array_equal(tg.grid_nodes, [r["zones"] for r in ref])
    # the Kulites, placed as uPSP's kulite_utilities places them
    kul = _upsp_kulite_positions(p)
    v = f.virtuals
    assert len(kul) == 14 and sorted(v.ids) == sorted(kul)
    for k, xyz in zip(v.ids, v.xyz, strict=True):
        np.testing.assert_array_equal(xyz, kul[k])
    assert len(f.taps) == 15 and not set(f.taps.ids) & set(kul)


@pytest.mark.parametrize("name", CALS)
def test_real_camera_tunnel_calibration_as_upsp_reads_it(upsp_samples, name):
    p = upsp_samples / "camera-tunnel-calibration" / name
    d = json.loads(p.read_text())
    rows, cols = d["sensor_resolution"][:2]
    cf = read_camera_file(p)
    cam = cf.camera
    assert cf.format == "upsp" and cf.has_pose and (cam.width, cam.height) == (cols, rows)
    np.testing.assert_array_equal(cam.K, _upsp_cv2_cm(d["uPSP_cameraMatrix"], (rows, cols)))
    np.testing.assert_array_equal(cam.dist, np.ravel(d["distCoeffs"]))
    np.testing.assert_array_equal(cam.R, d["rmat"])
    np.testing.assert_array_equal(cam.t, d["tvec"])
    # a cropped video (uPSP's processing example: 1024 x 512): uPSP adds the *image's*
    # half size to the stored offset
    c2 = read_camera_tunnel(p, 1024, 512)
    np.testing.assert_allclose(c2.K, _upsp_cv2_cm(d["uPSP_cameraMatrix"], (512, 1024)),
                               rtol=0, atol=1e-12)
    assert (c2.width, c2.height) == (1024, 512)
    np.testing.assert_array_equal(c2.R, cam.R)


@pytest.mark.parametrize("name", CALS)
def test_real_internal_calibration_as_upsp_reads_it(upsp_samples, name):
    p = upsp_samples / "internal-calibration" / name
    d = json.loads(p.read_text())
    cf = read_camera_file(p)
    assert cf.format == "upsp" and not cf.has_pose
    rows, cols = d["sensor_resolution"][:2]
    np.testing.assert_array_equal(cf.camera.K,
                                  _upsp_cv2_cm(d["uPSP_cameraMatrix"], (rows, cols)))
    np.testing.assert_array_equal(cf.camera.dist, np.ravel(d["distCoeffs"]))
    assert cf.sensor_size == tuple(d["sensor_size"])
    # the same intrinsics as the camera-to-tunnel file of the same camera
    ct = read_camera(upsp_samples / "camera-tunnel-calibration" / name)
    np.testing.assert_allclose(cf.camera.K, ct.K, rtol=1e-12)


def test_real_test_config(upsp_samples):
    p = upsp_samples / "test_config.json"
    d = json.loads(p.read_text())
    cfg = read_test_config(p)
    np.testing.assert_array_equal(cfg.cor_to_model, d["tunnel-cor_to_tgts_tvec"])
    assert cfg.oblique_angle == d["oblique_angle"] == 70
    assert cfg.extra["max_dist"] == 6 and cfg.extra["dot_pad"] == 4
    bad = dict(d, **{"tunnel-cor_to_tgts_rmat": [[0, 1, 0], [1, 0, 0], [0, 0, 1]]})
    with pytest.raises(InputError, match="tunnel-cor_to_tgts_rmat is not the identity"):
        tunnel_config(bad, "cfg.json")
    with pytest.raises(InputError, match=r"cfg.json: no 'tunnel-cor_to_tgts_tvec'"):
        tunnel_config({"oblique_angle": 70}, "cfg.json")
    (upsp_samples / "broken.json").write_text("{")
    with pytest.raises(InputError, match="broken.json: not JSON"):
        read_test_config(upsp_samples / "broken.json")


# ---------------------------------------------------------------- the tunnel transform
@pytest.mark.parametrize("name", CALS)
@pytest.mark.parametrize("cor", [None, [-195.5125, 0.0, 0.0], [-30.0, 1.5, -2.0]])
def test_camera_to_model_as_upsp_moves_the_model(upsp_samples, name, cor):
    """uPSP's tf_camera_tgts_thru_tunnel, on its real calibrations and test_config
    (its zero centre-of-rotation offset, then the processing example's -195.5 in)."""
    cfg_d = json.loads((upsp_samples / "test_config.json").read_text())
    if cor is not None:
        cfg_d["tunnel-cor_to_tgts_tvec"] = cor
    cfg = tunnel_config(cfg_d, "test_config.json")
    p = upsp_samples / "camera-tunnel-calibration" / name
    d = json.loads(p.read_text())
    cam = read_camera(p)
    wtd = _upsp_read_wtd(upsp_samples / "wtd_test.wtd")
    att_real = attitude_from_wtd(read_wtd(upsp_samples / "wtd_test.wtd"))
    assert (att_real.alpha, att_real.beta, att_real.phi, att_real.strutz) == \
        (wtd["ALPHA"], wtd["BETA"], wtd["PHI"], wtd["STRUTZ"])
    polar = [wtd] + [{"ALPHA": a, "BETA": b, "PHI": ph, "STRUTZ": z}
                     for a, b, ph, z in [(-5.0, 0.0, 0.0, 0.0), (15.0, 0.0, 0.0, 3.0),
                                         (7.5, -4.0, 30.0, -1.2), (2.0, 3.0, -90.0, 10.0)]]
    for w in polar:
        R_ref, t_ref = _upsp_camera_tgts(np.array(d["rmat"]), d["tvec"], w, cfg_d)
        got = camera_to_model(cam, Attitude(w["ALPHA"], w["BETA"], w["PHI"], w["STRUTZ"]),
                              cfg)
        np.testing.assert_allclose(got.R, R_ref, rtol=0, atol=1e-13)
        np.testing.assert_allclose(got.t, t_ref.ravel(), rtol=0, atol=1e-11)


def test_attitude_signs_move_the_model_as_documented():
    """ALPHA pitches, BETA yaws the other way, PHI rolls: each alone, on a point of the
    model's x axis and one of its y axis, about a centre of rotation 10 units behind."""
    from selfillum.entry.tunnel import TunnelConfig, model_to_tunnel

    cfg = TunnelConfig(np.array([10.0, 0.0, 0.0]))
    M, d = model_to_tunnel(Attitude(10.0, 0.0, 0.0, 0.0), cfg)
    x = M @ np.array([1.0, 0.0, 0.0]) + d  # the point 11 units ahead of the centre
    a = np.radians(10.0)
    np.testing.assert_allclose(x, 11.0 * np.array([np.cos(a), 0.0, -np.sin(a)]), atol=1e-12)
    M, _ = model_to_tunnel(Attitude(0.0, 10.0, 0.0, 0.0), cfg)
    b = np.radians(10.0)
    np.testing.assert_allclose(M @ [1.0, 0.0, 0.0], [np.cos(b), np.sin(b), 0.0], atol=1e-12)
    M, _ = model_to_tunnel(Attitude(0.0, 0.0, 10.0, 0.0), cfg)
    p = np.radians(10.0)
    np.testing.assert_allclose(M @ [0.0, 1.0, 0.0], [0.0, np.cos(p), -np.sin(p)], atol=1e-12)
    _, d = model_to_tunnel(Attitude(0.0, 0.0, 0.0, 4.0), cfg)
    np.testing.assert_allclose(d, [10.0, 0.0, 4.0])


def test_wtd_without_strutz_refused(tmp_path):
    p = tmp_path / "a.wtd"
    p.write_text("# MACH\tALPHA\tBETA\tPHI\tQ\tPS\n0.8\t2\t0\t0\t600\t1500\n")
    with pytest.raises(InputError, match=r"a.wtd: no STRUTZ \(nor STRUTZ_UNC\)"):
        attitude_from_wtd(read_wtd(p))
    p.write_text("# MACH\tALPHA\tBETA\tPHI\tSTRUTZ_UNC\n0.8\t2\t0.5\t-90\t3.0\n")
    assert attitude_from_wtd(read_wtd(p)) == Attitude(2.0, 0.5, -90.0, 3.0)
