"""An undo journal under a file that is appended to and updated in place (the HDF5 file of
a time history, :mod:`resection.io.history`), so that what was committed survives whatever
happens to the writes after it: a full disk, a read-only remount, ``kill -9``, a crash.

:class:`JournaledFile` is a binary file object (h5py opens it with its ``fileobj`` driver).
Before any byte of the committed part of the file (its length at the last
:meth:`~JournaledFile.commit`) is overwritten, the old bytes are appended to the journal
``<file>.journal`` (offset, length, bytes, CRC-32) and handed to the operating system;
bytes past the committed length need no journal. :meth:`~JournaledFile.commit` (after the
HDF5 file was flushed, so that it is whole on disk) empties the journal and records the new
committed length. A failed write is not raised into HDF5 (h5py cannot always carry an
exception out of its file driver: it may crash): it is recorded in
:attr:`~JournaledFile.failed`, which the caller checks after each HDF5 call, and from then
on nothing more reaches the file: that write and the later ones are kept in memory only
(so that HDF5 reads back what it wrote), :meth:`~JournaledFile.commit` refuses, and
:meth:`~JournaledFile.close` rolls the file back to its last commit.

A journal found next to a file is the trace of a run that did not finish: :func:`recover`
rolls the file back (the journal's records in reverse order, then the committed length),
and :func:`committed_view` reads the committed state without writing anything (for a reader
without write permission, or while a writer is at work). A journal whose last record was cut
short by the crash holds that record's bytes unwritten to the file: it is ignored.

The records are not fsync'ed: the journal survives the death of the process, not a power
cut of the machine.
"""

from __future__ import annotations

import io
import os
import struct
import zlib
from pathlib import Path

from resection.io.shadow import ShadowedFile

__all__ = ["JournaledFile", "committed_view", "discard", "journal_path", "recover"]

_MAGIC = b"RSJ1"
_HEADER = struct.Struct("<4sQ")  # magic, committed length
_RECORD = struct.Struct("<QQI")  # offset, length, crc32 of the bytes


def journal_path(path: str | os.PathLike) -> Path:
    """``P.h5`` -> ``P.h5.journal``."""
    p = Path(path)
    return p.with_name(p.name + ".journal")


def _read_journal(jpath: Path) -> tuple[int, list[tuple[int, bytes]]] | None:
    """``(committed length, [(offset, old bytes), ...])``, or None when there is no
    journal with a whole header (nothing to undo).

    Raises
    ------
    InputError
        A file of that name that is not a journal of this program (the user's: never
        replaced nor removed).
    """
    try:
        data = jpath.read_bytes()
    except FileNotFoundError:
        return None
    if not _MAGIC.startswith(data[:len(_MAGIC)]):
        from resection.errors import InputError

        raise InputError(f"{jpath}: exists and is not the journal of {jpath.stem} written "
                         "by this program; refusing to replace it: move it")
    if len(data) < _HEADER.size:
        return None  # a header cut short: nothing was journaled yet
    committed = _HEADER.unpack_from(data, 0)[1]
    records, pos = [], _HEADER.size
    while pos + _RECORD.size <= len(data):
        off, n, crc = _RECORD.unpack_from(data, pos)
        body = data[pos + _RECORD.size: pos + _RECORD.size + n]
        if len(body) != n or zlib.crc32(body) != crc:
            break  # cut short by the crash: its overwrite never happened
        records.append((off, body))
        pos += _RECORD.size + n
    return committed, records


def discard(path: str | os.PathLike) -> None:
    """Remove the journal of a file that is gone (the file is made anew): its records
    belong to the old file. A file of that name that is not a journal is refused."""
    jpath = journal_path(path)
    _read_journal(jpath)  # raises for a file of the user's
    if jpath.exists():
        jpath.unlink()


def recover(path: str | os.PathLike) -> bool:
    """Roll ``path`` back to its last commit when a journal says a run stopped after it;
    remove the journal. Returns whether anything was rolled back."""
    jpath = journal_path(path)
    state = _read_journal(jpath)
    if state is None:
        if jpath.exists():
            jpath.unlink()
        return False
    committed, records = state
    with open(path, "r+b") as fh:
        for off, old in reversed(records):
            fh.seek(off)
            fh.write(old)
        fh.truncate(committed)
        fh.flush()
        os.fsync(fh.fileno())
    jpath.unlink()
    return True


class _View(io.RawIOBase):
    """Read-only file object: ``path`` as it was at its last commit (journal records laid
    over it, cut at the committed length)."""

    def __init__(self, path: Path, committed: int, records):
        self._f = open(path, "rb")
        self._n = committed
        self._records = records
        self._pos = 0

    def readable(self):
        return True

    def seekable(self):
        return True

    def seek(self, pos, whence=0):
        self._pos = {0: pos, 1: self._pos + pos, 2: self._n + pos}[whence]
        return self._pos

    def tell(self):
        return self._pos

    def readinto(self, b):
        lo = self._pos
        hi = min(self._n, lo + len(b))
        if hi <= lo:
            return 0
        self._f.seek(lo)
        buf = bytearray(self._f.read(hi - lo).ljust(hi - lo, b"\0"))
        for off, old in reversed(self._records):  # oldest record applied last
            a, z = max(lo, off), min(hi, off + len(old))
            if a < z:
                buf[a - lo: z - lo] = old[a - off: z - off]
        b[: hi - lo] = buf
        self._pos = hi
        return hi - lo

    def close(self):
        self._f.close()
        super().close()


