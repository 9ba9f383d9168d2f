"""``resection track``: argument parsing only; the work is in :mod:`resection.sequence` and
:mod:`resection.sequence.motion_plots`."""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys

from resection.cli.paths import FolderOutput
from resection.cli.util import add_acceptance_options
from resection.defaults import (
    DEFAULT_MARKER_ACCURACY,
    DEFAULT_MAX_RMS,
    TRACK_FILES,
    TRACK_PRODUCER,
)
from resection.errors import InputError


def register(sub) -> None:
    """Add the ``track`` sub-command to an argparse sub-parser set."""
    p = sub.add_parser(
        "track",
        help="markers and Point of View in every frame of a sequence",
        description="Track the markers (by prediction from the previous frames, the "
        "statistical matcher when that fails) and solve the pose in every frame; writes "
        "poses.csv (3 angles in degrees, 3 translations, RMS per frame), markers.csv (marker "
        "positions per frame) and pose_vs_time.png to --out. With a fixed camera (default) "
        "the motion reported is the model's, relative to the first frame. A failed frame is "
        "recorded with its reason and the run goes on. Interrupted runs resume (each "
        "finished frame is kept in --out/frames; frames whose file changed are computed "
        "again); one run at a time writes into --out. Frames run in parallel on local "
        "worker processes (one per CPU core) or on a Dask --scheduler. See docs/tracking.md.",
    )
    p.add_argument("frames", nargs="+", metavar="FRAME",
                   help="frame images in time order (TIFF/PNG/NPY; glob patterns allowed), "
                   "or one file holding the run (.cine, .mraw/.cih, multi-page TIFF, 3-D NPY)")
    p.add_argument("--camera", required=True, help="camera JSON (intrinsics; its pose "
                   "approximates the first frame's when --link is not given)")
    p.add_argument("--markers", required=True, help="marker CSV: id,x,y,z[,diameter]")
    p.add_argument("--link", help="linking CSV of the first frame: id,candidate")
    p.add_argument("--mesh", help="model surface (STL, OBJ, PLY, Plot3D...): the normals at "
                   "the markers (where the marker file has no nx,ny,nz) say which markers "
                   "face the camera in a frame")
    p.add_argument("--diameter", required=True, type=float, help="marker diameter, pixels")
    p.add_argument("--polarity", choices=("dark", "bright"), default="dark")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--scheduler", metavar="ADDRESS", help="running Dask scheduler address")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes when no --scheduler is given (default: one "
                   "per CPU core; 1: in this process)")
    p.add_argument("--chunk-size", type=int, default=50, help="frames per task (default 50)")
    p.add_argument("--fps", type=float, help="frame rate, for the time axis of the plot")
    p.add_argument("--moving-camera", action="store_true",
                   help="the model is fixed and the camera moves (report the camera's motion)")
    p.add_argument("--pose-options", metavar="JSON",
                   help="solve_pose options as a JSON object, for every frame's pose and the "
                   "matcher's verifying solves, e.g. '{\"robust\": \"huber\", "
                   "\"max_rms\": 1.0}'")
    add_acceptance_options(p)
    p.add_argument("--no-resume", action="store_true",
                   help="recompute every frame even if --out holds finished ones")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_track, out_folder=FolderOutput(
        TRACK_FILES, "track.json", TRACK_PRODUCER, subfolders=("frames",)))


def _expand(patterns: list[str]) -> list[str]:
    out = []
    for pat in patterns:
        if any(ch in pat for ch in "*?[") and not os.path.exists(pat):
            hits = sorted(glob.glob(pat))
            if not hits:
                raise InputError(f"no frame matches {pat!r}")
            out.extend(hits)
        else:
            out.append(pat)
    return out


def _json_options(text: str | None, option: str) -> dict | None:
    if text is None:
        return None
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{option}: not valid JSON ({exc.msg})") from None
    if not isinstance(value, dict):
        raise InputError(f"{option}: expected a JSON object {{\"name\": value, ...}}")
    return value


def run_track(args: argparse.Namespace) -> int:
    from resection.sequence.plot_worker import MotionPlotter

    # the plot's process starts first: its imports run beside this process's and the run's
    with MotionPlotter() as plotter:
        return _run(args, plotter)


def _run(args: argparse.Namespace, plotter) -> int:
    from resection.io.cameras import read_camera
    from resection.sequence.run import track

    # the acceptance options given (the defaults are solve_pose's: a run made without
    # them, from the library or the CLI, resumes with the same settings)
    rule = {k: v for k, v, d in (("marker_accuracy", args.marker_accuracy,
                                  DEFAULT_MARKER_ACCURACY),
                                 ("max_rms", args.max_rms, DEFAULT_MAX_RMS)) if v != d}
    pose_kw = {**rule, **(_json_options(args.pose_options, "--pose-options") or {})} or None
    camera = read_camera(args.camera)
    frames = _expand(args.frames)
    try:
        result = track(
            frames, camera, args.markers, link=args.link, diameter=args.diameter,
            polarity=args.polarity, fixed_camera=not args.moving_camera,
            scheduler=args.scheduler, workers=args.workers, out_dir=args.out,
            resume=not args.no_resume, progress=not args.no_progress,
            chunk_size=args.chunk_size, pose_kw=pose_kw, mesh=args.mesh,
        )
    except KeyboardInterrupt as exc:
        from resection.sequence.outputs import finished_frames

        frames_dir = os.path.join(args.out, "frames")
        n = finished_frames(frames_dir)
        total = getattr(exc, "n_frames", None)  # set once the frames are counted
        of = f"{n}/{total} frames" if total is not None else f"{n} frames"
        print(f"interrupted: {of} finished are kept in {frames_dir}; "
              "run the same command again to resume", file=sys.stderr)
        return 130
    plotter.plot(result, os.path.join(args.out, "pose_vs_time.png"), fps=args.fps)
    n_ok = int(result.ok.sum())
    print(f"{n_ok}/{len(result)} frames solved ({result.n_computed} computed now), "
          f"motion relative to frame {result.reference}; results in {args.out}")
    counts = result.method_counts
    if counts:
        print(f"  {counts['predicted']} tracked by prediction, {counts['matched']} by the "
              "statistical matcher (where the prediction's gate failed)"
              + (f", {counts['linked']} linked by hand" if counts["linked"] else ""))
    for i in range(len(result)):
        if not result.ok[i]:
            print(f"  frame {result.frame[i]} ({result.file[i]}): {result.reason[i]}")
    if not n_ok:
        first = result.reason[0] if len(result) else "no frames"
        print(f"resection track: error: no frame solved (frame 0: {first})", file=sys.stderr)
    return 0 if n_ok else 1
