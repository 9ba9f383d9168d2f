"""``selfillum.unsteady.tracking.TrackingAhead``: a moving model's tracking in a helper
thread hands frame 0's pose over before the other frames are tracked, gives the poses
that tracking in turn gives, and its errors reach the caller when it asks for a pose;
``selfillum.unsteady.tracking_process.TrackingProcess``: the tracking in a child process,
relayed by it, gives the same poses, stops when told, and keeps its files only where the
run keeps its work."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from resection.errors import InputError
from selfillum.unsteady.inputs import track_poses
from selfillum.unsteady.tracking import TrackingAhead, TrackingStopped


def test_frame_zero_before_the_rest_and_the_poses_in_order():
    go = threading.Event()
    asked = []

    def track(i, on_frame):
        asked.append((i, threading.current_thread().name))
        on_frame(0, f"cam{i}-frame0")
        go.wait(10)  # the other frames: tracked once the test lets them
        for k in range(1, 5):
            on_frame(k, f"cam{i}-frame{k}")
        return [f"cam{i}-frame{k}" for k in range(5)], i

    ahead = TrackingAhead(track, 2, 5)
    p0, p1 = ahead.poses(0), ahead.poses(1)
    assert p0[0] == "cam0-frame0"  # before the rest of camera 0 is tracked
    assert not ahead._done.is_set()
    go.set()
    assert p1[0] == "cam1-frame0"
    assert list(p0) == [f"cam0-frame{k}" for k in range(5)]
    assert p1[-1] == "cam1-frame4" and p1[1:3] == ["cam1-frame1", "cam1-frame2"]
    assert len(p1) == 5
    with pytest.raises(IndexError):
        p1[5]
    assert ahead.result()[1] == 1  # the frames that took a neighbour's pose, summed
    assert [a[1] for a in asked] == ["tracking", "tracking"]  # one helper thread
    ahead.stop()  # done already: nothing to stop


def test_frame_zero_failed_takes_the_result():
    def track(i, on_frame):
        on_frame(0, None)  # frame 0 failed: its pose is a later frame's
        on_frame(1, "later")
        return ["later", "later"], 1

    ahead = TrackingAhead(track, 1, 2)
    assert ahead.poses(0)[0] == "later"


def test_an_error_of_the_tracker_reaches_the_caller():
    def track(i, on_frame):
        raise InputError("cam.mraw: tracking found the pose in no frame")

    ahead = TrackingAhead(track, 1, 3)
    with pytest.raises(InputError, match="no frame"):
        ahead.poses(0)[0]
    with pytest.raises(InputError, match="no frame"):
        ahead.poses(0)[2]
    ahead.stop()


def test_stop_ends_the_tracking_at_its_next_frame():
    """A run that ends before its tracking (an error, Ctrl-C) stops it at its next frame
    and waits for the thread."""
    done = []

    def track(i, on_frame):
        for k in range(10_000):
            on_frame(k, f"frame{k}")
            done.append(k)
            time.sleep(0.001)
        return [], 0

    ahead = TrackingAhead(track, 1, 10_000)
    assert ahead.poses(0)[0] == "frame0"
    ahead.stop()
    assert not ahead._thread.is_alive()
    assert 0 < len(done) < 10_000
    with pytest.raises(TrackingStopped):
        ahead.result()


def test_an_error_after_frame_zero_at_the_next_frame():
    def track(i, on_frame):
        on_frame(0, "first")
        raise ValueError("frame 7 unreadable")

    ahead = TrackingAhead(track, 1, 9)
    assert ahead.poses(0)[0] == "first"
    with pytest.raises(ValueError, match="unreadable"):
        ahead.poses(0)[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from scenes.unsteady_run import make_unsteady_run

    return make_unsteady_run(tmp_path_factory.mktemp("tracking_ahead"), frames=24)


def _inputs(run, tmp_path):
    """The run's config, its camera's input, calibrated camera and opened video."""
    from resection.io.cameras import read_camera_file
    from resection.io.upsp_inputs import read_deck
    from resection.io.video import open_frames
    from selfillum.unsteady import config_from_deck

    cfg = config_from_deck(read_deck(run.deck), out=tmp_path / "o.h5", progress=False)
    c = cfg.cameras[0]
    src = open_frames(c.video)
    cam = read_camera_file(c.calibration, image_size=src.shape[::-1]).camera
    return cfg, c, cam, src


def test_the_tracker_gives_frame_zero_early_and_the_same_poses(run, tmp_path, monkeypatch):
    """The real tracker (``track_poses``): the pose handed over early is the run's frame-0
    pose, each pose handed over as solved is the final one, and the poses tracked in the
    helper thread (its fits on one thread, ``fit_threads=1``) equal those tracked in turn
    (the fits on every core)."""
    import resection.markers.refine as refine

    threads = []
    real_blocks = refine._fit_in_blocks

    def blocks(fit, win, w, p, args, workers):
        threads.append(workers)
        return real_blocks(fit, win, w, p, args, workers)

    monkeypatch.setattr(refine, "_fit_in_blocks", blocks)
    cfg, c, cam, src = _inputs(run, tmp_path)
    T = len(src)
    try:
        alone, failed = track_poses(cfg, c, cam, src, T, tmp_path / "alone")
        assert set(threads[1:]) == {None}  # alone: every core after frame 0's
        threads.clear()
        early, handed = [], {}

        def spied(i, on_frame):
            def seen(k, p):
                if k == 0:
                    early.append(p)
                handed[k] = p
                on_frame(k, p)
            return track_poses(cfg, c, cam, src, T, tmp_path / "ahead", on_frame=seen,
                               fit_threads=1)

        ahead = TrackingAhead(spied, 1, T)
        poses = ahead.poses(0)
        first = poses[0]
        got = list(poses)
    finally:
        src.close()
    assert failed == 0 and ahead.result()[1] == 0
    assert len(early) == 1 and first is early[0]
    _assert_same_poses(alone, got)
    np.testing.assert_array_equal(first.R, alone[0].R)
    np.testing.assert_array_equal(first.t, alone[0].t)
    assert set(threads) == {1}  # beside the run: one thread
    assert sorted(handed) == list(range(T))
    for k, p in handed.items():  # each handed over as solved: the final pose
        np.testing.assert_array_equal(p.R, alone[k].R)
        np.testing.assert_array_equal(p.t, alone[k].t)
    # the poses follow the run's vibration: not all the same
    assert np.ptp([p.t[0] for p in got]) > 0


def test_a_stopped_tracking_keeps_its_frames_for_a_resume(run, tmp_path):
    """The real tracker stopped after its first frames: the frames it finished are in its
    folder, and a resumed tracking gives the poses of a tracking run whole."""
    cfg, c, cam, src = _inputs(run, tmp_path)
    T = len(src)
    try:
        gate = threading.Event()

        def slow(i, on_frame):
            def seen(k, p):
                on_frame(k, p)
                if k == 5:
                    gate.set()
                    time.sleep(0.5)  # the caller stops the run here
            return track_poses(cfg, c, cam, src, T, tmp_path / "w", on_frame=seen)

        ahead = TrackingAhead(slow, 1, T)
        assert gate.wait(60)
        ahead.stop()
        with pytest.raises(TrackingStopped):
            ahead.result()
        kept = sorted((tmp_path / "w" / "track1" / "frames").glob("frame_*.json"))
        assert 6 <= len(kept) < T
        resumed, _ = track_poses(cfg, c, cam, src, T, tmp_path / "w", resume=True)
        whole, _ = track_poses(cfg, c, cam, src, T, tmp_path / "whole")
    finally:
        src.close()
    for a, b in zip(whole, resumed, strict=True):
        np.testing.assert_allclose(a.R, b.R, atol=1e-9)
        np.testing.assert_allclose(a.t, b.t, atol=1e-9)


def test_ctrl_c_while_the_tracking_runs_beside_the_set_up(run, tmp_path, monkeypatch, capsys):
    """``selfillum unsteady --registration track``: Ctrl-C in the set-up while the
    tracking runs in its child process ends in exit 130 and one line, the child stopped
    (no process, no relaying thread left), the frames it finished moved from its
    temporary folder into the work folder; ``--resume`` then finishes the run."""
    import multiprocessing
    import tempfile

    import selfillum.unsteady.candidates as candidates
    from resection.sequence import process
    from selfillum.cli import main

    out = tmp_path / "o.h5"
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # the child's own folder
    frames_dir = tmp_path / "o.h5.work" / "track1" / "frames"
    real_track, real_faces = process.track_predicted, candidates.faces_in_view

    def slow_track(*a, **k):  # a frame of a long run (the child is forked: it has this),
        time.sleep(0.25)  # slow enough that the run's set-up comes before the last frame
        return real_track(*a, **k)

    def interrupted(*a, **k):  # the set-up, while the tracking is under way
        for _ in range(400):
            if len(list(scratch.glob("selfillum-track-*/track1/frames/frame_*.json"))) >= 4:
                break
            time.sleep(0.025)
        raise KeyboardInterrupt

    monkeypatch.setattr(process, "track_predicted", slow_track)
    monkeypatch.setattr(candidates, "faces_in_view", interrupted)
    _forked(monkeypatch)
    argv = ["unsteady", str(run.deck), "--paint-calibration", str(run.paint), "--steady",
            str(run.steady), "--fps", str(run.fps), "--out", str(out), "--quiet",
            "--no-plots", "--registration", "track"]
    capsys.readouterr()
    assert main(argv) == 130
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "interrupted" in err, err
    assert not any(t.name == "tracking" for t in threading.enumerate())
    assert not multiprocessing.active_children()
    assert not list(scratch.iterdir())  # the temporary folder moved, then removed
    kept = len(list(frames_dir.glob("frame_*.json")))
    assert 4 <= kept < 24  # stopped at its next frame, what it finished kept
    monkeypatch.setattr(candidates, "faces_in_view", real_faces)
    monkeypatch.setattr(process, "track_predicted", real_track)
    assert main([*argv, "--resume"]) == 0
    assert out.exists() and not (tmp_path / "o.h5.work").exists()
    assert not list(scratch.iterdir())


def _forked(monkeypatch):
    """The child forked whatever threads this test process holds (another test's): it
    then has this test's slowed tracker."""
    import multiprocessing

    from selfillum.unsteady import tracking_process

    monkeypatch.setattr(tracking_process, "_context",
                        lambda: multiprocessing.get_context("fork"))


def _assert_same_poses(a, b):
    """Two sequences of cameras with the same poses, to the bit."""
    for p, q in zip(a, b, strict=True):
        np.testing.assert_array_equal(p.R, q.R)
        np.testing.assert_array_equal(p.t, q.t)


def _tracked_alone(run, tmp_path):
    """The run's config, camera, frames, and its poses tracked in this process (with
    the frames that took a neighbour's)."""
    cfg, c, cam, src = _inputs(run, tmp_path)
    T = len(src)
    try:
        alone, failed = track_poses(cfg, c, cam, src, T, tmp_path / "alone")
    finally:
        src.close()
    return cfg, cam, T, alone, failed


def _motion_camera(cam):
    return lambda m: cam.with_pose(rvec=m[0], t=m[1])


def test_the_child_process_gives_the_poses_of_the_tracking_run_here(run, tmp_path):
    """:class:`TrackingProcess`: the poses its child tracks, relayed by a
    :class:`TrackingAhead`, are those :func:`track_poses` gives in this process, to the
    bit; its files go to the folder it is given, every frame finished."""
    from selfillum.unsteady.tracking_process import TrackingProcess

    cfg, cam, T, alone, failed = _tracked_alone(run, tmp_path)
    proc = TrackingProcess(cfg, tmp_path / "w")
    ahead = proc.ahead
    try:
        poses = ahead.poses(0, T, _motion_camera(cam))
        got = list(poses)
        assert poses[3] is got[3]  # each frame's camera made once
        assert ahead.result()[1] == failed == 0
    finally:
        proc.close()
    _assert_same_poses(alone, got)
    assert len(list((tmp_path / "w" / "track1" / "frames").glob("frame_*.json"))) == T


def test_a_fresh_tracking_is_kept_only_where_the_run_keeps_its_work(run, tmp_path,
                                                                    monkeypatch):
    """Without a folder the child tracks into a temporary one: moved into the folder
    :meth:`TrackingProcess.close` is given (a run that stops before its end keeps it for
    ``--resume``), removed otherwise."""
    import tempfile

    from selfillum.unsteady.tracking_process import TrackingProcess

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    cfg, c, cam, src = _inputs(run, tmp_path)
    T = len(src)
    src.close()
    work = tmp_path / "work"
    work.mkdir()
    for keep in (work, None):
        proc = TrackingProcess(cfg)
        assert proc.folder.parent == scratch
        ahead = proc.ahead
        ahead.result()
        proc.close(keep=keep)
        assert not list(scratch.iterdir())
    assert len(list((work / "track1" / "frames").glob("frame_*.json"))) == T
    assert sorted(p.name for p in work.iterdir()) == ["track1"]


def test_the_child_stops_at_its_next_frame(run, tmp_path, monkeypatch):
    """A stop while the child tracks: it ends at its next frame (not every frame
    tracked), the relay raises :class:`TrackingStopped`, what it finished stays. The
    child runs at a lower priority than the run."""
    from resection.sequence import process
    from selfillum.unsteady.tracking_process import CHILD_NICENESS, TrackingProcess

    real_track = process.track_predicted

    def slow_track(*a, **k):
        time.sleep(0.1)
        return real_track(*a, **k)

    monkeypatch.setattr(process, "track_predicted", slow_track)  # forked: the child's
    _forked(monkeypatch)
    cfg, c, cam, src = _inputs(run, tmp_path)
    T = len(src)
    src.close()
    proc = TrackingProcess(cfg, tmp_path / "w")
    ahead = proc.ahead
    ahead.poses(0, T)[2]
    if hasattr(os, "getpriority"):  # the run's work first: the child at a lower priority
        own = os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, proc.pid) == min(own + CHILD_NICENESS, 19)
    ahead.stop()
    with pytest.raises(TrackingStopped):
        ahead.result()
    proc.close()
    kept = len(list((tmp_path / "w" / "track1" / "frames").glob("frame_*.json")))
    assert 3 <= kept < T


