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
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.unsteady.blocks import cluster_phase1, local_phase1
from selfillum.unsteady.budget import DEFAULT_MEMORY_MB, Progress, peak_rss_mb, plan_blocks
from selfillum.unsteady.insitu import insitu_gain
from selfillum.unsteady.output import (
    FORMAT,
    VERSION,
    chunk_shape,
    json_attr,
    provenance,
    write_flat,
    write_xdmf,
)
from selfillum.unsteady.phase1 import (
    FILTERS,
    OVERLAPS,
    REGISTRATIONS,
    CameraRun,
    SelfIllumination,
    map_run,
)
from selfillum.unsteady.phase2 import DETREND_ORDER, node_gain, run_phase2
from selfillum.unsteady.spectra import Spectra
from selfillum.unsteady.work import Phase1Store

__all__ = ["CameraInput", "UnsteadyConfig", "UnsteadyResult", "run_unsteady",
           "config_from_deck"]


@dataclass(frozen=True)
class CameraInput:
    """A camera: ``number``, ``video`` (a ``.cine``, ``.mraw``, TIFF/NPY stack) and
    ``calibration`` (its camera file, pose of the first frame relative to the model)."""

    number: int
    video: Path
    calibration: Path


@dataclass
class UnsteadyConfig:
    """Everything a run needs (the command's flags or a uPSP deck, :func:`config_from_deck`).

    ``registration``: ``track`` (each frame's own pose from the project's tracking, or
    ``track_dirs``), ``first-frame`` (uPSP: affine pixel registration onto frame 0, its
    map), ``none`` (a fixed model: frame 0's map). ``number_frames``: -1 for all.
    ``reflectance``: a number or a per-face file. ``si``: remove the self-illumination.
    Without ``paint_calibration``, the gain comes from the in-situ Stern-Volmer fit on the
    ``taps`` (a ``.wtd`` or a tap file, placed by ``tap_positions`` or the targets file)
    with one ``wind_off`` image per camera at pressure ``p_ref`` (psf)
    (:mod:`selfillum.unsteady.insitu`).
    ``psd_probes`` (node numbers), ``psd_bands``, ``psd_nperseg``: Welch spectra
    (:mod:`selfillum.unsteady.spectra`). ``memory_mb``: the budget of the blocks
    (:func:`selfillum.unsteady.budget.plan_blocks`). ``plots``: write the dCp RMS on the
    model and the probes' PSD as PNG next to the output. ``fast``: Phase 1 by sparse
    products after the first frame (:mod:`selfillum.unsteady.fastmap`); False maps every
    frame the full way (a ray cast a frame). ``workers`` / ``scheduler``: Phase 1 and
    Phase 2 on Dask (:mod:`selfillum.unsteady.cluster`).
    """

    grid: Path
    sds: Path
    cameras: list
    out: Path
    paint_calibration: Path | None = None
    steady: Path | None = None
    targets: Path | None = None
    registration: str = "track"
    target_patcher: str = "none"
    overlap: str = "merge"
    filter: str = "none"
    filter_size: int = 3
    oblique_angle: float = 70.0
    number_frames: int = -1
    si: bool = True
    reflectance: object = 0.6
    unpainted: object = None
    rays: int = 1024
    seed: int = 0
    fps: float | None = None
    tinf: float | None = None
    upsp_flat: bool = False
    track_dirs: list | None = None
    taps: Path | None = None
    tap_positions: Path | None = None
    wind_off: list | None = None
    p_ref: float | None = None
    progress: bool = False
    psd_probes: list = field(default_factory=list)
    psd_bands: int = 8
    psd_nperseg: int | None = None
    memory_mb: float | None = DEFAULT_MEMORY_MB
    plots: bool = True
    resume: bool = False
    fast: bool = True
    workers: int | None = None
    scheduler: str | None = None
    general: dict = field(default_factory=dict)
    source: str = "flags"


