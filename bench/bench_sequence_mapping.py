"""Mapping a moving model over a sequence: per-frame maps against uPSP's way, both against
the truth, measured in the same run.

Scene: :mod:`scenes.moving_surface` (the model of :mod:`scenes.moving_model`, a wing slab and
a fuselage box, pitching 2 degrees at 1 Hz with heave and roll, 50 frames/s), frames
rendered by closed-form ray/box casting with a known paint field.

* **per frame** (:func:`resection.sequence.mapping.map_frames`): a ``SurfaceMap`` from every
  frame's own pose (the true pose here, as ``track`` gives it), node values from the pixels
  around each node (``SurfaceMap.to_nodes``);
* **uPSP's way**: the map of frame 0 only; every later frame is warped onto frame 0 by an
  affine ``cv2.findTransformECC`` (started from the previous frame's warp) and
  ``cv2.warpAffine``, then sampled with the frame-0 map. OpenCV is a bench/test-only peer.

Errors are node value minus the paint field at the node (counts; the field is about 600 to
1,400), split into nodes near an edge of the model's boxes (outline and fuselage-wing
junction) and the rest, over every frame and every node seen in it.

Run: ``.venv/bin/python bench/bench_sequence_mapping.py [--frames 500] [--size 256]``
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np

from resection.sequence.mapping import map_frames
from resection.surface.surface_map import SurfaceMap
from scenes.moving_model import pitch_oscillation
from scenes.moving_surface import edge_nodes, model_surface, paint_field, render_surface


def upsp_way(mesh, cam0, frames):
    """Frame-0 map + affine ECC warp of every frame onto frame 0 (uPSP)."""
    smap = SurfaceMap(mesh, cam0)
    template = frames[0]
    warp = np.eye(2, 3, dtype=np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-6)
    h, w = template.shape
    for k, img in enumerate(frames):
        if k:
            try:
                _, warp = cv2.findTransformECC(template, img, warp, cv2.MOTION_AFFINE, crit,
                                               None, 5)
            except cv2.error:  # not converged: keep the previous warp, as a pipeline would
                pass
            img = cv2.warpAffine(img, warp, (w, h), flags=cv2.INTER_LINEAR
                                 + cv2.WARP_INVERSE_MAP, borderValue=float("nan"))
        yield smap.to_nodes(img).values


def stats(err: np.ndarray, sel: np.ndarray) -> str:
    e = np.abs(err[:, sel])
    e = e[np.isfinite(e)]
    return (f"median {np.median(e):6.2f}  95th {np.percentile(e, 95):7.2f}  "
            f"99th {np.percentile(e, 99):7.1f}  max {e.max():7.1f}  ({e.size} values)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--size", type=int, default=256, help="image width = height, pixels")
    ap.add_argument("--face-size", type=float, default=0.01, help="grid spacing, metres")
    args = ap.parse_args()
    model = pitch_oscillation(args.frames, shape=(args.size, args.size))
    mesh = model_surface(args.face_size)
    print(f"{args.frames} frames {args.size}x{args.size}, grid {len(mesh.vertices)} nodes / "
          f"{len(mesh.faces)} faces, pitch amplitude "
          f"{np.degrees(np.abs(model.angles[:, 1]).max()):.2f} deg")
    t0 = time.perf_counter()
    frames = [render_surface(model, k) for k in range(args.frames)]
    print(f"rendering (closed-form ray/box casting): {time.perf_counter() - t0:.1f} s")
    cams = [model.camera_at(k) for k in range(args.frames)]
    truth = paint_field(mesh.vertices)
    edge = edge_nodes(mesh)

    def timed(fn):
        t0, c0 = time.perf_counter(), time.process_time()
        out = np.array(list(fn()))
        return out, time.perf_counter() - t0, time.process_time() - c0

    ours, t_ours, c_ours = timed(lambda: (r.values for r in map_frames(mesh, cams, frames,
                                                                        per="node")))
    theirs, t_theirs, c_theirs = timed(lambda: upsp_way(mesh, cams[0], frames))
    fixed, t_fixed, c_fixed = timed(lambda: (r.values for r in map_frames(
        mesh, cams[0], frames, per="node")))

    n = args.frames
    print(f"[speed] per-frame maps {n / t_ours:6.1f} frames/s | uPSP way (ECC + warp + "
          f"frame-0 map) {n / t_theirs:6.1f} frames/s | frame-0 map, no warp "
          f"{n / t_fixed:6.1f} frames/s | per-frame / uPSP {t_theirs / t_ours:.2f}")
    print(f"        per CPU second (process time, all threads): per-frame {n / c_ours:.1f}, "
          f"uPSP way {n / c_theirs:.1f}, frame-0 map {n / c_fixed:.1f} frames")
    for name, vals in (("per-frame", ours), ("uPSP way ", theirs), ("no warp  ", fixed)):
        err = vals - truth
        print(f"[error] {name} edges    {stats(err, edge)}")
        print(f"        {name} interior {stats(err, ~edge)}")
        worst = np.nanmax(np.abs(err[:, edge]), axis=1)
        print(f"        {name} worst edge error per frame: median {np.nanmedian(worst):.1f}, "
              f"max {np.nanmax(worst):.1f}")


if __name__ == "__main__":
    main()
