"""Speed of ``selfillum thermal`` end to end, as a user runs it (issue 37 item 6: 50
frames/s on 2 cores for 640 x 512 16-bit IR frames onto a 100k-node grid, moving model).

Generates the synthetic IR run of :mod:`scenes.ir_run` (the launcher top as a Plot3D grid
of about ``--nodes`` nodes, ``--frames`` frames of ``--width`` x ``--height`` uint16 at 50
frames/s: markers that appear, 8 px settling then vibration, Fresnel emissivity), then runs
the command in a fresh process (its own tracking of the markers, the view factors of
``--rays`` rays a face, Cook-Felderman) and, in the same session and on the same cores, two
peers for the ratios: the bare reading of every frame of the video through
``resection.io.video.open_frames`` (the I/O floor the run cannot beat), and a bare
library floor of Phase 1's per-frame work: every frame read, carried by ``cv2.remap``
(bilinear, a sub-pixel shift of the whole frame) and taken to the nodes by one SciPy
sparse product with about as many entries as the run's pixel-to-node operator (3 for
each of the 24 % of the pixels that see the model in this scene).
Prints frames/s over the whole process and over the run (inputs read before excluded),
each phase's time, the CPU time of the command with its child processes (the markers'
tracking runs in one: on a loaded machine the wall time follows the CPU time, on two free
cores the longer of the two processes' paths), the ratios, and ``uptime``'s load before
and after.

    python bench/bench_thermal.py --nodes 100000 --frames 200 [--threads 2]
    python bench/bench_thermal.py --frames 500 --q-max 15000 --folder DIR
    python bench/bench_thermal.py --folder DIR --reuse --frames 500 --tree OTHER_CHECKOUT
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from scenes.ir_run import make_ir_run  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--nodes", type=int, default=100_000)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=512)
    ap.add_argument("--rays", type=int, default=16)
    ap.add_argument("--q-max", type=float, default=3.0e4,
                    help="the scene's largest heat flux, W/m^2 (1.5e4 keeps a 500-frame run "
                    "within the 16-bit range and the radiometry's range_K)")
    ap.add_argument("--threads", type=int, default=2, help="cores the run may use")
    ap.add_argument("--folder", help="keep the inputs here (default: a temporary folder)")
    ap.add_argument("--extra", default="", help="more flags for the run")
    ap.add_argument("--reuse", action="store_true",
                    help="use the inputs already in --folder (an earlier run's)")
    ap.add_argument("--tree", default=str(ROOT),
                    help="the source tree the command runs from (another checkout: a before "
                    "and after in the same session)")
    args = ap.parse_args()
    folder = Path(args.folder) if args.folder else Path(tempfile.mkdtemp(prefix="bench_t_"))
    nphi = int(round(np.sqrt(args.nodes / 1.6)))
    nx = int(round(args.nodes / (nphi + 1)))
    t0 = time.perf_counter()
    if args.reuse and (folder / "ir.npy").is_file():
        from types import SimpleNamespace

        run = SimpleNamespace(grid=folder / "model.grid", targets=folder / "model.tgts",
                              video=folder / "ir.npy", calibration=folder / "cam01.json",
                              radiometry=folder / "R.json", substrate=folder / "S.json",
                              wtd=folder / "run.wtd", fps=50.0)
        print(f"inputs: reused from {folder}")
    else:
        run = make_ir_run(folder, frames=args.frames, width=args.width, height=args.height,
                          nx=nx, nphi=nphi, q_max=args.q_max)
        print(f"inputs: {len(run.q0)} nodes, {args.frames} frames of {args.width}x"
              f"{args.height} uint16 ({time.perf_counter() - t0:.0f} s to make)")
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS=str(args.threads),
               NUMBA_NUM_THREADS=str(args.threads), OPENBLAS_NUM_THREADS=str(args.threads))
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    # the bare read of every frame (same process kind, same cores)
    code = ("import sys, time; from resection.io.video import open_frames; "
            "s = open_frames(sys.argv[1]); t = time.perf_counter(); "
            "[s.native(k).sum() for k in range(len(s))]; "
            "print('READ', time.perf_counter() - t)")
    res = subprocess.run([sys.executable, "-c", code, str(run.video)], capture_output=True,
                         text=True, env=env, cwd=str(ROOT), check=True)
    t_read = float(re.search(r"READ ([\d.]+)", res.stdout).group(1))
    # the floor of Phase 1's per-frame work by bare library calls (same process kind)
    code = ("import sys, time, numpy as np, scipy.sparse as sp, cv2; "
            "from resection.io.video import open_frames; "
            "s = open_frames(sys.argv[1]); n = int(sys.argv[2]); H, W = s.shape; "
            "rng = np.random.default_rng(0); "
            "px = rng.choice(H * W, min(H * W, int(0.24 * H * W)), replace=False); "
            "M = sp.csr_matrix((rng.random(3 * px.size), (rng.integers(0, n, 3 * px.size), "
            "np.repeat(px, 3))), shape=(n, H * W)); "
            "mx, my = np.meshgrid(np.arange(W, dtype=np.float32) + 0.3, "
            "np.arange(H, dtype=np.float32) + 0.2); "
            "t = time.perf_counter(); "
            "[M @ cv2.remap(s.native(k).astype(np.float32), mx, my, "
            "cv2.INTER_LINEAR).ravel() for k in range(len(s))]; "
            "print('FLOOR', time.perf_counter() - t)")
    res = subprocess.run(["taskset", "-c", ",".join(str(c) for c in range(args.threads)),
                          sys.executable, "-c", code, str(run.video), str(args.nodes)],
                         capture_output=True, text=True, env=env, cwd=str(ROOT), check=True)
    t_floor = float(re.search(r"FLOOR ([\d.]+)", res.stdout).group(1))
    out = folder / "thermal.h5"
    env_run = dict(env, PYTHONPATH=str(Path(args.tree).resolve()))
    cmd = [sys.executable, "-m", "selfillum.cli", "thermal", "--grid", str(run.grid),
           "--targets", str(run.targets), "--video", str(run.video), "--calibration",
           str(run.calibration), "--radiometry", str(run.radiometry), "--substrate",
           str(run.substrate), "--sds", str(run.wtd), "--fps", str(run.fps), "--out",
           str(out), "--rays", str(args.rays), "--no-plots", "--quiet",
           *args.extra.split()]
    if args.threads:
        cmd = ["taskset", "-c", ",".join(str(c) for c in range(args.threads))] + cmd
    import resource

    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=env_run, cwd=args.tree)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    if res.returncode != 0:
        raise SystemExit(res.stderr.strip()[-2000:])
    txt = res.stdout
    print(txt.strip())
    m = re.search(r"run: ([\d.]+) frames/s end to end; set-up ([\d.]+) s .*phase 1 "
                  r"([\d.]+) s, phase 2 and outputs ([\d.]+) s", txt)
    fps_run, setup, p1, p2 = (float(v) for v in m.groups())
    print("load:", subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip())
    T = args.frames
    print(f"frames/s: {T / wall:.1f} over the whole process, {fps_run:.1f} over the run; "
          f"phase 1 {T / p1:.1f} frames/s; set-up {setup:.1f} s, phase 1 {p1:.1f} s, "
          f"phase 2 {p2:.1f} s")
    print(f"CPU time of the command and its child processes: {cpu:.1f} s ({cpu / wall:.2f} "
          "cores busy on average)")
    print(f"bare read of every frame: {t_read:.2f} s ({T / t_read:.0f} frames/s); the run "
          f"costs {wall / t_read:.1f} x the read (process), {(setup + p1 + p2) / t_read:.1f} "
          "x (run)")
    print(f"bare remap and node product of every frame: {t_floor:.2f} s ({T / t_floor:.0f} "
          f"frames/s); phase 1 costs {p1 / t_floor:.1f} x it, the whole process "
          f"{wall / t_floor:.1f} x")
    for p in folder.glob("thermal*"):
        if p.is_file():
            p.unlink()


if __name__ == "__main__":
    main()
