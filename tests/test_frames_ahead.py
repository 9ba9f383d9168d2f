"""``selfillum.unsteady.frames.FramesAhead``: the next frame made in a helper thread gives
what making each frame in turn gives, in the same order of calls, and its errors reach
the caller at that frame."""

from __future__ import annotations

import threading
import time

import pytest

from selfillum.unsteady.frames import FramesAhead


class _Stateful:
    """``make(k)``: a value that depends on the frames made before (like the
    registration, which starts from the last warp), the calls recorded with their
    threads."""

    def __init__(self, fail_at=None):
        self.last = 0
        self.calls = []
        self.fail_at = fail_at

    def __call__(self, k):
        time.sleep(0.002)
        self.calls.append((k, threading.current_thread().name))
        if k == self.fail_at:
            raise ValueError(f"frame {k} is bad")
        self.last = 10 * self.last + k
        return self.last


def test_made_ahead_equals_made_in_turn_and_runs_in_the_helper():
    frames = [3, 4, 5, 7, 8]
    turn = _Stateful()
    want = [turn(k) for k in frames]
    make = _Stateful()
    with FramesAhead(make, frames) as ahead:
        got = [ahead.get(k) for k in frames]
    assert got == want
    assert [k for k, _ in make.calls] == frames  # each once, in order
    assert all(name.startswith("frames-ahead") for _, name in make.calls[1:])
    assert not any(t.name.startswith("frames-ahead") and t.is_alive()
                   for t in threading.enumerate())  # closed: the helper ended


def test_drop_discards_the_frame_in_flight_and_makes_it_again():
    make = _Stateful()
    with FramesAhead(make, [0, 1, 2]) as ahead:
        assert ahead.get(0) == 0
        ahead.drop()  # frame 1 was in flight: finished, then discarded
        make.last = 5  # the caller changes what make reads
        assert ahead.get(1) == 51  # made again from the changed state
        assert ahead.get(2) == 512
    assert [k for k, _ in make.calls] == [0, 1, 1, 2]


def test_an_error_made_ahead_is_raised_at_its_frame():
    make = _Stateful(fail_at=2)
    with FramesAhead(make, [0, 1, 2, 3]) as ahead:
        assert ahead.get(0) == 0
        assert ahead.get(1) == 1  # frame 2 fails meanwhile, not raised yet
        with pytest.raises(ValueError, match="frame 2 is bad"):
            ahead.get(2)


def test_a_frame_out_of_order_is_made_in_the_caller():
    make = _Stateful()
    with FramesAhead(make, [0, 1, 2]) as ahead:
        ahead.get(0)
        assert ahead.get(2) == 12  # frame 1 in flight: finished, discarded; 2 made here
    assert [k for k, _ in make.calls] == [0, 1, 2]
    assert make.calls[2][1] == threading.current_thread().name


def test_make_sees_whether_the_caller_waits():
    """``waiting`` is set exactly while the caller waits for the frame in flight: a frame
    made while the caller is busy sees it clear, one the caller already waits for sees
    it set (a moving model's faces are then left to the caller, which is idle)."""
    waits = threading.Event()
    made = {k: threading.Event() for k in range(3)}
    seen = {}

    def make(k):
        if k == 1:  # the caller asks for frame 1 at once: it waits while this is made
            seen[k] = waits.wait(timeout=30)
        else:
            seen[k] = waits.is_set()
        made[k].set()
        return k

    ahead = FramesAhead(make, range(3), waiting=waits)
    try:
        assert ahead.get(0) == 0  # made in the caller's thread, frame 1 sent ahead
        assert ahead.get(1) == 1  # waited for: frame 2 sent ahead
        assert not waits.is_set()
        assert made[2].wait(timeout=30)  # the caller busy meanwhile
        assert ahead.get(2) == 2
    finally:
        ahead.close()
    assert seen == {0: False, 1: True, 2: False}
