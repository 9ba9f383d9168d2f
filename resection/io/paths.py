"""Checks of the paths a command is given, made before anything is read or written.

* an input must be a regular file (or a folder where one is expected): a FIFO nobody writes,
  ``/dev/zero``, a socket or a symlink loop is refused by its name instead of hanging or
  failing half way (:func:`check_input_path`);
* every output path is checked before the first file is written, so that a command never
  leaves some outputs and fails on the next: its folder exists and can be written, its name
  fits the file system, it is not a folder nor a special file (:func:`check_output_path`,
  :func:`check_output_folder`);
* temporary files of a run that was killed (``.name.<pid>-<hex>.tmp.ext``, see
  :func:`resection.io.outputs.atomic_path`) are removed by the next run into the same
  folder, never those of a live process (:func:`sweep_temporaries`).

``os.stat`` never opens a file, so none of these checks can block on a FIFO.
"""

from __future__ import annotations

import errno
import os
import re
import stat
from pathlib import Path

from resection.errors import InputError

__all__ = ["as_os_error", "check_input_path", "check_output_folder", "check_output_path",
           "os_error_text", "sweep_temporaries", "system_message"]

#: temporary names made by :func:`resection.io.outputs.atomic_path`
_TEMP = re.compile(r"^\..*\.(\d+)-[0-9a-f]{8}\.tmp(\.[^./]*)?$")

_KINDS = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def os_error_text(exc: OSError) -> str:
    """One line for an OS error: ``<file>: <what the system says>`` (``No space left on
    device``, ``Read-only file system``, ...); for an error of a library that wraps the
    system's (HDF5: ``..., errno = 28, error message = 'No space left on device', ...``),
    the system's message."""
    what = exc.strerror or system_message(exc) or str(exc) or type(exc).__name__
    what = " ".join(str(what).split())  # one line
    name = exc.filename if exc.filename is not None else None
    return f"{os.fsdecode(name)}: {what}" if name is not None else what


def system_message(exc: BaseException) -> str | None:
    """The operating system's message inside a library's error text (HDF5 quotes it as
    ``error message = '...'``), or None."""
    m = re.search(r"error message = '([^']*)'", str(exc))
    return m.group(1) if m else None


def as_os_error(exc: OSError, path: str | os.PathLike) -> OSError:
    """``exc`` as an OSError naming ``path`` with the system's errno and message when the
    library's text holds them (HDF5), for a one-line report."""
    if exc.errno is not None and exc.filename is not None:
        return exc
    m = re.search(r"errno = (\d+)", str(exc))
    code = exc.errno if exc.errno is not None else (int(m.group(1)) if m else None)
    msg = exc.strerror or system_message(exc) or (os.strerror(code) if code else None) \
        or " ".join(str(exc).split())
    return OSError(code, msg, os.fspath(path))


def _stat(path: Path, what: str, *, strict: bool = True):
    """``os.stat`` or None for a path that does not exist. ``strict=False`` (an option's
    value that may not be a path at all: a number, a JSON text) also gives None for a name
    that cannot be a path."""
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None
    except ValueError:  # an embedded NUL: not a path
        if strict:
            raise InputError(f"{what}: not a valid file name") from None
        return None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{what} {path}: symbolic link loop (too many levels of "
                             "links)") from None
        if exc.errno in (errno.ENOTDIR,) or (exc.errno == errno.ENAMETOOLONG and not strict):
            return None
        if exc.errno == errno.ENAMETOOLONG:
            raise InputError(f"{what} {path}: file name too long") from None
        raise InputError(f"{what} {path}: {exc.strerror}") from None


def _special(st) -> str | None:
    for test, kind in _KINDS:
        if test(st.st_mode):
            return kind
    return None


def check_input_path(path: str | os.PathLike, what: str = "input") -> None:
    """Refuse an input that is a symlink loop or not a regular file (a FIFO, a device,
    a socket): reading it would hang or never end. A missing path or a folder is left to
    the reader (which names what it expected)."""
    p = Path(path)
    st = _stat(p, what, strict=False)
    if st is None:
        return
    kind = _special(st)
    if kind is not None:
        raise InputError(f"{what} {p}: is {kind}, not a regular file")


def _name_max(folder: Path) -> int:
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):
        return 255


def _writable_folder(folder: Path, what: str, path: Path) -> None:
    st = _stat(folder, what)
    if st is None:
        raise InputError(f"{what} {path}: folder {folder} does not exist")
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what} {path}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        ro = _read_only_fs(folder)
        raise InputError(f"{what} {path}: cannot write into {folder} "
                         f"({'read-only file system' if ro else 'no write permission'})")


def _read_only_fs(folder: Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        return False


def check_output_path(path: str | os.PathLike, what: str = "output") -> None:
    """Refuse an output file that cannot be written, before anything is written: its
    folder is missing, not a folder or not writable (read-only file system, no
    permission), its name is longer than the file system allows, or the path is a folder
    or a special file."""
    p = Path(path)
    if str(path) == "":
        raise InputError(f"{what}: empty file name")
    folder = p.parent
    limit = _name_max(folder if folder.is_dir() else Path("."))
    for part in p.parts:
        if len(os.fsencode(part)) > limit:
            raise InputError(f"{what} {p}: a name of {len(os.fsencode(part))} bytes, longer "
                             f"than the file system's {limit}")
    st = _stat(p, what)
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise InputError(f"{what} {p}: is a folder, expected a file name")
        kind = _special(st)
        if kind is not None:
            raise InputError(f"{what} {p}: is {kind}, not a regular file")
    _writable_folder(folder, what, p)


def check_output_folder(path: str | os.PathLike, what: str = "output folder") -> None:
    """Refuse an output folder that cannot be made or written: it exists and is not a
    folder, or the folder it is to be made in (its nearest existing parent) or itself is
    not writable, or a name is too long."""
    p = Path(path)
    for part in p.parts:
        if len(os.fsencode(part)) > 255:
            raise InputError(f"{what} {p}: a name longer than 255 bytes")
    st = _stat(p, what)
    if st is not None:
        if not stat.S_ISDIR(st.st_mode):
            raise InputError(f"{what} {p}: exists and is not a folder")
        _writable_folder(p, what, p)
        return
    parent = p.absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    _writable_folder(parent, what, p)


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # someone else's live process
    return True


def sweep_temporaries(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary files (``.name.<pid>-<hex>.tmp.ext``) that a killed run left in
    ``folder``: those whose process is no longer alive on this host. Returns the removed
    paths. Nothing else is touched; an unreadable folder is left alone."""
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        m = _TEMP.match(e.name)
        if m is None or _alive(int(m.group(1))):
            continue
        try:
            if e.is_file(follow_symlinks=False):
                os.unlink(e.path)
                removed.append(Path(e.path))
        except OSError:
            pass
    return removed
