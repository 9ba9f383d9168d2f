"""Phase 1's work, kept so that an interrupted run resumes (``--resume``) without
recomputing its finished blocks of frames, and never reuses stale work.

The work folder ``OUT.h5.work/`` (next to the output) holds ``phase1.h5``: the node
intensities with and without the SI removal (``values``, ``raw``, ``(T, N)`` float32,
chunked as ``/dcp``), every camera's pose per frame (``R``, ``t``), ``frames_done`` (the
frames committed, a whole number of blocks) and ``inputs`` (JSON: every input file with its
size and modification time, every setting that changes Phase 1's numbers, the software's
version). It is written through the project's undo journal
(:class:`resection.io.journal.JournaledFile`, as ``map --out P.h5``'s history): a block is
committed when its rows, the poses and ``frames_done`` are flushed; a run killed in the
middle of a block (Ctrl-C, ``kill -9``, a full disk) leaves the file as it was at its last
commit. The form factors (``F.npz``) and the tracking (``trackN/``) are kept there too.

A folder found without ``--resume`` is refused (it is the work of an interrupted run); with
``--resume``, a folder whose ``inputs`` differ from this run's is refused by name (the keys
that differ): remove it to start again. The folder is removed when the run has succeeded.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from resection.errors import InputError

__all__ = ["work_folder", "Phase1Store"]

FORMAT = "selfillum-unsteady-work"


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
    """

    def __init__(self, out, inputs: dict, shape, chunks, n_cameras: int, *, resume: bool):
        import h5py

        from resection.io.journal import JournaledFile, discard
        from resection.io.outputs import atomic_path

        self.folder = work_folder(out)
        self.path = self.folder / "phase1.h5"
        self.inputs = json.dumps(inputs, sort_keys=True, default=str)
        T, N = shape
        self.resumed = self.path.exists()
        if self.folder.exists() and not resume:
            raise InputError(f"{self.folder}: the work of an interrupted run of {out}; give "
                             "--resume to carry it on, or remove the folder")
        self.folder.mkdir(exist_ok=True)
        if not self.resumed:
            discard(self.path)
            with atomic_path(self.path) as tmp, h5py.File(tmp, "w") as f:
                f.attrs["format"] = FORMAT
                f.attrs["frames_done"] = 0
                f.create_dataset("inputs", data=self.inputs)
                for name in ("values", "raw"):
                    f.create_dataset(name, (T, N), "f4", chunks=tuple(chunks))
                f.create_dataset("R", (n_cameras, T, 3, 3), "f8", fillvalue=np.nan)
                f.create_dataset("t", (n_cameras, T, 3), "f8", fillvalue=np.nan)
        try:
            self._jf = JournaledFile(self.path)
        except BlockingIOError:
            raise InputError(f"{self.folder}: another run is working in it") from None
        self._f = h5py.File(self._jf, "r+")
        try:
            self._check(T, N, n_cameras)
        except BaseException:
            self.close()
            raise

    def _check(self, T, N, C) -> None:
        f = self._f
        if f.attrs.get("format") != FORMAT:
            raise InputError(f"{self.path}: not the work of selfillum unsteady; remove "
                             f"{self.folder}")
        old = f["inputs"][()]
        old = old.decode() if isinstance(old, bytes) else str(old)
        if old != self.inputs:
            a, b = json.loads(old), json.loads(self.inputs)
            keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
            raise InputError(f"{self.folder}: the interrupted run was made from other inputs "
                             f"({', '.join(keys)}); cannot resume it: remove the folder")
        if f["values"].shape != (T, N) or f["R"].shape[0] != C:
            raise InputError(f"{self.path}: damaged work (shapes); remove {self.folder}")

    @property
    def frames_done(self) -> int:
        return int(self._f.attrs["frames_done"])

    @property
    def values(self):
        return self._f["values"]

    @property
    def raw(self):
        return self._f["raw"]

    def poses(self) -> tuple[np.ndarray, np.ndarray]:
        """``R`` (C, T, 3, 3), ``t`` (C, T, 3) as stored (NaN for frames not done)."""
        return self._f["R"][()], self._f["t"][()]

    def write_block(self, a: int, values, raw, R, t, frames_done: int | None = None) -> None:
        """Commit frames ``a .. a + len(values)``: their node rows and poses
        (``R`` (C, n, 3, 3), ``t`` (C, n, 3)), then ``frames_done`` (default the block's
        end; blocks finishing out of order: the end of the blocks done from frame 0)."""
        from resection.io.history import interrupt_after

        b = a + len(values)
        with interrupt_after():  # Ctrl-C waits for the commit (never inside HDF5)
            f = self._f
            f["values"][a:b] = values
            f["raw"][a:b] = raw
            f["R"][:, a:b] = R
            f["t"][:, a:b] = t
            f.attrs["frames_done"] = b if frames_done is None else int(frames_done)
            f.flush()
            if self._jf.failed is not None:
                err = self._jf.failed
                raise OSError(f"{self.path}: {err}")
            self._jf.commit()

    def form_factors(self, compute):
        """The form factors from ``F.npz`` when this work has them, else ``compute()``
        (saved for a later resume)."""
        import scipy.sparse as sp

        p = self.folder / "F.npz"
        if p.exists():
            return sp.csr_matrix(sp.load_npz(p))
        F = compute()
        tmp = self.folder / "F.tmp.npz"
        sp.save_npz(tmp, sp.csr_matrix(F))
        tmp.replace(p)
        return F

    def close(self) -> None:
        f = getattr(self, "_f", None)
        if f is not None and f.id.valid:
            f.close()
        jf = getattr(self, "_jf", None)
        if jf is not None and not jf.closed:
            jf.close()

    def remove(self) -> None:
        self.close()
        shutil.rmtree(self.folder, ignore_errors=True)
