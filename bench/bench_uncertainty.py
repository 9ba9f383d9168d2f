"""What ``--uncertainty`` adds to ``selfillum psp`` and ``selfillum unsteady``, whole
commands (issue 36 item 5: at most 30 % and 20 %).

Run: ``.venv/bin/python bench/bench_uncertainty.py [--repeat 3] [--psp-resolution 30]
[--frames 200]``

Each command runs in a fresh process, with and without ``--uncertainty`` (linear),
alternating, ``--repeat`` rounds; the ratio with / without of each round, of the wall time
and of the CPU time (user + system of all its threads: less sensitive to the other work on
shared cores), and the best and worst are printed (the peer is the same command without
the option, in the same round):

* ``psp``: the painted corner of ``scenes/psp_uncertainty.py`` (``--psp-resolution`` squares
  a side: ``4 r^2`` faces, 14,400 by default; a 640 x 480 camera; 1024 rays a face), with
  and without the pictures (``--no-plots``), 5 frames a condition
  (NPY stacks: the noise measured on them), the taps in a ``.wtd``, the markers for the
  poses' covariance (``--u marker=0.05px``);
* ``unsteady``: ``scenes/unsteady_run.py`` (2,500 faces, a 200 x 150 camera, ``--frames``
  frames, the default vibration), the paint calibration, ``--u gain_a=0.01 t0=1K q=2psf``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def psp_files(folder: Path, resolution: int) -> tuple:
    from scenes.psp_uncertainty import psp_uncertainty_case, write_psp_files

    c = psp_uncertainty_case(resolution=resolution, width=640, height=480, exact_rays=1024)
    args = write_psp_files(c, folder, 5, rays=1024, seed=0)
    return args, ["--uncertainty", "--markers", str(folder / "model.tgts"), "--u",
                  "marker=0.05px"], len(c.mesh.faces)


def unsteady_files(folder: Path, frames: int) -> tuple:
    from scenes.unsteady_run import make_unsteady_run

    run = make_unsteady_run(folder, frames=frames)
    base = ["unsteady", str(run.deck), "--paint-calibration", str(run.paint), "--steady",
            str(run.steady), "--fps", str(run.fps), "--quiet", "--no-plots"]
    return base, ["--uncertainty", "--u", "gain_a=0.01", "--u", "t0=1K", "--u", "q=2psf"]


def timed(cmd: list, out: Path) -> tuple[float, float]:
    """Wall time and CPU time (user + system, all threads) of the command."""
    import resource
    import shutil

    if out.exists():
        shutil.rmtree(out) if out.is_dir() else out.unlink()
    for p in out.parent.glob(out.stem + "*"):
        if p.is_file():
            p.unlink()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "selfillum.cli", *cmd, "--out", str(out)],
                   check=True, capture_output=True, cwd=ROOT)
    wall = time.perf_counter() - t
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--psp-resolution", type=int, default=60)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--cache", default="/tmp/bench_uncertainty")
    ap.add_argument("--only", choices=("psp", "unsteady"), help="one command only")
    args = ap.parse_args()
    cache = Path(args.cache)
    pdir = cache / f"psp{args.psp_resolution}"
    pdir.mkdir(parents=True, exist_ok=True)
    psp, psp_u, nf = psp_files(pdir, args.psp_resolution)
    uns, uns_u = unsteady_files(cache / "unsteady", args.frames) \
        if args.only != "psp" else (None, None)
    print(f"psp: {nf:,} faces, 640 x 480, 5 frames a condition; unsteady: {args.frames} "
          f"frames; load average {os.getloadavg()}")
    for name, base, extra, out, target in (
            ("psp", psp, psp_u, pdir / "out", 1.3),
            ("psp --no-plots", psp, psp_u + ["--no-plots"], pdir / "out", 1.3),
            ("unsteady", uns, uns_u, cache / "u.h5", 1.2)):
        if args.only not in (None, name.split()[0]):
            continue
        timed(base, out)  # warm the caches (numba, the page cache)
        ratios, cpu = [], []
        for _ in range(args.repeat):
            t0, c0 = timed(base, out)
            t1, c1 = timed(base + extra, out)
            ratios.append(t1 / t0)
            cpu.append(c1 / c0)
            print(f"  {name}: without {t0:.1f} s ({c0:.1f} s CPU), with --uncertainty "
                  f"{t1:.1f} s ({c1:.1f} s CPU): ratio {t1 / t0:.2f} (CPU {c1 / c0:.2f}); "
                  f"load average {os.getloadavg()[0]:.1f}", flush=True)
        print(f"{name}: wall ratio best {min(ratios):.2f}, worst {max(ratios):.2f}; CPU ratio "
              f"best {min(cpu):.2f}, worst {max(cpu):.2f} (target <= {target})")


if __name__ == "__main__":
    main()
