"""``resection pose`` and ``resection calibrate``: argument parsing only, the work is in
:mod:`resection.pose.solve`, :mod:`resection.pose.calibration` and :mod:`resection.io.markers`."""

from __future__ import annotations

import argparse
import math
import os

import numpy as np

from resection.cli.markers import add_detect_options, add_enhance_window_option
from resection.cli.util import add_acceptance_options, add_mesh_format
from resection.errors import InputError
from resection.io.outputs import atomic_write

_LOSSES = ("huber", "soft_l1", "cauchy", "arctan")


def register(sub) -> None:
    """Add the ``pose`` and ``calibrate`` sub-commands to an argparse sub-parser set."""
    p = sub.add_parser(
        "pose",
        help="camera Point of View from linked markers",
        description="Solve the camera pose (and optionally refine intrinsics) from markers "
        "with known model coordinates and linked image positions; prints the RMS and each "
        "marker's residual, writes the camera JSON.",
    )
    p.add_argument("--camera", required=True, help="input camera JSON (intrinsics)")
    p.add_argument("--markers", required=True, help="marker CSV id,x,y,z[,diameter][,nx,ny,nz] "
                   "or uPSP .tgts (its taps are never taken for targets)")
    p.add_argument("--points", help="linked image points CSV: id,u,v (pixels)")
    p.add_argument("--image", help="image: detect its markers and match them automatically "
                   "(approximate pose in --camera) or link them by hand with --links")
    p.add_argument("--links", help="with --image: linking CSV id,candidate (e.g. saved by "
                   "'resection link --serve'); every other target in view is then looked "
                   "for too (see --no-refind)")
    p.add_argument("--candidates", help="with --links: the candidate CSV it numbers (default: "
                   "detect on --image)")
    add_detect_options(p, required_diameter=False)
    add_enhance_window_option(p)
    p.add_argument("--out", required=True, help="output camera JSON with the solved pose")
    p.add_argument("--residuals", help="also write the residual table (CSV) here")
    p.add_argument("--robust", nargs="?", const="soft_l1", choices=_LOSSES,
                   help="robust loss (default soft_l1 when given without a value)")
    p.add_argument("--robust-scale", type=float, default=1.0,
                   help="pixel error where the robust loss bends (default 1)")
    p.add_argument("--refine-intrinsics", nargs="?", const="focal",
                   choices=("focal", "center", "all"),
                   help="also refine the focal length (default), focal and centre, or all "
                   "with distortion")
    add_acceptance_options(p)
    p.add_argument("--plot", metavar="OUT.png", help="also draw the overlay (the paper's "
                   "Figure 20): model outline (with --mesh), detected and reprojected markers "
                   "with ids, residual arrows with their scale, RMS in the title; over the "
                   "--image, or a blank frame with --points")
    p.add_argument("--mesh", help="model surface: with --image, targets it hides are not "
                   "looked for (reported as occluded) and targets lying under it are moved "
                   "out to it along their normals, with a warning (uPSP .tgts trap); with "
                   "--plot, its outline is drawn")
    add_mesh_format(p)
    p.add_argument("--no-refind", action="store_true",
                   help="with --image: do not look again, after the first pose, for the "
                   "targets it did not use (default: every target predicted in view, facing "
                   "the camera and not hidden is searched for in a window with local "
                   "enhancement, and those not used are listed with why)")
    p.add_argument("--crease", type=float, default=30.0, metavar="DEG",
                   help="with --plot --mesh: dihedral angle above which an edge is an "
                   "outline (default 30)")
    p.add_argument("--ambiguity-px", type=float, default=0.5, metavar="PX",
                   help="assumed (upper) marker uncertainty when telling competing poses "
                   "apart; lowered automatically when the residuals prove the markers "
                   "better measured (default 0.5)")
    p.set_defaults(func=run_pose)

    c = sub.add_parser(
        "calibrate",
        help="intrinsics and distortion from views of a target",
        description="Calibrate focal lengths, perspective centre and distortion from one or "
        "more views of a planar or 3-D target; prints the RMS, per-view RMS and the "
        "parameters, writes the camera JSON (pose of the first view).",
    )
    c.add_argument("--markers", help="target marker CSV shared by all views given by --points")
    c.add_argument("--points", nargs="+", default=[], help="linked image points CSV per view")
    c.add_argument("--points-dir", metavar="DIR",
                   help="directory whose .csv files (sorted) are the views' image points")
    c.add_argument("--views", nargs="+", default=[], metavar="MARKERS.csv:POINTS.csv",
                   help="views as marker/points file pairs (targets may differ)")
    c.add_argument("--size", required=True, metavar="WxH", help="image size in pixels")
    c.add_argument("--fix", nargs="+", default=[], metavar="NAME",
                   help="parameters held fixed: fx fy cx cy k1 k2 p1 p2 k3 aspect")
    c.add_argument("--camera", help="initial camera JSON (start and fixed values)")
    c.add_argument("--out", required=True, help="output camera JSON")
    c.add_argument("--residuals", help="also write the residual table (CSV) here, with a "
                   "view column")
    add_acceptance_options(c)
    c.set_defaults(func=run_calibrate)


