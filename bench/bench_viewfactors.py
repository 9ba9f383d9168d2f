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
5. Error against time on Howell's C-14 (two unit squares at 90 degrees sharing an edge,
   10 x 10 squares each): the stratified random rays of the previous release, the RQMC
   rays of ``view_factors``, and the closed-form point-to-triangle kernel
   (``selfillum.transport.kernel``, unoccluded only). Per-face error of the factor to the other
   plate against the converged kernel (its plate total checked against C-14).
6. The corner main job (6400 faces): largest and rms residual after correction against
   rays per face, stratified random against RQMC, the measurement simulated from the
   converged closed-form reference.
4. The same mesh at image level: :func:`selfillum.images.image_correction` on a 1024 x 768 image
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
from selfillum.transport.viewfactors import _OFFSET, RayScene, sample_rays  # noqa: E402


def _scene_frame(mesh):
    """A bare ``embreex`` scene (the peer: its own copy of the buffers), triangles in
    its centred frame (``RayScene``'s), normals and the ray-origin lift, as view_factors
    prepares them."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    v = np.asarray(mesh.vertices, dtype=np.float64)
    origin = RayScene(v, mesh.faces).origin
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=np.ascontiguousarray(v - origin, dtype=np.float32),
                 indices=np.ascontiguousarray(mesh.faces, dtype=np.int32))
    tri = (v - origin)[np.asarray(mesh.faces)]
    return scene, tri, face_normals(mesh), _OFFSET * float(np.ptp(v, axis=0).max())


def same_rays(mesh, k, seed):
    """The rays view_factors casts (same RQMC points), as Embree's float32 arrays."""
    scene, tri, nrm, offset = _scene_frame(mesh)
    o, d = [], []
    step = max(1, (1 << 20) // k)
    for b0 in range(0, len(tri), step):
        ids = np.arange(b0, min(b0 + step, len(tri)))
        p, dd, _ = sample_rays(tri[ids], nrm[ids], k, offset=offset, face_ids=ids, seed=seed)
        o.append(p)
        d.append(dd)
    return scene, np.concatenate(o), np.concatenate(d)


def throughput(mesh, k, label, workers=(1, None), repeat=3):
    """Best of ``repeat`` for view_factors (1 thread and the default, both cores) and
    for one bare embreex call on the same rays, alternated in the same run."""
    n = len(mesh.faces)
    scene, o32, d32 = same_rays(mesh, k, 0)
    best = {w: np.inf for w in workers}
    t_bare = np.inf
    for _ in range(repeat):
        for w in workers:
            t0 = time.perf_counter()
            F = view_factors(mesh, k, seed=0, workers=w)
            best[w] = min(best[w], time.perf_counter() - t0)
        t0 = time.perf_counter()
        hits = scene.run(o32, d32)
        t_bare = min(t_bare, time.perf_counter() - t0)
    # the same rays: every ray of view_factors hits what the bare call hits
    assert np.count_nonzero(np.asarray(hits) >= 0) >= F.nnz
    rays = n * k
    print(f"\n[1] ray throughput, {label}, {n} faces, K = {k} ({rays / 1e6:.2f} M rays)")
    print(f"    bare embreex run    {rays / t_bare / 1e6:6.2f} M rays/s  ({t_bare:.2f} s)")
    for w in workers:
        name = "1 thread" if w == 1 else "default threads"
        print(f"    view_factors, {name:16s} {rays / best[w] / 1e6:6.2f} M rays/s  "
              f"({best[w]:.2f} s), ratio to bare Embree {t_bare / best[w]:.2f}")
    return {w: t_bare / best[w] for w in workers}


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
    from resection.surface.surface_map import SurfaceMap
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


def _stratified_factors(mesh, k, seed):
    """The previous release's estimator: stratified random points and directions (one
    random stream a block of 512 faces), the same hit counting."""
    import scipy.sparse as sp

    scene, tri, nrm, offset = _scene_frame(mesh)
    rows, cols = [], []
    for b0 in range(0, len(tri), 512):
        ids = np.arange(b0, min(b0 + 512, len(tri)))
        rng = np.random.default_rng([seed, b0 // 512])
        o, d, _ = sample_rays(tri[ids], nrm[ids], k, rng, offset=offset)
        hit = np.asarray(scene.scene.run(o, d))
        src = np.repeat(ids, k)
        ok = (hit >= 0) & (hit != src)
        front = np.einsum("ij,ij->i", d[ok], nrm[hit[ok]]) < 0
        rows.append(src[ok][front])
        cols.append(hit[ok][front])
    r, c = np.concatenate(rows), np.concatenate(cols)
    n = len(tri)
    return sp.csr_matrix((np.full(r.size, 1.0 / k), (r, c)), shape=(n, n))


def error_against_time(ks, seeds=4):
    from selfillum.transport.kernel import pair_factors

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_viewfactors import howell_perpendicular, perpendicular_mesh

    mesh, g = perpendicular_mesh(n=10)
    a, b = np.flatnonzero(g == 0), np.flatnonzero(g == 1)
    nrm = face_normals(mesh)
    ii, jj = np.meshgrid(a, b, indexing="ij")
    exact = pair_factors(mesh.vertices, mesh.faces, nrm, ii.ravel(), jj.ravel(), order=8)
    per_face = exact.reshape(ii.shape).sum(axis=1)
    area = mesh.area_faces[a]
    c14 = howell_perpendicular(1, 1, 1)
    print(f"\n[5] error against time, perpendicular unit squares ({len(a)} + {len(b)} faces)")
    print(f"    converged kernel total {area @ per_face / area.sum():.8f}, Howell C-14 "
          f"{c14:.8f}")
    print("    estimator          K   per-face rms err   plate total err   time (s)")
    for k in ks:
        for name, fn in (("stratified", lambda s, k=k: _stratified_factors(mesh, k, s)),
                         ("RQMC", lambda s, k=k: view_factors(mesh, k, seed=s, workers=1))):
            errs, tots, ts = [], [], []
            for seed in range(seeds):
                t0 = time.perf_counter()
                F = fn(seed)
                ts.append(time.perf_counter() - t0)
                row = np.asarray(F[a][:, b].sum(axis=1)).ravel()
                errs.append(np.sqrt(np.mean((row / per_face - 1) ** 2)))
                tots.append(area @ row / area.sum() / c14 - 1)
            print(f"    {name:12s} {k:6d}   {np.mean(errs):10.2e}        "
                  f"{np.sqrt(np.mean(np.square(tots))):10.2e}      {np.median(ts):6.3f}")
    for order in (2, 3, 4):
        t0 = time.perf_counter()
        f = pair_factors(mesh.vertices, mesh.faces, nrm, ii.ravel(), jj.ravel(), order=order)
        t = time.perf_counter() - t0
        row = f.reshape(ii.shape).sum(axis=1)
        print(f"    kernel order {order} ({order * order:2d} pts)  "
              f"{np.sqrt(np.mean((row / per_face - 1) ** 2)):10.2e}        "
              f"{abs(area @ row / area.sum() / c14 - 1):10.2e}      {t:6.3f}  "
              f"(unoccluded only; N^2 pairs)")


def corner_residuals(ks):
    import scipy.sparse as sp

    from scenes.corner import exact_radiosity, symmetric_factors

    sc = corner(resolution=40)
    E, rho = sc.emission, sc.reflectance
    t0 = time.perf_counter()
    B = exact_radiosity(sc)
    print(f"\n[6] corner main job ({len(E)} faces): residual after correction, measurement "
          f"from the closed-form reference ({time.perf_counter() - t0:.1f} s)")
    print("    estimator              K    max residual   rms residual   view factors (s)")
    def symmetric(k):
        G = symmetric_factors(sc, view_factors(sc.mesh, k, seed=0))
        return sp.bmat([[None, sp.csr_matrix(G)], [sp.csr_matrix(G.T), None]]).tocsr()

    for k in ks:
        for name, fn in (("stratified", lambda k=k: _stratified_factors(sc.mesh, k, 0)),
                         ("RQMC", lambda k=k: view_factors(sc.mesh, k, seed=0)),
                         ("RQMC + symmetry", lambda k=k: symmetric(k))):
            t0 = time.perf_counter()
            F = fn()
            t = time.perf_counter() - t0
            r = np.abs(correct(F, B, rho) / E - 1)
            print(f"    {name:16s} {k:6d}   {100 * r.max():8.3f} %     "
                  f"{100 * np.sqrt(np.mean(r**2)):8.3f} %      {t:6.2f}")


def _sphere(subdivisions):
    """An icosphere painted inside: every ray hits, Embree does the most work a ray."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    sphere.invert()
    return sphere


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes")
    ap.add_argument("--only", type=int, nargs="*", help="run only these sections (1-6)")
    args = ap.parse_args()
    if args.only:
        for sec in args.only:
            {1: lambda: (throughput(corner(resolution=60).mesh, 1024,
                                    "open corner (most rays escape)"),
                         throughput(_sphere(5), 128, "inside a sphere (every ray hits)")),
             5: lambda: error_against_time([64, 256, 1024, 4096]),
             6: lambda: corner_residuals([256, 512, 1024, 2048, 4096])}[sec]()
        return
    sphere = _sphere(4 if args.quick else 5)
    if args.quick:
        throughput(corner(resolution=30).mesh, 64, "open corner (most rays escape)")
        throughput(sphere, 64, "inside a sphere (every ray hits)")
        scaling([10, 20, 40], 32)
        end_to_end(40, 64)
        image_level(40, 64)
        error_against_time([64, 256, 1024], seeds=2)
    else:
        throughput(corner(resolution=60).mesh, 1024, "open corner (most rays escape)")
        throughput(sphere, 128, "inside a sphere (every ray hits)")
        scaling([20, 40, 80, 160], 32)
        end_to_end(159, 64)
        image_level(159, 64)
        error_against_time([64, 256, 1024, 4096])
        corner_residuals([256, 1024, 4096])


if __name__ == "__main__":
    main()
