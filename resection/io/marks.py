"""Marks on the files a command writes beside its main output, so that the next run knows
which files are its own.

A side file (the XDMF sidecar of a time history, the ``.json`` summary of a corrected image,
a PNG preview) carries the key ``side_file_of`` naming the main output it goes with and
``written_by`` naming the command: a JSON key, an XDMF ``<Information>`` element, a PNG
``tEXt`` chunk. An existing side file is replaced only when it carries the mark for the same
main output (:func:`claim_side_file`); any other file of that name is the user's, and the
command refuses it by name. An output folder (``track --out``, ``selfillum psp --out``) is
marked by its manifest (``track.json``, ...) holding ``written_by``: the files the command
writes into it are replaced only in a folder so marked (:func:`claim_folder`).
"""

from __future__ import annotations

import json
import os
import re
import struct
import zlib
from collections.abc import Iterable
from pathlib import Path

from resection.errors import InputError

__all__ = ["MARK_KEY", "PRODUCER_KEY", "claim_folder", "claim_side_file", "existing", "is_marked",
           "mark", "mark_png", "xml_mark"]

MARK_KEY = "side_file_of"
PRODUCER_KEY = "written_by"
_SCAN = 1 << 16  # marks sit near the start of the file


def mark(main: str | os.PathLike, producer: str) -> dict:
    """The mark as JSON keys: ``{"written_by": producer, "side_file_of": main's name}``."""
    return {PRODUCER_KEY: producer, MARK_KEY: Path(main).name}


def xml_mark(main: str | os.PathLike, producer: str) -> str:
    """The mark as XDMF ``<Information>`` elements."""
    from xml.sax.saxutils import quoteattr

    return (f'<Information Name="{PRODUCER_KEY}" Value={quoteattr(producer)}/>'
            f'<Information Name="{MARK_KEY}" Value={quoteattr(Path(main).name)}/>')


def mark_png(path: str | os.PathLike, main: str | os.PathLike, producer: str) -> None:
    """Add the mark to a PNG file as two ``tEXt`` chunks after its header chunk (in place:
    call it on the temporary file before it is renamed)."""
    data = Path(path).read_bytes()
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise InputError(f"{path}: not a PNG file")
    ihdr_end = 8 + 12 + struct.unpack(">I", data[8:12])[0]

    def chunk(key: str, value: str) -> bytes:
        body = b"tEXt" + key.encode("latin-1") + b"\0" + value.encode("latin-1", "replace")
        return struct.pack(">I", len(body) - 4) + body + struct.pack(">I", zlib.crc32(body))

    extra = chunk(PRODUCER_KEY, producer) + chunk(MARK_KEY, json.dumps(Path(main).name))
    Path(path).write_bytes(data[:ihdr_end] + extra + data[ihdr_end:])


def is_marked(path: str | os.PathLike, main: str | os.PathLike) -> bool:
    """Whether ``path`` carries the mark of a side file of ``main`` (any of the forms
    above), read from its first 64 KiB."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(_SCAN)
    except OSError:
        return False
    from xml.sax.saxutils import escape

    name = Path(main).name
    forms = {name, json.dumps(name, ensure_ascii=False)[1:-1], json.dumps(name)[1:-1],
             escape(name, {'"': "&quot;"})}
    alternatives = b"|".join(re.escape(f.encode("utf-8", "replace")) for f in forms)
    pattern = (re.escape(MARK_KEY.encode()) + rb"""["']?\s*(?:[:=]|\sValue=)?\s*["'\0]{0,2}(?:"""
               + alternatives + rb""")(?:["'\0]|$)""")
    return re.search(pattern, head) is not None


def claim_side_file(side: str | os.PathLike, main: str | os.PathLike,
                    what: str = "side file") -> Path:
    """``side`` when it is absent or carries the mark of ``main``'s side file, else
    InputError naming it: a file the user put there is never replaced."""
    side = Path(side)
    if os.path.lexists(side) and not (side.is_file() and is_marked(side, main)):
        raise InputError(
            f"{side}: exists and is not the {what} of {Path(main).name} written by this "
            f"program; refusing to replace it: move it or choose another output name")
    return side


def _manifest_producer(manifest: Path) -> str | None:
    try:
        with open(manifest, encoding="utf-8") as fh:
            d = json.load(fh)
    except (OSError, ValueError, RecursionError):
        return None
    return d.get(PRODUCER_KEY) if isinstance(d, dict) else None


def existing(folder: str | os.PathLike, names: Iterable[str]) -> list[Path]:
    """The files of ``names`` (glob patterns allowed) that exist in ``folder`` (an empty
    folder holds nothing to lose and is left out)."""
    folder = Path(folder)
    found = []
    for name in names:
        if any(c in name for c in "*?["):
            found.extend(sorted(folder.glob(name)))
        elif os.path.lexists(folder / name):
            found.append(folder / name)
    return [p for p in found if not (p.is_dir() and not p.is_symlink() and not any(p.iterdir()))]


def claim_folder(folder: str | os.PathLike, names: Iterable[str], manifest: str,
                 producer: str) -> None:
    """Refuse to write the files ``names`` into ``folder`` when one of them exists and the
    folder is not marked as this command's output (its ``manifest`` file holds
    ``written_by = producer``): that file is the user's."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    ours = _manifest_producer(folder / manifest) == producer
    if ours:
        return
    found = existing(folder, names)
    if found:
        why = (f"its {manifest} is damaged or not {producer}'s: what the folder holds was "
               "made with unknown settings" if (folder / manifest).exists()
               else f"no {manifest} of it")
        raise InputError(
            f"{found[0]}: exists in a folder that is not a {producer} output ({why}); "
            "refusing to replace it: choose another output folder, or remove it")
