"""The driver: :func:`track`."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import InputError
from .execute import _default_workers, _execute_dask, _execute_local
from .frames import _frame_name
from .inputs import _as_link, _as_markers, _check_options, _settings
from .outputs import (
    _atomic_write_text,
    _frame_path,
    _frame_text,
    _read_frame,
    _write_csvs,
    _write_frame,
)
from .process import _process_frame, _process_linked, _repair, _Setup
from .results import FrameResult, TrackResult, _assemble


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
    chunk_size: int = 20,
    min_markers: int = 4,
    roi_margin: float | None = 40.0,
    detect_kw: dict | None = None,
    match_kw: dict | None = None,
    pose_kw: dict | None = None,
) -> TrackResult:
    """Track markers and solve the Point of View in every frame of a sequence.

    Parameters
    ----------
    frames : sequence of path-like or (H, W) arrays
        The frames in time order (TIFF/PNG/NPY files, see :func:`resection.io.images.read_image`).
        With a Dask cluster the paths must be readable by the workers.
    camera : Camera
        Calibrated intrinsics. Without ``link``, its pose must also approximate the pose of
        the first frame (matching starts from it).
    markers3d : path-like, (ids, points) or object with ``ids`` and ``points``
        The 3-D markers (DESIGN marker CSV ``id,x,y,z[,diameter]``), model units.
    link : path-like or dict, optional
        Linking of the first frame by hand: CSV ``id,candidate`` (see
        :mod:`resection.link`) or ``{id: candidate}``, the candidate numbers being the
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
        Worker processes of the local Dask cluster started when no ``scheduler`` is given;
        default: one per CPU core, at most one per chunk. 1 (or a single chunk to do) runs
        in this process, without Dask (same chunks, same results). The workers are spawned
        processes: a script that calls ``track`` with more than one worker needs the usual
        ``if __name__ == "__main__":`` guard.
    out_dir : path-like
        Output directory (created): ``poses.csv``, ``markers.csv``, ``frames/``, ``track.json``.
    resume : bool
        Keep the frames already finished in ``out_dir`` (by an interrupted run with the same
        settings); False recomputes everything.
    progress : bool
        Show a tqdm progress bar.
    chunk_size : int
        Consecutive frames per task.
    min_markers : int
        Frames with fewer matched markers fail.
    roi_margin : float or None
        Detect only inside the bounding box of the markers projected with the reference
        pose, widened by this many pixels (more than the motion from the reference frame
        plus a marker diameter); None searches the whole image.
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
        Bad inputs, or ``out_dir`` holds a run with different settings (use another directory
        or ``resume=False``). Failures of single frames are not raised: they are recorded.
    """
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    if isinstance(frames, (str, os.PathLike, np.ndarray)) and not (
            isinstance(frames, np.ndarray) and frames.ndim == 3):
        raise InputError("frames: expected a sequence of frames (paths or 2-D arrays)")
    frames = list(frames)
    if not frames:
        raise InputError("frames: the sequence is empty")
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        raise InputError(f"diameter: must be a number of pixels, got {diameter!r}") from None
    if not (np.isfinite(d) and d > 0):
        raise InputError(f"diameter: must be positive, got {diameter!r}")
    if polarity not in ("dark", "bright"):
        raise InputError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    if workers is None:
        workers = _default_workers()
    try:
        workers = int(workers)
    except (TypeError, ValueError):
        raise InputError(f"workers: must be a whole number, got {workers!r}") from None
    if workers < 1:
        raise InputError(f"workers: must be >= 1, got {workers}")
    if int(chunk_size) < 1:
        raise InputError(f"chunk_size: must be >= 1, got {chunk_size}")
    if int(min_markers) < 3:
        raise InputError(f"min_markers: must be >= 3, got {min_markers}")
    if roi_margin is not None and not (np.isfinite(roi_margin) and roi_margin > 0):
        raise InputError(f"roi_margin: must be positive or None, got {roi_margin!r}")
    for i, f in enumerate(frames):
        if not isinstance(f, (str, os.PathLike, np.ndarray)):
            raise InputError(f"frames[{i}]: expected a path or a 2-D array, got "
                             f"{type(f).__name__}")
    ids, pts = _as_markers(markers3d)
    link_d = _as_link(link)
    from ..markers import detect_markers
    from ..match import match_markers
    from ..pose import solve_pose

    detect_kw = _check_options(detect_kw, detect_markers, "detect_kw",
                               ("image", "diameter", "polarity"))
    match_kw = _check_options(match_kw, match_markers, "match_kw",
                              ("candidates", "markers3d", "reference", "camera", "pose_kw"))
    pose_kw = _check_options(pose_kw, solve_pose, "pose_kw",
                             ("camera", "points3d", "points2d", "refine_intrinsics"))
    setup = _Setup(camera=camera, ids=ids, points3d=pts, diameter=d, polarity=polarity,
                   detect_kw=detect_kw, match_kw=match_kw,
                   pose_kw=pose_kw, min_markers=int(min_markers),
                   roi_margin=None if roi_margin is None else float(roi_margin))
    chunk_size = int(chunk_size)

    out = Path(out_dir)
    frames_dir = out / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    settings = _settings(setup, link_d, fixed_camera, chunk_size)
    manifest = out / "track.json"
    if resume and manifest.is_file():
        try:
            with open(manifest, encoding="utf-8") as fh:
                old = json.load(fh)
        except (OSError, json.JSONDecodeError):
            old = None
        if old is not None and old != settings:
            diff = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
            raise InputError(f"{out}: holds a run with other settings ({', '.join(diff)}); "
                             "use another out_dir or resume=False")
    if not resume:
        for p in frames_dir.glob("frame_*.json"):
            p.unlink()
    _atomic_write_text(manifest, json.dumps(settings, indent=1))

    # frames already finished (resume): their recorded file must be the same frame
    done: dict[int, dict] = {}
    if resume:
        for i, f in enumerate(frames):
            dd = _read_frame(_frame_path(frames_dir, i))
            if dd is None:
                continue
            if dd["frame"] != i or dd["file"] != _frame_name(f):
                raise InputError(f"{out}: frame {i} was {dd['file']!r} in the interrupted run, "
                                 f"now {_frame_name(f)!r}; use another out_dir or resume=False")
            done[i] = dd

    from tqdm.auto import tqdm

    bar = tqdm(total=len(frames), initial=len(done), desc="track", unit="frame",
               disable=not progress)
    computed = 0

    def note(d: dict) -> None:
        """A frame finished (its file is written)."""
        nonlocal computed
        done[d["frame"]] = d
        computed += 1
        bar.update(1)

    def record(res: FrameResult) -> None:
        _write_frame(frames_dir, res)
        note(res.to_dict())

    try:
        # the reference frame, in this process
        if 0 in done:
            first = FrameResult.from_dict(done[0])
        else:
            if link_d is not None:
                first = _process_linked(frames[0], 0, setup, link_d)
            else:
                first = _process_frame(frames[0], 0, setup, None)
            record(first)
        seed = first if first.ok else None
        todo = {i for i in range(1, len(frames)) if i not in done}
        tasks = []
        for start in range(1, len(frames), chunk_size):
            idx = list(range(start, min(start + chunk_size, len(frames))))
            if not any(i in todo for i in idx):
                continue
            items = [(i, frames[i]) for i in idx]
            tasks.append((items, seed, {i: done[i] for i in idx if i in done}))
        if tasks:
            n_local = min(workers, len(tasks))  # no idle local workers: start-up costs
            if scheduler is None and n_local == 1:
                _execute_local(setup, tasks, record)
            else:
                def on_poll() -> None:
                    # frames the workers have written so far (shared filesystem)
                    names = set(os.listdir(frames_dir))
                    for i in sorted(todo):
                        if _frame_path(frames_dir, i).name in names:
                            d = _read_frame(_frame_path(frames_dir, i))
                            if d is not None and d.get("frame") == i:
                                todo.discard(i)
                                note(d)

                def on_chunk(dicts: list) -> None:
                    # a chunk came back: write what its worker could not (no shared
                    # filesystem with a remote cluster)
                    for dct in dicts:
                        i = dct["frame"]
                        if i not in todo:
                            continue
                        path, text = _frame_path(frames_dir, i), _frame_text(dct)
                        try:
                            same = path.read_text(encoding="utf-8") == text
                        except OSError:
                            same = False
                        if not same:
                            _atomic_write_text(path, text)
                        todo.discard(i)
                        note(dct)

                _execute_dask(setup, tasks, on_chunk, on_poll, scheduler, n_local,
                              str(frames_dir.resolve()))

        def rerecord(res: FrameResult) -> None:
            nonlocal computed
            _write_frame(frames_dir, res)
            done[res.frame] = res.to_dict()
            computed += 1

        _repair(frames, setup, done, rerecord)
    finally:
        bar.close()

    results = [FrameResult.from_dict(done[i]) for i in range(len(frames))]
    result = _assemble(results, fixed_camera, computed, str(out))
    _write_csvs(result, out)
    return result
