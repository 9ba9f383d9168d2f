"""Mitsuba render of the corner against the Lambertian model of the same scene.

1. For each Mitsuba variant this machine has: the time of an all-bounce render and its
   ratio to the time of the model's image (Embree view factors + radiosity solve +
   backprojection through a SurfaceMap), with the agreement of the two images.
2. Against the number of faces N: view factors, the correction of a measured radiosity
   (``selfillum.solve.radiosity.correct``), and one render with the fastest variant.
3. Glossy paint (``selfillum.solve.brdf``): the view-dependent transport (T and T2) and the
   glossy inverse against a glossy Mitsuba render, with the per-face agreement.

Run:  .venv/bin/python bench/bench_render.py [--resolution 20] [--spp 256] [--width 320]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.ndimage import maximum_filter, minimum_filter

from resection import Camera
from resection.surface.surface_map import SurfaceMap
from scenes.corner import corner
from selfillum.rendering.mitsuba_render import available_variants, render
from selfillum.solve.radiosity import correct, forward
from selfillum.transport.viewfactors import view_factors


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", type=int, default=20, help="corner squares a side")
    ap.add_argument("--rays", type=int, default=1024, help="view-factor rays per face")
    ap.add_argument("--spp", type=int, default=256, help="Mitsuba samples per pixel")
    ap.add_argument("--width", type=int, default=320, help="image width (height 3/4)")
    ap.add_argument("--variants", default=None,
                    help="comma-separated variants (default: all available)")
    args = ap.parse_args()

    sc = corner(resolution=args.resolution, reflectance=0.6, pattern="smooth")
    W = args.width
    H = W * 3 // 4
    f = 0.8125 * W
    cam = Camera.look_at([1.4, 0.5, 1.2], [0.3, 0.5, 0.3], [0, 1, 0],
                         K=[[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]],
                         width=W, height=H)
    nf = len(sc.mesh.faces)
    print(f"corner: {nf} faces, image {W} x {H}, reflectance {sc.reflectance}")

    t0 = time.perf_counter()
    F = view_factors(sc.mesh, rays_per_face=args.rays, seed=1)
    t1 = time.perf_counter()
    B = forward(F, sc.emission, sc.reflectance)
    t2 = time.perf_counter()
    smap = SurfaceMap(sc.mesh, cam)
    model = smap.to_image(B / np.pi, interpolation="nearest")
    t3 = time.perf_counter()
    t_model = t3 - t0
    print(f"model: view factors {t1 - t0:.2f} s ({args.rays} rays/face), solve "
          f"{t2 - t1:.3f} s, surface map + backprojection {t3 - t2:.2f} s; total "
          f"{t_model:.2f} s")

    fi = smap.face_index
    plate = np.where(fi >= 0, sc.plate[np.maximum(fi, 0)], -1)
    away = (plate >= 0) & (minimum_filter(plate, 5) == maximum_filter(plate, 5))

    variants = args.variants.split(",") if args.variants else available_variants()
    print(f"{'variant':<14}{'spp':>6}{'render s':>10}{'render/model':>14}"
          f"{'median err':>12}{'p95 |err|':>11}")
    for v in variants:
        # warm-up (JIT compilation of the vectorised variants), not timed
        render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=1, variant=v)
        t0 = time.perf_counter()
        res = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=args.spp,
                     seed=1, variant=v)
        t_render = time.perf_counter() - t0
        rel = res.image[away] / model[away] - 1.0
        print(f"{res.variant:<14}{res.spp:>6}{t_render:>10.2f}{t_render / t_model:>14.1f}"
              f"{100 * np.median(rel):>11.2f}%{100 * np.percentile(np.abs(rel), 95):>10.2f}%")

    print()
    print(f"against N ({args.rays} rays/face, render {variants[0]} at 64 spp, all bounces):")
    print(f"{'N':>7}{'F s':>8}{'correct s':>11}{'render s':>10}{'render/correct':>16}"
          f"{'render/(F+correct)':>20}")
    for res_n in (10, 20, 40):
        sc = corner(resolution=res_n, reflectance=0.6, pattern="smooth")
        t0 = time.perf_counter()
        F = view_factors(sc.mesh, rays_per_face=args.rays, seed=1)
        t1 = time.perf_counter()
        B = forward(F, sc.emission, sc.reflectance)
        t2 = time.perf_counter()
        correct(F, B, sc.reflectance)
        t3 = time.perf_counter()
        render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=64, seed=1,
               variant=variants[0])
        t4 = time.perf_counter()
        tf, tc, tr = t1 - t0, t3 - t2, t4 - t3
        print(f"{len(sc.mesh.faces):>7}{tf:>8.2f}{tc:>11.4f}{tr:>10.2f}{tr / tc:>16.0f}"
              f"{tr / (tf + tc):>20.1f}")

    glossy(cam, variants[0], args.spp)


def glossy(cam, variant, spp):
    from selfillum.solve.brdf import GlossyPaint, glossy_correct, glossy_forward, transport_matrix

    paint, rho = GlossyPaint(0.4, 0.3), 0.5
    sc = corner(resolution=10, reflectance=rho, pattern="smooth")
    F = view_factors(sc.mesh, rays_per_face=2048, seed=1)
    t0 = time.perf_counter()
    tr = transport_matrix(sc.mesh, paint, rho, cam, rays_per_face=2048, seed=2,
                          second_order_rays=16)
    t1 = time.perf_counter()
    L = glossy_forward(F, tr, sc.emission, rho, paint)
    t2 = time.perf_counter()
    E = glossy_correct(F, tr, L, rho, paint)
    t3 = time.perf_counter()
    res = render(sc.mesh, sc.emission, rho, cam, bounces=-1, spp=spp, seed=1, variant=variant,
                 paint=paint)
    t4 = time.perf_counter()
    smap = SurfaceMap(sc.mesh, cam)
    meas = smap.to_surface(res.image)
    ok = meas.counts > 20
    rel = meas.values[ok] / L[ok] - 1.0
    assert np.allclose(E, sc.emission, rtol=1e-6)
    print()
    print(f"glossy paint (w 0.4, alpha 0.3), {len(sc.mesh.faces)} faces, {variant} "
          f"{res.spp} spp:")
    print(f"  transport T+T2 {t1 - t0:.2f} s, forward {t2 - t1:.3f} s, inverse {t3 - t2:.3f} s,"
          f" render {t4 - t3:.2f} s; render/inverse {(t4 - t3) / (t3 - t2):.0f}, "
          f"render/(transport+inverse) {(t4 - t3) / (t3 - t2 + t1 - t0):.1f}")
    print(f"  render vs model per face: median {100 * np.median(rel):.2f}%, "
          f"95th pct |err| {100 * np.percentile(np.abs(rel), 95):.2f}%")


if __name__ == "__main__":
    main()
