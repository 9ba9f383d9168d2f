"""``selfillum unsteady``: the unsteady PSP run, from a uPSP input deck or flags.

Only parses arguments and calls :func:`selfillum.unsteady.run_unsteady`.
"""

from __future__ import annotations

import sys
from pathlib import Path

from resection.errors import InputError
from selfillum.cli.uncertainty import add_uncertainty_options, uncertainty_settings
from selfillum.unsteady.budget import DEFAULT_MEMORY_MB


def _node_list(text: str | None) -> list:
    if not text:
        return []
    try:
        return [int(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise InputError(f"--psd {text}: expected node numbers separated by commas "
                         "(grid file order, from 0)") from None


def _cmd_unsteady(args) -> int:
    from resection.io.upsp_inputs import read_deck
    from selfillum.unsteady import CameraInput, UnsteadyConfig, config_from_deck, run_unsteady
    from selfillum.unsteady.config import cap_workers

    flags = {"registration": args.registration, "target_patcher": args.target_patcher,
             "overlap": args.overlap, "filter": args.filter, "filter_size": args.filter_size,
             "oblique_angle": args.oblique_angle, "number_frames": args.number_frames,
             "cutoff_x_max": args.cutoff_x_max}
    common = {"paint_calibration": Path(args.paint_calibration) if args.paint_calibration
              else None, "steady": Path(args.steady), "si": not args.no_si,
              "reflectance": args.reflectance, "unpainted": args.unpainted, "rays": args.rays,
              "seed": args.seed, "fps": args.fps, "tinf": args.tinf,
              "upsp_flat": args.upsp_flat, "track_dirs": args.track,
              "taps": Path(args.taps) if args.taps else None,
              "tap_positions": Path(args.tap_positions) if args.tap_positions else None,
              "wind_off": [Path(p) for p in args.wind_off] if args.wind_off else None,
              "p_ref": args.p_ref, "progress": not args.quiet,
              "psd_probes": _node_list(args.psd), "psd_bands": args.psd_bands,
              "psd_nperseg": args.psd_nperseg, "memory_mb": args.memory,
              "plots": not args.no_plots, "resume": args.resume,
              "fast": not args.full_maps, "workers": args.workers,
              "scheduler": args.scheduler, "uncertainty": args.uncertainty,
              "samples": args.samples, "stated": uncertainty_settings(args),
              "surface": [Path(p) for p in args.surface or []]}
    if args.deck:
        if args.grid or args.sds or args.video or args.calibration:
            raise InputError("give either DECK.inp or --grid/--sds/--video/--calibration, "
                             "not both")
        cfg = config_from_deck(read_deck(args.deck), out=args.out, **flags)
        if args.targets:
            cfg.targets = Path(args.targets)
        for k, v in common.items():
            setattr(cfg, k, v)
    else:
        for name in ("grid", "sds", "video", "calibration"):
            if not getattr(args, name):
                raise InputError(f"without a deck, give --{name}")
        if len(args.video) != len(args.calibration):
            raise InputError(f"{len(args.video)} --video for {len(args.calibration)} "
                             "--calibration (one each per camera, in camera order)")
        cams = [CameraInput(k + 1, Path(v), Path(c)) for k, (v, c) in
                enumerate(zip(args.video, args.calibration, strict=True))]
        for c in cams:
            for p in (c.video, c.calibration):
                if not p.exists():
                    raise InputError(f"{p}: file not found")
        cfg = UnsteadyConfig(grid=Path(args.grid), sds=Path(args.sds), cameras=cams,
                             targets=Path(args.targets) if args.targets else None,
                             out=Path(args.out), **{k: v for k, v in flags.items()
                                                    if v is not None}, **common)
    if cfg.track_dirs is not None and len(cfg.track_dirs) != len(cfg.cameras):
        raise InputError(f"--track: {len(cfg.track_dirs)} folders for {len(cfg.cameras)} "
                         "cameras (one per camera, in camera order)")
    cfg.workers, note = cap_workers(cfg.workers) if cfg.workers and cfg.workers > 0 \
        else (cfg.workers, None)
    if note:
        print(f"unsteady: {note}", file=sys.stderr)
    res = run_unsteady(cfg)
    print(f"unsteady: {res.n_frames} frames x {res.n_nodes} nodes, {100 * res.seen:.1f} % of "
          f"the nodes seen; chunks {res.chunks[0]} frames x {res.chunks[1]} nodes")
    if res.tracked_failed:
        print(f"tracking: {res.tracked_failed} frames without a pose took the nearest "
              "tracked frame's")
    if not res.si:
        print("self-illumination: not removed (--no-si)")
    elif res.si_change_median == res.si_change_median:
        print(f"self-illumination: dCp changed by {res.si_change_median:.4g} (median over the "
              f"nodes of its RMS over time), {res.si_change_p95:.4g} (95th percentile)")
    else:
        print("self-illumination: removed; its change of dCp could not be measured (no node "
              "has a dCp with and without it)")
    print(f"run: {res.frames_per_s:.1f} frames/s end to end; peak memory "
          f"{res.peak_rss_mb:.0f} MB; blocks of {res.blocks[0]} frames (Phase 1) and "
          f"{res.blocks[1]} nodes (Phase 2)")
    tm = res.timings
    print(f"time: set-up {tm['setup']:.1f} s, phase 1 {tm['phase1']:.1f} s (first frame "
          f"{tm['first_frame']:.1f} s), phase 2 and outputs {tm['phase2']:.1f} s")
    if res.uncertainty:
        u = res.uncertainty
        print(f"uncertainty ({u['method']}): dCp of a frame {u['dcp_u_median']:.4g} (median, "
              "k = 1, random)" + (f"; gain {100 * u['dcp_u_gain_median']:.3g} % (systematic)"
                                  if u.get("dcp_u_gain_median") is not None else ""))
        for k, v in u["sources"].items():
            print(f"  {k:12s} {v}")
    if "frames_fast" in tm:
        print(f"phase 1: {tm['frames_fast']} frames by sparse products, {tm['frames_full']} "
              f"mapped the full way, {tm['frames_references']} references cast from a pose")
    print("wrote " + ", ".join(str(p) for p in res.files))
    return 0


def register(sub) -> None:
    """Add the ``unsteady`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    from selfillum.unsteady.options import FILTERS, OVERLAPS, REGISTRATIONS

    p = sub.add_parser(
        "unsteady",
        help="unsteady PSP: videos of several cameras to dCp time histories on the grid, "
        "self-illumination removed (uPSP's psp_process)",
        description="Phase 1 maps every frame of every camera onto the grid's nodes (each "
        "frame with its own tracked pose, targets/taps/Kulites left out, cameras combined, "
        "self-illumination removed); Phase 2 turns node intensities into dCp with the paint "
        "gain (uPSP's formulas). Writes OUT.h5 (dCp frames x nodes) and OUT.xdmf. "
        "See docs/unsteady.md.",
    )
    p.add_argument("deck", nargs="?", metavar="DECK.inp",
                   help="uPSP psp_process input deck (@all, @camera, @options); flags "
                   "given below override its @options")
    p.add_argument("--grid", help="Plot3D surface grid (without a deck)")
    p.add_argument("--sds", "--wtd", dest="sds", metavar="RUN.wtd",
                   help="wind-tunnel data (MACH, Q, PS, TTF) (without a deck)")
    p.add_argument("--targets", metavar="MODEL.tgts",
                   help="targets, taps and Kulites (.tgts; without a deck, or to override)")
    p.add_argument("--video", action="append",
                   help="a camera's video (.cine, .mraw, TIFF/NPY stack); repeat per camera")
    p.add_argument("--calibration", action="append",
                   help="a camera's calibration (camera file, pose of the first frame); "
                   "repeat per camera, same order as --video")
    p.add_argument("--paint-calibration", metavar="CAL.txt",
                   help="uPSP's paint gain file (a = ... to f = ...); without it, the gain "
                   "comes from the in-situ Stern-Volmer fit on --taps")
    p.add_argument("--taps", metavar="RUN.wtd|TAPS.csv",
                   help="pressure taps for the in-situ fit (no paint calibration): a .wtd "
                   "('# Tap CP', p = PS + Cp Q; tap n = the .tgts point CPnn) or a tap CSV")
    p.add_argument("--tap-positions", metavar="MODEL.tgts",
                   help="where the taps are (default: the targets file)")
    p.add_argument("--wind-off", action="append", metavar="IMAGE",
                   help="wind-off image at --p-ref, one per camera in camera order (in-situ "
                   "fit)")
    p.add_argument("--p-ref", type=float, metavar="PSF",
                   help="pressure of the wind-off images, psf (in-situ fit)")
    p.add_argument("--steady", required=True, metavar="STEADY.f",
                   help="steady Cp: a Plot3D function file on the grid")
    p.add_argument("--reflectance", default="0.6", metavar="R|FILE",
                   help="paint reflectance: a number or a per-face file (default 0.6)")
    p.add_argument("--out", required=True, metavar="OUT.h5", help="output HDF5 file")
    p.add_argument("--registration", choices=REGISTRATIONS, default=None,
                   help="track: every frame with its own pose (default); first-frame: uPSP's "
                   "affine pixel registration onto frame 0 and its map; none: a fixed model")
    p.add_argument("--target-patcher", choices=("none", "polynomial"), default=None,
                   help="dark spots left out of node values (none, default) or patched by a "
                   "3rd-order 2-D polynomial (polynomial)")
    p.add_argument("--overlap", choices=OVERLAPS, default=None,
                   help="cameras combined per node: average_view, best_view or merge "
                   "(feathered, gains matched; default)")
    p.add_argument("--filter", choices=FILTERS, default=None, help="image filter")
    p.add_argument("--filter-size", type=int, default=None, help="filter size, odd pixels")
    p.add_argument("--oblique-angle", type=float, default=None, metavar="DEG",
                   help="obliqueness cut-off, degrees (default 70)")
    p.add_argument("--number-frames", type=int, default=None,
                   help="frames to process (-1: all, default)")
    p.add_argument("--cutoff-x-max", type=float, default=None, metavar="X",
                   help="uPSP's psp_process -cutoff_x_max: grid nodes of x > X (grid units) "
                   "get no data (NaN); the model beyond still hides and lights the rest")
    p.add_argument("--no-si", action="store_true",
                   help="do not remove the self-illumination (uPSP's answer)")
    p.add_argument("--unpainted", metavar="FILE|BLOCKS",
                   help="faces that emit nothing and never make a node value: a per-face 0/1 "
                   "file or Plot3D block numbers counted from 1")
    p.add_argument("--rays", type=int, default=64, help="rays per face for the view "
                   "factors (default 64: on the hidden-face scene of the benchmark "
                   "bench_unsteady.UnsteadyAccuracyVsUpspLike, dCp next to the block as with "
                   "1024)")
    p.add_argument("--seed", type=int, default=0, help="view-factor seed")
    p.add_argument("--fps", type=float, help="frame rate, when the video does not say it")
    p.add_argument("--tinf", type=float, metavar="DEG_F",
                   help="free-stream static temperature (default: isentropic from TTF, MACH)")
    p.add_argument("--track", action="append", metavar="DIR",
                   help="a camera's 'resection track' output instead of tracking here; "
                   "repeat per camera")
    p.add_argument("--upsp-flat", action="store_true",
                   help="also write the flat files of uPSP's psp_process that its scripts "
                   "read next to OUT.h5: pressure, pressure_transpose, X, Y, Z and per-node "
                   "avg, rms, gain, steady_state, model_temp, coverage, intensity_avg, "
                   "intensity_rms, intensity_ratio_0 (docs/unsteady.md)")
    p.add_argument("--surface", action="append", metavar="FILE",
                   help="also write the per-node fields on the grid: steady cp, dcp_mean, "
                   "dcp_rms and, with --uncertainty, dcp_u, dcp_u_gain, dcp_rms_signal, "
                   "dcp_rms_signal_u, noise_floor: .vtu, .vtk, .xdmf, .ply, .csv or a Plot3D "
                   "function file .f (with its .nam); repeat for several files")
    p.add_argument("--psd", metavar="N1,N2,...",
                   help="probe nodes (grid file order, from 0): their Welch PSD of dCp is "
                   "stored (/psd/probe_psd) and plotted (OUT_psd.png)")
    p.add_argument("--psd-bands", type=int, default=None, metavar="K",
                   help="per node, the PSD averaged over K log-spaced bands (/psd/band_psd; "
                   "0: none; default 8, or the spectrum's frequencies above 0 when fewer)")
    p.add_argument("--psd-nperseg", type=int, metavar="FRAMES",
                   help="frames per Welch segment (default min(frames, 256))")
    p.add_argument("--memory", type=float, default=DEFAULT_MEMORY_MB, metavar="MB",
                   help="memory budget of the blocks of frames (Phase 1) and nodes "
                   "(Phase 2), MiB (default 256); the fixed part of the run (libraries, "
                   "one frame's images and maps, grid, form factors) comes on top")
    p.add_argument("--no-plots", action="store_true",
                   help="do not write OUT_rms.png (dCp RMS on the model) nor OUT_psd.png")
    p.add_argument("--resume", action="store_true",
                   help="carry on an interrupted run from its work folder OUT.h5.work "
                   "(finished blocks of frames are not recomputed; a run with other inputs "
                   "or settings is refused)")
    p.add_argument("--full-maps", action="store_true",
                   help="map every frame the full way (a ray cast and merge a frame) instead "
                   "of sparse products after the first frame (for comparison)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="Dask: a local cluster of N worker processes (Phase 1 over blocks of "
                   "frames, Phase 2 over blocks of nodes)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask: the scheduler of a running cluster (tcp://host:8786); its "
                   "workers must see the run's files at the same paths")
    p.add_argument("--quiet", action="store_true", help="no progress")
    add_uncertainty_options(p)
    p.set_defaults(func=_cmd_unsteady)
