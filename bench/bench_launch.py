"""Sparse products of the solve's size on numba's threads against one thread, quiet and
with CPU-bound processes beside (issue 21 item 5: why the solve's products stay serial).

Run: ``.venv/bin/python bench/bench_launch.py [--rows 185846] [--busy 0,2] [--repeat 5]``

A CSR product ``A @ x`` of the shapes the continuation's conjugate gradients apply at
every iteration on the 610,704-face grid (185,846 rows; 0.13 M, 0.4 M, 1 M and 2 M
stored entries, random columns within a band like the form factors of nearby faces) is
timed three ways in the same run: SciPy's ``csr_matvec`` (one thread), a numba kernel on
one thread, and the same kernel with ``prange`` over the rows on every core (numba's
threads, through :func:`resection._threads.numba_threads`). Each is the median of
``--repeat`` rounds of 20 products, with ``--busy`` CPU-bound processes running beside
(0: quiet). A parallel launch waits for every thread of numba's team: when another
process holds a core, the launch waits for the scheduler to give the thread its turn.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from resection._threads import numba_threads  # noqa: E402


@numba.njit(cache=True, nogil=True)
def _serial(indptr, indices, data, x, out):  # pragma: no cover - compiled
    for i in range(out.size):
        s = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            s += data[k] * x[indices[k]]
        out[i] = s


@numba.njit(cache=True, nogil=True, parallel=True)
def _parallel(indptr, indices, data, x, out):  # pragma: no cover - compiled
    for i in numba.prange(out.size):
        s = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            s += data[k] * x[indices[k]]
        out[i] = s


def _burn(stop) -> None:
    while not stop.is_set():
        sum(i * i for i in range(10_000))


def _matrix(rows: int, nnz: int, rng) -> sp.csr_matrix:
    r = rng.integers(0, rows, nnz)
    c = np.clip(r + rng.integers(-2000, 2000, nnz), 0, rows - 1)
    return sp.csr_matrix((rng.random(nnz), (r, c)), shape=(rows, rows))


def _time(fn, repeat: int) -> float:
    fn()
    runs = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(20):
            fn()
        runs.append((time.perf_counter() - t) / 20)
    return statistics.median(runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=185_846)
    ap.add_argument("--busy", default="0,2", help="CPU-bound processes beside, e.g. 0,2")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    mats = {n: _matrix(args.rows, n, rng) for n in (130_000, 400_000, 1_000_000, 2_000_000)}
    x = rng.random(args.rows)
    out = np.empty(args.rows)
    print(f"{args.rows:,} rows, numba's threads: {numba.get_num_threads()}, "
          f"{os.cpu_count()} cores")
    for busy in (int(b) for b in args.busy.split(",")):
        stop = mp.Event()
        procs = [mp.Process(target=_burn, args=(stop,)) for _ in range(busy)]
        for p in procs:
            p.start()
        time.sleep(1.0 if busy else 0.0)
        print(f"\n{busy} CPU-bound processes beside, load average {os.getloadavg()[0]:.1f}:")
        for nnz, A in mats.items():
            arrays = (A.indptr, A.indices, A.data, x, out)
            t_sp = _time(lambda A=A: A @ x, args.repeat)
            t_1 = _time(lambda a=arrays: _serial(*a), args.repeat)

            def par(a=arrays):
                with numba_threads(None):
                    _parallel(*a)

            t_p = _time(par, args.repeat)
            print(f"  {nnz / 1e6:4.2f} M entries: SciPy {1e3 * t_sp:6.2f} ms, numba one "
                  f"thread {1e3 * t_1:6.2f} ms, numba threads {1e3 * t_p:6.2f} ms: threads "
                  f"/ SciPy {t_p / t_sp:5.2f}x")
        stop.set()
        for p in procs:
            p.join()
    print(f"numba's threading layer: {numba.threading_layer()}")


if __name__ == "__main__":
    main()
