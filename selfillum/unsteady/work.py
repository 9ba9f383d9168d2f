"""Phase 1's work, kept so that an interrupted run resumes (``--resume``) without
recomputing its finished blocks of frames, and never reuses stale work.

The work folder ``OUT.h5.work/`` (next to the output) holds ``phase1.h5``: the node
intensities with the SI removal (``values``) and, in a run that removes it, without
(``raw``), ``(T, N)``, chunked as ``/dcp``, every camera's pose per frame (``R``, ``t``),
``frames_done`` (the
frames committed, a whole number of blocks) and ``inputs`` (JSON: every input file with its
size and a digest of its whole content, every setting that changes Phase 1's numbers, the
software's version: :func:`selfillum.unsteady.inputs.work_inputs`). It is written through
the project's undo journal (:class:`resection.io.journal.JournaledFile`, as ``map --out
P.h5``'s history): a block is
committed when its rows, the poses and ``frames_done`` are flushed; a run killed in the
middle of a block (Ctrl-C, ``kill -9``, a full disk) leaves the file as it was at its last
commit. The form factors (``F.npz``) and the tracking (``trackN/``) are kept there too.

The intensities are stored as uint16 codes with a power-of-two scale per frame
(``values_scale``, ``raw_scale``: :func:`encode_rows`): ``I = code / scale``, code 0 = unseen
(NaN, or an intensity <= 0, which Phase 2 treats as unseen too). The scale is the largest
power of two that keeps the frame's brightest node within 65,535, so the rounding error of
a node is under ``max_frame / 65535`` (1.5e-5 of the frame's brightest node; for 12-bit
video at most 1/32 of a count, a sixteenth of the sensor's own rounding). Half the bytes of
float32 to write in Phase 1 and to read in Phase 2.

The folder is the run's own: it holds a marker file (:data:`MARKER`: ``written_by`` and a
random ``token``, which ``phase1.h5`` repeats) written when the run creates the folder. A
folder of that name without the marker (the user's) is refused, never used nor removed. A
run holds the folder's lock (:func:`resection.io.lock.lock_folder`) from before it reads
anything in it to after it removed it: a second run on the same ``--out`` (two ``--resume``
at once) is refused and touches nothing. A folder found without ``--resume`` is refused (it
is the work of an interrupted run); with ``--resume``, a folder whose ``inputs`` differ from
this run's is refused by name (the keys that differ), and a damaged ``phase1.h5`` or
``F.npz`` by its name: remove the folder to start again. The folder is removed when the run
has succeeded.
"""

from __future__ import annotations

import functools
import json
import secrets
import shutil
from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["work_folder", "Phase1Store", "BlockBuffer", "encode_rows", "decode_columns",
           "CODE_MAX", "ENCODING"]

FORMAT = "selfillum-unsteady-work"
#: The marker file that makes a folder the work folder of a run (``written_by``, ``token``).
MARKER = "selfillum-unsteady-work.json"
PRODUCER = "selfillum unsteady"
#: Largest code of the work file's intensities.
CODE_MAX = 65535
#: The encoding's name (a key of the work's inputs: a resume needs the same).
ENCODING = "uint16, power-of-two scale per frame"


def encode_rows(rows, codes=None) -> tuple[np.ndarray, np.ndarray]:
    """Intensities ``(n, N)`` (NaN unseen) to uint16 codes and a scale per row.

    Returns
    -------
    codes : (n, N) uint16
        ``rint(I scale)`` (at least 1 where ``I > 0``), 0 where ``I`` is NaN or <= 0.
    scale : (n,) float64
        ``2 ** floor(log2(65535 / max_row))`` (1 for a row with nothing seen).
    """
    x = np.ascontiguousarray(np.atleast_2d(rows), dtype=np.float32)
    if codes is None:
        codes = np.empty(x.shape, np.uint16)
    scale = np.empty(len(x))
    _encoder()(x, codes, scale, float(CODE_MAX))
    return codes, scale


def decode_columns(codes, scale) -> np.ndarray:
    """uint16 codes ``(T, n)`` with their per-frame ``scale`` (T,) back to float64
    intensities, NaN where the code is 0."""
    c = np.asarray(codes)
    x = c / np.asarray(scale, dtype=np.float64)[:, None]
    return np.where(c > 0, x, np.nan)


