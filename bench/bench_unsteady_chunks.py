"""The unsteady run's dCp dataset: reading one frame of every node and one node's whole
history, on a run of 2,000 frames onto about 600 k nodes (4.8 GB of float32).

Ours: one chunked HDF5 dataset ``/dcp`` (T, N) with the chunks of
:func:`selfillum.unsteady.output.chunk_shape`, written in blocks of chunk rows as Phase 1
writes it. Peers in the same run: uPSP's two flat files (``pressure``, row = frame, and
``pressure_transpose``, row = node: twice the storage, one file for each use), and the same
dataset chunked one frame per chunk (the layout of a frame-per-dataset history).

Each read is timed warm (the file in the page cache) and cold (the file's pages dropped
with ``posix_fadvise(DONTNEED)`` before each read; no root needed), best of 5, at random
frames and nodes. Run: ``python bench/bench_unsteady_chunks.py [--frames 2000] [--nodes
600000] [--dir DIR]``; it needs about 3 x 4.8 GB of disk in DIR (removed at the end).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from selfillum.unsteady.output import chunk_shape, write_flat  # noqa: E402


def _drop(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def _time(fn, path: Path, cold: bool, picks) -> float:
    best = np.inf
    for p in picks:  # a few reads
        if cold:
            _drop(path)
        t0 = time.perf_counter()
        fn(p)
        best = min(best, time.perf_counter() - t0)
    return best


def _write(path: Path, T: int, N: int, chunks) -> float:
    rng = np.random.default_rng(0)
    base = rng.standard_normal((16, N)).astype(np.float32)  # row k: base[k % 16] + k
    tc = chunks[0] * max(1, 16 // chunks[0])
    t0 = time.perf_counter()
    with h5py.File(path, "w") as f:
        ds = f.create_dataset("dcp", (T, N), "f4", chunks=chunks)
        for a in range(0, T, tc):  # blocks of whole chunk rows, as Phase 1
            k = np.arange(a, min(a + tc, T))
            ds[a:k[-1] + 1] = base[k % 16] + k[:, None].astype(np.float32)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--nodes", type=int, default=600_000)
    ap.add_argument("--dir", default=None)
    a = ap.parse_args()
    T, N = a.frames, a.nodes
    work = Path(tempfile.mkdtemp(prefix="bench_unsteady_", dir=a.dir))
    try:
        ours = work / "ours.h5"
        per_frame = work / "per_frame.h5"
        ch = chunk_shape(T, N)
        print(f"{T} frames x {N} nodes ({T * N * 4 / 1e9:.2f} GB float32); "
              f"chunks {ch[0]} x {ch[1]} ({ch[0] * ch[1] * 4 / 1024:.0f} kB); "
              f"load {os.getloadavg()[0]:.1f}")
        w_ours = _write(ours, T, N, ch)
        w_pf = _write(per_frame, T, N, (1, N))
        t0 = time.perf_counter()
        with h5py.File(ours) as f:
            write_flat(f, work / "pressure", work / "pressure_transpose")
        w_flat = time.perf_counter() - t0
        print(f"write: ours {w_ours:.1f} s, frame chunks {w_pf:.1f} s, uPSP flat pair from "
              f"ours {w_flat:.1f} s")
        rng = np.random.default_rng(1)
        frames = rng.integers(0, T, 5)
        nodes = rng.integers(0, N, 5)
        fo = h5py.File(ours, "r", rdcc_nbytes=0)
        fp = h5py.File(per_frame, "r", rdcc_nbytes=0)
        pr = np.memmap(work / "pressure", "<f4", "r", shape=(T, N))
        pt = np.memmap(work / "pressure_transpose", "<f4", "r", shape=(N, T))
        check = fo["dcp"][int(frames[0])]
        assert np.array_equal(check, fp["dcp"][int(frames[0])])
        assert np.array_equal(check, np.asarray(pr[int(frames[0])]))
        assert np.array_equal(fo["dcp"][:, int(nodes[0])], np.asarray(pt[int(nodes[0])]))
        rows = []
        for cold in (False, True):
            r = {
                "ours frame": _time(lambda k: fo["dcp"][int(k)], ours, cold, frames),
                "ours node": _time(lambda n: fo["dcp"][:, int(n)], ours, cold, nodes),
                "frame-chunks frame": _time(lambda k: fp["dcp"][int(k)], per_frame, cold,
                                            frames),
                "frame-chunks node": _time(lambda n: fp["dcp"][:, int(n)], per_frame, cold,
                                           nodes),
                "uPSP pressure frame": _time(lambda k: np.array(pr[int(k)]), work / "pressure",
                                             cold, frames),
                "uPSP transpose node": _time(lambda n: np.array(pt[int(n)]),
                                             work / "pressure_transpose", cold, nodes),
            }
            rows.append(("cold" if cold else "warm", r))
        for name, r in rows:
            print(f"[{name}] one frame: ours {1e3 * r['ours frame']:.1f} ms, frame chunks "
                  f"{1e3 * r['frame-chunks frame']:.1f} ms, uPSP 'pressure' "
                  f"{1e3 * r['uPSP pressure frame']:.1f} ms")
            print(f"[{name}] one node's history: ours {1e3 * r['ours node']:.1f} ms, frame "
                  f"chunks {1e3 * r['frame-chunks node']:.1f} ms "
                  f"({r['frame-chunks node'] / r['ours node']:.0f}x ours), uPSP "
                  f"'pressure_transpose' {1e3 * r['uPSP transpose node']:.2f} ms")
        fo.close()
        fp.close()
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
