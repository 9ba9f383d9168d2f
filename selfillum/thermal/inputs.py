"""The thermal run's frames and poses: the video's counts as the signal Phase 1 maps
(:class:`SignalFrames`: the calibration's offset taken off, saturated pixels masked and
counted), each frame's pose from the project's tracking with the markers' polarity
(:func:`track_poses`; frames where too few markers are seen take the motion model), and
the counts checked against the calibration's range before the run (:func:`check_range`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["SignalFrames", "run_tracking", "track_poses", "check_range", "interpolate_poses"]


class SignalFrames:
    """Frames of a video as float32 ``counts - offset`` (the radiance-like signal ``U``
    of an IR camera, or the intensity of a TSP camera with ``offset`` 0); pixels at or
    above ``level`` (the sensor's full scale: :func:`resection.saturation.level_of`) are
    NaN (unseen: the faces they fall on are left out of that frame) and counted in
    ``saturated``."""

    def __init__(self, src, offset: float = 0.0, level: float | None = None):
        self.src = src
        self.offset = float(offset)
        self.level = level
        self.saturated = 0

    def __len__(self) -> int:
        return len(self.src)

    def __getitem__(self, k: int) -> np.ndarray:
        raw = self.src.native(k) if hasattr(self.src, "native") else np.asarray(self.src[k])
        img = raw.astype(np.float32)
        img -= np.float32(self.offset)
        if self.level is not None:
            sat = raw >= self.level
            n = int(np.count_nonzero(sat))
            if n:
                img[sat] = np.nan
                self.saturated += n
        return img


def check_range(src, video, mask, lo: float, hi: float, frames) -> None:
    """Counts of the model's pixels (``mask``) in ``frames`` within ``[lo, hi]`` (the
    calibration's range in counts), saturated pixels aside; else one line naming the video,
    the frame and the value."""
    from resection.saturation import level_of

    for k in frames:  # a few frames
        raw = src.native(k) if hasattr(src, "native") else np.asarray(src[k])
        level = level_of(raw.dtype, bits=getattr(src, "bits", None))
        v = raw[mask].astype(np.float64)
        if level is not None:
            v = v[v < level]
        if v.size == 0:
            continue
        if v.min() < lo or v.max() > hi:
            bad = v.min() if v.min() < lo else v.max()
            raise InputError(f"{video}: frame {k} has counts {bad:.0f} on the model, outside "
                             f"the calibration's range {lo:.0f}..{hi:.0f} counts")


def interpolate_poses(frames_ok, rvecs, tvecs, T, first=None):
    """Each frame's ``(rvec, t)``: the tracked ones as they are, the others linear in time
    between the tracked frames around them (rotation vectors interpolated: small motions),
    held at the ends; ``first`` = ``(rvec, t)`` of frame 0 (the calibration's pose) when
    frame 0 is not tracked."""
    fo = np.asarray(frames_ok, dtype=np.float64)
    rv = np.asarray(rvecs, dtype=np.float64)
    tv = np.asarray(tvecs, dtype=np.float64)
    if first is not None and (fo.size == 0 or fo[0] > 0):
        fo = np.concatenate([[0.0], fo])
        rv = np.vstack([first[0], rv])
        tv = np.vstack([first[1], tv])
    k = np.arange(T, dtype=np.float64)
    R = np.column_stack([np.interp(k, fo, rv[:, i]) for i in range(3)])
    t = np.column_stack([np.interp(k, fo, tv[:, i]) for i in range(3)])
    return R, t


def run_tracking(video, camera, targets, polarity: str, out_dir, *, progress: bool = False,
                 resume: bool = False):
    """The project's tracking (:func:`resection.sequence.track`, one process) of the markers
    ``targets`` of ``polarity`` in ``video`` with ``camera``'s calibration, into
    ``out_dir``; the markers' diameter in pixels from their size and distance."""
    from resection.io.markers import read_markers
    from resection.sequence import track

    ms = read_markers(targets)
    z = camera.to_camera_frame(ms.xyz)[:, 2]
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    dpx = float(np.median(ms.diameter * f / z[z > 0])) if ms.diameter is not None \
        else 5.0
    return track(str(video), camera, ms, diameter=dpx, polarity=polarity, out_dir=out_dir,
                 workers=1, progress=progress, resume=resume)


def track_poses(cfg, cam_in, camera, T, tmp: Path, *, resume: bool = False,
                track_dir: Path | None = None):
    """Each frame's camera (``(poses, failed)``): the project's tracking
    (:func:`run_tracking`, markers of ``cfg.polarity``), a given track folder
    (``cfg.track_dirs``) or the one tracked already (``track_dir``,
    :class:`selfillum.thermal.early.EarlyTracking`); frames without their own pose (too
    few markers seen: at the start of an IR run the markers have no contrast yet) are
    interpolated in time between the tracked frames, the calibration's pose standing for
    frame 0 (:func:`interpolate_poses`)."""
    from resection.camera.rotation import matrix_to_rotvec
    from resection.sequence import read_track

    if cfg.track_dirs is not None:
        tr = read_track(cfg.track_dirs[cfg.cameras.index(cam_in)])
    elif track_dir is not None:
        tr = read_track(track_dir)
    else:
        if cfg.targets is None:
            raise InputError("registration 'track' needs the targets (--targets)")
        folder = tmp / f"track{cam_in.number}"
        run_tracking(cam_in.video, camera, cfg.targets, cfg.polarity, folder,
                     progress=cfg.progress, resume=resume)
        tr = read_track(folder)  # as written (10 digits), as a track done early is read
    ok = np.flatnonzero((tr.status == "ok") & (tr.frame < T))
    if ok.size == 0:
        raise InputError(f"{cam_in.video}: tracking found the pose in no frame")
    order = np.argsort(tr.frame[ok])
    ok = ok[order]
    first = (matrix_to_rotvec(camera.R), np.asarray(camera.t, float))
    rv, tv = interpolate_poses(tr.frame[ok], tr.rvec[ok], tr.tvec[ok], T, first=first)
    failed = T - len(np.unique(tr.frame[ok]))
    poses = [camera.with_pose(rvec=rv[k], t=tv[k]) for k in range(T)]  # a Camera a frame
    return poses, int(failed)
