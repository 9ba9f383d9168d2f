"""Per-frame mapping of a moving model: the image <-> surface map rebuilt in every frame.

A model on a sting moves during a run (pitch, heave, bending). NASA's uPSP software maps the
first frame only and warps every later frame onto it with an affine image transform
(``cv2.findTransformECC``); what that cannot follow (perspective, parallax between parts at
different depths, occlusion and the silhouette moving over the background) lands at the
model's edges, its known error. Here every frame gets its own
:class:`resection.SurfaceMap` from that frame's camera pose (e.g. the ``track`` output), so
visibility, the obliqueness cut-off and the projection are exact per frame.

What is shared between frames is what does not depend on the pose: the Embree scene of the
grid and the camera's undistortion map (lines of sight of every pixel). A frame then costs
one rotation of the pixel rays, one Embree call on them and one sparse product.

Frames are consumed and results produced one at a time (:func:`map_frames` is a generator),
so memory does not grow with the length of the run; :func:`map_to_history` writes each
frame to the run's time-history file (:mod:`resection.io.history`) as it finishes, and
resumes an interrupted run.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.camera.model import Camera
from resection.errors import InputError
from resection.surface.surface_map import DEFAULT_MAX_OBLIQUENESS, SurfaceMap
from resection.surface.visibility import RayCaster

__all__ = ["FrameValues", "map_frames", "map_to_history"]


@dataclass(frozen=True)
class FrameValues:
    """One frame mapped onto the grid.

    Attributes
    ----------
    index : int
        Frame number (position in the sequence).
    values : (F,) or (V,) float64
        Per-face mean of the frame's pixels (``per="face"``, :meth:`SurfaceMap.to_surface`)
        or per-node values (``per="node"``, :meth:`SurfaceMap.to_nodes`); NaN where unseen.
    seen : (F,) or (V,) bool
        Finite values.
    camera : Camera
        The frame's camera (pose of the camera relative to the model).
    """

    index: int
    values: np.ndarray
    seen: np.ndarray
    camera: Camera


def _same_intrinsics(a: Camera, b: Camera) -> bool:
    return (a.width == b.width and a.height == b.height and np.array_equal(a.K, b.K)
            and np.array_equal(a.dist, b.dist))


def map_frames(
    mesh: trimesh.Trimesh,
    cameras,
    frames: Iterable,
    *,
    per: str = "face",
    max_obliqueness: float | None = DEFAULT_MAX_OBLIQUENESS,
) -> Iterator[FrameValues]:
    """Map every frame of a sequence onto the grid with that frame's own camera pose.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Model grid, model units (the model's own frame: the pose carries the motion).
    cameras : Camera or iterable of Camera
        One camera per frame (the camera relative to the model in that frame, e.g. the
        cameras written by ``track``), or one camera for a model that does not move (the
        map is then built once).
    frames : iterable of (H, W) array_like
        The images, read lazily (e.g. :func:`resection.io.video.iter_frames`).
    per : {"face", "node"}
        Per-face means, or per-node values (the grid's vertices).
    max_obliqueness : float or None
        Obliqueness cut-off, degrees (see :class:`resection.SurfaceMap`).

    Yields
    ------
    FrameValues
        One per frame, in order.

    Raises
    ------
    InputError
        Cameras of another image size or intrinsics than the first, fewer cameras than
        frames, a frame of the wrong shape.
    """
    if per not in ("face", "node"):
        raise InputError(f"per must be 'face' or 'node', got {per!r}")
    fixed = isinstance(cameras, Camera)
    cams = iter(()) if fixed else iter(cameras)
    caster = RayCaster(mesh)
    base = cameras if fixed else None
    smap = None
    for k, frame in enumerate(frames):
        if fixed:
            cam = cameras
        else:
            try:
                cam = next(cams)
            except StopIteration:
                raise InputError(f"cameras: {k} cameras for more frames (one per frame, "
                                 "or one for a model that does not move)") from None
            if not isinstance(cam, Camera):
                raise InputError(f"cameras: item {k} is a {type(cam).__name__}, not a Camera")
            if base is None:
                base = cam
            elif not _same_intrinsics(base, cam):
                raise InputError(f"cameras: frame {k}'s camera has other intrinsics or image "
                                 "size than frame 0's (one camera per sequence)")
            else:  # share frame 0's undistortion map: only the pose changes
                cam = base.with_pose(R=cam.R, t=cam.t)
        if smap is None or not fixed:
            smap = SurfaceMap(mesh, cam, max_obliqueness=max_obliqueness, caster=caster)
        img = np.asarray(frame)
        if img.shape != smap.shape:
            raise InputError(f"frame {k}: shape {img.shape} is not the camera's (H, W) = "
                             f"{smap.shape}")
        values = (smap.to_nodes(img) if per == "node" else smap.to_surface(img)).values
        yield FrameValues(k, values, np.isfinite(values), cam)


def map_to_history(
    path,
    mesh: trimesh.Trimesh,
    cameras,
    frames,
    *,
    frame_numbers=None,
    times=None,
    per: str = "node",
    resume: bool = False,
    max_obliqueness: float | None = DEFAULT_MAX_OBLIQUENESS,
    progress=None,
    inputs: dict | None = None,
    sources=None,
) -> int:
    """Map a sequence frame by frame into one time-history file (HDF5 + XDMF sidecar).

    Parameters
    ----------
    path : path-like
        The ``.h5`` file (see :class:`resection.io.history.HistoryWriter`).
    mesh : trimesh.Trimesh
    cameras : Camera or sequence of Camera
        One camera (a model that does not move) or one per entry of ``frame_numbers``.
    frames : indexable of (H, W) arrays
        ``frames[i]`` reads frame ``i`` (e.g. :func:`resection.io.video.open_frames`); only
        the frames mapped are read, one at a time.
    frame_numbers : sequence of int, optional
        Which frames to map, in order (default all ``len(frames)``), e.g. the frames
        ``track`` solved.
    times : sequence of float, optional
        Time of each entry of ``frame_numbers``, seconds (default: the frame numbers).
    per : {"node", "face"}
    resume : bool
        Continue the file of an interrupted run: the frames it holds are not mapped again.
        It must have been made with the same ``inputs``, ``per`` and ``max_obliqueness``,
        and its frames must have the times and cameras given here; else InputError (the
        file is left as it is).
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame.
    inputs : dict, optional
        Settings besides the arguments that the frames depend on (JSON-able), recorded in
        the file and compared on resume.
    sources : sequence of str, optional
        What each entry of ``frame_numbers`` is read from (e.g. its file's name and content
        digest, :func:`resection.sequence.frames.content_digest`), recorded per frame and
        compared on resume: a committed frame whose image changed is refused.

    Returns
    -------
    int
        Frames mapped by this call.
    """
    from resection.io.history import HistoryWriter

    nums = np.arange(len(frames)) if frame_numbers is None else np.asarray(frame_numbers, int)
    tms = nums.astype(float) if times is None else np.asarray(times, dtype=float)
    if tms.shape != nums.shape:
        raise InputError(f"times: {tms.size} times for {nums.size} frames")
    if not np.all(np.isfinite(tms)):
        raise InputError("times: must be finite (a frame rate of 0 or infinity?)")
    fixed = isinstance(cameras, Camera)
    if not fixed and len(cameras) != len(nums):
        raise InputError(f"cameras: {len(cameras)} cameras for {len(nums)} frames")
    record = {"inputs": inputs, "per": per,
              "max_obliqueness": None if max_obliqueness is None else float(max_obliqueness),
              "camera": (cameras if fixed else cameras[0]).to_dict() if len(nums) else None}
    with HistoryWriter(path, mesh, per=per, resume=resume,
                       inputs=json.loads(json.dumps(record, default=_plain))) as writer:
        _check_committed(writer, path, nums, tms, cameras, sources)
        todo = np.flatnonzero(~np.isin(nums, writer.done))
        cams = cameras if fixed else [cameras[i] for i in todo]
        images = (frames[int(nums[i])] for i in todo)
        for j, res in enumerate(map_frames(mesh, cams, images, per=per,
                                           max_obliqueness=max_obliqueness)):
            i = todo[j]
            writer.append(res.values, time=tms[i], camera=res.camera, index=int(nums[i]),
                          source="" if sources is None else str(sources[i]))
            if progress is not None:
                progress(writer.n_frames, len(nums))
    return len(todo)


def _plain(o):
    return np.asarray(o).tolist()


def _check_committed(writer, path, nums, tms, cameras, sources) -> None:
    """The frames a resumed file holds must be frames of this run, at the same times and
    with the same cameras."""
    if writer.n_frames == 0:
        return
    h = writer.committed_frames()
    pos = {int(n): i for i, n in enumerate(nums)}
    fixed = isinstance(cameras, Camera)
    for k, n in enumerate(h["index"]):
        i = pos.get(int(n))
        if i is None:
            raise InputError(f"{path}: holds frame {int(n)}, which this run does not map; "
                             "cannot resume it")
        if not np.isclose(h["time"][k], tms[i], rtol=1e-12, atol=0):
            raise InputError(f"{path}: frame {int(n)} was at {h['time'][k]:g} s, now at "
                             f"{tms[i]:g} s (another frame rate?); cannot resume it")
        src = "" if sources is None else str(sources[i])
        if h["source"][k] != src:
            raise InputError(f"{path}: frame {int(n)} was mapped from another image than "
                             f"{src.split('|')[0] or 'the one given now'}; cannot resume it")
        cam = cameras if fixed else cameras[i]
        for name in ("K", "dist", "R", "t"):
            if not np.allclose(h[name][k], getattr(cam, name), rtol=1e-12, atol=1e-12):
                raise InputError(f"{path}: frame {int(n)} was mapped with another camera "
                                 f"({name} differs); cannot resume it")

