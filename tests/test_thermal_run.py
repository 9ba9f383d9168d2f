"""``selfillum thermal`` end to end on a synthetic IR run with a known heat flux
(scenes.ir_run: markers that appear, 8 px settling then vibration, emissivity falling at
grazing angles, saturated pixels), the truth being the closed-form temperature of the
imposed heat flux; its output file and XDMF; bad inputs named on one line, exit 2, before
any heavy step; an interrupted run resumed."""

from __future__ import annotations

import dataclasses
import json
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest

from resection.errors import InputError
from scenes.ir_run import make_ir_run
from selfillum.cli.main import main
from selfillum.thermal import CameraInput, ThermalConfig, run_thermal


def _config(run, out, **kw) -> ThermalConfig:
    return ThermalConfig(**{"grid": run.grid, **kw},
                         cameras=[CameraInput(1, run.video, run.calibration)],
                         out=out, substrate=run.substrate, targets=run.targets,
                         radiometry=run.radiometry, sds=run.wtd, fps=run.fps, plots=False)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    return make_ir_run(tmp_path_factory.mktemp("ir_tiny"), frames=16, width=160, height=120,
                       nx=25, nphi=20, settle_s=0.2)


def _cli(run, out, *extra, radiometry=None):
    return main(["thermal", "--grid", str(run.grid), "--targets", str(run.targets),
                 "--video", str(run.video), "--calibration", str(run.calibration),
                 "--radiometry", str(radiometry or run.radiometry), "--substrate",
                 str(run.substrate), "--fps", str(run.fps), "--out", str(out), "--quiet",
                 *extra])


def test_command_writes_the_file(tiny, tmp_path, capsys):
    out = tmp_path / "run.h5"
    assert _cli(tiny, out, "--sds", str(tiny.wtd), "--probe", "3,40",
                "--picture-times", "0.1") == 0
    text = capsys.readouterr().out
    assert "saturated: 144 pixels masked" in text  # the 3 x 3 hot corner, 16 frames
    for p in (out, out.with_suffix(".xdmf"), tmp_path / "run_q_0.100s.png",
              tmp_path / "run_probes.png"):
        assert p.is_file() and p.stat().st_size > 0
    assert not (tmp_path / "run.h5.work").exists()
    with h5py.File(out) as f:
        T, q = f["temperature"][()], f["heat_flux"][()]
        assert T.shape == q.shape == (16, len(tiny.q0))
        assert f["stanton"].shape == T.shape
        assert f.attrs["format"] == "selfillum-thermal"
        assert f["probes/temperature"].shape == (16, 2)
        np.testing.assert_array_equal(f["probes/heat_flux"][()], q[:, [3, 40]])
    away = tiny.cos0 < -0.2  # the far side: unseen, NaN
    assert np.isnan(T[:, away]).all() and np.isnan(q[:, away]).all()
    seen = np.isfinite(q).all(axis=0)
    assert seen.sum() > 0.25 * len(seen)
    assert np.nanmax(np.abs(T[0, seen] - 295.0)) < 0.5  # the model starts at 295 K
    # the XDMF: one temporal grid a frame, each naming rows of the file's datasets
    root = ET.parse(out.with_suffix(".xdmf")).getroot()
    grids = root.findall(".//Grid[@CollectionType='Temporal']/Grid")
    assert len(grids) == 16
    names = {a.get("Name") for a in grids[5].findall("Attribute")}
    assert {"temperature", "heat_flux", "stanton", "heat_transfer_coefficient"} <= names
    with h5py.File(out) as f:
        for it in root.iter("DataItem"):
            if it.get("Format") == "HDF":
                assert it.text.split(":")[1] in f


@pytest.mark.parametrize("change, words", [
    ({"O": None}, "missing the calibration constant O"),
    ({"emissivity": 1.5}, "emissivity 1.5 is outside (0, 1]"),
    ({"reflected_temperature": -20.0}, "reflected_temperature -20.0 K is below 0 K"),
    ({"range_K": [250.0, 290.0]}, "outside the calibration's range"),
])
def test_bad_input_one_line_exit_2(tiny, tmp_path, capsys, change, words):
    d = json.loads(Path(tiny.radiometry).read_text())
    for k, v in change.items():
        if v is None:
            d.pop(k)
        else:
            d[k] = v
    rj = tmp_path / "R.json"
    rj.write_text(json.dumps(d))
    out = tmp_path / "bad.h5"
    assert _cli(tiny, out, radiometry=rj) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1
    named = str(tiny.video) if "range" in words else str(rj)
    assert named in err
    assert not out.exists() and not (tmp_path / "bad.h5.work").exists()


