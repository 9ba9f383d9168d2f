"""Small text files read whole, with the one-line errors every reader gives."""

from __future__ import annotations

import os

from resection.errors import InputError

__all__ = ["read_text_lines"]


def read_text_lines(path: str | os.PathLike, missing: str, kind: str) -> list[str]:
    """The lines of a UTF-8 text file (a byte-order mark is skipped).

    Parameters
    ----------
    path : path-like
    missing : str
        What the file is, for ``"{missing} not found: PATH"`` (e.g. ``"input deck"``).
    kind : str
        What the file should be, for ``"PATH: not a readable text {kind} (why)"``.

    Raises
    ------
    InputError
        The file is missing, unreadable or not UTF-8 text.
    """
    p = os.fspath(path)
    try:
        with open(p, encoding="utf-8-sig") as fh:
            return fh.read().splitlines()
    except FileNotFoundError:
        raise InputError(f"{missing} not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a readable text {kind} ({exc})") from None
