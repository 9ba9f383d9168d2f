"""The run's inputs opened and checked: the videos (:func:`open_videos`: length, rate),
each frame's pose from the project's tracking (:func:`track_poses`), and what Phase 1's
numbers depend on (:func:`work_inputs`, the key of a resumed run)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from resection.defaults import FRAME_RATE_RANGE
from resection.errors import InputError
from selfillum.unsteady.config import UnsteadyConfig
from selfillum.unsteady.output import provenance

__all__ = ["open_videos", "run_length", "track_poses", "tracked_motion", "work_inputs",
           "min_frames", "content_key", "file_digest", "check_cameras", "check_spot_sizes",
           "read_form_factors"]


def open_videos(cfg: UnsteadyConfig, need: int | None = None):
    """The videos opened, checked for length and rate, their first frame for light, and
    for ``need`` frames at least (the unsteady run: :func:`min_frames`):
    ``(sources, T, fps)``."""
    from resection.io.video import open_frames

    srcs = []
    try:
        for c in cfg.cameras:
            srcs.append(open_frames(c.video))
        return _check_videos(cfg, srcs, need)
    except BaseException:
        for s in srcs:
            s.close()
        raise


def run_length(cfg: UnsteadyConfig, n: list[int]) -> int:
    """The run's frames from its videos' lengths ``n`` (one a camera) and the deck's
    ``number_frames`` (-1: every frame, the videos of one length)."""
    where = cfg.source
    for c, k in zip(cfg.cameras, n, strict=True):
        if k == 0:
            raise InputError(f"{c.video}: no frames")
    if cfg.number_frames == -1:
        if len(set(n)) > 1:
            lens = ", ".join(f"{c.video.name}: {k}" for c, k in
                             zip(cfg.cameras, n, strict=True))
            raise InputError(f"{where}: number_frames = -1 but the videos differ in length "
                             f"({lens} frames)")
        return int(n[0])
    T = int(cfg.number_frames)
    short = [(c, k) for c, k in zip(cfg.cameras, n, strict=True) if k < T]
    if short:
        c, k = short[0]
        raise InputError(f"{where}: number_frames = {T} but {c.video} has {k} frames")
    return T


def _check_videos(cfg: UnsteadyConfig, srcs, need: int | None):
    from selfillum.unsteady.phase2 import DETREND_ORDER

    T = run_length(cfg, [len(s) for s in srcs])
    where = cfg.source
    rates = [s.frame_rate for s in srcs]
    lo, hi = FRAME_RATE_RANGE
    if cfg.fps is None:  # the videos' own rates: a bad one is the video's, not --fps's
        for c, r in zip(cfg.cameras, rates, strict=True):
            if r is not None and not lo <= r <= hi:  # NaN, inf, 1e-320, negative
                raise InputError(f"{c.video}: its header's frame rate {r} is not a frame "
                                 f"rate ({lo:.3g} to {hi:g} frames/s); give --fps")
    known = {float(r) for r in rates if r is not None and lo <= r <= hi}
    if len(known) > 1:
        rl = ", ".join(f"{c.video.name}: {r} fps" for c, r in
                       zip(cfg.cameras, rates, strict=True))
        raise InputError(f"{where}: the videos differ in frame rate ({rl})")
    fps = cfg.fps if cfg.fps is not None else (known.pop() if known else None)
    if fps is None:
        raise InputError(f"{cfg.cameras[0].video}: no frame rate in the video; give --fps")
    if not fps > 0:
        raise InputError(f"--fps must be positive, got {fps}")
    if need is not None and T < need:
        what = f"{where}: number_frames = {T}" if cfg.number_frames != -1 else \
            f"{cfg.cameras[0].video}: {T} frame{'s' if T != 1 else ''}"
        why = (f" (Phase 2 removes a polynomial of order {DETREND_ORDER} in time from every "
               "node's intensity)") if need == min_frames(DETREND_ORDER) else ""
        raise InputError(f"{what}; the run needs at least {need} frames{why}")
    for c, s in zip(cfg.cameras, srcs, strict=True):
        h, w = s.shape
        if cfg.filter == "gaussian" and cfg.filter_size > min(h, w):
            raise InputError(f"{where}: filter_size {cfg.filter_size} is larger than "
                             f"{c.video}'s {w}x{h} frames")
        first = np.asarray(s[0], dtype=np.float64)
        fin = first[np.isfinite(first)]
        if fin.size == 0 or not fin.max() > max(fin.min(), 0.0):
            lvl = f"every pixel {fin.max():g}" if fin.size else "no finite pixel"
            raise InputError(f"{c.video}: frame 0 is blank ({lvl}): no light to measure "
                             "(lens cap, a dark or a wrong file?)")
    return srcs, T, float(fps)


def min_frames(order: int) -> int:
    """Frames a run needs: the detrend's polynomial of ``order`` in time (``order + 1``
    coefficients) leaves a residual (dCp) only with at least ``order + 2`` frames."""
    return int(order) + 2


def track_poses(cfg, cam_in, camera, src, T, tmp: Path, *, resume: bool = False,
                on_frame=None, fit_threads: int | None = None):
    """Each frame's camera from the project's tracking (or a given track folder), and the
    number of frames that took a neighbour's pose (their tracking failed). ``on_frame(k,
    pose)``: called as the tracker finishes frame ``k`` (frame 0 first) with its camera
    (None where the frame failed: it then takes a neighbour's); an exception it raises
    stops the tracking (:func:`resection.sequence.track`'s ``on_frame``); ``fit_threads``:
    its marker fits' threads (default every core; 1 beside other work). The poses are
    :func:`tracked_motion`'s, made cameras."""

    def posed(motion):
        return None if motion is None else camera.with_pose(rvec=motion[0], t=motion[1])

    motion, failed = tracked_motion(
        cfg, cam_in, camera, T, tmp, resume=resume, fit_threads=fit_threads,
        on_frame=None if on_frame is None else (lambda k, m: on_frame(k, posed(m))))
    return [posed(m) for m in motion], failed


def tracked_motion(cfg, cam_in, camera, T: int, tmp: Path, *, resume: bool = False,
                   on_frame=None, fit_threads: int | None = None):
    """:func:`track_poses` as plain arrays: each of the ``T`` frames' ``(rvec, tvec)``
    (the pose of the nearest frame tracked where its own failed: ``(3,)`` rad, ``(3,)``
    model units), and the number of frames that took a neighbour's. ``on_frame(k,
    motion)`` with ``(rvec, tvec)``, or None where frame ``k`` failed. ``camera``: the
    calibrated camera (its pose the first frame's start); the tracking's files go to
    ``tmp / "track<number>"``."""
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

        def finished(res) -> None:
            on_frame(res.frame, (np.asarray(res.rvec, float), np.asarray(res.tvec, float))
                     if res.ok else None)

        tr = track(str(cam_in.video), camera, ms, diameter=dpx,
                   out_dir=Path(tmp) / f"track{cam_in.number}", workers=1,
                   progress=cfg.progress, resume=resume,
                   on_frame=None if on_frame is None else finished, fit_threads=fit_threads)
    ok = np.flatnonzero(tr.status == "ok")
    frame_ok = tr.frame[ok]
    if frame_ok.size == 0:
        raise InputError(f"{cam_in.video}: tracking found the pose in no frame")
    motion, failed = [], 0
    for k in range(T):  # per frame: the pose of the nearest tracked frame
        j = int(np.argmin(np.abs(frame_ok - k)))
        failed += int(frame_ok[j] != k)
        motion.append((np.asarray(tr.rvec[ok[j]], float), np.asarray(tr.tvec[ok[j]], float)))
    return motion, failed


def file_digest(path: str | os.PathLike, block: int = 1 << 23) -> str:
    """XXH3-128 digest (hex) of the whole content of ``path`` (a folder: of its files'
    names and digests, in name order), read in blocks of ``block`` bytes."""
    import xxhash

    p = Path(path)
    h = xxhash.xxh3_128()
    if p.is_dir():
        for q in sorted(x for x in p.rglob("*") if x.is_file()):
            h.update(f"{q.relative_to(p).as_posix()}\0{file_digest(q, block)}\0".encode())
        return h.hexdigest()
    buf = bytearray(block)
    view = memoryview(buf)
    with open(p, "rb") as fh:
        while n := fh.readinto(buf):
            h.update(view[:n])
    return h.hexdigest()


def content_key(paths: dict) -> dict:
    """Each input file (``{key: path or list of paths}``, None left out) with its size and
    :func:`file_digest`: the files' part of a resumed run's key (a file rewritten with the
    same size and its times restored still differs; touching a file does not)."""
    out = {}
    for key, p in paths.items():
        if p is None:
            continue
        for q in (p if isinstance(p, (list, tuple)) else [p]):
            out.setdefault(key, []).append({"path": str(Path(q).resolve()),
                                            "size": os.stat(q).st_size,
                                            "xxh3_128": file_digest(q)})
    return out


def work_inputs(cfg: UnsteadyConfig, T: int, N: int, fps: float) -> dict:
    """What Phase 1's numbers depend on: a resumed run with anything else is refused.
    The files by their content (:func:`content_key`), the settings by value (the fast
    maps or the full ones, ``--full-maps``, included)."""
    return {"software": provenance({})["version"], "files": content_key({
                "grid": cfg.grid, "targets": cfg.targets,
                "videos": [c.video for c in cfg.cameras],
                "calibrations": [c.calibration for c in cfg.cameras],
                "reflectance": cfg.reflectance if os.path.isfile(str(cfg.reflectance))
                else None,
                "unpainted": cfg.unpainted if os.path.isfile(str(cfg.unpainted)) else None,
                "track": cfg.track_dirs, "form_factors": cfg.form_factors}),
            "registration": cfg.registration, "target_patcher": cfg.target_patcher,
            "overlap": cfg.overlap, "filter": cfg.filter, "filter_size": cfg.filter_size,
            "oblique_angle": cfg.oblique_angle, "cutoff_x_max": cfg.cutoff_x_max,
            "frames": T, "nodes": N, "fps": fps,
            "si": cfg.si, "reflectance": str(cfg.reflectance),
            "unpainted": str(cfg.unpainted), "rays": cfg.rays, "seed": cfg.seed,
            "fast_maps": bool(cfg.fast)}


def check_cameras(cfg: UnsteadyConfig, camera_files, srcs, mesh, *, caster=None) -> None:
    """The camera checks of ``map`` for each camera on its video's first frame, before
    any heavy step: the calibration's record in the grid's units
    (:func:`resection.pose.camera_fit.require_same_units`), no two cameras with the same
    calibration, and, with the targets file, each target the camera should see landing on
    a dark spot of the frame (:func:`resection.pose.camera_fit.marker_fit`): calibrations
    swapped between cameras, or one camera's given to both, are refused by name."""
    from resection.io.markers import read_markers
    from resection.pose.camera_fit import marker_fit, require_fit, require_same_units
    from resection.surface.surface_map import SurfaceMap

    cams = [cf.camera for cf in camera_files]
    for i in range(len(cams)):
        for j in range(i):
            a, b = cams[i], cams[j]
            if np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and \
                    np.allclose(a.t, b.t) and np.allclose(a.dist, b.dist):
                ci, cj = cfg.cameras[i], cfg.cameras[j]
                raise InputError(f"{ci.calibration}: camera {ci.number} has the same "
                                 f"calibration as camera {cj.number} ({cj.calibration}): "
                                 "each camera needs its own")
    for c, cf in zip(cfg.cameras, camera_files, strict=True):
        require_same_units(cf.solved_on, mesh.vertices, c.calibration, cfg.grid)
    if cfg.targets is None:
        return
    markers = read_markers(cfg.targets)
    for c, cf, s in zip(cfg.cameras, camera_files, srcs, strict=True):
        img = np.asarray(s[0], dtype=np.float32)
        smap = SurfaceMap(mesh, cf.camera, max_obliqueness=None, caster=caster)
        fit = marker_fit(cf.camera, img, markers, surface_map=smap)
        require_fit(fit, c.calibration, f"{c.video} (frame 0, camera {c.number})")


def check_spot_sizes(spots, mesh, source) -> None:
    """Every target's, tap's and transducer's diameter positive and smaller than the
    model (its bounding box's largest side): a diameter of 1e30, or one in other units
    than the grid, would mask the whole frame (or nothing) and size the tracking's
    windows absurdly."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    size = float(np.max(v.max(axis=0) - v.min(axis=0)))
    d = np.asarray(spots.diameter, dtype=np.float64)
    bad = np.flatnonzero(~((d > 0) & (d < size)))
    if bad.size:
        k = int(bad[0])
        raise InputError(f"{source}: {spots.ids[k]}'s diameter {d[k]:g} is not between 0 and "
                         f"the model's size {size:.4g} ({bad.size} such; the grid's units?)")


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