@pytest.mark.slow
def test_ir_run_heat_flux_within_5_percent(tmp_path):
    run = make_ir_run(tmp_path / "scene", frames=45, width=240, height=180, nx=41, nphi=32)
    assert run.shift_px.max() == pytest.approx(8.0, abs=0.05)  # the settling motion
    res = run_thermal(_config(run, tmp_path / "run.h5"))
    assert res.tracked_failed >= 1  # frame 0: the markers have no contrast yet
    with h5py.File(res.out) as f:
        T, q = f["temperature"][()], f["heat_flux"][()]
        R, t = f["cameras/cam01/R"][()], f["cameras/cam01/t"][()]
    # the poses followed: the model's markers where the true poses put them
    from resection.io.cameras import read_camera
    from resection.io.markers import read_markers

    X = read_markers(run.targets).xyz
    cam0 = read_camera(run.calibration)
    err = [np.abs(cam0.with_pose(R=R[k], t=t[k]).project(X)
                  - cam0.with_pose(R=run.poses[k, :3], t=run.poses[k, 3]).project(X)).max()
           for k in range(len(R))]
    assert max(err[1:]) < 0.5
    obl = np.degrees(np.arccos(np.clip(run.cos0, -1, 1)))
    sel0 = (obl < 60) & ~run.near_marker
    sel = sel0 & np.isfinite(q[6:]).all(axis=0)
    assert sel.sum() > 0.8 * sel0.sum()  # the rest leave the image as the model moves
    eq = np.abs(q - run.q)[6:, sel] / run.q0[sel]
    assert np.percentile(eq, 95) < 0.05
    assert np.percentile(np.abs(T - run.T)[:, sel], 95) < 0.5
    # seen at 60-70 deg (to the cut-off): the emissivity at the pixels' view angles
    # (7.8 %; at the nodes' own, 10.9 %)
    graze = (obl >= 60) & (obl < 70) & ~run.near_marker & np.isfinite(q[6:]).all(axis=0)
    assert graze.sum() > 40
    assert np.percentile(np.abs(q - run.q)[6:, graze] / run.q0[graze], 95) < 0.095


@pytest.mark.slow
@pytest.mark.parametrize("child", [False, True])
def test_interrupted_run_resumes(tiny, tmp_path, monkeypatch, child):
    """An interrupted run resumed gives the fresh run's file; with the markers tracked
    by the child process (selfillum.thermal.early), its track kept in the work folder."""
    import selfillum.thermal.phase2 as p2
    import selfillum.thermal.run as run_mod

    monkeypatch.setattr(run_mod, "EARLY_TRACKING_CORES", 0.0 if child else float("inf"))
    out = tmp_path / "r.h5"
    real = p2.run_phase2

    def fail(*a, **k):
        raise RuntimeError("interrupted")

    monkeypatch.setattr(p2, "run_phase2", fail)
    with pytest.raises(RuntimeError):
        run_thermal(_config(tiny, out))
    assert (tmp_path / "r.h5.work").is_dir() and not out.exists()
    assert (tmp_path / "r.h5.work" / "track1" / "poses.csv").is_file()
    monkeypatch.setattr(p2, "run_phase2", real)
    with pytest.raises(Exception, match="give --resume"):
        run_thermal(_config(tiny, out))
    res = run_thermal(_config(tiny, out, resume=True))
    fresh = run_thermal(_config(tiny, tmp_path / "fresh.h5"))
    with h5py.File(res.out) as a, h5py.File(fresh.out) as b:
        np.testing.assert_array_equal(a["heat_flux"][()], b["heat_flux"][()])
    assert not (tmp_path / "r.h5.work").exists()


