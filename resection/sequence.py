"""Sequences: markers tracked and the Point of View solved in every frame of a run.

:func:`track` runs, for every frame of a sequence (the paper: 500 frames at 50 fps), marker
detection (:func:`resection.markers.detect_markers`), matching to the 3-D markers from the
previous frame (:func:`resection.match.match_markers`) and the pose
(:func:`resection.pose.solve_pose`), and writes

* ``poses.csv``: one row per frame: ``frame, file, status, reason, roll_deg, pitch_deg,
  yaw_deg, dx, dy, dz, rms_px, n_markers, rvec_x, rvec_y, rvec_z, tvec_x, tvec_y, tvec_z``;
* ``markers.csv``: one row per matched marker and frame: ``frame, id, u, v, residual,
  residual_u, residual_v`` (pixels; residual = observed minus reprojected, and its length).

Motion convention (``fixed_camera=True``: the camera is fixed in the tunnel, the model
moves): the laboratory frame is the model frame at the reference frame (the first frame that
succeeded). At frame ``k`` a model point ``X`` lies at ``Y = M_k X + d_k`` in that frame, with

``M_k = R_0^T R_k``,  ``d_k = R_0^T (t_k - t_0)``

(``R_k, t_k`` the solved camera pose, ``x_cam = R_k X + t_k``). The attitude is reported as
``M_k = Rz(yaw) Ry(pitch) Rx(roll)`` (intrinsic z-y'-x'' sequence, right-handed rotations
about the model's axes; degrees in the files) and ``(dx, dy, dz) = d_k`` is the displacement
of the model origin (model units). With ``fixed_camera=False`` (the model is fixed, the
camera moves) the same columns give the camera's attitude change ``R_k^T R_0`` (same Euler
convention) and the displacement of its perspective centre ``C_k - C_0``, model frame.

Parallelism and resume
----------------------
Frames are split into chunks of ``chunk_size`` consecutive frames. Within a chunk every frame
is matched from the previous successful frame; each chunk starts from the reference frame
(frame 0, linked through ``link`` or matched from the approximate ``camera``), so chunks are
independent and run in parallel on a Dask cluster (by default a ``LocalCluster`` with one
worker process per CPU core, or ``workers`` of them, or the scheduler at ``scheduler``;
``workers=1`` runs in this process, without Dask); the matcher therefore has to bridge
the motion between frame 0 and a chunk's first frame (several pixels are fine; a failed
match is retried once with twice the landing tolerance). After a large excursion that can
still fail: a second, sequential pass then processes again, from the last good frame before
them, the frames that failed while matched from an older frame (corrupt frames, which failed
although matched from the previous good frame, are not redone). The chunking does not depend
on the number of workers, so 1 and N workers give the same results.

Every finished frame is written at once to ``out_dir/frames/frame_NNNNNN.json`` (written to
a temporary file, flushed, fsync'ed and renamed, so a file is either complete or absent).
A run that is interrupted and started again with ``resume=True`` loads these files and
computes only the missing frames; ``poses.csv`` and ``markers.csv`` are merged from them at
the end. On a Dask cluster the file is written by the worker, inside the task, as soon as
the frame is finished (the workers of a local cluster share the filesystem), so an
interruption loses at most the frames in progress, one per worker; the progress bar follows
these files. A worker that cannot write there (a remote cluster without a shared
filesystem) leaves the file to the client, which writes it when the chunk comes back.
A failed frame is recorded (status ``failed`` and the reason) and the run goes on; the next
frame is then matched from the last good one.
"""

from __future__ import annotations

import csv
import dataclasses
import inspect
import json
import os
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ._checks import as_points
from .camera import Camera
from .errors import InputError, SolveError

__all__ = [
    "FrameResult",
    "TrackResult",
    "track",
    "read_track",
    "relative_motion",
    "POSE_COLUMNS",
    "MARKER_COLUMNS",
]

POSE_COLUMNS = ("frame", "file", "status", "reason", "roll_deg", "pitch_deg", "yaw_deg",
                "dx", "dy", "dz", "rms_px", "n_markers", "rvec_x", "rvec_y", "rvec_z",
                "tvec_x", "tvec_y", "tvec_z")
MARKER_COLUMNS = ("frame", "id", "u", "v", "residual", "residual_u", "residual_v")
_FORMAT_VERSION = 1