@functools.cache
def _encoder():
    import numba

    @numba.njit(cache=True, nogil=True)
    def encode(x, codes, scale, cmax):  # pragma: no cover - compiled
        n, N = x.shape
        for i in range(n):
            mx = 0.0
            for j in range(N):
                v = x[i, j]
                if v > mx:  # False on NaN
                    mx = v
            s = 2.0 ** np.floor(np.log2(cmax / mx)) if mx > 0 else 1.0
            scale[i] = s
            for j in range(N):
                v = x[i, j]
                if v > 0:
                    c = np.rint(v * s)
                    codes[i, j] = max(min(c, cmax), 1.0)
                else:
                    codes[i, j] = 0

    return encode


class BlockBuffer:
    """A block of ``n`` frames of ``N`` nodes, encoded frame by frame as they come
    (uint16 codes and scales; ``raw`` only in a run that removes the SI). ``nondata``:
    (N,) bool, nodes that get no data (:func:`selfillum.unsteady.grid.nondata_nodes`)."""

    def __init__(self, n: int, N: int, with_raw: bool, nondata=None):
        self.values = np.zeros((n, N), np.uint16)
        self.values_scale = np.ones(n)
        self.raw = np.zeros((n, N), np.uint16) if with_raw else None
        self.raw_scale = np.ones(n) if with_raw else None
        self.nondata = None if nondata is None or not np.any(nondata) else \
            np.asarray(nondata, bool)

    def put(self, i: int, values, raw=None) -> None:
        """Frame ``i`` of the block (node intensities, (N,), NaN unseen); the
        ``nondata`` nodes (uPSP's ``cutoff_x_max``) stored unseen."""
        if self.nondata is not None:
            values = np.where(self.nondata, np.nan, values)
            raw = None if raw is None else np.where(self.nondata, np.nan, raw)
        _, s = encode_rows(values, self.values[i:i + 1])
        self.values_scale[i] = s[0]
        if self.raw is not None:
            _, s = encode_rows(raw, self.raw[i:i + 1])
            self.raw_scale[i] = s[0]

    def rows(self, n: int) -> dict:
        """The first ``n`` frames: ``{name: (codes, scale)}``."""
        out = {"values": (self.values[:n], self.values_scale[:n])}
        if self.raw is not None:
            out["raw"] = (self.raw[:n], self.raw_scale[:n])
        return out


def work_folder(out) -> Path:
    """``OUT.h5`` -> ``OUT.h5.work``."""
    out = Path(out)
    return out.with_name(out.name + ".work")


