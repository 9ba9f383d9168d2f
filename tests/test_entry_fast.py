"""The entry's fast checks: one camera's first frame calibrated from the tunnel (against
the scene's true camera), datapoints that fail alone on a Dask local cluster (uPSP's real
.tgts, calibration and .wtd; a folder without videos, a corrupt video), and bad input
refused with one line and exit 2 before any work."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest

from resection.io.cameras import read_camera, read_camera_file
from scenes.entry import COR, STRUTZ
from scenes.unsteady_run import BOX, _camera, make_unsteady_run, plate_targets
from selfillum.cli import main
from selfillum.entry.calibrate import calibrate_camera
from selfillum.entry.tunnel import Attitude, TunnelConfig, camera_to_model, model_to_tunnel


def test_first_frame_calibrated_from_the_tunnel(tmp_path):
    """alpha = 15 deg with 0.4 deg of sting deflection and 3 mm of heave the .wtd does not
    know: the tunnel's prediction misses by pixels, the calibration finds the truth."""
    from resection.io.markers import read_markers

    cfg = TunnelConfig(COR)
    base = _camera(200, 150)
    M0, d0 = model_to_tunnel(Attitude(0.0, 0.0, 0.0, STRUTZ), cfg)
    ct = base.with_pose(R=base.R @ M0.T, t=base.t - base.R @ M0.T @ d0)
    true = camera_to_model(ct, Attitude(15.4, 0.0, 0.0, STRUTZ + 0.003), cfg)
    run = make_unsteady_run(tmp_path / "run", faces=300, frames=2, cameras0=[true],
                            targets=plate_targets([true], BOX, 15.0), vibration_deg=0.0)
    truth = true.with_pose(R=run.poses[0, 0, :3], t=run.poses[0, 0, 3])
    img = np.load(run.video)[0]
    assert np.isfinite(img).all()
    from selfillum.unsteady.grid import load_run_grid

    mesh = load_run_grid(run.grid).mesh
    markers = read_markers(run.targets)
    X = markers.xyz
    pred = camera_to_model(ct, Attitude(15.0, 0.0, 0.0, STRUTZ), cfg)
    miss = np.linalg.norm(pred.project(X) - truth.project(X), axis=1)
    assert np.median(miss) > 1.0
    out = tmp_path / "dp"
    out.mkdir()
    res = calibrate_camera(1, img, markers, mesh, pred, out, plot=False)
    assert res.reason is None and res.used >= 8 and res.rms < 0.5
    got = read_camera(out / "cam01-to-model.json")
    assert read_camera_file(out / "cam01-to-model.json").format == "upsp-model"
    err = np.linalg.norm(got.project(X) - truth.project(X), axis=1)
    assert err.max() < 0.3
    assert res.shift == pytest.approx(np.median(np.linalg.norm(
        pred.project(X) - got.project(X), axis=1)), rel=1e-6)
    # a prediction 30 deg off: refused with the reason, nothing written
    far = camera_to_model(ct, Attitude(45.0, 0.0, 0.0, STRUTZ), cfg)
    out2 = tmp_path / "dp2"
    out2.mkdir()
    bad = calibrate_camera(1, img, markers, mesh, far, out2, plot=False)
    assert bad.camera is None and bad.reason and not list(out2.iterdir())


def _fake_entry(root, samples):
    """uPSP's real .tgts, calibration, .wtd and test_config on a small grid, with
    datapoints whose videos fail."""
    from scenes.slab_block import slab_block, write_slab_block

    for n in ("fml_tc3_volume.tgts", "wtd_test.wtd", "test_config.json"):
        shutil.copy(samples / n, root / n)
    write_slab_block(slab_block(300, half=(0.35, 0.25), box=BOX), root / "model.grid")
    (root / "cal").mkdir()
    shutil.copy(samples / "camera-tunnel-calibration" / "camera01_35_6.json",
                root / "cal" / "camera01.json")
    from scenes.unsteady_run import write_node_function
    from selfillum.unsteady.grid import load_run_grid

    grid = load_run_grid(root / "model.grid")
    write_node_function(root / "steady.f", grid, -0.2 + 0.01 * grid.points[:, 0])
    (root / "paint.txt").write_text("a = 1\nb = 0\nc = 0\nd = 0\ne = 0\nf = 0\n")
    (root / "videos").mkdir()
    (root / "videos" / "30160201.mraw").write_bytes(b"\0" * 100)
    (root / "videos" / "30160201.cih").write_text("not a header\n")
    dp = {"camera_tunnel_calibration_dir": "cal", "camera_video_dir": "videos",
          "grid_file": "model.grid", "kulites_files_path": "",
          "paint_calibration_file": "paint.txt", "steady_psp_file": "steady.f",
          "targets_file": "fml_tc3_volume.tgts", "wtd_file": "wtd_test.wtd"}
    (root / "index.json").write_text(json.dumps({"__meta__": {"test_name": "t"},
                                                 "301601": dp, "301602": dp}))
    return root / "index.json"