# --------------------------------------------------------------------------- per frame
@dataclass(frozen=True)
class FrameResult:
    """What one frame gave.

    Attributes
    ----------
    frame : int
        Index of the frame in the sequence (0-based).
    file : str
        The frame's path (``""`` for an in-memory image).
    status : str
        ``"ok"`` or ``"failed"``.
    reason : str
        Why the frame failed (``""`` when ok).
    rvec, tvec : (3,) ndarray
        Solved camera pose (OpenCV Rodrigues vector, radians; translation, model units);
        NaN when failed.
    rms : float
        RMS reprojection error, pixels.
    ids : (n,) ndarray of str
        Matched marker ids.
    uv : (n, 2) ndarray
        Their measured positions, pixels.
    residuals : (n, 2) ndarray
        Observed minus reprojected positions, pixels.
    matched_from : int
        The frame whose markers this one was matched from (-1: the approximate camera or
        the linking).
    """

    frame: int
    file: str
    status: str
    reason: str = ""
    rvec: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    tvec: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    rms: float = float("nan")
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=str))
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    residuals: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    matched_from: int = -1

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def camera(self, base: Camera) -> Camera:
        """``base`` (intrinsics) with this frame's pose."""
        return base.with_pose(rvec=self.rvec, t=self.tvec)

    def to_dict(self) -> dict:
        return {
            "version": _FORMAT_VERSION, "frame": int(self.frame), "file": self.file,
            "status": self.status, "reason": self.reason,
            "rvec": [float(x) for x in self.rvec], "tvec": [float(x) for x in self.tvec],
            "rms": float(self.rms), "ids": [str(i) for i in self.ids],
            "uv": np.asarray(self.uv, float).tolist(),
            "residuals": np.asarray(self.residuals, float).tolist(),
            "matched_from": int(self.matched_from),
        }

    @classmethod
    def from_dict(cls, d: dict) -> FrameResult:
        n = len(d["ids"])
        return cls(
            frame=int(d["frame"]), file=str(d["file"]), status=str(d["status"]),
            reason=str(d["reason"]), rvec=np.array(d["rvec"], float),
            tvec=np.array(d["tvec"], float), rms=float(d["rms"]),
            ids=np.array(d["ids"], dtype=str),
            uv=np.array(d["uv"], float).reshape(n, 2),
            residuals=np.array(d["residuals"], float).reshape(n, 2),
            matched_from=int(d.get("matched_from", -1)),
        )


@dataclass(frozen=True)
class _Setup:
    """Everything a worker needs to process frames (picklable, sent once)."""

    camera: Camera
    ids: np.ndarray
    points3d: np.ndarray
    diameter: float
    polarity: str
    detect_kw: dict
    match_kw: dict
    pose_kw: dict
    min_markers: int
    roi_margin: float | None = None


def _load_image(frame) -> np.ndarray:
    if isinstance(frame, np.ndarray):
        img = frame
    else:
        from .io.images import read_image

        img = read_image(frame, mask_saturated=True)  # saturated pixels -> NaN, masked
    if img.ndim != 2:
        raise InputError(f"expected a 2-D image, got shape {img.shape}")
    return img


def _frame_name(frame) -> str:
    return "" if isinstance(frame, np.ndarray) else os.fspath(frame)


def _search_roi(setup: _Setup, reference: FrameResult | None, shape) -> tuple | None:
    """Bounding box ``(u_min, v_min, u_max, v_max)`` of all the markers projected with the
    reference pose (or the approximate camera), widened by ``roi_margin`` pixels: markers
    cannot be elsewhere, and detection costs grow with the searched area. None: search the
    whole image."""
    if setup.roi_margin is None or "roi" in setup.detect_kw:
        return None
    cam = setup.camera if reference is None else reference.camera(setup.camera)
    uv = cam.project(setup.points3d)
    uv = uv[np.isfinite(uv).all(axis=1)]
    if len(uv) == 0:
        return None
    m = float(setup.roi_margin)
    H, W = shape
    u0, v0 = np.floor(uv.min(axis=0) - m)
    u1, v1 = np.ceil(uv.max(axis=0) + m)
    u0, v0, u1, v1 = max(int(u0), 0), max(int(v0), 0), min(int(u1), W - 1), min(int(v1), H - 1)
    if u1 - u0 < 2 * m or v1 - v0 < 2 * m:  # markers predicted (nearly) off the image
        return None
    return (u0, v0, u1, v1)


