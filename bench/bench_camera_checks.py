"""What the camera checks of issue 20 cost, against the work they guard (same run).

* ``marker_fit`` (the window check per target of ``--markers``) and ``image_fingerprint``
  (the record ``pose`` writes, compared by ``map`` and ``correct``) against building the
  ``SurfaceMap`` of the same camera and mapping the image (``to_surface``);
* ``SurfaceMap.to_image`` with the renormalised interpolation against the previous
  interpolation (one sparse product of NaN-zeroed vertex values), interleaved.

Run: ``python bench/bench_camera_checks.py``. Prints medians and ratios; figures in
``bench/README.md``.
"""

from __future__ import annotations

import os
import time

import numpy as np
import trimesh

from resection import Camera
from resection.io.marker_set import MarkerSet
from resection.pose.camera_fit import image_fingerprint, marker_fit
from resection.surface.surface_map import SurfaceMap
from scenes.real_traits import real_traits


def _median(fn, repeat=5):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def checks() -> None:
    sc = real_traits(scale=4)  # 1280 x 960, two cameras, 22 targets
    ms = MarkerSet(sc.marker_ids, sc.surveyed, np.full(len(sc.marker_ids), 0.006))
    cam, img = sc.cameras[0], sc.images[0].astype(np.float32)
    smap = SurfaceMap(sc.mesh, cam)
    t_map = _median(lambda: SurfaceMap(sc.mesh, cam))
    t_fit = _median(lambda: marker_fit(cam, img, ms, surface_map=smap))
    t_fp = _median(lambda: image_fingerprint(img))
    t_surf = _median(lambda: smap.to_surface(img))
    fit = marker_fit(cam, img, ms, surface_map=smap)
    print(f"{img.shape[1]}x{img.shape[0]}, {len(sc.mesh.faces)} faces, {fit.line()}")
    print(f"SurfaceMap {t_map * 1e3:.1f} ms, to_surface {t_surf * 1e3:.1f} ms, marker_fit "
          f"{t_fit * 1e3:.1f} ms, fingerprint {t_fp * 1e3:.2f} ms")
    print(f"marker_fit / SurfaceMap = {t_fit / t_map:.3f}; "
          f"fingerprint / to_surface = {t_fp / t_surf:.3f}")


def backprojection() -> None:
    n = 400  # 320,000 faces
    xs = np.linspace(-1, 1, n + 1)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    mesh = trimesh.Trimesh(V, F, process=False)
    cam = Camera.look_at([0.1, -0.2, 2.4], [0, 0, 0], [0, 1, 0],
                         K=[[900, 0, 639.5], [0, 900, 479.5], [0, 0, 1]], width=1280, height=960)
    smap = SurfaceMap(mesh, cam)
    fv = 1000 + mesh.triangles_center[:, 0] * 300
    fv[mesh.triangles_center[:, 0] > 0.5] = np.nan  # unseen faces: the renormalised path

    def previous():
        vert = smap.vertex_values(fv[:, None], "linear")
        return (smap._interpolation_matrix() @ np.nan_to_num(vert)).T

    smap.to_image(fv)
    t = {"previous": [], "to_image": []}
    for _ in range(7):  # interleaved
        for k, f in (("previous", previous), ("to_image", lambda: smap.to_image(fv))):
            t0 = time.perf_counter()
            f()
            t[k].append(time.perf_counter() - t0)
    tp, tn = np.median(t["previous"]), np.median(t["to_image"])
    print(f"backprojection, {len(mesh.faces)} faces, {int(smap.mask.sum())} pixels: previous "
          f"interpolation core {tp * 1e3:.0f} ms, to_image (renormalised, background "
          f"filled) {tn * 1e3:.0f} ms, ratio {tn / tp:.2f}")


if __name__ == "__main__":
    print(f"load average {os.getloadavg()[0]:.2f}")
    checks()
    backprojection()
