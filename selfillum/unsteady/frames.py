"""A fixed map's frames made ready for the operator: read, registered, patched, filtered.

For a model that does not move (``registration`` ``none`` or ``first-frame``), each frame
of each camera is read as stored, warped onto frame 0 by its affine registration, cleared
of its dark spots and low-pass filtered (:func:`fixed_images`) before frame 0's operator
samples it. :class:`FramesAhead` makes the next frame's images in a helper thread while
the caller maps this one: the registration's fit, the warp and the filter release the
GIL, so the two run on two cores. On the 609,000-face run of issue 33 (one 1280 x 800
camera, 2 cores), the deck's options took 7.5-8.0 s in Phase 1 made in turn and 5.7-6.1 s
made ahead; with ``filter = gaussian`` 8.1-8.5 s and 6.0-6.8 s.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from selfillum.unsteady.spots import mask_spots

__all__ = ["read_frame", "fixed_images", "gaussian", "FramesAhead"]


def read_frame(frames, k: int) -> np.ndarray:
    """Frame ``k`` as stored (a video's integer counts, no float copy) where the source
    can (:meth:`resection.io.video.FrameSource.native`, no saturation mask asked)."""
    if hasattr(frames, "native") and not getattr(frames, "mask_saturated", False):
        return frames.native(k)
    return np.asarray(frames[k])


def fixed_images(cameras, k, regs, spot_px, filter, filter_size, pres=None,
                 read=None, workers=None) -> list:
    """Frame ``k`` of every camera for frame 0's map: as stored, or warped onto frame 0
    (``first-frame``) and filtered (its spots patched by ``pres`` or masked first), in
    float64. Without a filter, a warp samples only the pixels ``read[c]`` (the operator's),
    when given, on ``workers`` threads.

    Several cameras are prepared side by side, one thread a camera (the affine fit, the
    warp and the filter release the GIL), each on one thread of its own: a camera's work
    is coarse enough to pay a thread, where one camera's pixels split over threads did
    not on one camera (see :class:`FramesAhead`)."""
    from resection._threads import available_cores, run_blocks

    def one(ci: int, inner: int | None):
        c = cameras[ci]
        img = read_frame(c.frames, k)
        if regs[ci] is not None or filter == "gaussian":
            if regs[ci] is not None:  # first-frame: warped onto frame 0 (read as stored)
                if read is not None and filter != "gaussian":  # only what is read
                    from selfillum.unsteady.fastmap import PixelValues

                    return PixelValues(regs[ci].sample(img, regs[ci].fit(img), read[ci],
                                                       inner))
                img = regs[ci].warp_all(img, regs[ci].fit(img), inner)
            else:
                img = np.array(img, dtype=np.float64)
            if filter == "gaussian":  # the spots in place (the array is this call's own)
                if pres is not None and pres[ci] is not None:
                    img = pres[ci].apply(img, in_place=True)
                elif spot_px[ci] is not None:
                    img = mask_spots(img, *spot_px[ci])
                img = gaussian(img, filter_size, inner)
        return img

    n = len(cameras)
    busy = regs.count(None) < n or filter == "gaussian"  # work beyond reading the frame
    threads = min(n, available_cores() if workers is None else max(int(workers), 1))
    if n < 2 or not busy or threads < 2:
        return [one(ci, workers) for ci in range(n)]
    return [im for b in run_blocks(lambda b: [one(ci, 1) for ci in range(*b)],
                                   [(ci, ci + 1) for ci in range(n)], threads)
            for im in b]


def gaussian(img: np.ndarray, size: int, workers: int | None = None) -> np.ndarray:
    """NaN-aware Gaussian low-pass of a ``size`` x ``size`` kernel (OpenCV's sigma for a
    kernel size: ``0.3 ((size - 1) / 2 - 1) + 0.8``): :func:`.lowpass.gaussian_lowpass`
    on ``workers`` threads (default: the cores)."""
    from selfillum.unsteady.lowpass import gaussian_lowpass

    return gaussian_lowpass(img, size, workers)


class Helping:
    """Work a helper thread shares with the caller while the caller waits for it.

    The helper runs :meth:`run` on blocks of a compiled kernel (the GIL released); the
    caller, once it waits for the helper's frame (:meth:`assist`, from
    :meth:`FramesAhead.get`), takes the blocks not yet started. Each block is its own
    work, so the result does not depend on who ran it. :meth:`waiting` tells the helper
    whether the caller waits (it may then leave a last part of the frame to the
    caller)."""

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._job: _Job | None = None
        self._waits = False

    def waiting(self) -> bool:
        """Whether the caller waits for the frame in flight."""
        return self._waits

    def run(self, fn, n: int, block: int) -> None:
        """``fn((start, stop))`` for the blocks of ``block`` items of ``range(n)``: in this
        thread, and in the caller's while it waits; returns once every block is done (an
        error of one raised here)."""
        job = _Job(fn, [(a, min(a + block, n)) for a in range(0, n, block)])
        with self._cv:
            self._job = job
            self._cv.notify_all()
        try:
            job.work()
        finally:
            with self._cv:
                self._job = None
        job.finished.wait()
        if job.error is not None:
            raise job.error

    def assist(self, fut: Future) -> None:
        """Until ``fut`` is done: take the blocks the helper offers (the caller's wait)."""
        fut.add_done_callback(self._wake)
        with self._cv:
            self._waits = True
        try:
            while True:
                with self._cv:
                    self._cv.wait_for(lambda: fut.done() or (
                        self._job is not None and self._job.has_blocks()))
                    if fut.done():
                        return
                    job = self._job
                job.work()
        finally:
            self._waits = False

    def _wake(self, _fut) -> None:
        with self._cv:
            self._cv.notify_all()


class _Job:
    """Blocks of one kernel call, taken one at a time by either thread."""

    def __init__(self, fn, blocks) -> None:
        self.fn, self.blocks = fn, blocks
        self._next = 0
        self._left = len(blocks)
        self._lock = threading.Lock()
        self.finished = threading.Event()
        self.error: BaseException | None = None
        if not blocks:
            self.finished.set()

    def has_blocks(self) -> bool:
        return self._next < len(self.blocks)

    def work(self) -> None:
        while True:
            with self._lock:
                if self._next >= len(self.blocks):
                    return
                b = self.blocks[self._next]
                self._next += 1
            try:
                self.fn(b)
            except BaseException as exc:  # noqa: BLE001 - raised in the helper's run
                self.error = self.error or exc
            with self._lock:
                self._left -= 1
                if self._left == 0:
                    self.finished.set()


class FramesAhead:
    """The images (or samples) of a run's frames, each next one made in a helper thread.

    ``get(k)`` returns ``make(k)`` and starts ``make`` of the frame after ``k`` (in
    ``frames``' order) in one helper thread, so that it is ready when asked for. ``make``
    may keep state from frame to frame (the registration starts from the last warp): the
    helper runs the frames one at a time in order, and the caller touches that state only
    after :meth:`drop`, which waits for the frame in flight and discards it (made again
    when asked for). Use as a context manager, or :meth:`close` it: the helper ends.

    Parameters
    ----------
    make : callable
        ``make(k)`` -> the images of frame ``k``.
    frames : sequence of int
        The frames in the order they will be asked for.
    before : callable, optional
        ``before(k)``, run in the caller's thread when frame ``k`` is started (made or
        sent ahead): what ``make`` needs that only the caller may compute (a moving
        model's reference, cast when missing); then ``make(k, before(k))``.
    helping : Helping, optional
        While the caller waits for the frame in flight, it takes the blocks of work
        ``make`` offers there, and ``make`` may leave a last part of the frame's work to
        the caller (the work of a frame balanced between the two threads on any
        machine).
    """

    def __init__(self, make, frames, before=None, helping: Helping | None = None) -> None:
        self._make = make
        self._before = before
        order = [int(k) for k in frames]
        self._after = dict(zip(order[:-1], order[1:], strict=True))
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="frames-ahead")
        self._pending: tuple[int, Future] | None = None
        self._helping = helping

    def get(self, k: int):
        """The images of frame ``k`` (made ahead when ``k`` was the frame expected)."""
        k = int(k)
        pending, self._pending = self._pending, None
        if pending is not None and pending[0] == k:
            if self._helping is not None:
                self._helping.assist(pending[1])
            imgs = pending[1].result()  # its error, if any, raised here
        else:
            if pending is not None:
                _finish(pending[1])
            imgs = self._make(*self._args(k))
        nxt = self._after.get(k)
        if nxt is not None:
            self._pending = (nxt, self._pool.submit(self._make, *self._args(nxt)))
        return imgs

    def _args(self, k: int) -> tuple:
        return (k,) if self._before is None else (k, self._before(k))

    def drop(self) -> None:
        """Wait for the frame in flight and discard it (before the caller changes what
        ``make`` reads)."""
        pending, self._pending = self._pending, None
        if pending is not None:
            _finish(pending[1])

    def close(self) -> None:
        """Discard the frame in flight and end the helper thread."""
        self.drop()
        self._pool.shutdown(wait=True)

    def __enter__(self) -> FramesAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _finish(fut: Future) -> None:
    """Wait for ``fut``, its result and its error discarded (the frame is made again)."""
    fut.cancel()
    try:
        fut.result()
    except BaseException:  # noqa: BLE001, S110 - made again by the caller, which then raises
        pass
