"""Frames read ahead on a thread while the frames before them are tracked.

Tracking is a chain (each frame is predicted from the frames before it), but reading a
frame is not: its fingerprint (:func:`~resection.sequence.frames.fingerprint`) and its
image (:func:`~resection.sequence.frames.load_image`) depend on the file alone. A
:class:`FramePrefetcher` reads the frames of a chunk in order on one thread, at most
``depth`` frames ahead of the one being tracked, so that reading (file I/O and NumPy's
conversions, which release Python's GIL) overlaps the tracking of the frame before. Memory
stays flat: at most ``depth + 1`` images are held.

The reading thread owns the multi-frame files it opens (``sources``); they are closed by
:meth:`FramePrefetcher.close` once the thread has stopped. A frame that cannot be read
gives its exception back where the frame is taken, so its failure is recorded as it would
be without reading ahead.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from resection.sequence.frames import fingerprint, load_image

__all__ = ["LoadedFrame", "FramePrefetcher"]

#: Frames read ahead by default: enough to hide a slow read behind one fast frame.
DEPTH = 2


@dataclass(frozen=True)
class LoadedFrame:
    """A frame as read: its fingerprint (taken before the read) and its image, or the
    exception the read raised."""

    source: list | None
    image: np.ndarray | None
    error: BaseException | None = None

    def get(self) -> np.ndarray:
        """The image, or the read's exception raised again."""
        if self.error is not None:
            raise self.error
        return self.image


class FramePrefetcher:
    """Read ``frames`` (in this order) on one thread, ``depth`` frames ahead.

    Parameters
    ----------
    frames : sequence
        The frames to read (paths, arrays or :class:`~resection.sequence.frames.VideoFrame`),
        taken in the same order with :meth:`take`.
    depth : int
        Frames read ahead of the one taken last (at least 1).

    Use as a context manager; :meth:`take` returns the next frame's :class:`LoadedFrame`.
    """

    def __init__(self, frames: Sequence, depth: int = DEPTH):
        self._frames = list(frames)
        self._depth = max(1, int(depth))
        self._sources: dict = {}
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="track-read")
        self._pending: list[Future] = []
        self._next = 0  # next frame to submit
        for _ in range(min(self._depth, len(self._frames))):
            self._submit()

    def _submit(self) -> None:
        if self._next < len(self._frames):
            frame = self._frames[self._next]
            self._next += 1
            self._pending.append(self._pool.submit(self._read, frame))

    def _read(self, frame) -> LoadedFrame:
        source = fingerprint(frame)  # before reading: a later change is seen next time
        try:
            return LoadedFrame(source, load_image(frame, self._sources))
        except Exception as exc:  # noqa: BLE001 - given back where the frame is taken
            return LoadedFrame(source, None, exc)

    def take(self) -> LoadedFrame:
        """The next frame, read (waits for it); the frame ``depth`` further is queued."""
        if not self._pending:
            raise IndexError("FramePrefetcher: every frame has been taken")
        fut = self._pending.pop(0)
        self._submit()
        return fut.result()

    def close(self) -> None:
        """Stop reading (frames not yet started are dropped) and close the files opened."""
        for fut in self._pending:
            fut.cancel()
        self._pending.clear()
        self._pool.shutdown(wait=True)
        for src in self._sources.values():
            src.close()
        self._sources.clear()

    def __enter__(self) -> FramePrefetcher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
