"""An HDF5 file written through a Python file object whose write errors are recorded, not
raised into HDF5: a full disk (``ENOSPC``), a quota or an I/O error while an output is
written ends in one :class:`OSError` naming the file, never in HDF5's error storms and a
crash of the interpreter at exit (HDF5's own file driver leaves its objects unclosable
after a failed write, and h5py then crashes when it releases them).

:func:`guarded_h5` opens ``path`` for writing with h5py's ``fileobj`` driver over a
:class:`GuardedFile`. After the first failed write, nothing more reaches the disk: the
writes are kept in memory (so that HDF5 reads back what it wrote and closes cleanly), and
:meth:`GuardedFile.check` raises. The caller calls ``check()`` after each block it writes,
so that at most a block is held in memory; the file is closed, and the failure raised, when
the ``with`` block ends. The caller removes the partial file (write to a temporary name:
:func:`resection.io.outputs.atomic_path`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

from resection.io.shadow import ShadowedFile

__all__ = ["GuardedFile", "guarded_h5"]


class GuardedFile(ShadowedFile):
    """A binary read/write file object over a new file ``path`` whose write errors are
    recorded in :attr:`failed` (see the module docstring)."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        # unbuffered: a write that fails fails here, not at a later flush
        self._f = open(self.path, "w+b", buffering=0)  # noqa: SIM115 - closed by close()
        self._pos = 0
        self.failed: OSError | None = None
        self._shadow: list[tuple[int, bytes]] = []

    def check(self) -> None:
        """Raise the recorded failure as an :class:`OSError` naming the file."""
        if self.failed is not None:
            e = self.failed
            raise OSError(e.errno, e.strerror or str(e), self.path) from None

    # ------------------------------------------------------------------ file object
    def write(self, b):
        view = memoryview(b).cast("B")
        n = view.nbytes
        if self.failed is None:
            try:
                self._f.seek(self._pos)
                done = 0
                while done < n:
                    done += self._f.write(view[done:])
            except OSError as exc:
                self.failed = exc
        if self.failed is not None:  # kept in memory only (over what reached the disk)
            self._shadow.append((self._pos, bytes(view)))
        self._pos += n
        return n

    def truncate(self, size=None):
        size = self._pos if size is None else size
        if self.failed is None:
            try:
                self._f.truncate(size)
            except OSError as exc:
                self.failed = exc
        return size

    def flush(self):
        if self.failed is None and not self._f.closed:
            try:
                self._f.flush()
            except OSError as exc:
                self.failed = exc

    def close(self):
        if self.closed:
            return
        self.flush()
        try:
            self._f.close()
        except OSError as exc:
            if self.failed is None:
                self.failed = exc
        self._shadow.clear()
        super().close()


@contextlib.contextmanager
def guarded_h5(path: str | os.PathLike, **kwargs) -> Iterator[tuple]:
    """``(h5py.File, check)`` for a new HDF5 file at ``path`` (see the module docstring);
    ``kwargs`` go to :class:`h5py.File`. A write that failed is raised as :class:`OSError`
    naming ``path`` when the block ends (or at ``check()``)."""
    import h5py

    fh = GuardedFile(path)
    try:
        with h5py.File(fh, "w", **kwargs) as f:
            yield f, fh.check
    finally:
        fh.close()
    fh.check()
