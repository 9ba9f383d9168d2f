"""Threads over blocks of independent work whose kernels release the GIL.

Embree's ray queries (:mod:`resection.surface.embree`) and the package's numba kernels
compiled with ``nogil=True`` run without Python's global interpreter lock, so a few threads
over contiguous blocks of rays or image rows use every core with no copies and no process
start-up. The thread count defaults to the cores this process may use; nothing is kept
between calls.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from typing import TypeVar

__all__ = ["available_cores", "core_ids", "split_range", "run_blocks", "numba_threads"]

T = TypeVar("T")

#: Held while a parallel numba kernel runs (see :func:`numba_threads`). numba's fallback
#: threading layer (``workqueue``, used where neither OpenMP's libgomp nor TBB is
#: installed) aborts the process when two Python threads launch parallel kernels at once;
#: each launch already uses every core, so launches from several threads take turns.
_PARALLEL = threading.RLock()


def core_ids() -> list[int]:
    """The numbers of the cores this process may run on (its CPU affinity where the OS
    reports one, else all of them)."""
    try:
        ids = sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - platforms without affinity
        ids = []
    return ids or list(range(max(int(os.cpu_count() or 1), 1)))


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS reports one)."""
    return len(core_ids())


def _workers(workers: int | None) -> int:
    return available_cores() if workers is None else max(int(workers), 1)


def split_range(n: int, workers: int | None = None, *, min_size: int = 1,
                per_worker: int = 4) -> list[tuple[int, int]]:
    """Split ``range(n)`` into contiguous ``(start, stop)`` blocks.

    About ``per_worker`` blocks a thread (so that a thread slowed by another process does
    not hold up the end), none shorter than ``min_size`` unless ``n`` itself is; a single
    block with one worker.
    """
    n = int(n)
    if n <= 0:
        return []
    w = _workers(workers)
    count = 1 if w == 1 else max(1, min(w * per_worker, n // max(int(min_size), 1)))
    edges = [round(i * n / count) for i in range(count + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def run_blocks(fn: Callable[[tuple[int, int]], T], blocks: Sequence[tuple[int, int]],
               workers: int | None = None) -> list[T]:
    """``[fn(b) for b in blocks]``, on up to ``workers`` threads (default: the available
    cores); in the calling thread when there is one block or one worker. ``fn`` must do its
    work in GIL-free code to gain anything. The first exception raised is re-raised.

    The calling thread takes blocks too, beside ``workers - 1`` new threads, each taking
    the next block left: on two cores a frame's kernel split in two took 3.3 ms this way,
    against 4.4 ms on a kept pool of two and 7.5 ms on a new pool of two (a new thread's
    first large work arrays are fresh pages; see :mod:`selfillum.unsteady.lowpass`)."""
    w = min(_workers(workers), len(blocks))
    if w <= 1:
        return [fn(b) for b in blocks]
    out: list = [None] * len(blocks)
    errors: list[BaseException] = []
    lock = threading.Lock()
    nxt = iter(range(len(blocks)))

    def take() -> None:
        while True:
            with lock:
                i = None if errors else next(nxt, None)
            if i is None:
                return
            try:
                out[i] = fn(blocks[i])
            except BaseException as exc:  # noqa: BLE001 - re-raised in the caller
                with lock:
                    errors.append(exc)
                return

    helpers = [threading.Thread(target=take, daemon=True) for _ in range(w - 1)]
    for t in helpers:
        t.start()
    take()
    for t in helpers:
        t.join()
    if errors:
        raise errors[0]
    return out


@contextmanager
def numba_threads(workers: int | None):
    """numba's thread count for the parallel kernels called inside the ``with`` block:
    ``workers`` (at most numba's ``NUMBA_NUM_THREADS``, the cores by default), or left as
    it is when ``None``; the previous count is restored on exit (it is per calling thread).

    Every parallel kernel of the package runs inside such a block, which Python threads
    enter one at a time (re-entrant within a thread): numba's ``workqueue`` layer cannot
    run two parallel launches at once, and aborts the process if it is asked to.
    """
    with _PARALLEL:
        if workers is None:
            yield
            return
        import numba

        old = numba.get_num_threads()
        numba.set_num_threads(max(1, min(int(workers), numba.config.NUMBA_NUM_THREADS)))
        try:
            yield
        finally:
            numba.set_num_threads(old)
