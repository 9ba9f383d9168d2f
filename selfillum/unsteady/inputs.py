"""The run's inputs opened and checked: the videos (:func:`open_videos`: length, rate),
each frame's pose from the project's tracking (:func:`track_poses`), and what Phase 1's
numbers depend on (:func:`work_inputs`, the key of a resumed run)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from resection.errors import InputError
from selfillum.unsteady.config import UnsteadyConfig
from selfillum.unsteady.output import provenance

__all__ = ["open_videos", "track_poses", "work_inputs", "read_form_factors"]


def open_videos(cfg: UnsteadyConfig):
    """The videos opened, checked for length and rate: ``(sources, T, fps)``."""
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
    if cfg.fps is None:  # the videos' own rates: a bad one is the video's, not --fps's
        for c, r in zip(cfg.cameras, rates, strict=True):
            if r is not None and not (math.isfinite(r) and r > 0):
                raise InputError(f"{c.video}: its header's frame rate {r} is not a positive "
                                 "finite number; give --fps")
    known = {float(r) for r in rates if r and math.isfinite(r) and r > 0}
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


def track_poses(cfg, cam_in, camera, src, T, tmp: Path, *, resume: bool = False):
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


def work_inputs(cfg: UnsteadyConfig, T: int, N: int, fps: float) -> dict:
    """What Phase 1's numbers depend on: a resumed run with anything else is refused."""
    return {"files": provenance({
                "grid": cfg.grid, "targets": cfg.targets,
                "videos": [c.video for c in cfg.cameras],
                "calibrations": [c.calibration for c in cfg.cameras],
                "reflectance": cfg.reflectance if os.path.isfile(str(cfg.reflectance))
                else None,
                "unpainted": cfg.unpainted if os.path.isfile(str(cfg.unpainted)) else None,
                "track": cfg.track_dirs, "form_factors": cfg.form_factors}),
            "registration": cfg.registration, "target_patcher": cfg.target_patcher,
            "overlap": cfg.overlap, "filter": cfg.filter, "filter_size": cfg.filter_size,
            "oblique_angle": cfg.oblique_angle, "frames": T, "nodes": N, "fps": fps,
            "si": cfg.si, "reflectance": str(cfg.reflectance),
            "unpainted": str(cfg.unpainted), "rays": cfg.rays, "seed": cfg.seed}


def read_form_factors(path, n_faces: int):
    """View factors computed before (SciPy sparse ``.npz``, ``n_faces`` square, rows
    summing to at most 1), checked."""
    import scipy.sparse as sp

    p = os.fspath(path)
    try:
        F = sp.csr_matrix(sp.load_npz(p))
    except FileNotFoundError:
        raise InputError(f"{p}: view factors file not found") from None
    except (OSError, ValueError) as e:
        raise InputError(f"{p}: not a SciPy sparse .npz ({e})") from None
    if F.shape != (n_faces, n_faces):
        raise InputError(f"{p}: view factors {F.shape[0]}x{F.shape[1]}, the grid has "
                         f"{n_faces} faces")
    rows = np.asarray(F.sum(axis=1)).ravel()
    if not (np.all(np.isfinite(F.data)) and F.data.min(initial=0) >= 0
            and rows.max(initial=0) <= 1.0 + 1e-6):
        raise InputError(f"{p}: view factors must be finite, >= 0, each row summing to "
                         "at most 1")
    return F
