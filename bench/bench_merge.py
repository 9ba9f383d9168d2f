"""Multi-camera merge (resection.surface.merge) on the real-traits scene: speed against the plain
per-camera mapping (SurfaceMap.to_surface, the sparse product every merge needs anyway),
and the seam level against the scene's truth for the merge's variants.

Run: ``python bench/bench_merge.py [--scale 4]`` (scale 4: two 1280 x 960 frames).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from scipy.ndimage import distance_transform_edt

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))

from _timing import best_of  # noqa: E402
from test_merge import seam_level  # noqa: E402

from resection.surface.merge import merge_views  # noqa: E402
from resection.surface.surface_map import SurfaceMap  # noqa: E402
from scenes.real_traits import real_traits  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scale", type=float, default=4.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    t_scene, sc = best_of(lambda: real_traits(scale=args.scale), 1)
    maps = [SurfaceMap(sc.mesh, c) for c in sc.cameras]
    images = [np.where(i == 255, np.nan, i.astype(float)) for i in sc.images]
    H, W = images[0].shape
    print(f"scene: {W} x {H} frames, {len(sc.mesh.faces)} faces, built in {t_scene:.2f} s")
    # interleaved: peers, merge, peers, merge ...
    t_plain = t_merge = t_edt = t_map = np.inf
    for _ in range(args.repeat):
        t, _ = best_of(lambda: [m.to_surface(i) for m, i in zip(maps, images, strict=True)], 1)
        t_plain = min(t_plain, t)
        t, _ = best_of(lambda: [distance_transform_edt(m.mask) for m in maps], 1)
        t_edt = min(t_edt, t)
        t, _ = best_of(lambda: [SurfaceMap(sc.mesh, c) for c in sc.cameras], 1)
        t_map = min(t_map, t)
        t, mv = best_of(lambda: merge_views(maps, images), 1)
        t_merge = min(t_merge, t)
    print(f"merge of the two frames {t_merge * 1e3:.1f} ms; ratios: / plain per-camera "
          f"mapping (to_surface) {t_merge / t_plain:.1f}, / bare scipy distance_transform_edt "
          f"of the masks {t_merge / t_edt:.1f}, / building the two SurfaceMaps "
          f"{t_merge / t_map:.2f}")
    print(mv.report())
    for name, kw in [("plain mean (no gain, no feather)", dict(match_gain=False,
                                                               feather_px=0)),
                     ("feathered, no gain", dict(match_gain=False)),
                     ("gain matched, no feather", dict(feather_px=0)),
                     ("gain matched + feathered (default)", {})]:
        seam, inside = seam_level(sc, maps, merge_views(maps, images, **kw))
        print(f"{name:36s} seam p90 {100 * seam:5.2f} %   interior p90 {100 * inside:5.2f} %")


if __name__ == "__main__":
    main()
