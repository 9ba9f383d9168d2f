"""Model surface grids in and per-face results out.

Reading (:func:`load_mesh`) gives a :class:`trimesh.Trimesh` built with ``process=False``,
so the face order is that of the file and every per-face array of the package follows it;
:func:`read_surface` gives the same triangles as a :class:`~resection.trisurface.TriSurface`
without importing trimesh for PLY, STL, Plot3D and Cart3D files (the other formats still
go through trimesh):

* anything trimesh reads (STL, OBJ, PLY, GLB, OFF, ...); a scene of several geometries is
  concatenated and ``face_attributes["component"]`` says which geometry a face came from;
* Plot3D surface grids (:func:`read_plot3d`): multi-block or single-block, formatted ASCII or
  unformatted Fortran binary (4- or 8-byte record markers, either byte order) or raw stream
  binary, single or double precision, with or without IBLANK, all detected from the file.
  Every 2-D block (one of ``ni, nj, nk`` equal to 1) is split into triangles, two per grid
  cell; cells with a corner of IBLANK = 0 are dropped; triangles made degenerate by a
  collapsed grid line (two coincident grid points, e.g. a nose singularity) are dropped.
  ``face_attributes["block"]`` (the block number counted from 1 in file order, as the
  Plot3D manual and uPSP count them), ``["cell_i"]``, ``["cell_j"]`` (0-based cell indices
  along the block's two surface directions) are kept per face;
* Cart3D ``.tri`` (ASCII, or Fortran unformatted): ``face_attributes["component"]`` holds the
  component id of every triangle (1 if the file has none).

Degenerate (zero-area) triangles, NaN or infinite coordinates and empty meshes are refused
with :class:`~resection.errors.InputError`.

Writing (:func:`write_surface`) puts per-face (and per-node) fields on the mesh through
:mod:`resection.io.fields` (meshio: VTK, VTU, XDMF; plyfile: PLY; CSV, NPY; Plot3D ``.f``).
Plot3D grids themselves live in :mod:`resection.io.plot3d` (re-exported here).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from resection._mesh_graph import cross_squares, repeated_faces, vertex_classes
from resection.defaults import MESH_FORMATS
from resection.errors import InputError
from resection.io.plot3d import (  # noqa: F401 - re-exported: Plot3D lives in io/plot3d.py
    PLOT3D_SUFFIXES,
    is_plot3d,
    read_bytes,
    read_plot3d,
    split_records,
    write_plot3d,
)
from resection.io.triangle_files import read_ply, read_stl
from resection.trisurface import MERGE_DIGITS, TriSurface

if TYPE_CHECKING:
    import trimesh

__all__ = [
    "load_mesh",
    "read_surface",
    "merged",
    "check_mesh",
    "duplicate_faces",
    "MESH_FORMATS",
    "read_plot3d",
    "write_plot3d",
    "plot3d_to_mesh",
    "plot3d_to_surface",
    "read_cart3d_tri",
    "read_cart3d_surface",
    "write_cart3d_tri",
    "write_surface",
    "read_face_fields",
]

CART3D_SUFFIXES = (".tri",)


# --------------------------------------------------------------------------- checks
def check_mesh(mesh: trimesh.Trimesh, source: str = "mesh") -> trimesh.Trimesh:
    """Refuse meshes the mapping cannot use; return ``mesh`` unchanged otherwise.

    Raises
    ------
    InputError
        No faces, NaN/infinite vertex coordinates, face indices out of range, or
        degenerate triangles (zero area relative to the model size, repeated vertices).
    """
    verts, faces = _check_indices(mesh, source)
    area2 = np.sqrt(cross_squares(verts, faces))  # twice the areas
    size = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    degenerate = area2 <= 1e-14 * size * size
    if degenerate.any():
        idx = np.flatnonzero(degenerate)
        raise InputError(
            f"{source}: {idx.size} degenerate triangle(s) (zero area or repeated vertices), "
            f"first at face {idx[0]} with vertices {faces[idx[0]].tolist()}"
        )
    dup = duplicate_faces(faces)
    if dup.size:
        a, b = dup[0]
        raise InputError(
            f"{source}: {len(dup)} duplicate face(s) (the same triangle twice), first: faces "
            f"{a} and {b} with vertices {faces[a].tolist()}; remove the copies"
        )
    return mesh


def _check_indices(mesh: trimesh.Trimesh, source: str) -> tuple[np.ndarray, np.ndarray]:
    """The checks of :func:`check_mesh` that merging vertices needs (faces present,
    finite coordinates, indices in range); ``(vertices, faces)`` as arrays."""
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    if len(faces) == 0 or len(verts) == 0:
        raise InputError(f"{source}: empty mesh (no triangles)")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InputError(f"{source}: faces must be triangles, got shape {faces.shape}")
    bad = ~np.all(np.isfinite(verts), axis=1)
    if bad.any():
        raise InputError(
            f"{source}: {bad.sum()} vertex(es) with NaN or infinite coordinates "
            f"(first: vertex {np.flatnonzero(bad)[0]})"
        )
    if faces.min() < 0 or faces.max() >= len(verts):
        raise InputError(
            f"{source}: face vertex indices out of range [0, {len(verts) - 1}] "
            f"(min {faces.min()}, max {faces.max()})"
        )
    return verts, faces


def duplicate_faces(faces) -> np.ndarray:
    """Pairs ``(first, copy)`` of faces that are the same triangle with the same orientation
    (the same three vertex indices in the same cyclic order), as an ``(M, 2)`` array.

    Opposite windings of the same vertices (the two sides of a zero-thickness sheet) are
    not duplicates. Vertices must be merged for coordinates-equal copies to show.
    """
    return repeated_faces(faces)  # the first face of each group, then the copy


# --------------------------------------------------------------------------- loading
def load_mesh(path: str | os.PathLike, *, format: str | None = None,
              merge_vertices: bool = True) -> trimesh.Trimesh:
    """Read a model surface as triangles.

    Parameters
    ----------
    path : path-like
        The file. Without ``format``: STL/OBJ/PLY/OFF/GLB/GLTF and Cart3D ``.tri`` by their
        extensions; Plot3D by content whatever the extension (``.grid``, ``.grd``, ``.x``,
        ``.g``, ``.xyz``, ``.p3d``, ``.fmt``, ...).
    format : one of :data:`MESH_FORMATS`, optional
        Force the format (the commands' ``--format``).
    merge_vertices : bool
        Merge coincident vertices (STL stores three per triangle; Plot3D block interfaces
        and collapsed lines repeat grid points) so that neighbouring faces share vertices,
        which the vertex interpolation of :meth:`SurfaceMap.to_image` needs. Face order and
        face attributes are not changed.

    Returns
    -------
    trimesh.Trimesh
        ``process=False``: faces in file order, with ``face_attributes`` as described in
        the module docstring and ``metadata["source"]``, ``metadata["format"]``.
    """
    path, fmt = _resolve(path, format)
    if fmt in ("plot3d", "cart3d"):
        return read_surface(path, format=fmt, merge_vertices=merge_vertices).to_trimesh()
    if fmt == "stl":
        _check_stl(path)
    mesh = _load_trimesh(path, fmt)
    mesh.metadata["source"] = str(path)
    verts, faces = _check_indices(mesh, str(path))  # what merging needs; the rest after
    if merge_vertices and _needs_merging(verts, faces):
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
    return check_mesh(mesh, str(path))


def read_surface(path: str | os.PathLike, *, format: str | None = None,
                 merge_vertices: bool = True) -> TriSurface | trimesh.Trimesh:
    """Read a model surface as :func:`load_mesh` does, into a
    :class:`~resection.trisurface.TriSurface` without importing trimesh.

    The same vertices, faces, face order, face attributes and ``metadata["source"]``,
    ``["format"]`` as :func:`load_mesh` for PLY (all triangles), STL (binary, or ASCII
    with one solid), Plot3D and Cart3D files; the vertex merge is trimesh's
    (:data:`~resection.trisurface.MERGE_DIGITS`). Any other file goes through
    :func:`load_mesh` and comes back as its ``trimesh.Trimesh``. Parameters and errors as
    :func:`load_mesh`.
    """
    path, fmt = _resolve(path, format)
    if fmt == "plot3d":
        surface = plot3d_to_surface(read_plot3d(path), merge_vertices=merge_vertices,
                                    source=str(path))
        surface.metadata["format"] = "plot3d"
    elif fmt == "cart3d":
        surface = read_cart3d_surface(path)
    elif fmt == "stl":
        surface = read_stl(path, _check_stl(path))
    elif fmt == "ply":
        surface = read_ply(path)
    else:
        surface = None
    if surface is None:
        return load_mesh(path, format=fmt, merge_vertices=merge_vertices)
    if fmt in ("stl", "ply"):
        surface.face_attributes.setdefault(
            "component", np.zeros(len(surface.faces), dtype=np.int64))
        surface.metadata["format"] = path.suffix.lower().lstrip(".")
    surface.metadata["source"] = str(path)
    _check_indices(surface, str(path))  # what merging needs; the rest after
    if merge_vertices:
        surface = merged(surface)
    return check_mesh(surface, str(path))


def merged(surface: TriSurface) -> TriSurface:
    """``surface`` with coincident vertices merged as trimesh's
    ``merge_vertices(merge_tex=True, merge_norm=True)`` merges them: vertices equal once
    scaled by ``10**MERGE_DIGITS`` and rounded become the first of them, unused vertices
    are dropped, the kept ones stay in their order; faces, their order and the face
    attributes are unchanged. ``surface`` itself when nothing merges."""
    verts, faces = surface.vertices, surface.faces
    rep, classes, all_used = vertex_classes(verts, faces, MERGE_DIGITS)
    if all_used and classes == len(verts):
        return surface
    keep = rep == np.arange(len(verts))  # the first used vertex of each class
    new = np.cumsum(keep) - 1
    return TriSurface(verts[keep], new[rep[faces]], surface.face_attributes,
                      surface.metadata)


def _resolve(path: str | os.PathLike, format: str | None) -> tuple[Path, str]:
    """The checked path and the format name (given, or from the extension / content)."""
    path = Path(os.fspath(path))
    if not path.exists():
        raise InputError(f"mesh file not found: {path}")
    if path.is_dir():
        raise InputError(f"mesh path is a directory: {path}")
    fmt = (format or "").lower().lstrip(".")
    if fmt and fmt not in MESH_FORMATS:
        raise InputError(f"{path}: unknown mesh format {format!r}; one of "
                         f"{', '.join(MESH_FORMATS)}")
    return path, fmt or _format_by_content(path, path.suffix.lower())


def _needs_merging(verts: np.ndarray, faces: np.ndarray) -> bool:
    """Whether ``merge_vertices(merge_tex=True, merge_norm=True)`` would change the mesh:
    some vertex is unused, or two coincide at trimesh's merge precision. A grid written
    merged (most are) then skips trimesh's sort of every vertex row (0.2 s for 300,000
    vertices) for one hashed pass."""
    _, classes, all_used = vertex_classes(verts, faces, MERGE_DIGITS)
    return not all_used or classes != len(verts)


def _format_by_content(path: Path, suffix: str) -> str:
    """The mesh format of a file without ``format=``: the trimesh formats and Cart3D by
    their extensions, Plot3D by content whatever the extension (``.grid``, ``.grd``, ...)."""
    ext = suffix.lstrip(".")
    if ext in ("stl", "obj", "ply", "off", "glb", "gltf"):
        return ext
    if suffix in CART3D_SUFFIXES:
        return "cart3d"
    if suffix in PLOT3D_SUFFIXES or is_plot3d(path):
        return "plot3d"
    raise InputError(
        f"{path}: unknown mesh format (extension {suffix or 'none'!r}, and the content is "
        f"not a Plot3D grid); give --format (one of {', '.join(MESH_FORMATS)})"
    )


def _check_stl(path: Path) -> bytes:
    """Refuse a truncated or random STL with a clear message (trimesh would otherwise try
    to decode it as text and fail on an unrelated import); the file's bytes otherwise."""
    data = read_bytes(str(path), "STL", "empty file")
    if len(data) >= 84:
        n = int(np.frombuffer(data, "<u4", 1, 80)[0])
        if len(data) == 84 + 50 * n:
            if n == 0:
                raise InputError(f"{path}: empty mesh (binary STL with 0 triangles)")
            return data  # a well-formed binary STL
    head = data[:512].lstrip().lower()
    if head.startswith(b"solid"):
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError:
            text = None
        if text is not None:
            body = text.lower()
            if "facet" in body and body.count("endfacet") == body.count("facet normal") \
                    and "endsolid" in body:
                return data
            raise InputError(f"{path}: truncated or malformed ASCII STL ("
                             f"{body.count('facet normal')} facets opened, "
                             f"{body.count('endfacet')} closed"
                             f"{'' if 'endsolid' in body else ', no endsolid'})")
    if len(data) >= 84:
        n = int(np.frombuffer(data, "<u4", 1, 80)[0])
        raise InputError(f"{path}: not a valid STL: binary header announces {n} triangles "
                         f"({84 + 50 * n} bytes) but the file has {len(data)} bytes "
                         "(truncated or not an STL)")
    raise InputError(f"{path}: not a valid STL ({len(data)} bytes, too short for a header)")


