"""Ray tracers for the view factors on the same rays: Embree (``embreex``, one call, and
the same rays over threads) against Mitsuba / Dr.Jit (``selfillum.transport.mitsuba_rays``: OptiX
with the ``cuda_ad_rgb`` variant on a GPU, Dr.Jit's LLVM backend on the CPU otherwise).

1. Bare rays (issue 14 item 6): the same float32 rays through Embree (one call, and over
   the threads) and through Mitsuba; the same first hit.
2. Whole ``view_factors(tracer="mitsuba")`` (issue 21 item 6: the rays sampled, traced and
   summed per face pair in Dr.Jit, :mod:`selfillum.transport.mitsuba_factors`) against its
   bare rays (``Scene.ray_intersect_preliminary`` on the very same rays, made beforehand on
   the device, launch by launch: no sampling, no accumulation) and against whole
   ``view_factors`` with Embree over the threads, interleaved, on the open corner and on the
   real-size grid of ``bench_si_command.py`` (slab and box, 609k faces), K = 64 and 256.
   The F of the two tracers are compared entry by entry.

The same script runs unchanged on a machine with a GPU (the cuda variant is then chosen by
:mod:`selfillum.mitsuba_variants`) and on one without (the llvm variant): the variant used
and the load average are printed with the figures.

Run: ``.venv/bin/python bench/bench_tracers.py [--quick] [--variant auto|cuda|llvm]
[--sections 1,2] [--scenes corner,sphere,grid] [--k 64,256] [--faces 609000]``
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

from resection._threads import available_cores  # noqa: E402
from scenes.corner import corner  # noqa: E402
from selfillum import view_factors  # noqa: E402
from selfillum.mesh import face_normals  # noqa: E402
from selfillum.transport.mitsuba_factors import MitsubaFactorTracer  # noqa: E402
from selfillum.transport.mitsuba_rays import MitsubaRayScene  # noqa: E402
from selfillum.transport.viewfactors import _OFFSET, RayScene  # noqa: E402


def compare(mesh, k, label, variant, repeat):
    scene, o32, d32 = same_rays(mesh, k, 0)
    v = np.asarray(mesh.vertices, np.float64)
    ms = MitsubaRayScene(v, mesh.faces, variant=variant)
    assert np.allclose(ms.origin, RayScene(v, mesh.faces).origin)  # the rays' frame
    cores = len(os.sched_getaffinity(0))
    edges = np.linspace(0, len(d32), 4 * cores + 1).astype(int)

    def embree_threads():
        with ThreadPoolExecutor(cores) as pool:
            parts = pool.map(lambda i: scene.run(o32[edges[i]:edges[i + 1]],
                                                       d32[edges[i]:edges[i + 1]]),
                             range(4 * cores))
            return np.concatenate(list(parts))

    calls = {"embree": lambda: np.asarray(scene.run(o32, d32)),
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


def _chunks(rows: np.ndarray, launch: int) -> list:
    """The launches of ``MitsubaFactorTracer.rows``: equal blocks of at most ``launch``."""
    step = max(1, -(-rows.size // max(1, -(-rows.size // launch))))
    return [rows[i:i + step] for i in range(0, rows.size, step)]


def whole_against_bare(mesh, k, label, repeat):
    """Whole ``view_factors(tracer="mitsuba")`` (scene, sampling, tracing, sums per face
    pair, the CSR matrix) against its bare rays (``ray_intersect_preliminary`` on the very
    same rays, made beforehand on the device, launch by launch: no sampling, no
    accumulation) and against ``view_factors`` with threaded Embree, interleaved."""
    v = np.asarray(mesh.vertices, np.float64)
    n = len(mesh.faces)
    size = float(np.ptp(v, axis=0).max())
    normals = face_normals(mesh)

    def build():
        return MitsubaFactorTracer(v, mesh.faces, normals, k, 0, offset=_OFFSET * size)

    tr = build()
    mi, dr = tr.scene._mi, tr.scene._dr
    chunks = _chunks(np.arange(n), tr.launch)

    def bare():
        spent = 0.0
        for part in chunks:
            ray = tr.device_rays(part)  # made and evaluated on the device: not timed
            with tr.scene._variant():
                dr.sync_thread()
                t0 = time.perf_counter()
                pi = tr.scene._scene.ray_intersect_preliminary(ray, coherent=False)
                face = mi.UInt32(pi.prim_index)
                dr.eval(face)
                dr.sync_thread()
                spent += time.perf_counter() - t0
            del ray, pi, face
        return spent

    out = {}
    every = np.arange(n)
    calls = {"mitsuba": lambda: view_factors(mesh, k, seed=0, tracer="mitsuba"),
             "launches": lambda: tr.rows(every),
             "scene": build,
             "bare": bare,
             "embree": lambda: view_factors(mesh, k, seed=0)}
    # warm-up: Dr.Jit's kernels compiled (or loaded from its cache), numba's loaded
    few = np.arange(min(n, 2000))
    view_factors(mesh, k, seed=0, tracer="mitsuba", rows=few)
    view_factors(mesh, k, seed=0, rows=few)
    bare_few = tr.device_rays(few[:10])
    with tr.scene._variant():
        dr.eval(tr.scene._scene.ray_intersect_preliminary(bare_few, coherent=False).prim_index)
    best = dict.fromkeys(calls, float("inf"))
    for _ in range(repeat):
        for key, fn in calls.items():
            t0 = time.perf_counter()
            res = fn()
            spent = time.perf_counter() - t0
            if key == "bare":
                spent = res
            elif key not in ("launches", "scene"):
                out[key] = res
            best[key] = min(best[key], spent)
    rays = n * k
    load = open("/proc/loadavg").read().split()[:3]
    print(f"\n{label}, {n:,} faces, K = {k}: {rays / 1e6:.1f} M rays, variant "
          f"{tr.scene.variant}, {len(chunks)} launch(es) of <= {tr.launch:,} faces, load "
          f"{' '.join(load)} (best of {repeat})")
    print(f"    whole view_factors, mitsuba    {best['mitsuba']:7.3f} s  "
          f"({rays / best['mitsuba'] / 1e6:6.1f} M rays/s)")
    print(f"      of which the launches        {best['launches']:7.3f} s  (sampling, tracing, "
          f"sums per pair, CSR: MitsubaFactorTracer.rows on a built scene; a scene build "
          f"{best['scene']:.2f} s)")
    print(f"    bare rays, mitsuba             {best['bare']:7.3f} s  "
          f"({rays / best['bare'] / 1e6:6.1f} M rays/s)")
    print(f"    whole view_factors, embree     {best['embree']:7.3f} s  "
          f"({rays / best['embree'] / 1e6:6.1f} M rays/s, {available_cores()} threads)")
    print(f"    speed of whole mitsuba / its bare rays {best['bare'] / best['mitsuba']:.2f}x, "
          f"/ scene build + bare rays {(best['scene'] + best['bare']) / best['mitsuba']:.2f}x; "
          f"launches / bare rays {best['bare'] / best['launches']:.2f}x; whole mitsuba / "
          f"embree threaded {best['embree'] / best['mitsuba']:.2f}x")
    diff = abs(out["embree"] - out["mitsuba"])
    rows = np.abs(np.asarray(out["embree"].sum(axis=1))
                  - np.asarray(out["mitsuba"].sum(axis=1)))
    print(f"    |F_embree - F_mitsuba|: largest entry {diff.max():.2e} (one ray = {1 / k:.2e}), "
          f"{(diff > 1e-12).nnz} of {out['embree'].nnz:,} entries differ, largest row-sum "
          f"difference {rows.max():.2e}", flush=True)


def grid(faces: int):
    """The real-size grid of ``bench_si_command.py`` (a slab carrying a box)."""
    from bench_si_big import _FACE_FACTOR

    from scenes.slab_block import slab_block

    return slab_block(int(faces * _FACE_FACTOR)).mesh


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--variant", default="auto", help="of the bare-ray comparison [1]")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sections", default="1,2",
                    help="1: bare rays, Embree against Mitsuba (corner, sphere); 2: whole "
                         "view_factors against its bare rays and Embree")
    ap.add_argument("--scenes", default="corner,grid", help="of section 2: corner, sphere, grid")
    ap.add_argument("--k", default="64,256", help="rays per face of section 2")
    ap.add_argument("--faces", type=int, default=609_000, help="of the grid")
    args = ap.parse_args()
    sections = {int(x) for x in args.sections.split(",")}
    res, k = (30, 64) if args.quick else (60, 256)
    if 1 in sections:
        sphere = trimesh.creation.icosphere(subdivisions=4 if args.quick else 5)
        sphere.invert()
        compare(corner(resolution=res).mesh, k, "open corner (most rays escape)",
                args.variant, args.repeat)
        compare(sphere, 64 if args.quick else 128, "inside a sphere (every ray hits)",
                args.variant, args.repeat)
    if 2 in sections:
        for name in args.scenes.split(","):
            if name == "corner":
                mesh, label = corner(resolution=res).mesh, "open corner"
            elif name == "sphere":
                mesh = trimesh.creation.icosphere(subdivisions=4 if args.quick else 5)
                mesh.invert()
                label = "inside a sphere"
            else:
                mesh, label = grid(args.faces), "slab and box grid (bench_si_command)"
            for kk in (int(x) for x in args.k.split(",")):
                whole_against_bare(mesh, kk, label, args.repeat)


if __name__ == "__main__":
    main()
