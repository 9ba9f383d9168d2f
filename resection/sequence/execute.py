"""Running the frames: the reference frame in this process, then chunks of consecutive
frames in this process or on a Dask cluster, then the repair pass."""

from __future__ import annotations

import os
import time
from pathlib import Path

from resection.errors import InputError
from resection.sequence.outputs import (
    FrameWriter,
    atomic_write_text,
    frame_path,
    frame_text,
    read_frame,
    summary,
    write_frame,
)
from resection.sequence.process import (
    DEFERRED,
    Setup,
    process_frame,
    process_linked,
    repair,
    run_chunk,
)
from resection.sequence.results import FrameResult

#: Dask configuration of the local cluster's workers. The nanny sets
#: ``MALLOC_TRIM_THRESHOLD_`` by default, which freezes glibc's dynamic mmap threshold: every
#: frame-sized array (4 MB) is then mmap'ed and faulted in afresh, which doubled the CPU time
#: of a tracked frame in a worker (20 ms against 11 ms in this process, 1 Mpx frames,
#: bench_track.py). Unset (None), the workers allocate as this process does.
LOCAL_WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: seconds to start a local cluster of worker processes and load the package and its
#: compiled kernels in them (measured 2.7 s on the 2-core development machine, more
#: under load: ``bench/bench_track.py``). A run starts them only when the work left after
#: the first chunk, timed in this process, takes longer than that plus its share.
LOCAL_CLUSTER_START_S = 3.0


def run_frames(frames: list, setup: Setup, link: dict | None, done: dict, *,
               chunk_size: int, workers: int, scheduler: str | None, frames_dir: Path,
               progress: bool) -> int:
    """Compute every frame not in ``done`` (index -> ``(ok, matched_from)``, completed in
    place), each written to ``frames_dir`` as soon as it is finished. Returns the number
    computed. Memory does not grow with the frames: a finished frame is kept as its file
    and those two numbers; the frames are read one at a time, where they are processed."""
    bar = _progress_bar(len(frames), len(done), progress)
    computed = 0

    def note(d: dict) -> None:
        """A frame finished (its file is written; a deferred one is computed later)."""
        nonlocal computed
        done[d["frame"]] = summary(d)
        if d.get("matched_from") != DEFERRED:
            computed += 1
            bar.update(1)

    writer = FrameWriter(frames_dir)

    def record(res: FrameResult) -> None:
        d = res.to_dict()
        writer.write(d)
        note(d)

    try:
        d0 = read_frame(frame_path(frames_dir, 0)) if 0 in done else None
        if d0 is not None:  # the reference frame, in this process
            first = FrameResult.from_dict(d0)
        else:
            first = (process_linked(frames[0], 0, setup, link) if link is not None
                     else process_frame(frames[0], 0, setup, None))
            record(first)
        seed0 = first if first.ok else None
        tasks = _chunks(frames, done, seed0, chunk_size, frames_dir)
        n_local = min(workers, len(tasks))  # no idle local workers: start-up costs
        if tasks and scheduler is None and n_local > 1:
            # no worker processes for a run that this process finishes sooner: the first
            # chunk runs here, timed, and the rest goes to a local cluster only if that
            # pays its start-up
            t0 = time.perf_counter()
            last = _execute_local(setup, tasks[:1], record, (seed0, None))
            per_frame = (time.perf_counter() - t0) / max(_to_compute(tasks[:1]), 1)
            tasks = tasks[1:]
            n_local = min(workers, len(tasks))
            if not cluster_pays(per_frame * _to_compute(tasks), min(n_local, free_cores())):
                n_local = 1
        else:
            last = (seed0, None)
        if tasks and scheduler is None and n_local == 1:
            _execute_local(setup, tasks, record, last)
        elif tasks:
            todo = {i for items, _, _ in tasks for i, _ in items if i not in done}
            _execute_dask(setup, tasks, _on_chunk(frames_dir, todo, note),
                          _on_poll(frames_dir, todo, note), scheduler, n_local,
                          str(frames_dir.resolve()))

        writer.flush()  # the repair pass reads the frames' files

        def rerecord(res: FrameResult) -> None:
            nonlocal computed
            write_frame(frames_dir, res)
            if done.get(res.frame, (False, -1))[1] == DEFERRED:
                bar.update(1)
            done[res.frame] = summary(res.to_dict())
            computed += 1

        repair(frames, setup, done, rerecord, frames_dir)
    finally:
        writer.close()  # the finished frames are written, also when the run is interrupted
        bar.close()
    return computed


class _NoBar:
    """A progress bar that shows nothing (tqdm is not imported for it: 25 ms)."""

    def update(self, n: int = 1) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(total: int, initial: int, show: bool):
    if not show:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc="track", unit="frame")