def _load_trimesh(path: Path, file_type: str | None) -> trimesh.Trimesh:
    import trimesh

    try:
        loaded = trimesh.load(str(path), file_type=file_type, process=False)
    except Exception as exc:  # trimesh raises many kinds; report one line
        raise InputError(f"{path}: cannot be read as a mesh ({type(exc).__name__}: {exc})") \
            from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise InputError(f"{path}: empty mesh (the scene holds no triangles)")
        comp = np.concatenate([np.full(len(g.faces), k) for k, g in enumerate(geoms)])
        verts, faces, off = [], [], 0
        for g in geoms:  # loop over geometries (a handful), not faces
            verts.append(np.asarray(g.vertices))
            faces.append(np.asarray(g.faces) + off)
            off += len(g.vertices)
        mesh = trimesh.Trimesh(np.vstack(verts), np.vstack(faces), process=False)
        mesh.face_attributes["component"] = comp
    elif isinstance(loaded, trimesh.Trimesh):
        mesh = loaded
        _ply_face_properties(mesh)
        if "component" not in mesh.face_attributes:
            mesh.face_attributes["component"] = np.zeros(len(mesh.faces), dtype=np.int64)
    else:
        raise InputError(f"{path}: holds no triangles ({type(loaded).__name__})")
    mesh.metadata["format"] = path.suffix.lower().lstrip(".")
    return mesh


