"""The next frame's images made while this frame is mapped.

Phase 1's fast way does two kinds of work a frame: reading and registering the frame (the
video's decode, the affine fit and the warp at the operator's pixels, compiled kernels
that release Python's global interpreter lock) and mapping it (the sparse products onto
the faces, the self-illumination, the nodes). :class:`FramePrefetch` runs the first kind
for frame ``k + 1`` in one background thread while the caller does the second for frame
``k``, so the two use two cores instead of taking turns on one.

Frames are made in the order given, one at a time, so a registration that starts from the
previous frame's warp sees the frames in order. Before the caller reads a frame itself
(the full way), :meth:`FramePrefetch.settle` waits for the frame being made, so that a
video reader is never used from two threads at once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

__all__ = ["FramePrefetch"]


class FramePrefetch:
    """Make ``make(k)`` for the frame after ``k`` in a background thread.

    Parameters
    ----------
    make : callable
        ``make(k)``: frame ``k``'s images (read, registered, sampled).
    frames : sequence of int
        The frames in the order they will be asked for.

    Notes
    -----
    An exception raised while making a frame is raised by :meth:`get` of that frame, in
    the caller's thread. Use as a context manager (or call :meth:`close`) so that the
    thread ends with the run.
    """

    def __init__(self, make: Callable[[int], Any], frames: Sequence[int]):
        self._make = make
        order = [int(k) for k in frames]
        self._after = dict(zip(order[:-1], order[1:], strict=True))
        self._pool: ThreadPoolExecutor | None = None
        self._pending: tuple[int, Future] | None = None

    def get(self, k: int):
        """Frame ``k``'s images (made ahead when it was the next frame), and the next
        frame's started."""
        k = int(k)
        if self._pending is not None and self._pending[0] == k:
            images = self._pending[1].result()
            self._pending = None
        else:
            self.settle()
            self._pending = None
            images = self._make(k)
        nxt = self._after.get(k)
        if nxt is not None:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1,
                                                thread_name_prefix="frame-prefetch")
            self._pending = (nxt, self._pool.submit(self._make, nxt))
        return images

    def settle(self) -> None:
        """Wait for the frame being made (its result, or its error, kept for :meth:`get`)."""
        if self._pending is not None:
            self._pending[1].exception()

    def close(self) -> None:
        """Wait for the frame being made and end the thread."""
        self.settle()
        self._pending = None
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self) -> FramePrefetch:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