@dataclass(frozen=True)
class UnsteadyResult:
    """What a run did: ``out`` (the HDF5 file), ``n_frames``, ``n_nodes``, ``chunks``,
    ``seen`` (share of nodes with a dCp), ``si_change_median`` / ``si_change_p95`` (over
    the seen nodes, of the RMS over time of the change of dCp by the SI removal; NaN
    without SI), ``tracked_failed`` (frames whose pose was taken from the nearest good
    frame), ``files`` (everything written), ``peak_rss_mb`` (the process's peak resident
    memory, MiB), ``frames_per_s`` (frames over the whole run's time), ``blocks``
    (frames per Phase 1 block, nodes per Phase 2 block), ``timings`` (seconds: ``setup``
    = inputs, tracking, form factors; ``phase1``, of which ``first_frame`` (its maps and
    the self-illumination's frame-0 solve); ``phase2`` = Phase 2 and the outputs)."""

    out: Path
    n_frames: int
    n_nodes: int
    chunks: tuple
    seen: float
    si_change_median: float
    si_change_p95: float
    tracked_failed: int
    files: tuple
    peak_rss_mb: float = float("nan")
    frames_per_s: float = float("nan")
    blocks: tuple = ()
    timings: dict = field(default_factory=dict)


_DECK_REGISTRATION = {"pixel": "first-frame", "none": "none", "track": "track",
                      "first-frame": "first-frame"}


def config_from_deck(deck, **overrides) -> UnsteadyConfig:
    """An :class:`UnsteadyConfig` from a :class:`resection.io.upsp_inputs.Deck`; the
    ``@options`` are honoured or refused by name; ``overrides`` (not None) win."""
    where = f"{deck.path}: @options"
    opts = dict(deck.options)
    kw: dict = {}
    if "target_patcher" in opts:
        kw["target_patcher"] = opts["target_patcher"]
    if "registration" in opts:
        r = opts["registration"]
        if r not in _DECK_REGISTRATION:
            raise InputError(f"{where} registration = {r}: unknown (pixel, none, track)")
        kw["registration"] = _DECK_REGISTRATION[r]
    if opts.get("pixel_interpolation", "linear") != "linear":
        raise InputError(f"{where} pixel_interpolation = {opts['pixel_interpolation']}: "
                         "only linear is supported")
    if "overlap" in opts:
        kw["overlap"] = opts["overlap"]
    if "filter" in opts:
        kw["filter"] = opts["filter"]
    for key, conv in (("filter_size", int), ("oblique_angle", float), ("number_frames", int)):
        if key in opts:
            try:
                kw[key] = conv(opts[key])
            except ValueError:
                raise InputError(f"{where} {key} = {opts[key]}: not a number") from None
    kw.update({k: v for k, v in overrides.items() if v is not None})
    cams = [CameraInput(c.number, c.video, c.calibration) for c in deck.cameras]
    tg = {c.targets for c in deck.cameras if c.targets is not None}
    if len(tg) > 1:
        raise InputError(f"{deck.path}: cameras name different targets files; one .tgts "
                         "for the model")
    targets = tg.pop() if tg else deck.targets
    out = kw.pop("out", None)
    if out is None:
        raise InputError(f"{deck.path}: give --out OUT.h5")
    return UnsteadyConfig(grid=deck.grid, sds=deck.sds, cameras=cams, targets=targets,
                          out=Path(out), general=dict(deck.general), source=str(deck.path),
                          **kw)


def _check_options(cfg: UnsteadyConfig) -> None:
    where = cfg.source
    if cfg.registration not in REGISTRATIONS:
        raise InputError(f"{where}: registration {cfg.registration!r} unknown (one of "
                         f"{', '.join(REGISTRATIONS)})")
    if cfg.target_patcher not in ("none", "polynomial"):
        raise InputError(f"{where}: target_patcher {cfg.target_patcher!r} unknown (none, "
                         "polynomial)")
    if cfg.overlap not in OVERLAPS:
        raise InputError(f"{where}: overlap {cfg.overlap!r} unknown (one of "
                         f"{', '.join(OVERLAPS)})")
    if cfg.filter not in FILTERS:
        raise InputError(f"{where}: filter {cfg.filter!r} unknown (none, gaussian)")
    if cfg.filter == "gaussian" and (cfg.filter_size < 3 or cfg.filter_size % 2 == 0):
        raise InputError(f"{where}: filter_size {cfg.filter_size} must be odd and >= 3")
    if not 0 < cfg.oblique_angle <= 90:
        raise InputError(f"{where}: oblique_angle {cfg.oblique_angle} must be in (0, 90]")
    if cfg.number_frames == 0 or cfg.number_frames < -1:
        raise InputError(f"{where}: number_frames {cfg.number_frames} must be -1 (all) or > 0")
    if not cfg.cameras:
        raise InputError(f"{where}: no camera")
    if cfg.out.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(f"{cfg.out}: the output is an HDF5 file (.h5)")


