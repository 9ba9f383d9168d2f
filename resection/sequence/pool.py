"""Local worker processes for the chunks of a run, without a Dask cluster's start-up.

A Dask ``LocalCluster`` takes 2.7-3 s to start on 2 cores: a scheduler, a nanny and a
fresh interpreter per worker, each importing the package. Here the workers are forked
from a *fork server*: one fresh process, started as soon as a run may need workers (while
this process works on the reference frame and the first chunk), that imports the tracking
code and loads its compiled kernels once (:mod:`resection.sequence._server`); each worker
forked from it starts in milliseconds with all of it loaded. The server holds no threads
and no Embree device, so the fork is safe whatever this process has started. Where the
platform has no fork server (Windows), the workers are spawned.

Each worker receives the run's :class:`~resection.sequence.process.Setup` once, when it
starts, and keeps it for the chunks it runs. The workers ignore Ctrl-C: on an interrupt
this process cancels the chunks not started and waits for those running, which write every
frame they finish (at most a chunk each).
"""

from __future__ import annotations

import multiprocessing
import signal
import time
from concurrent.futures import Future, ProcessPoolExecutor

from resection.sequence.process import Setup, run_chunk

__all__ = ["start_server", "server_wait", "WorkerPool", "EARLY_SERVER_CORES",
           "EARLY_SERVER_FRAMES"]

#: modules the fork server imports (and whose kernels it loads) before forking workers
PRELOAD = ["resection.sequence._server"]
#: seconds the fork server takes to import :data:`PRELOAD` and load its kernels (1.0-1.2 s
#: measured on the 2-core development machine beside a starting ``track``), with a margin
SERVER_READY_S = 1.5
#: cores from which the server is started at the run's start (beside this process and the
#: plot's process) and beside the reference frame; with fewer it slows this process's own
#: start, and it is started beside the reference frame only for a run of at least
#: :data:`EARLY_SERVER_FRAMES` frames (2,000 frames on 2 cores: 7.6 s that way, 10.6 s
#: with the server started once workers were known to pay), else once they are
EARLY_SERVER_CORES = 4
EARLY_SERVER_FRAMES = 1000

#: the worker process's setup, set once by :func:`_start_worker` (each worker has its own)
_WORKER: dict = {}


def _context():
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        return ctx
    return multiprocessing.get_context("spawn")


def start_server() -> float | None:
    """Start the fork server now, so that it is ready when workers are wanted (it loads
    the package while this process carries on; a second call does nothing). Returns the
    time it was asked to start (``time.perf_counter``); where there is no fork server,
    nothing is started and ``None`` returned (spawned workers load the package
    themselves, as they start)."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return None
    from multiprocessing import forkserver

    _context()
    t = time.perf_counter()
    forkserver.ensure_running()
    return t


def server_wait(since: float | None) -> float:
    """Seconds until a server asked to start at ``since`` (:func:`start_server`; ``None``:
    none started, the workers load the package themselves) has loaded the package, at most
    :data:`SERVER_READY_S`."""
    if since is None:
        return SERVER_READY_S
    return min(max(SERVER_READY_S - (time.perf_counter() - since), 0.0), SERVER_READY_S)


def _start_worker(setup: Setup) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run's process handles Ctrl-C
    _WORKER["setup"] = setup


def _run(items, seed, done, frames_dir, previous):
    return run_chunk(_WORKER["setup"], items, seed, done, None, frames_dir,
                     previous=previous)


class WorkerPool:
    """``workers`` local processes running chunks of ``setup``'s run.

    Use as a context manager; :meth:`submit` returns a future of the chunk's frame
    dictionaries (:func:`~resection.sequence.process.run_chunk`).
    """

    def __init__(self, setup: Setup, workers: int) -> None:
        self._pool = ProcessPoolExecutor(max_workers=int(workers), mp_context=_context(),
                                         initializer=_start_worker, initargs=(setup,))

    def submit(self, items, seed, done, frames_dir: str, previous=None) -> Future:
        return self._pool.submit(_run, items, seed, done, frames_dir, previous)

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # on an error or Ctrl-C: the chunks not started are dropped, those running end
        self._pool.shutdown(wait=True, cancel_futures=exc_type is not None)
