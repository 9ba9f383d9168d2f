"""``resection compare-cameras``: argument parsing only; the comparison is
:func:`resection.pose.compare.compare_cameras`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from resection.cli.util import add_mesh_format
from resection.errors import InputError


def register(sub) -> None:
    c = sub.add_parser(
        "compare-cameras",
        help="how far apart two cameras of the same view are (a new pose against an older "
        "calibration)",
        description="Project the targets (--markers) and the grid's nodes (--mesh) through "
        "both cameras and print the mean and largest pixel distance between the two "
        "projections (points in front of both cameras and in the image of either; hidden "
        "nodes count too), the two perspective centres and their distance (model units), "
        "the angle of the rotation between them (degrees) and the changes of focal length "
        "and principal point.")
    c.add_argument("camera_a", help="first camera file (any family convert-camera reads)")
    c.add_argument("camera_b", help="second camera file, compared with the first")
    c.add_argument("--markers", help="targets: marker CSV or uPSP .tgts")
    c.add_argument("--mesh", help="model grid: its nodes projected through both")
    add_mesh_format(c)
    c.add_argument("--image", help="an image of the cameras: their size, for a uPSP file "
                   "that gives none")
    c.add_argument("--out", help="also write the comparison as JSON here")
    c.set_defaults(func=run_compare)


def run_compare(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera_file
    from resection.io.outputs import atomic_write
    from resection.pose.compare import compare_cameras

    size = None
    if args.image:
        from resection.io.images import image_info

        shape = image_info(args.image)["shape"]
        size = (shape[-1], shape[-2])
    fa = read_camera_file(args.camera_a, image_size=size)
    fb = read_camera_file(args.camera_b, image_size=size or (fa.camera.width,
                                                             fa.camera.height))
    for path, f in ((args.camera_a, fa), (args.camera_b, fb)):
        if not f.has_pose:
            raise InputError(f"{path}: holds no pose (intrinsics only); compare cameras "
                             "with a pose")
    sets = []
    if args.markers:
        from resection.io.markers import read_markers

        ms = read_markers(args.markers)
        sets.append(("targets", ms.xyz, np.asarray(ms.ids, dtype=object)))
    if args.mesh:
        from resection.io.meshes import load_mesh

        mesh = load_mesh(args.mesh, format=args.mesh_format)
        sets.append(("grid nodes", np.asarray(mesh.vertices),
                     np.arange(len(mesh.vertices))))
    res = compare_cameras(fa.camera, fb.camera, sets)
    print(res.report((args.camera_a, args.camera_b)))
    if args.out:
        d = {"camera_a": args.camera_a, "camera_b": args.camera_b,
             "centre_a": res.centre_a.tolist(), "centre_b": res.centre_b.tolist(),
             "centre_distance": res.centre_distance, "rotation_deg": res.rotation_deg,
             "focal_change_px": res.focal_change.tolist(),
             "principal_point_change_px": res.principal_change.tolist(),
             "points": {s.name: {"n": s.n, "mean_px": s.mean, "largest_px": s.largest,
                                 "worst": s.worst} for s in res.spreads}}
        text = json.dumps(d, indent=1, default=str) + "\n"
        atomic_write(args.out, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))
        print(f"compare-cameras: written to {args.out}")
    return 0