def _open_videos(cfg: UnsteadyConfig):
    from resection.io.video import open_frames

    srcs = [open_frames(c.video) for c in cfg.cameras]
    n = [len(s) for s in srcs]
    where = cfg.source
    if cfg.number_frames == -1:
        if len(set(n)) > 1:
            lens = ", ".join(f"{c.video.name}: {k}" for c, k in
                             zip(cfg.cameras, n, strict=True))
            raise InputError(f"{where}: number_frames = -1 but the videos differ in length "
                             f"({lens} frames)")
        T = n[0]
    else:
        T = cfg.number_frames
        short = [(c, k) for c, k in zip(cfg.cameras, n, strict=True) if k < T]
        if short:
            c, k = short[0]
            raise InputError(f"{where}: number_frames = {T} but {c.video} has {k} frames")
    rates = [s.frame_rate for s in srcs]
    known = {float(r) for r in rates if r}
    if len(known) > 1:
        rl = ", ".join(f"{c.video.name}: {r} fps" for c, r in
                       zip(cfg.cameras, rates, strict=True))
        raise InputError(f"{where}: the videos differ in frame rate ({rl})")
    fps = cfg.fps if cfg.fps is not None else (known.pop() if known else None)
    if fps is None:
        raise InputError(f"{cfg.cameras[0].video}: no frame rate in the video; give --fps")
    if not fps > 0:
        raise InputError(f"--fps must be positive, got {fps}")
    return srcs, T, float(fps)


def _track(cfg, cam_in, camera, src, T, tmp: Path, *, resume: bool = False):
    """Each frame's camera from the project's tracking (or a given track folder)."""
    from resection.io.markers import read_markers
    from resection.sequence import read_track, track

    if cfg.track_dirs is not None:
        tr = read_track(cfg.track_dirs[cfg.cameras.index(cam_in)])
    else:
        if cfg.targets is None:
            raise InputError(f"{cfg.source}: registration 'track' needs the targets (.tgts)")
        ms = read_markers(cfg.targets)
        z = camera.to_camera_frame(ms.xyz)[:, 2]
        f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
        dpx = float(np.median(ms.diameter * f / z[z > 0])) if ms.diameter is not None \
            else 5.0
        tr = track(str(cam_in.video), camera, ms, diameter=dpx,
                   out_dir=tmp / f"track{cam_in.number}", workers=1, progress=cfg.progress,
                   resume=resume)
    ok = np.flatnonzero(tr.status == "ok")
    frame_ok = tr.frame[ok]
    if frame_ok.size == 0:
        raise InputError(f"{cam_in.video}: tracking found the pose in no frame")
    poses, failed = [], 0
    for k in range(T):  # per frame: pick the pose of the nearest tracked frame
        j = int(np.argmin(np.abs(frame_ok - k)))
        failed += int(frame_ok[j] != k)
        poses.append(camera.with_pose(rvec=tr.rvec[ok[j]], t=tr.tvec[ok[j]]))
    return poses, failed


