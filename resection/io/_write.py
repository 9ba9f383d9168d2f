"""Writing a file safely (internal): a temporary name in the same folder, renamed into
place, so that a crash never leaves half a file and a reader never sees one."""

from __future__ import annotations

import os
from collections.abc import Callable

from .outputs import atomic_path


def atomic_write(path: str | os.PathLike, write: Callable[[str], None]) -> None:
    """Call ``write(tmp_path)`` and rename the temporary file to ``path``.

    The temporary file keeps ``path``'s extension (some writers choose the format by it).
    A missing output folder is an :class:`InputError` naming it. One implementation with
    the commands' outputs: :func:`resection.io.outputs.atomic_path`.
    """
    with atomic_path(path) as tmp:
        write(os.fspath(tmp))


def atomic_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (see :func:`atomic_write`)."""
    def write(tmp):
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)

    atomic_write(path, write)
