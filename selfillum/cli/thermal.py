"""``selfillum thermal``: IR thermography or TSP, from videos to surface temperature and
heat flux at every grid node.

Only parses arguments and calls :func:`selfillum.thermal.run_thermal`.
"""

from __future__ import annotations

from pathlib import Path

from resection.errors import InputError
from selfillum.unsteady.budget import DEFAULT_MEMORY_MB


def _numbers(text: str | None, kind, what: str) -> list:
    if not text:
        return []
    try:
        return [kind(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise InputError(f"{what} {text}: expected numbers separated by commas") from None


def _cmd_thermal(args) -> int:
    from selfillum.thermal import CameraInput, ThermalConfig, run_thermal

    if len(args.video) != len(args.calibration):
        raise InputError(f"{len(args.video)} --video for {len(args.calibration)} "
                         "--calibration (one each per camera, in camera order)")
    cams = [CameraInput(k + 1, Path(v), Path(c)) for k, (v, c) in
            enumerate(zip(args.video, args.calibration, strict=True))]
    for p in [Path(args.grid), Path(args.substrate), *(c.video for c in cams),
              *(c.calibration for c in cams)]:
        if not p.exists():
            raise InputError(f"{p}: file not found")
    cfg = ThermalConfig(
        grid=Path(args.grid), cameras=cams, out=Path(args.out),
        substrate=Path(args.substrate),
        targets=Path(args.targets) if args.targets else None,
        radiometry=Path(args.radiometry) if args.radiometry else None,
        tsp_calibration=Path(args.tsp_calibration) if args.tsp_calibration else None,
        wind_off=[Path(p) for p in args.wind_off] if args.wind_off else None,
        reflectance=args.reflectance, sds=Path(args.sds) if args.sds else None,
        recovery_factor=args.recovery_factor, tinf=args.tinf, method=args.method,
        fps=args.fps, number_frames=args.number_frames, registration=args.registration,
        target_patcher=args.target_patcher, overlap=args.overlap,
        oblique_angle=args.oblique_angle, marker_polarity=args.polarity,
        track_dirs=args.track, si=not args.no_si, si_refresh=args.si_refresh,
        rays=args.rays, seed=args.seed,
        probes=_numbers(args.probe, int, "--probe"),
        picture_times=_numbers(args.picture_times, float, "--picture-times"),
        memory_mb=args.memory, resume=args.resume, progress=not args.quiet,
        plots=not args.no_plots)
    res = run_thermal(cfg)
    print(f"thermal ({cfg.mode}): {res.n_frames} frames x {res.n_nodes} nodes, "
          f"{100 * res.seen:.1f} % of the nodes with a heat flux ({res.method})")
    if res.tracked_failed:
        print(f"tracking: {res.tracked_failed} frames with too few markers seen took the "
              "motion model (poses interpolated between tracked frames)")
    if res.saturated_pixels:
        print(f"saturated: {res.saturated_pixels} pixels masked (unseen)")
    if res.out_of_range:
        print(f"calibration range: {res.out_of_range} node samples outside it (NaN)")
    tm = res.timings
    print(f"run: {res.frames_per_s:.1f} frames/s end to end; set-up {tm['setup']:.1f} s "
          f"(inputs, tracking, view factors), phase 1 {tm['phase1']:.1f} s, phase 2 and "
          f"outputs {tm['phase2']:.1f} s")
    print("wrote " + ", ".join(str(p) for p in res.files))
    return 0


def register(sub) -> None:
    """Add the ``thermal`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    from selfillum.thermal.heatflux import METHODS
    from selfillum.unsteady.options import OVERLAPS, REGISTRATIONS

    p = sub.add_parser(
        "thermal",
        help="IR thermography or TSP: videos to surface temperature and heat flux on the "
        "grid, frame by frame",
        description="Phase 1 maps every frame onto the grid's nodes (each frame with its own "
        "tracked pose, markers patched, cameras combined, the model's own reflected "
        "radiation removed); Phase 2 turns node signals into temperature (IR: FLIR's Planck "
        "form, directional emissivity, reflected walls; TSP: intensity ratio through the "
        "paint's calibration) and the temperature histories into heat flux (Cook-Felderman "
        "or impulse response, layered substrates). Writes OUT.h5 (/temperature, /heat_flux "
        "frames x nodes) and OUT.xdmf. See docs/thermal.md.")
    p.add_argument("--grid", required=True, help="Plot3D surface grid or Cart3D .tri")
    p.add_argument("--targets", metavar="MODEL.tgts",
                   help="markers (tracking, and patched out of the node values)")
    p.add_argument("--video", action="append", required=True,
                   help="a camera's video (.cine, .mraw, TIFF/NPY stack); repeat per camera")
    p.add_argument("--calibration", action="append", required=True,
                   help="a camera's calibration (pose of the first frame); repeat per camera")
    p.add_argument("--radiometry", metavar="R.json",
                   help="IR: FLIR's R, B, F, O, emissivity, reflected_temperature (K)")
    p.add_argument("--tsp-calibration", metavar="C.json",
                   help="TSP: the paint's calibration (arrhenius or polynomial)")
    p.add_argument("--wind-off", action="append", metavar="IMAGE",
                   help="TSP: wind-off image at the calibration's T_ref; one per camera")
    p.add_argument("--reflectance", default="0.6", metavar="R|FILE",
                   help="TSP: the paint's reflectance (self-illumination; default 0.6)")
    p.add_argument("--substrate", required=True, metavar="S.json",
                   help="rho, c, k (SI), or layers on a substrate")
    p.add_argument("--method", choices=METHODS,
                   help="heat flux: cook-felderman (semi-infinite; default there) or impulse "
                   "(default for layers)")
    p.add_argument("--sds", "--wtd", dest="sds", metavar="RUN.wtd",
                   help="tunnel conditions (MACH, Q, PS, TTF): Stanton number and h")
    p.add_argument("--recovery-factor", type=float,
                   help="adiabatic-wall recovery factor (default 0.896)")
    p.add_argument("--tinf", type=float, metavar="DEG_F",
                   help="free-stream static temperature (default: isentropic)")
    p.add_argument("--fps", type=float, help="frame rate, when the video does not say it")
    p.add_argument("--out", required=True, metavar="OUT.h5", help="output HDF5 file")
    p.add_argument("--registration", choices=REGISTRATIONS, default="track",
                   help="track (default), first-frame or none")
    p.add_argument("--target-patcher", choices=("none", "polynomial"), default="polynomial",
                   help="markers patched by uPSP's polynomial from a ring of the model "
                   "around them (default) or left out of the node values (none)")
    p.add_argument("--overlap", choices=OVERLAPS, default="average_view",
                   help="cameras combined per node (default average_view)")
    p.add_argument("--oblique-angle", type=float, default=70.0, metavar="DEG",
                   help="obliqueness cut-off, degrees (default 70)")
    p.add_argument("--number-frames", type=int, default=-1)
    p.add_argument("--polarity", choices=("dark", "bright"),
                   help="markers on the images (default: bright for IR, dark for TSP)")
    p.add_argument("--track", action="append", metavar="DIR",
                   help="a camera's 'resection track' output instead of tracking here")
    p.add_argument("--no-si", action="store_true",
                   help="do not remove the model's own reflected radiation")
    p.add_argument("--si-refresh", type=float, default=0.01, metavar="FRACTION",
                   help="solve the faces no camera sees again when the seen signal has "
                   "drifted by this much (default 0.01)")
    p.add_argument("--rays", type=int, default=256, help="rays per face, view factors")
    p.add_argument("--seed", type=int, default=0, help="view-factor seed")
    p.add_argument("--probe", metavar="N1,N2,...",
                   help="probe nodes: their T and q histories (OUT_probes.png)")
    p.add_argument("--picture-times", metavar="T1,T2,...",
                   help="times (s) of pictures of q on the model (OUT_q_<t>s.png)")
    p.add_argument("--memory", type=float, default=DEFAULT_MEMORY_MB, metavar="MB",
                   help="memory budget of the blocks, MiB (default 256)")
    p.add_argument("--no-plots", action="store_true", help="no pictures")
    p.add_argument("--resume", action="store_true",
                   help="carry on an interrupted run from OUT.h5.work")
    p.add_argument("--quiet", action="store_true", help="no progress")
    p.set_defaults(func=_cmd_thermal)
