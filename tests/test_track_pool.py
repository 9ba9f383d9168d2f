"""Local worker processes of ``track`` and the restart of deferred chunks.

A pitch oscillation of +-16 degrees (scenes.moving_model): the chunks that start far from
frame 0 cannot be tracked from it. On two real worker processes (forked from the pool's
server) they must be started again from the chunk before them, give the scene's truth and
the same result as one process, and leave nothing to the sequential repair pass.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from resection.io.cameras import read_camera
from resection.sequence import execute as seq_execute
from resection.sequence import process as seq_process
from resection.sequence import track
from resection.sequence.chain import ChunkChain, is_deferred
from resection.sequence.pool import SERVER_READY_S, server_wait
from resection.sequence.process import DEFERRED
from resection.sequence.results import FrameResult
from scenes.moving_model import pitch_oscillation, write_sequence


def frames_here(monkeypatch) -> list[int]:
    """The frames this process tracks from now on, in order (workers are not seen)."""
    here: list[int] = []
    process = seq_process.process_frame

    def spy(frame, index, *a, **k):
        here.append(index)
        return process(frame, index, *a, **k)

    monkeypatch.setattr(seq_process, "process_frame", spy)
    monkeypatch.setattr(seq_execute, "process_frame", spy)
    return here


def workers_start_free(monkeypatch) -> None:
    """Two idle cores and workers that cost nothing to start (their server ready)."""
    monkeypatch.setattr(seq_execute, "LOCAL_CLUSTER_START_S", 0.0)
    monkeypatch.setattr(seq_execute, "server_wait", lambda since: 0.0)
    monkeypatch.setattr(seq_execute, "free_cores", lambda *a: 2.0)


def _ok(frame: int, matched_from: int | None = None) -> dict:
    return FrameResult(frame=frame, file="", status="ok", rvec=np.zeros(3),
                       tvec=np.array([0.0, 0.0, 1.0]), rms=0.1,
                       matched_from=frame - 1 if matched_from is None else matched_from
                       ).to_dict()


def _failed(frames, matched_from) -> list[dict]:
    return [FrameResult(frame=f, file="", status="failed", reason="x",
                        matched_from=matched_from).to_dict() for f in frames]


def _deferred(frames) -> list[dict]:
    return _failed(frames, DEFERRED)


def test_chain_starts_a_deferred_chunk_from_the_one_before():
    # three chunks of 3 frames after a first one (frames 1-3) run here: 4-6, 7-9, 10-12
    chain = ChunkChain([0, 0, 0], before=None)
    # chunk 1 (7-9) defers while chunk 0 runs: it waits
    assert chain.came_back(1, _deferred([7, 8, 9])) == []
    assert chain.waiting == [1]
    # chunk 0 comes back good: chunk 1 starts from its last two good frames (6, then 5)
    ready = chain.came_back(0, [_ok(4), _ok(5), _ok(6)])
    assert [(k, ref.frame, prev.frame) for k, (ref, prev) in ready] == [(1, 6, 5)]
    assert chain.waiting == []
    # chunk 2 deferred after chunk 1 is known to be restarted, not done: waits for it
    assert chain.came_back(2, _deferred([10, 11, 12])) == []
    # chunk 1's second run comes back with its last frame failed: chunk 2 starts from 8, 7
    res = [_ok(7), _ok(8), *_failed([9], 8)]
    ready = chain.came_back(1, res)
    assert [(k, ref.frame, prev.frame) for k, (ref, prev) in ready] == [(2, 8, 7)]
    # a chunk deferred a second time is not started again (left to the repair pass)
    assert chain.came_back(2, _deferred([10, 11, 12])) == []
    assert chain.waiting == []
    assert is_deferred(_deferred([1])) and not is_deferred([_ok(3)])


def test_chain_waits_for_the_chunk_run_beside_the_workers():
    # the first chunk's rest runs in this process while the workers take the others: the
    # frames before chunk 0 are known only when it is done
    chain = ChunkChain([0, 0], before=None, known=False)
    assert chain.came_back(0, _deferred([11, 12, 13])) == []
    assert chain.waiting == [0]
    ready = chain.set_before(tuple(FrameResult.from_dict(_ok(f)) for f in (10, 9)))
    assert [(k, ref.frame, prev.frame) for k, (ref, prev) in ready] == [(0, 10, 9)]
    # nothing good before it: left to the repair pass
    chain = ChunkChain([0, 0], before=None, known=False)
    assert chain.came_back(0, _deferred([11, 12, 13])) == []
    assert chain.set_before(None) == [] and chain.waiting == []


def test_chain_does_not_restart_from_the_same_seed():
    # the first chunk after frame 0, seeded from frame 0 (a Dask scheduler: no chunk here)
    zero = FrameResult.from_dict(_ok(0, -1))
    chain = ChunkChain([0, 0], before=(zero, None))
    assert chain.came_back(0, _deferred([1, 2])) == []  # no closer frame than frame 0
    assert chain.waiting == []
    # one chunk with no good frame passes on the frames before it
    chain = ChunkChain([0, 0, 0], before=(zero, None))
    assert chain.came_back(2, _deferred([7, 8, 9])) == []
    assert chain.came_back(0, _failed([1, 2, 3], 0)) == []
    ready = chain.came_back(1, [_ok(4), _ok(5), _ok(6)])
    assert [(k, ref.frame) for k, (ref, _) in ready] == [(2, 6)]


def test_server_wait_counts_down_from_its_start():
    assert server_wait(None) == SERVER_READY_S  # none: spawned workers load it themselves
    assert server_wait(time.perf_counter()) == pytest.approx(SERVER_READY_S, abs=0.1)
    assert server_wait(time.perf_counter() - 0.5) == pytest.approx(SERVER_READY_S - 0.5,
                                                                    abs=0.1)
    assert server_wait(time.perf_counter() - 60.0) == 0.0


def test_a_short_run_does_not_wait_for_the_server(sweep, tmp_path, monkeypatch):
    # 32 frames on two idle cores: the workers would wait for their server longer than the
    # frames take here, so the run stays in this process
    model, files, cam = sweep
    monkeypatch.setattr(seq_execute, "free_cores", lambda *a: 2.0)
    here = frames_here(monkeypatch)
    res = track(files["frames"], cam, files["markers"], out_dir=tmp_path / "o", workers=2,
                diameter=5.6, progress=False, chunk_size=8)
    assert res.ok.all() and sorted(here) == list(range(32))


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    base = tmp_path_factory.mktemp("sweep")
    model = pitch_oscillation(32, amplitude_deg=16.0, frequency_hz=2.0)
    files = write_sequence(model, base / "frames")
    return model, files, read_camera(files["camera"])


@pytest.mark.parametrize("probe", [10, 3])
def test_workers_restart_deferred_chunks_and_agree_with_one_process(sweep, tmp_path,
                                                                     monkeypatch, probe):
    # probe 3: the first chunk's first 3 frames are timed here, its other 5 run here
    # while the workers take the three chunks after it
    model, files, cam = sweep
    monkeypatch.setattr(seq_execute, "PROBE_FRAMES", probe)
    kw = dict(diameter=5.6, progress=False, chunk_size=8)
    one = track(files["frames"], cam, files["markers"], out_dir=tmp_path / "one", workers=1,
                **kw)
    assert one.ok.all()
    # workers that cost nothing to start on an idle machine: the three chunks after the
    # first (run here, timed) go to two worker processes
    workers_start_free(monkeypatch)
    here = {"frames": frames_here(monkeypatch), "repaired": 0}
    repair = seq_execute.repair

    def spy_repair(frames, setup, done, record, frames_dir):
        def counted(res):
            here["repaired"] += 1
            record(res)
        return repair(frames, setup, done, counted, frames_dir)

    monkeypatch.setattr(seq_execute, "repair", spy_repair)
    out = tmp_path / "two"
    res = track(files["frames"], cam, files["markers"], out_dir=out, workers=2, **kw)
    # frames 0-8 here, the rest in the workers (the spy does not reach them)
    assert here["frames"] == list(range(9))
    assert res.ok.all() and res.n_computed == 32
    assert here["repaired"] == 0  # the deferred chunks were started again on the workers
    used = [json.load(open(p))["matched_from"] for p in sorted((out / "frames").glob("*.json"))]
    starts = [k for k in (9, 17, 25) if used[k] == k - 1]
    assert starts, used  # at least one chunk start tracked from the frame before it
    assert all(used[k] in (0, k - 1) for k in (9, 17, 25))
    # the scene's truth, and one process's result: the same to the solver's convergence
    # where the same markers are matched. The frame after a chunk start tracked from frame
    # 0 is predicted with the mean velocity since frame 0 (one process: since the frame
    # before), and in this fast motion (+-16 deg at 2 Hz) may miss a marker or two.
    assert np.abs(res.angles - np.degrees(model.angles)).max() < 0.01
    ids = [json.load(open(d / "frames" / f"frame_{k:06d}.json"))["ids"]
           for d in (tmp_path / "one", out) for k in range(32)]
    same = np.array([a == b for a, b in zip(ids[:32], ids[32:], strict=True)])
    assert same.sum() >= 32 - 3, np.flatnonzero(~same)  # at most one frame a chunk
    np.testing.assert_allclose(res.angles[same], one.angles[same], atol=1e-6)
    np.testing.assert_allclose(res.translation[same], one.translation[same], atol=1e-9)
    np.testing.assert_allclose(res.angles, one.angles, atol=2e-3)


def test_interrupt_with_workers_keeps_finished_frames(sweep, tmp_path, monkeypatch):
    model, files, cam = sweep
    workers_start_free(monkeypatch)
    on_chunk = seq_execute._on_chunk

    def stopped(frames_dir, note, remote):
        handle = on_chunk(frames_dir, note, remote)

        def first_back(dicts):
            handle(dicts)
            raise KeyboardInterrupt  # Ctrl-C when the first chunk comes back
        return first_back

    monkeypatch.setattr(seq_execute, "_on_chunk", stopped)
    out = tmp_path / "o"
    kw = dict(diameter=5.6, progress=False, chunk_size=8, workers=2)
    with pytest.raises(KeyboardInterrupt):
        track(files["frames"], cam, files["markers"], out_dir=out, **kw)
    kept = sorted(int(p.stem.split("_")[1]) for p in (out / "frames").glob("frame_*.json"))
    assert kept[:9] == list(range(9)) and len(kept) >= 9 + 8  # and the chunk(s) that ran
    assert all(json.load(open(out / "frames" / f"frame_{k:06d}.json"))["frame"] == k
               for k in kept)
    assert not list((out / "frames").glob("*.tmp"))
    monkeypatch.setattr(seq_execute, "_on_chunk", on_chunk)
    res = track(files["frames"], cam, files["markers"], out_dir=out, **kw)
    assert res.ok.all() and res.n_computed <= 32 - 9
    assert np.abs(res.angles - np.degrees(model.angles)).max() < 0.01


def test_spawned_workers_where_there_is_no_fork_server(sweep, tmp_path, monkeypatch):
    # Windows has no fork server: the workers are spawned and load the package themselves
    import multiprocessing

    from resection.sequence import pool

    methods = [m for m in multiprocessing.get_all_start_methods() if m != "forkserver"]
    monkeypatch.setattr(pool.multiprocessing, "get_all_start_methods", lambda: methods)
    assert pool.start_server() is None and pool._context().get_start_method() == "spawn"
    model, files, cam = sweep
    workers_start_free(monkeypatch)
    here = frames_here(monkeypatch)
    res = track(files["frames"][:17], cam, files["markers"], out_dir=tmp_path / "o",
                workers=2, diameter=5.6, progress=False, chunk_size=4)
    assert here == list(range(5))  # frames 5-16 in the spawned workers
    assert res.ok.all() and res.n_computed == 17
    assert np.abs(res.angles - np.degrees(model.angles[:17])).max() < 0.01


def test_the_server_starts_first_only_with_cores_to_spare(monkeypatch):
    from resection.sequence import run

    frames = [f"f{k}.npy" for k in range(200)]
    monkeypatch.setattr("resection._threads.available_cores", lambda: 16)
    assert run._may_use_workers(frames, None, None, 50)
    assert not run._may_use_workers(frames[:101], None, None, 50)  # two chunks, no more
    assert not run._may_use_workers(frames, "tcp://host:8786", None, 50)  # Dask's own
    assert not run._may_use_workers(frames, None, 1, 50)  # in this process
    assert not run._may_use_workers("run.cine", None, None, 50)  # not known yet
    monkeypatch.setattr("resection._threads.available_cores", lambda: 2)
    assert not run._may_use_workers(frames, None, None, 50)  # beside the reference frame


def test_deferred_placeholders_are_not_finished_frames(tmp_path):
    # what Ctrl-C reports as kept: a deferred chunk's placeholders are computed on resume
    from resection.sequence.outputs import finished_frames, frame_path, write_frame

    for d in [_ok(0, -1), _ok(1), *_failed([2], 1), *_deferred([3, 4])]:
        write_frame(tmp_path, FrameResult.from_dict(d))
    frame_path(tmp_path, 5).write_text("{truncated", encoding="utf-8")  # unreadable
    assert finished_frames(tmp_path) == 3  # two good, one failed for good


def test_a_resumed_run_computes_deferred_placeholders_in_their_chunk(sweep, tmp_path):
    # a run stopped while a deferred chunk waited: its placeholders are not kept
    from resection.sequence.frames import fingerprint, frame_name
    from resection.sequence.outputs import _read_manifest, start_run, write_frame

    model, files, cam = sweep
    frames, out = files["frames"][:16], tmp_path / "o"
    first = track(frames, cam, files["markers"], out_dir=out, workers=1, diameter=5.6,
                  progress=False, chunk_size=8)
    for k in (10, 11, 12):
        write_frame(out / "frames", FrameResult(
            frame=k, file=frame_name(frames[k]), status="failed", reason="deferred",
            matched_from=DEFERRED, source=fingerprint(frames[k])))
    done = start_run(out, frames, _read_manifest(out / "track.json"), True)
    # 13-15 were predicted from 12, computed again: they are computed again too
    assert sorted(done) == list(range(10))
    assert not any((out / "frames" / f"frame_{k:06d}.json").exists() for k in range(10, 16))
    res = track(frames, cam, files["markers"], out_dir=out, workers=1, diameter=5.6,
                progress=False, chunk_size=8)
    assert res.ok.all() and res.n_computed == 6
    # the scene's truth; the frames kept are the first run's, and the others agree with it
    # as a chunk start does in this fast motion (resumed, frame 10 is predicted from frame
    # 9 with the mean velocity since frame 0, the seed of the resumed chunk, not from 8)
    assert np.abs(res.angles - np.degrees(model.angles[:16])).max() < 0.01
    np.testing.assert_array_equal(res.angles[:10], first.angles[:10])
    np.testing.assert_allclose(res.angles, first.angles, atol=2e-3)
