"""Per-face and per-node fields on a surface mesh: one writer and one reader for every
command (``map`` writes, ``view --values`` and ``backproject`` read).

Formats, chosen by the extension:

``.vtk`` (VTK legacy), ``.vtu`` (VTK XML)
    through the ``meshio`` library: the mesh's triangles with ``cell_data`` (per-face) and
    ``point_data`` (per-node) arrays; ParaView opens both. The legacy ``.vtk`` is
    written in the 4.2 layout with the classic type names that VTK's own reader knows
    (``unsigned_char`` for booleans, ``int`` for integers that fit 32 bits, ``float``,
    ``double``): meshio's 5.1 names (``vtktypeint32``) make VTK drop every field.
``.xdmf``
    XDMF 3: the light data (the grid's structure, the fields' names and shapes) in the XML,
    the heavy data (points, triangles, every field) in an HDF5 file beside it,
    ``<stem>.data.h5`` (:func:`xdmf_data_path`), as the unsteady run's and the time
    histories' are: two cameras on a real grid were 100 MB of inline XML. The HDF5 file
    carries the mark of the XDMF file's side file (:mod:`resection.io.marks`); one of that
    name without it is the user's and is never replaced. ParaView's and meshio's XDMF
    readers read it.
``.ply``
    through the ``plyfile`` library (meshio's PLY writer drops per-face data): binary
    little-endian, vertices as doubles, one face property per face field and one vertex
    property per node field.
``.csv``
    one row per face: ``face, cx, cy, cz`` (centroid) then the fields (node fields only:
    one row per node, ``node, x, y, z`` then the fields).
``.npy``
    one field: its ``(n_faces,)`` or ``(n_faces, k)`` array; read back as ``"values"``.
``.f``
    Plot3D function file on the original grid's nodes (mesh read from a Plot3D grid), one
    variable per field column in the order given, with a ``.nam`` sidecar (same name,
    extension ``.nam``) naming the variables one a line, as FAST and Tecplot read it. Node
    fields (one value per mesh vertex, e.g. ``SurfaceMap.to_nodes``, the one definition of
    a node value that ``map`` writes to ``.f`` and ``.h5`` alike:
    :mod:`resection.surface.node_values`) go to the grid nodes sharing that vertex
    (:func:`resection.io.plot3d.vertices_to_grid_nodes`); face fields (results that exist
    per face only) are averaged to the nodes (:func:`resection.io.plot3d.faces_to_grid_nodes`).

Names are sanitised to ``[A-Za-z0-9_]``; an ``(n, k)`` field becomes ``name_0 ..
name_{k-1}``; booleans are written as 0/1 integers (unsigned bytes in ``.vtk``). NaN is kept
(the value of unseen faces).
Every file is written to a temporary name and renamed into place.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from resection.errors import InputError
from resection.io._write import atomic_text, atomic_write

__all__ = ["write_fields", "read_fields", "nam_path", "xdmf_data_path", "FIELD_SUFFIXES"]

FIELD_SUFFIXES = (".vtk", ".vtu", ".xdmf", ".ply", ".csv", ".npy", ".f")
_MESHIO = {".vtk": "vtk", ".vtu": "vtu"}


def _columns(fields: dict | None, n: int, what: str,
             bool_dtype=np.int32) -> list[tuple[str, np.ndarray]]:
    """Flatten fields to ``(name, (n,) array)`` columns, checked; booleans as
    ``bool_dtype`` 0/1."""
    cols = []
    for k, v in (fields or {}).items():
        a = np.asarray(v)
        if a.ndim == 0 or a.shape[0] != n or a.ndim > 2:
            raise InputError(f"{what} field {k!r}: shape {a.shape} does not match the mesh's "
                             f"{n} {what}s")
        if a.dtype == bool:
            a = a.astype(bool_dtype)
        if not np.issubdtype(a.dtype, np.number):
            raise InputError(f"{what} field {k!r}: must be numeric, got dtype {a.dtype}")
        name = re.sub(r"[^A-Za-z0-9_]", "_", str(k)) or "field"
        if a.ndim == 1:
            cols.append((name, a))
        else:
            cols += [(f"{name}_{c}", a[:, c]) for c in range(a.shape[1])]
    names = [c[0] for c in cols]
    dup = sorted({x for x in names if names.count(x) > 1})
    if dup:
        raise InputError(f"{what} fields: duplicate name(s) after sanitising: {dup}")
    return cols


def _attributes(mesh) -> dict:
    nf = len(mesh.faces)
    out = {}
    for k, v in mesh.face_attributes.items():
        a = np.asarray(v)
        if a.shape[:1] == (nf,) and a.ndim <= 2 and (np.issubdtype(a.dtype, np.number)
                                                    or a.dtype == bool):
            out[k] = a
    return out


def write_fields(
    path: str | os.PathLike,
    mesh,
    face_fields: dict | None = None,
    node_fields: dict | None = None,
    *,
    include_attributes: bool = True,
) -> None:
    """Write per-face and per-node fields of ``mesh`` (formats in the module docstring).

    Parameters
    ----------
    path : path-like
        ``.vtk``, ``.vtu``, ``.xdmf``, ``.ply``, ``.csv``, ``.npy`` or ``.f``.
    mesh : trimesh.Trimesh
    face_fields, node_fields : dict of name -> (n,) or (n, k) array
        Numeric values per face / per vertex (NaN allowed).
    include_attributes : bool
        Also write the mesh's numeric ``face_attributes`` (``block``, ``component``...)
        as face fields (not in ``.npy`` / ``.f``).
    """
    path = os.fspath(path)
    suffix = Path(path).suffix.lower()
    if suffix not in FIELD_SUFFIXES:
        raise InputError(f"{path}: unknown field file format {suffix!r} (use "
                         f"{', '.join(FIELD_SUFFIXES)})")
    nf, nv = len(mesh.faces), len(mesh.vertices)
    faces_in = dict(face_fields or {})
    if include_attributes and suffix not in (".npy", ".f"):
        faces_in = {**_attributes(mesh), **faces_in}
    bool_dtype = np.uint8 if suffix == ".vtk" else np.int32  # VTK legacy: unsigned_char
    fcols = _columns(faces_in, nf, "face", bool_dtype)
    ncols = _columns(node_fields, nv, "node", bool_dtype)
    reserved = {"x", "y", "z", "node", "face", "cx", "cy", "cz", "vertex_indices"}
    clash = sorted({k for k, _ in fcols + ncols} & reserved)
    if clash and suffix in (".ply", ".csv"):
        raise InputError(f"{path}: field name(s) {clash} are taken by the {suffix} layout; "
                         "rename them")
    if suffix in _MESHIO:
        atomic_write(path, _write_meshio, mesh, fcols, ncols, _MESHIO[suffix])
    elif suffix == ".xdmf":
        _write_xdmf_hdf5(path, mesh, fcols, ncols)
    elif suffix == ".ply":
        atomic_write(path, _write_ply, mesh, fcols, ncols)
    elif suffix == ".csv":
        atomic_write(path, _write_csv, mesh, fcols, ncols)
    elif suffix == ".npy":
        _write_npy(path, face_fields, node_fields)
    else:
        _write_function(path, mesh, face_fields, node_fields)


def _write_meshio(tmp, mesh, fcols, ncols, fmt):
    import meshio

    m = meshio.Mesh(
        np.asarray(mesh.vertices, dtype=np.float64),
        [("triangle", np.asarray(mesh.faces, dtype=np.int64))],
        cell_data={k: [np.ascontiguousarray(a)] for k, a in fcols},
        point_data={k: np.ascontiguousarray(a) for k, a in ncols},
    )
    kw = {"data_format": "XML"} if fmt == "xdmf" else {}
    if fmt == "vtk":
        # VTK's own legacy reader (ParaView's) knows the classic type names only: the 4.2
        # layout, booleans as unsigned_char (uint8), integers as int (int32) where they fit
        m.cell_data = {k: [_vtk_legacy_array(v[0])] for k, v in m.cell_data.items()}
        m.point_data = {k: _vtk_legacy_array(v) for k, v in m.point_data.items()}
        fmt, kw = "vtk42", {"binary": True}
    meshio.write(os.fspath(tmp), m, file_format=fmt, **kw)


def xdmf_data_path(path: str | os.PathLike) -> Path:
    """The HDF5 file of an ``.xdmf`` field file's heavy data, ``<stem>.data.h5`` beside it,
    checked: an existing file of that name without the mark of this XDMF file's side file
    is refused (InputError), as is a name equal to the XDMF file's."""
    from resection.io.outputs import side_path

    return side_path(path, "data", ".h5")


