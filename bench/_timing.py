"""Timing helper shared by the bench scripts (run them as ``python bench/bench_x.py``)."""

from __future__ import annotations

import time


def best_of(fn, repeat: int = 3):
    """``(best wall time in seconds over `repeat` calls, the last call's result)``."""
    best = float("inf")
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out
