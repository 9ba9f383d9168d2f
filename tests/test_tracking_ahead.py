"""``selfillum.unsteady.tracking.TrackingAhead``: a moving model's tracking in a helper
thread hands frame 0's pose over before the other frames are tracked, gives the poses
that tracking in turn gives, and its errors reach the caller when it asks for a pose."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from resection.errors import InputError
from selfillum.unsteady.tracking import TrackingAhead


def test_frame_zero_before_the_rest_and_the_poses_in_order():
    go = threading.Event()
    asked = []

    def track(i, on_first):
        asked.append((i, threading.current_thread().name))
        on_first(f"cam{i}-frame0")
        go.wait(10)  # the other frames: tracked once the test lets them
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
    ahead.wait()


def test_frame_zero_failed_takes_the_result():
    ahead = TrackingAhead(lambda i, on_first: (["later", "b"], 1), 1, 2)
    assert ahead.poses(0)[0] == "later"


def test_an_error_of_the_tracker_reaches_the_caller():
    def track(i, on_first):
        raise InputError("cam.mraw: tracking found the pose in no frame")

    ahead = TrackingAhead(track, 1, 3)
    with pytest.raises(InputError, match="no frame"):
        ahead.poses(0)[0]
    with pytest.raises(InputError, match="no frame"):
        ahead.poses(0)[2]
    ahead.wait()


def test_an_error_after_frame_zero_at_the_next_frame():
    def track(i, on_first):
        on_first("first")
        raise ValueError("frame 7 unreadable")

    ahead = TrackingAhead(track, 1, 9)
    assert ahead.poses(0)[0] == "first"
    with pytest.raises(ValueError, match="unreadable"):
        ahead.poses(0)[1]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from scenes.unsteady_run import make_unsteady_run

    return make_unsteady_run(tmp_path_factory.mktemp("tracking_ahead"), frames=24)


def test_the_tracker_gives_frame_zero_early_and_the_same_poses(run, tmp_path):
    """The real tracker (``track_poses``): the pose handed over early is the run's frame-0
    pose, and the poses tracked in the helper thread equal those tracked in turn."""
    from resection.io.cameras import read_camera_file
    from resection.io.upsp_inputs import read_deck
    from resection.io.video import open_frames
    from selfillum.unsteady import config_from_deck
    from selfillum.unsteady.inputs import track_poses

    cfg = config_from_deck(read_deck(run.deck), out=tmp_path / "o.h5", progress=False)
    c = cfg.cameras[0]
    src = open_frames(c.video)
    try:
        cam = read_camera_file(c.calibration, image_size=src.shape[::-1]).camera
        T = len(src)
        alone, failed = track_poses(cfg, c, cam, src, T, tmp_path / "alone")
        early = []
        ahead = TrackingAhead(lambda i, on_first: track_poses(
            cfg, c, cam, src, T, tmp_path / "ahead",
            on_first=lambda p: (early.append(p), on_first(p))), 1, T)
        poses = ahead.poses(0)
        first = poses[0]
        got = list(poses)
    finally:
        src.close()
    assert failed == 0 and ahead.result()[1] == 0
    assert len(early) == 1 and first is early[0]
    for a, b in zip(alone, got, strict=True):
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(first.R, alone[0].R)
    np.testing.assert_array_equal(first.t, alone[0].t)
    # the poses follow the run's vibration: not all the same
    assert np.ptp([p.t[0] for p in got]) > 0
