"""``--uncertainty`` on ``selfillum psp`` and ``selfillum unsteady``: the shared options,
and ``psp``'s run with its budget. Only parses and calls :mod:`selfillum.uncertainty`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["add_uncertainty_options", "psp_with_uncertainty", "uncertainty_settings"]


def add_uncertainty_options(p) -> None:
    """``--uncertainty [linear|mc]``, ``--samples N``, ``--u KEY=VALUE``."""
    p.add_argument("--uncertainty", nargs="?", const="linear", choices=("linear", "mc"),
                   help="standard uncertainty (k = 1) of every value, source by source: "
                   "linear propagation (default) or mc, the GUM S1 Monte Carlo through the "
                   "whole chain (docs/uncertainty.md)")
    p.add_argument("--samples", type=int, default=200,
                   help="Monte Carlo draws (per source, and all together; default 200)")
    p.add_argument("--u", action="append", metavar="KEY=VALUE", default=[],
                   help="a stated uncertainty with its unit, e.g. camera_gain=4e/count, "
                   "read_noise=10e, marker=0.04px, reflectance=0.02, unseen=50%%, taps=0.2psf, "
                   "paint_temperature=1%%/K, temperature=0.3K, t0=1K, tinf=1K, q=2psf, "
                   "p_inf=2psf, gain_a=0.01 .. gain_f; repeat")


def uncertainty_settings(args):
    """The stated uncertainties and the method, checked (one-line errors)."""
    from selfillum.uncertainty.stated import parse_stated

    stated = parse_stated(args.u)
    if args.uncertainty is None and args.u:
        raise InputError("--u given without --uncertainty")
    if args.uncertainty == "mc" and not args.samples >= 2:
        raise InputError(f"--samples {args.samples}: the Monte Carlo needs at least 2")
    return stated


def psp_with_uncertainty(args, stated) -> int:
    from resection.io.cameras import read_camera
    from resection.io.images import write_image
    from resection.io.markers import read_markers
    from resection.io.meshes import load_mesh
    from resection.io.outputs import atomic_write, output_folder
    from resection.io.wtd import is_wtd, read_wtd
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster
    from selfillum.cli.surfaces import surface_paths
    from selfillum.images.image_correction import read_reflectance
    from selfillum.images.psp import read_taps
    from selfillum.surface_fields import write_mesh_fields
    from selfillum.transport.viewfactors import view_factors
    from selfillum.uncertainty.psp_chain import PSPInputs
    from selfillum.uncertainty.psp_io import (
        face_columns,
        node_columns,
        read_condition,
        write_uncertainty,
    )
    from selfillum.uncertainty.psp_run import noise_models, psp_uncertainty

    cams = args.camera
    if not args.wind_on:
        raise InputError(f"give one wind-on image per camera ({len(cams)} cameras, 0 "
                         "wind-on images)")
    off, noff, voff = read_condition(args.wind_off, len(cams), "--wind-off")
    on, non, von = read_condition(args.wind_on, len(cams), "--wind-on")
    mesh = load_mesh(args.mesh, format=args.mesh_format)
    surfaces = surface_paths(args, mesh)
    taps = read_taps(args.taps, positions=args.tap_positions)
    tunnel = None
    if is_wtd(args.taps):
        w = read_wtd(args.taps)
        tunnel = (w.value("PS"), w.value("Q"), np.array(list(w.taps.values()), np.float64))
    markers = read_markers(args.markers).xyz if args.markers else None
    caster = RayCaster(mesh)
    maps = [SurfaceMap(mesh, read_camera(c), caster=caster) for c in cams]
    F = rho = None
    if not args.no_correction:
        rho = read_reflectance(args.reflectance, len(mesh.faces))
        F = view_factors(mesh, rays_per_face=args.rays, seed=args.seed,
                         progress=not args.quiet, caster=caster)
    inp = PSPInputs(mesh, maps, off, on, noff, non, taps, args.p_ref, F, rho, args.rays,
                    args.seed, tunnel, markers, caster)
    noise = noise_models(stated, len(cams), voff, von, off, on)
    state, budgets = psp_uncertainty(inp, stated, method=args.uncertainty,
                                     samples=args.samples, noise=noise, seed=args.seed)
    res = state.result
    law = res.stern_volmer
    info = {"written_by": "selfillum psp", "A": law.A, "B": law.B, "p_ref": law.p_ref,
            "si_corrected": res.corrected,
            "taps": {tid: {"face": int(f), "residual": float(r)} for tid, f, r in
                     zip(taps.ids, res.tap_faces, res.tap_residuals, strict=True)}}
    with output_folder(args.out) as out:
        for k, m in enumerate(maps):
            atomic_write(out / f"pressure_{k}.tif", write_image,
                         m.to_image(res.pressure).astype(np.float32))
        written = write_uncertainty(out, mesh, maps, state, budgets,
                                    stated, atomic_write, plots=not args.no_plots)
        atomic_write(out / "stern_volmer.json", Path.write_text,
                     json.dumps(info, indent=2) + "\n")
    if surfaces:
        cols = face_columns(state, budgets)
        cols.pop("face")
        nodes = node_columns(mesh, cols)
        for p in surfaces:
            write_mesh_fields(p, mesh, cols, nodes)
    q = "cp" if "cp" in budgets else "p"
    b = budgets[q]
    fin = b.combined[np.isfinite(b.combined)]
    print(f"Stern-Volmer   I_ref/I = {law.A:.4f} + {law.B:.4f} p/p_ref (p_ref {law.p_ref:g})")
    print(f"uncertainty    {b.method}: {q}_u median {np.median(fin):.4g}, 95th percentile "
          f"{np.percentile(fin, 95):.4g} (k = 1)")
    for src, st in b.status.items():
        print(f"  {src:13s}{st}")
    if "tap_scatter_ratio" in b.info:
        print(f"taps           scatter / stated sources: {b.info['tap_scatter_ratio']:.3g}")
    print(f"wrote {out}/pressure_*.tif, {', '.join(written)}, stern_volmer.json"
          + "".join(f", {p}" for p in surfaces))
    return 0
