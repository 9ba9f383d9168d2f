"""uPSP target files (``.tgts``): painted targets and pressure taps with their normals.

Format (NASA uPSP)::

    # comment lines start with '#'
    *Targets
    index  x  y  z  nx  ny  nz  diameter  block  i  j  name
    ...
    *Taps
    index  x  y  z  nx  ny  nz  diameter  block  i  j  name
    ...

Fields are separated by white space; coordinates and diameters in model units; the normal is
the outward surface normal at the target; ``block i j`` locate the nearest grid node (kept
for the writer only). The ``name`` is the marker id (unique over both sections). Taps are
flagged in :attr:`resection.io.markers.MarkerSet.taps`: they are dark spots that are not
targets.

A target lying under the grid surface (a known trap of uPSP files, whose targets are often
surveyed on the bare model before painting) is moved out to the surface along its normal by
:func:`snap_to_surface`, with a warning naming it.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from resection.errors import InputError
from resection.io._write import atomic_text
from resection.io.marker_set import MarkerSet

__all__ = ["is_tgts", "read_tgts", "write_tgts", "snap_to_surface"]

_NCOLS = 12
_COLUMNS = "index x y z nx ny nz diameter block i j name"


def is_tgts(path: str | os.PathLike) -> bool:
    """True when the file's first line that is not blank or a ``#`` comment is a ``*``
    section header (``*Targets`` / ``*Taps``): a uPSP target file, whatever its extension."""
    try:
        with open(os.fspath(path), encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                s = line.strip()
                if s and not s.startswith("#"):
                    return s.startswith("*")
    except OSError:
        return False  # the CSV reader names the problem
    return False


def read_tgts(path: str | os.PathLike) -> MarkerSet:
    """Read a uPSP ``.tgts`` file into a :class:`MarkerSet` (taps flagged).

    Raises
    ------
    InputError
        Missing file, unknown section, a row with missing or extra columns, a non-numeric
        field, a zero normal, a duplicate name, no targets: the message names the file and
        the line.
    """
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8-sig") as fh:
            lines = fh.read().splitlines()
    except FileNotFoundError:
        raise InputError(f"marker file not found: {path}") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text (UTF-8) target file") from None
    section = None
    ids, xyz, nrm, diam, taps = [], [], [], [], []
    seen: dict[str, int] = {}
    for lineno, line in enumerate(lines, 1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith("*"):
            name = s[1:].strip().lower()
            if name not in ("targets", "taps"):
                raise InputError(f"{path}:{lineno}: unknown section {s!r} (expected *Targets "
                                 "or *Taps)")
            section = name
            continue
        if section is None:
            raise InputError(f"{path}:{lineno}: data before a *Targets or *Taps section")
        fields = s.split()
        if len(fields) < _NCOLS:
            raise InputError(f"{path}:{lineno}: {len(fields)} columns, expected {_NCOLS} "
                             f"({_COLUMNS})")
        if len(fields) > _NCOLS:
            raise InputError(f"{path}:{lineno}: {len(fields)} columns, expected {_NCOLS} "
                             f"({_COLUMNS}); names cannot contain spaces")
        try:
            vals = [float(f) for f in fields[1:8]]
            int(fields[0]), int(fields[8]), int(fields[9]), int(fields[10])
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
        taps.append(section == "taps")
    if not ids or all(taps):
        raise InputError(f"{path}: no targets (expected a *Targets section with rows "
                         f"{_COLUMNS})")
    return MarkerSet(tuple(ids), np.array(xyz), np.array(diam), np.array(nrm), np.array(taps))


def write_tgts(path: str | os.PathLike, markers: MarkerSet, *, grid_nodes=None) -> None:
    """Write a :class:`MarkerSet` as a uPSP ``.tgts`` file (targets, then taps).

    ``grid_nodes``: optional ``(N, 3)`` integers ``block i j`` (zeros when not given).
    Markers without normals cannot be written (uPSP needs them).
    """
    n = len(markers)
    if np.isnan(markers.normals).any():
        raise InputError(f"{path}: every marker needs a normal in a .tgts file")
    if np.isnan(markers.diameter).any():
        raise InputError(f"{path}: every marker needs a diameter in a .tgts file")
    if any(not k or any(c.isspace() for c in k) for k in markers.ids):
        raise InputError(f"{path}: .tgts names cannot be empty or contain spaces")
    nodes = np.zeros((n, 3), int) if grid_nodes is None else np.asarray(grid_nodes, int)
    out = [f"# {_COLUMNS}"]
    for title, sel in (("*Targets", ~markers.taps), ("*Taps", markers.taps)):
        idx = np.flatnonzero(sel)
        if title == "*Taps" and idx.size == 0:
            continue
        out.append(title)
        for k, i in enumerate(idx, 1):
            nums = [*markers.xyz[i], *markers.normals[i], markers.diameter[i]]
            out.append(" ".join([str(k), *(repr(float(v)) for v in nums),
                                 *(str(int(v)) for v in nodes[i]), markers.ids[i]]))
    atomic_text(path, "\n".join(out) + "\n")


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
