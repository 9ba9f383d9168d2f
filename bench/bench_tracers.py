"""Ray tracers for the view factors on the same rays: Embree (``embreex``, one call, and
the same rays over threads) against Mitsuba / Dr.Jit (``selfillum.transport.mitsuba_rays``: OptiX
with the ``cuda_ad_rgb`` variant on a GPU, Dr.Jit's LLVM backend on the CPU otherwise).

Issue 14 item 6 asks for the GPU comparison: speed ratio, and the same ``F`` within the
noise. The same script runs on a machine with a GPU (the cuda variant is then chosen) and on
one without (the llvm variant): the variant used is printed with the figures.

Run: ``.venv/bin/python bench/bench_tracers.py [--quick] [--variant auto|cuda|llvm]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_viewfactors import same_rays  # noqa: E402

from scenes.corner import corner  # noqa: E402
from selfillum import view_factors  # noqa: E402
from selfillum.transport.mitsuba_rays import MitsubaRayScene  # noqa: E402


def compare(mesh, k, label, variant, repeat):
    scene, o32, d32 = same_rays(mesh, k, 0)
    v = np.asarray(mesh.vertices, np.float64)
    ms = MitsubaRayScene(v, mesh.faces, variant=variant)
    assert np.allclose(ms.origin, scene.origin)
    cores = len(os.sched_getaffinity(0))
    edges = np.linspace(0, len(d32), 4 * cores + 1).astype(int)

    def embree_threads():
        with ThreadPoolExecutor(cores) as pool:
            parts = pool.map(lambda i: scene.scene.run(o32[edges[i]:edges[i + 1]],
                                                       d32[edges[i]:edges[i + 1]]),
                             range(4 * cores))
            return np.concatenate(list(parts))

    calls = {"embree": lambda: np.asarray(scene.scene.run(o32, d32)),
             "embree_threads": embree_threads,
             "mitsuba": lambda: ms.run(o32, d32)}
    for fn in calls.values():  # warm-up: scene commit, Dr.Jit kernel compilation
        fn()
    best = dict.fromkeys(calls, float("inf"))
    out = {}
    for _ in range(repeat):
        for key, fn in calls.items():
            t0 = time.perf_counter()
            out[key] = fn()
            best[key] = min(best[key], time.perf_counter() - t0)
    rays = len(d32)
    same = np.mean(out["embree"] == out["mitsuba"])
    hit = np.mean(out["embree"] >= 0)
    print(f"\n{label}: {len(mesh.faces)} faces, K = {k}, {rays / 1e6:.2f} M rays "
          f"({100 * hit:.1f} % hit something)")
    for key in calls:
        print(f"    {key:15s} {rays / best[key] / 1e6:7.2f} M rays/s  ({best[key]:.3f} s)")
    print(f"    {ms.variant} / embree (one call): {best['embree'] / best['mitsuba']:.2f}x "
          f"the speed; / embree over {cores} threads: "
          f"{best['embree_threads'] / best['mitsuba']:.2f}x")
    print(f"    same first hit on {100 * same:.4f} % of the rays")


def whole_factors(mesh, k, label, repeat):
    """view_factors with each tracer: time, and the F they give on the same rays."""
    best = {"embree": float("inf"), "mitsuba": float("inf")}
    F = {}
    for tracer in best:
        view_factors(mesh, k, seed=0, tracer=tracer)  # warm-up (pool, compilation)
    for _ in range(repeat):
        for tracer in best:
            t0 = time.perf_counter()
            F[tracer] = view_factors(mesh, k, seed=0, tracer=tracer)
            best[tracer] = min(best[tracer], time.perf_counter() - t0)
    diff = abs(F["embree"] - F["mitsuba"])
    rows = np.abs(np.asarray(F["embree"].sum(axis=1)) - np.asarray(F["mitsuba"].sum(axis=1)))
    print(f"\nview_factors, {label}, K = {k}: embree (default workers) {best['embree']:.3f} s, "
          f"mitsuba {best['mitsuba']:.3f} s: mitsuba / embree speed "
          f"{best['embree'] / best['mitsuba']:.2f}x")
    print(f"    |F_embree - F_mitsuba|: largest entry {diff.max():.2e} (one ray = {1 / k:.2e}), "
          f"entries that differ {diff.nnz}, largest row-sum difference {rows.max():.2e}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--variant", default="auto")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    sphere = trimesh.creation.icosphere(subdivisions=4 if args.quick else 5)
    sphere.invert()
    res, k = (30, 64) if args.quick else (60, 256)
    compare(corner(resolution=res).mesh, k, "open corner (most rays escape)", args.variant,
            args.repeat)
    compare(sphere, 64 if args.quick else 128, "inside a sphere (every ray hits)",
            args.variant, args.repeat)
    whole_factors(corner(resolution=res).mesh, 4 * k, "open corner", args.repeat)


if __name__ == "__main__":
    main()