def run_unsteady(cfg: UnsteadyConfig) -> UnsteadyResult:
    """Run Phase 1 and Phase 2 and write the output (see the module notes)."""
    import h5py

    from resection.io.cameras import read_camera
    from resection.io.markers import read_markers
    from resection.io.outputs import atomic_path
    from resection.io.upsp_inputs import read_paint_calibration
    from resection.io.wtd import read_wtd
    from selfillum.images.image_correction import read_reflectance
    from selfillum.solve.unseen import read_unpainted
    from selfillum.unsteady.conditions import Conditions
    from selfillum.unsteady.grid import load_run_grid, read_steady_cp
    from selfillum.unsteady.spots import DarkSpots

    _check_options(cfg)
    out = Path(cfg.out)
    if not out.parent.is_dir():
        raise InputError(f"{out}: output folder {out.parent} does not exist")
    # ---------------------------------------------------------------- inputs, all checked
    grid = load_run_grid(cfg.grid)
    if cfg.steady is None:
        raise InputError("no steady Cp: give --steady STEADY.f")
    cp = read_steady_cp(cfg.steady, grid)
    wtd = read_wtd(cfg.sds)
    cond = Conditions.from_wtd(wtd, tinf=cfg.tinf)
    law = gain = taps = tapn = offs = None
    if cfg.paint_calibration is not None:
        cal = read_paint_calibration(cfg.paint_calibration)
        gain = node_gain(cal, cond.surface_temperature, cp, cond)
    else:
        taps, tapn, offs = _insitu_inputs(cfg, grid)
    spots = None
    if cfg.targets is not None:
        spots = DarkSpots.from_markers(read_markers(cfg.targets, include_taps=True),
                                       str(cfg.targets))
    mesh = grid.mesh
    unpainted = None
    if cfg.unpainted is not None:
        unpainted, _ = read_unpainted(cfg.unpainted, mesh)
    rho = read_reflectance(cfg.reflectance, len(mesh.faces)) if cfg.si else None
    cams = [read_camera(c.calibration) for c in cfg.cameras]
    srcs, T, fps = _open_videos(cfg)
    for k, (c, cam, s) in enumerate(zip(cfg.cameras, cams, srcs, strict=True)):
        if (cam.height, cam.width) != tuple(s.shape):
            raise InputError(f"{c.calibration}: a {cam.width}x{cam.height} camera, its video "
                             f"{c.video} is {s.shape[1]}x{s.shape[0]}")
        if offs is not None and offs[k].shape != tuple(s.shape):
            raise InputError(f"{cfg.wind_off[k]}: wind-off image {offs[k].shape[1]}x"
                             f"{offs[k].shape[0]}, camera {c.number}'s video "
                             f"{s.shape[1]}x{s.shape[0]}")
    flat = [out.parent / "pressure", out.parent / "pressure_transpose"] if cfg.upsp_flat \
        else []
    xdmf = out.with_suffix(".xdmf")
    pngs = [out.with_name(out.stem + "_rms.png")] if cfg.plots else []
    if cfg.plots and cfg.psd_probes:
        pngs.append(out.with_name(out.stem + "_psd.png"))
    for p in [out, xdmf, *flat, *pngs]:
        if p.exists():
            raise InputError(f"{p}: exists; remove it or choose another --out")
    N = grid.n_nodes
    tc, nc = chunk_shape(T, N)
    plan = plan_blocks(T, N, (tc, nc), cfg.memory_mb)
    frames = np.arange(T)
    times = frames / fps
    spectra = Spectra(N, fps, T, probes=cfg.psd_probes, n_bands=cfg.psd_bands,
                      nperseg=cfg.psd_nperseg) if (cfg.psd_probes or cfg.psd_bands) \
        else None
    t_start = time.perf_counter()
    store = Phase1Store(out, _work_inputs(cfg, T, N, fps), (T, N), (tc, nc), len(cfg.cameras),
                        resume=cfg.resume)
    done = store.frames_done
    prog = Progress(T, N, enabled=cfg.progress, start=done)
    finished = False
    stack0 = contextlib.ExitStack()
    try:
        # ------------------------------------------------------------ registration
        runs, failed = [], 0
        for c, cam, s in zip(cfg.cameras, cams, srcs, strict=True):
            poses = None
            if cfg.registration == "track":
                poses, nf = _track(cfg, c, cam, s, T, store.folder, resume=store.resumed)
                failed += nf
            runs.append(CameraRun(c.number, cam, s, poses))
        si = F = None
        if cfg.si:
            from selfillum.transport.viewfactors import view_factors

            F = store.form_factors(lambda: view_factors(
                mesh, rays_per_face=cfg.rays, seed=cfg.seed, progress=cfg.progress))
            si = SelfIllumination(mesh, F, rho, unpainted)
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
                                     store, R, t, done, fb, T, prog)
        else:
            gains0 = local_phase1(cfg, grid, runs, todo, spots, si, unpainted, store, R, t,
                                   done, fb, T, N, prog)
        store.close()
        t_p2 = time.perf_counter()
        # a chunk column of each dataset held in HDF5's cache: node blocks narrower than a
        # chunk (a small budget, a long run) then read each chunk once, not once a block
        # (each dataset has its cache; only when the blocks are narrower than a chunk)
        col = (T // tc + 1) * tc * nc * 4 if plan.nodes_per_block < nc else 0
        with h5py.File(store.path, "r", rdcc_nbytes=col + 2**20, rdcc_nslots=100_003,
                       rdcc_w0=1.0) as s1:
            vals, raw = s1["values"], s1["raw"]
            if gain is None:  # the in-situ fit on the taps
                law = _insitu_fit(cfg, grid, runs, vals, taps, tapn, offs, spots, unpainted,
                                  F, rho, gains0)
                gain = insitu_gain(law, cp, cond)
            # -------------------------------------------------------- Phase 2 + output
            files = [out, xdmf, *flat, *pngs]
            with contextlib.ExitStack() as stack:
                tmp = [stack.enter_context(atomic_path(p)) for p in files]
                with h5py.File(tmp[0], "w") as f:
                    stats = _write_run(f, cfg, grid, cond, cp, gain, vals, raw, times, frames,
                                       runs, R, t, tc, nc, si is not None, plan=plan,
                                       spectra=spectra, progress=prog.nodes,
                                       client=client, work=store.path)
                    prog.close()
                    if law is not None:
                        f.attrs["stern_volmer"] = json_attr(
                            {"A": law.A, "B": law.B, "p_ref": law.p_ref,
                             "taps": list(taps.ids), "tap_nodes": tapn.tolist()})
                    write_xdmf(tmp[1], out.name, T, N, len(grid.triangles), times)
                    if flat:
                        write_flat(f, tmp[2], tmp[3], node_block=plan.nodes_per_block)
                    if pngs:
                        _pictures(grid, stats["rms"], spectra, tmp[-len(pngs):])
        finished = True
    except InputError:
        finished = True  # bad input: nothing to resume, nothing left
        raise
    finally:
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
               "first_frame": (prog.t_first or t_p2) - t_p1}
    return UnsteadyResult(out, T, N, (tc, nc), stats["seen"], stats["si_median"],
                          stats["si_p95"], failed, tuple(files), peak_rss_mb(),
                          T / el if el > 0 else float("nan"),
                          (plan.frames_per_block, plan.nodes_per_block), timings)


