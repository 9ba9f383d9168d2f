"""Wind-tunnel data files (``.wtd``): the tunnel's conditions for a data point and the
pressure taps' Cp.

Layout (as NASA's tunnel data systems write them for uPSP; uPSP's ``file-formats`` doc
and its test data's ``wtd_test.wtd``)::

    RUN 3016 2
    # MACH	ALPHA	BETA	PHI	PTOT	TTF	PS	Q	...
    0.838751	-0.041887	0.011826	-90.0	2390.1	104.2	1523.4	603.2	...
    # Tap CP
    1	-0.2311
    2	-0.1874
    ...

* An optional first line ``RUN n m`` names the run and its sequence (point). uPSP's
  Python reader (``parsers.read_wind_tunnel_data``) skips the first line; its C++ reader
  (``read_tunnel_conditions``) skips every line before the first ``#`` line. Here a
  ``RUN`` line is read into :attr:`WindTunnelData.run` and ``.sequence``; any other line
  before the header is an error naming it.
* The first ``#`` line names the columns (tab- or blank-separated, case kept as written
  and looked up without case); the next non-comment line holds one value per column.
* A ``#`` line reading ``Tap CP`` (any case, any spacing) starts the tap table: one row per
  tap, ``number cp`` (the tap's number, an integer, and its pressure coefficient). The
  table runs to the end of the file or to the next ``#`` header line.
* No-data values, as the data system writes them: a tap Cp of ``9.9999`` (no reading of
  that tap) and a column value of ``99999`` (a channel not recorded; ``T102``... in
  uPSP's sample). No-data taps are left out of :attr:`WindTunnelData.taps` and listed in
  ``no_data_taps``; a no-data column stays in ``columns`` but :meth:`WindTunnelData.value`
  refuses it, naming the column and the value.
* ``PS = Q = 0`` is a wind-off point (:attr:`WindTunnelData.wind_off`); a command that
  needs the dynamic pressure refuses it by that name.
* A column named twice, or a second value row under the header, is read as the first one
  and a :class:`UserWarning` names the line used.

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
import warnings
from dataclasses import dataclass, field

import numpy as np

from resection.errors import InputError
from resection.io.text import read_text_lines

__all__ = ["WindTunnelData", "read_wtd", "is_wtd", "tap_name", "tap_candidates", "NO_DATA_CP",
           "NO_DATA_VALUE"]

_TAP_HEADER = re.compile(r"^#\s*tap\s*_?\s*cp\s*$", re.IGNORECASE)
_RUN_LINE = re.compile(r"^RUN\s+(\S+)\s+(\S+)\s*$", re.IGNORECASE)

#: A tap Cp the data system writes for a tap with no reading.
NO_DATA_CP = 9.9999
#: A column value the data system writes for a channel not recorded.
NO_DATA_VALUE = 99999.0


def _is_no_data(v: float, mark: float) -> bool:
    return bool(abs(v - mark) <= 1e-6 * mark)


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
        Tap number -> Cp, in file order (empty when the file has no ``# Tap CP`` table);
        taps holding the no-data Cp (:data:`NO_DATA_CP`) are left out.
    no_data_taps : tuple of int
        The taps listed with the no-data Cp, in file order.
    run, sequence : int or None
        From a first line ``RUN n m``; None without one.
    """

    path: str
    columns: dict
    taps: dict = field(default_factory=dict)
    no_data_taps: tuple = ()
    run: int | None = None
    sequence: int | None = None

    @property
    def wind_off(self) -> bool:
        """``PS`` and ``Q`` both present and both 0: a wind-off point."""
        low = {k.lower(): v for k, v in self.columns.items()}
        return low.get("ps") == 0.0 and low.get("q") == 0.0

    @property
    def label(self) -> str:
        """``run 3016 point 2`` where the file names them, else the file's name."""
        if self.run is None:
            return os.path.basename(self.path)
        return f"run {self.run} point {self.sequence}"

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
        low = {k.lower(): (k, v) for k, v in self.columns.items()}
        for n in names:
            if n.lower() in low:
                k, v = low[n.lower()]
                if _is_no_data(v, NO_DATA_VALUE):
                    raise InputError(f"{self.path}: column {k} holds the no-data value "
                                     f"{v:g} (not recorded for this point)")
                return v
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
        raise InputError(f"{path}:{lineno}: {what} {_shorten(text)!r} is not a "
                         "number") from None