def _xdmf_item(h5name: str, key: str, a: np.ndarray) -> str:
    """An XDMF ``DataItem`` pointing at dataset ``key`` of ``h5name``."""
    from xml.sax.saxutils import escape

    kind = {"f": "Float", "i": "Int", "u": "UInt", "b": "UChar"}[a.dtype.kind]
    dims = " ".join(str(d) for d in a.shape)
    return (f'<DataItem Dimensions="{dims}" NumberType="{kind}" '
            f'Precision="{a.dtype.itemsize}" Format="HDF">{escape(h5name)}:/{key}</DataItem>')


def _write_xdmf_hdf5(path: str, mesh, fcols, ncols) -> None:
    """The ``.xdmf`` layout of the module docstring: the HDF5 file first, then the XML,
    each through a temporary name; the XML names the HDF5 file by its final name."""
    import contextlib
    import json
    from xml.sax.saxutils import quoteattr

    import h5py

    from resection.io.marks import mark
    from resection.io.outputs import atomic_path

    h5 = xdmf_data_path(path)
    pts = np.asarray(mesh.vertices, dtype=np.float64)
    tri = np.asarray(mesh.faces, dtype=np.int64)
    lines = ['<?xml version="1.0"?>', '<Xdmf Version="3.0">', "<Domain>",
             '<Grid Name="surface" GridType="Uniform">',
             f'<Topology TopologyType="Triangle" NumberOfElements="{len(tri)}">',
             _xdmf_item(h5.name, "triangles", tri), "</Topology>",
             '<Geometry GeometryType="XYZ">', _xdmf_item(h5.name, "points", pts),
             "</Geometry>"]
    with contextlib.ExitStack() as stack:
        tmp_h5 = stack.enter_context(atomic_path(h5))
        with h5py.File(tmp_h5, "w") as f:
            # the mark first, a fixed-length string: in the file's first bytes, where
            # resection.io.marks.is_marked looks for it
            f.attrs["mark"] = np.bytes_(json.dumps(mark(path, "resection map")))
            f.create_dataset("points", data=pts)
            f.create_dataset("triangles", data=tri)
            for where, cols in (("Cell", fcols), ("Node", ncols)):
                for k, a in cols:
                    key = f"{where.lower()}/{k}"
                    f.create_dataset(key, data=a)
                    lines += [f"<Attribute Name={quoteattr(k)} AttributeType=\"Scalar\" "
                              f'Center="{where}">', _xdmf_item(h5.name, key, a),
                              "</Attribute>"]
        lines += ["</Grid>", "</Domain>", "</Xdmf>", ""]
        atomic_text(path, "\n".join(x for x in lines if x))


