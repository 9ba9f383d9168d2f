"""uPSP target files (``.tgts``): painted targets, pressure taps and transducers.

Format (NASA uPSP)::

    # comment lines start with '#'
    *Targets
    index  x  y  z  nx  ny  nz  diameter  block  i  j  name
    ...
    *Taps
    index  x  y  z  nx  ny  nz  diameter  block  i  j  name
    ...
    *Virtuals
    index  x  y  z  nx  ny  nz  diameter  block  i  j  name
    ...

A file is a list of labelled sections, each opened by a ``*Name`` line. Fields are separated
by white space; coordinates and diameters in model units; the normal is the outward surface
normal at the point; ``block i j`` locate the nearest grid node (kept and written back). The
``name`` is the point's id, unique over the known sections.

Sections (:func:`read_tgts` reads every one):

``*Targets``
    Painted registration targets: what detection, matching and pose use.
``*Taps``
    Pressure taps (static orifices): dark spots in the image that are *not* targets.
``*Virtuals`` (also spelled ``*Kulites``)
    Unsteady pressure transducers (Kulites): dark spots that are not targets either; their
    positions serve the unsteady run (``selfillum psp --tap-positions``).
any other ``*Name``
    Reported in one warning line, kept (written back verbatim by :func:`write_tgts`), not used.
    uPSP reads one section at a time and ignores the others; we say so instead of silently.

:func:`read_markers <resection.io.markers.read_markers>` returns the targets of a ``.tgts``
(``include_taps=True``: also taps and transducers, flagged in
:attr:`~resection.io.markers.MarkerSet.taps`, so that no caller takes one for a target).

A target lying under the grid surface (a known trap of uPSP files, whose targets are often
surveyed on the bare model before painting) is moved out to the surface along its normal by
:func:`snap_to_surface`, with a warning naming it.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from resection.errors import InputError
from resection.io._write import atomic_text
from resection.io.marker_set import MarkerSet

__all__ = ["TgtsFile", "TgtsSection", "is_tgts", "read_tgts", "write_tgts", "snap_to_surface",
           "KNOWN_SECTIONS"]

_NCOLS = 12
_COLUMNS = "index x y z nx ny nz diameter block i j name"
#: canonical kind of each known section name (lower case, without the ``*``)
KNOWN_SECTIONS = {"targets": "targets", "taps": "taps", "virtuals": "virtuals",
                  "kulites": "virtuals"}


def _empty_markers() -> MarkerSet:
    return MarkerSet((), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool))


@dataclass(frozen=True)
class TgtsSection:
    """One ``*Name`` section of a ``.tgts`` file.

    Attributes
    ----------
    name : str
        The section's name as written, without the ``*`` (``"Targets"``, ``"Virtuals"``).
    kind : str
        ``"targets"``, ``"taps"``, ``"virtuals"`` (``*Virtuals`` or ``*Kulites``), or
        ``"unknown"``.
    line : int
        Line number (from 1) of the section's header.
    rows : tuple of str
        The section's data lines as written (what :func:`write_tgts` writes back for an
        unknown section).
    markers : MarkerSet
        The points of a known section (empty for an unknown one); ``taps`` is True for every
        point that is not a target.
    grid_nodes : (N, 3) int ndarray
        ``block i j`` of each point, as written (blocks counted from 1, as uPSP does).
    """

    name: str
    kind: str
    line: int
    rows: tuple[str, ...]
    markers: MarkerSet = field(default_factory=_empty_markers)
    grid_nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), int))


@dataclass(frozen=True)
class TgtsFile:
    """Every section of a ``.tgts`` file, in file order.

    Attributes
    ----------
    path : str
    sections : tuple of TgtsSection
        In file order; a section name written twice gives two entries (both read).
    header : tuple of str
        The comment lines before the first section (uPSP writes ``#GRID_FILE: ...``
        there), written back by :func:`write_tgts`.
    """

    path: str
    sections: tuple[TgtsSection, ...]
    header: tuple[str, ...] = ()

    def section(self, name: str) -> tuple[TgtsSection, ...]:
        """The sections called ``name`` (case-insensitive, with or without ``*``)."""
        key = name.lstrip("*").strip().lower()
        return tuple(s for s in self.sections if s.name.lower() == key)

    def _kind(self, kind: str) -> MarkerSet:
        parts = [s.markers for s in self.sections if s.kind == kind]
        return _concat(parts) if parts else _empty_markers()

    @property
    def targets(self) -> MarkerSet:
        """The ``*Targets`` points (what matching and pose use)."""
        return self._kind("targets")

    @property
    def taps(self) -> MarkerSet:
        """The ``*Taps`` points (pressure taps; ``MarkerSet.taps`` all True)."""
        return self._kind("taps")

    @property
    def virtuals(self) -> MarkerSet:
        """The ``*Virtuals`` / ``*Kulites`` points (unsteady transducers; ``MarkerSet.taps``
        all True: dark spots that are not targets)."""
        return self._kind("virtuals")

    @property
    def markers(self) -> MarkerSet:
        """Every known point: targets, then taps, then transducers (non-targets flagged in
        ``MarkerSet.taps``): every dark spot the file knows of."""
        return _concat([self.targets, self.taps, self.virtuals])

    @property
    def unknown(self) -> tuple[str, ...]:
        """Names of the sections that are not known (kept, not used)."""
        return tuple(s.name for s in self.sections if s.kind == "unknown")

    @property
    def grid_nodes(self) -> np.ndarray:
        """``(N, 3)`` ``block i j`` of :attr:`markers`, in the same order."""
        parts = [s.grid_nodes for k in ("targets", "taps", "virtuals")
                 for s in self.sections if s.kind == k]
        return np.concatenate(parts) if parts else np.zeros((0, 3), int)


def _concat(parts) -> MarkerSet:
    parts = [p for p in parts if len(p)]
    if not parts:
        return _empty_markers()
    if len(parts) == 1:
        return parts[0]
    return MarkerSet(tuple(k for p in parts for k in p.ids),
                     np.concatenate([p.xyz for p in parts]),
                     np.concatenate([p.diameter for p in parts]),
                     np.concatenate([p.normals for p in parts]),
                     np.concatenate([p.taps for p in parts]))


def is_tgts(path: str | os.PathLike) -> bool:
    """True when the file's first line that is not blank or a ``#`` comment is a ``*``
    section header (``*Targets``, ``*Taps``, ...): a uPSP target file, whatever its
    extension."""
    try:
        with open(os.fspath(path), encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                s = line.strip()
                if s and not s.startswith("#"):
                    return s.startswith("*")
    except OSError:
        return False  # the CSV reader names the problem
    return False


def read_tgts(path: str | os.PathLike) -> TgtsFile:
    """Read every section of a uPSP ``.tgts`` file.

    Known sections (``*Targets``, ``*Taps``, ``*Virtuals``/``*Kulites``, any case) are parsed
    into marker tables; another section is kept as written and reported in one warning line
    (:class:`UserWarning` naming the file, line and section).

    Returns
    -------
    TgtsFile
        ``.targets``, ``.taps``, ``.virtuals``: :class:`MarkerSet` each; ``.markers``: all of
        them (non-targets flagged); ``.sections``: every section in file order.

    Raises
    ------
    InputError
        Missing file, data before the first section, a row of a known section with missing
        or extra columns, a non-numeric field, a zero normal, a non-positive diameter, a name
        given twice: the message names the file and the line. A file without targets is
        read (the caller that needs targets says so).
    """
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except FileNotFoundError:
        raise InputError(f"marker file not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"marker file is a directory: {path}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text (UTF-8) target file") from None
    heads: list[tuple[str, int]] = []
    bodies: list[list[tuple[int, str]]] = []
    header: list[str] = []
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith("#"):
            if s and not heads:
                header.append(s)
            continue
        if s.startswith("*"):
            heads.append((s[1:].strip(), lineno))
            bodies.append([])
        elif not heads:
            raise InputError(f"{path}:{lineno}: data before the first section (*Targets, "
                             "*Taps, *Virtuals)")
        else:
            bodies[-1].append((lineno, s))
    seen: dict[str, int] = {}
    sections = []
    for (name, lineno), body in zip(heads, bodies, strict=True):
        kind = KNOWN_SECTIONS.get(name.lower(), "unknown")
        rows = tuple(s for _, s in body)
        if kind == "unknown":
            warnings.warn(f"{path}:{lineno}: section '*{name}' is not one of *Targets, *Taps, "
                          f"*Virtuals, *Kulites: its {len(rows)} row(s) are kept, not used",
                          UserWarning, stacklevel=2)
            sections.append(TgtsSection(name, kind, lineno, rows))
            continue
        ms, nodes = _parse_rows(path, body, kind, seen)
        sections.append(TgtsSection(name, kind, lineno, rows, ms, nodes))
    return TgtsFile(path, tuple(sections), tuple(header))


def _parse_rows(path: str, body, kind: str, seen: dict[str, int]):
    ids, xyz, nrm, diam, nodes = [], [], [], [], []
    for lineno, s in body:
        fields = s.split()
        if len(fields) < _NCOLS:
            raise InputError(f"{path}:{lineno}: {len(fields)} columns, expected {_NCOLS} "
                             f"({_COLUMNS})")
        if len(fields) > _NCOLS:
            raise InputError(f"{path}:{lineno}: {len(fields)} columns, expected {_NCOLS} "
                             f"({_COLUMNS}); names cannot contain spaces")
        try:
            vals = [float(f) for f in fields[1:8]]
            int(fields[0])
            node = [int(f) for f in fields[8:11]]
        except ValueError:
            raise InputError(f"{path}:{lineno}: a numeric column is not a number "
                             f"({' '.join(fields[:11])})") from None
        if not np.all(np.isfinite(vals)):
            raise InputError(f"{path}:{lineno}: NaN or infinite value")
        if not any(vals[3:6]):
            raise InputError(f"{path}:{lineno}: zero normal")
        if vals[6] <= 0:
            raise InputError(f"{path}:{lineno}: diameter must be positive, got {vals[6]}")
        name = fields[11]
        if name in seen:
            raise InputError(f"{path}:{lineno}: duplicate name {name!r} (first on line "
                             f"{seen[name]})")
        seen[name] = lineno
        ids.append(name)
        xyz.append(vals[0:3])
        nrm.append(vals[3:6])
        diam.append(vals[6])
        nodes.append(node)
    n = len(ids)
    ms = MarkerSet(tuple(ids), np.array(xyz, float).reshape(n, 3), np.array(diam, float),
                   np.array(nrm, float).reshape(n, 3), np.full(n, kind != "targets"))
    return ms, np.array(nodes, int).reshape(n, 3)


def write_tgts(path: str | os.PathLike, markers: MarkerSet | TgtsFile, *,
               grid_nodes=None) -> None:
    """Write a uPSP ``.tgts`` file.

    ``markers``: a :class:`TgtsFile` (every section written back in order, unknown ones
    verbatim, ``block i j`` kept) or a :class:`MarkerSet` (targets, then the points flagged
    in ``taps`` under ``*Taps``). ``grid_nodes``: optional ``(N, 3)`` integers ``block i j``
    for a MarkerSet (zeros when not given). Points without normals or diameters cannot be
    written (uPSP needs them).
    """
    out = [f"# {_COLUMNS}"]
    if isinstance(markers, TgtsFile):
        out = list(markers.header) or out
        parts = []
        for s in markers.sections:
            if s.kind == "unknown":
                parts.append((s.name, None, s.rows))
            else:
                parts.append((s.name, s.markers, s.grid_nodes))
    else:
        n = len(markers)
        nodes = np.zeros((n, 3), int) if grid_nodes is None else \
            np.asarray(grid_nodes, int).reshape(n, 3)
        parts = [("Targets", markers.subset(~markers.taps), nodes[~markers.taps])]
        if markers.taps.any():
            parts.append(("Taps", markers.subset(markers.taps), nodes[markers.taps]))
    for title, ms, extra in parts:
        out.append(f"*{title}")
        if ms is None:
            out.extend(extra)
            continue
        _check_writable(path, ms)
        for k in range(len(ms)):
            nums = [*ms.xyz[k], *ms.normals[k], ms.diameter[k]]
            out.append(" ".join([str(k + 1), *(repr(float(v)) for v in nums),
                                 *(str(int(v)) for v in extra[k]), ms.ids[k]]))
    atomic_text(path, "\n".join(out) + "\n")


def _check_writable(path, ms: MarkerSet) -> None:
    if np.isnan(ms.normals).any():
        raise InputError(f"{path}: every marker needs a normal in a .tgts file")
    if np.isnan(ms.diameter).any():
        raise InputError(f"{path}: every marker needs a diameter in a .tgts file")
    if any(not k or any(c.isspace() for c in k) for k in ms.ids):
        raise InputError(f"{path}: .tgts names cannot be empty or contain spaces")


def snap_to_surface(markers: MarkerSet, mesh, *, source: str = "markers",
                    tolerance: float | None = None) -> MarkerSet:
    """Move markers that lie under the surface out to it along their normals.

    A marker is under the surface when it lies behind the nearest face (its offset from the
    closest surface point points against that face's normal) by more than ``tolerance``
    (default: 1e-6 of the mesh's bounding-box diagonal). It is moved to the first surface
    hit of the ray from it along its own normal (to the closest surface point when it has no
    normal or the ray misses). A :class:`UserWarning` names the moved markers and the
    distances.

    Parameters
    ----------
    markers : MarkerSet
    mesh : trimesh.Trimesh
        Outward-oriented surface, same units as the markers.

    Raises
    ------
    InputError
        Markers and mesh in different units (spreads differing by 1000, 25.4 or 39.37, or
        markers far off the mesh: :func:`resection.camera.units.spread_hint`).
    """
    import trimesh

    if len(markers) == 0:
        return markers
    from resection.camera.units import (
        spread_hint,  # markers in mm on a mesh in m are not 'under' it
    )

    hint = spread_hint(markers.xyz, mesh.vertices, "the markers", "the mesh")
    if hint:
        raise InputError(f"{source}: {hint}")
    diag = float(np.linalg.norm(np.ptp(mesh.bounds, axis=0)))
    tol = 1e-6 * diag if tolerance is None else float(tolerance)
    closest, _, tri = trimesh.proximity.closest_point(mesh, markers.xyz)
    depth = np.einsum("ij,ij->i", markers.xyz - closest, mesh.face_normals[tri])
    under = np.flatnonzero(depth < -tol)
    if under.size == 0:
        return markers
    xyz = markers.xyz.copy()
    n = markers.normals[under]
    has_n = np.all(np.isfinite(n), axis=1)
    new = closest[under].copy()
    if has_n.any():
        origins = xyz[under][has_n]
        locs, ray_idx, _ = mesh.ray.intersects_location(origins, n[has_n], multiple_hits=True)
        dist = np.einsum("ij,ij->i", locs - origins[ray_idx], n[has_n][ray_idx])
        first = np.full(len(origins), np.inf)
        np.minimum.at(first, ray_idx, np.where(dist > 0, dist, np.inf))
        hit = np.isfinite(first)
        rows = np.flatnonzero(has_n)[hit]
        new[rows] = origins[hit] + first[hit, None] * n[has_n][hit]
    moved = np.linalg.norm(new - xyz[under], axis=1)
    xyz[under] = new
    names = ", ".join(f"{markers.ids[i]} ({m:.3g})" for i, m in zip(under, moved, strict=True))
    warnings.warn(f"{source}: {under.size} target(s) lay under the surface and were moved out "
                  f"along their normals (distance moved): {names}", UserWarning, stacklevel=2)
    return MarkerSet(markers.ids, xyz, markers.diameter, markers.normals, markers.taps)
