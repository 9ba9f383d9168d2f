"""Frames read ahead on a thread (resection.sequence.prefetch)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from resection.sequence import prefetch
from resection.sequence.frames import fingerprint
from resection.sequence.prefetch import FramePrefetcher


def test_frames_come_in_order_with_their_fingerprints(tmp_path):
    paths = []
    for i in range(5):
        p = tmp_path / f"f{i}.npy"
        np.save(p, np.full((4, 6), i, np.uint8))
        paths.append(p)
    with FramePrefetcher(paths, depth=2) as reader:
        for i, p in enumerate(paths):
            got = reader.take()
            assert got.source == fingerprint(p)
            assert got.get().shape == (4, 6) and np.all(got.get() == i)
        with pytest.raises(IndexError):
            reader.take()


def test_reads_at_most_depth_ahead_and_stops_on_close(monkeypatch):
    """Memory stays flat: no more than ``depth`` frames are read beyond the one taken;
    after close() no further frame is read."""
    started = []
    gate = threading.Event()

    def slow_load(frame, sources=None):
        started.append(frame)
        gate.wait(5)
        return np.zeros((2, 2))

    monkeypatch.setattr(prefetch, "load_image", slow_load)
    frames = [f"frame{i}" for i in range(10)]  # not files: fingerprints are [-1, ...]
    reader = FramePrefetcher(frames, depth=3)
    gate.set()
    reader.take()
    reader.take()
    reader.close()
    # two frames taken, three queued after the last one taken at most
    assert 2 <= len(started) <= 2 + 3
    assert started == frames[:len(started)]


def test_a_frame_that_cannot_be_read_gives_its_error_where_it_is_taken(tmp_path):
    good = tmp_path / "good.npy"
    np.save(good, np.zeros((3, 3), np.uint8))
    bad = tmp_path / "missing.npy"
    with FramePrefetcher([good, bad, good]) as reader:
        assert reader.take().error is None
        failed = reader.take()
        assert failed.source == [-1, -1, -1, -1, ""] and failed.image is None
        with pytest.raises(Exception, match="missing.npy"):
            failed.get()
        assert reader.take().get().shape == (3, 3)  # the run goes on after a bad frame
