"""The driver: :func:`track`."""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from resection._numba_cache import ensure_numba_cache
from resection.camera.model import Camera
from resection.defaults import TRACK_FILES, TRACK_PRODUCER
from resection.io.lock import lock_folder
from resection.io.marks import claim_folder
from resection.io.outputs import refuse_overwriting_inputs
from resection.io.paths import sweep_temporaries
from resection.sequence.execute import run_frames
from resection.sequence.inputs import checked, run_settings
from resection.sequence.outputs import frames_from_files, start_run, write_csvs
from resection.sequence.pool import EARLY_SERVER_CORES, start_server
from resection.sequence.results import TrackResult, assemble


def track(
    frames: Sequence,
    camera: Camera,
    markers3d,
    *,
    link=None,
    diameter: float,
    polarity: str = "dark",
    fixed_camera: bool = True,
    scheduler: str | None = None,
    workers: int | None = None,
    out_dir: str | os.PathLike,
    resume: bool = True,
    progress: bool = True,
    chunk_size: int = 50,
    min_markers: int = 4,
    roi_margin: float | None = 40.0,
    detect_kw: dict | None = None,
    match_kw: dict | None = None,
    pose_kw: dict | None = None,
    mesh=None,
    on_frame=None,
    fit_threads: int | None = None,
) -> TrackResult:
    """Track markers and solve the Point of View in every frame of a sequence.

    Parameters
    ----------
    frames : sequence of path-like or (H, W) arrays, or one path
        The frames in time order (TIFF/PNG/NPY files, see :func:`resection.io.images.read_image`),
        or one file holding them all (Phantom ``.cine``, Photron ``.mraw``/``.cih``,
        multi-page TIFF, 3-D NPY: :mod:`resection.io.video`), read one frame at a time.
        With a Dask cluster the files must be readable by the workers.
    camera : Camera
        Calibrated intrinsics. Without ``link``, its pose must also approximate the pose of
        the first frame (matching starts from it).
    markers3d : path-like, (ids, points) or object with ``ids`` and ``points``
        The 3-D markers (DESIGN marker CSV ``id,x,y,z[,diameter][,nx,ny,nz]`` or a uPSP
        ``.tgts`` file), model units. Their normals, when given, say which markers face
        the camera in a frame (see ``mesh``).
    link : path-like or dict, optional
        Linking of the first frame by hand: CSV ``id,candidate`` (see
        :mod:`resection.markers.link`) or ``{id: candidate}``, the candidate numbers being the
        order of ``detect_markers`` on the whole first frame with this ``diameter``,
        ``polarity`` and ``detect_kw`` (as ``resection detect`` writes them).
    diameter : float
        Marker diameter in the images, pixels.
    polarity : {"dark", "bright"}
    fixed_camera : bool
        The camera is fixed and the model moves (report the model's motion), or the reverse.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``).
    workers : int, optional
        Local worker processes when no ``scheduler`` is given
        (:mod:`resection.sequence.pool`); default: one per CPU core, at most one per chunk.
        1 (or a single chunk to do) runs in this process (same chunks, same results). The
        workers are forked from a fresh server process (spawned on Windows): a script that
        calls ``track`` with more than one worker needs the usual
        ``if __name__ == "__main__":`` guard.
    out_dir : path-like
        Output directory (created): ``poses.csv``, ``markers.csv``, ``frames/``, ``track.json``.
    resume : bool
        Keep the frames already finished in ``out_dir`` (by an interrupted run with the same
        settings) whose files have not changed since (size, modification and status-change
        times, inode: see :mod:`resection.sequence.frames`); False recomputes everything.
    progress : bool
        Show a tqdm progress bar.
    chunk_size : int
        Consecutive frames per task. The first frame of a chunk is matched from frame 0
        (chunks run independently), usually by the statistical matcher, which costs tens of
        tracked frames; the others are tracked by prediction.
    min_markers : int
        Frames with fewer matched markers fail.
    roi_margin : float or None
        Detect only inside the bounding box of the markers projected with the reference
        pose, widened by this many pixels (more than the motion from the reference frame
        plus a marker diameter); None searches the whole image.
    mesh : path-like or trimesh.Trimesh, optional
        The model surface: a marker's normal (where the marker file gives none) is that of
        the nearest face. Tracking by prediction expects in a frame the markers found in
        the previous frames and those whose normal faces the camera, never one facing
        away (:func:`resection.sequence.predict.expected_markers`); without normals, a
        marker never seen is looked for every few frames.
    on_frame : callable, optional
        ``on_frame(result)`` with each frame's :class:`FrameResult` as soon as it is
        finished in this process, frame 0 first (also when a resumed run reads it back):
        a caller that needs the first frame's pose goes on with it meanwhile. Frames
        finished by worker processes or a cluster are not reported. An exception it raises
        stops the run, the frames finished being kept (a caller's way to stop a tracking
        it runs in a thread).
    fit_threads : int, optional
        Threads of a frame's marker fits when the frames run in this process (``workers``
        1, or a single chunk): default every core; 1 where this process does other work
        beside the tracking (a caller tracking in a helper thread), so that the tracking
        takes one core and leaves the other work its own.
    detect_kw, match_kw, pose_kw : dict, optional
        Extra keyword arguments of ``detect_markers``, ``match_markers`` and
        ``solve_pose`` (``pose_kw`` also goes to the matcher's verifying pose solves; the
        intrinsics are not refined per frame). Unknown names are an InputError.

    Returns
    -------
    TrackResult

    Raises
    ------
    InputError
        Bad inputs, ``out_dir`` holds a run with different settings (use another directory
        or ``resume=False``), or another live process is writing into ``out_dir`` (the
        message names it; see :mod:`resection.io.lock`). Failures of single frames are not
        raised: they are recorded.
    """
    ensure_numba_cache()  # before the kernels are imported: a fresh read-only install
    server_since = None
    if _may_use_workers(frames, scheduler, workers, chunk_size):
        # the workers' server loads the package beside these checks
        server_since = start_server()
    frames, setup, link_d, workers, chunk_size = checked(
        frames, camera, markers3d, link=link, diameter=diameter, polarity=polarity,
        workers=workers, chunk_size=chunk_size, min_markers=min_markers,
        roi_margin=roi_margin, detect_kw=detect_kw, match_kw=match_kw, pose_kw=pose_kw,
        mesh=mesh)
    out = Path(out_dir)
    _check_out_dir(out, frames, markers3d, link)
    frames_dir = out / "frames"
    made = None  # the topmost folder this run creates
    for parent in (out, *out.parents):
        if parent.exists():
            break
        made = parent
    try:
        frames_dir.mkdir(parents=True, exist_ok=True)
        with lock_folder(out, command=f"track: {len(frames)} frames"):
            for folder in (out, frames_dir):  # what a killed run left half written
                sweep_temporaries(folder)
            settings = run_settings(setup, link_d, fixed_camera, chunk_size)
            done = start_run(out, frames, settings, resume)
            computed = run_frames(frames, setup, link_d, done, chunk_size=chunk_size,
                                  workers=workers, scheduler=scheduler,
                                  frames_dir=frames_dir, progress=progress,
                                  server_since=server_since, on_frame=on_frame,
                                  fit_threads=fit_threads)
            result = assemble(frames_from_files(frames_dir, len(frames)), fixed_camera,
                               computed, str(out))
            write_csvs(result, out)
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):  # the run's frame count, for the message
            exc.n_frames = len(frames)  # (a stack's frames, not its files)
        # a folder made by this run goes again when it holds no finished frame to resume
        if made is not None and not any(frames_dir.glob("frame_*.json")):
            shutil.rmtree(made, ignore_errors=True)
        raise
    return result