class Phase1Store:
    """Phase 1's blocks of frames, journaled (see the module notes).

    Parameters
    ----------
    out : path
        The run's output (the folder is ``OUT.h5.work``).
    inputs : dict
        JSON-able record of what Phase 1 is computed from.
    shape : (T, N)
    chunks : (tc, nc)
    n_cameras : int
    resume : bool
    with_raw : bool
        Keep the intensities without the SI removal too (a run that removes it).
    """

    def __init__(self, out, inputs: dict, shape, chunks, n_cameras: int, *, resume: bool,
                 with_raw: bool = True):
        import contextlib

        from resection.io.lock import lock_folder

        self.folder = work_folder(out)
        self.path = self.folder / "phase1.h5"
        self.inputs = json.dumps(dict(inputs, encoding=ENCODING), sort_keys=True,
                                 default=str)
        self.with_raw = bool(with_raw)
        self._owned = False
        self._lock = contextlib.ExitStack()
        created = self._make_folder(out, resume)
        if not created:
            self._token_of_marker()  # a folder that is not ours: refused before the lock
        try:
            # one run in the folder at a time: a second one (two --resume at once) is
            # refused before it reads, writes or removes anything in it
            try:
                self._lock.enter_context(lock_folder(self.folder, command=f"selfillum "
                                                     f"unsteady --out {out}"))
            except InputError as exc:
                raise InputError(f"{self.folder}: another run is working in it "
                                 f"({str(exc).split(': in use by ', 1)[-1]})") from None
            self.token = self._claim(created)
            self._open(shape, chunks, n_cameras)
        except BaseException:
            self.close()
            raise

    def _make_folder(self, out, resume: bool) -> bool:
        """Create the work folder (True), or find it (False): only with ``--resume``."""
        try:
            self.folder.mkdir()
            return True
        except FileExistsError:
            pass
        if not self.folder.is_dir() or self.folder.is_symlink():
            raise InputError(f"{self.folder}: exists and is not a work folder of "
                             f"selfillum unsteady; refusing to use or remove it: move it or "
                             "choose another --out")
        if not resume:
            raise InputError(f"{self.folder}: the work of an interrupted run of {out}; give "
                             "--resume to carry it on, or remove the folder")
        return False

    def _claim(self, created: bool) -> str:
        """The folder's token: a new one in a folder this run created (its marker file
        written at once), else the one its marker holds. A folder without the marker is
        not this program's (the user's): refused, never used nor removed."""
        from resection.io.outputs import atomic_write

        if created:
            token = secrets.token_hex(16)
            atomic_write(self.folder / MARKER, Path.write_text, json.dumps(
                {"written_by": PRODUCER, "token": token}) + "\n")
            self._owned = True
            return token
        token = self._token_of_marker()
        self._owned = True
        return token

    def _token_of_marker(self) -> str:
        mark = self.folder / MARKER
        try:
            d = json.loads(mark.read_text(encoding="utf-8"))
            token = d["token"] if d.get("written_by") == PRODUCER else None
        except (OSError, ValueError, TypeError, KeyError, AttributeError, RecursionError):
            token = None
        if not isinstance(token, str) or not token:
            why = "its marker file is damaged" if mark.exists() else \
                f"no marker file {MARKER} in it"
            raise InputError(f"{self.folder}: not a work folder of selfillum unsteady "
                             f"({why}); refusing to use or remove it: move it or choose "
                             "another --out")
        return token

    def _open(self, shape, chunks, n_cameras: int) -> None:
        import h5py

        from resection.io.journal import JournaledFile, discard
        from resection.io.outputs import atomic_path

        T, N = shape
        self.resumed = self.path.exists()
        if not self.resumed:
            discard(self.path)
            with atomic_path(self.path) as tmp, h5py.File(tmp, "w") as f:
                f.attrs["format"] = FORMAT
                f.attrs["token"] = self.token
                f.attrs["frames_done"] = 0
                f.create_dataset("inputs", data=self.inputs)
                for name in ("values", "raw") if self.with_raw else ("values",):
                    f.create_dataset(name, (T, N), "u2", chunks=tuple(chunks))
                    f.create_dataset(name + "_scale", (T,), "f8", fillvalue=np.nan)
                f.create_dataset("R", (n_cameras, T, 3, 3), "f8", fillvalue=np.nan)
                f.create_dataset("t", (n_cameras, T, 3), "f8", fillvalue=np.nan)
        try:
            self._jf = JournaledFile(self.path)
        except BlockingIOError:
            raise InputError(f"{self.folder}: another run is working in it") from None
        try:
            self._f = h5py.File(self._jf, "r+")
        except (OSError, ValueError, KeyError) as exc:
            raise InputError(f"{self.path}: damaged work file ({_first_line(exc)}); remove "
                             f"{self.folder} to start again") from None
        self._check(T, N, n_cameras)

    def _check(self, T, N, C) -> None:
        try:
            self._check_file(T, N, C)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{self.path}: damaged work file ({_first_line(exc)}); remove "
                             f"{self.folder} to start again") from None

    def _check_file(self, T, N, C) -> None:
        f = self._f
        if f.attrs.get("format") != FORMAT:
            raise InputError(f"{self.path}: not the work of selfillum unsteady; remove "
                             f"{self.folder}")
        tok = f.attrs.get("token")
        tok = tok.decode() if isinstance(tok, bytes) else tok
        if tok != self.token:
            raise InputError(f"{self.path}: not the work file of {self.folder}'s run (another "
                             f"token than its {MARKER}); remove {self.folder} to start again")
        old = f["inputs"][()]
        old = old.decode() if isinstance(old, bytes) else str(old)
        if old != self.inputs:
            a, b = json.loads(old), json.loads(self.inputs)
            keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
            raise InputError(f"{self.folder}: the interrupted run was made from other inputs "
                             f"({', '.join(keys)}); cannot resume it: remove the folder")
        names = ("values", "raw") if self.with_raw else ("values",)
        if f["values"].shape != (T, N) or f["R"].shape != (C, T, 3, 3) or \
                f["t"].shape != (C, T, 3) or ("raw" in f) != self.with_raw or \
                any(f[n + "_scale"].shape != (T,) for n in names):
            raise InputError(f"{self.path}: damaged work (shapes); remove {self.folder}")
        done = f.attrs.get("frames_done")
        if not isinstance(done, (int, np.integer)) or not 0 <= int(done) <= T:
            raise InputError(f"{self.path}: damaged work (frames_done {done!r}); remove "
                             f"{self.folder}")

    @property
    def frames_done(self) -> int:
        return int(self._f.attrs["frames_done"])


    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """``R`` (C, T, 3, 3), ``t`` (C, T, 3) as stored (NaN for frames not done)."""
        return self._f["R"][()], self._f["t"][()]

    def write_block(self, a: int, rows: dict, R, t, frames_done: int | None = None) -> None:
        """Commit frames ``a:a + n``: their node rows (``rows``:
        :meth:`BlockBuffer.rows`) and poses (``R`` (C, n, 3, 3), ``t`` (C, n, 3)), then
        ``frames_done`` (default the block's end; blocks finishing out of order: the end
        of the blocks done from frame 0)."""
        from resection.io.history import interrupt_after
        from selfillum.unsteady.phase2 import seen_ranges

        b = a + len(rows["values"][0])
        with interrupt_after():  # Ctrl-C waits for the commit (never inside HDF5)
            f = self._f
            for name, (codes, scale) in rows.items():
                ds = f[name]
                for c, e in seen_ranges(codes.any(axis=0), ds.chunks):
                    ds[a:b, c:e] = codes[:, c:e]  # chunks all 0 (unseen) stay unwritten
                f[name + "_scale"][a:b] = scale
            f["R"][:, a:b] = R
            f["t"][:, a:b] = t
            f.attrs["frames_done"] = b if frames_done is None else int(frames_done)
            f.flush()
            if self._jf.failed is not None:
                err = self._jf.failed
                raise OSError(f"{self.path}: {err}")
            self._jf.commit()

    def form_factors(self, compute, n_faces: int | None = None):
        """The form factors from ``F.npz`` when this work has them (checked: readable,
        ``n_faces`` square), else ``compute()`` (saved for a later resume)."""
        import scipy.sparse as sp

        p = self.folder / "F.npz"
        if p.exists():
            try:
                F = sp.csr_matrix(sp.load_npz(p))
            except Exception as exc:  # noqa: BLE001 - NumPy/zipfile raise many kinds
                raise InputError(f"{p}: damaged form factors ({_first_line(exc)}); remove "
                                 f"{self.folder} to start again") from None
            if n_faces is not None and F.shape != (n_faces, n_faces):
                raise InputError(f"{p}: form factors of {F.shape[0]} faces, the grid has "
                                 f"{n_faces}; remove {self.folder} to start again")
            return F
        F = compute()
        tmp = self.folder / "F.tmp.npz"
        sp.save_npz(tmp, sp.csr_matrix(F))
        tmp.replace(p)
        return F

    def _close_file(self) -> None:
        f = getattr(self, "_f", None)
        if f is not None and f.id.valid:
            f.close()
        jf = getattr(self, "_jf", None)
        if jf is not None and not jf.closed:
            jf.close()

    def close(self) -> None:
        """Close the work file and release the folder's lock (the folder stays)."""
        try:
            self._close_file()
        finally:
            self._lock.close()

    def remove(self) -> None:
        """Remove the work folder (only one that carries this run's marker, while this run
        holds its lock), then release the lock."""
        try:
            self._close_file()
            if self._owned:
                shutil.rmtree(self.folder, ignore_errors=True)
        finally:
            self._lock.close()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return (text.splitlines()[0] if text else type(exc).__name__)[:200]
