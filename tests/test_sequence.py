"""Sequences: a synthetic run with a known model motion (scenes.moving_model) tracked by
``resection.sequence.track``; interruption and resume, corrupt frames, Dask, CLI, plot.

The reference is the scene's truth: the motion is built from explicit rotation matrices and
the frames are rendered at the exact projections of the markers (pixel-integrated blurred
noisy disks), independently of the tracking code.
"""

from __future__ import annotations

import json
import os
from types import SimpleNamespace

import numpy as np
import pytest

from resection import InputError
from resection import sequence as seq
from resection.cli.main import main
from resection.io.cameras import read_camera
from resection.sequence import execute as seq_execute
from resection.sequence import process as seq_process
from resection.sequence import read_track, relative_motion
from resection.sequence import track as _track
from scenes.moving_model import pitch_oscillation, rotation_zyx, write_sequence

N_FAST = 60


def track(*args, workers=1, **kw):
    """``track`` in this process (its default is a local Dask cluster) unless a test asks
    for workers."""
    return _track(*args, workers=workers, **kw)


def _model(n):
    return pitch_oscillation(n)


@pytest.fixture(scope="module")
def run60(tmp_path_factory):
    """60 frames written to disk and tracked once, in this process."""
    base = tmp_path_factory.mktemp("seq60")
    model = _model(N_FAST)
    files = write_sequence(model, base / "frames")
    cam = read_camera(files["camera"])
    res = track(files["frames"], cam, files["markers"], diameter=5.6, out_dir=base / "out",
                progress=False)
    return model, files, cam, res, base


def _check_against_truth(model, res, n):
    assert res.ok.all(), res.reason[~res.ok]
    # attitude and position change relative to frame 0
    ang_err = res.angles - np.degrees(model.angles[:n])
    assert np.abs(ang_err).max() < 0.01
    assert np.abs(res.translation - model.translation[:n]).max() < 1e-4  # 0.1 mm
    # the motion is really there (a test of a static model would pass trivially)
    assert np.ptp(res.angles[:, 1]) > 1.0
    # marker positions against the true projections
    truth = np.stack([model.uv(k) for k in range(n)])
    got = res.marker_positions(model.ids)
    assert np.isfinite(got).all()  # every marker found in every frame
    rms = np.sqrt(np.mean(np.sum((got - truth) ** 2, axis=-1)))
    assert rms < 0.05
    return rms, np.abs(ang_err).max()


def test_track_recovers_known_motion(run60):
    model, files, cam, res, base = run60
    _check_against_truth(model, res, N_FAST)
    assert res.n_computed == N_FAST and res.reference == 0
    # the CSV files hold the same numbers
    back = read_track(base / "out")
    np.testing.assert_allclose(back.angles, res.angles, atol=1e-8)
    np.testing.assert_allclose(back.translation, res.translation, atol=1e-12)
    np.testing.assert_allclose(back.marker_uv, res.marker_uv, atol=1e-6)
    assert back.status.tolist() == ["ok"] * N_FAST
    assert back.file.tolist() == files["frames"]
    with open(base / "out" / "poses.csv") as fh:
        assert fh.readline().strip() == ",".join(seq.POSE_COLUMNS)
    with open(base / "out" / "markers.csv") as fh:
        assert fh.readline().strip() == "frame,id,u,v,residual,residual_u,residual_v"


@pytest.mark.slow
def test_track_500_frames(tmp_path):
    model = _model(500)
    files = write_sequence(model, tmp_path / "frames")
    cam = read_camera(files["camera"])
    res = track(files["frames"], cam, files["markers"], diameter=5.6, out_dir=tmp_path / "out",
                progress=False)
    _check_against_truth(model, res, 500)


def test_large_excursion_chunks_repaired(tmp_path):
    # +-16 degrees at 2 Hz: chunks starting far from frame 0 cannot be matched from it; the
    # sequential repair pass matches them from the previous good frame instead
    model = pitch_oscillation(24, amplitude_deg=16.0, frequency_hz=2.0)
    files = write_sequence(model, tmp_path / "frames")
    cam = read_camera(files["camera"])
    res = track(files["frames"], cam, files["markers"], diameter=5.6, out_dir=tmp_path / "o",
                progress=False, chunk_size=8)
    assert res.ok.all(), res.reason[~res.ok]
    assert np.abs(res.angles - np.degrees(model.angles)).max() < 0.01
    assert np.ptp(res.angles[:, 1]) > 28.0
    used = [json.load(open(p))["matched_from"]
            for p in sorted((tmp_path / "o" / "frames").glob("*.json"))]
    assert used[0] == -1 and used[1] == 0
    assert any(used[k] == k - 1 for k in (9, 17))  # a chunk start that needed the repair


