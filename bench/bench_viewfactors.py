"""Speed and scale of :func:`selfillum.view_factors` and the correction.

Run: ``.venv/bin/python bench/bench_viewfactors.py [--quick]``

1. Ray throughput of ``view_factors`` against the ceiling: a bare ``embreex`` intersection
   call (``EmbreeScene.run`` on prepared float32 arrays) on the very same rays, in the
   same run. The ratio is the share of the time spent in Embree itself.
2. Time against the number of faces N at a fixed number of rays per face: the fitted
   exponent of ``t ~ N^p`` must be close to 1 (N K rays, a sparse matrix of N K
   entries), not 2.
3. 100,000 faces end to end: view factors, simulated measurement (forward) and the
   correction (direct, all faces seen; and partial, a quarter hidden), with the peak
   memory of the process against the size of F.
4. The same mesh at image level: :func:`selfillum.correct_image` on a 1024 x 768 image
   (surface map, view factors, inverse, per-pixel interpolated correction), the image
   made by backprojecting a finer forward model (128 rays a face, another seed).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _timing import best_of  # noqa: E402

from scenes.corner import corner  # noqa: E402
from selfillum import correct, forward, view_factors  # noqa: E402
from selfillum.mesh import face_normals  # noqa: E402
from selfillum.viewfactors import _OFFSET, RayScene, sample_rays  # noqa: E402


def same_rays(mesh, k, seed):
    """The rays view_factors casts (same RQMC points), as Embree's float32 arrays."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    scene = RayScene(v, mesh.faces)
    tri = (v - scene.origin)[np.asarray(mesh.faces)]
    nrm = face_normals(mesh)
    offset = _OFFSET * float(np.ptp(v, axis=0).max())
    o, d = [], []
    step = max(1, (1 << 20) // k)
    for b0 in range(0, len(tri), step):
        ids = np.arange(b0, min(b0 + step, len(tri)))
        p, dd, _ = sample_rays(tri[ids], nrm[ids], k, offset=offset, face_ids=ids, seed=seed)
        o.append(p)
        d.append(dd)
    return scene, np.concatenate(o), np.concatenate(d)


def throughput(mesh, k, label):
    n = len(mesh.faces)
    t_vf, F = best_of(lambda: view_factors(mesh, k, seed=0))
    scene, o32, d32 = same_rays(mesh, k, 0)
    t_bare, hits = best_of(lambda: scene.scene.run(o32, d32))
    # the same rays: every ray of view_factors hits what the bare call hits
    assert np.count_nonzero(np.asarray(hits) >= 0) >= F.nnz
    rays = n * k
    print(f"\n[1] ray throughput, {label}, {n} faces, K = {k} ({rays / 1e6:.2f} M rays)")
    print(f"    view_factors        {rays / t_vf / 1e6:6.2f} M rays/s  ({t_vf:.2f} s)")
    print(f"    bare embreex run    {rays / t_bare / 1e6:6.2f} M rays/s  ({t_bare:.2f} s)")
    print(f"    ratio view_factors / bare Embree = {t_bare / t_vf:.2f}")
    return t_bare / t_vf


def scaling(resolutions, k):
    print(f"\n[2] time against N (corner mesh, K = {k})")
    ns, ts = [], []
    for res in resolutions:
        mesh = corner(resolution=res).mesh
        t, F = best_of(lambda m=mesh: view_factors(m, k, seed=0), repeat=2)
        ns.append(len(mesh.faces))
        ts.append(t)
        print(f"    N = {ns[-1]:7d}  {t:7.3f} s  {ns[-1] * k / t / 1e6:5.2f} M rays/s  "
              f"nnz/row {F.nnz / ns[-1]:.1f}")
    p = np.polyfit(np.log(ns), np.log(ts), 1)[0]
    print(f"    fitted exponent t ~ N^p: p = {p:.2f}  (1 = linear, 2 = quadratic)")
    return p


def end_to_end(resolution, k):
    sc = corner(resolution=resolution)
    mesh, E, rho = sc.mesh, sc.emission, sc.reflectance
    n = len(mesh.faces)
    print(f"\n[3] end to end, corner mesh {n} faces, K = {k}")
    t0 = time.perf_counter()
    F = view_factors(mesh, k, seed=0)
    t1 = time.perf_counter()
    B = forward(F, E, rho)
    t2 = time.perf_counter()
    E1 = correct(F, B, rho)
    t3 = time.perf_counter()
    c = mesh.triangles_center
    seen = ~((sc.plate == 1) & (c[:, 2] > 0.5))  # upper half of the wall hidden
    E2, info = correct(F, np.where(seen, B, np.nan), rho, seen, mesh=mesh, return_info=True)
    t4 = time.perf_counter()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux: KiB)
    f_mib = (F.data.nbytes + F.indices.nbytes + F.indptr.nbytes) / 2**20
    print(f"    view factors          {t1 - t0:6.2f} s  (nnz {F.nnz}, <= N K = {n * k})")
    print(f"    forward (simulate)    {t2 - t1:6.2f} s")
    print(f"    correction, all seen  {t3 - t2:6.3f} s  max |E - E_true| / E "
          f"{np.max(np.abs(E1 - E) / E):.1e}")
    print(f"    correction, 1/4 hidden{t4 - t3:6.2f} s  ({info.iterations} LSMR iterations; "
          f"max error on seen faces {np.max((np.abs(E2 - E) / E)[seen]):.3f})")
    print(f"    total view factors + correction (all seen): {t1 - t0 + t3 - t2:.2f} s")
    print(f"    F in memory {f_mib:.0f} MiB; peak process memory {peak:.0f} MiB")
    return t1 - t0 + t3 - t2