def _vtk_legacy_array(a: np.ndarray) -> np.ndarray:
    """An array in a type VTK's legacy reader reads: float32/float64 kept, booleans and
    0/1 columns of a boolean field as uint8, other integers as int32 when they fit, else
    float64."""
    if a.dtype.kind == "f":
        return a
    if a.dtype == bool:
        return a.astype(np.uint8)
    if a.dtype == np.uint8:
        return a
    if a.size == 0 or (a.min() >= np.iinfo(np.int32).min and a.max() <= np.iinfo(np.int32).max):
        return a.astype(np.int32)
    return a.astype(np.float64)


def _ply_dtype(a: np.ndarray) -> str:
    if np.issubdtype(a.dtype, np.integer):
        info = np.iinfo(np.int32)
        if a.size and (a.min() < info.min or a.max() > info.max):
            raise InputError("PLY holds 32-bit integers only; a field exceeds them")
        return "<i4"
    return "<f8"


def _write_ply(tmp, mesh, fcols, ncols):
    from plyfile import PlyData, PlyElement

    V = np.asarray(mesh.vertices, dtype=np.float64)
    F = np.asarray(mesh.faces)
    vdt = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")] + [(k, _ply_dtype(a)) for k, a in ncols]
    vert = np.empty(len(V), dtype=vdt)
    vert["x"], vert["y"], vert["z"] = V.T
    for k, a in ncols:
        vert[k] = a
    fdt = [("vertex_indices", "<i4", (3,))] + [(k, _ply_dtype(a)) for k, a in fcols]
    face = np.empty(len(F), dtype=fdt)
    face["vertex_indices"] = F
    for k, a in fcols:
        face[k] = a
    PlyData([PlyElement.describe(vert, "vertex"),
             PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"},
                                 val_types={"vertex_indices": "i4"})],
            text=False, byte_order="<",
            comments=["windtunnel-optics surface fields"]).write(os.fspath(tmp))