def _linked(markers_path: str, points_path: str, mesh=None):
    from resection.io.markers import link_points, read_markers, read_points

    markers = read_markers(markers_path, mesh=mesh)
    ids, uv = read_points(points_path)
    return link_points(markers, ids, uv, source=points_path)


def pose_inputs(args: argparse.Namespace, mesh=None):
    """Camera and linked ``(ids, points3d, points2d)`` of the ``pose`` command (the place
    where other sources of image points plug in). ``mesh``: the model surface, if given
    (targets under it are moved out to it)."""
    from resection.io.cameras import read_camera
    from resection.io.markers import read_markers
    from resection.markers.from_image import image_points

    size = None
    if getattr(args, "image", None):  # the image's size serves a uPSP file that gives none
        from resection.io.images import read_image

        size = read_image(args.image).shape[::-1]
    camera = read_camera(args.camera, image_size=size)
    if getattr(args, "image", None):
        if args.points:
            raise InputError("give --points or --image, not both")
        markers = read_markers(args.markers, mesh=mesh) if mesh is not None else args.markers
        pts = image_points(args.image, markers, args.camera,
                           diameter=args.diameter, polarity=args.polarity,
                           template=args.template, roi=args.roi, threshold=args.threshold,
                           enhance=args.enhance, enhance_windows=args.enhance_window,
                           links=args.links, candidates=args.candidates,
                           marker_accuracy=args.marker_accuracy, max_rms=args.max_rms,
                           markers_source=args.markers)
        print(f"image: {len(pts.candidates)} candidates, {len(pts.ids)} markers linked")
        return camera, pts.ids, pts.points3d, pts.points2d
    if not args.points:
        if getattr(args, "links", None) or getattr(args, "candidates", None):
            raise InputError("--links/--candidates need --image IMAGE")
        raise InputError("no image points: give --points POINTS.csv or --image IMAGE")
    ids, X, uv = _linked(args.markers, args.points, mesh)
    return camera, ids, X, uv


def run_pose(args: argparse.Namespace) -> int:
    from resection.io.cameras import write_camera
    from resection.io.images import read_image
    from resection.io.markers import read_markers, write_residuals
    from resection.io.meshes import load_mesh
    from resection.markers.refind import refind_targets
    from resection.pose.figure20 import write_pose_plot
    from resection.pose.solve import solve_pose

    if args.mesh and not (args.plot or args.image):
        raise InputError("--mesh is for refinding (--image) and the overlay (--plot): give "
                         "one of them too")
    mesh = load_mesh(args.mesh, format=args.mesh_format) if args.mesh else None
    camera, ids, X, uv = pose_inputs(args, mesh)
    result = solve_pose(camera, X, uv, robust=args.robust, robust_scale=args.robust_scale,
                        refine_intrinsics=args.refine_intrinsics or False,
                        max_rms=args.max_rms, marker_accuracy=args.marker_accuracy,
                        ambiguity_px=args.ambiguity_px, ids=ids)
    if args.image and not args.no_refind:  # after --links too: every other target
        found = refind_targets(
            read_image(args.image, mask_saturated=True), read_markers(args.markers, mesh=mesh),
            result.camera, np.asarray(ids)[result.used], uv[result.used],
            diameter=args.diameter, polarity=args.polarity, mesh=mesh,
            marker_accuracy=args.marker_accuracy, max_rms=args.max_rms,
            pose_kw=dict(robust=args.robust, robust_scale=args.robust_scale,
                         refine_intrinsics=args.refine_intrinsics or False,
                         ambiguity_px=args.ambiguity_px))
        print("\n".join(found.report()))
        result, ids, X, uv = found.pose, found.ids, found.points3d, found.points2d
    print(f"pose: {result.message}")
    print(f"rms {result.rms:.4f} px")
    print(f"{'id':>12} {'du':>9} {'dv':>9} {'error':>9}")
    for k, r, e, u in zip(ids, result.residuals, result.errors, result.used, strict=True):
        print(f"{k:>12} {r[0]:9.4f} {r[1]:9.4f} {e:9.4f}" + ("" if u else "  outlier, dropped"))
    from resection.pose.camera_fit import solved_on_record

    # what the camera was solved on: the image (name, size, fingerprint) and the targets
    # of the marker file (their units), for the commands that use the camera later
    record = solved_on_record(args.image, read_image(args.image) if args.image else None,
                              args.markers, read_markers(args.markers))
    write_camera(args.out, result.camera, solved_on=record)  # atomic
    if args.residuals:
        atomic_write(args.residuals, write_residuals, ids, uv, result.residuals)
    print(f"camera written to {args.out}")
    if args.plot:
        image = read_image(args.image, mask_saturated=True) if args.image else None
        atomic_write(args.plot, write_pose_plot, result, X, uv, image=image, mesh=mesh,
                     ids=ids, crease_deg=args.crease)
        print(f"overlay written to {args.plot}")
    return 0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size: expected WxH (e.g. 1280x960), got {text!r}") from None
    return w, h


