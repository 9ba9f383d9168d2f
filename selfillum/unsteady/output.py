"""The unsteady run's file: dCp of every frame at every node, in one chunked HDF5 dataset,
with an XDMF sidecar for ParaView and, on request, uPSP's flat files.

Layout (``format = "selfillum-unsteady"``, ``version = 1`` in the root attributes)::

    /dcp                 (T, N) float32   dCp, row = frame, column = grid node; NaN unseen
    /grid/points         (N, 3) float64   grid nodes in the grid file's order (block by
                                          block, i fastest): node n of /dcp
    /grid/triangles      (F, 3) int64     the triangles, in node numbers
    /grid/block_dims     (B, 3) int64     ni, nj, nk of each block
    /frames/time         (T,) float64     seconds from the first frame
    /frames/index        (T,) int64       frame numbers in the videos
    /cameras/camNN/K, dist                intrinsics of camera NN (attributes width, height,
                                          number, video)
    /cameras/camNN/R, t  (T, 3, 3), (T, 3) its pose in each frame (x_cam = R X + t)
    /steady/cp, /steady/gain  (N,)        steady Cp and Phase 2 gain per node
    /stats/dcp_mean, /stats/dcp_rms (N,)  mean and RMS (about zero) of dCp over the frames
    /stats/si_change_rms (N,)             RMS over the frames of dCp(SI removed) - dCp(not)
    root attributes: conditions, options, provenance (JSON text), si_change_median,
                     si_change_p95

Chunks (:func:`chunk_shape`): ``(tc, nc)`` about 256 kB, shaped so that reading one frame
of every node and reading one node's whole history cost about the same number of bytes
(``N tc ~ T nc``). Phase 1 writes blocks of ``tc`` frames (whole chunk rows), Phase 2 reads
blocks of ``nc`` nodes (whole chunk columns).

Flat files (``--upsp-flat``, uPSP's ``psp_process`` outputs): ``pressure`` (``T`` rows of
``N`` float32, row = frame) and ``pressure_transpose`` (``N`` rows of ``T`` float32,
row = node), little-endian, no header.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

__all__ = ["FORMAT", "VERSION", "chunk_shape", "write_xdmf", "write_flat", "writing"]

FORMAT = "selfillum-unsteady"
VERSION = 1
CHUNK_BYTES = 256 * 1024


def chunk_shape(n_frames: int, n_nodes: int, chunk_bytes: int = CHUNK_BYTES,
                itemsize: int = 4) -> tuple[int, int]:
    """``(tc, nc)``: ``tc nc itemsize ~ chunk_bytes`` and ``tc / nc ~ T / N`` (one frame
    and one node's history read the same number of chunk bytes), within the dataset."""
    T, N = max(int(n_frames), 1), max(int(n_nodes), 1)
    cells = max(chunk_bytes // itemsize, 1)
    tc = int(np.clip(round(np.sqrt(cells * T / N)), 1, T))
    nc = int(np.clip(cells // tc, 1, N))
    return tc, nc


@contextlib.contextmanager
def writing(path, temporaries: dict | None = None):
    """An :class:`OSError` raised inside (a full disk, a quota) named after the output
    ``path`` it was writing when it names no file or one of its ``temporaries`` (temporary
    name -> output), so that the user reads which output could not be written."""
    try:
        yield
    except OSError as exc:
        names = {str(k): v for k, v in (temporaries or {}).items()}
        if exc.filename is None or str(exc.filename) in names:
            target = names.get(str(exc.filename), path)
            raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from None
        raise


def json_attr(obj) -> str:
    return json.dumps(obj, indent=1, sort_keys=True, default=str)


def write_xdmf(path: Path, h5_name: str, n_frames: int, n_nodes: int, n_tris: int,
               times) -> None:
    """The XDMF sidecar: the grid, and one temporal grid per frame whose ``dCp`` is row
    ``k`` of ``/dcp`` (a hyperslab), plus the per-node statistics."""
    h5 = escape(h5_name)
    lines = [
        '<?xml version="1.0"?>',
        '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">',
        "<Domain>",
        '<Grid Name="grid" GridType="Uniform">',
        f'<Topology TopologyType="Triangle" NumberOfElements="{n_tris}">',
        f'<DataItem Dimensions="{n_tris} 3" NumberType="Int" Precision="8" Format="HDF">'
        f"{h5}:/grid/triangles</DataItem>",
        "</Topology>",
        '<Geometry GeometryType="XYZ">',
        f'<DataItem Dimensions="{n_nodes} 3" NumberType="Float" Precision="8" '
        f'Format="HDF">{h5}:/grid/points</DataItem>',
        "</Geometry>",
    ]
    for name in ("dcp_mean", "dcp_rms"):
        lines += [f'<Attribute Name="{name}" AttributeType="Scalar" Center="Node">',
                  f'<DataItem Dimensions="{n_nodes}" NumberType="Float" Precision="4" '
                  f'Format="HDF">{h5}:/stats/{name}</DataItem>', "</Attribute>"]
    lines += ["</Grid>", '<Grid Name="dcp" GridType="Collection" CollectionType="Temporal">']
    include = ('<xi:include xpointer="xpointer(//Grid[@Name=&quot;grid&quot;]/*'
               '[self::Topology or self::Geometry])"/>')
    for k in range(n_frames):  # one entry of text per frame
        lines += [
            f'<Grid Name="frame {k}" GridType="Uniform">', include,
            f'<Time Value="{float(times[k])!r}"/>',
            '<Attribute Name="dCp" AttributeType="Scalar" Center="Node">',
            f'<DataItem ItemType="HyperSlab" Dimensions="1 {n_nodes}" Type="HyperSlab">',
            f'<DataItem Dimensions="3 2" Format="XML">{k} 0 1 1 1 {n_nodes}</DataItem>',
            f'<DataItem Dimensions="{n_frames} {n_nodes}" NumberType="Float" Precision="4" '
            f'Format="HDF">{h5}:/dcp</DataItem>',
            "</DataItem>", "</Attribute>", "</Grid>",
        ]
    lines += ["</Grid>", "</Domain>", "</Xdmf>", ""]
    Path(path).write_text("\n".join(lines), encoding="utf-8")


def write_flat(h5file, pressure_path, transpose_path, node_block: int | None = None) -> None:
    """uPSP's ``pressure`` and ``pressure_transpose`` from ``/dcp``, streamed along the
    chunks (blocks of frames for one, blocks of ``node_block`` nodes, default a chunk
    column, for the other)."""
    ds = h5file["dcp"]
    T, N = ds.shape
    tc, nc = ds.chunks
    nc = int(node_block or nc)
    with open(pressure_path, "wb") as fh:
        for a in range(0, T, tc):  # blocks of frames
            fh.write(np.ascontiguousarray(ds[a:a + tc], dtype="<f4").tobytes())
    with open(transpose_path, "wb") as fh:
        for a in range(0, N, nc):  # blocks of nodes
            fh.write(np.ascontiguousarray(ds[:, a:a + nc].T, dtype="<f4").tobytes())


def provenance(paths: dict) -> dict:
    """Input files with their size and modification time, and the software's version."""
    from importlib import metadata

    try:
        version = metadata.version("windtunnel-optics")
    except metadata.PackageNotFoundError:
        version = "unknown"
    files = {}
    for key, p in paths.items():
        if p is None:
            continue
        for q in (p if isinstance(p, (list, tuple)) else [p]):
            st = os.stat(q)
            files.setdefault(key, []).append({"path": str(Path(q).resolve()),
                                              "size": st.st_size, "mtime": st.st_mtime})
    return {"software": "windtunnel-optics", "version": version, "files": files}
