"""``resection detect``, ``resection link`` and ``resection match``: argument parsing only;
the work is in :mod:`resection.markers.detect`, :mod:`~resection.markers.link`,
:mod:`~resection.markers.match` and :mod:`resection.markers.from_image`."""

from __future__ import annotations

import argparse
import math

import numpy as np

from resection.cli.util import add_acceptance_options, add_mesh_format
from resection.errors import InputError
from resection.io.outputs import atomic_write


def add_enhance_window_option(parser) -> None:
    """``--enhance-window``: enhance (and search) only inside boxes; shared by ``detect``
    and ``pose --image``."""
    parser.add_argument("--enhance-window", type=float, nargs=4, action="append",
                        metavar=("UMIN", "VMIN", "UMAX", "VMAX"),
                        help="with --enhance: enhance only inside this box (pixels, "
                        "inclusive; repeat for several boxes)")


def add_detect_options(p: argparse.ArgumentParser, *, required_diameter: bool = True) -> None:
    """Detection options shared by ``detect`` and ``pose --image``."""
    p.add_argument("--diameter", type=float, required=required_diameter,
                   help="marker diameter in pixels" + ("" if required_diameter else
                   " (default: from the marker file's diameters and the camera)"))
    p.add_argument("--polarity", choices=("dark", "bright"), default="dark",
                   help="markers darker (default) or brighter than the model")
    p.add_argument("--template", choices=("tophat", "cone"), default="tophat",
                   help="correlation template (default tophat)")
    p.add_argument("--roi", type=float, nargs=4, metavar=("UMIN", "VMIN", "UMAX", "VMAX"),
                   help="search only inside this box (pixels, inclusive)")
    p.add_argument("--threshold", type=float,
                   help="merit threshold (image units; default 5 noise sigmas)")
    p.add_argument("--enhance", choices=("background", "normalize", "clahe"),
                   help="enhance the image first (low-contrast infrared images)")


def register(sub) -> None:
    """Add ``detect``, ``link`` and ``match`` to an argparse sub-parser set."""
    d = sub.add_parser(
        "detect", help="find marker candidates in an image",
        description="Detect circular markers with sub-pixel accuracy; writes the candidate "
        "CSV u,v,diameter,depth,merit,snr (numbered from 0 in file order).")
    d.add_argument("image", help="image file (.tif/.tiff, .png, .npy)")
    add_detect_options(d)
    add_enhance_window_option(d)
    d.add_argument("--out", "-o", required=True, help="output candidate CSV")
    d.set_defaults(func=run_detect)

    k = sub.add_parser(
        "link", help="link candidates to targets by hand: a page to click in, or a PNG",
        description="With --serve: a local page (127.0.0.1 only, a random token in its "
        "address) shows the frame, its candidates and the targets; click a candidate, then "
        "its target; from 4 links (3 with an approximate pose) the pose is solved live, the "
        "other targets are predicted and their candidates offered; Save writes --save-links, "
        "--pose and --out (docs/linking.md). Without it: draw the numbered candidates over "
        "the image, with the markers projected from an approximate camera (PNG); optionally "
        "write a suggested linking CSV; with --links, read a linking CSV id,candidate and "
        "write the linked markers (unlinked candidates are thrown away).")
    k.add_argument("image", help="image file")
    k.add_argument("--candidates", help="candidate CSV from 'resection detect' (with "
                   "--serve: default, detect on the image)")
    k.add_argument("--camera", help="camera file: intrinsics, and an approximate pose if it "
                   "has one (to draw, suggest or predict the markers)")
    k.add_argument("--markers", help="marker CSV id,x,y,z[,diameter] or uPSP .tgts")
    k.add_argument("--png", help="output PNG to read the candidate numbers from")
    k.add_argument("--suggest", help="write a suggested linking CSV (nearest projected "
                   "markers) here, to be checked and edited")
    k.add_argument("--links", help="linking CSV id,candidate to read (with --serve: the "
                   "links to start from)")
    k.add_argument("--out", "-o", help="output linked candidates CSV (with --links, or "
                   "written by Save with --serve)")
    k.add_argument("--serve", action="store_true", help="link by clicking in a local page "
                   "(needs --camera and --markers)")
    k.add_argument("--save-links", metavar="LINKS.csv", help="with --serve: the linking CSV "
                   "id,candidate that Save writes (read by pose --links and track --link)")
    k.add_argument("--pose", metavar="CAMERA.json", help="with --serve: the solved camera "
                   "that Save writes")
    k.add_argument("--diameter", type=float, help="with --serve: marker diameter in pixels "
                   "for the detection (default: from the marker file and the camera's pose; "
                   "needed when the camera has none); give pose/track the same value")
    k.add_argument("--polarity", choices=("dark", "bright"), default="dark",
                   help="with --serve: markers darker (default) or brighter than the model")
    k.add_argument("--mesh", help="with --serve: model surface; targets it hides are not "
                   "predicted")
    add_mesh_format(k)
    k.add_argument("--port", type=int, default=0, help="with --serve: port (default: a free "
                   "one)")
    k.add_argument("--open", action="store_true", help="with --serve: open the page in the "
                   "default browser")
    add_acceptance_options(k)
    k.set_defaults(func=run_link)

    m = sub.add_parser(
        "match", help="link candidates to markers automatically",
        description="Match candidates to markers (statistical method: triples, transform, "
        "count, verify by a pose solve); refuses with the reason when the answer is not "
        "certain.")
    m.add_argument("--candidates", required=True, help="candidate CSV")
    m.add_argument("--markers", required=True, help="marker CSV id,x,y,z[,diameter]")
    m.add_argument("--camera", help="approximate camera JSON (reference, and intrinsics for "
                   "the pose verification)")
    m.add_argument("--reference", help="matched candidate CSV of an earlier frame (id,u,v,...)")
    m.add_argument("--search-radius", type=float, default=25.0,
                   help="largest marker motion from the reference, px (default 25)")
    m.add_argument("--tolerance", type=float, default=3.0,
                   help="landing distance on a candidate, px (default 3)")
    add_acceptance_options(m)
    m.add_argument("--out", "-o", required=True, help="output matched candidate CSV (with id)")
    m.add_argument("--pose", help="also write the solved camera JSON here")
    m.set_defaults(func=run_match)