def _detect(img: np.ndarray, setup: _Setup, roi=None):
    from .markers import detect_markers

    kw = dict(setup.detect_kw)
    if roi is not None:
        kw["roi"] = roi
    return detect_markers(img, setup.diameter, polarity=setup.polarity, **kw)


def _match(candidates, setup: _Setup, reference: FrameResult | None):
    """Match the candidates to the 3-D markers, from the reference frame's markers (their
    pixel positions) or, without a reference, from the approximate camera. Returns the
    matched ``(ids, uv)`` and the matcher's pose solve (a ``PoseResult``)."""
    from .match import match_markers

    markers3d = (setup.ids, setup.points3d)
    ref = setup.camera if reference is None else (tuple(reference.ids), reference.uv)
    kw = {**setup.match_kw, "pose_kw": setup.pose_kw}
    try:
        m = match_markers(candidates, markers3d, ref, camera=setup.camera, **kw)
    except SolveError as first:
        # The matcher's hypotheses are 2-D similarities: a pitch of a degree or two between
        # the reference and this frame (a chunk's first frame is matched from frame 0) bends
        # the marker pattern by more than the landing tolerance. One retry with twice the
        # tolerance; the matcher's pose verification and residual test still guard it.
        default = inspect.signature(match_markers).parameters["tolerance"].default
        kw["tolerance"] = 2.0 * float(kw.get("tolerance", default))
        try:
            m = match_markers(candidates, markers3d, ref, camera=setup.camera, **kw)
        except SolveError:
            raise SolveError(f"{first} (also with tolerance {kw['tolerance']:g} px)") from None
    return np.asarray(m.marker_ids).astype(str), np.asarray(m.uv, float).reshape(-1, 2), m.pose


def _solve(ids: np.ndarray, uv: np.ndarray, setup: _Setup, frame: int, file: str,
           pose=None) -> FrameResult:
    """The frame's pose from matched markers (``pose``: the matcher's ``PoseResult`` for
    exactly these markers, solved with ``pose_kw``, reused)."""
    from .pose import solve_pose

    index = {k: i for i, k in enumerate(setup.ids)}
    unknown = [i for i in ids if i not in index]
    if unknown:
        raise InputError(f"matched marker id(s) {unknown[:3]} are not in the marker file")
    if len(ids) < setup.min_markers:
        raise SolveError(f"only {len(ids)} markers matched, at least {setup.min_markers} "
                         "needed")
    if pose is None:
        X = setup.points3d[[index[i] for i in ids]]
        pose = solve_pose(setup.camera, X, uv, **setup.pose_kw)
    return FrameResult(frame=frame, file=file, status="ok", rvec=np.asarray(pose.camera.rvec),
                       tvec=np.asarray(pose.camera.t, float), rms=float(pose.rms),
                       ids=np.asarray(ids, dtype=str), uv=np.asarray(uv, float),
                       residuals=np.asarray(pose.residuals, float))


def _process_frame(frame_data, index: int, setup: _Setup,
                   reference: FrameResult | None) -> FrameResult:
    """Read, detect, match from ``reference`` and solve one frame; never raises for a bad
    frame: the failure is returned with its reason."""
    res = _process_frame_unlabelled(frame_data, index, setup, reference)
    return dataclasses.replace(res, matched_from=-1 if reference is None else reference.frame)


def _process_frame_unlabelled(frame_data, index: int, setup: _Setup,
                              reference: FrameResult | None) -> FrameResult:
    name = _frame_name(frame_data)
    try:
        img = _load_image(frame_data)
        if img.shape != (setup.camera.height, setup.camera.width):
            raise InputError(f"image is {img.shape[1]}x{img.shape[0]} px, the camera "
                             f"{setup.camera.width}x{setup.camera.height}")
        if not np.isfinite(img).any():
            raise InputError("image has no finite pixel (all NaN or infinite)")
        cands = _detect(img, setup, _search_roi(setup, reference, img.shape))
        if len(cands) < setup.min_markers:
            raise SolveError(f"only {len(cands)} marker candidates detected")
        ids, uv, pose = _match(cands, setup, reference)
        return _solve(ids, uv, setup, index, name, pose)
    except Exception as exc:  # noqa: BLE001 - any failure of one frame must not stop the run
        msg = str(exc).splitlines()[0] if str(exc) else ""
        reason = f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__
        return FrameResult(frame=index, file=name, status="failed", reason=reason)