@pytest.mark.slow
def test_tsp_run_heat_flux_within_5_percent(tmp_path):
    """TSP: dark markers, the Arrhenius paint, the wind-off image in the calibration's
    pose; the same known heat flux."""
    run = make_ir_run(tmp_path / "scene", frames=45, width=240, height=180, nx=41, nphi=32,
                      noise=20.0, tsp={"E_over_R": 2500.0})
    cfg = ThermalConfig(grid=run.grid, cameras=[CameraInput(1, run.video, run.calibration)],
                        out=tmp_path / "tsp.h5", substrate=run.substrate,
                        targets=run.targets, tsp_calibration=run.radiometry,
                        wind_off=[run.folder / "wind_off.npy"], fps=run.fps, plots=False)
    res = run_thermal(cfg)
    assert res.tracked_failed == 0  # dark dots: seen from the first frame
    with h5py.File(res.out) as f:
        T, q = f["temperature"][()], f["heat_flux"][()]
        assert f.attrs["mode"] == "tsp"
    obl = np.degrees(np.arccos(np.clip(run.cos0, -1, 1)))
    sel0 = (obl < 60) & ~run.near_marker
    sel = sel0 & np.isfinite(q[6:]).all(axis=0)
    assert sel.sum() > 0.8 * sel0.sum()
    # the ratio carries the tracked poses' error (0.4 px) times the paint's texture: 0.5 K
    assert np.percentile(np.abs(T - run.T)[:, sel], 95) < 1.0
    assert np.percentile(np.abs(q - run.q)[6:, sel] / run.q0[sel], 95) < 0.05


def test_table_radiometry_and_layered_substrate(tiny, tmp_path):
    """The same run with the camera's calibration as a table (every 5 K) and with a layer
    on the substrate: the table gives the Planck form's temperatures; a layered substrate
    takes the impulse response and refuses Cook-Felderman by name."""
    from scenes.ir_run import PLANCK
    from selfillum.thermal.radiometry import Planck

    pl = Planck(PLANCK["R"], PLANCK["B"], PLANCK["F"], PLANCK["O"])
    d = json.loads(Path(tiny.radiometry).read_text())
    Tt = np.arange(250.0, 500.1, 5.0)
    table = {"table": {"temperature_K": list(Tt), "counts": list(pl.signal(Tt))},
             "O": PLANCK["O"], "emissivity": d["emissivity"],
             "reflected_temperature": d["reflected_temperature"]}
    rj = tmp_path / "table.json"
    rj.write_text(json.dumps(table))
    a = run_thermal(_config(tiny, tmp_path / "planck.h5"))
    b = run_thermal(dataclasses.replace(_config(tiny, tmp_path / "table.h5"), radiometry=rj))
    with h5py.File(a.out) as fa, h5py.File(b.out) as fb:
        Ta, Tb = fa["temperature"][()], fb["temperature"][()]
    fin = np.isfinite(Ta)
    assert fin.any() and np.array_equal(fin, np.isfinite(Tb))
    assert np.max(np.abs(Ta[fin] - Tb[fin])) < 5e-3
    sj = tmp_path / "layers.json"
    sj.write_text(json.dumps({"layers": [{"rho": 1200, "c": 1500, "k": 0.2,
                                          "thickness": 30e-6}],
                              "substrate": json.loads(Path(tiny.substrate).read_text())}))
    c = run_thermal(dataclasses.replace(_config(tiny, tmp_path / "layer.h5"), substrate=sj))
    assert c.method == "impulse"
    with pytest.raises(InputError, match="Cook-Felderman needs one semi-infinite"):
        run_thermal(dataclasses.replace(_config(tiny, tmp_path / "cf.h5"), substrate=sj,
                                        method="cook-felderman"))


def test_grid_turned_inside_out_is_named_not_an_empty_result(tiny, tmp_path):
    """A grid whose faces point into the model (written with its j index reversed): the
    package's maps take a face's normal side as its painted side, so nothing is seen; the
    run says so in one line and leaves no file, instead of an empty result."""
    from resection.io.meshes import write_plot3d
    from resection.io.plot3d import read_plot3d

    (xyz, _), = read_plot3d(str(tiny.grid))
    flipped = tmp_path / "flipped.grid"
    write_plot3d(flipped, [xyz[:, ::-1]])
    out = tmp_path / "b.h5"
    with pytest.raises(InputError, match="no node has a temperature"):
        run_thermal(_config(tiny, out, si=False, grid=flipped))
    assert not out.exists() and not (tmp_path / "b.h5.work").exists()


