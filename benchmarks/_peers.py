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


#: The environment variable that sets the size of the suite's issue-size benchmarks:
#: ``small`` (the default: one ``--quick`` pass of the class within minutes on 2 cores) or
#: ``issue`` (the size an issue set its target at; see the class's docstring).
SIZE_VARIABLE = "WTO_BENCH_SIZE"
#: The environment variable naming another checkout of the project (a folder with
#: ``resection/``, ``selfillum/`` and ``scenes/``) for the benchmarks timed beside it.
BASELINE_VARIABLE = "WTO_BENCH_BASELINE"


def bench_size() -> str:
    """The size of the issue-size benchmarks, from ``WTO_BENCH_SIZE`` (``small`` when it
    is unset); used as their one parameter so that asv keeps each size's history apart."""
    size = os.environ.get(SIZE_VARIABLE, "small")
    if size not in ("small", "issue"):
        raise ValueError(f"{SIZE_VARIABLE}={size!r}: expected 'small' or 'issue'")
    return size


def baseline_root() -> Path | None:
    """The other checkout named by ``WTO_BENCH_BASELINE``, or None when it is unset. A
    relative path (asv runs the benchmarks in a folder of its own) or a folder without the
    project's packages raises."""
    value = os.environ.get(BASELINE_VARIABLE)
    if not value:
        return None
    if not Path(value).is_absolute():
        raise ValueError(f"{BASELINE_VARIABLE}={value}: give an absolute path")
    root = Path(value).resolve()
    if not ((root / "selfillum").is_dir() and (root / "resection").is_dir()):
        raise ValueError(f"{BASELINE_VARIABLE}={value}: not a checkout of the project "
                         "(no selfillum/ and resection/ in it)")
    return root


def best_times(*fns, repeat: int = 3, alternate: bool = False) -> list[float]:
    """Best wall time of each function, the functions called in turn ``repeat`` times
    (the same moments of a noisy machine for all); ``alternate``: every other round in
    the reverse order (A B, B A, ...), so that neither always runs first."""
    best = [float("inf")] * len(fns)
    for r in range(repeat):
        order = list(enumerate(fns))
        if alternate and r % 2:
            order.reverse()
        for k, fn in order:
            t0 = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def ratio_of_best(ours, peer, repeat: int = 3) -> float:
    """Best time of ``ours()`` over best time of ``peer()``, the two called in turn
    ``repeat`` times."""
    a, b = best_times(ours, peer, repeat=repeat)
    return a / b


def run_command(cmd: list[str], *, cores: int | None = None, env: dict | None = None,
                root: Path = ROOT) -> tuple[float, float]:
    """Wall seconds and peak resident memory (MiB) of a command in a fresh process, started
    in a temporary folder with the checkout ``root`` (default: this one) first on
    ``PYTHONPATH``; ``cores``: pinned to the first ``cores`` CPUs of this process's
    affinity (``taskset``). A failure raises with the command's last error lines."""
    full = [*cmd]
    if cores is not None:
        cpus = sorted(os.sched_getaffinity(0))[:cores]
        full = ["taskset", "-c", ",".join(map(str, cpus)), *full]
    env = {**os.environ, "PYTHONPATH": str(root), **(env or {})}
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