def read_wtd(path: str | os.PathLike) -> WindTunnelData:
    """Read a ``.wtd`` file (see the module notes for the layout).

    Raises
    ------
    InputError
        Missing or unreadable file, no header line, a line before the header other than a
        first ``RUN n m``, a value line with another number of fields than the header, a
        value that is not a number, a tap row that is not ``number cp``, a tap listed twice.
        The message names the file and the line.
    """
    p = os.fspath(path)
    lines = read_text_lines(p, "wind-tunnel data file", ".wtd file")
    names: list[str] | None = None
    columns: dict[str, float] = {}
    taps: dict[int, float] = {}
    no_data: list[int] = []
    run = seq = None
    mode = "header"
    seen = 0  # non-blank lines before this one
    for lineno, raw in enumerate(lines, 1):
        s = raw.strip()
        if not s:
            continue
        seen += 1
        if s.startswith("#"):
            if _TAP_HEADER.match(s):
                mode = "taps"
            elif names is None:
                names = s.lstrip("#").split()
                if not names:
                    raise InputError(f"{p}:{lineno}: empty header line")
                _warn_twice(names, p, lineno)
                mode = "values"
            else:
                mode = "skip"  # another table this reader does not use
            continue
        if mode == "values":
            vals = s.split()
            if len(vals) != len(names):
                raise InputError(f"{p}:{lineno}: {len(vals)} values for {len(names)} columns "
                                 f"({_shorten(' '.join(names))})")
            columns, low = {}, set()
            for n, v in zip(names, vals, strict=True):
                x = _number(v, p, lineno, f"column {n}")
                if n.lower() not in low:  # a name given twice: the first is used
                    low.add(n.lower())
                    columns[n] = x
            value_line = lineno
            mode = "after-values"
        elif mode == "after-values":
            warnings.warn(f"{p}:{lineno}: a second value row under the header; the values of "
                          f"line {value_line} are used", UserWarning, stacklevel=2)
            mode = "skip"
        elif mode == "taps":
            parts = s.split()
            if len(parts) != 2:
                raise InputError(f"{p}:{lineno}: a tap row is 'number cp', got "
                                 f"{_shorten(s)!r}")
            try:
                num = int(parts[0])
            except ValueError:
                raise InputError(f"{p}:{lineno}: tap number {_shorten(parts[0])!r} is not an "
                                 "integer") from None
            if num in taps or num in no_data:
                raise InputError(f"{p}:{lineno}: tap {num} listed twice")
            cp = _number(parts[1], p, lineno, f"Cp of tap {num}")
            if _is_no_data(cp, NO_DATA_CP):
                no_data.append(num)
            elif not np.isfinite(cp):
                raise InputError(f"{p}:{lineno}: Cp of tap {num} is not finite ({parts[1]})")
            else:
                taps[num] = cp
        elif mode == "header":
            m = _RUN_LINE.match(s)
            if m is None or seen != 1:
                raise InputError(f"{p}:{lineno}: {_shorten(s)!r} before the '# NAME ...' "
                                 "header line (only a first line 'RUN n m' may come before it)")
            run = _integer(m.group(1), p, lineno, "run number")
            seq = _integer(m.group(2), p, lineno, "point (sequence) number")
    if names is None:
        raise InputError(f"{p}: no '# NAME ...' header line (not a .wtd file?)")
    if not columns:
        raise InputError(f"{p}: a header line but no values")
    bad = [k for k, v in columns.items() if not np.isfinite(v)]
    if bad:
        raise InputError(f"{p}: column {bad[0]} is not finite")
    return WindTunnelData(p, columns, taps, tuple(no_data), run, seq)


def _shorten(text: str, n: int = 60) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."


def _integer(text: str, path: str, lineno: int, what: str) -> int:
    if not re.fullmatch(r"[+-]?\d{1,18}", text):
        raise InputError(f"{path}:{lineno}: {what} {_shorten(text)!r} is not an integer")
    return int(text)


def _warn_twice(names: list[str], path: str, lineno: int) -> None:
    low = [n.lower() for n in names]
    for i, n in enumerate(low):
        if n in low[:i]:
            warnings.warn(f"{path}:{lineno}: column {names[i]} named twice; the first "
                          f"(column {low.index(n) + 1}) is used", UserWarning, stacklevel=3)
            return


def tap_candidates(number: int) -> tuple[str, ...]:
    """Names a tap numbered ``number`` may carry in a ``.tgts``, in order of preference."""
    n = int(number)
    return (f"CP{n:02d}", f"CP{n}", str(n))


def tap_name(number: int, names) -> str | None:
    """The name of tap ``number`` among ``names`` (e.g. a ``.tgts``'s marker ids): the
    first of :func:`tap_candidates` present, or None."""
    have = set(names)
    return next((c for c in tap_candidates(number) if c in have), None)
