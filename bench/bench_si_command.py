"""The whole ``selfillum correct`` command on a big grid against a bare one-thread Embree
pass, quiet and at a load of 2 (issue 21 item 4).

Run: ``.venv/bin/python bench/bench_si_command.py [--faces 609000] [--repeat 2]``

The model is :func:`scenes.slab_block.slab_block` (as ``bench_si_big.py``): a painted slab
carrying a black box, one 1280 x 1024 camera from above. Its files are written once to
``--cache``: the grid (binary PLY), the camera (JSON), the image (NPY, float32), the
unpainted faces (NPY). Measured, interleaved, in rounds:

* **peer**: a bare Embree pass of 256 cosine-distributed rays from every face
  (``bench_si_big.bare_embree``: the scene build and ``EmbreeScene.run`` on prepared
  float32 arrays, one thread, in this process; making the rays is not timed);
* **ours**: ``selfillum correct --mesh ... --camera ... --image ... --reflectance 0.5
  --unpainted ... --out ...`` in a fresh process, timed from its start to its end: the
  interpreter, the imports, reading the grid and the image, the surface map, the view
  factors of the seen and coupled faces, the solve, the per-pixel correction and writing.

Quiet rounds first, then the same rounds with ``--load`` CPU-bound processes (pure Python
loops) running beside them, started before and stopped after each round. The ratio
ours / peer of each round is printed; target: at most 1.5.

With ``--roots A,B`` the command of each source tree (its ``PYTHONPATH``) runs in every
round, one after the other between the same two peer passes (e.g. the previous commit
unpacked with ``git archive`` against this one), so that both see the same load.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_si_big import _FACE_FACTOR, bare_embree  # noqa: E402

from resection.io.cameras import write_camera  # noqa: E402
from resection.surface.surface_map import SurfaceMap  # noqa: E402
from scenes.slab_block import slab_block, slab_camera  # noqa: E402


def files(faces: int, cache: Path) -> tuple[dict, object]:
    sc = slab_block(int(faces * _FACE_FACTOR))
    out = {"mesh": cache / "grid.ply", "camera": cache / "camera.json",
           "image": cache / "image.npy", "unpainted": cache / "unpainted.npy"}
    if not all(p.is_file() for p in out.values()):
        cam = slab_camera(1280, 1024, zoom=1.25)
        smap = SurfaceMap(sc.mesh, cam)
        img = np.where(smap.mask, sc.emission[np.maximum(smap.face_index, 0)], 0.0) * 100.0
        sc.mesh.export(out["mesh"])
        write_camera(out["camera"], cam)
        np.save(out["image"], img.astype(np.float32))
        np.save(out["unpainted"], (~sc.painted).astype(np.uint8))
    return {k: str(v) for k, v in out.items()}, sc.mesh


def load_processes(n: int) -> list:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=609_000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--load", type=int, default=2)
    ap.add_argument("--cache", default="/tmp/bench_si_command")
    ap.add_argument("--roots", default=str(ROOT),
                    help="comma-separated source trees to compare (default: this one)")
    args = ap.parse_args()
    cache = Path(args.cache) / str(args.faces)
    cache.mkdir(parents=True, exist_ok=True)
    f, mesh = files(args.faces, cache)
    n = len(mesh.faces)
    roots = args.roots.split(",")
    cmds = {r: [sys.executable, "-m", "selfillum.cli", "correct", "--mesh", f["mesh"],
                "--camera", f["camera"], "--image", f["image"], "--reflectance", "0.5",
                "--unpainted", f["unpainted"], "--out", str(cache / f"corrected_{i}.npy"),
                "--quiet"] for i, r in enumerate(roots)}  # an output of its own each
    envs = {r: {**os.environ, "PYTHONPATH": r} for r in roots}
    for r in roots:
        # run from the tree itself: ``python -m`` puts the working folder first on sys.path
        subprocess.run(cmds[r], env=envs[r], check=True, capture_output=True, cwd=r)
    print(f"{n:,} faces; load average {os.getloadavg()}")
    rows = []
    for extra in (0, args.load):
        for _ in range(args.repeat):
            busy = load_processes(extra)
            try:
                time.sleep(1.0 if extra else 0.0)
                t_peer = bare_embree(mesh)
                t_cmd = {}
                for r in roots:
                    t = time.perf_counter()
                    subprocess.run(cmds[r], env=envs[r], check=True, capture_output=True,
                                   cwd=r)
                    t_cmd[r] = time.perf_counter() - t
                t_peer2 = bare_embree(mesh, seed=1)
                load = os.getloadavg()[0]
            finally:
                for p in busy:
                    p.kill()
                    p.wait()
            peer = 0.5 * (t_peer + t_peer2)
            for r in roots:
                rows.append((extra, r, t_cmd[r], peer, t_cmd[r] / peer))
                print(f"  {extra} busy processes beside: {r}: selfillum correct "
                      f"{t_cmd[r]:.1f} s, bare Embree {t_peer:.1f} / {t_peer2:.1f} s: ratio "
                      f"{t_cmd[r] / peer:.2f}; load average {load:.1f}", flush=True)
    for extra in (0, args.load):
        for r in roots:
            q = [x[4] for x in rows if x[0] == extra and x[1] == r]
            print(f"{'quiet' if extra == 0 else f'load {extra}'}: {r}: ratio best "
                  f"{min(q):.2f}, worst {max(q):.2f} (target <= 1.5)")

if __name__ == "__main__":
    main()