def cluster_pays(seconds: float, workers: float, start_s: float | None = None) -> bool:
    """Whether ``workers`` local worker processes (a number of cores' worth, at most the
    free cores) finish ``seconds`` of work in this process sooner, their start-up
    ``start_s`` (default :data:`LOCAL_CLUSTER_START_S`) included (perfect scaling
    assumed, so the answer errs towards starting them)."""
    start = LOCAL_CLUSTER_START_S if start_s is None else float(start_s)
    return workers > 1 and start + seconds / workers < seconds


def free_cores() -> float:
    """Cores free for more worker processes: those this process may use less the 1-minute
    load average of the machine (other users' processes; this process's own share, 1,
    counted back), at least 1. On a loaded machine a second worker process does not
    make the run faster."""
    from resection._threads import available_cores

    try:
        load = os.getloadavg()[0]
    except OSError:  # no load average on this platform
        load = 0.0
    return max(1.0, available_cores() - max(load - 1.0, 0.0))


def _to_compute(tasks) -> int:
    return sum(len(items) - len(done) for items, _, done in tasks)


def _chunks(frames: list, done: dict, seed: FrameResult | None, chunk_size: int,
            frames_dir: Path) -> list:
    """``(items, seed, done)`` per chunk of consecutive frames (after frame 0) with at least
    one frame to compute; ``items = [(index, frame), ...]``, ``done`` the dicts of the
    chunk's finished frames (read back from their files: they serve as references)."""
    tasks = []
    for start in range(1, len(frames), chunk_size):
        idx = range(start, min(start + chunk_size, len(frames)))
        if all(i in done for i in idx):
            continue
        finished = {i: read_frame(frame_path(frames_dir, i)) for i in idx if i in done}
        tasks.append(([(i, frames[i]) for i in idx], seed,
                      {i: d for i, d in finished.items() if d is not None}))
    return tasks


def _on_poll(frames_dir: Path, todo: set, note):
    """While Dask runs: pick up the frames the workers have written (shared filesystem)."""
    def on_poll() -> None:
        names = set(os.listdir(frames_dir))
        for i in sorted(todo):
            if frame_path(frames_dir, i).name in names:
                d = read_frame(frame_path(frames_dir, i))
                if d is not None and d.get("frame") == i:
                    todo.discard(i)
                    note(d)
    return on_poll


def _on_chunk(frames_dir: Path, todo: set, note):
    """A chunk came back: write what its worker could not (no shared filesystem with a
    remote cluster)."""
    def on_chunk(dicts: list) -> None:
        for dct in dicts:
            i = dct["frame"]
            if i not in todo:
                continue
            path, text = frame_path(frames_dir, i), frame_text(dct)
            try:
                same = path.read_text(encoding="utf-8") == text
            except OSError:
                same = False
            if not same:
                atomic_write_text(path, text, sync=False)
            todo.discard(i)
            note(dct)
    return on_chunk


def _execute_local(setup, tasks, on_frame, last=None):
    """The chunks one after the other in this process, each seeded with the last two good
    frames of the chunk before it (``last``: those before the first chunk), as they are
    known here: a chunk's first frame is then predicted from the frames just before it
    rather than from frame 0, as on a cluster (the results agree to the solver's
    convergence). Returns the last two good frames."""
    last = last or (None, None)
    for items, seed, done in tasks:
        ref, prev = last if last[0] is not None else (seed, None)
        dicts = run_chunk(setup, items, ref, done, on_frame, previous=prev)
        good = [d for d in dicts if d["status"] == "ok"]
        if good:
            tail = [FrameResult.from_dict(d) for d in good[-2:]]
            last = (tail[-1], tail[0] if len(tail) == 2 else ref)
        else:
            last = (None, None)
    return last


def _execute_dask(setup, tasks, on_chunk, on_poll, scheduler, workers, frames_dir,
                  poll_s: float = 0.25, connect_timeout: float = 20.0):
    """Run the chunks on Dask. The tasks write every finished frame to ``frames_dir``
    themselves; ``on_poll()`` is called while waiting (it picks those files up, for the
    progress bar) and ``on_chunk(dicts)`` when a chunk comes back."""
    import logging
    import time

    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        with dask.config.set(LOCAL_WORKER_CONFIG):
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                   processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        msg = None
        try:
            client = Client(scheduler, timeout=connect_timeout)
        except (OSError, ValueError, TypeError) as exc:  # unreachable or malformed address
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if msg is not None:
            # the half-built Client must be collected now: left to a later garbage
            # collection, its __del__ can run while another cluster starts and hang it
            import gc

            gc.collect()
            raise InputError(f"scheduler: cannot connect to the Dask scheduler at "
                             f"{scheduler!r} ({msg})")
    try:
        s = client.scatter(setup, broadcast=True)
        futures = [client.submit(run_chunk, s, items, seed, done, None, frames_dir,
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


def default_workers() -> int:
    """Worker processes of the default local cluster: one per CPU core."""
    return max(int(os.cpu_count() or 1), 1)
