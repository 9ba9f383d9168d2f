"""``selfillum.unsteady.frames.FramesAhead``: the next frame made in a helper thread gives
what making each frame in turn gives, in the same order of calls, and its errors reach
the caller at that frame."""

from __future__ import annotations

import threading
import time

import pytest

from selfillum.unsteady.frames import FramesAhead, Helping


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


def test_make_sees_whether_the_caller_waits_and_shares_its_blocks():
    """While the caller waits for the frame in flight, ``Helping.waiting`` is true and the
    caller takes blocks of the kernel the helper runs (``Helping.run``): every block once,
    some in each thread; a frame made while the caller is busy sees it not waiting. An
    error in a block (whichever thread ran it) reaches the caller at that frame."""
    helping = Helping()
    made = {k: threading.Event() for k in range(4)}
    seen, ran = {}, {}
    caller_took = threading.Event()
    me = threading.current_thread().name

    def block(b):
        ran[b] = threading.current_thread().name
        if ran[b] == me:
            caller_took.set()
        else:  # the helper holds on until the caller has taken a block
            assert caller_took.wait(timeout=30)
        if b == 13:
            raise ValueError("block 13 is bad")

    def make(k):
        if k in (1, 3):  # asked for at once: the caller waits while this is made
            deadline = time.monotonic() + 30
            while not helping.waiting() and time.monotonic() < deadline:
                time.sleep(0.001)
            seen[k] = helping.waiting()
            caller_took.clear()
            first = 0 if k == 1 else 10  # blocks 0-9, then 10-19
            helping.run(lambda b: block(first + b[0]), 10, 1)
        else:
            seen[k] = helping.waiting()
        made[k].set()
        return k

    ahead = FramesAhead(make, range(4), helping=helping)
    try:
        assert ahead.get(0) == 0  # made in the caller's thread, frame 1 sent ahead
        assert ahead.get(1) == 1  # waited for (its blocks shared): frame 2 sent ahead
        assert not helping.waiting()
        assert made[2].wait(timeout=30)  # the caller busy meanwhile
        assert ahead.get(2) == 2
        with pytest.raises(ValueError, match="block 13 is bad"):
            ahead.get(3)
    finally:
        ahead.close()
    assert seen == {0: False, 1: True, 2: False, 3: True}
    first = {b: ran[b] for b in range(10)}
    assert set(first) == set(range(10))
    assert me in first.values() and any(t != me for t in first.values())