def image_level(resolution, k):
    from resection import Camera
    from resection.surface import SurfaceMap
    from selfillum import correct_image

    sc = corner(resolution=resolution)
    W, H = 1024, 768
    f = 0.8125 * W
    cam = Camera.look_at([1.4, 0.5, 1.2], [0.3, 0.5, 0.3], [0, 1, 0],
                         K=[[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]],
                         width=W, height=H)
    B = forward(view_factors(sc.mesh, 128, seed=5), sc.emission, sc.reflectance)
    smap = SurfaceMap(sc.mesh, cam)
    img = smap.to_image(B / np.pi, background=0.0).astype(np.float32)
    truth = smap.to_image(sc.emission / np.pi, background=0.0)
    t0 = time.perf_counter()
    r = correct_image(img, sc.mesh, cam, sc.reflectance, rays_per_face=k)
    t1 = time.perf_counter()
    m = smap.mask
    rel = r.image[m] / truth[m] - 1.0
    before = img[m] / truth[m] - 1.0
    print(f"\n[4] image level, {len(sc.mesh.faces)} faces, {W} x {H} image, K = {k}")
    print(f"    correct_image (map + view factors + {r.info.method} + per pixel) "
          f"{t1 - t0:.2f} s")
    print(f"    |corrected / emission image - 1|: median {np.median(np.abs(rel)):.4f}, "
          f"95th pct {np.percentile(np.abs(rel), 95):.4f} (before: "
          f"{np.percentile(np.abs(before), 95):.3f})")
    return t1 - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes")
    args = ap.parse_args()
    sphere = trimesh.creation.icosphere(subdivisions=4 if args.quick else 5)
    sphere.invert()  # painted inside: every ray hits, Embree does the most work a ray
    if args.quick:
        throughput(corner(resolution=30).mesh, 64, "open corner (most rays escape)")
        throughput(sphere, 64, "inside a sphere (every ray hits)")
        scaling([10, 20, 40], 32)
        end_to_end(40, 64)
        image_level(40, 64)
    else:
        throughput(corner(resolution=60).mesh, 128, "open corner (most rays escape)")
        throughput(sphere, 128, "inside a sphere (every ray hits)")
        scaling([20, 40, 80, 160], 32)
        end_to_end(159, 64)
        image_level(159, 64)


if __name__ == "__main__":
    main()
