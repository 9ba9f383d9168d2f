"""Command line of ``selfillum``: parses arguments and calls the library, nothing else.

Sub-commands: ``corner`` (the corner case end to end), ``correct`` (correct a camera
image of a painted model), ``render`` (Mitsuba render, :mod:`selfillum.cli.render`).
Errors on bad input are printed as one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import gc
import sys
from contextlib import contextmanager

from resection.cli.paths import FolderOutput
from resection.cli.util import OneLineParser, add_camera_check_options, add_mesh_format, run
from resection.defaults import DEFAULT_MAX_OBLIQUENESS
from resection.errors import InputError


def _cmd_corner(args) -> int:
    from pathlib import Path

    from selfillum.corner import run_corner, write_corner

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"--out: {out} exists and is not a folder")
    rays = {} if args.rays is None else {"rays_per_face": args.rays}
    result = run_corner(
        resolution=args.resolution,
        **rays,
        reflectance=args.reflectance,
        pattern=args.pattern,
        seed=args.seed,
        reference=args.reference,
        symmetry=not args.no_symmetry,
        progress=not args.quiet,
    )
    paths = write_corner(result, args.out)
    n = result.numbers
    print(f"faces                          {n.faces}")
    ref = ("closed-form kernel, no rays" if n.reference == "exact"
           else f"{n.reference_rays_per_face} rays per face")
    avg = ", averaged over the corner's symmetries" if n.symmetry else ""
    print(f"rays per face                  {n.rays_per_face}{avg} (measurement simulated: "
          f"{ref})")
    print(f"reflectance                    {n.reflectance:g}")
    print(f"largest self-illumination      {100 * n.max_si_fraction:.1f} % of the signal")
    print(
        f"largest residual, corrected    {100 * n.max_residual_fraction:.2f} % "
        f"(rms {100 * n.rms_residual_fraction:.2f} %)"
    )
    print(f"time                           {n.seconds['total']:.1f} s")
    for kind in ("png", "csv", "json"):
        print(f"wrote {paths[kind]}")
    return 0


def _cmd_correct(args) -> int:
    with _no_collections():  # the imports allocate many objects and leave no garbage
        from resection.saturation import report
        from selfillum.images.image_correction import correct_image_file
        from selfillum.summary import summarize

    result = correct_image_file(
        args.mesh,
        args.camera,
        args.image,
        args.reflectance,
        args.out,
        rays_per_face=args.rays,
        seed=args.seed,
        mode=args.mode,
        surface_out=args.surface,
        unseen=args.unseen,
        unpainted=args.unpainted,
        max_obliqueness=args.max_obliqueness,
        progress=not args.quiet,
        mesh_format=args.mesh_format,
        dtype=args.dtype,
        markers=args.markers,
        polarity=args.polarity,
        saturation=args.saturation,
    )
    s = summarize(result)
    seen = s.seen_min if s.seen_min == s.seen_max else f"{s.seen_min} to {s.seen_max}"
    p, u = s.si_percentiles, s.unseen_part_percentiles
    print(f"unseen faces emit              {s.assumption}")
    print(f"faces seen                     {seen} of {s.faces} ({s.grazing} beyond "
          f"{args.max_obliqueness:g} deg count as unseen)")
    print(f"unseen faces in the solve      {s.coupled} (coupled to the seen ones)")
    print(f"self-illumination, seen faces  median {100 * p['50']:.1f} %, 95th "
          f"{100 * p['95']:.1f} %, 99th {100 * p['99']:.1f} % of the signal")
    print(f"  of it from unseen faces      median {100 * u['50']:.1f} %, 95th "
          f"{100 * u['95']:.1f} %, 99th {100 * u['99']:.1f} % of the signal")
    frames = f" at most ({len(result.info)} frames)" if isinstance(result.info, tuple) else ""
    print(f"inverse                        {s.method}, {s.iterations} iterations{frames}")
    for w in s.warnings:
        print(f"warning: {w}", file=sys.stderr)
    line = report(result.saturated, result.saturation, result.saturated_faces)
    if line:
        print(f"warning: {line}", file=sys.stderr)
    print(f"wrote {args.out}")
    print(f"wrote {args.out}.json")
    if args.surface:
        print(f"wrote {args.surface}")
    return 0


@contextmanager
def _no_collections():
    """Python's cyclic garbage collector off inside (imports: about 15 % of their time
    goes to collections that find nothing), back as it was after."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _positive(kind):
    def parse(text):
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a {kind.__name__}: {text!r}") from None
        if v <= 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return v

    return parse