def _ply_face_properties(mesh: trimesh.Trimesh) -> None:
    """Scalar per-face PLY properties (as written by :func:`write_surface`) become
    ``face_attributes``."""
    raw = mesh.metadata.get("_ply_raw", {}).get("face", {}).get("data")
    names = getattr(getattr(raw, "dtype", None), "names", None) or ()
    nf = len(mesh.faces)
    for name in names:
        if name in ("vertex_indices", "vertex_index"):
            continue
        a = raw[name]
        if a.ndim == 1 and len(a) == nf and np.issubdtype(a.dtype, np.number):
            mesh.face_attributes[name] = np.array(a)


# --------------------------------------------------------------------------- Plot3D
def plot3d_to_mesh(blocks, *, merge_vertices: bool = True,
                   source: str = "plot3d") -> trimesh.Trimesh:
    """:func:`plot3d_to_surface` as a ``trimesh.Trimesh`` (``process=False``)."""
    return plot3d_to_surface(blocks, merge_vertices=merge_vertices, source=source).to_trimesh()


def plot3d_to_surface(blocks, *, merge_vertices: bool = True,
                      source: str = "plot3d") -> TriSurface:
    """Triangulate Plot3D surface blocks into a :class:`~resection.trisurface.TriSurface`.

    Each block must be 2-D: exactly one of ``ni, nj, nk`` equal to 1. Cell ``(i, j)`` with
    corners ``p00, p10, p11, p01`` gives triangles ``(p00, p10, p11)`` (face ``2 c``) and
    ``(p00, p11, p01)`` (face ``2 c + 1``) before dropping, so the normal follows
    ``d/di x d/dj``. Cells with a corner of IBLANK 0 are dropped, and so are triangles that
    a collapsed grid line makes degenerate.
    """
    verts, faces, blk, ci, cj = [], [], [], [], []
    off = 0
    for b, item in enumerate(blocks):  # loop over blocks
        xyz, ib = item if isinstance(item, tuple) else (item, None)
        xyz = np.asarray(xyz, dtype=np.float64)
        if xyz.ndim == 3:
            xyz = xyz[:, :, None, :]
        if xyz.ndim != 4 or xyz.shape[3] != 3:
            raise InputError(f"{source}: block {b + 1} has shape {xyz.shape}, expected "
                             "(ni,nj,nk,3)")
        dims = xyz.shape[:3]
        keep = [a for a in range(3) if dims[a] > 1]
        if len(keep) != 2:
            raise InputError(
                f"{source}: block {b + 1} with dimensions {dims} is not a surface (exactly one "
                "of ni, nj, nk must be 1)"
            )
        P = xyz.reshape(dims[keep[0]], dims[keep[1]], 3)
        na, nb = P.shape[:2]
        idx = np.arange(na * nb).reshape(na, nb)
        p00, p10 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
        p11, p01 = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tri = np.stack([np.column_stack([p00, p10, p11]), np.column_stack([p00, p11, p01])],
                       axis=1).reshape(-1, 3)
        ii, jj = np.meshgrid(np.arange(na - 1), np.arange(nb - 1), indexing="ij")
        cell_i, cell_j = np.repeat(ii.ravel(), 2), np.repeat(jj.ravel(), 2)
        ok = np.ones(len(tri), dtype=bool)
        if ib is not None:
            ibf = np.asarray(ib).reshape(na, nb).ravel()
            cell_ok = (ibf[p00] != 0) & (ibf[p10] != 0) & (ibf[p11] != 0) & (ibf[p01] != 0)
            ok &= np.repeat(cell_ok, 2)
        Pf = P.reshape(-1, 3)
        a, bb, c = Pf[tri[:, 0]], Pf[tri[:, 1]], Pf[tri[:, 2]]
        collapsed = (np.all(a == bb, axis=1) | np.all(bb == c, axis=1)
                     | np.all(a == c, axis=1))
        ok &= ~collapsed
        verts.append(Pf)
        faces.append(tri[ok] + off)
        blk.append(np.full(ok.sum(), b + 1))  # blocks count from 1
        ci.append(cell_i[ok])
        cj.append(cell_j[ok])
        off += len(Pf)
    if not verts or off == 0:
        raise InputError(f"{source}: empty mesh (no blocks)")
    mesh = TriSurface(np.vstack(verts), np.vstack(faces))
    if len(mesh.faces) == 0:
        raise InputError(f"{source}: empty mesh (every cell blanked or collapsed)")
    faces0 = mesh.faces
    if merge_vertices:
        mesh = merged(mesh)
    # grid node (blocks in order, each block's nodes as reshape(-1)) -> mesh vertex, -1 for a
    # node no face uses (blanked); merging keeps the faces and their order
    node_vertex = np.full(off, -1, dtype=np.int64)
    node_vertex[faces0.ravel()] = np.asarray(mesh.faces).ravel()
    mesh.metadata["plot3d_node_vertex"] = node_vertex
    mesh.face_attributes["block"] = np.concatenate(blk).astype(np.int64)
    mesh.face_attributes["cell_i"] = np.concatenate(ci).astype(np.int64)
    mesh.face_attributes["cell_j"] = np.concatenate(cj).astype(np.int64)
    mesh.metadata["plot3d_dims"] = [tuple(int(x) for x in (
        (np.asarray(it[0] if isinstance(it, tuple) else it).shape[:3] + (1,))[:3]))
        for it in blocks]
    return check_mesh(mesh, source)


