"""The unsteady run's output written through :func:`resection.io.guarded.guarded_h5` (a
Python file object under HDF5, so that a full disk is one error, not a crash) against h5py's
own file driver, in the same run: a (T, N) float32 dataset in the run's chunks, written by
blocks of nodes as Phase 2 writes it. Prints the seconds of each and their ratio (best of
``--repeat``).

    python bench/bench_guarded_h5.py --frames 2000 --nodes 50000
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def _write(f, data, chunks, block):
    ds = f.create_dataset("dcp", data.shape, "f4", chunks=chunks, fillvalue=np.nan)
    for a in range(0, data.shape[1], block):
        ds[:, a:a + block] = data[:, a:a + block]


def main() -> None:
    import h5py

    from resection.io.guarded import guarded_h5
    from selfillum.unsteady.output import chunk_shape

    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--nodes", type=int, default=50000)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    data = np.random.default_rng(0).standard_normal((a.frames, a.nodes)).astype(np.float32)
    chunks = chunk_shape(a.frames, a.nodes)
    block = chunks[1] * 4
    best = {"h5py": np.inf, "guarded": np.inf}
    with tempfile.TemporaryDirectory() as d:
        for _ in range(a.repeat):
            for name in best:
                p = Path(d) / f"{name}.h5"
                p.unlink(missing_ok=True)
                t = time.perf_counter()
                if name == "h5py":
                    with h5py.File(p, "w") as f:
                        _write(f, data, chunks, block)
                else:
                    with guarded_h5(p) as (f, check):
                        _write(f, data, chunks, block)
                        check()
                best[name] = min(best[name], time.perf_counter() - t)
    mb = data.nbytes / 2**20
    print(f"{a.frames} frames x {a.nodes} nodes ({mb:.0f} MiB), chunks {chunks}")
    print(f"h5py's driver {best['h5py']:.3f} s, guarded {best['guarded']:.3f} s, ratio "
          f"{best['guarded'] / best['h5py']:.2f}")


if __name__ == "__main__":
    main()
