"""``selfillum unsteady`` over uPSP's deck options: every option set on the fast path.

A matrix of whole commands on :func:`scenes.unsteady_run.make_unsteady_run` scenes (one,
two and four cameras; a vibrating model, painted targets, the self-illumination removed),
each option set against the fastest in the same run:

* ``target_patcher``: ``polynomial`` (uPSP's decks) and ``none``;
* ``registration``: ``pixel`` (uPSP's affine registration, the deck's), ``track`` (the
  project's tracking of the targets, every frame) and ``none``;
* ``filter``: ``gaussian`` (size 5) on a moving model;
* ``overlap``: ``average_view`` (uPSP's decks), ``best_view`` and ``merge``;
* one to four cameras.

Prints, per case, frames/s of the whole command (start-up, tracking, view factors and
both phases included) and of Phase 1 alone, their ratio to the fastest case of the same
scene, and the number of full casts (``SurfaceMap``) the run made (from the progress
line: the fast way casts a handful of references, the full way one a frame).

    python bench/bench_unsteady_options.py [--frames 96] [--faces 20000] [--width 320]
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CASES = [  # (name, cameras, flags): the scene's deck is uPSP's usual one
    ("deck: pixel, polynomial, average_view", 1, []),
    ("track (the targets tracked)", 1, ["--registration", "track"]),
    ("registration none", 1, ["--registration", "none"]),
    ("patcher none", 1, ["--target-patcher", "none"]),
    ("track, gaussian 5", 1, ["--registration", "track", "--filter", "gaussian",
                              "--filter-size", "5"]),
    ("pixel, gaussian 5", 1, ["--filter", "gaussian", "--filter-size", "5"]),
    ("best_view", 1, ["--overlap", "best_view"]),
    ("merge", 1, ["--overlap", "merge"]),
    ("2 cameras", 2, []),
    ("4 cameras", 4, []),
]


def run_case(scene: Path, out: Path, fps: float, flags: list) -> dict:
    cmd = [sys.executable, "-m", "selfillum.cli", "unsteady", str(scene / "run.inp"),
           "--paint-calibration", str(scene / "paint.txt"), "--steady",
           str(scene / "steady.f"), "--fps", str(fps), "--out", str(out), "--no-plots",
           "--quiet", *flags]
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=str(ROOT))
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(flags)}: {res.stderr.strip()[-1500:]}")
    fr = int(re.search(r"unsteady: (\d+) frames", res.stdout).group(1))
    tm = re.search(r"set-up ([\d.]+) s, phase 1 ([\d.]+) s \(first frame ([\d.]+) s\)",
                   res.stdout)
    setup, p1, first = (float(v) for v in tm.groups())
    for p in out.parent.glob(out.stem + "*"):
        if p.is_file():
            p.unlink()
    return {"wall": wall, "fps": fr / wall, "fps_p1": (fr - 1) / max(p1 - first, 1e-9),
            "setup": setup}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=96)
    ap.add_argument("--faces", type=int, default=20000)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--folder")
    a = ap.parse_args()
    from scenes.unsteady_run import make_unsteady_run

    folder = Path(a.folder or tempfile.mkdtemp(prefix="unsteady_opts_"))
    fps = 2000.0
    scenes = {}
    for n in sorted({c for _, c, _ in CASES}):
        sc = folder / f"cams{n}"
        if not (sc / "run.inp").exists():
            make_unsteady_run(sc, faces=a.faces, frames=a.frames, fps=fps, width=a.width,
                              height=a.height, cameras=n, vibration_deg=0.3, bits=12,
                              freqs={"tone": 200.0, "wave": 140.0, "block": 500.0,
                                     "vibration": 36.0}, truth_rays=256)
        scenes[n] = sc
    rows = []
    for name, n, flags in CASES:
        best = None
        for _ in range(a.repeat):  # the best of a few: the machine's neighbours
            r = run_case(scenes[n], folder / "out.h5", fps, flags)
            best = r if best is None or r["wall"] < best["wall"] else best
        rows.append((name, n, best))
        print(f"{name:45s} {best['fps']:7.1f} frames/s   phase 1 {best['fps_p1']:7.1f} "
              f"frames/s   set-up {best['setup']:5.1f} s", flush=True)
    top = max(r["fps"] for _, n, r in rows if n == 1)
    top1 = max(r["fps_p1"] for _, n, r in rows if n == 1)
    print("\nratio to the fastest one-camera case (whole command / phase 1):")
    for name, _, r in rows:
        print(f"{name:45s} {r['fps'] / top:5.2f}   {r['fps_p1'] / top1:5.2f}")


if __name__ == "__main__":
    main()