def test_relative_motion_against_scene_truth():
    model = _model(40)
    cams = [model.camera_at(k) for k in range(40)]
    rv = np.array([c.rvec for c in cams])
    tv = np.array([c.t for c in cams])
    ang, tr = relative_motion(rv, tv, 0)
    np.testing.assert_allclose(ang, np.degrees(model.angles), atol=1e-10)
    np.testing.assert_allclose(tr, model.translation, atol=1e-12)
    # the angles rebuild M with the explicit Rz Ry Rx product
    M = rotation_zyx(*np.radians(ang).T)
    np.testing.assert_allclose(M, [model.camera.R.T @ c.R for c in cams], atol=1e-12)
    # moving camera: displacement of the perspective centre, rotation R_k^T R_0
    ang_c, tr_c = relative_motion(rv, tv, 0, fixed_camera=False)
    np.testing.assert_allclose(tr_c, [c.center - cams[0].center for c in cams], atol=1e-12)
    Mc = rotation_zyx(*np.radians(ang_c).T)
    np.testing.assert_allclose(Mc, [c.R.T @ cams[0].R for c in cams], atol=1e-12)
    rv[3] = np.nan
    ang, tr = relative_motion(rv, tv, 0)
    assert np.isnan(ang[3]).all() and np.isfinite(ang[4]).all()
    with pytest.raises(InputError, match="reference frame 3 has no pose"):
        relative_motion(rv, tv, 3)


def test_interrupt_and_resume(run60, tmp_path, monkeypatch):
    model, files, cam, ref, _ = run60
    frames = files["frames"]
    out = tmp_path / "out"
    # a first run over the first half
    half = track(frames[:30], cam, files["markers"], diameter=5.6, out_dir=out, progress=False)
    assert half.n_computed == 30
    mtimes = {p: os.stat(p).st_mtime_ns for p in (out / "frames").glob("*.json")}
    assert len(mtimes) == 30
    # then an interruption (Ctrl-C) in the middle of the next run
    calls = {"n": 0}
    load = seq_process.load_image

    def interrupted(frame, *args):  # Ctrl-C while the 12th frame of this run is read
        calls["n"] += 1
        if calls["n"] == 12:
            raise KeyboardInterrupt
        return load(frame, *args)

    monkeypatch.setattr(seq_process, "load_image", interrupted)
    with pytest.raises(KeyboardInterrupt):
        track(frames, cam, files["markers"], diameter=5.6, out_dir=out, progress=False)
    assert len(list((out / "frames").glob("*.json"))) == 30 + 11
    assert not list((out / "frames").glob("*.tmp"))
    # resume: only the 19 missing frames are computed, the finished files are not touched
    calls["n"] = -10**9
    res = track(frames, cam, files["markers"], diameter=5.6, out_dir=out, progress=False)
    assert res.n_computed == N_FAST - 41
    assert calls["n"] == -10**9 + N_FAST - 41
    for p, t in mtimes.items():
        assert os.stat(p).st_mtime_ns == t
    # and the result is the one of the uninterrupted run
    np.testing.assert_allclose(res.angles, ref.angles, atol=1e-9)
    np.testing.assert_allclose(res.marker_uv, ref.marker_uv, atol=1e-9)
    # a run with other settings in the same directory is refused, resume=False redoes all
    with pytest.raises(InputError, match="other settings"):
        track(frames, cam, files["markers"], diameter=6.0, out_dir=out, progress=False)
    with pytest.raises(InputError, match="frame 0 was"):
        track(frames[3:], cam, files["markers"], diameter=5.6, out_dir=out, progress=False)


