"""Is the orchestration of ``selfillum entry`` free? An entry of ``--datapoints``
datapoints against the sum of the same datapoints run alone (one ``selfillum entry --only
ID`` each: its own process, its own Dask cluster, its own view factors), on the synthetic
entry of :mod:`scenes.entry` (uPSP's index and processing file, 12-bit ``.mraw``, the
plate-and-block model at ``--faces``, ``--frames`` frames of ``--width`` x ``--height``).

Each command runs in a fresh process, after an untimed warm-up (numba's cached kernels,
the page cache); the wall times are compared in the same run, as the ratio
``entry / sum(alone)`` (the issue's target: at most 1.2), for the Dask local cluster
(``--workers``) and in-process (``--workers 0``). The machine's load (``uptime``) is
printed: on a shared machine, run it more than once.

    python bench/bench_entry.py --datapoints 4 --frames 64 [--faces 2500] [--rays 64]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from scenes.entry import make_entry  # noqa: E402


def timed(args: list) -> float:
    cmd = [sys.executable, "-c", "import sys; from selfillum.cli import main; "
           "sys.exit(main(sys.argv[1:]))", *args]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    el = time.perf_counter() - t0
    if r.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(args)} failed:\n{r.stderr[-2000:]}")
    return el


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datapoints", type=int, default=4)
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--faces", type=int, default=2500)
    ap.add_argument("--width", type=int, default=200)
    ap.add_argument("--height", type=int, default=150)
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--workers", type=int, default=1)
    a = ap.parse_args()
    alphas = tuple(-5.0 + 20.0 * k / max(1, a.datapoints - 1) for k in range(a.datapoints))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        e = make_entry(tmp / "entry", alphas=alphas, wind_off=False, corrupt=False,
                       faces=a.faces, frames=a.frames, width=a.width, height=a.height)
        print(f"entry of {len(e.ids)} datapoints made in {time.perf_counter() - t0:.1f} s")
        base = [str(e.index), "--processing", str(e.processing), "--rays", str(a.rays),
                "--quiet"]
        for workers in (a.workers, 0):
            w = ["--workers", str(workers)]
            # untimed: compiled kernels cached, files in the page cache, for either order
            timed(["entry", *base, *w, "--only", e.ids[0], "--out", str(tmp / "warm")])
            shutil.rmtree(tmp / "warm")
            whole = timed(["entry", *base, *w, "--out", str(tmp / "all")])
            shutil.rmtree(tmp / "all")
            alone = []
            for dp in e.ids:
                alone.append(timed(["entry", *base, *w, "--only", dp, "--out",
                                    str(tmp / dp)]))
                shutil.rmtree(tmp / dp)
            print(f"load {os.getloadavg()[0]:.1f}; workers {workers}: entry {whole:.1f} s, "
                  "datapoints alone "
                  f"{' + '.join(f'{x:.1f}' for x in alone)} = {sum(alone):.1f} s; "
                  f"ratio {whole / sum(alone):.2f}")


if __name__ == "__main__":
    main()
