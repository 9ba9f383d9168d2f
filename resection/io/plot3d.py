"""Plot3D surface grids (the wind-tunnel / CFD norm) and Plot3D function files.

Grid files (:func:`read_plot3d`, :func:`write_plot3d`): multi-block or single-block,
formatted ASCII or unformatted Fortran binary (4- or 8-byte record markers, either byte
order) or raw stream binary, single or double precision, with or without IBLANK, all
detected from the content whatever the extension (``.grid``, ``.grd``, ``.x``, ``.g``,
``.xyz``, ``.p3d``, ``.fmt``; :func:`is_plot3d`). A file whose coordinates are byte-swapped
relative to its record markers is detected (its values are implausible in one byte order and
plausible in the other) and read in the right order; a file implausible in both is refused
with a message saying so.

Function files (:func:`write_plot3d_function`, :func:`read_plot3d_function`): per-node
values on the grid, ``nblocks``, then ``ni nj nk nvar`` per block, then per block the
variables one after the other with ``i`` fastest (Fortran records, as the grid).
:func:`faces_to_grid_nodes` turns per-face values of a mesh made by
:func:`~resection.io.meshes.plot3d_to_mesh` back into per-node values on the blocks.
"""

from __future__ import annotations

import os

import numpy as np

from resection.errors import InputError
from resection.io._write import atomic_write

__all__ = [
    "read_plot3d",
    "write_plot3d",
    "is_plot3d",
    "write_plot3d_function",
    "read_plot3d_function",
    "faces_to_grid_nodes",
    "PLOT3D_SUFFIXES",
]

PLOT3D_SUFFIXES = (".xyz", ".x", ".p3d", ".g", ".grd", ".grid", ".fmt", ".p3dfmt", ".plot3d")


# --------------------------------------------------------------------------- Fortran records
def _fortran_records(data: bytes, marker: int, endian: str) -> list[bytes] | None:
    """Split unformatted sequential Fortran data into records, None if it is not that."""
    dt = np.dtype(f"{endian}i{marker}")
    pos, out, n = 0, [], len(data)
    view = memoryview(data).cast("B")  # records as views of the file's bytes, not copies
    while pos < n:
        if pos + marker > n:
            return None
        length = int(np.frombuffer(data, dt, 1, pos)[0])
        end = pos + marker + length
        if length < 0 or end + marker > n:
            return None
        if int(np.frombuffer(data, dt, 1, end)[0]) != length:
            return None
        out.append(view[pos + marker:end])
        pos = end + marker
    return out if out else None


def split_records(data: bytes):
    for marker in (4, 8):
        for endian in ("<", ">"):
            recs = _fortran_records(data, marker, endian)
            if recs is not None:
                return recs, endian
    return None, None


# --------------------------------------------------------------------------- Plot3D
def _block_layout(dims: np.ndarray, sizes_bytes: list[int] | int, source: str):
    """Precision and IBLANK presence from the data sizes. Returns (real_bytes, iblank)."""
    npts = np.prod(dims, axis=1)
    total = int(npts.sum())
    for real in (4, 8):
        for ib in (False, True):
            per = 3 * real + (4 if ib else 0)
            if isinstance(sizes_bytes, int):
                if sizes_bytes == per * total:
                    return real, ib
            elif all(s == per * int(p) for s, p in zip(sizes_bytes, npts, strict=True)):
                return real, ib
    raise InputError(
        f"{source}: Plot3D data sizes do not match the block dimensions "
        f"{dims.tolist()} for single or double precision, with or without IBLANK"
    )


def _split_block(values: np.ndarray, iblank: np.ndarray | None, dims):
    ni, nj, nk = (int(d) for d in dims)
    xyz = values.reshape(3, nk, nj, ni).transpose(3, 2, 1, 0)  # (ni, nj, nk, 3), i fastest
    ib = None if iblank is None else iblank.reshape(nk, nj, ni).transpose(2, 1, 0)
    return np.ascontiguousarray(xyz, dtype=np.float64), ib