def _work_inputs(cfg: UnsteadyConfig, T: int, N: int, fps: float) -> dict:
    """What Phase 1's numbers depend on: a resumed run with anything else is refused."""
    return {"files": provenance({
                "grid": cfg.grid, "targets": cfg.targets,
                "videos": [c.video for c in cfg.cameras],
                "calibrations": [c.calibration for c in cfg.cameras],
                "reflectance": cfg.reflectance if os.path.isfile(str(cfg.reflectance))
                else None,
                "unpainted": cfg.unpainted if os.path.isfile(str(cfg.unpainted)) else None,
                "track": cfg.track_dirs}),
            "registration": cfg.registration, "target_patcher": cfg.target_patcher,
            "overlap": cfg.overlap, "filter": cfg.filter, "filter_size": cfg.filter_size,
            "oblique_angle": cfg.oblique_angle, "frames": T, "nodes": N, "fps": fps,
            "si": cfg.si, "reflectance": str(cfg.reflectance),
            "unpainted": str(cfg.unpainted), "rays": cfg.rays, "seed": cfg.seed}


def _pictures(grid, rms, spectra, paths) -> None:
    """The dCp RMS on the model and, with probes, their PSD (PNG)."""
    from selfillum.unsteady.plots import plot_psd, plot_rms

    plot_rms(grid, rms, paths[0])
    if len(paths) > 1:
        plot_psd(spectra.freq, spectra.probe_psd, spectra.probes, paths[1],
                 mean_psd=spectra.mean_psd, points=grid.points)


