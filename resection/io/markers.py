"""Marker and image-point files (CSV) and pose/calibration outputs.

Formats (docs/design.md):

* marker file: CSV with a header ``id,x,y,z`` and optionally ``diameter`` (model units)
  and ``nx,ny,nz`` (the outward surface normal at the marker; all three or none); ids are
  strings, unique. A uPSP ``.tgts`` file (``*Targets``, ``*Taps``, ``*Virtuals`` sections, see
  :mod:`resection.io.tgts`) is recognised by content and read by the same
  :func:`read_markers`.
* linked image points: CSV ``id,u,v`` (pixels, centre of the top-left pixel at (0, 0));
  the columns of a matched-candidates file (``diameter,depth,merit,snr``) may be present
  and are ignored.
* residual table: CSV ``id,u,v,u_proj,v_proj,du,dv,error`` (``du, dv`` observed minus
  projected, px).

Empty lines and lines starting with ``#`` are skipped. Any problem raises
:class:`~resection.errors.InputError` naming the file and the line.
"""

from __future__ import annotations

import csv
import math
import os

import numpy as np

from resection._checks import as_points
from resection.errors import InputError
from resection.io._write import atomic_text
from resection.io.marker_set import MarkerSet  # re-exported

__all__ = [
    "MarkerSet",
    "read_markers",
    "write_markers",
    "read_points",
    "write_points",
    "link_points",
    "write_residuals",
    "write_view_residuals",
]

_CANDIDATE_COLUMNS = ("diameter", "depth", "merit", "snr")