def _process_linked(frame_data, index: int, setup: _Setup, link: dict) -> FrameResult:
    """The reference frame through a linking by hand: marker id -> candidate number, the
    candidates being those of ``detect_markers`` on the whole frame (as ``resection detect``
    numbers them). A linking that does not fit the candidates raises InputError."""
    name = _frame_name(frame_data)
    try:
        img = _load_image(frame_data)
        if img.shape != (setup.camera.height, setup.camera.width):
            raise InputError(f"image is {img.shape[1]}x{img.shape[0]} px, the camera "
                             f"{setup.camera.width}x{setup.camera.height}")
        cands = _detect(img, setup)
    except Exception as exc:  # noqa: BLE001 - recorded, the run goes on
        msg = str(exc).splitlines()[0] if str(exc) else ""
        return FrameResult(frame=index, file=name, status="failed",
                           reason=f"{type(exc).__name__}: {msg}")
    ids, uv = _apply_link(cands, link, setup)
    try:
        return _solve(ids, uv, setup, index, name)
    except Exception as exc:  # noqa: BLE001
        msg = str(exc).splitlines()[0] if str(exc) else ""
        return FrameResult(frame=index, file=name, status="failed",
                           reason=f"{type(exc).__name__}: {msg}")


def _apply_link(candidates, link: dict, setup: _Setup) -> tuple[np.ndarray, np.ndarray]:
    markers = (setup.ids, setup.points3d)
    if link["path"] is not None:
        from .link import read_links

        ids, uv, _ = read_links(link["path"], candidates, markers)
        return np.asarray(ids).astype(str), np.asarray(uv, float).reshape(-1, 2)
    pairs = link["pairs"]
    known = set(setup.ids)
    unknown = [k for k in pairs if k not in known]
    if unknown:
        raise InputError(f"link: id(s) not in the marker file: {', '.join(unknown[:10])}")
    idx = np.array([pairs[k] for k in pairs], int)
    if idx.size and (idx.min() < 0 or idx.max() >= len(candidates)):
        raise InputError(f"link: candidate numbers must lie in 0..{len(candidates) - 1} "
                         f"(the first frame has {len(candidates)} candidates)")
    if len(set(idx.tolist())) != idx.size:
        raise InputError("link: a candidate is linked twice")
    return np.array(list(pairs), dtype=str), candidates.uv[idx].reshape(-1, 2)


def _run_chunk(setup: _Setup, items: list, seed: FrameResult | None,
               done: dict | None = None,
               on_frame: Callable[[FrameResult], None] | None = None,
               frames_dir: str | None = None) -> list[dict]:
    """Process consecutive frames ``items = [(index, frame), ...]``, each matched from the
    previous good one (the first from ``seed``). Frames already in ``done`` (index -> dict)
    are not recomputed but serve as references. With ``frames_dir`` (a Dask task) every
    frame's result file is written there as soon as the frame is finished, so that an
    interruption loses at most the frame in progress. Returns the frames' dictionaries."""
    done = done or {}
    ref = seed
    out = []
    for index, frame in items:
        if index in done:
            res = FrameResult.from_dict(done[index])
        else:
            res = _process_frame(frame, index, setup, ref)
            if frames_dir is not None:
                _try_write_frame(Path(frames_dir), res)
            if on_frame is not None:
                on_frame(res)
        if res.ok:
            ref = res
        out.append(res.to_dict())
    return out


def _repair(frames: list, setup: _Setup, done: dict, record) -> None:
    """Second, sequential pass over the frames that failed while matched from a frame other
    than the last good one before them (a chunk's first frames are matched from frame 0:
    after a large excursion that can fail where matching from the previous frame works).
    Such a frame is processed again from the last good frame; a frame that failed although
    matched from it (a corrupt frame) is left as it is, so the pass is cheap and a resumed
    run does not redo it. Deterministic: it depends only on the first pass' results."""
    last_good = None
    for i in range(len(frames)):
        d = done[i]
        if d["status"] == "ok":
            last_good = i
            continue
        if last_good is None or d.get("matched_from", -1) == last_good:
            continue
        res = _process_frame(frames[i], i, setup, FrameResult.from_dict(done[last_good]))
        record(res)
        if res.ok:
            last_good = i


