"""Wind-tunnel data files (``.wtd``): the tunnel's conditions for a data point and the
pressure taps' Cp.

Layout (as NASA's tunnel data systems write them for uPSP; uPSP's ``file-formats`` doc)::

    # MACH	ALPHA	BETA	PHI	PTOT	TTF	PS	Q	...
    0.838751	-0.041887	0.011826	-90.0	2390.1	104.2	1523.4	603.2	...
    # Tap CP
    1	-0.2311
    2	-0.1874
    ...

* The first ``#`` line names the columns (tab- or blank-separated, case kept as written
  and looked up without case); the next non-comment line holds one value per column.
* A ``#`` line reading ``Tap CP`` (any case, any spacing) starts the tap table: one row per
  tap, ``number cp`` (the tap's number, an integer, and its pressure coefficient). The
  table runs to the end of the file or to the next ``#`` header line.

Units are the tunnel's: at NASA Ames ``PS`` and ``Q`` in psf, ``PTOT`` in psf, ``TTF`` the
stagnation (total) temperature in degrees Fahrenheit. Nothing is converted here; the reader
only parses and checks. Columns a caller needs are asked for by name
(:meth:`WindTunnelData.value`), and a missing one is an :class:`InputError` naming the file
and the column.

Taps are numbered in the ``.wtd``; a model's ``.tgts`` names them. :func:`tap_name` gives
the pairing used everywhere in this package: tap ``n`` is the ``.tgts`` marker named
``CPnn`` (two digits at least: 1 -> ``CP01``, 12 -> ``CP12``, 123 -> ``CP123``), or else
``CPn`` without padding, or else the bare number ``n``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

from resection.errors import InputError
from resection.io.text import read_text_lines

__all__ = ["WindTunnelData", "read_wtd", "is_wtd", "tap_name", "tap_candidates"]

_TAP_HEADER = re.compile(r"^#\s*tap\s*_?\s*cp\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class WindTunnelData:
    """One data point of a ``.wtd`` file.

    Attributes
    ----------
    path : str
        The file read.
    columns : dict
        Column name (as written) -> value.
    taps : dict
        Tap number -> Cp, in file order (empty when the file has no ``# Tap CP`` table).
    """

    path: str
    columns: dict
    taps: dict = field(default_factory=dict)

    def has(self, name: str) -> bool:
        """Whether a column of this name (any case) is present."""
        return any(k.lower() == name.lower() for k in self.columns)

    def value(self, *names: str) -> float:
        """The value of the first of ``names`` present (any case).

        Raises
        ------
        InputError
            None of them is a column: the message names the file and the column(s).
        """
        low = {k.lower(): v for k, v in self.columns.items()}
        for n in names:
            if n.lower() in low:
                return low[n.lower()]
        alts = " or ".join(repr(n) for n in names)
        raise InputError(f"{self.path}: no {alts} column (columns: "
                         f"{', '.join(self.columns) or 'none'})")


def is_wtd(path: str | os.PathLike) -> bool:
    """A ``.wtd`` by its extension or by a ``# Tap CP`` line in its first 200 lines."""
    p = os.fspath(path)
    if p.lower().endswith(".wtd"):
        return True
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            for i, line in enumerate(fh):
                if i > 200:
                    break
                if _TAP_HEADER.match(line.strip()):
                    return True
    except OSError:
        return False
    return False


def _number(text: str, path: str, lineno: int, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{path}:{lineno}: {what} {text!r} is not a number") from None


def read_wtd(path: str | os.PathLike) -> WindTunnelData:
    """Read a ``.wtd`` file (see the module notes for the layout).

    Raises
    ------
    InputError
        Missing or unreadable file, no header line, a value line with another number of
        fields than the header, a value that is not a number, a tap row that is not
        ``number cp``, a tap listed twice. The message names the file and the line.
    """
    p = os.fspath(path)
    lines = read_text_lines(p, "wind-tunnel data file", ".wtd file")
    names: list[str] | None = None
    columns: dict[str, float] = {}
    taps: dict[int, float] = {}
    mode = "header"
    for lineno, raw in enumerate(lines, 1):
        s = raw.strip()
        if not s:
            continue
        if s.startswith("#"):
            if _TAP_HEADER.match(s):
                mode = "taps"
            elif names is None:
                names = s.lstrip("#").split()
                if not names:
                    raise InputError(f"{p}:{lineno}: empty header line")
                mode = "values"
            else:
                mode = "skip"  # another table this reader does not use
            continue
        if mode == "values":
            vals = s.split()
            if len(vals) != len(names):
                raise InputError(f"{p}:{lineno}: {len(vals)} values for {len(names)} columns "
                                 f"({' '.join(names)})")
            columns = {n: _number(v, p, lineno, f"column {n}") for n, v in
                       zip(names, vals, strict=True)}
            mode = "skip"
        elif mode == "taps":
            parts = s.split()
            if len(parts) != 2:
                raise InputError(f"{p}:{lineno}: a tap row is 'number cp', got {s!r}")
            try:
                num = int(parts[0])
            except ValueError:
                raise InputError(f"{p}:{lineno}: tap number {parts[0]!r} is not an "
                                 "integer") from None
            if num in taps:
                raise InputError(f"{p}:{lineno}: tap {num} listed twice")
            taps[num] = _number(parts[1], p, lineno, f"Cp of tap {num}")
        elif mode == "header":
            raise InputError(f"{p}:{lineno}: values before the '# NAME ...' header line")
    if names is None:
        raise InputError(f"{p}: no '# NAME ...' header line (not a .wtd file?)")
    if not columns:
        raise InputError(f"{p}: a header line but no values")
    bad = [k for k, v in columns.items() if not np.isfinite(v)]
    if bad:
        raise InputError(f"{p}: column {bad[0]} is not finite")
    return WindTunnelData(p, columns, taps)


def tap_candidates(number: int) -> tuple[str, ...]:
    """Names a tap numbered ``number`` may carry in a ``.tgts``, in order of preference."""
    n = int(number)
    return (f"CP{n:02d}", f"CP{n}", str(n))


def tap_name(number: int, names) -> str | None:
    """The name of tap ``number`` among ``names`` (e.g. a ``.tgts``'s marker ids): the
    first of :func:`tap_candidates` present, or None."""
    have = set(names)
    return next((c for c in tap_candidates(number) if c in have), None)