def _write_csv(tmp, mesh, fcols, ncols):
    if fcols and ncols:
        raise InputError(f"{tmp}: a CSV holds face fields or node fields, not both (use .vtu)")
    if ncols:
        pos, cols, first = np.asarray(mesh.vertices, dtype=np.float64), ncols, "node"
        names = [first, "x", "y", "z"]
    else:
        pos, cols, first = np.asarray(mesh.triangles_center, dtype=np.float64), fcols, "face"
        names = [first, "cx", "cy", "cz"]
    table = np.column_stack([np.arange(len(pos)), pos] + [a.astype(np.float64)
                                                          for _, a in cols])
    fmt = ["%d", "%.17g", "%.17g", "%.17g"] + [
        "%d" if np.issubdtype(a.dtype, np.integer) else "%.17g" for _, a in cols]
    np.savetxt(tmp, table, fmt=fmt, delimiter=",",
               header=",".join(names + [k for k, _ in cols]), comments="")


def _write_npy(path, face_fields, node_fields):
    items = list((face_fields or {}).items()) + list((node_fields or {}).items())
    if len(items) != 1:
        raise InputError(f"{path}: a .npy file holds one field, got {len(items)} "
                         f"({', '.join(str(k) for k, _ in items)}); use .vtu or .csv")
    arr = np.asarray(items[0][1])
    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise InputError(f"{path}: field {items[0][0]!r} is not numeric")

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.save(fh, arr, allow_pickle=False)

    atomic_write(path, write)


def nam_path(path: str | os.PathLike) -> str:
    """The ``.nam`` sidecar of a Plot3D function file: same name, extension ``.nam``."""
    return os.fspath(Path(os.fspath(path)).with_suffix(".nam"))


def _write_function(path, mesh, face_fields, node_fields):
    from resection.io.plot3d import (
        faces_to_grid_nodes,
        vertices_to_grid_nodes,
        write_plot3d_function,
    )

    if node_fields and face_fields:
        raise InputError(f"{path}: a Plot3D function file holds node values: give node "
                         "fields or face fields, not both")
    if node_fields:
        cols = _columns(node_fields, len(mesh.vertices), "node")
    else:
        cols = _columns(face_fields, len(mesh.faces), "face")
    if not cols:
        raise InputError(f"{path}: no field to write")
    values = np.column_stack([a.astype(np.float64) for _, a in cols])
    nodes = vertices_to_grid_nodes(mesh, values) if node_fields else \
        faces_to_grid_nodes(mesh, values)
    nam = nam_path(path)
    if os.path.exists(nam) and not os.path.exists(path):
        raise InputError(f"{nam}: exists and was not made with {Path(path).name} (its variable "
                         "names go there); refusing to replace it: move it or choose another "
                         "output name")
    write_plot3d_function(path, nodes)
    atomic_text(nam, "".join(f"{name}\n" for name, _ in cols))


