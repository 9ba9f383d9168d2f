"""Writing a file safely (internal): a temporary name in the same folder, renamed into
place, so that a crash never leaves half a file and a reader never sees one."""

from __future__ import annotations

import os
from collections.abc import Callable

from ..errors import InputError


def atomic_write(path: str | os.PathLike, write: Callable[[str], None]) -> None:
    """Call ``write(tmp_path)`` and rename the temporary file to ``path``.

    The temporary file keeps ``path``'s extension (some writers choose the format by it).
    A missing output folder is an :class:`InputError` naming it.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise InputError(f"{path}: output folder {folder} does not exist")
    base = os.path.basename(path)
    stem, ext = os.path.splitext(base)
    tmp = os.path.join(folder, f".{stem}.{os.getpid()}.tmp{ext}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def atomic_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`atomic_write`)."""
    def write(tmp):
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)

    atomic_write(path, write)
