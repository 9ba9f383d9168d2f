"""The whole command on 2 cores and on more, on one machine (issue 21 item 5): what more
cores give, measured rather than projected.

Each command runs in a fresh process pinned to the first ``c`` cores
(``taskset -c 0-(c-1)``), for each ``c`` of ``--cores``, the rounds interleaved, best of
``--repeat``. Printed per core count: wall seconds, the speed-up over 2 cores, and the
serial share of the 2-core time that this speed-up implies by Amdahl's law,
``s = (T_c / T_2 - 2 / c) / (1 - 2 / c)`` (``T_c = T_2 (s + (1 - s) 2 / c)``). The issue's
target: at 16 cores, at least 3x the 2-core speed (``s`` at or under 20 %).

* ``correct``: ``selfillum correct`` on the real-size grid of ``bench_si_command.py``
  (609k faces, slab and box), start-up, reading and writing included.
* ``track``: ``resection track`` on ``--track-frames`` frames of the body of revolution of
  ``bench_track_command.py`` (with ``--track-frames 0``, skipped).

The package's thread counts follow the process's CPU affinity
(:func:`resection._threads.available_cores`), so nothing else is set per run.

With ``--roots A,B`` each source tree's command runs in every round (``PYTHONPATH``):
before and after in the same run.

Run: ``.venv/bin/python bench/bench_cores.py [--cores 2,4,8,16] [--repeat 2]
[--faces 609000] [--track-frames 200] [--roots A,B] [--commands correct,track]``
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))


def pinned(cores: int, cmd: list[str], root: Path = ROOT) -> float:
    """Wall seconds of ``cmd`` on the first ``cores`` cores, importing the package from the
    source tree ``root`` (fails loudly)."""
    t = time.perf_counter()
    path = os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))
    subprocess.run(["taskset", "-c", f"0-{cores - 1}", *cmd], check=True,
                   stdout=subprocess.DEVNULL, cwd=tempfile.gettempdir(),
                   env={**os.environ, "PYTHONPATH": path})
    return time.perf_counter() - t


def report(name: str, best: dict[int, float]) -> None:
    t2 = best.get(2)
    print(f"\n{name}: load average {os.getloadavg()[0]:.1f}")
    for c, t in sorted(best.items()):
        line = f"  {c:3d} cores  {t:7.2f} s"
        if t2 is not None and c != 2:
            s = (t / t2 - 2.0 / c) / (1.0 - 2.0 / c)
            line += (f"   speed-up over 2 cores {t2 / t:5.2f}x   implied serial share "
                     f"{100 * s:4.0f} % of the 2-core time")
        print(line, flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cores", default=f"2,{len(os.sched_getaffinity(0))}")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--faces", type=int, default=609_000)
    ap.add_argument("--track-frames", type=int, default=200)
    ap.add_argument("--commands", default="correct,track",
                    help="which commands to time (default both)")
    ap.add_argument("--cache", default=str(Path(tempfile.gettempdir()) / "bench_cores"))
    ap.add_argument("--roots", default=str(ROOT),
                    help="comma-separated source trees, run in turn in every round (e.g. an "
                    "earlier commit unpacked with git archive, against this one)")
    args = ap.parse_args()
    cores = sorted({int(c) for c in args.cores.split(",")})
    if max(cores) > len(os.sched_getaffinity(0)):
        sys.exit(f"bench_cores: --cores {args.cores} asks for more cores than the "
                 f"{len(os.sched_getaffinity(0))} this process may use")
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    cmds = {}
    from bench_si_command import files

    wanted = set(args.commands.split(","))
    if "correct" in wanted:
        (cache / "grid").mkdir(exist_ok=True)
        f, _ = files(args.faces, cache / "grid")
        cmds["correct"] = [py, "-m", "selfillum.cli", "correct", "--mesh", f["mesh"],
                           "--camera", f["camera"], "--image", f["image"], "--reflectance",
                           "0.5", "--unpainted", f["unpainted"], "--quiet", "--out",
                           str(cache / "corrected.npy")]
    if args.track_frames and "track" in wanted:
        from bench_track_command import PERIOD, render

        sc = render(cache / "track")
        frames = [sc["frames"][k % PERIOD] for k in range(args.track_frames)]
        cmds["track"] = [py, "-m", "resection.cli", "track", *frames, "--camera",
                         sc["camera"], "--markers", sc["markers"], "--link", sc["link"],
                         "--diameter", "5", "--out", str(cache / "track_out"),
                         "--no-progress", "--no-resume"]
    roots = [Path(r).resolve() for r in args.roots.split(",")]
    for name, cmd in cmds.items():
        best = {(r, c): float("inf") for r in roots for c in cores}
        for r in roots:
            clean(cache)
            pinned(max(cores), cmd, r)  # warm-up: numba's cache, the OS's file cache
        for _ in range(args.repeat):
            for c in cores:
                for r in roots:
                    clean(cache)
                    best[r, c] = min(best[r, c], pinned(c, cmd, r))
        for r in roots:
            label = (f"{name} ({args.faces:,} faces)" if name == "correct"
                     else f"{name} ({args.track_frames} frames)")
            report(f"{label}, {r}", {c: best[r, c] for c in cores})


def clean(cache: Path) -> None:
    """Remove the corrected image of the last run (outputs are never overwritten)."""
    for p in cache.glob("corrected.npy*"):
        p.unlink()

if __name__ == "__main__":
    main()
