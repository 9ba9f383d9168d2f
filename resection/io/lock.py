"""Output-folder lock: one run writes into a folder at a time.

:func:`lock_folder` holds an exclusive lock on ``<folder>/.resection.lock`` while a run
writes into the folder. The lock is an advisory ``flock`` on that file (POSIX), so the
operating system releases it when the holding process ends, however it ends (``kill -9``
included): a lock left by a dead process is stale and is simply taken over. The file
names the holder in JSON (``pid``, ``host``, ``started``: UTC ISO 8601 time, ``command``),
so that a second run refused while the first is alive can say which process holds it.

Where ``fcntl`` is not available (Windows), or the filesystem does not support ``flock``,
the lock falls back to creating the file exclusively; a lock file whose process is no
longer alive on this host is then taken over.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

from resection.errors import InputError

__all__ = ["LOCK_NAME", "lock_folder", "read_lock"]

LOCK_NAME = ".resection.lock"

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None


def read_lock(folder: str | os.PathLike) -> dict | None:
    """The holder recorded in ``folder``'s lock file (``pid``, ``host``, ``started``,
    ``command``), or None when there is no readable lock file. The file may be left by a
    process that has ended: only :func:`lock_folder` tells a live lock from a stale one."""
    try:
        with open(Path(folder) / LOCK_NAME, encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _holder_text(d: dict | None) -> str:
    if not d:
        return "another process"
    return (f"process {d.get('pid', '?')} on {d.get('host', '?')} (started "
            f"{d.get('started', '?')}: {d.get('command', '?')})")


def _me(command: str | None) -> dict:
    now = datetime.datetime.now(datetime.UTC).replace(microsecond=0)
    return {"pid": os.getpid(), "host": socket.gethostname(),
            "started": now.isoformat().replace("+00:00", "Z"),
            "command": command if command is not None else " ".join(sys.argv)[:300]}


def _pid_alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError, ValueError, TypeError, OverflowError):
        return True  # exists (another user's) or cannot tell: assume alive
    return True


@contextlib.contextmanager
def lock_folder(folder: str | os.PathLike, *, command: str | None = None) -> Iterator[dict]:
    """Hold the exclusive lock of an output folder for the duration of a ``with`` block.

    Parameters
    ----------
    folder : path-like
        An existing folder.
    command : str, optional
        What the holder is doing, recorded in the lock file (default: this process's
        command line).

    Yields
    ------
    dict
        The holder record written to the lock file (``pid``, ``host``, ``started``,
        ``command``).

    Raises
    ------
    InputError
        Another live process holds the lock (the message names it), or the lock file cannot
        be created.
    """
    folder = Path(folder)
    path = folder / LOCK_NAME
    me = _me(command)
    fd = None if fcntl is None else _flock(folder, path)
    if fd is None:  # no fcntl (Windows), or a filesystem without flock
        with _exclusive_create(path, me):
            yield me
        return
    try:
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps(me).encode())
        os.fsync(fd)
        yield me
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # while still locked: nobody can take a lock on the old file
        os.close(fd)


def _flock(folder: Path, path: Path) -> int | None:
    """A descriptor of ``path`` holding its exclusive ``flock``; None when the filesystem
    does not support ``flock``; InputError when another process holds it."""
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            raise InputError(f"{folder}: cannot create the lock file {LOCK_NAME} "
                             f"({exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError(f"{folder}: in use by {_holder_text(read_lock(folder))}; wait "
                             "for it to finish or use another output folder") from None
        except OSError:  # e.g. ENOLCK, EOPNOTSUPP: no flock on this filesystem
            os.close(fd)
            return None
        # the holder before us may have removed the file between our open and our lock:
        # then we hold a lock on a deleted file, and must start again
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


@contextlib.contextmanager
def _exclusive_create(path: Path, me: dict) -> Iterator[None]:
    for _ in range(2):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            break
        except FileExistsError:
            d = read_lock(path.parent)
            if d and d.get("host") == me["host"] and not _pid_alive(d.get("pid")):
                with contextlib.suppress(OSError):
                    os.unlink(path)
                continue
            raise InputError(f"{path.parent}: in use by {_holder_text(d)}; wait for it to "
                             "finish or use another output folder") from None
    else:
        raise InputError(f"{path.parent}: cannot take over the lock file {LOCK_NAME}")
    try:
        os.write(fd, json.dumps(me).encode())
        os.close(fd)
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
