"""Per-frame and per-sequence results of :func:`resection.sequence.track`."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from resection.camera.model import Camera
from resection.sequence.motion import relative_motion

#: ``matched_from`` of a frame left uncomputed by its chunk, a placeholder (see
#: :func:`resection.sequence.process.run_chunk`)
DEFERRED = -2

POSE_COLUMNS = ("frame", "file", "status", "reason", "roll_deg", "pitch_deg", "yaw_deg",
                "dx", "dy", "dz", "rms_px", "n_markers", "rvec_x", "rvec_y", "rvec_z",
                "tvec_x", "tvec_y", "tvec_z")
MARKER_COLUMNS = ("frame", "id", "u", "v", "residual", "residual_u", "residual_v")
FORMAT_VERSION = 3  # 2: frame files record their source's fingerprint; 3: its content
# digest, and the fingerprint of the frame it was matched or predicted from

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
    source : list or None
        Fingerprint of the frame's file when it was read (see
        :func:`resection.sequence.frames.fingerprint`); None for an in-memory frame.
    ref_source : list or None
        Fingerprint of the frame ``matched_from`` when this one was computed from it: a
        resumed run recomputes this frame when that one has changed since.
    method : str
        How the markers were associated: ``"predicted"`` (gated windows around the
        positions predicted from the previous poses, :mod:`resection.sequence.predict`),
        ``"matched"`` (the statistical matcher), ``"linked"`` (by hand); ``""`` if failed.
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
    source: list | None = None
    method: str = ""
    ref_source: list | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def camera(self, base: Camera) -> Camera:
        """``base`` (intrinsics) with this frame's pose."""
        return base.with_pose(rvec=self.rvec, t=self.tvec)

    def to_dict(self) -> dict:
        return {
            "version": FORMAT_VERSION, "frame": int(self.frame), "file": self.file,
            "status": self.status, "reason": self.reason,
            "rvec": [float(x) for x in self.rvec], "tvec": [float(x) for x in self.tvec],
            "rms": float(self.rms), "ids": [str(i) for i in self.ids],
            "uv": np.asarray(self.uv, float).tolist(),
            "residuals": np.asarray(self.residuals, float).tolist(),
            "matched_from": int(self.matched_from),
            "source": None if self.source is None else list(self.source),
            "method": self.method,
            "ref_source": None if self.ref_source is None else list(self.ref_source),
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
            source=d.get("source"), method=str(d.get("method", "")),
            ref_source=d.get("ref_source"),
        )


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
    method : (F,) str ndarray or None
        How each frame's markers were associated (:attr:`FrameResult.method`:
        ``predicted``, ``matched``, ``linked``, ``""`` when failed); None when unknown
        (a result read back from the CSVs).
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
    method: np.ndarray | None = None

    @property
    def ok(self) -> np.ndarray:
        """(F,) bool: frames that succeeded."""
        return self.status == "ok"

    def __len__(self) -> int:
        return len(self.frame)

    @property
    def method_counts(self) -> dict:
        """Frames by association method: ``{"predicted": n, "matched": n, "linked": n,
        "failed": n}`` (empty when the methods are unknown). ``matched`` counts the frames
        that went to the statistical matcher."""
        if self.method is None:
            return {}
        m = np.where(self.status == "ok", self.method, "failed")
        return {k: int(np.sum(m == k)) for k in ("predicted", "matched", "linked", "failed")}

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


def assemble(results, fixed_camera: bool, n_computed: int,
              out_dir: str | None) -> TrackResult:
    """The TrackResult of the frames ``results`` (an iterable of FrameResult in frame
    order, consumed one at a time: only the compact arrays of the result are kept)."""
    cols = {k: [] for k in ("frame", "file", "status", "reason", "rms", "rvec", "tvec",
                            "ids", "uv", "residuals", "method")}
    for r in results:
        for k in ("frame", "file", "status", "reason", "rms", "method"):
            cols[k].append(getattr(r, k))
        cols["rvec"].append(np.asarray(r.rvec, float))
        cols["tvec"].append(np.asarray(r.tvec, float))
        cols["ids"].append(np.asarray(r.ids, str))
        cols["uv"].append(np.asarray(r.uv, float).reshape(-1, 2))
        cols["residuals"].append(np.asarray(r.residuals, float).reshape(-1, 2))
    F = len(cols["frame"])
    status = np.array(cols["status"], dtype=object).astype(str)
    rvec = np.array(cols["rvec"], float).reshape(F, 3)
    tvec = np.array(cols["tvec"], float).reshape(F, 3)
    good = np.flatnonzero(status == "ok")
    if good.size:
        ref = int(good[0])
        angles, trans = relative_motion(rvec, tvec, ref, fixed_camera=fixed_camera)
    else:
        ref = -1
        angles = trans = np.full((F, 3), np.nan)
    nm = np.array([len(i) for i in cols["ids"]], int)
    frame = np.array(cols["frame"], int)
    mid = np.concatenate(cols["ids"]) if F else np.zeros(0, str)
    muv = np.vstack(cols["uv"]) if F else np.zeros((0, 2))
    mres = np.vstack(cols["residuals"]) if F else np.zeros((0, 2))
    return TrackResult(
        frame=frame, file=np.array(cols["file"], dtype=object).astype(str),
        status=status, reason=np.array(cols["reason"], dtype=object).astype(str),
        angles=angles, translation=trans, rms=np.array(cols["rms"], float),
        n_markers=nm, rvec=rvec, tvec=tvec, marker_frame=np.repeat(frame, nm),
        marker_id=mid.astype(str), marker_uv=muv.reshape(-1, 2),
        marker_residual=mres.reshape(-1, 2), fixed_camera=fixed_camera, reference=ref,
        n_computed=n_computed, out_dir=out_dir,
        method=np.array(cols["method"], dtype=object).astype(str).reshape(F),
    )