# --------------------------------------------------------------------------- Cart3D
def read_cart3d_tri(path: str | os.PathLike) -> trimesh.Trimesh:
    """:func:`read_cart3d_surface` as a ``trimesh.Trimesh`` (``process=False``)."""
    return read_cart3d_surface(path).to_trimesh()


def read_cart3d_surface(path: str | os.PathLike) -> TriSurface:
    """Read a Cart3D ``.tri`` surface (ASCII or Fortran unformatted) into a
    :class:`~resection.trisurface.TriSurface`.

    Layout: ``nVerts nTris``; the vertices (x y z); the triangles (1-based vertex indices);
    optionally one component id per triangle (kept as ``face_attributes["component"]``,
    1 when absent).
    """
    path = os.fspath(path)
    data = read_bytes(path, "Cart3D", "empty mesh (empty file)")
    recs, endian = split_records(data)
    if recs is not None and len(recs[0]) in (8, 12):
        head = np.frombuffer(recs[0], f"{endian}i4")
        nv, nt = int(head[0]), int(head[1])
        if len(recs) < 3:
            raise InputError(f"{path}: Cart3D binary file is truncated")
        real = len(recs[1]) // max(3 * nv, 1)
        if real not in (4, 8) or len(recs[1]) != 3 * nv * real:
            raise InputError(f"{path}: Cart3D vertex record does not hold {nv} vertices")
        V = np.frombuffer(recs[1], f"{endian}f{real}").reshape(nv, 3).astype(np.float64)
        T = np.frombuffer(recs[2], f"{endian}i4")
        if T.size != 3 * nt:
            raise InputError(f"{path}: Cart3D triangle record does not hold {nt} triangles")
        T = T.reshape(nt, 3).astype(np.int64)
        comp = (np.frombuffer(recs[3], f"{endian}i4").astype(np.int64)
                if len(recs) > 3 and len(recs[3]) == 4 * nt else np.ones(nt, np.int64))
    else:
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError:
            raise InputError(f"{path}: not a Cart3D .tri file (neither ASCII nor "
                             "Fortran records)") from None
        lines = text.split("\n", 1)
        try:
            head = [int(x) for x in lines[0].split()]
        except ValueError:
            raise InputError(f"{path}: first line must be 'nVerts nTris'") from None
        if len(head) < 2 or head[0] < 0 or head[1] < 0:
            raise InputError(f"{path}: first line must be 'nVerts nTris'")
        nv, nt = head[0], head[1]
        if nv == 0 or nt == 0:
            raise InputError(f"{path}: empty mesh ({nv} vertices, {nt} triangles)")
        body = lines[1] if len(lines) > 1 else ""
        try:
            v = np.array(body.replace("D", "E").split(), dtype=np.float64)
        except ValueError as exc:
            raise InputError(f"{path}: non-numeric entry ({exc})") from None
        need = 3 * nv + 3 * nt
        if v.size < need:
            raise InputError(
                f"{path}: expected {nv} vertices and {nt} triangles ({need} numbers), "
                f"found {v.size} numbers"
            )
        V = v[:3 * nv].reshape(nv, 3)
        T = v[3 * nv:need]
        if np.any(T != np.round(T)):
            raise InputError(f"{path}: triangle vertex indices must be integers")
        T = T.reshape(nt, 3).astype(np.int64)
        rest = v[need:]
        comp = rest[:nt].astype(np.int64) if rest.size >= nt else np.ones(nt, np.int64)
    if nv == 0 or nt == 0:
        raise InputError(f"{path}: empty mesh ({nv} vertices, {nt} triangles)")
    if T.min() < 1 or T.max() > nv:
        raise InputError(
            f"{path}: triangle vertex indices must be 1-based in [1, {nv}], "
            f"found {T.min()}..{T.max()}"
        )
    if not np.all(np.isfinite(V)):
        raise InputError(f"{path}: vertices contain NaN or infinite coordinates")
    mesh = TriSurface(V, T - 1, {"component": comp})
    mesh.metadata["format"] = "cart3d"
    return check_mesh(mesh, path)