def _may_use_workers(frames, scheduler, workers, chunk_size) -> bool:
    """Whether a run of these arguments may give chunks to local workers (a list of frame
    files of more than two chunks) and has the cores to start their server now
    (:data:`~resection.sequence.pool.EARLY_SERVER_CORES`: this process, the plot's process
    and the server start at once): the server is then started first
    (:func:`resection.sequence.pool.start_server`), before the inputs are checked. With
    fewer cores it is started once workers are known to pay (started here, it took a core
    from this process's start: 2,000 frames on 2 cores 13.3 s against 12.1 s; on 16 cores
    5.6 s against 6.1 s, with the first chunk's rest run beside the workers)."""
    from resection._threads import available_cores

    try:
        many = isinstance(frames, list | tuple) and len(frames) > 2 * int(chunk_size) + 1
    except (TypeError, ValueError):  # bad arguments: refused by the checks
        return False
    return (scheduler is None and many and workers != 1
            and available_cores() >= EARLY_SERVER_CORES)


def _check_out_dir(out: Path, frames: list, markers3d, link) -> None:
    """Refuse an output folder whose files would replace the user's (a folder that is not
    a track output but holds a ``poses.csv``) or an input (``--markers out/markers.csv``),
    before anything is written."""
    claim_folder(out, TRACK_FILES, "track.json", TRACK_PRODUCER)
    inputs = {"markers3d": [markers3d] if isinstance(markers3d, (str, os.PathLike)) else [],
              "link": [link] if isinstance(link, (str, os.PathLike)) else [],
              "frames": [f for f in frames if isinstance(f, (str, os.PathLike))]}
    refuse_overwriting_inputs({f"out_dir {out / n}": out / n for n in TRACK_FILES[:3]},
                              inputs)
