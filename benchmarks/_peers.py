"""Shared set-up for the suite: the bench scripts' scenes and peers, importable from asv."""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "bench"):  # scenes/ and the bench scripts of this checkout
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))


def ratio_of_best(ours, peer, repeat: int = 3) -> float:
    """Best time of ``ours()`` over best time of ``peer()``, the two called in turn
    ``repeat`` times (the same moments of a noisy machine for both)."""
    best = [float("inf"), float("inf")]
    for _ in range(repeat):
        for k, fn in enumerate((ours, peer)):
            t0 = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best[0] / best[1]
