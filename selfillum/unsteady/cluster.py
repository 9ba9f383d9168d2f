"""The run on Dask: Phase 1 spread over blocks of frames, Phase 2 over blocks of nodes.

``--workers N`` starts a local cluster of ``N`` worker processes (one thread each);
``--scheduler ADDRESS`` joins a running one (the workers must read the run's files at the
same paths: a shared file system). One process writes: the workers return their blocks and
the command writes them (Phase 1 into the journaled work file, in the order they finish;
Phase 2 into ``/dcp``), so the files are the same with one worker or many.

A Phase 1 task maps frame 0 and then its block (frame 0 fixes the cameras' gains, the
self-illumination's reference and the registration's, exactly as the run on one process
does, so the blocks do not depend on how the frames were split). The form factors and the
job's settings are sent to every worker once; with ``registration = track`` so are the
poses of every frame, in a compact form (:class:`PoseArrays`: a camera's rotations and
translations as two arrays), and each task plans a moving model's references over all the
run's frames (:class:`selfillum.unsteady.references.ReferencePlan`, deterministic given
the poses, frame 0's probe points and the frames), so it samples each of its frames through
the same reference as one process (a reference outside its block is cast from its pose
alone: no image).
A Phase 2 task reads its block of nodes from the work file,
computes dCp, its statistics and Welch spectra, and returns them.
"""

from __future__ import annotations

import contextlib
import functools
from dataclasses import dataclass

import numpy as np

__all__ = ["Phase1Job", "PoseArrays", "open_client", "phase1_blocks", "phase2_blocks"]


@dataclass(frozen=True)
class Phase1Job:
    """What a worker needs to map frames (plain, picklable values and paths)."""

    grid: str
    videos: tuple
    cameras: tuple  # frame 0's Camera of each camera
    numbers: tuple
    spots: object
    registration: str
    patcher: str
    overlap: str
    filter: str
    filter_size: int
    oblique_angle: float
    unpainted: object
    rho: object
    gains: object
    fast: bool
    nondata: object = None  # (N,) bool: nodes stored unseen (cutoff_x_max)


@contextlib.contextmanager
def open_client(workers: int | None, scheduler: str | None):
    """A ``distributed.Client``: on ``scheduler``, or on a local cluster of ``workers``
    processes of one thread each (closed at the end)."""
    from distributed import Client, LocalCluster

    if scheduler:
        with Client(scheduler) as client:
            yield client
        return
    with LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        yield client


@functools.lru_cache(maxsize=2)
def _grid(path: str):
    from selfillum.unsteady.grid import load_run_grid

    return load_run_grid(path)  # once a worker process


class PoseArrays:
    """One camera's pose of every frame as arrays, indexed like a list of Camera.

    Parameters
    ----------
    camera : resection.Camera
        The intrinsics (any frame's camera).
    R : (T, 3, 3) array
        Rotations model -> camera, frame by frame.
    t : (T, 3) array
        Translations, model units.
    """

    def __init__(self, camera, R, t):
        self.camera, self.R, self.t = camera, np.asarray(R), np.asarray(t)

    @classmethod
    def of(cls, poses) -> PoseArrays:
        """From a sequence of Camera (every frame's, same intrinsics)."""
        return cls(poses[0], np.stack([np.asarray(c.R, np.float64) for c in poses]),
                   np.stack([np.asarray(c.t, np.float64).ravel() for c in poses]))

    def __len__(self) -> int:
        return len(self.R)

    def __getitem__(self, k: int):
        return self.camera.with_pose(R=self.R[k], t=self.t[k])