def test_corrupt_frames_are_recorded_and_skipped(tmp_path):
    model = _model(24)
    files = write_sequence(model, tmp_path / "frames")
    frames = list(files["frames"])
    with open(frames[9], "wb") as fh:  # unreadable file
        fh.write(b"\x93NUMPY garbage")
    np.save(frames[10], np.full((256, 256), np.nan, np.float32))  # all-NaN image
    frames[15] = str(tmp_path / "frames" / "missing.npy")  # file that does not exist
    np.save(frames[17], np.full((200, 256), 1000.0, np.float32))  # wrong size
    cam = read_camera(files["camera"])
    res = track(frames, cam, files["markers"], diameter=5.6, out_dir=tmp_path / "out",
                progress=False, chunk_size=8)
    bad = [9, 10, 15, 17]
    assert np.flatnonzero(~res.ok).tolist() == bad
    assert "frame_00009.npy" in res.reason[9]
    assert "cannot read image" in res.reason[9] or "not a valid .npy" in res.reason[9]
    assert "no finite pixel" in res.reason[10] or "masked" in res.reason[10]
    assert "no such image" in res.reason[15]
    assert "256x200" in res.reason[17]
    assert np.isnan(res.angles[bad]).all() and (res.n_markers[bad] == 0).all()
    good = np.flatnonzero(res.ok)
    np.testing.assert_allclose(res.angles[good], np.degrees(model.angles[good]), atol=0.01)
    with open(tmp_path / "out" / "poses.csv") as fh:
        rows = fh.read().splitlines()
    assert rows[11].split(",")[2] == "failed"  # header + frame 10
    assert len(rows) == 25


def test_dask_two_workers_same_as_one(run60, tmp_path):
    import logging

    from dask.distributed import LocalCluster

    model, files, cam, _, _ = run60
    n = 30  # three chunks of 10 frames, in this process and on two workers
    ref = track(files["frames"][:n], cam, files["markers"], diameter=5.6,
                out_dir=tmp_path / "one", progress=False, chunk_size=10)
    # an existing cluster, given by its scheduler address (the CLI test covers workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        res = track(files["frames"][:n], cam, files["markers"], diameter=5.6,
                    out_dir=tmp_path / "o", scheduler=cluster.scheduler_address,
                    progress=False, chunk_size=10)
    assert res.n_computed == n
    assert res.status.tolist() == ref.status[:n].tolist()
    np.testing.assert_allclose(res.angles, ref.angles[:n], atol=1e-9)
    np.testing.assert_allclose(res.translation, ref.translation[:n], atol=1e-12)
    sel = ref.marker_frame < n
    assert res.marker_id.tolist() == ref.marker_id[sel].tolist()
    np.testing.assert_allclose(res.marker_uv, ref.marker_uv[sel], atol=1e-9)


def test_cli_track_and_plot(run60, tmp_path, capsys):
    model, files, cam, ref, _ = run60
    out = tmp_path / "cli"
    rc = main(["track", *files["frames"][:12], "--camera", files["camera"], "--markers",
               files["markers"], "--diameter", "5.6", "--out", str(out), "--fps", "50",
               "--no-progress", "--chunk-size", "5", "--workers", "2"])
    assert rc == 0
    assert "12/12 frames solved" in capsys.readouterr().out
    back = read_track(out)
    np.testing.assert_allclose(back.angles, ref.angles[:12], atol=1e-8)
    png = out / "pose_vs_time.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    with open(out / "track.json") as fh:
        assert json.load(fh)["chunk_size"] == 5
    # bad input: one line on stderr, exit status 2
    rc = main(["track", files["frames"][0], "--camera", str(tmp_path / "nope.json"),
               "--markers", files["markers"], "--diameter", "5.6", "--out", str(out)])
    assert rc == 2
    assert "nope.json" in capsys.readouterr().err


def test_first_frame_linked_by_hand(run60, tmp_path):
    from resection.io.images import read_image
    from resection.markers.detect import detect_markers
    from resection.markers.link import suggest_links, write_links

    model, files, cam, ref, _ = run60
    # the person's linking of frame 0 (candidate numbers as `resection detect` writes them)
    cands = detect_markers(read_image(files["frames"][0]), 5.6)
    ids, index = suggest_links(cands, model.camera_at(0), (model.ids, model.points3d))
    assert len(ids) == len(model.ids)
    link = tmp_path / "link.csv"
    write_links(link, ids, index)
    # with a link the camera's pose is not used: give a useless one
    far = cam.with_pose(R=np.eye(3), t=[0.0, 0.0, 5.0])
    n = 12
    res = track(files["frames"][:n], far, files["markers"], link=link, diameter=5.6,
                out_dir=tmp_path / "o", progress=False)
    assert res.ok.all()
    np.testing.assert_allclose(res.angles, ref.angles[:n], atol=1e-7)
    np.testing.assert_allclose(res.rvec, ref.rvec[:n], atol=1e-9)
    # without the link, that camera cannot start the run
    res = track(files["frames"][:2], far, files["markers"], diameter=5.6,
                out_dir=tmp_path / "o2", progress=False)
    assert not res.ok[0] and res.reason[0].startswith("SolveError")
    # a linking that does not fit the first frame's candidates is an input error
    write_links(link, ids[:3], [0, 1, 999])
    with pytest.raises(InputError, match="candidate 999 does not exist"):
        track(files["frames"][:2], far, files["markers"], link=link, diameter=5.6,
              out_dir=tmp_path / "o3", progress=False)
    with pytest.raises(InputError, match="no such linking file"):
        track(files["frames"][:2], far, files["markers"], link=tmp_path / "none.csv",
              diameter=5.6, out_dir=tmp_path / "o4", progress=False)