def _read_table(path, required: tuple[str, ...], optional: tuple[str, ...], what: str):
    """Rows of a CSV file as ``(line_number, {column: text})``, header checked."""
    path = os.fspath(path)
    try:
        fh = open(path, newline="", encoding="utf-8-sig")  # a BOM (Excel) is skipped
    except FileNotFoundError:
        raise InputError(f"{what} file not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"{what} file is a directory: {path}") from None
    with fh:
        try:
            lines = [(i + 1, ln) for i, ln in enumerate(fh.read().splitlines())]
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a text (UTF-8) CSV file") from None
    lines = [(i, ln) for i, ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"{path}: empty {what} file (expected a header "
                         f"{','.join(required)})")
    hline, header = lines[0]
    cols = [c.strip().lower() for c in next(csv.reader([header]))]
    missing = [c for c in required if c not in cols]
    if missing:
        raise InputError(f"{path}:{hline}: missing column(s) {', '.join(missing)} in header "
                         f"{header.strip()!r} (expected {','.join(required)})")
    unknown = [c for c in cols if c not in required and c not in optional]
    if unknown:
        raise InputError(f"{path}:{hline}: unknown column(s) {', '.join(unknown)}; allowed: "
                         f"{', '.join(required + optional)}")
    dup = {c for c in cols if cols.count(c) > 1}
    if dup:
        raise InputError(f"{path}:{hline}: repeated column(s) {', '.join(sorted(dup))}")
    rows = []
    for lineno, text in lines[1:]:
        fields = [f.strip() for f in next(csv.reader([text]))]
        if len(fields) != len(cols):
            raise InputError(f"{path}:{lineno}: expected {len(cols)} fields, got {len(fields)}")
        rows.append((lineno, dict(zip(cols, fields, strict=True))))
    if not rows:
        raise InputError(f"{path}: no data rows")
    return path, rows


def _number(path, lineno, row, col, *, allow_empty=False) -> float:
    text = row[col]
    if text == "" and allow_empty:
        return math.nan
    try:
        val = float(text)
    except ValueError:
        raise InputError(f"{path}:{lineno}: column {col}: not a number: {text!r}") from None
    if not math.isfinite(val):
        raise InputError(f"{path}:{lineno}: column {col}: value {text!r} is not finite")
    return val


def _ids(path, rows) -> tuple[str, ...]:
    seen: dict[str, int] = {}
    for lineno, row in rows:
        k = row["id"]
        if k == "":
            raise InputError(f"{path}:{lineno}: empty id")
        if k in seen:
            raise InputError(f"{path}:{lineno}: duplicate id {k!r} (first on line {seen[k]})")
        seen[k] = lineno
    return tuple(seen)


def read_markers(path: str | os.PathLike, *, mesh=None, include_taps: bool = False) -> MarkerSet:
    """Read a marker file: CSV ``id,x,y,z[,diameter][,nx,ny,nz]`` or a uPSP ``.tgts`` file
    (recognised by its ``*Targets`` section, whatever the extension).

    Parameters
    ----------
    mesh : trimesh.Trimesh, optional
        The model surface: targets lying under it (a known trap of uPSP target files) are
        moved out to it along their normals, with a warning naming them
        (:func:`resection.io.tgts.snap_to_surface`).
    include_taps : bool
        Also return the pressure taps and transducers of a ``.tgts`` file (``*Taps``,
        ``*Virtuals``/``*Kulites``, flagged in :attr:`MarkerSet.taps`). By default only
        the targets are returned, so that no caller can take one for a target.

    Raises
    ------
    InputError
        Missing file or column, unknown column, duplicate or empty id, non-numeric or
        non-finite coordinate, negative diameter: the message names the file and line.
    """
    from resection.io import tgts

    if tgts.is_tgts(path):
        tf = tgts.read_tgts(path)
        ms = tf.markers if include_taps else tf.targets
        if not include_taps and len(ms) == 0:
            raise InputError(f"{os.fspath(path)}: no targets (expected a *Targets section "
                             "with rows index x y z nx ny nz diameter block i j name)")
    else:
        ms = _read_marker_csv(path)
    if mesh is not None:
        ms = tgts.snap_to_surface(ms, mesh, source=os.fspath(path))
    return ms


def _read_marker_csv(path) -> MarkerSet:
    path, rows = _read_table(path, ("id", "x", "y", "z"), ("diameter", "nx", "ny", "nz"),
                             "marker")
    ids = _ids(path, rows)
    xyz = np.array([[_number(path, ln, r, c) for c in ("x", "y", "z")] for ln, r in rows])
    if "diameter" in rows[0][1]:
        diam = np.array([_number(path, ln, r, "diameter", allow_empty=True) for ln, r in rows])
        for (ln, _), d in zip(rows, diam, strict=True):
            if d <= 0:
                raise InputError(f"{path}:{ln}: diameter must be positive, got {d}")
    else:
        diam = np.full(len(rows), np.nan)
    ncols = [c for c in ("nx", "ny", "nz") if c in rows[0][1]]
    normals = None
    if ncols:
        if len(ncols) != 3:
            raise InputError(f"{path}: normal columns nx,ny,nz come together, got only "
                             f"{','.join(ncols)}")
        normals = np.array([[_number(path, ln, r, c, allow_empty=True) for c in ncols]
                            for ln, r in rows])
        for (ln, _), n in zip(rows, normals, strict=True):
            if np.isnan(n).any() and not np.isnan(n).all():
                raise InputError(f"{path}:{ln}: give all of nx,ny,nz or none")
            if np.all(np.isfinite(n)) and not np.any(n):
                raise InputError(f"{path}:{ln}: zero normal")
    return MarkerSet(ids, xyz, diam, normals)


def write_markers(path: str | os.PathLike, ids, xyz, diameter=None, normals=None) -> None:
    """Write a marker file ``id,x,y,z[,diameter][,nx,ny,nz]`` (for uPSP's ``.tgts`` see
    :func:`resection.io.tgts.write_tgts`)."""
    ids = [str(k) for k in ids]
    xyz = as_points(xyz, 3, "xyz")
    if len(ids) != len(xyz):
        raise InputError(f"write_markers: {len(ids)} ids but {len(xyz)} coordinates")
    if len(set(ids)) != len(ids):
        raise InputError("write_markers: duplicate ids")
    cols = [["id"] + list(ids), *([["x", "y", "z"][k]] + list(xyz[:, k]) for k in range(3))]
    if diameter is not None:
        d = np.asarray(diameter, dtype=float).ravel()
        if d.shape != (len(ids),):
            raise InputError(f"write_markers: {d.size} diameters for {len(ids)} markers")
        cols.append(["diameter"] + list(d))
    if normals is not None:
        nrm = as_points(normals, 3, "normals", allow_nan=True)
        if len(nrm) != len(ids):
            raise InputError(f"write_markers: {len(nrm)} normals for {len(ids)} markers")
        cols += [[c] + list(nrm[:, k]) for k, c in enumerate(("nx", "ny", "nz"))]

    def text(v):
        if isinstance(v, str):
            return v
        return "" if np.isnan(v) else repr(float(v))

    lines = [",".join(c[0] for c in cols)]
    for i in range(len(ids)):
        row = [cols[0][i + 1]] + [text(c[i + 1]) for c in cols[1:]]
        lines.append(_csv_line(row))
    atomic_text(os.fspath(path), "\n".join(lines) + "\n")


def _csv_line(fields) -> str:
    import io

    buf = io.StringIO()
    csv.writer(buf, lineterminator="").writerow(fields)
    return buf.getvalue()


def read_points(path: str | os.PathLike) -> tuple[tuple[str, ...], np.ndarray]:
    """Read linked image points ``id,u,v`` (pixels). Returns ``(ids, uv (N, 2))``."""
    path, rows = _read_table(path, ("id", "u", "v"), _CANDIDATE_COLUMNS, "image points")
    ids = _ids(path, rows)
    uv = np.array([[_number(path, ln, r, c) for c in ("u", "v")] for ln, r in rows])
    return ids, uv


def write_points(path: str | os.PathLike, ids, uv) -> None:
    """Write linked image points ``id,u,v``."""
    ids = [str(k) for k in ids]
    uv = as_points(uv, 2, "uv")
    if len(ids) != len(uv):
        raise InputError(f"write_points: {len(ids)} ids but {len(uv)} points")
    with open(os.fspath(path), "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["id", "u", "v"])
        for k, p in zip(ids, uv, strict=True):
            w.writerow([k, repr(float(p[0])), repr(float(p[1]))])


def link_points(markers: MarkerSet, ids, uv, *, source: str = "image points"):
    """Pair image points with their markers by id.

    Returns ``(ids, points3d (N, 3), points2d (N, 2))`` in the order of the image points.
    An image-point id absent from the marker set is an error (a typo must not silently
    drop a marker).
    """
    ids = tuple(str(k) for k in ids)
    uv = as_points(uv, 2, source)
    if len(ids) != len(uv):
        raise InputError(f"{source}: {len(ids)} ids but {len(uv)} points")
    pos = {k: i for i, k in enumerate(markers.ids)}
    unknown = [k for k in ids if k not in pos]
    if unknown:
        raise InputError(f"{source}: id(s) not in the marker file: "
                         f"{', '.join(unknown[:10])}" + (" ..." if len(unknown) > 10 else ""))
    return ids, markers.xyz[[pos[k] for k in ids]], uv


def write_residuals(path: str | os.PathLike, ids, uv, residuals) -> None:
    """Write the residual table ``id,u,v,u_proj,v_proj,du,dv,error`` (px; ``du, dv``
    observed minus projected)."""
    ids = [str(k) for k in ids]
    uv = as_points(uv, 2, "uv")
    res = as_points(residuals, 2, "residuals", allow_nan=True)
    if not (len(ids) == len(uv) == len(res)):
        raise InputError("write_residuals: ids, uv and residuals differ in length")
    err = np.hypot(res[:, 0], res[:, 1])
    with open(os.fspath(path), "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["id", "u", "v", "u_proj", "v_proj", "du", "dv", "error"])
        for k, p, r, e in zip(ids, uv, res, err, strict=True):
            w.writerow([k, f"{p[0]:.6f}", f"{p[1]:.6f}", f"{p[0] - r[0]:.6f}",
                        f"{p[1] - r[1]:.6f}", f"{r[0]:.6f}", f"{r[1]:.6f}", f"{e:.6f}"])


def write_view_residuals(path: str | os.PathLike, ids, uv, residuals) -> None:
    """Residual table of a multi-view calibration: ``view,id,u,v,du,dv,error`` (px;
    ``du, dv`` observed minus projected). ``ids``, ``uv``, ``residuals``: one entry per
    view."""
    if not (len(ids) == len(uv) == len(residuals)):
        raise InputError("write_view_residuals: ids, uv and residuals differ in length")
    with open(os.fspath(path), "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(["view", "id", "u", "v", "du", "dv", "error"])
        for v, (i, p, r) in enumerate(zip(ids, uv, residuals, strict=True)):
            p = as_points(p, 2, f"view {v} uv")
            r = as_points(r, 2, f"view {v} residuals", allow_nan=True)
            if not (len(i) == len(p) == len(r)):
                raise InputError(f"write_view_residuals: view {v}: lengths differ")
            e = np.hypot(r[:, 0], r[:, 1])
            for k, pp, rr, ee in zip(i, p, r, e, strict=True):
                w.writerow([v, k, f"{pp[0]:.6f}", f"{pp[1]:.6f}", f"{rr[0]:.6f}",
                            f"{rr[1]:.6f}", f"{ee:.6f}"])
