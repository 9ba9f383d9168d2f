"""Phase 2's compute per (frame, node) cell, against the revision before, in one run.

A block of 2,000 frames x 4,369 nodes (a chunk column of the 600 k-node run), every node
seen: 12-bit-like intensities (1,500 counts, 1 % noise) as the work file's uint16 codes.
Timed: dCp, its statistics and the Welch PSD (nperseg 256) of the block, in memory (no
file), with the default threads and with one; the peer is the revision given by
``--baseline DIR`` (a ``git archive`` of it), whose ``dcp_block`` and ``welch_block`` run
on the same block (decoded to float32, as its work file held it). Alternating, median of
``--repeat`` runs, ``uptime``'s load printed.

    python bench/bench_unsteady_phase2.py --baseline /tmp/base [--repeat 3]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _module(root: Path, rel: str, name: str):
    spec = importlib.util.spec_from_file_location(name, root / rel)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def main() -> None:
    from selfillum.unsteady.phase2 import legendre_basis, phase2_block
    from selfillum.unsteady.spectra import welch_block
    from selfillum.unsteady.work import decode_columns, encode_rows

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="a checkout of the revision before")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--nodes", type=int, default=4369)
    args = ap.parse_args()
    base = Path(args.baseline)
    old2 = _module(base, "selfillum/unsteady/phase2.py", "old_phase2")
    olds = _module(base, "selfillum/unsteady/spectra.py", "old_spectra")
    T, n = args.frames, args.nodes
    rng = np.random.default_rng(0)
    t = np.arange(T)
    codes, scale = encode_rows((1500 * (1 + 0.01 * rng.standard_normal((T, n))))
                               .astype(np.float32))
    g = np.full(n, 0.5)
    basis = legendre_basis(t)

    def now(workers):
        d, _, _, _, share = phase2_block(codes, t, g, 300.0, scale=scale, basis=basis,
                                         workers=workers, return_share=True)
        welch_block(d, 2000.0, 256, workers=workers, share=share)

    def before():
        d = old2.dcp_block(decode_columns(codes, scale).astype(np.float32), t, g, 300.0)
        olds.welch_block(d, 2000.0, 256)

    cases = {"now (default threads)": lambda: now(None), "now (one thread)": lambda: now(1),
             "before": before}
    for f in cases.values():  # compiled kernels loaded, caches warm
        f()
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    res = {k: [] for k in cases}
    for _ in range(args.repeat):
        for k, f in cases.items():
            w = time.perf_counter()
            f()
            res[k].append((time.perf_counter() - w) * 1e9 / (T * n))
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    ref = np.median(res["before"])
    for k, v in res.items():
        print(f"{k:<24}{np.median(v):7.1f} ns a cell (runs "
              f"{', '.join(f'{x:.1f}' for x in v)}); before / this {ref / np.median(v):.1f}")


if __name__ == "__main__":
    main()
