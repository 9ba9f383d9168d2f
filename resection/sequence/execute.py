"""Running the frames: the reference frame in this process, then chunks of consecutive
frames in this process, on local worker processes (:mod:`resection.sequence.pool`) or on a
Dask cluster, a deferred chunk started again from the chunk before it
(:mod:`resection.sequence.chain`), then the repair pass."""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

from resection._threads import available_cores
from resection.errors import InputError
from resection.sequence.chain import ChunkChain, tail_of
from resection.sequence.load import LoadWindow, free_by_load_average
from resection.sequence.outputs import (
    FrameWriter,
    atomic_write_text,
    frame_path,
    frame_text,
    read_frame,
    summary,
    write_frame,
)
from resection.sequence.pool import (
    EARLY_SERVER_CORES,
    EARLY_SERVER_FRAMES,
    WorkerPool,
    server_wait,
    start_server,
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

#: seconds to start the local worker processes (:mod:`resection.sequence.pool`) from a
#: server that has loaded the package and its kernels (forked, they start in milliseconds;
#: this allows for a loaded machine); the time the server still needs is added
#: (:func:`~resection.sequence.pool.server_wait`). A run starts them only when the work
#: left after the first frames, timed in this process, takes longer than that plus its
#: share.
LOCAL_CLUSTER_START_S = 0.5


def run_frames(frames: list, setup: Setup, link: dict | None, done: dict, *,
               chunk_size: int, workers: int, scheduler: str | None, frames_dir: Path,
               progress: bool, server_since: float | None = None,
               on_frame=None, fit_threads: int | None = None) -> int:
    """Compute every frame not in ``done`` (index -> ``(ok, matched_from)``, completed in
    place), each written to ``frames_dir`` as soon as it is finished. ``server_since``:
    when the workers' server was started (:func:`resection.sequence.pool.start_server`),
    if it was. Returns the number of frames computed (each counted once). Memory does not
    grow with the frames: a finished frame is kept as its file and those two numbers; the
    frames are read one at a time, where they are processed. ``on_frame(result)``, when
    given, is called with each frame finished in this process (frame 0 first, also when
    read back), after its file is written (see :func:`resection.sequence.track`);
    ``fit_threads``: the marker fits' threads when the frames run in this process alone
    (default every core)."""
    bar = _progress_bar(len(frames), len(done), progress)
    computed: set[int] = set()

    def note(d: dict) -> None:
        """A frame finished (its file is written; a deferred one is computed later)."""
        done[d["frame"]] = summary(d)
        if d.get("matched_from") != DEFERRED and d["frame"] not in computed:
            computed.add(d["frame"])
            bar.update(1)

    writer = FrameWriter(frames_dir)

    def record(res: FrameResult) -> None:
        d = res.to_dict()
        writer.write(d)
        note(d)
        if on_frame is not None:
            on_frame(res)

    try:
        window = LoadWindow.start()  # the machine's other work, over this run's first work
        d0 = read_frame(frame_path(frames_dir, 0)) if 0 in done else None
        if d0 is not None:  # the reference frame, in this process
            first = FrameResult.from_dict(d0)
        else:
            left = len(frames) - 1 - len(done)
            n_chunks = 1 + left // max(int(chunk_size), 1)
            cores = available_cores()
            if (scheduler is None and min(workers, n_chunks - 1) > 1 and cores > 1
                    and (cores >= EARLY_SERVER_CORES or left >= EARLY_SERVER_FRAMES)):
                if server_since is None:  # readied beside the reference frame and chunk
                    server_since = start_server()
            first = (process_linked(frames[0], 0, setup, link) if link is not None
                     else process_frame(frames[0], 0, setup, None))
            record(first)
        if d0 is not None and on_frame is not None:
            on_frame(first)
        seed0 = first if first.ok else None
        tasks = _chunks(frames, done, seed0, chunk_size, frames_dir)
        n_local = min(workers, len(tasks))  # no idle local workers: start-up costs
        here = None  # the rest of the first chunk, run here beside the workers
        if tasks and scheduler is None and n_local > 1:
            # no worker processes for a run that this process finishes sooner: the first
            # frames of the first chunk run here, timed, and the chunks after it go to
            # local workers only if that pays their start-up; this process then does the
            # rest of the first chunk beside them
            head, rest = _split(tasks[0], PROBE_FRAMES)
            t0 = time.perf_counter()
            last = _execute_local(setup, [head], record, (seed0, None))
            per_frame = (time.perf_counter() - t0) / max(_to_compute([head]), 1)
            later = ([rest] if rest is not None else []) + tasks[1:]
            n_local = min(workers, len(tasks) - 1)
            # the server's start takes a core in the window
            free = free_cores(window, 0.0 if server_since is None else 1.0)
            start_s = max(LOCAL_CLUSTER_START_S, server_wait(server_since))
            if n_local > 1 and cluster_pays(per_frame * _to_compute(later),
                                            min(n_local, free), start_s):
                here, tasks = rest, tasks[1:]
            else:
                n_local, tasks = 1, later
        else:
            last = (seed0, None)
        before = _tail(last)
        if tasks and scheduler is None and n_local == 1:  # alone: the fits on every core
            # (or on the caller's fit_threads)
            _execute_local(dataclasses.replace(setup, fit_workers=fit_threads), tasks,
                           record, last)
        elif tasks:
            on_poll = _on_poll(frames_dir, tasks, done, note) if progress else None
            if scheduler is None:
                local = None if here is None else (
                    lambda: _tail(_execute_local(setup, [here], record, last)))
                _execute_pool(setup, tasks, before, _on_chunk(frames_dir, note, False),
                              on_poll, n_local, str(frames_dir.resolve()), local=local)
            else:
                _execute_dask(setup, tasks, before, _on_chunk(frames_dir, note, True),
                              on_poll, scheduler, n_local, str(frames_dir.resolve()))

        writer.flush()  # the repair pass reads the frames' files

        def rerecord(res: FrameResult) -> None:
            write_frame(frames_dir, res)
            note(res.to_dict())
            if on_frame is not None:
                on_frame(res)

        repair(frames, setup, done, rerecord, frames_dir)
    finally:
        writer.close()  # the finished frames are written, also when the run is interrupted
        bar.close()
    return len(computed)


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


def free_cores(window: LoadWindow | None = None, helpers: float = 0.0) -> float:
    """Cores free for more worker processes: those this process may use less those that
    other work kept busy over ``window`` (:mod:`resection.sequence.load`; without one, the
    1-minute load average, this process counted back), at least 1. On a loaded machine a
    second worker process does not make the run faster."""
    return free_by_load_average() if window is None else window.free_cores(helpers)


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


def _on_poll(frames_dir: Path, tasks: list, done: dict, note):
    """While the workers run: pick up the frames they have written (shared filesystem),
    for the progress bar."""
    todo = {i for items, _, _ in tasks for i, _ in items if i not in done}

    def on_poll() -> None:
        names = set(os.listdir(frames_dir))
        for i in sorted(todo):
            if frame_path(frames_dir, i).name in names:
                d = read_frame(frame_path(frames_dir, i))
                if d is not None and d.get("frame") == i:
                    todo.discard(i)
                    note(d)
    return on_poll


def _on_chunk(frames_dir: Path, note, remote: bool):
    """A chunk came back: write what its worker could not (no shared filesystem with a
    remote cluster, ``remote``; a local worker that could not write, e.g. a full disk:
    the write here raises), and note its frames."""
    def on_chunk(dicts: list) -> None:
        for dct in dicts:
            path = frame_path(frames_dir, dct["frame"])
            if remote:
                text = frame_text(dct)
                try:
                    same = path.read_text(encoding="utf-8") == text
                except OSError:
                    same = False
                if not same:
                    atomic_write_text(path, text, sync=False)
            elif not path.is_file():
                atomic_write_text(path, frame_text(dct), sync=False)
            note(dct)
    return on_chunk


def _run_chain(submit, wait, tasks, before, on_chunk, on_poll, poll_s: float,
               local=None) -> None:
    """Run ``tasks`` through ``submit(items, seed, done, previous) -> future``, each
    chunk seeded from its first seed (frame 0), and start a deferred chunk again from the
    chunk before it once that is back (:mod:`resection.sequence.chain`). ``wait(futures,
    timeout)`` returns the futures finished (possibly none). ``local()``, if given, is
    this process's share, run once the tasks are submitted: the chunk before the first
    task, whose last two good frames it returns (they replace ``before``)."""
    seeds = [-1 if seed is None else seed.frame for _, seed, _ in tasks]
    chain = ChunkChain(seeds, before, known=local is None)
    running: dict = {}

    def submit_all() -> None:
        for k, (items, seed, done) in enumerate(tasks):
            running[submit(items, seed, done, None)] = k

    if local is None:
        submit_all()
    else:
        # submitting starts the workers, which waits for their server to have loaded the
        # package: on a thread, while this process does its share
        import threading

        failed: list = []

        def submitter() -> None:
            try:
                submit_all()
            except BaseException as exc:  # noqa: BLE001 - raised in this thread below
                failed.append(exc)

        thread = threading.Thread(target=submitter, name="track-submit", daemon=True)
        thread.start()
        try:
            tail = local()
        finally:
            thread.join()
        if failed:
            raise failed[0]
        for j, (ref, prev) in chain.set_before(tail):
            items, _, done = tasks[j]
            running[submit(items, ref, done, prev)] = j
    while running:
        finished = wait(list(running), poll_s)
        if not finished and on_poll is not None:
            on_poll()
        for fut in finished:
            k = running.pop(fut)
            dicts = fut.result()
            on_chunk(dicts)
            for j, (ref, prev) in chain.came_back(k, dicts):
                items, _, done = tasks[j]
                running[submit(items, ref, done, prev)] = j


def _execute_pool(setup, tasks, before, on_chunk, on_poll, workers, frames_dir,
                  poll_s: float = 0.25, local=None) -> None:
    """Run the chunks on ``workers`` local processes (:mod:`resection.sequence.pool`).
    The tasks write every finished frame to ``frames_dir`` themselves; ``on_chunk(dicts)``
    is called when a chunk comes back, ``on_poll()`` (if given) while waiting; ``local``:
    see :func:`_run_chain`."""
    from concurrent.futures import FIRST_COMPLETED
    from concurrent.futures import wait as wait_futures

    def wait(futures, timeout):
        return wait_futures(futures, timeout=timeout, return_when=FIRST_COMPLETED).done

    with WorkerPool(setup, workers) as pool:
        _run_chain(lambda items, seed, done, prev: pool.submit(items, seed, done,
                                                               frames_dir, prev),
                   wait, tasks, before, on_chunk, on_poll, poll_s, local)


#: frames of the first chunk timed in this process before local workers are started
PROBE_FRAMES = 10


def _split(task, n: int):
    """A chunk's task as its first ``n`` frames and the rest (``None``: nothing left)."""
    items, seed, done = task
    if len(items) <= n:
        return task, None
    return (items[:n], seed, done), (items[n:], seed, done)


def _tail(last):
    """``_execute_local``'s last two good frames, ``None`` when there is none."""
    return last if last[0] is not None else None


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
        tail = tail_of(dicts)
        if tail is None:
            last = (None, None)
        else:  # one good frame: the frame it was predicted from before it
            last = (tail[0], ref if tail[1] is None else tail[1])
    return last


def _execute_dask(setup, tasks, before, on_chunk, on_poll, scheduler, workers, frames_dir,
                  poll_s: float = 0.25, connect_timeout: float = 20.0):
    """Run the chunks on the Dask cluster at ``scheduler``. The tasks write every finished
    frame to ``frames_dir`` when they can (a shared filesystem); ``on_chunk(dicts)`` is
    called when a chunk comes back, ``on_poll()`` (if given) while waiting."""
    from dask.distributed import Client

    del workers  # the cluster's own
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

    def wait(futures, timeout):
        ready = [f for f in futures if f.done()]
        if not ready:
            time.sleep(timeout)
        return ready

    try:
        s = client.scatter(setup, broadcast=True)
        _run_chain(lambda items, seed, done, prev: client.submit(
                       run_chunk, s, items, seed, done, None, frames_dir, previous=prev,
                       pure=False),
                   wait, tasks, before, on_chunk, on_poll, poll_s)
    finally:
        client.close()


def default_workers() -> int:
    """Local worker processes by default: one per CPU core."""
    return max(int(os.cpu_count() or 1), 1)
