"""Shared timing for the suite: ratios of best times taken in turn, and whole commands run
in fresh processes."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # scenes/ of this checkout
    sys.path.insert(0, str(ROOT))


def best_times(*fns, repeat: int = 3) -> list[float]:
    """Best wall time of each function, the functions called in turn ``repeat`` times
    (the same moments of a noisy machine for all)."""
    best = [float("inf")] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def ratio_of_best(ours, peer, repeat: int = 3) -> float:
    """Best time of ``ours()`` over best time of ``peer()``, the two called in turn
    ``repeat`` times."""
    a, b = best_times(ours, peer, repeat=repeat)
    return a / b


def run_command(cmd: list[str], *, cores: int | None = None, env: dict | None = None
                ) -> tuple[float, float]:
    """Wall seconds and peak resident memory (MiB) of a command in a fresh process, started
    in a temporary folder with this checkout first on ``PYTHONPATH``; ``cores``: pinned to
    the first ``cores`` CPUs of this process's affinity (``taskset``). A failure raises
    with the command's last error lines."""
    full = [*cmd]
    if cores is not None:
        cpus = sorted(os.sched_getaffinity(0))[:cores]
        full = ["taskset", "-c", ",".join(map(str, cpus)), *full]
    env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    t0 = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-f", "%M", *full], env=env, capture_output=True,
                       text=True, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t0
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd[:4])} ...: exit {p.returncode}\n{p.stderr[-2000:]}")
    return wall, float(p.stderr.strip().splitlines()[-1]) / 1024.0


def serial_share(t_one: float, t_two: float) -> float:
    """Amdahl's serial share of the 2-core time from the times on 1 and 2 cores:
    ``T1 = S + P``, ``T2 = S + P / 2`` give ``S / T2 = 2 - T1 / T2``."""
    return 2.0 - t_one / t_two