def _obliqueness(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 < v <= 90.0:
        raise argparse.ArgumentTypeError(f"must be in (0, 90] degrees, got {text}")
    return v


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="selfillum",
        description="Self-illumination of painted wind-tunnel models: view factors, "
        "Lambertian forward model and correction.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    p = sub.add_parser(
        "corner",
        help="the corner case: two plates at 90 degrees, SI and its correction",
        description="Two painted plates at 90 degrees: view factors by Embree ray casting, "
        "simulated self-illumination, correction; writes corner_profile.png, "
        "corner_profile.csv and corner_numbers.json to OUT.",
    )
    p.add_argument("--out", required=True, help="output folder (created if needed)")
    p.add_argument(
        "--resolution",
        type=_positive(int),
        default=40,
        help="squares along each plate side (default 40: 6400 triangles)",
    )
    p.add_argument(
        "--rays",
        type=_positive(int),
        default=None,
        help="rays per face for the working view factors (default 1024: averaged over the "
        "corner's symmetries, largest residual after correction about 0.2 %%)",
    )
    p.add_argument(
        "--no-symmetry",
        action="store_true",
        help="use the ray-cast factors as they are, not averaged over the corner's "
        "symmetries (a general model has none; 4096 rays then leave about 0.2 %%)",
    )
    p.add_argument(
        "--reference",
        choices=("exact", "rays"),
        default="exact",
        help="how the measurement is simulated: 'exact' (default) converged form factors "
        "from the closed-form point-to-triangle kernel; 'rays' ray-cast factors with 4x "
        "the rays and another seed",
    )
    p.add_argument(
        "--reflectance",
        type=float,
        default=0.6,
        help="paint reflectance in [0, 1) (default 0.6: about 30%% SI)",
    )
    p.add_argument(
        "--pattern",
        choices=("smooth", "uniform"),
        default="smooth",
        help="true emission field (default smooth)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_corner, out_folder=FolderOutput(
        ("corner_profile.png", "corner_profile.csv", "corner_numbers.json"),
        "corner_numbers.json", "selfillum corner"))

    p = sub.add_parser(
        "correct",
        help="correct a camera image of a painted model for self-illumination",
        description="Map the image onto the model's faces, remove self-illumination "
        "(Lambertian, view factors by Embree ray casting) and write the corrected image: "
        "same shape, float32 for an 8-bit image (else its own pixel type; --dtype to "
        "choose), pixels off the model unchanged. The image is assumed "
        "proportional to radiance (dark level subtracted).",
    )
    p.add_argument(
        "--mesh",
        required=True,
        help="model surface (STL, OBJ, PLY, ..., Plot3D, "
        "Cart3D .tri); normals point to the painted side",
    )
    add_mesh_format(p)
    p.add_argument("--camera", required=True, help="camera JSON (resection.Camera)")
    p.add_argument("--image", required=True, help="image to correct (.tif, .tiff, .png, .npy)")
    p.add_argument(
        "--reflectance",
        required=True,
        help="paint reflectance: a number in [0, 1) or a per-face .npy/.csv file",
    )
    p.add_argument("--out", required=True, help="corrected image (.tif, .tiff, .npy, .png)")
    p.add_argument("--dtype", choices=("float32", "uint16", "uint8"), default=None,
                   help="pixel type of the corrected image (default: float32 for an 8-bit "
                   "image, whose correction is often under one count, else the input's "
                   "type; PNG: integers only)")
    p.add_argument(
        "--mode",
        choices=("subtract", "ratio"),
        default="subtract",
        help="subtract the interpolated self-illumination (default) or "
        "multiply by the interpolated E/B ratio",
    )
    p.add_argument(
        "--rays",
        type=_positive(int),
        default=256,
        help="rays per face for the view factors (default 256)",
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument(
        "--surface",
        default=None,
        help="also write per-face radiosity/emission/seen/unseen_share (.ply, .vtk, .csv)",
    )
    p.add_argument(
        "--unseen",
        default="continue",
        metavar="continue|none|FILE",
        help="what faces the camera does not see emit: the smoothest continuation of "
        "the seen emission (default), nothing, or per-face values (.npy/.csv)",
    )
    p.add_argument(
        "--unpainted",
        default=None,
        metavar="FILE|BLOCKS",
        help="faces that emit nothing, seen or not: a per-face 0/1 file (.npy/.csv, 1 = "
        "unpainted) or Plot3D block numbers counted from 1 (e.g. 7-11)",
    )
    p.add_argument(
        "--max-obliqueness",
        type=_obliqueness,
        default=DEFAULT_MAX_OBLIQUENESS,
        metavar="DEG",
        help="faces seen more obliquely than this (degrees from the normal) count as "
        "unseen (default 70)",
    )
    add_camera_check_options(p)
    p.add_argument("--saturation", type=float, default=None, metavar="LEVEL",
                   help="pixels at or above this are saturated: unknown, left as they are "
                   "and their faces unseen (default: the image type's full scale, 255 or "
                   "65535; none for float images)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_correct)
    from selfillum.cli import entry, psp, render, thermal, unsteady

    render.register(sub)
    psp.register(sub)
    unsteady.register(sub)
    thermal.register(sub)
    entry.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command of ``argv`` (default: the process's arguments); the exit status.

    Called without ``argv`` (the console script, ``python -m selfillum.cli``) the process
    ends right after: the objects left are frozen out of the collector
    (:func:`gc.freeze`), so that the interpreter's exit does not walk them all again
    (0.2-0.3 s after ``correct`` on a 600,000-face grid), and Ctrl-C is caught from the
    start (:func:`resection.cli.interrupts.install`). Called with ``argv`` (in a process
    that goes on) nothing is frozen."""
    if argv is None:
        from resection.cli.interrupts import done, install

        install()
    try:
        status = run(build_parser(), argv)
    except KeyboardInterrupt:  # while the parser is built (its imports) or parses
        print("selfillum: interrupted", file=sys.stderr)
        status = 130
    if argv is None:
        done()  # the status is decided: a Ctrl-C while the interpreter ends is ignored
        gc.freeze()
    return status


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