# --------------------------------------------------------------------------- files
def _atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _frame_path(frames_dir: Path, index: int) -> Path:
    return frames_dir / f"frame_{index:06d}.json"


def _frame_text(d: dict) -> str:
    return json.dumps(d)


def _write_frame(frames_dir: Path, res: FrameResult) -> None:
    _atomic_write_text(_frame_path(frames_dir, res.frame), _frame_text(res.to_dict()))


def _try_write_frame(frames_dir: Path, res: FrameResult) -> None:
    """A worker's write of a finished frame. A worker that cannot reach the output directory
    (a remote cluster without a shared filesystem) leaves it to the client, which writes
    the frame when the chunk comes back."""
    try:
        _write_frame(frames_dir, res)
    except OSError:
        pass


def _read_frame(path: Path) -> dict | None:
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(d, dict) or d.get("version") != _FORMAT_VERSION:
        return None
    return d


# --------------------------------------------------------------------------- motion
def relative_motion(rvecs, tvecs, reference: int = 0, *,
                    fixed_camera: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Attitude and position change of every frame relative to a reference frame.

    Parameters
    ----------
    rvecs, tvecs : (F, 3) array_like
        Camera poses (``x_cam = R(rvec) X + t``), NaN rows for failed frames.
    reference : int
        Index of the reference frame (must have a finite pose).
    fixed_camera : bool
        True: the model moves in front of a fixed camera; return the model's attitude
        ``M = R_0^T R_k`` and origin displacement ``R_0^T (t_k - t_0)``. False: the camera
        moves around a fixed model; return ``R_k^T R_0`` and ``C_k - C_0``.

    Returns
    -------
    angles : (F, 3) ndarray
        ``(roll, pitch, yaw)`` in degrees with ``M = Rz(yaw) Ry(pitch) Rx(roll)``.
    translation : (F, 3) ndarray
        Model units; NaN rows for failed frames.
    """
    rv = as_points(rvecs, 3, "rvecs", allow_nan=True)
    tv = as_points(tvecs, 3, "tvecs", allow_nan=True)
    if len(rv) != len(tv):
        raise InputError(f"relative_motion: {len(rv)} rvecs but {len(tv)} tvecs")
    if not (0 <= reference < len(rv)) or not np.all(np.isfinite(rv[reference])):
        raise InputError(f"relative_motion: reference frame {reference} has no pose")
    good = np.all(np.isfinite(rv), axis=1) & np.all(np.isfinite(tv), axis=1)
    angles = np.full((len(rv), 3), np.nan)
    trans = np.full((len(rv), 3), np.nan)
    if not good.any():
        return angles, trans
    R = Rotation.from_rotvec(rv[good]).as_matrix()
    R0 = Rotation.from_rotvec(rv[reference]).as_matrix()
    t0 = tv[reference]
    if fixed_camera:
        M = np.einsum("ji,njk->nik", R0, R)
        d = (tv[good] - t0) @ R0  # R0^T (t - t0) per row
    else:
        M = np.einsum("nji,jk->nik", R, R0)
        C = -np.einsum("nji,nj->ni", R, tv[good])
        d = C - (-R0.T @ t0)
    ypr = Rotation.from_matrix(M).as_euler("ZYX")
    angles[good] = np.degrees(ypr[:, ::-1])
    trans[good] = d
    return angles, trans


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class TrackResult:
    """The per-frame poses and marker positions of a tracked sequence.

    Attributes
    ----------
    frame : (F,) int ndarray
    file : (F,) str ndarray
    status, reason : (F,) str ndarrays
    angles : (F, 3) ndarray
        ``(roll, pitch, yaw)``, degrees (see the module docstring for the convention).
    translation : (F, 3) ndarray
        ``(dx, dy, dz)``, model units.
    rms : (F,) ndarray
        RMS reprojection error, pixels.
    n_markers : (F,) int ndarray
    rvec, tvec : (F, 3) ndarrays
        Solved camera poses.
    marker_frame : (K,) int ndarray
    marker_id : (K,) str ndarray
    marker_uv : (K, 2) ndarray
        Measured marker positions, pixels.
    marker_residual : (K, 2) ndarray
        Observed minus reprojected, pixels.
    fixed_camera : bool
    reference : int
        The frame the motion is relative to (-1 when no frame succeeded).
    n_computed : int
        Frames computed by this call (the others were resumed from ``out_dir``).
    out_dir : str or None
    """

    frame: np.ndarray
    file: np.ndarray
    status: np.ndarray
    reason: np.ndarray
    angles: np.ndarray
    translation: np.ndarray
    rms: np.ndarray
    n_markers: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    marker_frame: np.ndarray
    marker_id: np.ndarray
    marker_uv: np.ndarray
    marker_residual: np.ndarray
    fixed_camera: bool = True
    reference: int = 0
    n_computed: int = 0
    out_dir: str | None = None

    @property
    def ok(self) -> np.ndarray:
        """(F,) bool: frames that succeeded."""
        return self.status == "ok"

    def __len__(self) -> int:
        return len(self.frame)

    def marker_positions(self, ids) -> np.ndarray:
        """``(F, len(ids), 2)`` measured positions of the given markers in every frame, NaN
        where a marker was not matched."""
        ids = [str(i) for i in ids]
        out = np.full((len(self.frame), len(ids), 2), np.nan)
        col = {k: j for j, k in enumerate(ids)}
        row = {int(f): i for i, f in enumerate(self.frame)}
        sel = np.array([m in col for m in self.marker_id], bool)
        if sel.any():
            r = np.array([row[int(f)] for f in self.marker_frame[sel]])
            c = np.array([col[m] for m in self.marker_id[sel]])
            out[r, c] = self.marker_uv[sel]
        return out


def _assemble(results: list[FrameResult], fixed_camera: bool, n_computed: int,
              out_dir: str | None) -> TrackResult:
    F = len(results)
    status = np.array([r.status for r in results], dtype=object).astype(str)
    rvec = np.array([r.rvec for r in results], float).reshape(F, 3)
    tvec = np.array([r.tvec for r in results], float).reshape(F, 3)
    good = np.flatnonzero(status == "ok")
    if good.size:
        ref = int(good[0])
        angles, trans = relative_motion(rvec, tvec, ref, fixed_camera=fixed_camera)
    else:
        ref = -1
        angles = trans = np.full((F, 3), np.nan)
    nm = np.array([len(r.ids) for r in results], int)
    mf = np.repeat(np.array([r.frame for r in results], int), nm)
    mid = np.concatenate([np.asarray(r.ids, str) for r in results]) if F else np.zeros(0, str)
    muv = np.vstack([r.uv for r in results]) if F else np.zeros((0, 2))
    mres = np.vstack([r.residuals for r in results]) if F else np.zeros((0, 2))
    return TrackResult(
        frame=np.array([r.frame for r in results], int),
        file=np.array([r.file for r in results], dtype=object).astype(str),
        status=status, reason=np.array([r.reason for r in results], dtype=object).astype(str),
        angles=angles, translation=trans, rms=np.array([r.rms for r in results], float),
        n_markers=nm, rvec=rvec, tvec=tvec, marker_frame=mf, marker_id=mid.astype(str),
        marker_uv=muv.reshape(-1, 2), marker_residual=mres.reshape(-1, 2),
        fixed_camera=fixed_camera, reference=ref, n_computed=n_computed, out_dir=out_dir,
    )


def _fmt(x: float) -> str:
    return "" if not np.isfinite(x) else f"{x:.10g}"


def _write_csvs(result: TrackResult, out: Path) -> None:
    import io

    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(POSE_COLUMNS)
    for i in range(len(result)):
        w.writerow([int(result.frame[i]), result.file[i], result.status[i], result.reason[i],
                    *map(_fmt, result.angles[i]), *map(_fmt, result.translation[i]),
                    _fmt(result.rms[i]), int(result.n_markers[i]),
                    *map(_fmt, result.rvec[i]), *map(_fmt, result.tvec[i])])
    _atomic_write_text(out / "poses.csv", buf.getvalue())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(MARKER_COLUMNS)
    res = result.marker_residual
    for k in range(len(result.marker_frame)):
        w.writerow([int(result.marker_frame[k]), result.marker_id[k],
                    f"{result.marker_uv[k, 0]:.6f}", f"{result.marker_uv[k, 1]:.6f}",
                    f"{np.hypot(*res[k]):.6f}", f"{res[k, 0]:.6f}", f"{res[k, 1]:.6f}"])
    _atomic_write_text(out / "markers.csv", buf.getvalue())


def read_track(out_dir: str | os.PathLike) -> TrackResult:
    """Read the ``poses.csv`` and ``markers.csv`` written by :func:`track`."""
    out = Path(out_dir)
    pose_path, marker_path = out / "poses.csv", out / "markers.csv"
    for p in (pose_path, marker_path):
        if not p.is_file():
            raise InputError(f"{p}: not found (is {out} a track output directory?)")
    with open(pose_path, encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or tuple(rows[0]) != POSE_COLUMNS:
        raise InputError(f"{pose_path}: header is not {','.join(POSE_COLUMNS)}")
    body = rows[1:]

    def num(s):
        return float(s) if s != "" else np.nan

    def col(name):
        return [r[POSE_COLUMNS.index(name)] for r in body]

    def cols(*names):
        return np.array([[num(r[POSE_COLUMNS.index(n)]) for n in names] for r in body],
                        float).reshape(len(body), len(names))

    with open(marker_path, encoding="utf-8", newline="") as fh:
        mrows = list(csv.reader(fh))
    if not mrows or tuple(mrows[0]) != MARKER_COLUMNS:
        raise InputError(f"{marker_path}: header is not {','.join(MARKER_COLUMNS)}")
    mb = mrows[1:]
    status = np.array(col("status"), dtype=object).astype(str)
    good = np.flatnonzero(status == "ok")
    meta = {}
    if (out / "track.json").is_file():
        with open(out / "track.json", encoding="utf-8") as fh:
            meta = json.load(fh)
    return TrackResult(
        frame=np.array(col("frame"), int), file=np.array(col("file"), dtype=object).astype(str),
        status=status, reason=np.array(col("reason"), dtype=object).astype(str),
        angles=cols("roll_deg", "pitch_deg", "yaw_deg"), translation=cols("dx", "dy", "dz"),
        rms=cols("rms_px")[:, 0], n_markers=np.array(col("n_markers"), int),
        rvec=cols("rvec_x", "rvec_y", "rvec_z"), tvec=cols("tvec_x", "tvec_y", "tvec_z"),
        marker_frame=np.array([r[0] for r in mb], int),
        marker_id=np.array([r[1] for r in mb], dtype=object).astype(str),
        marker_uv=np.array([[float(r[2]), float(r[3])] for r in mb], float).reshape(-1, 2),
        marker_residual=np.array([[float(r[5]), float(r[6])] for r in mb],
                                 float).reshape(-1, 2),
        fixed_camera=bool(meta.get("fixed_camera", True)),
        reference=int(good[0]) if good.size else -1, n_computed=0, out_dir=str(out),
    )


# --------------------------------------------------------------------------- inputs
def _as_markers(markers3d) -> tuple[np.ndarray, np.ndarray]:
    """``(ids, points)`` from a marker file path, an ``(ids, points)`` pair, or an object
    with ``ids`` and ``points``/``xyz`` attributes."""
    if isinstance(markers3d, (str, os.PathLike)):
        from .io.markers import read_markers

        markers3d = read_markers(markers3d)
    if isinstance(markers3d, tuple) and len(markers3d) == 2:
        ids, pts = markers3d
    else:
        ids = getattr(markers3d, "ids", None)
        pts = getattr(markers3d, "points", getattr(markers3d, "xyz", None))
        if ids is None or pts is None:
            raise InputError("markers3d: expected a marker file, (ids, points) or an object "
                             "with ids and points")
    pts = as_points(pts, 3, "markers3d points")
    ids = np.asarray(ids).astype(str).ravel()
    if len(ids) != len(pts):
        raise InputError(f"markers3d: {len(ids)} ids for {len(pts)} points")
    u, c = np.unique(ids, return_counts=True)
    if np.any(c > 1):
        raise InputError(f"markers3d: duplicate marker id {str(u[c > 1][0])!r}")
    return ids, pts


def _check_options(kw, func, name: str, reserved: tuple) -> dict:
    """Checked copy of extra keyword arguments for ``func``: a bad name would otherwise
    make every frame fail, one by one."""
    if kw is None:
        return {}
    if not isinstance(kw, dict):
        raise InputError(f"{name}: expected a dict of {func.__name__} options, got "
                         f"{type(kw).__name__}")
    params = inspect.signature(func).parameters
    allowed = {k for k, p in params.items()
               if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and k not in reserved}
    unknown = sorted(str(k) for k in kw if k not in allowed)
    if unknown:
        why = [k for k in unknown if k in reserved]
        note = (f" ({', '.join(why)}: set by track itself; the intrinsics stay those of "
                "the camera)" if why else "")
        raise InputError(f"{name}: unknown or reserved {func.__name__} option(s) {unknown}"
                         f"{note}; expected some of {sorted(allowed)}")
    return dict(kw)


def _as_link(link) -> dict | None:
    """``{"path": str or None, "pairs": {id: candidate} or None, "text": file content}``."""
    if link is None:
        return None
    if isinstance(link, (str, os.PathLike)):
        path = os.fspath(link)
        try:
            with open(path, encoding="utf-8") as fh:
                text = fh.read()
        except FileNotFoundError:
            raise InputError(f"{path}: no such linking file") from None
        except OSError as exc:
            raise InputError(f"{path}: cannot read the linking file ({exc})") from None
        return {"path": path, "pairs": None, "text": text}
    if not isinstance(link, dict) or not link:
        raise InputError("link: expected a linking CSV (id,candidate) or a non-empty "
                         "{id: candidate number} dict")
    try:
        pairs = {str(k): int(v) for k, v in link.items()}
    except (TypeError, ValueError):
        raise InputError("link: candidate numbers must be integers") from None
    return {"path": None, "pairs": pairs, "text": None}


def _settings(setup: _Setup, link: dict | None, fixed_camera: bool, chunk_size: int) -> dict:
    """The settings a resumed run must share with the interrupted one (JSON-able)."""
    def plain(d):
        return json.loads(json.dumps(d, default=lambda o: np.asarray(o).tolist()))

    return plain({
        "version": _FORMAT_VERSION,
        "camera": setup.camera.to_dict(),
        "markers": {"ids": setup.ids.tolist(), "points": setup.points3d.tolist()},
        "diameter": setup.diameter, "polarity": setup.polarity,
        "detect_kw": setup.detect_kw, "match_kw": setup.match_kw, "pose_kw": setup.pose_kw,
        "min_markers": setup.min_markers, "roi_margin": setup.roi_margin,
        "link": None if link is None else (link["text"] if link["path"] is not None
                                           else {k: link["pairs"][k]
                                                 for k in sorted(link["pairs"])}),
        "fixed_camera": bool(fixed_camera), "chunk_size": int(chunk_size),
    })


# --------------------------------------------------------------------------- the driver
def _execute_local(setup, tasks, on_frame):
    for items, seed, done in tasks:
        _run_chunk(setup, items, seed, done, on_frame)


def _execute_dask(setup, tasks, on_chunk, on_poll, scheduler, workers, frames_dir,
                  poll_s: float = 0.25, connect_timeout: float = 20.0):
    """Run the chunks on Dask. The tasks write every finished frame to ``frames_dir``
    themselves; ``on_poll()`` is called while waiting (it picks those files up, for the
    progress bar) and ``on_chunk(dicts)`` when a chunk comes back."""
    import logging
    import time

    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout=connect_timeout)
        except (OSError, ValueError, TypeError) as exc:  # unreachable or malformed address
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(f"scheduler: cannot connect to the Dask scheduler at "
                             f"{scheduler!r} ({msg})") from None
    try:
        s = client.scatter(setup, broadcast=True)
        futures = [client.submit(_run_chunk, s, items, seed, done, None, frames_dir,
                                 pure=False)
                   for items, seed, done in tasks]
        pending = as_completed(futures)
        while not pending.is_empty():
            if pending.has_ready():
                for fut in pending.next_batch(block=False):
                    on_chunk(fut.result())
            else:
                on_poll()
                time.sleep(poll_s)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _default_workers() -> int:
    """Worker processes of the default local cluster: one per CPU core."""
    return max(int(os.cpu_count() or 1), 1)


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
    from .markers import detect_markers
    from .match import match_markers
    from .pose import solve_pose

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
