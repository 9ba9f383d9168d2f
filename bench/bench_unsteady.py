"""Speed and memory of ``selfillum unsteady`` end to end, as a user runs it.

Generates a run: the slab-and-block model as a Plot3D grid of about ``--nodes`` nodes, one
``--width`` x ``--height`` 12-bit camera (uint16 NPY stack of ``--frames`` frames: the
model rendered once, a 120 Hz tone of 1 % in its light and 0.5 % noise), the ``.wtd``, the
paint calibration, the steady Cp and, for the moving model, a ``resection track`` folder
of the true poses (``--vibration-deg``, default a 0.1-degree, 0.6-mm vibration at 30 Hz:
the pose source is not what is timed). Then runs the command (a fresh process each, its
peak RSS from ``getrusage``) for:

* ``fixed``: ``--registration none --no-si``;
* ``fixed+si``: ``--registration none`` with the self-illumination removed every frame;
* ``moving+si``: ``--registration track --track DIR`` (each frame's pose) with SI;
* with ``--full``: the same with ``--full-maps`` (a ray cast and merge every frame: the
  path before the sparse products), for the ratio.

Prints frames/s end to end, each phase's share (set-up = inputs and form factors, Phase 1,
Phase 2 with the outputs), peak RSS, and ``uptime``'s load. The runs use the command's own
defaults (view factors' rays, pictures) unless ``--rays``/``--no-plots`` are given.

``--deck FOLDER`` runs instead a uPSP run as a user has it: the folder made by
:func:`scenes.unsteady_run.make_unsteady_run` (its ``run.inp`` deck with uPSP's options,
``target_patcher = polynomial``, ``registration = pixel``, ``overlap = average_view``; the
``.wtd`` with NASA's ``RUN`` line), the whole command
``selfillum unsteady run.inp --paint-calibration paint.txt --steady steady.f
--reflectance 0.6 --out OUT.h5``, each run beside ``--baseline``'s (alternating) for the
ratio.

    python bench/bench_unsteady.py --nodes 600000 --frames 2000 [--full] [--rays 16]
    python bench/bench_unsteady.py --deck RUN_FOLDER --baseline OLD_CHECKOUT --repeat 3
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from scenes.unsteady_large import make_large_run  # noqa: E402


def run_case(folder: Path, name: str, extra: list, fps: float, rays: int | None,
             root: Path = ROOT, deck: bool = False, out_dir: Path | None = None) -> dict:
    out = (out_dir or folder) / f"{name}.h5"
    for p in out.parent.glob(f"{name}*"):
        if p.is_file():
            p.unlink()
    head = [sys.executable, "-c",
            "import sys; from selfillum.cli import main; "
            "from selfillum.unsteady.budget import peak_rss_mb; rc = main(sys.argv[1:]); "
            "print('PEAK_MB', peak_rss_mb()); sys.exit(rc)", "unsteady"]
    if deck:  # the user's command on the scene's deck, nothing else
        cmd = head + [str(folder / "run.inp"), "--paint-calibration",
                      str(folder / "paint.txt"), "--steady", str(folder / "steady.f"),
                      "--reflectance", "0.6", "--out", str(out), *extra]
    else:
        cmd = head + ["--grid", str(folder / "model.grid"), "--sds", str(folder / "run.wtd"),
                      "--video", str(folder / "cam01.npy"), "--calibration",
                      str(folder / "cam01.json"), "--paint-calibration",
                      str(folder / "paint.txt"), "--steady", str(folder / "steady.f"),
                      "--fps", str(fps), "--out", str(out), "--quiet", "--overlap",
                      "average_view", *extra]
    if rays is not None:
        cmd += ["--rays", str(rays)]
    env = dict(os.environ, PYTHONPATH=str(root))
    t0 = time.perf_counter()
    # cwd = the revision: "python -c" puts the working folder first on sys.path
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=str(root))
    wall = time.perf_counter() - t0
    if res.returncode != 0:
        raise SystemExit(f"{name}: {res.stderr.strip()[-2000:]}")
    txt = res.stdout
    fr = int(re.search(r"unsteady: (\d+) frames", txt).group(1))
    tm = re.search(r"set-up ([\d.]+) s, phase 1 ([\d.]+) s \(first frame ([\d.]+) s\), "
                   r"phase 2 and outputs ([\d.]+) s", txt)
    setup, p1, first, p2 = (float(v) for v in tm.groups())
    rss = float(re.search(r"PEAK_MB ([\d.]+)", txt).group(1))  # VmHWM: this process's
    for p in out.parent.glob(f"{name}*"):
        if p.is_file():
            p.unlink()
    return {"case": name, "frames": fr, "wall": wall, "setup": setup, "phase1": p1,
            "first": first, "fps_p1_after": (fr - 1) / max(p1 - first, 1e-9),
            "phase2": p2, "fps_run": fr / (setup + p1 + p2), "fps_wall": fr / wall,
            "fps_p12": fr / (p1 + p2), "rss_mb": rss}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=600_000)
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=800)
    ap.add_argument("--rays", type=int, help="rays a face for the view factors (default: "
                    "the command's)")
    ap.add_argument("--no-plots", action="store_true", help="runs without the pictures")
    ap.add_argument("--deck", help="a make_unsteady_run folder: its deck's whole command")
    ap.add_argument("--full", action="store_true", help="also the full per-frame maps")
    ap.add_argument("--vibration-deg", type=float, default=0.1,
                    help="pitch amplitude (the heave 0.6 mm per 0.1 degree), 30 Hz")
    ap.add_argument("--cases", default="fixed,fixed+si,moving+si")
    ap.add_argument("--memory", default="256",
                    help="--memory of the runs, MiB (the command's default)")
    ap.add_argument("--baseline", help="a checkout of another revision: each case is run "
                    "with it too, alternating (e.g. `git archive REV | tar -x -C DIR`)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each case")
    ap.add_argument("--extra", default="", help="more flags for every run")
    ap.add_argument("--folder", help="keep the inputs here (default: a temporary folder)")
    ap.add_argument("--reuse", action="store_true",
                    help="use the inputs already in --folder (made by an earlier run with "
                    "the same sizes)")
    args = ap.parse_args()
    if args.deck:
        return deck_runs(args)
    folder = Path(args.folder) if args.folder else Path(tempfile.mkdtemp(prefix="bench_u_"))
    folder.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    key = {"nodes": args.nodes, "frames": args.frames, "width": args.width,
           "height": args.height, "vibration_deg": args.vibration_deg}
    made = folder / "inputs.json"
    if args.reuse and made.exists() and json.loads(made.read_text())["key"] == key:
        info = json.loads(made.read_text())["info"]
    else:
        info = make_large_run(folder, args.nodes, args.frames, args.width, args.height,
                              vibration_deg=args.vibration_deg)
        made.write_text(json.dumps({"key": key, "info": info}))
    print(f"inputs: {info['nodes']} nodes, {info['faces']} faces, {args.frames} frames of "
          f"{args.width}x{args.height} uint16 ({time.perf_counter() - t0:.0f} s to make); "
          f"vibration {args.vibration_deg} deg: points move up to {info['vibration_px']:.1f} "
          "px")
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    cases = {"fixed": ["--registration", "none", "--no-si"],
             "fixed+si": ["--registration", "none"],
             "moving+si": ["--registration", "track", "--track", str(folder / "track1")]}
    rows = []
    for _ in range(args.repeat):
        for name in args.cases.split(","):
            extra = cases[name] + ["--memory", args.memory] + args.extra.split() + \
                (["--no-plots"] if args.no_plots else [])
            rows.append(run_case(folder, name, extra, info["fps"], args.rays))
            if args.baseline:
                rows.append(run_case(folder, name + "(base)", extra, info["fps"], args.rays,
                                     Path(args.baseline)))
            if args.full:
                rows.append(run_case(folder, name + "(full)", extra + ["--full-maps"],
                                     info["fps"], args.rays))
    report(rows)


def deck_runs(args) -> None:
    """The user's command on a deck folder, beside ``--baseline``'s, ``--repeat`` times."""
    folder = Path(args.deck)
    out_dir = Path(tempfile.mkdtemp(prefix="bench_deck_"))
    extra = args.extra.split() + (["--no-plots"] if args.no_plots else [])
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    rows = []
    for _ in range(args.repeat):
        rows.append(run_case(folder, "deck", extra, 0.0, args.rays, deck=True,
                             out_dir=out_dir))
        if args.baseline:
            rows.append(run_case(folder, "deck(base)", extra, 0.0, args.rays,
                                 Path(args.baseline), deck=True, out_dir=out_dir))
    report(rows)
    if args.baseline:
        new = [r["wall"] for r in rows if r["case"] == "deck"]
        old = [r["wall"] for r in rows if r["case"] == "deck(base)"]
        ratios = sorted(o / n for n, o in zip(new, old, strict=True))
        print(f"speed-up over the baseline (wall, pair by pair): median "
              f"{ratios[len(ratios) // 2]:.2f}x, range {ratios[0]:.2f}-{ratios[-1]:.2f}x")


def report(rows) -> None:
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    print("frames/s: over the run's set-up and phases (inputs read before excluded); wall: "
          "the whole process (start, imports, inputs read) as a user times it")
    print(f"{'case':<18}{'frames/s':>9}{'wall':>7}{'wall s':>8}{'(p1+p2)':>9}{'set-up s':>10}"
          f"{'phase1 s':>10}{'frame0 s':>9}{'p1 f/s':>8}{'phase2 s':>10}{'p1 %':>6}"
          f"{'p2 %':>6}{'peak MB':>9}")
    for r in rows:
        tot = r["setup"] + r["phase1"] + r["phase2"]
        print(f"{r['case']:<18}{r['fps_run']:>9.1f}{r['fps_wall']:>7.1f}{r['wall']:>8.1f}"
              f"{r['fps_p12']:>9.1f}{r['setup']:>10.1f}"
              f"{r['phase1']:>10.1f}{r['first']:>9.1f}{r['fps_p1_after']:>8.1f}"
              f"{r['phase2']:>10.1f}{100 * r['phase1'] / tot:>6.0f}"
              f"{100 * r['phase2'] / tot:>6.0f}{r['rss_mb']:>9.0f}")


if __name__ == "__main__":
    main()