def test_an_input_error_of_the_child_reaches_the_caller(run, tmp_path):
    """A targets file the child cannot read: its one-line error, naming the file, is
    raised where the run asks for a pose."""
    import dataclasses

    from selfillum.unsteady.tracking_process import TrackingProcess

    cfg, c, cam, src = _inputs(run, tmp_path)
    src.close()
    bad = tmp_path / "bad.tgts"
    bad.write_text("not a targets file\n")
    proc = TrackingProcess(dataclasses.replace(cfg, targets=bad), tmp_path / "w")
    ahead = proc.ahead
    try:
        with pytest.raises(InputError, match="bad.tgts"):
            ahead.poses(0, 24)[0]
    finally:
        proc.close()


def test_spawned_where_another_thread_runs(run, tmp_path):
    """A caller with a thread of its own running is never forked: the child is spawned
    (a fresh interpreter) and gives the same poses."""
    from selfillum.unsteady import tracking_process
    from selfillum.unsteady.tracking_process import TrackingProcess

    cfg, cam, T, alone, _ = _tracked_alone(run, tmp_path)
    hold = threading.Event()
    other = threading.Thread(target=hold.wait, args=(60,))
    other.start()
    try:
        assert tracking_process._context().get_start_method() == "spawn"
        proc = TrackingProcess(cfg, tmp_path / "w")
    finally:
        hold.set()
        other.join()
    ahead = proc.ahead
    try:
        got = list(ahead.poses(0, T, _motion_camera(cam)))
    finally:
        proc.close()
    _assert_same_poses(alone, got)