def _parse_binary_plot3d(data: bytes, source: str):
    recs, endian = split_records(data)
    if recs is not None:
        header = 0
        first = recs[0]
        if len(first) == 4 and len(recs) >= 2:
            nb = int(np.frombuffer(first, f"{endian}i4")[0])
            dims = np.frombuffer(recs[1], f"{endian}i4")
            header = 2
        elif len(first) == 12:
            nb, dims, header = 1, np.frombuffer(first, f"{endian}i4"), 1
        else:
            raise InputError(f"{source}: unrecognised Plot3D header record ({len(first)} bytes)")
        if dims.size != 3 * nb or nb < 1:
            raise InputError(
                f"{source}: Plot3D header gives {nb} block(s) but {dims.size} dimensions "
                "(only 3-D grids with ni, nj, nk are read)"
            )
        dims = dims.reshape(nb, 3).astype(np.int64)
        if np.any(dims < 1):
            raise InputError(f"{source}: non-positive Plot3D block dimensions {dims.tolist()}")
        data_recs = recs[header:]
        if len(data_recs) != nb:
            raise InputError(
                f"{source}: Plot3D header announces {nb} block(s), file holds "
                f"{len(data_recs)} data record(s)"
            )
        real, has_ib = _block_layout(dims, [len(r) for r in data_recs], source)
        blocks = []
        for rec, d in zip(data_recs, dims, strict=True):  # loop over blocks
            n = int(np.prod(d))
            vals = _byte_order(np.frombuffer(rec, f"{endian}f{real}", 3 * n), source,
                               len(blocks) + 1)
            ib = np.frombuffer(rec, f"{endian}i4", n, 3 * n * real) if has_ib else None
            blocks.append(_split_block(vals, ib, d))
        return blocks, {"encoding": "fortran", "precision": real, "iblank": has_ib}
    # raw stream (C binary, no record markers)
    for endian in ("<", ">"):
        # the header only (block count, 3 dimensions a block): no copy of the whole file
        ints = np.frombuffer(data, f"{endian}i4", min(len(data) // 4, 1 + 3 * 100000))
        for multi in (True, False):
            if multi:
                if ints.size < 4 or not (1 <= ints[0] <= 100000):
                    continue
                nb, off = int(ints[0]), 1
            else:
                nb, off = 1, 0
            if ints.size < off + 3 * nb:
                continue
            dims = ints[off:off + 3 * nb].reshape(nb, 3).astype(np.int64)
            if np.any(dims < 1) or np.any(dims > 10**7):
                continue
            rest = len(data) - 4 * (off + 3 * nb)
            try:
                real, has_ib = _block_layout(dims, rest, source)
            except InputError:
                continue
            blocks, pos = [], 4 * (off + 3 * nb)
            for d in dims:
                n = int(np.prod(d))
                vals = _byte_order(np.frombuffer(data, f"{endian}f{real}", 3 * n, pos),
                                   source, len(blocks) + 1)
                pos += 3 * n * real
                ib = None
                if has_ib:
                    ib = np.frombuffer(data, f"{endian}i4", n, pos)
                    pos += 4 * n
                blocks.append(_split_block(vals, ib, d))
            return blocks, {"encoding": "stream", "precision": real, "iblank": has_ib}
    return None, None


def _implausible(vals: np.ndarray) -> int:
    """How many coordinates no grid holds: NaN/inf, |x| > 1e30, or 0 < |x| < 1e-30 (what
    bytes read in the wrong order give)."""
    with np.errstate(invalid="ignore", over="ignore"):
        a = np.abs(vals)
        return int(np.count_nonzero(~(a <= 1e30) | ((a < 1e-30) & (a > 0))))


def _byte_order(vals: np.ndarray, source: str, block: int) -> np.ndarray:
    """The block's coordinates in the byte order that makes them plausible.

    The byte order found from the header (record markers, dimensions) is tried first; when
    its values are implausible and the swapped order's are not, the coordinates were
    written in the other order (a mixed-endian file) and are read so. Implausible in both:
    an error saying so (not a degenerate-triangle message later)."""
    bad = _implausible(vals)
    if bad == 0:
        return vals
    swapped = vals.view(vals.dtype.newbyteorder())
    if _implausible(swapped) == 0:
        return swapped
    order = "big" if vals.dtype.byteorder == ">" else "little"
    raise InputError(
        f"{source}: block {block}: {bad} of {vals.size} coordinates are implausible (NaN, "
        f"or beyond 1e30 or below 1e-30 in magnitude) in both byte orders: wrong byte "
        f"order or precision, or not a Plot3D grid (header read as {order}-endian)"
    )


def _expand_repeats(tokens: list[str], source: str) -> np.ndarray:
    """Fortran list-directed repeat counts ``n*value``, expanded without a Python loop over
    the tokens."""
    arr = np.array(tokens)
    has = np.char.find(arr, "*") >= 0
    counts = np.ones(arr.size, dtype=np.int64)
    head, _, val = np.char.partition(arr[has], "*").T
    try:
        n = head.astype(np.int64)
    except ValueError:
        raise InputError(f"{source}: bad repeat count in '{arr[has][0]}'") from None
    if np.any(n < 1):
        raise InputError(f"{source}: repeat counts must be positive")
    counts[has] = n
    arr = arr.astype(val.dtype if val.dtype.itemsize > arr.dtype.itemsize else arr.dtype)
    arr[has] = val
    return np.repeat(arr, counts)


def _parse_ascii_plot3d(text: str, source: str):
    tokens = text.replace("D", "E").replace("d", "e").replace(",", " ").split()
    if "*" in text:
        tokens = _expand_repeats(tokens, source)
    try:
        v = np.array(tokens, dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{source}: not a Plot3D file (non-numeric entry: {exc})") from None
    for multi in (True, False):
        if multi:
            # nan or inf as the block count (int() of them raises): not a count
            if v.size < 4 or not np.isfinite(v[0]) or v[0] != np.round(v[0]) or v[0] < 1 \
                    or v[0] > v.size:
                continue
            nb, off = int(v[0]), 1
        else:
            nb, off = 1, 0
        if v.size < off + 3 * nb:
            continue
        dims = v[off:off + 3 * nb]
        if not np.all(np.isfinite(dims)) or np.any(dims != np.round(dims)) \
                or np.any(dims < 1) or np.any(dims > v.size):
            continue
        dims = dims.reshape(nb, 3).astype(np.int64)
        npts = np.prod(dims, axis=1)
        rest = v.size - off - 3 * nb
        if rest == 3 * npts.sum():
            has_ib = False
        elif rest == 4 * npts.sum():
            has_ib = True
        else:
            continue
        blocks, pos = [], off + 3 * nb
        for d, n in zip(dims, npts, strict=True):  # loop over blocks
            vals = v[pos:pos + 3 * n]
            pos += 3 * n
            ib = None
            if has_ib:
                ib = v[pos:pos + n]
                pos += n
                if np.any(ib != np.round(ib)):
                    raise InputError(f"{source}: Plot3D IBLANK values must be integers")
                ib = ib.astype(np.int32)
            blocks.append(_split_block(vals, ib, d))
        return blocks, {"encoding": "ascii", "precision": 8, "iblank": has_ib}
    raise InputError(
        f"{source}: the number of values ({v.size}) does not fit a Plot3D grid "
        "(multi- or single-block, 3 coordinates per point, optional IBLANK)"
    )


def read_bytes(path: str, kind: str, empty: str) -> bytes:
    """The whole file, or InputError naming it when it is missing or blank."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise InputError(f"{kind} file not found: {path}") from None
    if not data[:4096].strip() and not data.strip():  # (no copy of a big file that is not)
        raise InputError(f"{path}: {empty}")
    return data


def read_plot3d(path: str | os.PathLike) -> list[tuple[np.ndarray, np.ndarray | None]]:
    """Read a Plot3D grid file (format detected from its content).

    Returns
    -------
    list of (xyz, iblank)
        One entry per block: ``xyz`` (ni, nj, nk, 3) float64 and ``iblank`` (ni, nj, nk)
        int or None.
    """
    path = os.fspath(path)
    data = read_bytes(path, "Plot3D", "empty file")
    blocks = None
    # a binary grid has non-text bytes in its header (the block count and dimensions as
    # 4-byte integers); an ASCII one is text throughout: the first 4 kB decide
    raw = np.frombuffer(data[:4096], np.uint8)
    binary = bool(np.any((raw < 9) | ((raw > 13) & (raw < 32)) | (raw > 126)))
    text = ""
    if not binary:
        try:
            text = data.decode("ascii")
        except UnicodeDecodeError:
            binary = True  # text-like first 4 kB, binary after: try the binary layouts
    if binary:
        blocks, _info = _parse_binary_plot3d(data, path)
        if blocks is None:
            raise InputError(f"{path}: not a readable Plot3D file (binary, no layout fits)")
    else:
        blocks, _info = _parse_ascii_plot3d(text, path)
    for k, (xyz, _) in enumerate(blocks):  # (binary blocks passed _byte_order already)
        if not binary and not np.all(np.isfinite(xyz)):
            raise InputError(f"{path}: block {k + 1} holds NaN or infinite coordinates")
    return blocks


def write_plot3d(
    path: str | os.PathLike,
    blocks,
    *,
    iblank=None,
    binary: bool = True,
    precision: str = "double",
    endian: str = "<",
    multiblock: bool = True,
    records: bool = True,
) -> None:
    """Write a Plot3D grid.

    Parameters
    ----------
    blocks : list of (ni, nj, nk, 3) or (ni, nj, 3) arrays
        Grid points (a 2-D array gets ``nk = 1``).
    iblank : list of (ni, nj, nk) int arrays, optional
    binary : bool
        Unformatted binary (Fortran records unless ``records=False``: raw stream) or
        formatted ASCII.
    precision : {"single", "double"}
    endian : {"<", ">"}
    multiblock : bool
        Write the number of blocks first (required for more than one block).
    """
    arrs = []
    for k, b in enumerate(blocks):
        try:
            a = np.asarray(b, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"write_plot3d: block {k + 1} is not a numeric array") from None
        a = a[:, :, None, :] if a.ndim == 3 else a
        if a.ndim != 4 or a.shape[3] != 3 or 0 in a.shape:
            raise InputError(f"write_plot3d: block {k + 1} has shape {np.shape(b)}, expected "
                             "(ni, nj, nk, 3) or (ni, nj, 3)")
        if not np.all(np.isfinite(a)):
            raise InputError(f"write_plot3d: block {k + 1} holds NaN or infinite coordinates")
        arrs.append(a)
    if not arrs:
        raise InputError("write_plot3d: no blocks")
    if not multiblock and len(arrs) != 1:
        raise InputError("write_plot3d: several blocks need multiblock=True")
    ibs = [None] * len(arrs)
    if iblank is not None:
        iblank = list(iblank)
        if len(iblank) != len(arrs):
            raise InputError(f"write_plot3d: {len(iblank)} IBLANK arrays for {len(arrs)} "
                             "blocks")
        for k, (ib, a) in enumerate(zip(iblank, arrs, strict=True)):
            ib = np.asarray(ib)
            if ib.size != np.prod(a.shape[:3]) or not np.issubdtype(ib.dtype, np.integer):
                raise InputError(f"write_plot3d: IBLANK of block {k + 1} must be integers of "
                                 f"shape {a.shape[:3]}, got {ib.dtype} {ib.shape}")
            ibs[k] = ib.reshape(a.shape[:3])
    dims = np.array([a.shape[:3] for a in arrs], dtype=np.int64)
    real = {"single": 4, "double": 8}.get(precision)
    if real is None:
        raise InputError(f"write_plot3d: precision must be 'single' or 'double', got {precision}")

    def block_payload(a, ib):
        vals = a.transpose(3, 2, 1, 0).ravel()  # x, y, z each with i fastest
        out = np.asarray(vals, f"{endian}f{real}").tobytes()
        if ib is not None:
            out += np.asarray(ib.transpose(2, 1, 0).ravel(), f"{endian}i4").tobytes()
        return out

    path = os.fspath(path)
    if binary:
        def rec(payload: bytes) -> bytes:
            if not records:
                return payload
            m = np.array([len(payload)], f"{endian}i4").tobytes()
            return m + payload + m

        parts = []
        if multiblock:
            parts.append(rec(np.array([len(arrs)], f"{endian}i4").tobytes()))
        parts.append(rec(np.asarray(dims.ravel(), f"{endian}i4").tobytes()))
        parts += [rec(block_payload(a, ib)) for a, ib in zip(arrs, ibs, strict=True)]
        payload = b"".join(parts)

        def write_bin(tmp):
            with open(tmp, "wb") as fh:
                fh.write(payload)

        atomic_write(path, write_bin)
        return
    fmt = "%.8e" if real == 4 else "%.17e"

    def write_ascii(tmp):
        with open(tmp, "w", encoding="ascii") as fh:
            if multiblock:
                fh.write(f"{len(arrs)}\n")
            for d in dims:
                fh.write(f"{d[0]} {d[1]} {d[2]}\n")
            for a, ib in zip(arrs, ibs, strict=True):
                np.savetxt(fh, a.transpose(3, 2, 1, 0).reshape(-1, 4) if a.size % 4 == 0
                           else a.transpose(3, 2, 1, 0).reshape(-1, 1), fmt=fmt)
                if ib is not None:
                    np.savetxt(fh, ib.transpose(2, 1, 0).reshape(-1, 1), fmt="%d")

    atomic_write(path, write_ascii)


# --------------------------------------------------------------------------- by content
def is_plot3d(path: str | os.PathLike) -> bool:
    """True when the file parses as a Plot3D grid (any of the layouts :func:`read_plot3d`
    reads), whatever its extension."""
    try:
        read_plot3d(path)
    except (InputError, UnicodeDecodeError, ValueError):
        return False
    return True


# --------------------------------------------------------------------------- function files
def write_plot3d_function(
    path: str | os.PathLike,
    values,
    *,
    precision: str = "double",
    endian: str = "<",
) -> None:
    """Write per-node values as a multi-block Plot3D function file (``.f``).

    Parameters
    ----------
    values : list of (ni, nj, nk, nvar) or (ni, nj, nk) arrays
        One array per grid block, on the grid's nodes (NaN allowed: nodes without a value).
    precision : {"single", "double"}
    endian : {"<", ">"}

    Layout: Fortran unformatted records (4-byte markers): ``nblocks``; ``ni nj nk nvar`` for
    every block; then one record per block with the variables one after the other, ``i``
    fastest, then ``j``, then ``k`` (what Plot3D readers such as ParaView's expect with
    "multi-block", "binary" and "has byte count").
    """
    real = {"single": 4, "double": 8}.get(precision)
    if real is None:
        raise InputError(f"{path}: precision must be 'single' or 'double', got {precision!r}")
    arrs = []
    for k, v in enumerate(values):
        a = np.asarray(v, dtype=np.float64)
        if a.ndim == 3:
            a = a[..., None]
        if a.ndim != 4 or 0 in a.shape:
            raise InputError(f"{path}: block {k + 1} values have shape {np.shape(v)}, expected "
                             "(ni, nj, nk[, nvar])")
        arrs.append(a)
    if not arrs:
        raise InputError(f"{path}: no blocks to write")

    def rec(payload: bytes) -> bytes:
        m = np.array([len(payload)], f"{endian}i4").tobytes()
        return m + payload + m

    parts = [rec(np.array([len(arrs)], f"{endian}i4").tobytes()),
             rec(np.array([a.shape for a in arrs], f"{endian}i4").ravel().tobytes())]
    parts += [rec(np.asarray(a.transpose(3, 2, 1, 0).ravel(), f"{endian}f{real}").tobytes())
              for a in arrs]
    payload = b"".join(parts)

    def write(tmp):
        with open(tmp, "wb") as fh:
            fh.write(payload)

    atomic_write(path, write)


def read_plot3d_function(path: str | os.PathLike) -> list[np.ndarray]:
    """Read a multi-block Plot3D function file written as :func:`write_plot3d_function`
    writes it (either byte order, single or double precision). Returns one
    ``(ni, nj, nk, nvar)`` float64 array per block."""
    path = os.fspath(path)
    data = read_bytes(path, "Plot3D function", "empty file")
    recs, endian = split_records(data)
    if recs is None or len(recs) < 3 or len(recs[0]) != 4:
        raise InputError(f"{path}: not a multi-block Plot3D function file (Fortran records)")
    nb = int(np.frombuffer(recs[0], f"{endian}i4")[0])
    dims = np.frombuffer(recs[1], f"{endian}i4")
    if nb < 1 or dims.size != 4 * nb or len(recs) != 2 + nb:
        raise InputError(f"{path}: Plot3D function header does not match its records")
    dims = dims.reshape(nb, 4)
    out = []
    for k, (r, d) in enumerate(zip(recs[2:], dims, strict=True)):
        n = int(np.prod(d))
        real = len(r) // n if n else 0
        if real not in (4, 8) or len(r) != real * n:
            raise InputError(f"{path}: block {k + 1}: {len(r)} bytes for {n} values")
        v = np.frombuffer(r, f"{endian}f{real}").astype(np.float64)
        out.append(v.reshape(d[3], d[2], d[1], d[0]).transpose(3, 2, 1, 0).copy())
    return out


def _grid_dims(mesh) -> list[tuple[int, int, int]]:
    dims = mesh.metadata.get("plot3d_dims") if hasattr(mesh, "metadata") else None
    if dims is None:
        raise InputError("per-node Plot3D output needs a mesh read from a Plot3D grid")
    return [tuple(int(x) for x in d) for d in dims]


def vertices_to_grid_nodes(mesh, vertex_values) -> list[np.ndarray]:
    """Per-vertex values of a triangulated Plot3D grid on the grid's own nodes.

    ``mesh`` must come from :func:`~resection.io.meshes.plot3d_to_mesh` (or
    :func:`~resection.io.meshes.load_mesh` of a Plot3D file): ``metadata["plot3d_node_vertex"]``
    gives the mesh vertex of every grid node (nodes merged across block interfaces share
    it, and so their value). NaN at a node no face uses (blanked).

    Parameters
    ----------
    vertex_values : (n_vertices,) or (n_vertices, nvar) array

    Returns
    -------
    list of (ni, nj, nk, nvar) float64 arrays, one per block.
    """
    dims = _grid_dims(mesh)
    nv = mesh.metadata.get("plot3d_node_vertex")
    if nv is None:
        raise InputError("per-node Plot3D output needs a mesh read from a Plot3D grid")
    v = np.asarray(vertex_values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape[0] != len(mesh.vertices):
        raise InputError(f"{v.shape[0]} node values for {len(mesh.vertices)} vertices")
    nv = np.asarray(nv)
    vals = np.where((nv >= 0)[:, None], v[np.maximum(nv, 0)], np.nan)
    out, pos = [], 0
    for d in dims:
        n = int(np.prod(d))
        out.append(vals[pos:pos + n].reshape(*d, v.shape[1]))
        pos += n
    return out


def faces_to_grid_nodes(mesh, face_values) -> list[np.ndarray]:
    """Per-face values of a triangulated Plot3D grid as per-node values on its blocks.

    ``mesh`` must come from :func:`~resection.io.meshes.plot3d_to_mesh` (or
    :func:`~resection.io.meshes.load_mesh` of a Plot3D file): its ``face_attributes``
    ``block``, ``cell_i``, ``cell_j`` and ``metadata["plot3d_dims"]`` locate every face.
    Blocks are numbered from 1 in ``face_attributes["block"]``. A cell's value is the mean
    of its (up to two) finite triangle values; a node's value is the mean of its (up to
    four) adjacent finite cells; NaN where none. (For image values, ``map`` writes the node
    values of :meth:`resection.surface.surface_map.SurfaceMap.to_nodes` instead: see
    :mod:`resection.surface.node_values`.)

    Parameters
    ----------
    face_values : (n_faces,) or (n_faces, nvar) array

    Returns
    -------
    list of (ni, nj, nk, nvar) float64 arrays, one per block (the grid's own dimensions).
    """
    dims = mesh.metadata.get("plot3d_dims")
    fa = mesh.face_attributes
    if dims is None or not all(k in fa for k in ("block", "cell_i", "cell_j")):
        raise InputError("per-node Plot3D output needs a mesh read from a Plot3D grid")
    v = np.asarray(face_values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape[0] != len(mesh.faces):
        raise InputError(f"{v.shape[0]} face values for {len(mesh.faces)} faces")
    blk = np.asarray(fa["block"])
    ci, cj = np.asarray(fa["cell_i"]), np.asarray(fa["cell_j"])
    out = []
    for b, d in enumerate(dims):  # loop over blocks (a handful), not faces
        d = tuple(int(x) for x in d)
        keep = [a for a in range(3) if d[a] > 1]
        na, nb = d[keep[0]], d[keep[1]]
        sel = blk == b + 1  # blocks count from 1
        cell = ci[sel] * (nb - 1) + cj[sel]
        fin = np.isfinite(v[sel])
        ncell = (na - 1) * (nb - 1)
        csum = np.zeros((ncell, v.shape[1]))
        ccnt = np.zeros((ncell, v.shape[1]))
        np.add.at(csum, cell, np.where(fin, v[sel], 0.0))
        np.add.at(ccnt, cell, fin)
        with np.errstate(invalid="ignore", divide="ignore"):
            cval = (csum / ccnt).reshape(na - 1, nb - 1, -1)
        has = np.isfinite(cval)
        nsum = np.zeros((na, nb, v.shape[1]))
        ncnt = np.zeros((na, nb, v.shape[1]))
        cz = np.where(has, cval, 0.0)
        for di in (0, 1):  # the four corners of every cell
            for dj in (0, 1):
                nsum[di:na - 1 + di, dj:nb - 1 + dj] += cz
                ncnt[di:na - 1 + di, dj:nb - 1 + dj] += has
        with np.errstate(invalid="ignore", divide="ignore"):
            node = nsum / ncnt
        out.append(node.reshape(*d, v.shape[1]))
    return out