@pytest.mark.slow
def test_parts_lighting_each_other(tmp_path):
    """A slab with a block on it (scenes.ir_block), the radiosity of every face solved with
    its own view factors (4,096 rays, another seed): the run's removal of the model's own
    radiation brings the heat flux near the block within 5 % (p95); without it, errors near
    the block are several times larger."""
    from scenes.ir_block import make_ir_block_run

    run = make_ir_block_run(tmp_path / "scene")
    err = {}
    for si in (True, False):
        cfg = ThermalConfig(grid=run.grid, out=tmp_path / f"b{si}.h5",
                            cameras=[CameraInput(1, run.video, run.calibration)],
                            substrate=run.substrate, radiometry=run.radiometry, fps=run.fps,
                            registration="none", plots=False, si=si)
        res = run_thermal(cfg)
        with h5py.File(res.out) as f:
            q = f["heat_flux"][()]
            opts = json.loads(f.attrs["options"])
        for name, m in (("plate", run.plate), ("near", run.near)):
            sel = m & np.isfinite(q[6:]).all(axis=0)
            assert sel.sum() >= 0.8 * m.sum()  # the rest lie outside the image
            err[si, name] = np.percentile(np.abs(q - run.q)[6:, sel] / run.q0[sel], 95)
        if si:
            assert opts["si_solves"] > 1  # the hidden faces solved again as they heat
    assert err[True, "plate"] < 0.05 and err[True, "near"] < 0.05
    assert err[False, "near"] > 2 * err[True, "near"]


@pytest.mark.slow
def test_two_cameras(tmp_path):
    """A second camera from the +x side, tracked on its own: the cameras combined
    (average_view, uPSP's) keep the heat flux within 5 % (p95) where camera 1 sees the
    model at less than 60 degrees, and more nodes are seen than by camera 1 alone."""
    run = make_ir_run(tmp_path / "scene", frames=45, width=240, height=180, nx=41, nphi=32,
                      second_camera=True)
    seen = []
    for cams in ([CameraInput(1, run.video, run.calibration)],
                 [CameraInput(1, run.video, run.calibration),
                  CameraInput(2, run.video2, run.calibration2)]):
        cfg = ThermalConfig(grid=run.grid, cameras=cams, out=tmp_path / f"c{len(cams)}.h5",
                            substrate=run.substrate, targets=run.targets,
                            radiometry=run.radiometry, fps=run.fps, plots=False)
        res = run_thermal(cfg)
        with h5py.File(res.out) as f:
            q = f["heat_flux"][()]
            assert len(f["cameras"]) == len(cams)
        seen.append(np.isfinite(q[6:]).all(axis=0).sum())
    obl = np.degrees(np.arccos(np.clip(run.cos0, -1, 1)))
    sel = (obl < 60) & ~run.near_marker & np.isfinite(q[6:]).all(axis=0)
    assert sel.sum() > 250
    assert np.percentile(np.abs(q - run.q)[6:, sel] / run.q0[sel], 95) < 0.05
    assert seen[1] > seen[0]


def test_polynomial_patch_on_a_moving_model(tiny, tmp_path):
    """uPSP's polynomial patch with each frame's tracked pose (the fast way's patch
    operator, whose ring reaches pixels off the model near its edges): the same
    temperatures as the markers left out, away from the markers."""
    a = run_thermal(_config(tiny, tmp_path / "none.h5", target_patcher="none"))
    b = run_thermal(_config(tiny, tmp_path / "poly.h5", target_patcher="polynomial"))
    with h5py.File(a.out) as fa, h5py.File(b.out) as fb:
        Ta, Tb = fa["temperature"][()], fb["temperature"][()]
    sel = ~tiny.near_marker & np.isfinite(Ta).all(axis=0) & np.isfinite(Tb).all(axis=0)
    assert sel.sum() > 100
    assert np.percentile(np.abs(Ta[:, sel] - Tb[:, sel]), 95) < 0.1


def test_a_small_memory_budget_gives_the_same_result(tiny, tmp_path):
    """Blocks of a few frames (Phase 1) and of a few nodes (Phase 2) under a tiny budget:
    the same file's values as one block."""
    a = run_thermal(_config(tiny, tmp_path / "big.h5", memory_mb=None))
    b = run_thermal(_config(tiny, tmp_path / "small.h5", memory_mb=0.01))  # 4 frames, 3 nodes
    with h5py.File(a.out) as fa, h5py.File(b.out) as fb:
        for name in ("temperature", "heat_flux"):
            np.testing.assert_array_equal(fa[name][()], fb[name][()])


