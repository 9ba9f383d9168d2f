"""PLY and STL triangle files read into a :class:`~resection.trisurface.TriSurface`, without
trimesh.

The vertices, faces and face order are those ``trimesh.load(..., process=False)`` gives
(the tests compare them), before any vertex merge:

* PLY (binary either byte order, or ASCII) through ``plyfile``: ``x, y, z`` of the
  ``vertex`` element as float64, the ``vertex_indices`` (or ``vertex_index``) lists of the
  ``face`` element; every scalar numeric face property (as
  :func:`~resection.io.meshes.write_surface` writes them) becomes a face attribute;
* STL: binary (``84 + 50 n`` bytes) as float32 corners (the 2-byte attribute of each
  triangle as face attribute ``stl``), or ASCII with one ``solid``; three vertices per
  triangle, in file order.

Files these readers do not cover (polygons other than triangles, several ASCII ``solid``
blocks, a PLY without faces or with types plyfile does not know) give ``None``: the caller
reads them through trimesh.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from resection.errors import InputError
from resection.trisurface import TriSurface

__all__ = ["read_ply", "read_stl"]

#: One binary STL record: the file's normal, three float32 corners, the attribute count.
_STL_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attr", "<u2")])


def read_ply(path: Path) -> TriSurface | None:
    """The triangles of a PLY file; ``None`` for a PLY that is not all triangles or that
    plyfile cannot read (a broken file, or non-standard property types such as the
    ``int64`` of trimesh's exports): trimesh reads it, or says what is wrong."""
    import plyfile

    known = {"face": {"vertex_indices": 3, "vertex_index": 3}}
    try:
        try:
            ply = plyfile.PlyData.read(str(path), known_list_len=known)
        except plyfile.PlyElementParseError:  # lists of other lengths: read them as they are
            ply = plyfile.PlyData.read(str(path), mmap=False)
    except (plyfile.PlyParseError, ValueError, OSError, EOFError, IndexError, KeyError):
        return None  # not plyfile's PLY (e.g. trimesh's int64 properties): trimesh's turn
    names = [e.name for e in ply.elements]
    if "vertex" not in names or "face" not in names:
        return None
    vert, face = ply["vertex"].data, ply["face"].data
    fnames = face.dtype.names or ()
    key = next((k for k in ("vertex_indices", "vertex_index") if k in fnames), None)
    if key is None or not all(k in (vert.dtype.names or ()) for k in "xyz"):
        return None
    lists = face[key]
    if lists.dtype == object:  # rows of any length: triangles only
        lengths = np.fromiter((len(r) for r in lists), np.int64, len(lists))
        if len(lists) == 0 or np.any(lengths != 3):
            return None
        lists = np.stack(lists)
    faces = np.array(lists, dtype=np.int64).reshape(-1, 3)
    vertices = np.column_stack([np.asarray(vert[k], dtype=np.float64) for k in "xyz"])
    attrs = {}
    for name in fnames:
        a = face[name]
        if name != key and a.ndim == 1 and len(a) == len(faces) \
                and np.issubdtype(a.dtype, np.number):
            attrs[name] = np.array(a)
    return TriSurface(vertices, faces, attrs, {"format": "ply"})


def read_stl(path: Path, data: bytes) -> TriSurface | None:
    """The triangles of an STL file whose bytes ``data`` were checked well formed;
    ``None`` for an ASCII STL of several solids."""
    n = int(np.frombuffer(data, "<u4", 1, 80)[0]) if len(data) >= 84 else -1
    if len(data) == 84 + 50 * n:
        rec = np.frombuffer(data, _STL_RECORD, n, 84)
        vertices = rec["corners"].reshape(-1, 3).astype(np.float64)
        attrs = {"stl": np.array(rec["attr"])}  # the attribute count, as trimesh keeps it
    else:
        text = data.decode("ascii").lower()
        if text.count("endsolid") != 1:
            return None
        parts = text.split("vertex")[1:]
        try:
            vertices = np.array(" ".join(p[:p.find("\n")] for p in parts).split(),
                                dtype=np.float64)
        except ValueError as exc:
            raise InputError(f"{path}: non-numeric vertex in the ASCII STL ({exc})") from None
        if vertices.size == 0 or vertices.size % 9:
            raise InputError(f"{path}: ASCII STL with {vertices.size} vertex coordinates "
                             "(not three 3-D corners per facet)")
        vertices, attrs = vertices.reshape(-1, 3), {}
    faces = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
    return TriSurface(vertices, faces, attrs, {"format": "stl"})
