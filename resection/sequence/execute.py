"""Running the chunks of frames: in this process, or on a Dask cluster."""

from __future__ import annotations

import os

from ..errors import InputError
from .process import _run_chunk


def _execute_local(setup, tasks, on_frame):
    for items, seed, done in tasks:
        _run_chunk(setup, items, seed, done, on_frame)


def _execute_dask(setup, tasks, on_chunk, on_poll, scheduler, workers, frames_dir,
                  poll_s: float = 0.25, connect_timeout: float = 20.0):
    """Run the chunks on Dask. The tasks write every finished frame to ``frames_dir``
    themselves; ``on_poll()`` is called while waiting (it picks those files up, for the
    progress bar) and ``on_chunk(dicts)`` when a chunk comes back."""
    import logging
    import time

    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout=connect_timeout)
        except (OSError, ValueError, TypeError) as exc:  # unreachable or malformed address
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(f"scheduler: cannot connect to the Dask scheduler at "
                             f"{scheduler!r} ({msg})") from None
    try:
        s = client.scatter(setup, broadcast=True)
        futures = [client.submit(_run_chunk, s, items, seed, done, None, frames_dir,
                                 pure=False)
                   for items, seed, done in tasks]
        pending = as_completed(futures)
        while not pending.is_empty():
            if pending.has_ready():
                for fut in pending.next_batch(block=False):
                    on_chunk(fut.result())
            else:
                on_poll()
                time.sleep(poll_s)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _default_workers() -> int:
    """Worker processes of the default local cluster: one per CPU core."""
    return max(int(os.cpu_count() or 1), 1)