def test_phase1_frames_counted(tiny, tmp_path):
    """The file says how Phase 1 mapped the frames: a moving model's frames by the fast
    sparse products through a few references cast from the tracked poses."""
    res = run_thermal(_config(tiny, tmp_path / "ways.h5"))
    with h5py.File(res.out) as f:
        ways = json.loads(f.attrs["options"])["phase1_frames"]
    assert ways["fast"] + ways["full"] == res.n_frames
    assert ways["fast"] >= res.n_frames - 1 and 1 <= ways["references"] <= 4


def test_markers_tracked_in_a_child_process(tiny, tmp_path, monkeypatch):
    """With a core free, the markers are tracked by a child process started before the
    grid is read (selfillum.thermal.early): the same poses and heat flux as the tracking
    in the run's own process, the track kept in the work folder while the run works, and
    no temporary folder left."""
    import selfillum.thermal.early as early
    import selfillum.thermal.run as run_mod

    used = []
    real_adopt = early.EarlyTracking.adopt

    def adopt(self, work):
        got = real_adopt(self, work)
        used.append(sorted(got))
        assert (Path(work) / "track1" / "poses.csv").is_file()
        return got

    monkeypatch.setattr(early.EarlyTracking, "adopt", adopt)
    monkeypatch.setattr(run_mod, "EARLY_TRACKING_CORES", 0.0)  # a core always free
    a = run_thermal(_config(tiny, tmp_path / "child.h5"))
    assert used == [[1]]
    monkeypatch.setattr(run_mod, "EARLY_TRACKING_CORES", float("inf"))  # never
    b = run_thermal(_config(tiny, tmp_path / "here.h5"))
    assert used == [[1]]
    assert a.tracked_failed == b.tracked_failed >= 1
    with h5py.File(a.out) as fa, h5py.File(b.out) as fb:
        for name in ("cameras/cam01/R", "cameras/cam01/t", "heat_flux"):
            np.testing.assert_array_equal(fa[name][()], fb[name][()])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["child.h5", "child.xdmf",
                                                           "here.h5", "here.xdmf"]


def test_bad_input_stops_the_tracking_child(tiny, tmp_path, monkeypatch, capsys):
    """A bad input found after the child has started (the radiometry, read with the grid)
    is named on one line, exit 2; the child is stopped and its folder removed."""
    import selfillum.thermal.early as early
    import selfillum.thermal.run as run_mod

    started = []
    real_close = early.EarlyTracking.close

    def close(self):
        started.append(self.proc.pid)
        real_close(self)
        assert self.proc.poll() is not None  # stopped

    monkeypatch.setattr(early.EarlyTracking, "close", close)
    monkeypatch.setattr(run_mod, "EARLY_TRACKING_CORES", 0.0)
    d = json.loads(Path(tiny.radiometry).read_text())
    d["emissivity"] = 1.5
    rj = tmp_path / "R.json"
    rj.write_text(json.dumps(d))
    assert _cli(tiny, tmp_path / "bad.h5", radiometry=rj) == 2
    err = capsys.readouterr().err.strip()
    assert "emissivity 1.5 is outside (0, 1]" in err and len(err.splitlines()) == 1
    assert len(started) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["R.json"]


def test_a_failed_tracking_child_leaves_the_tracking_to_the_run(tiny, tmp_path, monkeypatch):
    """A child that fails (here: a Python that exits at once) leaves the run to track the
    markers in its own process: the same result as a run that tracks them there."""
    import selfillum.thermal.early as early
    import selfillum.thermal.run as run_mod

    monkeypatch.setattr(run_mod, "EARLY_TRACKING_CORES", 0.0)
    monkeypatch.setattr(early.sys, "executable", "/bin/false")
    a = run_thermal(_config(tiny, tmp_path / "failed.h5"))
    monkeypatch.setattr(run_mod, "EARLY_TRACKING_CORES", float("inf"))
    b = run_thermal(_config(tiny, tmp_path / "here.h5"))
    with h5py.File(a.out) as fa, h5py.File(b.out) as fb:
        np.testing.assert_array_equal(fa["heat_flux"][()], fb["heat_flux"][()])
    assert not [p for p in tmp_path.iterdir() if ".track-" in p.name]
