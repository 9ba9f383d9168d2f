"""PLY and STL triangle files read into a :class:`~resection.trisurface.TriSurface`, without
trimesh.

The vertices, faces and face order are those ``trimesh.load(..., process=False)`` gives
(the tests compare them), before any vertex merge:

* PLY (binary of either byte order with NumPy, ASCII through ``plyfile``): ``x, y, z`` of
  the ``vertex`` element as float64, the ``vertex_indices`` (or ``vertex_index``) lists of the
  ``face`` element; every scalar numeric face property (as
  :func:`~resection.io.meshes.write_surface` writes them) becomes a face attribute;
* STL: binary (``84 + 50 n`` bytes) as float32 corners (the 2-byte attribute of each
  triangle as face attribute ``stl``), or ASCII with one ``solid``; three vertices per
  triangle, in file order.

Files these readers do not cover (polygons other than triangles, several ASCII ``solid``
blocks, a PLY without faces, lists other than the corners, unknown types) give ``None``:
the caller reads them through trimesh.
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
    cannot be read here (a broken file, an unknown type): trimesh reads it, or says what
    is wrong. Binary files are read with NumPy (which also takes the ``int64`` and
    ``uint64`` properties of trimesh's exports), ASCII ones with plyfile."""
    data = path.read_bytes()
    head = _ply_header(data)
    if head is None:
        return None
    fmt, elements, start = head
    if fmt == "ascii":
        return _read_ply_ascii(path)
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        return None
    order = "<" if fmt == "binary_little_endian" else ">"
    arrays, offset = {}, start
    for name, count, props in elements:  # a handful of elements
        fields, lists = [], []
        for pname, ptype in props:
            if isinstance(ptype, tuple):  # a list: only the face's corners, three each
                if name != "face" or pname not in _CORNERS:
                    return None
                if ptype[0] not in _PLY_TYPES or ptype[1] not in _PLY_TYPES:
                    return None
                fields += [(pname + " n", order + _PLY_TYPES[ptype[0]]),
                           (pname, order + _PLY_TYPES[ptype[1]], (3,))]
                lists.append(pname)
            elif ptype in _PLY_TYPES:
                fields.append((pname, order + _PLY_TYPES[ptype]))
            else:
                return None
        try:
            dtype = np.dtype(fields)
        except (TypeError, ValueError):  # repeated property names
            return None
        if count < 0 or offset + count * dtype.itemsize > len(data):
            return None  # truncated
        arr = np.frombuffer(data, dtype, count, offset)
        offset += count * dtype.itemsize
        if any(np.any(arr[k + " n"] != 3) for k in lists):
            return None  # polygons, or rows this layout misreads from there on
        arrays[name] = arr
    return _surface(arrays.get("vertex"), arrays.get("face"))


#: PLY scalar types as NumPy's (with the 64-bit integers trimesh writes).
_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8", "int64": "i8", "uint64": "u8"}
_CORNERS = ("vertex_indices", "vertex_index")


def _ply_header(data: bytes):
    """``(format, [(element, count, [(property, type or (count type, item type))])],
    offset of the body)``, or ``None`` when ``data`` has no PLY header."""
    end = data.find(b"end_header", 0, 1 << 20)
    if not data.startswith(b"ply") or end < 0:
        return None
    nl = data.find(b"\n", end)
    fmt, elements = None, []
    for line in data[:end].decode("ascii", "replace").splitlines()[1:]:  # header lines
        w = line.split()
        try:
            if w and w[0] == "format":
                fmt = w[1]
            elif w and w[0] == "element":
                elements.append((w[1], int(w[2]), []))
            elif w and w[0] == "property" and elements:
                elements[-1][2].append((w[4], (w[2], w[3])) if w[1] == "list"
                                       else (w[2], w[1]))
        except (IndexError, ValueError):
            return None
    return (fmt, elements, nl + 1) if nl >= 0 else None


def _read_ply_ascii(path: Path) -> TriSurface | None:
    import plyfile

    try:
        ply = plyfile.PlyData.read(str(path))
    except (plyfile.PlyParseError, ValueError, OSError, EOFError, IndexError, KeyError):
        return None  # trimesh's turn
    names = [e.name for e in ply.elements]
    if "vertex" not in names or "face" not in names:
        return None
    face = ply["face"].data
    key = next((k for k in _CORNERS if k in (face.dtype.names or ())), None)
    if key is None:
        return None
    lists = face[key]
    if lists.dtype == object:  # rows of any length: triangles only
        lengths = np.fromiter((len(r) for r in lists), np.int64, len(lists))
        if len(lists) == 0 or np.any(lengths != 3):
            return None
        lists = np.stack(lists)
    return _surface(ply["vertex"].data, face, np.asarray(lists).reshape(-1, 3))


def _surface(vert, face, corners=None) -> TriSurface | None:
    """The TriSurface of a PLY's vertex and face records (``None`` when one is missing)."""
    if vert is None or face is None or not all(k in (vert.dtype.names or ()) for k in "xyz"):
        return None
    names = face.dtype.names or ()
    key = next((k for k in _CORNERS if k in names), None)
    if key is None:
        return None
    faces = np.array(face[key] if corners is None else corners, dtype=np.int64).reshape(-1, 3)
    vertices = np.column_stack([np.asarray(vert[k], dtype=np.float64) for k in "xyz"])
    attrs = {}
    for name in names:
        a = face[name]
        if name != key and not name.endswith(" n") and a.ndim == 1 \
                and len(a) == len(faces) and np.issubdtype(a.dtype, np.number):
            attrs[name] = a.astype(a.dtype.newbyteorder("="))  # a native-order copy
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
