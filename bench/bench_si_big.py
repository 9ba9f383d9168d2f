"""``selfillum correct`` on big grids, end to end, against a bare Embree pass (issue 14).

Run: ``.venv/bin/python bench/bench_si_big.py [--faces N ...] [--before]``

The model is :func:`scenes.slab_block.slab_block`: a painted slab carrying a black box,
every face of one size (the underside, which no camera sees, is half of the faces), seen
by one 1280 x 1024 camera from above (about a quarter of the faces seen, some of the box's
sides beyond the 70-degree cut-off). The image is the paint's emission at each pixel's
face.

Measured in the same run, interleaved (peer, ours, peer):

* **peer**: a bare Embree pass of 256 cosine-distributed rays from every face of the mesh
  (``embreex``: the scene build and ``EmbreeScene.run`` on prepared float32 arrays,
  chunks of 1 M rays, one thread; the making of the rays is not timed);
* **ours**: :func:`selfillum.images.image_correction.correct_image`, 256 rays a face: surface map,
  view factors of the seen and coupled faces only, the unseen-face solve, the per-pixel
  correction, timed stage by stage (map, coupled view factors, the rest). Peak memory:
  the process's maximum resident size after it.
* with ``--before``: the whole ``F`` (every row) as the code did before the coupled-face
  restriction, timed alone (its LSMR over every hidden face is not rerun: 2,104
  iterations on the real grid).

The ratio ours / peer is the figure of merit (target <= 1.5). The numba kernels are
compiled on a small scene before any timing (a one-off cost per process).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from embreex import rtcore_scene  # noqa: E402
from embreex.mesh_construction import TriangleMesh  # noqa: E402

from resection.surface.surface_map import SurfaceMap  # noqa: E402
from scenes.slab_block import slab_block, slab_camera  # noqa: E402
from selfillum.images.image_correction import correct_image  # noqa: E402
from selfillum.mesh import face_normals  # noqa: E402
from selfillum.transport.coupling import coupled_view_factors  # noqa: E402
from selfillum.transport.viewfactors import view_factors  # noqa: E402

#: Requested face counts give about 0.93 times as many triangles (see slab_block).
_FACE_FACTOR = 1.076


def bare_embree(mesh, k: int = 256, seed: int = 0, rays_per_chunk: int = 1 << 20) -> float:
    """Seconds spent in Embree building the scene and intersecting ``k`` cosine rays from
    every face (making the rays is not counted)."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
    vs = np.ascontiguousarray(v - origin, dtype=np.float32)
    fs = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    t0 = time.perf_counter()
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=vs, indices=fs)
    spent = time.perf_counter() - t0  # the BVH build is part of the pass
    tri = vs[fs]
    nrm = face_normals(mesh).astype(np.float32)
    helper = np.where((np.abs(nrm[:, 0]) < 0.9)[:, None], [1.0, 0, 0], [0, 1.0, 0])
    t1 = np.cross(nrm, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    rng = np.random.default_rng(seed)
    lift = 1e-6 * float(np.ptp(v, axis=0).max())
    step = max(1, rays_per_chunk // k)
    for f0 in range(0, len(fs), step):  # chunks of faces (memory), not a loop over rays
        f1 = min(f0 + step, len(fs))
        m = f1 - f0
        r = rng.random((m, k, 4), dtype=np.float32)
        s = np.sqrt(r[..., 0])
        b1, b2 = s * (1 - r[..., 1]), s * r[..., 1]
        T = tri[f0:f1]
        o = (T[:, None, 0] + b1[..., None] * (T[:, None, 1] - T[:, None, 0])
             + b2[..., None] * (T[:, None, 2] - T[:, None, 0]) + lift * nrm[f0:f1, None])
        rad, phi = np.sqrt(r[..., 2]), 2 * np.pi * r[..., 3]
        z = np.sqrt(np.maximum(0.0, 1.0 - r[..., 2]))
        d = (rad[..., None] * np.cos(phi)[..., None] * t1[f0:f1, None]
             + rad[..., None] * np.sin(phi)[..., None] * t2[f0:f1, None]
             + z[..., None] * nrm[f0:f1, None])
        o = np.ascontiguousarray(o.reshape(-1, 3), dtype=np.float32)
        d = np.ascontiguousarray(d.reshape(-1, 3), dtype=np.float32)
        t0 = time.perf_counter()
        scene.run(o, d)
        spent += time.perf_counter() - t0
    return spent


def run(faces: int, before: bool) -> dict:
    sc = slab_block(int(faces * _FACE_FACTOR))
    n = len(sc.mesh.faces)
    cam = slab_camera(1280, 1024, zoom=1.25)
    print(f"\n{n:,} faces, camera {cam.width} x {cam.height}", flush=True)
    smap = SurfaceMap(sc.mesh, cam)
    img = np.where(smap.mask, sc.emission[np.maximum(smap.face_index, 0)], 0.0) * 100.0
    del smap
    img = img.astype(np.float32)
    print(f"  load average {open('/proc/loadavg').read().split()[:3]}", flush=True)
    t_peer = [bare_embree(sc.mesh)]
    print(f"  bare Embree, {n * 256 / 1e6:.0f} M rays: {t_peer[0]:.1f} s", flush=True)
    # ours, stage by stage (what correct_image does when given no F and no map)
    t0 = time.perf_counter()
    smap = SurfaceMap(sc.mesh, cam)
    t_map = time.perf_counter() - t0
    seen = (smap.pixel_counts > 0) & ~smap.oblique
    t0 = time.perf_counter()
    F, rows = coupled_view_factors(sc.mesh, seen, rays_per_face=256)
    t_vf = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = correct_image(img, sc.mesh, cam, sc.reflectance, F=F, surface_map=smap,
                      unpainted=~sc.painted)
    t_rest = time.perf_counter() - t0
    t_ours = t_map + t_vf + t_rest
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    info = r.info
    print(f"  correct_image: {t_ours:.1f} s = map {t_map:.1f} + view factors of "
          f"{int(rows.sum()):,} rows {t_vf:.1f} + solve and per-pixel {t_rest:.1f}; seen "
          f"{int(r.seen.sum()):,}, coupled {info.n_coupled:,} of {info.n_hidden:,} unseen, "
          f"{info.method} {info.iterations} iterations, peak RSS {rss:.2f} GB", flush=True)
    t_peer.append(bare_embree(sc.mesh, seed=1))
    peer = float(np.mean(t_peer))
    print(f"  bare Embree again: {t_peer[1]:.1f} s; ratio correct / bare = "
          f"{t_ours / peer:.2f} (target <= 1.5)", flush=True)
    print(f"  view factors of the coupled rows / bare = {t_vf / peer:.2f}", flush=True)
    out = {"faces": n, "seen": int(r.seen.sum()), "coupled": info.n_coupled,
           "peer": peer, "ours": t_ours, "ratio": t_ours / peer, "rss_gb": rss}
    if before:
        t0 = time.perf_counter()
        F = view_factors(sc.mesh, rays_per_face=256)
        t_full = time.perf_counter() - t0
        print(f"  whole F (every row, as before): {t_full:.1f} s = {t_full / peer:.2f} x bare "
              f"({F.nnz:,} non-zeros)", flush=True)
        out["full_F"] = t_full
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--faces", type=int, nargs="+", default=[609_000, 1_000_000])
    ap.add_argument("--before", action="store_true", help="also time the whole F")
    args = ap.parse_args()
    print(f"load average {open('/proc/loadavg').read().split()[:3]}")
    # compile the numba kernels once, in this process, before any timing (forked workers
    # inherit them): a one-off cost per process, not one of big grids
    small = slab_block(3000)
    cam = slab_camera(160, 128)
    correct_image(np.ones((128, 160), np.float32), small.mesh, cam, small.reflectance,
                  rays_per_face=8, unpainted=~small.painted)
    view_factors(small.mesh, rays_per_face=8, workers=1)
    for f in args.faces:
        run(f, args.before)


if __name__ == "__main__":
    main()