def test_failing_datapoints_fail_alone_on_a_local_cluster(upsp_samples, tmp_path, capsys):
    idx = _fake_entry(tmp_path, upsp_samples)
    out = tmp_path / "out"
    rc = main(["entry", str(idx), "--test-config", str(tmp_path / "test_config.json"),
               "--out", str(out), "--workers", "1", "--quiet"])
    assert rc == 1
    with open(out / "summary.csv", newline="") as fh:
        rows = {r["datapoint"]: r for r in csv.DictReader(fh)}
    assert rows["301601"]["status"] == \
        f"failed: datapoint 301601: no video 301601NN.cine/.mraw in {tmp_path / 'videos'}"
    s = rows["301602"]["status"]
    assert s.startswith("failed: datapoint 301602: ") and "30160201" in s
    # the real .wtd's attitude, read into the row
    assert float(rows["301602"]["alpha"]) == 0.05 and float(rows["301602"]["phi"]) == 0.9
    assert (out / "index.html").is_file()
    printed = capsys.readouterr().out
    assert "2 failed" in printed and "datapoint 301601: no video" in printed


def test_bad_input_exit_2(upsp_samples, tmp_path, capsys):
    idx = _fake_entry(tmp_path, upsp_samples)
    tc = ["--test-config", str(tmp_path / "test_config.json")]
    d = json.loads(idx.read_text())
    d["301602"] = dict(d["301602"], wtd_file="nope.wtd")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    rc = main(["entry", str(bad), *tc, "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].endswith(f"datapoint 301602: wtd {tmp_path / 'nope.wtd'}: file not found")
    assert not (tmp_path / "o").exists()
    rc = main(["entry", str(idx), "--out", str(tmp_path / "o"), "--quiet"])
    assert rc == 2 and "datapoint 301601: no tunnel configuration" in capsys.readouterr().err
    rc = main(["entry", str(idx), *tc, "--only", "999999", "--out", str(tmp_path / "o")])
    assert rc == 2 and "--only 999999: no such datapoint" in capsys.readouterr().err
    proc = tmp_path / "proc.json"
    for x, say in (("abc", "cutoff_x_max must be a number, got 'abc'"),
                   (-1e6, "cutoff_x_max -1e+06: every node of ")):
        proc.write_text(json.dumps({"processing": {"defaults": {
            "psp_process": {"cutoff_x_max": x}}, "__overlays__": [["defaults",
                                                                  {".*": ".*"}]]}}))
        rc = main(["entry", str(idx), *tc, "--processing", str(proc), "--out",
                   str(tmp_path / "o")])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1 and say in err[0]
        assert "301601" in err[0] and str(proc) in err[0]  # the datapoint, the file
        assert not (tmp_path / "o").exists()
    proc.write_text(json.dumps({"processing": {"defaults": {
        "psp_process": {"bound_pts": 3}}, "__overlays__": [["defaults", {".*": ".*"}]]}}))
    rc = main(["entry", str(idx), *tc, "--processing", str(proc), "--out",
               str(tmp_path / "o")])
    assert rc == 2 and "psp_process parameter 'bound_pts' is not supported" in \
        capsys.readouterr().err
    # a cut-off that leaves nodes: every datapoint's run gets it (as psp_process's
    # -cutoff_x_max, from the psp_process set, as uPSP's tree.py passes it)
    from selfillum.entry.run import EntryConfig, prepare_entry

    proc.write_text(json.dumps({"processing": {"defaults": {
        "psp_process": {"cutoff_x_max": "1e6"}}, "__overlays__": [["defaults",
                                                                    {".*": ".*"}]]}}))
    _, tasks, _ = prepare_entry(EntryConfig(idx, tmp_path / "o", processing=proc,
                                            test_config=tmp_path / "test_config.json"))
    assert tasks and all(t.unsteady["cutoff_x_max"] == 1e6 for t in tasks)
    from resection.io.plot3d import write_plot3d_function

    write_plot3d_function(tmp_path / "small.f", [np.zeros((3, 4, 1))])
    d = json.loads(idx.read_text())
    d["301601"] = dict(d["301601"], steady_psp_file="small.f")
    bad.write_text(json.dumps(d))
    rc = main(["entry", str(bad), *tc, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "datapoint 301601: " in err[0] and \
        "small.f" in err[0]
    (tmp_path / "o" / "301601").mkdir(parents=True)
    (tmp_path / "o" / "301601" / "row.json").write_text("{}")
    rc = main(["entry", str(idx), *tc, "--out", str(tmp_path / "o")])
    assert rc == 2 and "give --resume or another --out" in capsys.readouterr().err


def test_form_factors_file_checked(tmp_path):
    """The entry's view factors given to a run (UnsteadyConfig.form_factors): read back as
    written, a wrong size or a row summing over 1 refused by name."""
    import scipy.sparse as sp

    from resection import InputError
    from selfillum.unsteady.inputs import read_form_factors

    F = sp.random(6, 6, density=0.5, random_state=1, format="csr") * 0.1
    sp.save_npz(tmp_path / "F.npz", F)
    np.testing.assert_array_equal(read_form_factors(tmp_path / "F.npz", 6).toarray(),
                                  F.toarray())
    with pytest.raises(InputError, match=r"F.npz: view factors 6x6, the grid has 7 faces"):
        read_form_factors(tmp_path / "F.npz", 7)
    sp.save_npz(tmp_path / "G.npz", sp.csr_matrix(np.full((6, 6), 0.5)))
    with pytest.raises(InputError, match="G.npz: view factors must be finite, >= 0, each "
                                         "row summing to at most 1"):
        read_form_factors(tmp_path / "G.npz", 6)
    with pytest.raises(InputError, match="H.npz: view factors file not found"):
        read_form_factors(tmp_path / "H.npz", 6)
