"""``selfillum psp``: pressure from wind-off / wind-on PSP images, SI removed first.

Only parses arguments, reads the inputs, calls :func:`selfillum.images.psp.psp_images` and writes
the results.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from resection.cli.paths import FolderOutput
from resection.cli.util import add_mesh_format
from resection.errors import InputError
from selfillum.cli.surfaces import surface_paths, write_surfaces
from selfillum.cli.uncertainty import add_uncertainty_options, uncertainty_settings


def _cmd_psp(args) -> int:
    from resection.io.cameras import read_camera
    from resection.io.images import write_image
    from resection.io.meshes import load_mesh
    from resection.io.outputs import atomic_write, output_folder
    from resection.surface.surface_map import SurfaceMap
    from selfillum.cli.render import per_face_arg
    from selfillum.images.psp import check_fit_inputs, psp_images, read_taps
    from selfillum.transport.viewfactors import view_factors
    from selfillum.uncertainty.psp_io import read_condition

    stated = uncertainty_settings(args)  # --u checked, also without --uncertainty
    if args.uncertainty is not None:
        from selfillum.cli.uncertainty import psp_with_uncertainty

        return psp_with_uncertainty(args, stated)
    cams, offs, ons = args.camera, args.wind_off, args.wind_on or []
    # one image (or stack, or k files) per camera: several frames are averaged
    if not offs or len(offs) % len(cams):
        raise InputError(f"give one wind-off image per camera ({len(cams)} cameras, "
                         f"{len(offs)} wind-off images)")
    if not ons or len(ons) % len(cams):
        raise InputError(f"give one wind-on image per camera ({len(cams)} cameras, "
                         f"{len(ons)} wind-on images)")
    mesh = load_mesh(args.mesh, format=args.mesh_format)
    surfaces = surface_paths(args, mesh)
    taps = read_taps(args.taps, positions=args.tap_positions)
    check_fit_inputs(taps, args.p_ref, args.taps)  # before the maps and the view factors
    maps = [SurfaceMap(mesh, read_camera(c)) for c in cams]
    off_imgs = read_condition(offs, len(cams), "--wind-off")[0]
    on_imgs = read_condition(ons, len(cams), "--wind-on")[0]
    F = rho = None
    if not args.no_correction:
        rho = per_face_arg(args.reflectance, "--reflectance")
        F = view_factors(mesh, rays_per_face=args.rays, seed=args.seed,
                         progress=not args.quiet)
    res, images = psp_images(maps, off_imgs, on_imgs, taps, args.p_ref, F=F,
                             reflectance=rho, correct_si=not args.no_correction)
    law = res.stern_volmer
    info = {
        "written_by": "selfillum psp",
        "A": law.A, "B": law.B, "p_ref": law.p_ref, "si_corrected": res.corrected,
        "taps": {tid: {"face": int(f), "residual": float(r)}
                 for tid, f, r in zip(taps.ids, res.tap_faces, res.tap_residuals,
                                      strict=True)},
    }
    table = np.column_stack([np.arange(len(res.pressure)), res.pressure, res.ratio])
    # the folder exists only once there is something to write (removed if writing fails)
    with output_folder(args.out) as out:
        for k, img in enumerate(images):
            atomic_write(out / f"pressure_{k}.tif", write_image, img.astype(np.float32))
        atomic_write(out / "pressure_faces.csv", np.savetxt, table, fmt=["%d", "%.9g", "%.9g"],
                     delimiter=",", header="face,pressure,ratio", comments="")
        atomic_write(out / "stern_volmer.json", Path.write_text,
                     json.dumps(info, indent=2) + "\n")
    write_surfaces(surfaces, mesh, {"pressure": res.pressure, "ratio": res.ratio})
    rms = float(np.sqrt(np.nanmean(res.tap_residuals**2)))
    print(f"Stern-Volmer   I_ref/I = {law.A:.4f} + {law.B:.4f} p/p_ref (p_ref {law.p_ref:g})")
    print(f"taps           {len(taps.ids)}, rms residual {rms:.4g}")
    print(f"SI corrected   {'yes' if res.corrected else 'no'}")
    print(f"wrote {out}/pressure_*.tif, pressure_faces.csv, stern_volmer.json"
          + "".join(f", {p}" for p in surfaces))
    return 0


def register(sub) -> None:
    """Add the ``psp`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    p = sub.add_parser(
        "psp",
        help="pressure from wind-off/wind-on PSP images (Stern-Volmer on taps, SI removed)",
        description="Map wind-off and wind-on images of one or several cameras onto the "
        "model, remove the self-illumination from both, fit I_ref/I = A + B p/p_ref on the "
        "pressure taps and write the pressure per face and per camera image.",
    )
    p.add_argument("--mesh", required=True, help="model surface (STL, OBJ, PLY, Plot3D, ...)")
    add_mesh_format(p)
    p.add_argument("--camera", required=True, action="append",
                   help="camera JSON file; repeat for several cameras")
    p.add_argument("--wind-off", required=True, action="append",
                   help="wind-off image (uniform p_ref), one per camera, in camera order; a "
                   "multi-page TIFF or NPY stack, or k files per camera (camera by camera), "
                   "is averaged")
    p.add_argument("--wind-on", action="append",
                   help="wind-on image, one per camera (stacks as --wind-off)")
    p.add_argument("--taps", required=True, help="pressure taps CSV: id,x,y,z,p, or id,p with "
                   "--tap-positions; or a uPSP RUN.wtd (its '# Tap CP' table, p = PS + Cp Q, "
                   "tap n = the .tgts point CPnn) with --tap-positions")
    p.add_argument("--tap-positions", metavar="MODEL.tgts",
                   help="tap positions for an id,p tap file: a uPSP .tgts file (its Taps section) "
                   "or a marker file")
    p.add_argument("--p-ref", required=True, type=float, help="pressure of the wind-off run")
    p.add_argument("--reflectance", default="0.6",
                   help="paint reflectance: a number or a per-face file (default 0.6)")
    p.add_argument("--rays", type=int, default=1024,
                   help="rays per face for the view factors (default 1024)")
    p.add_argument("--seed", type=int, default=0, help="view-factor seed (default 0)")
    p.add_argument("--no-correction", action="store_true",
                   help="do not remove the self-illumination (for comparison)")
    p.add_argument("--out", required=True, help="output folder (created if needed)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_uncertainty_options(p)
    p.add_argument("--surface", action="append", metavar="FILE",
                   help="also write the per-face results and their node values on the model: "
                   ".vtu, .vtk, .xdmf, .ply, .csv, or a Plot3D function file .f (node values, "
                   "a Plot3D --mesh); with --uncertainty, cp_u / p_u and each source's part "
                   "too; repeat for several files")
    p.add_argument("--no-plots", action="store_true",
                   help="with --uncertainty: no picture of the uncertainty nor budget chart")
    p.add_argument("--markers", metavar="FILE",
                   help="marker positions (a .tgts or marker file) for the poses' covariance "
                   "(--uncertainty, with --u marker=..px)")
    p.set_defaults(func=_cmd_psp, out_folder=FolderOutput(
        ("pressure_*.tif", "pressure_faces.csv", "stern_volmer.json", "pressure_nodes.csv",
         "uncertainty.json", "p_u.png", "cp_u.png", "budget.png"), "stern_volmer.json",
        "selfillum psp"))