def _map_block(job: Phase1Job, F, a: int, b: int, poses=None):
    """Frames ``a .. b`` of every camera (frame 0 first), on a worker; ``poses``: per
    camera a :class:`PoseArrays` of every frame (a moving model's references planned
    over them all)."""
    from resection.io.video import open_frames
    from resection.memory import keep_freed_memory

    keep_freed_memory()  # the nanny's MALLOC_TRIM_THRESHOLD_ undone (page faults)
    from selfillum.unsteady.phase1 import CameraRun, SelfIllumination, map_run
    from selfillum.unsteady.work import BlockBuffer

    grid = _grid(job.grid)
    srcs = [open_frames(v) for v in job.videos]
    try:
        runs = [CameraRun(n, c, s, None if poses is None else poses[i])
                for i, (n, c, s) in enumerate(zip(job.numbers, job.cameras, srcs,
                                                  strict=True))]
        si = None if F is None else SelfIllumination(grid.mesh, F, job.rho, job.unpainted)
        frames = list(range(a, b)) if a == 0 else [0, *range(a, b)]
        every = None if poses is None else range(len(poses[0]))  # the one-process plan
        buf = BlockBuffer(b - a, grid.n_nodes, with_raw=si is not None, nondata=job.nondata)
        C = len(runs)
        R, t = np.empty((C, b - a, 3, 3)), np.empty((C, b - a, 3))
        for fn in map_run(grid, runs, frames, spots=job.spots, registration=job.registration,
                          patcher=job.patcher, overlap=job.overlap, filter=job.filter,
                          filter_size=job.filter_size, max_obliqueness=job.oblique_angle,
                          si=si, unpainted=job.unpainted, gains=job.gains, fast=job.fast,
                          workers=1, plan_frames=every):
            k = fn.index
            if k < a:
                continue  # frame 0 again: the references
            buf.put(k - a, fn.values, fn.raw)
            for ci, cm in enumerate(fn.cameras):
                R[ci, k - a], t[ci, k - a] = cm.R, cm.t
        return a, buf.rows(b - a), R, t
    finally:
        for s in srcs:
            with contextlib.suppress(Exception):
                s.close()


def phase1_blocks(client, job: Phase1Job, F, blocks, poses=None):
    """Yield ``(a, rows, R, t)`` for every ``(a, b)`` of ``blocks``, as they finish
    (``rows``: :meth:`selfillum.unsteady.work.BlockBuffer.rows`); ``poses``: per camera
    every frame's Camera (``registration = track``), sent to every worker once as
    :class:`PoseArrays`."""
    from distributed import as_completed

    Ff = client.scatter(F, broadcast=True) if F is not None else None
    jobf = client.scatter(job, broadcast=True)
    posef = None if poses is None else client.scatter(
        tuple(PoseArrays.of(p) for p in poses), broadcast=True)
    futs = [client.submit(_map_block, jobf, Ff, a, b, posef, pure=False)
            for a, b in blocks]
    for fut in as_completed(futs):
        yield fut.result()
        fut.release()


def _phase2_block(path: str, a: int, b: int, times, gain, q: float, with_raw: bool,
                  fs: float | None, nperseg: int | None):
    """dCp of nodes ``a .. b`` from the work file, its statistics and spectra."""
    import h5py

    from resection.memory import keep_freed_memory

    keep_freed_memory()  # the nanny's MALLOC_TRIM_THRESHOLD_ undone (page faults)

    from selfillum.unsteady.phase2 import phase2_block
    from selfillum.unsteady.spectra import welch_block

    with h5py.File(path, "r") as f:
        raw = f["raw"][:, a:b] if with_raw else None
        raw_scale = f["raw_scale"][()] if with_raw else None
        d, mean, rms, change, share = phase2_block(
            f["values"][:, a:b], times, gain, q, scale=f["values_scale"][()], raw=raw,
            raw_scale=raw_scale, workers=1, return_share=True)
    psd = welch_block(d, fs, nperseg, workers=1, share=share)[1] if fs is not None else None
    return a, d, mean, rms, change, psd


def phase2_blocks(client, path: str, N: int, nodes_per_block: int, times, gain, q: float,
                  with_raw: bool, spectra=None):
    """Yield Phase 2's ``(a, dcp, mean, rms, si_change, psd)`` per block of nodes, as they
    finish (``psd`` None without ``spectra``)."""
    from distributed import as_completed

    fs = spectra.fs if spectra is not None else None
    nper = spectra.nperseg if spectra is not None else None
    futs = [client.submit(_phase2_block, path, a, min(a + nodes_per_block, N), times,
                          gain[a:a + nodes_per_block], q, with_raw, fs, nper, pure=False)
            for a in range(0, N, nodes_per_block)]
    for fut in as_completed(futs):
        yield fut.result()
        fut.release()
