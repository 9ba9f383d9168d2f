"""NASA uPSP ``psp_process`` inputs: the input deck (``.inp``) and the paint gain file.

Input deck (uPSP's ``file-formats`` doc, ``upsp_inputs.cpp``)::

    @general
        test = my-test
        run = 1234
        sequence = 56
    @vars
        dir = /data/test
    @all
        sds = $dir/inputs/123456.wtd
        grid = $dir/inputs/model.grid
        targets = $dir/inputs/model.tgts
        normals = $dir/inputs/normals.dat      (optional)
    @camera
        number = 1
        filename = $dir/inputs/12345601.cine   (or: cine = ...)
        calibration = $dir/inputs/cam01-to-model.json
    @options
        target_patcher = polynomial
        registration = pixel
        overlap = best_view
        filter = gaussian
        filter_size = 3
        oblique_angle = 70
        number_frames = 2000
    @output
        dir = $dir/outputs

Lines are ``key = value``; ``#`` starts a comment line; ``%`` lines are metadata.
``$name`` in a value is replaced by the ``@vars`` entry ``name`` (longest names first).
A relative path is taken relative to the deck's folder. ``@all`` may also give
``targets`` and ``calibration`` for every camera that does not give its own. Cameras are
sorted by ``number`` as uPSP does.

Paint gain file (uPSP's "Unsteady PSP gain calibration")::

    a = 1.1
    b = 2.2
    ...
    f = 6.6

the six coefficients of ``Gain = a + bT + cT^2 + (d + eT + fT^2) Pss`` (T in deg F, Pss in
psf).
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from resection.errors import InputError
from resection.io.paths import check_input_path
from resection.io.text import read_text_lines

__all__ = ["Deck", "DeckCamera", "read_deck", "PaintCalibration", "read_paint_calibration",
           "DECK_OPTIONS"]

#: The largest ``@camera number`` (uPSP numbers its cameras from 1).
MAX_CAMERA_NUMBER = 65535
#: The ``@options`` keys a deck may give (uPSP's list).
DECK_OPTIONS = ("target_patcher", "registration", "pixel_interpolation", "overlap", "filter",
                "filter_size", "oblique_angle", "number_frames")
_SECTIONS = ("general", "vars", "all", "camera", "options", "output")
_ALL_KEYS = ("sds", "grid", "targets", "normals", "calibration", "grid_units", "active_comps")
_CAMERA_KEYS = ("number", "filename", "cine", "calibration", "targets", "aedc")


@dataclass(frozen=True)
class DeckCamera:
    """One ``@camera`` block: ``number``, ``video`` (its ``filename`` or ``cine``),
    ``calibration`` and ``targets`` (absolute paths)."""

    number: int
    video: Path
    calibration: Path
    targets: Path | None


@dataclass(frozen=True)
class Deck:
    """A ``psp_process`` input deck, ``$vars`` substituted and paths made absolute.

    Attributes
    ----------
    path : Path
    general : dict
        ``@general`` entries (test, run, sequence, tunnel, ...), as text.
    sds, grid : Path
        The wind-tunnel data file and the grid.
    targets : Path or None
        ``@all`` targets (cameras may name their own).
    normals : Path or None
    cameras : tuple of DeckCamera
        Sorted by number.
    options : dict
        ``@options`` entries as text (keys of :data:`DECK_OPTIONS`).
    output_dir : Path or None
    """

    path: Path
    general: dict
    sds: Path
    grid: Path
    targets: Path | None
    normals: Path | None
    cameras: tuple
    options: dict = field(default_factory=dict)
    output_dir: Path | None = None


#: Longest value a ``$var`` expansion may give (the longest path Linux opens): a var
#: repeated in a var repeated in ... grows tenfold a level, to megabytes.
MAX_EXPANDED = 4096


def _substitute(value: str, vars_: dict, where: str) -> str:
    def repl(m):
        name = m.group(1) or m.group(2)
        if name not in vars_:
            raise InputError(f"{where}: ${name[:40]} is not defined in @vars")
        return vars_[name]

    for _ in range(10):  # vars may refer to vars
        new = re.sub(r"\$\{(\w+)\}|\$(\w+)", repl, value)
        if len(new) > MAX_EXPANDED:
            raise InputError(f"{where}: $vars expand to more than {MAX_EXPANDED} characters "
                             "(a var repeated in a var?)")
        if new == value:
            return new
        value = new
    raise InputError(f"{where}: $vars nested too deeply (a loop?)")


def read_deck(path: str | os.PathLike, *, check_files: bool = True) -> Deck:
    """Read a uPSP input deck.

    Parameters
    ----------
    check_files : bool
        Check that every file it names exists (the message names the deck, the section
        and the key).

    Raises
    ------
    InputError
        Missing deck, a line that is not ``key = value``, an unknown section or key, an
        undefined ``$var``, no ``@all sds``/``grid``, no camera, a camera without
        ``filename``/``cine`` or ``calibration``, a camera number given twice, a missing
        file.
    """
    p = Path(path)
    lines = read_text_lines(p, "input deck", "input deck")
    section = None
    raw: dict[str, dict] = {"general": {}, "vars": {}, "all": {}, "options": {}, "output": {}}
    cams: list[dict] = []
    where_of: dict[tuple, int] = {}
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith("#") or s.startswith("%"):
            continue
        if s.startswith("@"):
            section = s[1:].split()[0].lower() if s[1:].split() else ""
            if section not in _SECTIONS:
                raise InputError(f"{p}:{lineno}: unknown section {s!r} (expected "
                                 + ", ".join("@" + x for x in _SECTIONS) + ")")
            if section == "camera":
                cams.append({"_line": lineno})
            continue
        if section is None:
            raise InputError(f"{p}:{lineno}: {s!r} before any @section")
        if "=" not in s:
            raise InputError(f"{p}:{lineno}: expected 'key = value', got {s!r}")
        key, value = (x.strip() for x in s.split("=", 1))
        key = key.lower()
        allowed = {"all": _ALL_KEYS, "camera": _CAMERA_KEYS, "options": DECK_OPTIONS,
                   "output": ("dir", "name")}.get(section)
        if allowed is not None and key not in allowed:
            raise InputError(f"{p}:{lineno}: unknown key {key!r} in @{section} (expected "
                             f"{', '.join(allowed)})")
        target = cams[-1] if section == "camera" else raw[section]
        slot = (section, len(cams) if section == "camera" else 0, key)
        if key in target:  # as uPSP's reader, the last one counts: say so
            warnings.warn(f"{p}:{lineno}: @{section} {key} given twice (also line "
                          f"{where_of[slot]}); the value of line {lineno} is used",
                          UserWarning, stacklevel=2)
        target[key] = value
        where_of[slot] = lineno
    vars_ = raw["vars"]
    base = p.parent

    def resolve(section, idx, key, value):
        where = f"{p}:{where_of.get((section, idx, key), '?')}: @{section} {key}"
        v = _substitute(value, vars_, where)
        q = Path(v).expanduser()
        q = q if q.is_absolute() else base / q
        if check_files:
            check_input_path(q, where)  # a FIFO or a device would hang the reader
            if not q.exists():
                raise InputError(f"{where}: file not found: {q}")
        return q

    al = raw["all"]
    for key in ("sds", "grid"):
        if key not in al:
            raise InputError(f"{p}: @all has no {key!r} (the "
                             + ("wind-tunnel data .wtd" if key == "sds" else "grid")
                             + " file)")
    sds = resolve("all", 0, "sds", al["sds"])
    grid = resolve("all", 0, "grid", al["grid"])
    targets = resolve("all", 0, "targets", al["targets"]) if "targets" in al else None
    normals = resolve("all", 0, "normals", al["normals"]) if "normals" in al else None
    if not cams:
        raise InputError(f"{p}: no @camera block")
    cameras, numbers = [], {}
    for i, c in enumerate(cams, 1):
        line = c["_line"]
        if "number" not in c:
            raise InputError(f"{p}:{line}: @camera has no 'number'")
        try:
            num = int(c["number"])
        except ValueError:
            raise InputError(f"{p}:{line}: @camera number {c['number']!r} is not an "
                             "integer") from None
        if not 0 <= num <= MAX_CAMERA_NUMBER:
            raise InputError(f"{p}:{line}: @camera number {c['number']} out of range (0 to "
                             f"{MAX_CAMERA_NUMBER})")
        if num in numbers:
            raise InputError(f"{p}:{line}: camera number {num} given twice (also line "
                             f"{numbers[num]})")
        numbers[num] = line
        vkey = "filename" if "filename" in c else "cine" if "cine" in c else None
        if vkey is None:
            raise InputError(f"{p}:{line}: @camera {num} has no video ('filename' or "
                             "'cine')")
        video = resolve("camera", i, vkey, c[vkey])
        if "calibration" in c:
            cal = resolve("camera", i, "calibration", c["calibration"])
        elif "calibration" in al:
            cal = resolve("all", 0, "calibration", al["calibration"])
        else:
            raise InputError(f"{p}:{line}: @camera {num} has no 'calibration' (nor @all)")
        if c.get("aedc", "false").lower() not in ("false", "0", "no"):
            raise InputError(f"{p}:{line}: @camera {num} aedc = {c['aedc']}: AEDC's .cine "
                             "layout is not read (aedc = false only)")
        tg = resolve("camera", i, "targets", c["targets"]) if "targets" in c else targets
        cameras.append(DeckCamera(num, video, cal, tg))
    cameras.sort(key=lambda c: c.number)
    out = raw["output"]
    out_dir = None
    if "dir" in out:
        out_dir = Path(_substitute(out["dir"], vars_, f"{p}: @output dir")).expanduser()
        out_dir = out_dir if out_dir.is_absolute() else base / out_dir
    options = {k: _substitute(v, vars_, f"{p}: @options {k}") for k, v in
               raw["options"].items()}
    return Deck(p, dict(raw["general"]), sds, grid, targets, normals, tuple(cameras),
                options, out_dir)


@dataclass(frozen=True)
class PaintCalibration:
    """``Gain = a + bT + cT^2 + (d + eT + fT^2) Pss`` (T deg F, Pss psf)."""

    a: float
    b: float
    c: float
    d: float
    e: float
    f: float

    def gain(self, T, Pss):
        """The gain at surface temperature ``T`` (deg F) and steady pressure ``Pss``
        (psf); arrays broadcast."""
        return (self.a + self.b * T + self.c * T**2
                + (self.d + self.e * T + self.f * T**2) * Pss)


def read_paint_calibration(path: str | os.PathLike) -> PaintCalibration:
    """Read uPSP's paint gain file: lines ``name = value`` for ``a`` to ``f`` (``#``
    comments and blank lines allowed).

    Raises
    ------
    InputError
        Missing file, a line that is not ``name = value``, an unknown name, a value that is
        not a finite number, a coefficient given twice or missing (the message names it).
    """
    p = os.fspath(path)
    lines = read_text_lines(p, "paint calibration file", "paint calibration")
    vals: dict[str, float] = {}
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if "=" not in s:
            raise InputError(f"{p}:{lineno}: expected 'name = value', got {s!r}")
        k, v = (x.strip() for x in s.split("=", 1))
        k = k.lower()
        if k not in "abcdef" or len(k) != 1:
            raise InputError(f"{p}:{lineno}: unknown coefficient {k!r} (expected a to f)")
        if k in vals:
            raise InputError(f"{p}:{lineno}: coefficient {k!r} given twice")
        try:
            x = float(v)
        except ValueError:
            raise InputError(f"{p}:{lineno}: coefficient {k} = {v!r} is not a number"
                             ) from None
        if x != x or x in (float("inf"), float("-inf")):
            raise InputError(f"{p}:{lineno}: coefficient {k} is not finite")
        vals[k] = x
    missing = [k for k in "abcdef" if k not in vals]
    if missing:
        raise InputError(f"{p}: coefficient {missing[0]!r} missing (a paint calibration "
                         "gives a, b, c, d, e and f)")
    return PaintCalibration(**vals)