def committed_view(path: str | os.PathLike):
    """A read-only file object of ``path`` as committed when a journal is beside it, else
    None (read the file itself; also when the file of that name is not a journal)."""
    from resection.errors import InputError

    try:
        state = _read_journal(journal_path(path))
    except InputError:
        return None
    if state is None:
        return None
    committed, records = state
    return _View(Path(path), committed, records)


#: Seconds a writer waits for the file's lock before it is refused: a reader holds HDF5's
#: shared lock while it reads (a viewer polling the file), briefly; a writer holds it for
#: its whole run.
LOCK_WAIT_S = 2.0


def _lock(fh, wait_s: float = LOCK_WAIT_S) -> None:
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        return
    import time

    end = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            return
        except BlockingIOError:
            if time.monotonic() >= end:
                raise
            time.sleep(0.01)
        except OSError:
            return  # a file system without flock


class JournaledFile(ShadowedFile):
    """Binary read/write file object over ``path`` (which must exist) with an undo journal
    (see the module docstring). One writer at a time: an advisory lock on the file (held
    until :meth:`close`, released by the system when the process ends however it ends);
    then a journal left by an earlier run is rolled back.

    ``opener`` (for tests) opens the file and the journal: ``opener(path, mode)``.

    Raises
    ------
    BlockingIOError
        Another process (or another writer in this one) holds the file.
    """

    def __init__(self, path: str | os.PathLike, *, opener=open):
        self.path = Path(path)
        self._f = opener(self.path, "r+b")
        try:
            _lock(self._f)
            recover(self.path)  # only now: the journal of a live writer is not ours to undo
        except BaseException:
            self._f.close()
            raise
        self._j = opener(journal_path(self.path), "w+b")
        self._pos = 0
        self.failed: BaseException | None = None
        self._shadow: list[tuple[int, bytes]] = []  # writes kept in memory after a failure
        self.committed = os.fstat(self._f.fileno()).st_size
        self._start()

    # ------------------------------------------------------------------ journal
    def _start(self) -> None:
        self._j.seek(0)
        self._j.truncate(0)
        self._j.write(_HEADER.pack(_MAGIC, self.committed))
        self._j.flush()

    def fail(self, exc: BaseException) -> None:
        """Record a failure: from now on nothing more reaches the file (see above)."""
        if self.failed is None:
            self.failed = exc

    def commit(self) -> None:
        """Make what was written so far the committed state (call after the HDF5 file is
        flushed)."""
        if self.failed is not None:
            raise OSError(f"{self.path}: an earlier write failed; nothing more is committed")
        try:
            self._f.flush()
            self.committed = os.fstat(self._f.fileno()).st_size
            self._start()
        except OSError as exc:
            self.fail(exc)
            raise

    # ------------------------------------------------------------------ file object
    def write(self, b):
        data = bytes(b)
        if self.failed is None:
            try:
                lo, hi = self._pos, min(self._pos + len(data), self.committed)
                if lo < hi:
                    self._journal(lo, hi)
                self._f.seek(self._pos)
                self._f.write(data)
                self._f.flush()
            except OSError as exc:
                self.fail(exc)
        if self.failed is not None:  # kept in memory only (see the module docstring)
            self._shadow.append((self._pos, data))
        self._pos += len(data)
        return len(data)

    def _journal(self, lo: int, hi: int) -> None:
        self._f.seek(lo)
        old = self._f.read(hi - lo)
        self._j.write(_RECORD.pack(lo, len(old), zlib.crc32(old)) + old)
        self._j.flush()  # in the system's hands before the file is touched

    def truncate(self, size=None):
        size = self._pos if size is None else size
        if self.failed is not None:
            return size
        try:
            if size < self.committed:
                self._journal(size, self.committed)
            self._f.truncate(size)
        except OSError as exc:
            self.fail(exc)
        return size

    def flush(self):
        if self.failed is None and not self._f.closed:
            try:
                self._f.flush()
            except OSError as exc:
                self.fail(exc)

    def close(self):
        """Close; after a failure roll the file back to its last commit, else drop the
        (empty) journal."""
        if self.closed:
            return
        try:
            self._f.close()
        except OSError as exc:
            self.fail(exc)
        self._j.close()
        if self.failed is not None:
            recover(self.path)
        else:
            with_journal = journal_path(self.path)
            state = _read_journal(with_journal)
            if state is not None and state[1]:  # writes after the last commit: undone
                recover(self.path)
            elif with_journal.exists():
                with_journal.unlink()
        super().close()
