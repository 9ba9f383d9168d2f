"""The whole thermal run in one call, :func:`run_thermal`: inputs read and checked, Phase 1
(the unsteady run's: frames onto nodes with each frame's tracked pose, markers patched,
cameras combined, the model's own reflected light removed; committed to the work folder
``OUT.h5.work`` block by block, kept by an interrupted run for ``resume``), Phase 2 (signal
to temperature, heat flux, Stanton number; blocks of nodes), the output file with its XDMF
and pictures. Memory is bounded by the blocks' sizes
(:func:`selfillum.unsteady.budget.plan_blocks`); outputs are written to temporary names and
renamed when the run has succeeded."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.thermal.config import ThermalConfig, ThermalResult

__all__ = ["run_thermal"]


def _read_inputs(cfg: ThermalConfig):
    """Everything the run reads, checked, before any heavy step."""
    from resection.io.cameras import read_camera
    from resection.io.markers import read_markers
    from resection.io.wtd import read_wtd
    from selfillum.thermal.heatflux import METHODS, read_substrate
    from selfillum.thermal.radiometry import read_radiometry
    from selfillum.thermal.stanton import FlowReference
    from selfillum.thermal.tsp import read_tsp_calibration
    from selfillum.unsteady.conditions import RECOVERY_FACTOR, Conditions
    from selfillum.unsteady.grid import load_run_grid
    from selfillum.unsteady.spots import DarkSpots

    cfg.check()
    out = Path(cfg.out)
    if not out.parent.is_dir():
        raise InputError(f"{out}: output folder {out.parent} does not exist")
    sub = read_substrate(cfg.substrate)
    method = cfg.method or ("cook-felderman" if sub.semi_infinite else "impulse")
    if method not in METHODS:
        raise InputError(f"--method {method!r} unknown (one of {', '.join(METHODS)})")
    if method == "cook-felderman" and not sub.semi_infinite:
        raise InputError(f"{cfg.substrate}: Cook-Felderman needs one semi-infinite "
                         "material; layers or a finite base take --method impulse")
    rad = read_radiometry(cfg.radiometry) if cfg.mode == "ir" else None
    cal = read_tsp_calibration(cfg.tsp_calibration) if cfg.mode == "tsp" else None
    flow = None
    if cfg.sds is not None:
        cond = Conditions.from_wtd(read_wtd(cfg.sds), tinf=cfg.tinf)
        flow = FlowReference.from_conditions(cond, cfg.recovery_factor or RECOVERY_FACTOR)
    grid = load_run_grid(cfg.grid)
    spots = None
    if cfg.targets is not None:
        spots = DarkSpots.from_markers(read_markers(cfg.targets, include_taps=True),
                                       str(cfg.targets))
    bad = [n for n in cfg.probes if not 0 <= int(n) < grid.n_nodes]
    if bad:
        raise InputError(f"--probe {bad[0]}: the grid has nodes 0..{grid.n_nodes - 1}")
    cams = [read_camera(c.calibration) for c in cfg.cameras]
    return out, sub, method, rad, cal, flow, grid, spots, cams


def run_thermal(cfg: ThermalConfig) -> ThermalResult:
    """Run the thermal job (module notes); see ``docs/thermal.md``."""
    early = _start_tracking(cfg)
    try:
        return _run(cfg, early)
    finally:
        if early is not None:
            early.close()


#: free cores (this process's included, by the 1-minute load average) from which the
#: markers are tracked in a child process beside the run's set-up: on a machine whose
#: cores are busy, the child's own start and imports (about 1.5 s of CPU) cost more than
#: the overlap gains, and on two free cores it gained nothing either (the paper's
#: 500-frame run: 53.1-55.7 frames/s with it, 52.9-55.1 without, about 1 s more CPU), so
#: it needs more than two
EARLY_TRACKING_CORES = 2.5


def _start_tracking(cfg: ThermalConfig):
    """The markers' tracking started in a child process
    (:class:`selfillum.thermal.early.EarlyTracking`) before the rest of the inputs are
    read, for a fresh run that tracks them, where a core is free for it
    (:data:`EARLY_TRACKING_CORES`); None otherwise (a resumed run, given tracks, no
    tracking, busy cores, or options the run will refuse: the run then tracks in its own
    process, or names the problem)."""
    from resection.sequence.load import free_by_load_average
    from selfillum.unsteady.work import work_folder

    out = Path(cfg.out)
    if (cfg.registration != "track" or cfg.track_dirs is not None or cfg.targets is None
            or cfg.resume or not out.parent.is_dir() or out.exists()
            or work_folder(out).exists() or free_by_load_average() < EARLY_TRACKING_CORES):
        return None
    try:
        cfg.check()
    except InputError:
        return None
    from selfillum.thermal.early import EarlyTracking

    try:
        return EarlyTracking(out, cfg.cameras, cfg.targets, cfg.polarity)
    except OSError:  # no child (no process or folder to be had): tracked in the run
        return None


def _run(cfg: ThermalConfig, early) -> ThermalResult:
    """:func:`run_thermal`, the tracking started early or None."""
    import h5py

    from resection.io.outputs import atomic_path
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster
    from selfillum.images.image_correction import read_reflectance
    from selfillum.thermal.balance import NodeGeometry, camera_centres
    from selfillum.thermal.inputs import SignalFrames, check_range, track_poses
    from selfillum.thermal.output import FORMAT, VERSION, write_xdmf
    from selfillum.thermal.phase2 import BYTES_PER_CELL, run_phase2
    from selfillum.thermal.reflections import HeatingSelfIllumination
    from selfillum.unsteady.blocks import local_phase1
    from selfillum.unsteady.budget import PHASE2_BYTES_PER_CELL, Progress, plan_blocks
    from selfillum.unsteady.config import check_options
    from selfillum.unsteady.inputs import open_videos, work_inputs
    from selfillum.unsteady.output import chunk_shape, json_attr, provenance
    from selfillum.unsteady.phase1 import CameraRun, SelfIllumination
    from selfillum.unsteady.work import Phase1Store

    out, sub, method, rad, cal, flow, grid, spots, cams = _read_inputs(cfg)
    p1 = cfg.phase1_config()
    check_options(p1)
    mesh = grid.mesh
    nf = len(mesh.faces)
    # the reflectance of the model's exchange: 1 - the hemispherical emissivity (IR), the
    # paint's (TSP)
    if cfg.mode == "ir":
        rho_h = 1.0 - rad.emissivity.hemispherical()
        rho = np.full(nf, rho_h)
    else:
        rho = read_reflectance(cfg.reflectance, nf)
        rho_h = float(np.mean(rho))
    si_on = cfg.si and bool(np.any(rho > 0))
    srcs, T, fps = open_videos(p1)
    if T < 2:
        raise InputError(f"{cfg.cameras[0].video}: {T} frame; the heat flux needs 2 or more")
    offset = rad.planck.O if rad is not None else 0.0
    offs = None
    for c, cam, s in zip(cfg.cameras, cams, srcs, strict=True):
        if (cam.height, cam.width) != tuple(s.shape):
            raise InputError(f"{c.calibration}: a {cam.width}x{cam.height} camera, its video "
                             f"{c.video} is {s.shape[1]}x{s.shape[0]}")
    if cfg.mode == "tsp":
        from resection.io.images import read_image

        offs = [read_image(p, mask_saturated=True) for p in cfg.wind_off]  # saturated: NaN
        for p, o, s in zip(cfg.wind_off, offs, srcs, strict=True):
            if o.shape != tuple(s.shape):
                raise InputError(f"{p}: wind-off image {o.shape[1]}x{o.shape[0]}, its "
                                 f"camera's video {s.shape[1]}x{s.shape[0]}")
    N = grid.n_nodes
    times = np.arange(T) / fps
    pic_frames = []
    for ts in cfg.picture_times:
        if not 0 <= ts <= times[-1]:
            raise InputError(f"--picture-time {ts} s: the run spans 0..{times[-1]:.6g} s")
        pic_frames.append(int(np.argmin(np.abs(times - ts))))
    stem = out.with_suffix("")
    xdmf = out.with_suffix(".xdmf")
    pngs = [Path(f"{stem}_q_{times[k]:.3f}s.png") for k in pic_frames] if cfg.plots else []
    probe_png = Path(f"{stem}_probes.png") if cfg.plots and cfg.probes else None
    files = [out, xdmf, *pngs] + ([probe_png] if probe_png else [])
    for p in files:
        if p.exists():
            raise InputError(f"{p}: exists; remove it or choose another --out")
    caster = RayCaster(mesh)
    if rad is not None and rad.planck.t_range is not None:  # counts on the model, checked
        lo, hi = rad.planck.signal_range()
        for c, cam, s in zip(cfg.cameras, cams, srcs, strict=True):
            mask = SurfaceMap(mesh, cam, max_obliqueness=cfg.oblique_angle,
                              caster=caster).mask
            check_range(s, c.video, mask, lo, hi, sorted({0, T - 1}))
    tc, nc = chunk_shape(T, N)
    plan = plan_blocks(T, N, (tc, nc), cfg.memory_mb)
    t0 = time.perf_counter()
    F = None
    si_note = "" if si_on else ("--no-si" if not cfg.si else "reflectance 0")
    if si_on:  # the view factors first: a model none of whose faces sees another (a
        # convex body) has no light of its own to remove, and Phase 1 then stores one
        # signal, not two
        F = _form_factors(out, cfg, mesh, caster)
        if F.nnz == 0:
            si_on, F, si_note = False, None, "no face sees another"
    p1.si = si_on
    inputs = work_inputs(p1, T, N, fps)
    inputs.update(thermal_mode=cfg.mode, signal_offset=offset, polarity=cfg.polarity,
                  reflectance_h=rho_h, si_refresh=cfg.si_refresh)
    store = Phase1Store(out, inputs, (T, N), (tc, nc), len(cfg.cameras), resume=cfg.resume,
                        with_raw=si_on)
    done = store.frames_done
    prog = Progress(T, N, enabled=cfg.progress, start=done)
    finished = False
    frames_in = [SignalFrames(s, offset, float(2 ** s.bits - 1) if s.bits else None)
                 for s in srcs]
    failed = 0
    try:
        runs = []
        tracked = early.adopt(store.folder) if early is not None and early.wait() else {}
        for c, cam, fr in zip(cfg.cameras, cams, frames_in, strict=True):
            poses = None
            if cfg.registration == "track":
                poses, nf_ = track_poses(cfg, c, cam, T, store.folder, resume=store.resumed,
                                         track_dir=tracked.get(c.number))
                failed += nf_
            runs.append(CameraRun(c.number, cam, fr, poses))
        si = None
        if si_on:
            store.form_factors(lambda: F)  # kept for a resume
            si = HeatingSelfIllumination(mesh, F, rho, refresh=cfg.si_refresh)
        off_nodes = None
        if offs is not None:  # the wind-off images onto the nodes, SI removed as wind-on
            from selfillum.unsteady.phase1 import map_run

            si_off = SelfIllumination(mesh, F, rho) if si_on else None  # one image
            fn = next(map_run(grid, [CameraRun(c.number, cam, [o]) for c, cam, o in
                                     zip(cfg.cameras, cams, offs, strict=True)], [0],
                              spots=spots, registration="none", patcher=cfg.target_patcher,
                              overlap=cfg.overlap, max_obliqueness=cfg.oblique_angle,
                              si=si_off, fast=False, caster=caster))
            off_nodes = np.asarray(fn.values, np.float64)
        R, t = store.poses()
        t1 = time.perf_counter()
        todo = np.arange(T)[done:] if done == 0 else np.concatenate([[0],
                                                                    np.arange(T)[done:]])
        counts: dict = {}  # the frames mapped each way, kept in the file's options
        local_phase1(p1, grid, runs, todo, spots, si, None, store, R, t, done,
                     plan.frames_per_block, T, N, prog, caster=caster, counts=counts)
        caster = None
        store.close()
        t2 = time.perf_counter()
        geom = NodeGeometry.from_grid(grid, F)
        # Phase 2's blocks within the budget at this phase's cost a cell (the unsteady
        # plan counts its own, smaller one)
        nb = plan.nodes_per_block * PHASE2_BYTES_PER_CELL // BYTES_PER_CELL
        nb = max(1, nb // nc * nc if nb >= nc else nb)
        with h5py.File(store.path, "r") as s1, contextlib.ExitStack() as stack:
            R, t = s1["R"][()], s1["t"][()]
            tmp = [stack.enter_context(atomic_path(p)) for p in files]
            with h5py.File(tmp[0], "w") as f:
                _write_head(f, grid, times, runs, cfg, R, t)
                for name in ("temperature", "heat_flux") + (
                        ("heat_transfer_coefficient", "stanton") if flow else ()):
                    f.create_dataset(name, (T, N), "f4", chunks=(tc, nc), fillvalue=np.nan)
                p2 = run_phase2(s1, f, mode=cfg.mode, rad=rad, cal=cal, off=off_nodes,
                                rho_h=rho_h, geom=geom, centres=camera_centres(R, t),
                                sub=sub, method=method, dt=1.0 / fps, flow=flow, block=nb,
                                probes=cfg.probes, progress=prog.nodes,
                                max_obliqueness=cfg.oblique_angle)
                prog.close()
                if not p2["seen"].any():  # never an empty result
                    raise InputError(f"{cfg.grid}: no node has a temperature in any frame "
                                     "(do the grid's faces point out of the model, and the "
                                     "cameras at it?)")
                sat = int(sum(fr.saturated for fr in frames_in))
                g = f.create_group("probes")
                g.create_dataset("nodes", data=np.asarray(cfg.probes, np.int64))
                g.create_dataset("temperature", data=p2["probe_T"].astype(np.float32))
                g.create_dataset("heat_flux", data=p2["probe_q"].astype(np.float32))
                f.attrs.update(format=FORMAT, version=VERSION, mode=cfg.mode, method=method,
                               saturated_pixels=sat, out_of_range=p2["out_of_range"],
                               tracked_failed=failed, fps=fps)
                f.attrs["substrate"] = json_attr({"base": vars(sub.base),
                                                  "layers": [vars(x) for x in sub.layers]})
                if rad is not None:
                    f.attrs["radiometry"] = json_attr({
                        **rad.planck.to_dict(), "emissivity": vars(rad.emissivity),
                        "hemispherical_emissivity": 1.0 - rho_h,
                        "reflected_temperature": rad.reflected_temperature})
                if cal is not None:
                    f.attrs["tsp_calibration"] = json_attr(vars(cal))
                if flow is not None:
                    f.attrs["flow"] = json_attr(flow.to_dict())
                f.attrs["options"] = json_attr({
                    "registration": cfg.registration, "target_patcher": cfg.target_patcher,
                    "overlap": cfg.overlap, "oblique_angle": cfg.oblique_angle,
                    "si": si_on, "si_off_because": si_note, "rays": cfg.rays,
                    "seed": cfg.seed,
                    "si_refresh": cfg.si_refresh,
                    "si_solves": si.solves if si is not None else 0,
                    "phase1_frames": counts,
                    "polarity": cfg.polarity, "chunks": [tc, nc]})
                f.attrs["provenance"] = json_attr(provenance({
                    "grid": cfg.grid, "targets": cfg.targets, "substrate": cfg.substrate,
                    "radiometry": cfg.radiometry, "tsp_calibration": cfg.tsp_calibration,
                    "wind_off": cfg.wind_off, "sds": cfg.sds,
                    "videos": [c.video for c in cfg.cameras],
                    "calibrations": [c.calibration for c in cfg.cameras],
                    "reflectance": cfg.reflectance
                    if os.path.isfile(str(cfg.reflectance)) else None}))
                write_xdmf(tmp[1], out.name, T, N, len(grid.triangles), times,
                           ("temperature", "heat_flux")
                           + (("heat_transfer_coefficient", "stanton") if flow else ()))
                if pngs or probe_png:
                    from selfillum.thermal.output import plot_heat_flux, plot_probes

                    for k, p in zip(pic_frames, tmp[2:2 + len(pngs)], strict=True):
                        plot_heat_flux(grid, f["heat_flux"][k], times[k], p)
                    if probe_png:
                        plot_probes(times, p2["probe_T"], p2["probe_q"], cfg.probes,
                                    grid.points, tmp[-1])
        finished = True
    except InputError:
        finished = True
        raise
    finally:
        for s in srcs:
            with contextlib.suppress(Exception):
                s.close()
        if finished:
            store.remove()
        else:
            store.close()
    el = time.perf_counter() - t0
    return ThermalResult(out, T, N, float(p2["seen"].mean()), failed, sat,
                         p2["out_of_range"], tuple(files), T / el if el > 0 else float("nan"),
                         method, {"setup": t1 - t0, "phase1": t2 - t1,
                                  "phase2": time.perf_counter() - t2})


def _form_factors(out, cfg, mesh, caster):
    """The view factors: those an interrupted run of ``out`` kept (``--resume``), else
    computed (Embree, ``cfg.rays`` a face)."""
    import scipy.sparse as sp

    from selfillum.transport.viewfactors import view_factors
    from selfillum.unsteady.work import work_folder

    kept = work_folder(out) / "F.npz"
    if cfg.resume and kept.exists():
        return sp.csr_matrix(sp.load_npz(kept))
    return sp.csr_matrix(view_factors(mesh, rays_per_face=cfg.rays, seed=cfg.seed,
                                      progress=cfg.progress, caster=caster))


def _write_head(f, grid, times, runs, cfg, R, t) -> None:
    """The grid, the frames' times and the cameras (as the unsteady run's file)."""
    g = f.create_group("grid")
    g.create_dataset("points", data=grid.points)
    g.create_dataset("triangles", data=grid.triangles)
    g.create_dataset("block_dims", data=np.asarray(grid.dims, np.int64).reshape(-1, 3))
    fr = f.create_group("frames")
    fr.create_dataset("time", data=times)
    fr.create_dataset("index", data=np.arange(len(times), dtype=np.int64))
    cg = f.create_group("cameras")
    for ci, r in enumerate(runs):  # a few cameras
        c = cg.create_group(f"cam{r.number:02d}")
        c.attrs.update(width=r.camera.width, height=r.camera.height, number=r.number,
                       video=str(cfg.cameras[ci].video))
        c.create_dataset("K", data=r.camera.K)
        c.create_dataset("dist", data=r.camera.dist)
        c.create_dataset("R", data=R[ci])
        c.create_dataset("t", data=t[ci])
