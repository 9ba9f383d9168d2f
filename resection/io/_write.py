"""Writing a file safely (internal): through :func:`resection.io.outputs.atomic_write`, a
temporary name in the same folder renamed into place, so that a crash never leaves half a
file and a reader never sees one."""

from __future__ import annotations

import os

from resection.io.outputs import atomic_write

__all__ = ["atomic_write", "atomic_text"]


def atomic_text(path: str | os.PathLike, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    def write(tmp):
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)

    atomic_write(path, write)
