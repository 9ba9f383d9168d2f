"""The whole unsteady run: inputs checked, Phase 1 (frames onto nodes), Phase 2 (dCp), the
output file, in one call: :func:`run_unsteady`.

Nothing is written before every input has been read and checked; the outputs are written
to temporary names and renamed only when the run has succeeded (a failed run leaves
nothing, not half a file). Phase 1 commits its node intensities in blocks of frames to the
work folder ``OUT.h5.work`` (:mod:`selfillum.unsteady.work`: journaled, kept by an
interrupted run for ``--resume``, removed when the run succeeds); Phase 2 reads them back in
blocks of nodes. The blocks' sizes come from the memory budget
(:func:`selfillum.unsteady.budget.plan_blocks`): memory is bounded whatever the length of
the run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.surface_fields import check_surface_paths, write_grid_fields
from selfillum.unsteady.blocks import cluster_phase1, local_phase1
from selfillum.unsteady.budget import (
    Progress,
    chunk_column_bytes,
    peak_rss_mb,
    plan_blocks,
)
from selfillum.unsteady.config import (
    CameraInput,
    UnsteadyConfig,
    UnsteadyResult,
    check_options,
    config_from_deck,
)
from selfillum.unsteady.inputs import (
    check_cameras,
    check_spot_sizes,
    min_frames,
    open_videos,
    read_form_factors,
    track_poses,
    tracked_motion,
    work_inputs,
)
from selfillum.unsteady.insitu import insitu_fit, insitu_gain, insitu_inputs
from selfillum.unsteady.output import (
    FLAT_FILES,
    camera_coverage,
    chunk_shape,
    json_attr,
    node_fields,
    surface_fields,
    write_flat,
    write_node_files,
    write_xdmf,
    writing,
)
from selfillum.unsteady.phase1 import CameraRun, SelfIllumination
from selfillum.unsteady.phase2 import DETREND_ORDER, node_gain
from selfillum.unsteady.plots import write_pictures
from selfillum.unsteady.results import write_results
from selfillum.unsteady.spectra import Spectra, default_bands
from selfillum.unsteady.tracking import TrackingAhead
from selfillum.unsteady.tracking_process import TrackingProcess, can_start
from selfillum.unsteady.uncertainty_out import wind_off_noise
from selfillum.unsteady.work import Phase1Store, work_folder

__all__ = ["CameraInput", "UnsteadyConfig", "UnsteadyResult", "run_unsteady",
           "config_from_deck"]


def run_unsteady(cfg: UnsteadyConfig) -> UnsteadyResult:
    """Run Phase 1 and Phase 2 and write the output (see the module notes).

    A moving model tracked here (``registration = track``, no ``--track`` folders, no
    cluster) is tracked in a child process started first, beside the reading of the
    inputs (:mod:`selfillum.unsteady.tracking_process`)."""
    check_options(cfg)
    out = Path(cfg.out)
    if not out.parent.is_dir():
        raise InputError(f"{out}: output folder {out.parent} does not exist")
    proc = None
    if _tracked_here(cfg) and can_start() and not (cfg.resume and work_folder(out).exists()):
        proc = TrackingProcess(cfg)  # a fresh run: into a temporary folder
    try:
        return _run(cfg, out, proc)
    finally:
        if proc is not None:  # ended before its work folder was open: nothing kept
            proc.close()


def _tracked_here(cfg: UnsteadyConfig) -> bool:
    """Whether the run tracks its moving model itself, in this machine."""
    return (cfg.registration == "track" and cfg.track_dirs is None
            and not (cfg.workers or cfg.scheduler))


def _run(cfg: UnsteadyConfig, out: Path, proc) -> UnsteadyResult:
    import h5py

    from resection.io.cameras import read_camera_file
    from resection.io.guarded import guarded_h5
    from resection.io.markers import read_markers
    from resection.io.outputs import atomic_path
    from resection.io.upsp_inputs import read_paint_calibration
    from resection.io.wtd import read_wtd
    from resection.surface.visibility import RayCaster
    from selfillum.images.image_correction import read_reflectance
    from selfillum.solve.unseen import read_unpainted
    from selfillum.unsteady.conditions import Conditions
    from selfillum.unsteady.grid import load_run_grid, nondata_nodes, read_steady_cp
    from selfillum.unsteady.spots import DarkSpots

    # ---------------------------------------------------------------- inputs, all checked
    grid = load_run_grid(cfg.grid)
    nondata = nondata_nodes(grid, cfg.cutoff_x_max, f"{cfg.source}: cutoff_x_max")
    if cfg.steady is None:
        raise InputError("no steady Cp: give --steady STEADY.f")
    cp = read_steady_cp(cfg.steady, grid)
    wtd = read_wtd(cfg.sds)
    cond = Conditions.from_wtd(wtd, tinf=cfg.tinf)
    law = gain = taps = tapn = offs = coeffs = None
    off_noise = wind_off_noise(cfg)  # --uncertainty: the camera noise of wind-off frames
    if cfg.paint_calibration is not None:
        cal = read_paint_calibration(cfg.paint_calibration)
        gain = node_gain(cal, cond.surface_temperature, cp, cond)
        bad = ~np.isfinite(gain)
        if bad.any():
            raise InputError(f"{cfg.paint_calibration}: the gain is not finite at "
                             f"{int(bad.sum())} of {bad.size} nodes (coefficients too large "
                             "for the run's temperature and pressures)")
        coeffs = (cal.a, cal.b, cal.c, cal.d, cal.e, cal.f)
    else:
        taps, tapn, offs = insitu_inputs(cfg, grid)
    spots = None
    if cfg.targets is not None:
        spots = DarkSpots.from_markers(read_markers(cfg.targets, include_taps=True),
                                       str(cfg.targets))
    mesh = grid.mesh
    if spots is not None:
        check_spot_sizes(spots, mesh, cfg.targets)
    unpainted = None
    if cfg.unpainted is not None:
        unpainted, _ = read_unpainted(cfg.unpainted, mesh)
    rho = read_reflectance(cfg.reflectance, len(mesh.faces)) if cfg.si else None
    F_given = read_form_factors(cfg.form_factors, len(mesh.faces)) \
        if cfg.si and cfg.form_factors is not None else None
    srcs, T, fps = open_videos(cfg, need=min_frames(DETREND_ORDER))
    try:
        camfiles = [read_camera_file(c.calibration, image_size=s.shape[::-1])
                    for c, s in zip(cfg.cameras, srcs, strict=True)]
    except BaseException:
        for s in srcs:
            s.close()
        raise
    cams = [cf.camera for cf in camfiles]
    for k, (c, cam, s) in enumerate(zip(cfg.cameras, cams, srcs, strict=True)):
        if (cam.height, cam.width) != tuple(s.shape):
            raise InputError(f"{c.calibration}: a {cam.width}x{cam.height} camera, its video "
                             f"{c.video} is {s.shape[1]}x{s.shape[0]}")
        if offs is not None and offs[k].shape != tuple(s.shape):
            raise InputError(f"{cfg.wind_off[k]}: wind-off image {offs[k].shape[1]}x"
                             f"{offs[k].shape[0]}, camera {c.number}'s video "
                             f"{s.shape[1]}x{s.shape[0]}")
    flat = [out.parent / name for name in FLAT_FILES] if cfg.upsp_flat else []
    xdmf = out.with_suffix(".xdmf")
    pngs = [out.with_name(out.stem + "_rms.png")] if cfg.plots else []
    if cfg.plots and cfg.psd_probes:
        pngs.append(out.with_name(out.stem + "_psd.png"))
    for p in [out, xdmf, *flat, *pngs]:
        if p.exists():
            raise InputError(f"{p}: exists; remove it or choose another --out")
    surfaces = check_surface_paths(cfg.surface, outputs=[out, xdmf, *flat, *pngs],
                                   inputs=[cfg.grid, cfg.steady, cfg.sds],
                                   plot3d=bool(grid.dims))
    N = grid.n_nodes
    tc, nc = chunk_shape(T, N)
    frames = np.arange(T)
    times = frames / fps
    if cfg.psd_bands is None:  # the default, now that the run's length is known
        cfg = dataclasses.replace(cfg, psd_bands=default_bands(T, cfg.psd_nperseg))
    spectra = Spectra(N, fps, T, probes=cfg.psd_probes, n_bands=cfg.psd_bands,
                      nperseg=cfg.psd_nperseg) if (cfg.psd_probes or cfg.psd_bands) \
        else None
    plan = plan_blocks(T, N, (tc, nc), cfg.memory_mb,
                       node_bytes=spectra.bytes_per_node if spectra is not None else 0)
    local = not (cfg.workers or cfg.scheduler)
    # one Embree scene of the grid for the camera checks, the view factors and this
    # process's maps
    caster = RayCaster(mesh) if cfg.si or local else None
    check_cameras(cfg, camfiles, srcs, mesh, caster=caster)  # map's checks, frame 0
    t_start = time.perf_counter()
    counts: dict = {}  # frames mapped each way in this process (map_run)
    store = Phase1Store(out, work_inputs(cfg, T, N, fps), (T, N), (tc, nc), len(cfg.cameras),
                        resume=cfg.resume, with_raw=cfg.si)
    done = store.frames_done
    prog = Progress(T, N, enabled=cfg.progress, start=done)
    finished = False
    ahead = proc.ahead if proc is not None else None
    stack0 = contextlib.ExitStack()
    try:
        # ------------------------------------------------------------ registration
        runs, failed = [], 0
        if ahead is None and _tracked_here(cfg):
            if can_start():  # a resumed run: into its work folder
                proc = TrackingProcess(cfg, store.folder, resume=store.resumed)
                ahead = proc.ahead
            else:  # a daemonic process (a Dask worker's): in a thread, its fits on one
                ahead = TrackingAhead(lambda i, on_frame: tracked_motion(
                    cfg, cfg.cameras[i], cams[i], T, store.folder, resume=store.resumed,
                    on_frame=on_frame, fit_threads=1), len(cams))
        for i, (c, cam, s) in enumerate(zip(cfg.cameras, cams, srcs, strict=True)):
            poses = None
            if ahead is not None:  # each frame's pose as the tracker solves it
                poses = ahead.poses(i, T, lambda m, cam=cam: cam.with_pose(rvec=m[0],
                                                                            t=m[1]))
            elif cfg.registration == "track":
                poses, nf = track_poses(cfg, c, cam, s, T, store.folder, resume=store.resumed)
                failed += nf
            runs.append(CameraRun(c.number, cam, s, poses))
        si = F = None
        if cfg.si:
            from selfillum.transport.coupling import coupled_view_factors
            from selfillum.unsteady.candidates import faces_in_view

            # rows cast from the faces frame 0's cameras may see, and those they light
            cand = faces_in_view(mesh, cams)
            if not cand.any():
                raise InputError(f"{cfg.cameras[0].calibration}: no face of the grid faces a "
                                 "camera within its image (the wrong camera, or units?)")
            F = store.form_factors(lambda: F_given if F_given is not None else
                                   coupled_view_factors(mesh, cand, rays_per_face=cfg.rays,
                                                        seed=cfg.seed, progress=cfg.progress,
                                                        caster=caster)[0],
                                   n_faces=len(mesh.faces))
            si = SelfIllumination(mesh, F, rho, unpainted)
        if not local:
            caster = None  # the workers build their own
        # ------------------------------------------------------------ Phase 1
        R, t = store.poses()
        t_p1 = time.perf_counter()
        # a resumed run maps frame 0 again (its gains, SI and registration references),
        # then the frames not done
        todo = frames[done:] if done == 0 else np.concatenate([[0], frames[done:]])
        fb = plan.frames_per_block
        client = None
        if cfg.workers or cfg.scheduler:
            from selfillum.unsteady.cluster import open_client

            client = stack0.enter_context(open_client(cfg.workers, cfg.scheduler))
            gains0 = cluster_phase1(client, cfg, grid, runs, spots, unpainted, rho, F,
                                     store, R, t, done, fb, T, prog, nondata=nondata)
        else:
            gains0 = local_phase1(cfg, grid, runs, todo, spots, si, unpainted, store, R, t,
                                   done, fb, T, N, prog, caster=caster, counts=counts,
                                   nondata=nondata)
            caster = None
        if ahead is not None:  # its frames that took a neighbour's pose
            failed += ahead.result()[1]
        store.close()
        t_p2 = time.perf_counter()
        view = None  # the RMS picture's view of the model, made beside Phase 2 (its own
        # ray-tracing scene and mesh copy; Phase 2's reads and writes leave a core free)
        if pngs:
            from concurrent.futures import ThreadPoolExecutor

            from selfillum.unsteady.plots import prepare_rms_view

            pool = stack0.enter_context(ThreadPoolExecutor(1, thread_name_prefix="picture"))
            view = pool.submit(prepare_rms_view, grid)
        # a chunk column of each dataset held in HDF5's cache: node blocks narrower than a
        # chunk (a small budget, a long run) then read each chunk once, not once a block
        # (each dataset has its cache; only when the blocks are narrower than a chunk)
        col = chunk_column_bytes(T, (tc, nc)) if plan.nodes_per_block < nc else 0
        with h5py.File(store.path, "r", rdcc_nbytes=col + 2**20, rdcc_nslots=100_003,
                       rdcc_w0=1.0) as s1:
            if gain is None:  # the in-situ fit on the taps
                fit = {}
                law = insitu_fit(cfg, grid, runs, s1, taps, tapn, offs, spots, unpainted,
                                  F, rho, gains0, out=fit)
                coeffs = ("insitu", law, fit["ratio"], taps.pressure)
                gain = insitu_gain(law, cp, cond)
            # -------------------------------------------------------- Phase 2 + output
            files = [out, xdmf, *flat, *pngs]
            with contextlib.ExitStack() as stack:
                tmp = [stack.enter_context(atomic_path(p)) for p in files]
                # a full disk: one OSError naming the file, never HDF5's crash
                named = dict(zip(tmp, files, strict=True))
                with writing(out, named), guarded_h5(tmp[0]) as (f, check):

                    def nodes(done, check=check):
                        check()  # a failed write stops the run within a block
                        prog.nodes(done)

                    stats = write_results(f, cfg, grid, cond, cp, gain, s1, times, frames,
                                          runs, R, t, tc, nc, plan=plan, spectra=spectra,
                                          progress=nodes, client=client,
                                          work=store.path)
                    prog.close()
                    if not stats["seen"] > 0:  # nothing to write: refused, not exit 0
                        raise InputError(f"{out}: no node has a dCp: no node was seen in "
                                         "enough frames (check the videos, the cameras' "
                                         "calibrations and the grid)")
                    if cfg.uncertainty is not None:  # docs/uncertainty.md
                        from selfillum.unsteady.uncertainty_out import write_uncertainty

                        stats["uncertainty"] = write_uncertainty(
                            f, cfg, grid, runs, s1, stats, spectra, fps, frames, gain, cond,
                            cp, coeffs, off_noise, chain={"spots": spots, "F": F, "rho": rho,
                                                          "unpainted": unpainted})
                    if surfaces:
                        fields = {k: f[d][()] for k, d in surface_fields(f)}
                        for p in surfaces:
                            with writing(p):
                                write_grid_fields(p, grid, fields)
                    if law is not None:
                        f.attrs["stern_volmer"] = json_attr(
                            {"A": law.A, "B": law.B, "p_ref": law.p_ref,
                             "taps": list(taps.ids), "tap_nodes": tapn.tolist()})
                    with writing(xdmf, named):
                        write_xdmf(tmp[1], out.name, T, N, len(grid.triangles), times,
                                   extra=node_fields(f))
                    if flat:
                        with writing(flat[0], named):
                            write_flat(f, tmp[2], tmp[3], node_block=plan.nodes_per_block)
                            cover = camera_coverage(grid, [r.camera for r in runs],
                                                    cfg.oblique_angle)
                            if nondata is not None:  # never projected (cutoff_x_max)
                                cover[nondata] = 0
                            write_node_files(f, dict(zip(FLAT_FILES[2:],
                                                         tmp[4:len(flat) + 2], strict=True)),
                                             work=s1, coverage=cover,
                                             node_block=plan.nodes_per_block)
                    if pngs:
                        with writing(pngs[0], named):
                            write_pictures(grid, stats["rms"], spectra, tmp[-len(pngs):],
                                           view=view.result())
        finished = True
    except InputError:
        finished = True  # bad input: nothing to resume, nothing left
        raise
    finally:
        # ended before the tracking (an error, Ctrl-C): stopped at its next frame, before
        # its folder is removed or kept (a fresh run's: kept in the work folder if it is)
        if proc is not None:
            proc.close(keep=None if finished else store.folder)
        elif ahead is not None:
            ahead.stop()
        with contextlib.suppress(Exception):
            stack0.close()  # the Dask client and its cluster
        for s in srcs:
            with contextlib.suppress(Exception):
                s.close()
        if finished:
            store.remove()
        else:  # interrupted or failed: the committed blocks stay for --resume
            store.close()
    t_end = time.perf_counter()
    el = t_end - t_start
    timings = {"setup": t_p1 - t_start, "phase1": t_p2 - t_p1, "phase2": t_end - t_p2,
               "first_frame": (prog.t_first or t_p2) - t_p1, **{
                   f"frames_{k}": v for k, v in counts.items()}}
    return UnsteadyResult(out, T, N, (tc, nc), stats["seen"], stats["si_median"],
                          stats["si_p95"], failed, tuple(files) + tuple(surfaces),
                          peak_rss_mb(),
                          T / el if el > 0 else float("nan"),
                          (plan.frames_per_block, plan.nodes_per_block), timings,
                          stats.get("uncertainty", {}), si=bool(cfg.si))