def _insitu_inputs(cfg, grid):
    """Taps, their grid nodes and the wind-off images, checked (no paint calibration)."""
    from resection.io.images import read_image
    from selfillum.images.psp import read_taps
    from selfillum.unsteady.insitu import tap_nodes

    if cfg.taps is None:
        raise InputError("no paint calibration: give --paint-calibration CAL.txt (uPSP's a..f "
                         "gain file), or --taps with --wind-off and --p-ref for the in-situ "
                         "Stern-Volmer fit")
    if not cfg.wind_off or len(cfg.wind_off) != len(cfg.cameras):
        n = len(cfg.wind_off or [])
        raise InputError(f"--taps: the in-situ fit needs one --wind-off image per camera "
                         f"({len(cfg.cameras)} cameras, {n} images)")
    if cfg.p_ref is None or not cfg.p_ref > 0:
        raise InputError("--taps: the in-situ fit needs --p-ref (the wind-off pressure, psf)")
    positions = cfg.tap_positions if cfg.tap_positions is not None else cfg.targets
    taps = read_taps(cfg.taps, positions=positions)
    nodes = tap_nodes(grid, taps.points, taps.ids, str(cfg.taps))
    offs = [np.asarray(read_image(p), dtype=np.float64) for p in cfg.wind_off]
    return taps, nodes, offs


def _insitu_fit(cfg, grid, runs, vals, taps, nodes, offs, spots, unpainted, F, rho, gains):
    """Stern-Volmer ``A, B`` from the wind-off / time-mean intensity ratio at the taps."""
    from selfillum.images.psp import fit_stern_volmer

    order, inverse = np.unique(nodes, return_inverse=True)  # h5py reads sorted columns
    with _quiet():
        on = np.nanmean(vals[:, order], axis=0)[inverse]
    off_runs = [CameraRun(r.number, r.camera, [img]) for r, img in zip(runs, offs,
                                                                         strict=True)]
    si = SelfIllumination(grid.mesh, F, rho, unpainted) if F is not None else None
    fn = next(map_run(grid, off_runs, [0], spots=spots, registration="none",
                      patcher=cfg.target_patcher, overlap=cfg.overlap, filter=cfg.filter,
                      filter_size=cfg.filter_size, max_obliqueness=cfg.oblique_angle, si=si,
                      unpainted=unpainted, gains=gains if cfg.overlap == "merge" else None))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = fn.values[nodes] / on
    try:
        return fit_stern_volmer(ratio, taps.pressure, cfg.p_ref)
    except InputError as e:
        raise InputError(f"{cfg.taps}: {e}") from None