def run_detect(args: argparse.Namespace) -> int:
    from resection.markers.detect import write_candidates
    from resection.markers.from_image import detect_in_image

    cand = detect_in_image(args.image, args.diameter, args.polarity, args.template, args.roi,
                           args.threshold, enhance=args.enhance,
                           enhance_windows=args.enhance_window)
    atomic_write(args.out, write_candidates, cand)
    print(f"detect: {len(cand)} candidates (noise {cand.noise:.3g}, threshold "
          f"{cand.threshold:.3g}, {cand.n_masked} masked pixels, rejected "
          + ", ".join(f"{k} {v}" for k, v in cand.n_rejected.items()) + ")")
    print(f"candidates written to {args.out}")
    return 0


def run_link(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera
    from resection.io.images import read_image
    from resection.io.markers import read_markers
    from resection.markers.detect import read_candidates, write_candidates
    from resection.markers.link import draw_links, read_links, suggest_links, write_links

    if args.serve:
        return run_link_serve(args)
    if args.save_links or args.pose:
        raise InputError("--save-links and --pose go with --serve")
    if not args.candidates:
        raise InputError("give --candidates (the candidate CSV from 'resection detect'), "
                         "or --serve to link by clicking")
    cand, _ = read_candidates(args.candidates)
    camera = read_camera(args.camera) if args.camera else None
    markers = read_markers(args.markers) if args.markers else None
    if (camera is None) != (markers is None) and (args.png or args.suggest):
        raise InputError("--camera and --markers go together (to draw or suggest links)")
    if not (args.png or args.suggest or args.links):
        raise InputError("nothing to do: give --png, --suggest and/or --links")
    if camera is not None and markers is not None and (args.png or args.suggest):
        from resection.io.cameras import read_camera_file
        from resection.pose.pose_needed import has_usable_pose, no_pose_message

        if not has_usable_pose(camera, markers.xyz, read_camera_file(args.camera).has_pose):
            if args.suggest:
                raise InputError(no_pose_message(
                    "intrinsics only", camera=args.camera, image=args.image,
                    markers=args.markers, what="no links can be suggested from it"))
            print(f"link: {args.camera} has no pose: the PNG numbers the likely candidates, "
                  "no projected markers (or link by clicking: resection link --serve)")
            camera = None
        atomic_write(args.png, draw_links, read_image(args.image, mask_saturated=True), cand,
                     camera=camera, markers=markers)
        print(f"drawing written to {args.png}")
    if args.suggest:
        if camera is None:
            raise InputError("--suggest needs --camera and --markers")
        ids, index = suggest_links(cand, camera, markers)
        atomic_write(args.suggest, write_links, ids, index)
        print(f"{len(ids)} suggested links written to {args.suggest}")
    if args.links:
        if not args.out:
            raise InputError("--links needs --out for the linked candidates")
        ids, _, index = read_links(args.links, cand, markers)
        labels = [None] * len(cand)
        for k, i in zip(ids, index, strict=True):
            labels[int(i)] = k
        atomic_write(args.out, write_candidates, cand, ids=labels)
        print(f"link: {len(ids)} markers linked, {len(cand) - len(ids)} candidates thrown "
              f"away; written to {args.out}")
    return 0


def run_link_serve(args: argparse.Namespace) -> int:
    from resection.markers.link_server import LinkServer
    from resection.markers.link_session import open_session

    if not (args.camera and args.markers):
        raise InputError("--serve needs --camera (intrinsics at least) and --markers")
    if args.png or args.suggest:
        raise InputError("--png and --suggest do not go with --serve")
    if not (args.save_links or args.pose or args.out):
        raise InputError("--serve: name what Save writes: --save-links LINKS.csv and/or "
                         "--pose CAMERA.json (and --out LINKED.csv)")
    session = open_session(args.image, args.markers, args.camera, mesh=args.mesh,
                           mesh_format=args.mesh_format, candidates=args.candidates,
                           links=args.links, diameter=args.diameter, polarity=args.polarity,
                           save_links=args.save_links, save_camera=args.pose,
                           save_linked=args.out, marker_accuracy=args.marker_accuracy,
                           max_rms=args.max_rms)
    server = LinkServer(session, args.port)
    d = session.diameter
    print(f"link: {len(session.candidates)} candidates"
          + (f" (diameter {d:g} px: give pose and track --diameter {d:g})"
             if math.isfinite(d) else "") + f", {len(session.markers.ids)} targets; camera "
          + ("with an approximate pose" if session.has_pose else "without a pose"))
    print(f"open {server.url}", flush=True)
    print("(Save and quit on the page, or Ctrl+C, stops the server)", flush=True)
    if server.run(open_browser=args.open):
        print("link: saved; server stopped")
    return 0


def run_match(args: argparse.Namespace) -> int:
    from resection.io.cameras import read_camera, write_camera
    from resection.io.markers import read_markers
    from resection.markers.detect import read_candidates, write_candidates
    from resection.markers.match import match_markers

    cand, _ = read_candidates(args.candidates)
    markers = read_markers(args.markers)
    camera = read_camera(args.camera) if args.camera else None
    if args.reference:
        rc, rids = read_candidates(args.reference)
        if rids is None:
            raise InputError(f"{args.reference}: no 'id' column (not a matched file)")
        reference = (tuple(rids), rc.uv)
    elif camera is not None:
        reference = camera
    else:
        raise InputError("give --camera (approximate camera) and/or --reference (earlier "
                         "matched frame)")
    res = match_markers(cand, markers, reference, camera=camera,
                        search_radius=args.search_radius, tolerance=args.tolerance,
                        max_rms=args.max_rms, marker_accuracy=args.marker_accuracy)
    atomic_write(args.out, write_candidates, cand, ids=list(res.ids))
    print(f"match: {res.message}")
    if res.pose is not None:
        errs = np.hypot(res.residuals[:, 0], res.residuals[:, 1])
        print(f"{'id':>12} {'error':>9}")
        for k, e in zip(res.marker_ids, errs, strict=True):
            print(f"{k:>12} {e:9.4f}")
        if args.pose:
            atomic_write(args.pose, write_camera, res.pose.camera)
            print(f"camera written to {args.pose}")
    elif args.pose:
        raise InputError("--pose needs --camera")
    print(f"matched candidates written to {args.out}")
    return 0