# --------------------------------------------------------------------------- reading
def read_fields(path: str | os.PathLike, n_faces: int | None = None, *,
                location: str = "face") -> dict[str, np.ndarray]:
    """Read the per-face (or per-node) fields of a file :func:`write_fields` writes.

    Parameters
    ----------
    n_faces : int, optional
        Check that every field has this many values (faces, or nodes with
        ``location="node"``).
    location : {"face", "node"}

    Returns
    -------
    dict of name -> (n,) float64 array, in file order (``.npy``: ``{"values": ...}``).
    """
    path = Path(os.fspath(path))
    if not path.exists():
        raise InputError(f"field file not found: {path}")
    if location not in ("face", "node"):
        raise InputError(f"location must be 'face' or 'node', got {location!r}")
    suffix = path.suffix.lower()
    if suffix in _MESHIO or suffix == ".xdmf":
        fields = _read_meshio(path, _MESHIO.get(suffix, "xdmf"), location)
    elif suffix == ".ply":
        fields = _read_ply(path, location)
    elif suffix == ".csv":
        fields = _read_csv(path, location)
    elif suffix == ".npy":
        from resection.io.images import load_npy

        arr = load_npy(path)
        if arr.ndim != 1:
            raise InputError(f"{path}: expected one value per {location} (1-D), got shape "
                             f"{arr.shape}")
        fields = {"values": arr.astype(np.float64)}
    else:
        raise InputError(f"{path}: unknown field file format {suffix!r} (use "
                         f"{', '.join(s for s in FIELD_SUFFIXES if s != '.f')})")
    if n_faces is not None:
        for name, v in fields.items():
            if len(v) != n_faces:
                raise InputError(f"{path}: field {name!r} has {len(v)} values but the mesh "
                                 f"has {n_faces} {location}s")
    return fields


def _read_meshio(path: Path, fmt: str, location: str) -> dict:
    import meshio

    reader = {"vtk": meshio.vtk.read, "vtu": meshio.vtu.read, "xdmf": meshio.xdmf.read}[fmt]
    try:
        m = reader(os.fspath(path))  # the format's reader raises (meshio.read would exit)
    except Exception as exc:  # meshio raises many kinds; report one line
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{path}: cannot be read as {fmt.upper()} ({msg})") from None
    if location == "node":
        return {k: np.asarray(v, dtype=np.float64) for k, v in m.point_data.items()
                if np.asarray(v).ndim == 1}
    tri = [i for i, c in enumerate(m.cells) if c.type == "triangle"]
    if len(tri) != len(m.cells):
        raise InputError(f"{path}: holds cells other than triangles")
    out = {}
    for k, blocks in m.cell_data.items():
        a = np.concatenate([np.asarray(blocks[i]) for i in tri])
        if a.ndim == 1:
            out[k] = a.astype(np.float64)
    return out


def _read_ply(path: Path, location: str) -> dict:
    from plyfile import PlyData, PlyParseError

    try:
        ply = PlyData.read(os.fspath(path))
    except (PlyParseError, ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: cannot be read as PLY ({exc})") from None
    name = "face" if location == "face" else "vertex"
    try:
        el = ply[name]
    except KeyError:
        raise InputError(f"{path}: no {name} element") from None
    skip = {"vertex_indices", "vertex_index"} if name == "face" else {"x", "y", "z"}
    return {p.name: np.asarray(el[p.name], dtype=np.float64) for p in el.properties
            if p.name not in skip and np.asarray(el[p.name]).ndim == 1}


def _read_csv(path: Path, location: str) -> dict:
    with open(path, encoding="utf-8-sig") as fh:
        header = fh.readline().strip().split(",")
    first, pos = ("face", ("cx", "cy", "cz")) if location == "face" else \
        ("node", ("x", "y", "z"))
    if header[:1] != [first]:
        raise InputError(f"{path}: expected a CSV whose first column is {first!r}, got "
                         f"{header[0]!r}")
    try:
        table = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, encoding="utf-8-sig")
    except ValueError as exc:
        raise InputError(f"{path}: non-numeric entry ({str(exc).splitlines()[0]})") from None
    if table.shape[1] != len(header):
        raise InputError(f"{path}: {table.shape[1]} columns but {len(header)} names")
    order = np.argsort(table[:, 0], kind="stable")
    return {n: table[order, k] for k, n in enumerate(header) if n not in (first, *pos)}