def run_calibrate(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera, write_camera
    from resection.io.markers import write_view_residuals
    from resection.pose.calibration import calibrate

    size = _size(args.size)
    pairs = []
    points = list(args.points)
    if args.points_dir:
        if not os.path.isdir(args.points_dir):
            raise InputError(f"--points-dir: not a directory: {args.points_dir}")
        found = sorted(f for f in os.listdir(args.points_dir) if f.lower().endswith(".csv"))
        if not found:
            raise InputError(f"--points-dir: no .csv files in {args.points_dir}")
        points += [os.path.join(args.points_dir, f) for f in found]
    if points:
        if not args.markers:
            raise InputError("--points needs --markers (the target shared by the views)")
        pairs += [(args.markers, p) for p in points]
    elif args.markers:
        raise InputError("--markers needs --points (one linked points file per view)")
    for v in args.views:
        if ":" not in v:
            raise InputError(f"--views: expected MARKERS.csv:POINTS.csv, got {v!r}")
        m, pt = v.rsplit(":", 1)
        pairs.append((m, pt))
    if not pairs:
        raise InputError("no views: give --markers M.csv --points P1.csv ... (or "
                         "--points-dir DIR), or --views M.csv:P.csv ...")
    views, ids = [], []
    for m, pt in pairs:
        i, X, uv = _linked(m, pt)
        views.append((X, uv))
        ids.append(i)
    initial = read_camera(args.camera) if args.camera else None
    result = calibrate(views, size, fix=args.fix, initial=initial,
                       marker_accuracy=args.marker_accuracy, max_rms=args.max_rms, ids=ids)
    cam = result.camera
    print(f"calibrate: {result.message}")
    print(f"rms {result.rms:.4f} px")
    for (_, pt), r in zip(pairs, result.view_rms, strict=True):
        print(f"  view {os.path.basename(pt)}: rms {r:.4f} px")
    for name in result.parameters:
        val = {"f": cam.K[0, 0], "fx": cam.K[0, 0], "fy": cam.K[1, 1], "cx": cam.K[0, 2],
               "cy": cam.K[1, 2], "k1": cam.dist[0], "k2": cam.dist[1], "p1": cam.dist[2],
               "p2": cam.dist[3], "k3": cam.dist[4]}[name]
        print(f"  {name:>3} = {val:.6g} +- {result.std[name]:.2g}")
    print(f"{'view':>4} {'id':>12} {'du':>9} {'dv':>9} {'error':>9}")
    for v, (i, r, m) in enumerate(zip(ids, result.residuals, result.used, strict=True)):
        for k, (du, dv), u in zip(i, r, m, strict=True):
            print(f"{v:>4} {k:>12} {du:9.4f} {dv:9.4f} {math.hypot(du, dv):9.4f}"
                  + ("" if u else "  outlier, dropped"))
    atomic_write(args.out, write_camera, cam)
    if args.residuals:
        atomic_write(args.residuals, write_view_residuals, ids, [uv for _, uv in views],
                     result.residuals)
    print(f"camera written to {args.out}")
    return 0