def test_each_solved_frame_handed_over_before_the_tracking_ends():
    """A frame's pose is handed over as soon as it is solved (the plan's pieces wait for
    their own frames only); a failed frame waits for the result, which gives it a
    neighbour's pose."""
    go = threading.Event()

    def track(i, on_frame):
        for k in range(3):
            on_frame(k, f"frame{k}")
        on_frame(3, None)  # failed: takes a neighbour's pose in the result
        go.wait(10)
        on_frame(4, "frame4")
        return ["frame0", "frame1", "frame2", "frame2", "frame4"], 1

    ahead = TrackingAhead(track, 1, 5)
    poses = ahead.poses(0)
    assert poses[2] == "frame2"  # before the tracking goes on
    assert not ahead._done.is_set()
    got = []
    waiter = threading.Thread(target=lambda: got.append(poses[3]))
    waiter.start()
    waiter.join(0.2)
    assert waiter.is_alive() and not got  # the failed frame waits for the result
    go.set()
    waiter.join(10)
    assert got == ["frame2"] and poses[4] == "frame4"
    ahead.stop()


def _run_in_daemon(argv):
    import sys

    from selfillum.cli import main

    sys.exit(main(argv))


def test_a_daemonic_process_tracks_in_a_thread(run, tmp_path):
    """A Dask worker's process is daemonic and may start no child (``selfillum entry`` on
    a cluster): the run tracks in its relaying thread there, and writes the dCp of the
    run tracked in a child process, to the bit."""
    import multiprocessing

    import h5py

    from selfillum.cli import main

    def argv(out):
        return ["unsteady", str(run.deck), "--paint-calibration", str(run.paint),
                "--steady", str(run.steady), "--fps", str(run.fps), "--out", str(out),
                "--quiet", "--no-plots", "--registration", "track"]

    p = multiprocessing.get_context("spawn").Process(
        target=_run_in_daemon, args=(argv(tmp_path / "d.h5"),), daemon=True)
    p.start()
    p.join(600)
    assert p.exitcode == 0  # (a child started there fails the run: no children allowed)
    assert main(argv(tmp_path / "c.h5")) == 0
    with h5py.File(tmp_path / "d.h5") as d, h5py.File(tmp_path / "c.h5") as c:
        np.testing.assert_array_equal(d["dcp"][()], c["dcp"][()])
