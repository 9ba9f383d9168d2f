"""The solve of ``selfillum correct`` alone (``selfillum.solve.radiosity.correct``, the
unseen faces' continuation inside), on the inputs the command gives it, in each source
tree (issue 21 item 5).

Run: ``.venv/bin/python bench/bench_solve.py [--faces 609000] [--roots A,B] [--repeat 5]``

The command of ``bench_si_command.py`` (the 610,704-face grid, its camera, image and
unpainted faces) runs once in this tree with ``correct`` wrapped to save its inputs
(``F``, the radiosity, the reflectance, the seen and unpainted faces, the mesh) in the
cache folder. Then for each ``--roots`` tree, interleaved round by round, a fresh
process (``PYTHONPATH`` the tree) loads them and times ``correct``: the first call (the
process's first compiled kernels loaded from numba's cache, as in the command, after
numba's one-time start, which a small kernel of every tree triggers first) and the best
of ``--repeat`` later calls, wall and process CPU seconds. The emission of the seen faces
is compared between the trees (largest difference over the largest value).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def capture(cache: Path, faces: int) -> Path:
    """Run the command once with ``correct`` wrapped; its inputs in ``cache``."""
    out = cache / "solve_inputs.npz"
    if out.exists():
        return out
    import numpy as np
    import scipy.sparse as sp

    sys.path.insert(0, str(ROOT / "bench"))
    from bench_si_command import files

    f, _ = files(faces, cache)
    import selfillum.images.image_correction as ic

    original = ic.correct

    def wrapped(F, radiosity, reflectance, seen=None, **kw):
        F = sp.csr_matrix(F)
        mesh = kw["mesh"]
        np.savez(out, data=F.data, indices=F.indices, indptr=F.indptr, n=F.shape[0],
                 B=radiosity, rho=reflectance, seen=seen, unpainted=kw.get("unpainted"),
                 vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces))
        return original(F, radiosity, reflectance, seen, **kw)

    ic.correct = wrapped
    from selfillum.cli.main import main

    sys.argv = ["selfillum", "correct", "--mesh", f["mesh"], "--camera", f["camera"],
                "--image", f["image"], "--reflectance", "0.5", "--unpainted",
                f["unpainted"], "--quiet", "--out", str(cache / "corrected_solve.npy")]
    main()
    ic.correct = original
    return out


def child(path: str, repeat: int, save: str) -> None:
    """Time ``correct`` on the saved inputs in this process; JSON on stdout."""
    import numba
    import numpy as np
    import scipy.sparse as sp
    import trimesh

    from selfillum.solve.radiosity import correct

    numba.njit(cache=False)(lambda x: x + 1)(1)  # numba's one-time start, not counted
    z = np.load(path)
    n = int(z["n"])
    F = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=(n, n))
    mesh = trimesh.Trimesh(z["vertices"], z["faces"], process=False)
    kw = dict(mesh=mesh, unpainted=z["unpainted"], unseen="continue", return_info=True)
    times = []
    for _ in range(repeat + 1):
        w, c = time.perf_counter(), time.process_time()
        E, info = correct(F, z["B"], z["rho"], z["seen"], **kw)
        times.append((time.perf_counter() - w, time.process_time() - c))
    np.save(save, E)
    print(json.dumps({"first": times[0], "warm": min(times[1:]), "iterations": info.iterations,
                      "residual": info.residual}))


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2], int(sys.argv[3]), sys.argv[4])
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, default=609_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--roots", default=str(ROOT))
    ap.add_argument("--cache", default="/tmp/bench_si_command")
    args = ap.parse_args()
    cache = Path(args.cache) / str(args.faces)
    cache.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT))
    inputs = capture(cache, args.faces)
    roots = [Path(r) for r in args.roots.split(",")]
    print(f"load average at start {os.getloadavg()}")
    best: dict[Path, dict] = {}
    for _ in range(args.rounds):
        for i, r in enumerate(roots):
            env = {**os.environ, "PYTHONPATH": str(r)}
            res = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child",
                                  str(inputs), str(args.repeat), str(cache / f"E_{i}.npy")],
                                 env=env, capture_output=True, text=True, cwd=r)
            if res.returncode:
                raise RuntimeError(res.stderr[-2000:])
            out = json.loads(res.stdout.strip().splitlines()[-1])
            b = best.setdefault(r, out)
            for k in ("first", "warm"):
                if out[k][0] < b[k][0]:
                    b[k] = out[k]
    import numpy as np

    ref = np.load(cache / "E_0.npy")
    for i, r in enumerate(roots):
        b = best[r]
        E = np.load(cache / f"E_{i}.npy")
        ok = np.isfinite(ref)
        diff = float(np.max(np.abs(E[ok] - ref[ok])) / np.max(np.abs(ref[ok])))
        print(f"{r}: first call {b['first'][0]:.3f} s wall / {b['first'][1]:.3f} s CPU, "
              f"warm {b['warm'][0]:.3f} s wall / {b['warm'][1]:.3f} s CPU "
              f"({b['iterations']} iterations, residual {b['residual']:.1e}); "
              f"E against the first tree's: {diff:.1e} of its largest value")
    if len(roots) > 1:
        a, z = best[roots[0]], best[roots[-1]]
        print(f"last / first tree: first call {z['first'][0] / a['first'][0]:.2f} (CPU "
              f"{z['first'][1] / a['first'][1]:.2f}), warm {z['warm'][0] / a['warm'][0]:.2f} "
              f"(CPU {z['warm'][1] / a['warm'][1]:.2f})")
    print(f"load average at end {os.getloadavg()}")


if __name__ == "__main__":
    main()