def test_plot_motion_draws_the_result(run60, tmp_path):
    from resection.sequence.motion_plots import plot_motion

    model, files, cam, ref, _ = run60
    fig = plot_motion(ref, tmp_path / "m.png", fps=50, length_unit="mm", length_scale=1000,
                      truth=(np.degrees(model.angles), model.translation))
    ang_ax, tr_ax, rms_ax = fig.axes[:3]
    lines = {ln.get_label(): ln for ln in ang_ax.lines}
    np.testing.assert_allclose(lines["pitch"].get_xdata(), np.arange(N_FAST) / 50)
    np.testing.assert_allclose(lines["pitch"].get_ydata(), ref.angles[:, 1])
    np.testing.assert_allclose({ln.get_label(): ln for ln in tr_ax.lines}["dz"].get_ydata(),
                               1000 * ref.translation[:, 2])
    np.testing.assert_allclose(rms_ax.lines[0].get_ydata(), ref.rms)
    assert (tmp_path / "m.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError, match="fps"):
        plot_motion(ref, fps=0)


def test_in_memory_frames(run60, tmp_path):
    model, files, cam, ref, _ = run60
    stack = np.stack([model.image(k) for k in range(6)])  # (F, H, W) array
    res = track(stack, cam, (model.ids, model.points3d), diameter=5.6, out_dir=tmp_path / "m",
                progress=False)
    assert res.ok.all() and res.file.tolist() == [""] * 6
    np.testing.assert_allclose(res.angles, ref.angles[:6], atol=1e-9)


def test_bad_input(run60, tmp_path):
    model, files, cam, ref, _ = run60
    kw = dict(out_dir=tmp_path / "o", progress=False)
    with pytest.raises(InputError, match="empty"):
        track([], cam, files["markers"], diameter=5.6, **kw)
    with pytest.raises(InputError, match="diameter"):
        track(files["frames"], cam, files["markers"], diameter=-1, **kw)
    with pytest.raises(InputError, match="polarity"):
        track(files["frames"], cam, files["markers"], diameter=5.6, polarity="grey", **kw)
    with pytest.raises(InputError, match="workers"):
        track(files["frames"], cam, files["markers"], diameter=5.6, workers=0, **kw)
    with pytest.raises(InputError, match="camera"):
        track(files["frames"], "cam.json", files["markers"], diameter=5.6, **kw)
    with pytest.raises(InputError, match="frames\\[1\\]"):
        track([files["frames"][0], 3], cam, files["markers"], diameter=5.6, **kw)
    with pytest.raises(InputError, match="duplicate"):
        track(files["frames"], cam, (["a", "a", "b"], np.eye(3)), diameter=5.6, **kw)
    with pytest.raises(InputError, match="not found"):
        read_track(tmp_path / "nothing")
    with pytest.raises(InputError, match="cannot connect to the Dask scheduler at 'foo bar'"):
        track(files["frames"][:3], cam, files["markers"], diameter=5.6, scheduler="foo bar",
              **kw)


def test_dask_interruption_keeps_every_finished_frame(run60, tmp_path, monkeypatch):
    # Each frame's result file is written inside the Dask task as soon as the frame is
    # finished, not when its chunk returns: a run stopped in the middle of a chunk keeps
    # the frames that chunk had finished, and resuming computes only the rest.
    import logging

    from dask.distributed import LocalCluster

    model, files, cam, ref, _ = run60
    n, stop = 20, 15
    process = seq_process.process_frame

    def dies_at_frame(frame, index, setup, reference, previous=None, **kw):
        if index == stop:  # the run is stopped while the chunk (frames 1..19) is in flight
            raise RuntimeError("interrupted")
        return process(frame, index, setup, reference, previous, **kw)

    monkeypatch.setattr(seq_process, "process_frame", dies_at_frame)
    out = tmp_path / "o"
    # in-process workers (threads) so that the patch reaches the task
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster:
        with pytest.raises(RuntimeError, match="interrupted"):
            track(files["frames"][:n], cam, files["markers"], diameter=5.6, out_dir=out,
                  scheduler=cluster.scheduler_address, chunk_size=n - 1, progress=False)
    written = sorted(int(p.stem.split("_")[1]) for p in (out / "frames").glob("*.json"))
    assert written == list(range(stop))  # frame 0 (client) and 1..14 (the task)
    assert not list((out / "frames").glob("*.tmp"))
    monkeypatch.setattr(seq_process, "process_frame", process)
    res = track(files["frames"][:n], cam, files["markers"], diameter=5.6, out_dir=out,
                chunk_size=n - 1, progress=False)
    assert res.n_computed == n - stop
    np.testing.assert_allclose(res.angles, ref.angles[:n], atol=1e-9)
    np.testing.assert_allclose(res.marker_uv, ref.marker_uv[ref.marker_frame < n], atol=1e-9)


def test_default_is_local_workers_and_client_writes_unshared_frames(run60, tmp_path,
                                                                    monkeypatch, capsys):
    # Without --workers/--scheduler the CLI (and track) use local worker processes, one
    # per CPU core. The executor is replaced here by one that runs the chunks as a worker
    # that cannot write would: it writes no file, so the client must write every frame
    # when the chunk comes back.
    model, files, cam, ref, _ = run60
    seen = {}

    def fake_pool(setup, tasks, before, on_chunk, on_poll, workers, frames_dir, local=None):
        seen.update(workers=workers, frames_dir=frames_dir, polls=on_poll is not None)
        if local is not None:
            local()
        for items, s, done in tasks:
            on_chunk(seq_process.run_chunk(setup, items, s, done))

    monkeypatch.setattr(seq_execute, "_execute_pool", fake_pool)
    monkeypatch.setattr(os, "cpu_count", lambda: 3)
    # a run this short is finished sooner in this process than by starting workers
    out = tmp_path / "short"
    rc = main(["track", *files["frames"][:8], "--camera", files["camera"], "--markers",
               files["markers"], "--diameter", "5.6", "--out", str(out), "--no-progress",
               "--chunk-size", "3"])
    assert rc == 0 and "8/8 frames solved" in capsys.readouterr().out and not seen
    # with workers that start at no cost, the chunks after the first (timed here) go to
    # the cluster: three chunks, the first here, two workers for the two others
    monkeypatch.setattr(seq_execute, "LOCAL_CLUSTER_START_S", 0.0)
    monkeypatch.setattr(seq_execute, "server_wait", lambda since: 0.0)  # a ready server
    monkeypatch.setattr(seq_execute, "free_cores", lambda *a: 3.0)  # an idle machine
    out = tmp_path / "cli"
    rc = main(["track", *files["frames"][:8], "--camera", files["camera"], "--markers",
               files["markers"], "--diameter", "5.6", "--out", str(out), "--no-progress",
               "--chunk-size", "3"])
    assert rc == 0 and "8/8 frames solved" in capsys.readouterr().out
    assert seen["workers"] == 2 and not seen["polls"]  # no progress bar: no polling
    assert os.path.isabs(seen["frames_dir"])
    assert len(list((out / "frames").glob("frame_*.json"))) == 8
    np.testing.assert_allclose(read_track(out).angles, ref.angles[:8], atol=1e-9)
    # nothing left to do on a resume
    res = _track(files["frames"][:8], cam, files["markers"], diameter=5.6, out_dir=out,
                 chunk_size=3, progress=False)
    assert res.n_computed == 0
    # no more local workers than chunks: three chunks, two workers; two chunks (one
    # left after the first), no cluster; one chunk, no cluster
    seen.clear()
    _track(files["frames"][:10], cam, files["markers"], diameter=5.6,
           out_dir=tmp_path / "b", chunk_size=3, progress=False)
    assert seen["workers"] == 2
    seen.clear()
    _track(files["frames"][:8], cam, files["markers"], diameter=5.6,
           out_dir=tmp_path / "b2", chunk_size=4, progress=False)
    assert not seen
    seen.clear()
    res = _track(files["frames"][:4], cam, files["markers"], diameter=5.6,
                 out_dir=tmp_path / "c", chunk_size=4, progress=False)
    assert not seen and res.ok.all() and res.n_computed == 4


def test_cluster_pays_only_when_it_finishes_sooner():
    from resection.sequence.execute import cluster_pays

    # 3 s to start two workers: they finish 10 s of work in 3 + 5 s, but not 5 s (3 + 2.5)
    assert cluster_pays(10.0, 2, start_s=3.0) and not cluster_pays(5.0, 2, start_s=3.0)
    assert cluster_pays(4.0, 4, start_s=2.0) and not cluster_pays(100.0, 1, start_s=0.0)


def test_free_cores_count_the_load(monkeypatch, tmp_path):
    from resection.sequence import execute
    from resection.sequence.load import LoadWindow, cpu_ticks

    # without a window: the 1-minute load average, this process counted back
    monkeypatch.setattr(os, "getloadavg", lambda: (3.9, 3.0, 2.0))
    monkeypatch.setattr("resection._threads.available_cores", lambda: 2)
    assert execute.free_cores() == 1.0  # 2 cores, 2.9 busy besides this process
    monkeypatch.setattr(os, "getloadavg", lambda: (1.5, 1.0, 1.0))
    monkeypatch.setattr("resection._threads.available_cores", lambda: 16)
    assert execute.free_cores() == 15.5
    # over a window: the cores' busy ticks in /proc/stat (user nice system idle iowait irq
    # softirq steal), less this process's own CPU time and its helpers'
    stat = tmp_path / "stat"

    def write(ticks):
        stat.write_text("cpu  0 0 0 0 0 0 0 0\n" + "".join(
            f"cpu{c} {u} 0 0 {i} 0 0 0 0 0 0\n" for c, (u, i) in enumerate(ticks)))

    monkeypatch.setattr("resection._threads.core_ids", lambda: [0, 1])
    monkeypatch.setattr("resection._threads.available_cores", lambda: 2)
    write([(100, 900), (50, 950)])
    assert cpu_ticks([0, 1], str(stat)) == (150, 2000)
    assert cpu_ticks([0, 2], str(stat)) is None  # a CPU missing: no figure
    clock = {"cpu": 10.0, "wall": 100.0}  # this process's CPU and wall seconds
    monkeypatch.setattr("resection.sequence.load.time", SimpleNamespace(
        process_time=lambda: clock["cpu"], perf_counter=lambda: clock["wall"]))
    w = LoadWindow.start(str(stat))
    # an idle machine but for this process (one core for 1 s) and the pool's server
    write([(200, 900), (150, 950)])
    clock.update(cpu=11.0, wall=101.0)
    assert w.free_cores(helpers=1.0) == 2.0
    # the same ticks without the server: one core of other work
    assert w.free_cores(helpers=0.0) == pytest.approx(1.0)
    # this process sharing its core with other work (half of it): one core and a half busy
    clock.update(cpu=10.5)
    assert w.free_cores(helpers=1.0) == pytest.approx(1.5)
    # half the second core idle, the server counted: nothing else ran
    write([(200, 900), (100, 1000)])
    clock.update(cpu=11.0)
    assert w.free_cores(helpers=0.5) == 2.0
    # a lagging load average (a job just ended) does not count when ticks are at hand
    monkeypatch.setattr(os, "getloadavg", lambda: (11.0, 5.0, 2.0))
    assert w.free_cores(helpers=1.0) == 2.0


def test_pose_options_reach_every_solve(run60, tmp_path, capsys):
    model, files, cam, ref, _ = run60
    frames = files["frames"][:3]
    # the frames' RMS is a few hundredths of a pixel: a 0.5 px limit changes nothing, a
    # 1e-4 px one refuses every frame (through the matcher's verifying solves)
    assert np.nanmax(ref.rms[:3]) < 0.1
    res = track(frames, cam, files["markers"], diameter=5.6, out_dir=tmp_path / "a",
                pose_kw={"max_rms": 0.5, "robust": "huber"}, progress=False)
    assert res.ok.all()
    np.testing.assert_allclose(res.angles, ref.angles[:3], atol=1e-3)
    out = tmp_path / "b"
    rc = main(["track", *frames, "--camera", files["camera"], "--markers", files["markers"],
               "--diameter", "5.6", "--out", str(out), "--no-progress", "--workers", "1",
               "--pose-options", '{"max_rms": 1e-4}'])
    assert rc == 1
    back = read_track(out)
    assert (back.status == "failed").all()
    assert all("max_rms" in r for r in back.reason), back.reason
    # option names are checked before any frame is processed
    kw = dict(out_dir=tmp_path / "c", progress=False)
    with pytest.raises(InputError, match="pose_kw.*max_rmss"):
        track(frames, cam, files["markers"], diameter=5.6, pose_kw={"max_rmss": 1}, **kw)
    with pytest.raises(InputError, match="refine_intrinsics.*set by track"):
        track(frames, cam, files["markers"], diameter=5.6,
              pose_kw={"refine_intrinsics": "focal"}, **kw)
    with pytest.raises(InputError, match="detect_kw.*k_sigmaa"):
        track(frames, cam, files["markers"], diameter=5.6, detect_kw={"k_sigmaa": 4}, **kw)
    with pytest.raises(InputError, match="match_kw.*tolerence"):
        track(frames, cam, files["markers"], diameter=5.6, match_kw={"tolerence": 4}, **kw)
    assert not (tmp_path / "c").exists()
    rc = main(["track", *frames, "--camera", files["camera"], "--markers", files["markers"],
               "--diameter", "5.6", "--out", str(out), "--pose-options", "{max_rms: 1}"])
    assert rc == 2 and "--pose-options: not valid JSON" in capsys.readouterr().err


def test_cli_ctrl_c_says_what_is_kept(run60, tmp_path, monkeypatch, capsys):
    model, files, cam, ref, _ = run60
    calls = {"n": 0}
    load = seq_process.load_image

    def interrupted(frame, *args):
        calls["n"] += 1
        if calls["n"] == 3:  # Ctrl-C while frame 2 is being processed
            raise KeyboardInterrupt
        return load(frame, *args)

    monkeypatch.setattr(seq_process, "load_image", interrupted)
    out = tmp_path / "o"
    args = ["track", *files["frames"][:4], "--camera", files["camera"], "--markers",
            files["markers"], "--diameter", "5.6", "--out", str(out), "--no-progress",
            "--workers", "1"]
    assert main(args) == 130
    err = capsys.readouterr().err
    assert "interrupted: 2/4 frames finished are kept" in err and "again to resume" in err
    monkeypatch.setattr(seq_process, "load_image", load)
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "4/4 frames solved (2 computed now)" in out
    # frame 0 matched from the approximate camera, the others tracked by prediction
    assert "3 tracked by prediction, 1 by the statistical matcher" in out


def test_frames_of_integer_files_have_saturated_pixels_masked(tmp_path):
    import tifffile

    from resection.sequence.frames import load_image

    img = np.full((20, 30), 1000, np.uint16)
    img[5:8, 10:14] = 65535
    tifffile.imwrite(tmp_path / "f.tif", img)
    out = load_image(tmp_path / "f.tif")
    assert out.shape == (20, 30) and np.isnan(out).sum() == 12
    assert np.all(np.isnan(out[5:8, 10:14])) and np.all(out[~np.isnan(out)] == 1000)


def test_frames_from_one_multi_frame_file(run60, tmp_path):
    """A sequence given as one file holding every frame (a 3-D NPY stack and a multi-page
    TIFF, read through resection.io.video one frame at a time) tracks as the same frames
    given as files; a failed frame names the file and the frame; resume knows the file."""
    import tifffile

    model, files, cam, ref, _ = run60
    n = 12
    stack = np.stack([np.load(f) for f in files["frames"][:n]]).astype(np.float32)
    stack[5] = np.nan  # a frame with nothing to see
    np.save(tmp_path / "run.npy", stack)
    tifffile.imwrite(tmp_path / "run.tif", stack)
    good = np.arange(n) != 5
    for name in ("run.npy", "run.tif"):
        out = tmp_path / f"out_{name}"
        res = track(tmp_path / name, cam, files["markers"], diameter=5.6, out_dir=out,
                    progress=False, chunk_size=4)
        assert len(res) == n and res.ok.tolist() == good.tolist()
        np.testing.assert_allclose(res.angles[good], ref.angles[:n][good], atol=1e-6)
        assert res.file[3] == f"{tmp_path / name}#3"
        assert f"{tmp_path / name}#5" in res.reason[5]
        again = track([str(tmp_path / name)], cam, files["markers"], diameter=5.6,
                      out_dir=out, progress=False, chunk_size=4)
        assert again.n_computed == 0
    # the CLI takes the file as its one frame argument
    rc = main(["track", str(tmp_path / "run.npy"), "--camera", files["camera"], "--markers",
               files["markers"], "--diameter", "5.6", "--out", str(tmp_path / "cli"),
               "--no-progress", "--workers", "1", "--chunk-size", "4"])
    assert rc == 0
    np.testing.assert_allclose(read_track(tmp_path / "cli").angles[good],
                               ref.angles[:n][good], atol=1e-6)


def test_memory_does_not_grow_with_the_frames(run60, tmp_path):
    """Issue 13 item 4, the fast check (the former bench/bench_track_memory.py follows the RSS over
    10,000 frames): while the frames are computed, the memory held grows by well under
    1 kB a frame (a finished frame is kept as its file and two numbers: about 0.2 kB;
    keeping each frame's whole record, as before, holds about 12 kB a frame here)."""
    import tracemalloc

    from resection.sequence.execute import run_frames
    from resection.sequence.inputs import checked

    model, files, cam, _, _ = run60
    held = {}
    for n in (20, 80):
        frames = [files["frames"][k % 20] for k in range(n)]  # 20 frames, again and again
        frames, setup, _, _, _ = checked(
            frames, cam, files["markers"], link=None, diameter=5.6, polarity="dark",
            workers=1, chunk_size=20, min_markers=4, roi_margin=40.0, detect_kw=None,
            match_kw=None, pose_kw=None)
        fdir = tmp_path / f"o{n}" / "frames"
        fdir.mkdir(parents=True)
        done: dict = {}
        tracemalloc.start()
        try:
            base = tracemalloc.get_traced_memory()[0]
            run_frames(frames, setup, None, done, chunk_size=20, workers=1, scheduler=None,
                       frames_dir=fdir, progress=False)
            held[n] = tracemalloc.get_traced_memory()[0] - base
        finally:
            tracemalloc.stop()
        assert len(done) == n and all(v[0] for v in done.values())
    per_frame = (held[80] - held[20]) / 60
    assert per_frame < 1000, held


def test_a_chunk_that_fails_from_a_far_seed_is_left_to_the_sequential_pass(run60, tmp_path):
    """A chunk seeded from frame 0 (as on a cluster) whose first frame fails computes no
    more: its other frames are recorded as deferred, not computed; the sequential pass
    then computes them from the good frame before them, and they agree with the run in
    this process."""
    from resection.sequence.execute import _chunks
    from resection.sequence.inputs import checked
    from resection.sequence.process import DEFERRED, process_frame, repair, run_chunk

    model, files, cam, ref, _ = run60
    n = 12
    frames = list(files["frames"][:n])
    bad = tmp_path / "corrupt.npy"
    bad.write_bytes(b"not an image")
    frames[5] = str(bad)  # the first frame of the second chunk (frames 5 to 8)
    frames, setup, _, _, _ = checked(
        frames, cam, files["markers"], link=None, diameter=5.6, polarity="dark", workers=1,
        chunk_size=4, min_markers=4, roi_margin=40.0, detect_kw=None, match_kw=None,
        pose_kw=None)
    first = process_frame(frames[0], 0, setup, None)
    tasks = _chunks(frames, {}, first, 4, tmp_path)
    items, seed, done = tasks[1]
    assert [i for i, _ in items] == [5, 6, 7, 8] and seed.frame == 0
    computed = []
    dicts = run_chunk(setup, items, seed, done, on_frame=computed.append)
    assert [d["status"] for d in dicts] == ["failed"] * 4
    assert dicts[0]["matched_from"] == 0 and "corrupt.npy" in dicts[0]["reason"]
    assert all(d["matched_from"] == DEFERRED and "not computed" in d["reason"]
               for d in dicts[1:])
    # the sequential pass: every frame of chunks 1 and 3 good, chunk 2 as recorded
    from resection.sequence.outputs import write_frame
    from resection.sequence.results import FrameResult

    fdir = tmp_path / "frames"
    fdir.mkdir()
    state = {}
    for task in (tasks[0], tasks[2]):
        for d in run_chunk(setup, *task[:3]):
            state[d["frame"]] = d
    for d in dicts:
        state[d["frame"]] = d
    state[0] = first.to_dict()
    for d in state.values():
        write_frame(fdir, FrameResult.from_dict(d))
    summary = {i: (state[i]["status"] == "ok", state[i]["matched_from"]) for i in range(n)}
    redone = {}

    def record(res):
        redone[res.frame] = res
        write_frame(fdir, res)

    repair(frames, setup, summary, record, fdir)
    assert sorted(redone) == [5, 6, 7, 8]  # the corrupt frame is tried once more
    assert not redone[5].ok and all(redone[i].ok for i in (6, 7, 8))
    for i in (6, 7, 8):
        np.testing.assert_allclose(redone[i].rvec, ref.rvec[i], atol=1e-7)