def write_cart3d_tri(path: str | os.PathLike, mesh: trimesh.Trimesh, components=None) -> None:
    """Write a Cart3D ASCII ``.tri`` file (1-based indices, one component id per face)."""
    comp = (np.asarray(mesh.face_attributes.get("component", np.ones(len(mesh.faces))))
            if components is None else np.asarray(components))
    with open(os.fspath(path), "w", encoding="ascii") as fh:
        fh.write(f"{len(mesh.vertices)} {len(mesh.faces)}\n")
        np.savetxt(fh, np.asarray(mesh.vertices), fmt="%.17g")
        np.savetxt(fh, np.asarray(mesh.faces) + 1, fmt="%d")
        np.savetxt(fh, comp.reshape(-1, 1).astype(np.int64), fmt="%d")


# --------------------------------------------------------------------------- fields
def write_surface(path: str | os.PathLike, mesh: trimesh.Trimesh, face_fields: dict | None = None,
                  *, include_attributes: bool = True, node_fields: dict | None = None) -> None:
    """Write the mesh with per-face (and per-node) fields: ``.vtk``, ``.vtu``, ``.xdmf``
    (meshio), ``.ply`` (plyfile), ``.csv``, ``.npy`` or a Plot3D function file ``.f``.

    See :func:`resection.io.fields.write_fields`, which this calls.
    """
    from resection.io.fields import write_fields

    write_fields(path, mesh, face_fields, node_fields, include_attributes=include_attributes)


def read_face_fields(path: str | os.PathLike, n_faces: int | None = None) -> dict:
    """Per-face fields from any file :func:`write_surface` writes (``.npy``: one array,
    returned as ``"values"``). See :func:`resection.io.fields.read_fields`."""
    from resection.io.fields import read_fields

    return read_fields(path, n_faces)
