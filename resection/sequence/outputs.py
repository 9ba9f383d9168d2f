"""Files of a tracked sequence: per-frame result files, ``poses.csv``, ``markers.csv``, and
:func:`read_track`."""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path

import numpy as np

from resection.defaults import TRACK_PRODUCER
from resection.errors import InputError
from resection.io.marks import PRODUCER_KEY
from resection.io.outputs import atomic_path
from resection.sequence.results import (
    DEFERRED,
    FORMAT_VERSION,
    MARKER_COLUMNS,
    POSE_COLUMNS,
    FrameResult,
    TrackResult,
)


def atomic_write_text(path: Path, text: str, *, sync: bool = True) -> None:
    """Write ``text`` to a temporary file next to ``path`` and rename it into place: a
    crash of the process leaves the old file or the new one, never half of one. ``sync``
    also flushes it to the disk first (against a crash of the machine); the per-frame
    files skip that (it costs more than tracking the frame): after a power cut a frame
    file may be empty or truncated, and a resumed run then reads it as missing and
    computes the frame again."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        fh.write(text)
        if sync:
            fh.flush()
            os.fsync(fh.fileno())


def frame_path(frames_dir: Path, index: int) -> Path:
    return frames_dir / f"frame_{index:06d}.json"


def frame_text(d: dict) -> str:
    return json.dumps(d)


def write_frame(frames_dir: Path, res: FrameResult) -> None:
    atomic_write_text(frame_path(frames_dir, res.frame), frame_text(res.to_dict()),
                       sync=False)


class FrameWriter:
    """The per-frame files written by a thread, beside the tracking: encoding a frame's
    record and writing its file (:func:`write_frame`) cost a sixth of a tracked frame.
    :meth:`write` queues a frame's dictionary (at most :attr:`MAX_PENDING` wait: memory
    stays flat); :meth:`flush` waits until every queued file is written and raises the
    first error of the thread (a full disk, ...), as the write itself would have."""

    MAX_PENDING = 16

    def __init__(self, frames_dir: Path) -> None:
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        self._dir = frames_dir
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="track-write")
        self._pending: deque = deque()

    def write(self, d: dict) -> None:
        """Queue the file of the frame whose record is ``d`` (not changed afterwards)."""
        while self._pending and (self._pending[0].done()
                                 or len(self._pending) >= self.MAX_PENDING):
            self._pending.popleft().result()  # raises the thread's error
        self._pending.append(self._pool.submit(_write_record, self._dir, d))

    def flush(self) -> None:
        """Wait for every queued file; raise the first error."""
        while self._pending:
            self._pending.popleft().result()

    def close(self) -> None:
        """Write what is queued (errors are raised by :meth:`flush`, not here) and stop."""
        self._pool.shutdown(wait=True)
        self._pending.clear()


def _write_record(frames_dir: Path, d: dict) -> None:
    atomic_write_text(frame_path(frames_dir, d["frame"]), frame_text(d), sync=False)


def try_write_frame(frames_dir: Path, res: FrameResult) -> None:
    """A worker's write of a finished frame. A worker that cannot reach the output directory
    (a remote cluster without a shared filesystem) leaves it to the client, which writes
    the frame when the chunk comes back."""
    try:
        write_frame(frames_dir, res)
    except OSError:
        pass


def read_frame(path: Path) -> dict | None:
    try:
        with open(path, encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(d, dict) or d.get("version") != FORMAT_VERSION:
        return None
    return d

def _fmt(x: float) -> str:
    return "" if not np.isfinite(x) else f"{x:.10g}"


def write_csvs(result: TrackResult, out: Path) -> None:
    """``poses.csv`` and ``markers.csv``, each streamed to a temporary file (in blocks of
    rows, not built in memory) and renamed into place."""
    def poses():
        for i in range(len(result)):
            yield [int(result.frame[i]), result.file[i], result.status[i], result.reason[i],
                   *map(_fmt, result.angles[i]), *map(_fmt, result.translation[i]),
                   _fmt(result.rms[i]), int(result.n_markers[i]),
                   *map(_fmt, result.rvec[i]), *map(_fmt, result.tvec[i])]

    def markers():
        res, uv = result.marker_residual, result.marker_uv
        err = np.hypot(res[:, 0], res[:, 1])
        for k in range(len(result.marker_frame)):
            yield [int(result.marker_frame[k]), result.marker_id[k], f"{uv[k, 0]:.6f}",
                   f"{uv[k, 1]:.6f}", f"{err[k]:.6f}", f"{res[k, 0]:.6f}", f"{res[k, 1]:.6f}"]

    _atomic_write_rows(out / "poses.csv", POSE_COLUMNS, poses())
    _atomic_write_rows(out / "markers.csv", MARKER_COLUMNS, markers())


def _atomic_write_rows(path: Path, header, rows) -> None:
    """CSV rows written to a temporary file next to ``path``, synced, renamed into place."""
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(header)
        w.writerows(rows)
        fh.flush()
        os.fsync(fh.fileno())


def frames_from_files(frames_dir: Path, n: int):
    """The finished frames ``0 .. n-1`` read back from their files, one at a time."""
    for i in range(n):
        d = read_frame(frame_path(frames_dir, i))
        if d is None or d.get("frame") != i:
            raise InputError(f"{frame_path(frames_dir, i)}: missing or unreadable; another "
                             "process changed the output folder during the run?")
        yield FrameResult.from_dict(d)


def finished_frames(frames_dir: str | os.PathLike) -> int:
    """How many frames of a run in ``frames_dir`` are finished: the readable frame files,
    less the placeholders of a deferred chunk (a chunk that could not start from frame 0
    and was not computed yet: a resumed run computes them, :func:`start_run`)."""
    n = 0
    for path in Path(frames_dir).glob("frame_*.json"):
        d = read_frame(path)
        n += d is not None and d.get("matched_from") != DEFERRED
    return n


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
    for path, table, width in ((pose_path, body, len(POSE_COLUMNS)),
                               (marker_path, mb, len(MARKER_COLUMNS))):
        short = next((k for k, r in enumerate(table) if len(r) != width), None)
        if short is not None:
            raise InputError(f"{path}: line {short + 2} has {len(table[short])} fields, "
                             f"expected {width} (a truncated or edited file?)")
    try:
        return _track_result(out, body, mb, col, cols)
    except ValueError as exc:
        raise InputError(f"{out}: a non-numeric value in poses.csv or markers.csv "
                         f"({exc})") from None


def _track_result(out: Path, body, mb, col, cols) -> TrackResult:
    status = np.array(col("status"), dtype=object).astype(str)
    good = np.flatnonzero(status == "ok")
    meta = _read_manifest(out / "track.json") or {}
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


def _read_manifest(manifest: Path) -> dict | None:
    """The settings recorded in ``track.json`` (without the producer's mark), or None when
    it is missing, unreadable or not a track manifest."""
    try:
        with open(manifest, encoding="utf-8") as fh:
            old = json.load(fh)
    except (OSError, ValueError, RecursionError):
        return None
    if not isinstance(old, dict) or old.get(PRODUCER_KEY) != TRACK_PRODUCER:
        return None
    return {k: v for k, v in old.items() if k != PRODUCER_KEY}


def start_run(out: Path, frames: list, settings: dict, resume: bool) -> dict[int, tuple]:
    """Prepare ``out`` (locked by the caller) for a run: check that a run there had the same
    settings, write them, and return the frames already finished that are still right, as
    ``index -> (ok, matched_from)``; the result files of the others are removed.

    A frame is kept when its file has not changed (:func:`~.frames.fingerprint`: metadata
    and a digest of a sample of its content) and the frame it was matched or predicted
    from is kept too, unchanged since (its recorded fingerprint): a frame computed from a
    frame that changed is computed again. A deferred chunk's placeholder is no result: its
    frame is computed (in its chunk, in parallel, rather than by the sequential pass). A
    missing or unreadable manifest means the settings of the frames found are unknown: they
    are all computed again."""
    from resection.sequence.frames import changed, frame_name

    frames_dir = out / "frames"
    manifest = out / "track.json"
    old = _read_manifest(manifest) if resume else None
    if old is not None and old != settings:
        diff = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
        raise InputError(f"{out}: holds a run with other settings ({', '.join(diff)}); "
                         "use another out_dir or resume=False")
    if old is None:  # a fresh run, or settings unknown: no frame of before is kept
        for p in frames_dir.glob("frame_*.json"):
            p.unlink()
    atomic_write_text(manifest, json.dumps({PRODUCER_KEY: TRACK_PRODUCER, **settings},
                                            indent=1))
    done: dict[int, tuple] = {}
    if old is None:
        return done
    names = set(os.listdir(frames_dir))
    sources: dict[int, object] = {}  # fingerprints of the frames kept
    digests: dict = {}  # the files' content digests (:func:`~.frames.fingerprint`)
    for i, f in enumerate(frames):
        path = frame_path(frames_dir, i)
        if path.name not in names:
            continue
        d = read_frame(path)
        if d is None:
            continue
        if d["frame"] != i or d["file"] != frame_name(f):
            raise InputError(f"{out}: frame {i} was {d['file']!r} in the interrupted run, "
                             f"now {frame_name(f)!r}; use another out_dir or resume=False")
        ref = int(d.get("matched_from", -1))
        stale_ref = ref >= 0 and (ref not in sources or d.get("ref_source") != sources[ref])
        if ref == DEFERRED or stale_ref or changed(f, d.get("source"), digests):  # again
            path.unlink()
            continue
        sources[i] = d.get("source")
        done[i] = summary(d)
    return done


def summary(d: dict) -> tuple[bool, int]:
    """What the run keeps in memory of a finished frame: ``(ok, matched_from)``; the rest
    is in its file."""
    return d["status"] == "ok", int(d.get("matched_from", -1))
