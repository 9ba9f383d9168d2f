"""What issue 34's checks and limiter cost, against the work they sit in (same run), on
NASA uPSP's grid (609,120 faces) and camera 1 (1280 x 800), from ``tests/data/upsp``:

* ``SurfaceMap.to_image`` (``backproject``'s default, linear) with the vertex values held
  within the values of their faces (the limiter) against the same call without it
  (the limiter replaced by nothing), interleaved, warm;
* the footprint check of ``map`` without ``--markers``
  (:func:`resection.pose.footprint.footprint_fit`: Otsu, 8-pixel cells, 7 scales) against
  building the camera's ``SurfaceMap`` that ``map`` builds anyway (same Embree scene);
* the dark-border search (:func:`resection.border.mask_dark_border`) against
  ``SurfaceMap.to_surface`` of the same frame.

Run: ``python bench/bench_issue34.py``. Prints medians and ratios; figures in
``bench/README.md``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from resection.border import mask_dark_border  # noqa: E402
from resection.io.cameras import read_camera  # noqa: E402
from resection.io.meshes import load_mesh  # noqa: E402
from resection.pose.footprint import footprint_fit  # noqa: E402
from resection.surface import vertex_fit  # noqa: E402
from resection.surface.surface_map import SurfaceMap  # noqa: E402
from resection.surface.visibility import RayCaster  # noqa: E402

DATA = ROOT / "tests" / "data" / "upsp"


def _median(fn, repeat=7):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def main() -> None:
    mesh = load_mesh(DATA / "fml_tc3_volume.grid")
    cam = read_camera(DATA / "camera-tunnel-calibration" / "camera01_35_6.json")
    caster = RayCaster(mesh)
    smap = SurfaceMap(mesh, cam, caster=caster)
    fv = np.random.default_rng(0).integers(1, 166, len(mesh.faces)).astype(float)
    smap.to_image(fv)  # the matrices built, the kernels compiled
    real = vertex_fit._clamp_to_support
    with_l, without = [], []
    for _ in range(3):  # interleaved
        vertex_fit._clamp_to_support = real
        with_l.append(_median(lambda: smap.to_image(fv)))
        vertex_fit._clamp_to_support = lambda *a: None
        without.append(_median(lambda: smap.to_image(fv)))
    vertex_fit._clamp_to_support = real
    a, b = float(np.median(with_l)), float(np.median(without))
    print(f"to_image, limiter: {1e3 * a:.1f} ms; without: {1e3 * b:.1f} ms; ratio {a / b:.2f}")
    rng = np.random.default_rng(1)
    frame = np.where(smap.mask, 2400.0, 60.0) * rng.gamma(30.0, 1 / 30.0, smap.shape)
    frame[:, :3] = 2.0  # a dark border
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    footprint_fit(cam, frame, caster, bounds=(lo, hi))  # warm
    f = _median(lambda: footprint_fit(cam, frame, caster, bounds=(lo, hi)))
    s = _median(lambda: SurfaceMap(mesh, cam, caster=caster), repeat=3)
    print(f"footprint check: {1e3 * f:.1f} ms; SurfaceMap of the camera: {1e3 * s:.1f} ms; "
          f"ratio {f / s:.3f}")
    d = _median(lambda: mask_dark_border(frame))
    m = _median(lambda: smap.to_surface(frame))
    print(f"dark border: {1e3 * d:.1f} ms; to_surface: {1e3 * m:.1f} ms; ratio {d / m:.2f}")


if __name__ == "__main__":
    main()