def _write_run(f, cfg, grid, cond, cp, gain, vals, raw, times, frames, runs, R, t, tc, nc,
               with_si: bool, *, plan=None, spectra=None, progress=None, client=None,
               work=None) -> dict:
    T, N = vals.shape
    f.attrs["format"] = FORMAT
    f.attrs["version"] = VERSION
    g = f.create_group("grid")
    g.create_dataset("points", data=grid.points)
    g.create_dataset("triangles", data=grid.triangles)
    g.create_dataset("block_dims", data=np.asarray(grid.dims, np.int64))
    fr = f.create_group("frames")
    fr.create_dataset("time", data=times)
    fr.create_dataset("index", data=frames.astype(np.int64))
    cg = f.create_group("cameras")
    for ci, r in enumerate(runs):
        c = cg.create_group(f"cam{r.number:02d}")
        c.attrs.update(width=r.camera.width, height=r.camera.height, number=r.number,
                       video=str(cfg.cameras[ci].video))
        c.create_dataset("K", data=r.camera.K)
        c.create_dataset("dist", data=r.camera.dist)
        c.create_dataset("R", data=R[ci])
        c.create_dataset("t", data=t[ci])
    st = f.create_group("steady")
    st.create_dataset("cp", data=cp)
    st.create_dataset("gain", data=gain)
    dcp = f.create_dataset("dcp", (T, N), "f4", chunks=(tc, nc), fillvalue=np.nan)
    if spectra is not None and spectra.n_bands:
        spectra.band = f.create_dataset("psd/band_psd", (N, spectra.n_bands), "f4",
                                        fillvalue=np.nan)
    if client is None:
        p2 = run_phase2(vals, dcp, frames, gain, cond.q, raw=raw if with_si else None,
                        block=plan.nodes_per_block if plan is not None else None,
                        spectra=spectra, progress=progress)
    else:  # on Dask: blocks of nodes on the workers, written here
        from selfillum.unsteady.cluster import phase2_blocks

        p2 = {k: np.full(N, np.nan, np.float32) for k in ("mean", "rms", "si_change")}
        n_done = 0
        for a, d, mean, rms, change, psd in phase2_blocks(
                client, str(work), N, plan.nodes_per_block, frames, np.asarray(gain), cond.q,
                with_si, spectra):
            b = a + d.shape[1]
            dcp[:, a:b] = d
            p2["mean"][a:b], p2["rms"][a:b] = mean, rms
            if change is not None:
                p2["si_change"][a:b] = change
            if spectra is not None:
                spectra.add(a, None, psd=psd)
            n_done += b - a
            if progress is not None:
                progress(n_done)
    if spectra is not None:
        spectra.write(f.require_group("psd"))
    mean, rms, change = p2["mean"], p2["rms"], p2["si_change"]
    s = f.create_group("stats")
    s.create_dataset("dcp_mean", data=mean)
    s.create_dataset("dcp_rms", data=rms)
    if with_si:
        s.create_dataset("si_change_rms", data=change)
    fin = change[np.isfinite(change)]
    si_med = float(np.median(fin)) if fin.size else float("nan")
    si_p95 = float(np.percentile(fin, 95)) if fin.size else float("nan")
    f.attrs["si_change_median"] = si_med
    f.attrs["si_change_p95"] = si_p95
    f.attrs["conditions"] = json_attr(cond.to_dict())
    f.attrs["options"] = json_attr({
        "registration": cfg.registration, "target_patcher": cfg.target_patcher,
        "overlap": cfg.overlap, "filter": cfg.filter, "filter_size": cfg.filter_size,
        "oblique_angle": cfg.oblique_angle, "number_frames": T, "si": cfg.si,
        "reflectance": str(cfg.reflectance), "unpainted": str(cfg.unpainted),
        "rays": cfg.rays, "seed": cfg.seed, "detrend_order": DETREND_ORDER,
        "general": cfg.general, "source": cfg.source, "chunks": [tc, nc],
        "psd_probes": [int(n) for n in cfg.psd_probes], "psd_bands": cfg.psd_bands,
        "psd_nperseg": spectra.nperseg if spectra is not None else None})
    f.attrs["provenance"] = json_attr(provenance({
        "grid": cfg.grid, "sds": cfg.sds, "steady": cfg.steady,
        "paint_calibration": cfg.paint_calibration, "targets": cfg.targets,
        "taps": cfg.taps, "tap_positions": cfg.tap_positions, "wind_off": cfg.wind_off,
        "videos": [c.video for c in cfg.cameras],
        "calibrations": [c.calibration for c in cfg.cameras],
        "deck": cfg.source if os.path.isfile(cfg.source) else None}))
    f.attrs["memory"] = json_attr({
        "budget_mb": cfg.memory_mb,
        "frames_per_block": plan.frames_per_block if plan is not None else tc,
        "nodes_per_block": plan.nodes_per_block if plan is not None else nc})
    return {"seen": float(np.isfinite(rms).mean()), "si_median": si_med, "si_p95": si_p95,
            "rms": rms}


@contextlib.contextmanager
def _quiet():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield
