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

Flat files (``--upsp-flat``): the files of uPSP's ``psp_process`` that its scripts read,
beside ``OUT.h5``, little-endian float32, no header, nodes in the grid file's order
(:data:`FLAT_FILES`):

* ``pressure`` (``T`` rows of ``N``, row = frame) and ``pressure_transpose`` (``N`` rows of
  ``T``, row = node): dCp;
* ``X``, ``Y``, ``Z`` (``N``): the grid's nodes; uPSP's ``upsp-kulite-comparison``
  (``_read_pressure_transpose``) takes the node count from the size of ``X`` and the
  frame count from ``pressure_transpose``'s;
* per node (``N``): ``avg`` and ``rms`` of dCp over the frames (rms about zero), ``gain``
  (Phase 2's), ``steady_state`` (steady Cp; above 3 NaN, as ``psp_process`` writes it),
  ``model_temp`` (the model's temperature, deg F), ``coverage`` (how many cameras see the
  node in the first frame), ``intensity_avg`` and ``intensity_rms`` (the intensity Phase 1
  mapped, mean and rms over the frames) and ``intensity_ratio_0`` (``intensity_avg`` over
  the first frame's intensity, less 1).

``psp_process``'s ``intensity`` and ``intensity_transpose`` (every frame's raw intensity,
as large as ``pressure``) are not written: no uPSP script reads them.
"""

from __future__ import annotations

import contextlib
import json
import os
import warnings
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

__all__ = ["FORMAT", "VERSION", "FLAT_FILES", "chunk_shape", "write_xdmf", "write_flat",
           "write_node_files", "camera_coverage", "writing", "node_fields", "surface_fields"]

FORMAT = "selfillum-unsteady"
VERSION = 1
CHUNK_BYTES = 256 * 1024
#: The flat files of ``--upsp-flat``: the two time histories, then one value per node.
FLAT_FILES = ("pressure", "pressure_transpose", "X", "Y", "Z", "avg", "rms", "gain",
              "steady_state", "model_temp", "coverage", "intensity_avg", "intensity_rms",
              "intensity_ratio_0")
#: uPSP writes a steady Cp above this as NaN (``psp_process``: no steady data there).
STEADY_CP_MAX = 3.0


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


def node_fields(h5file) -> list:
    """``(name, dataset)`` of the per-node fields beyond the statistics that the file holds
    (the uncertainty's, ``--uncertainty``)."""
    names = ("dcp_u", "dcp_u_noise", "dcp_u_mapping", "dcp_u_gain", "stats/dcp_rms_signal",
             "stats/dcp_rms_signal_u", "psd/noise_floor")
    return [(n.split("/")[-1], "/" + n) for n in names if n in h5file]


def surface_fields(h5file) -> list:
    """``(name, dataset)`` of the per-node fields ``--surface`` writes: the steady Cp, the
    mean and RMS of dCp, and :func:`node_fields`."""
    base = [("cp", "/steady/cp"), ("dcp_mean", "/stats/dcp_mean"),
            ("dcp_rms", "/stats/dcp_rms")]
    return [(n, d) for n, d in base if d[1:] in h5file] + node_fields(h5file)


def write_xdmf(path: Path, h5_name: str, n_frames: int, n_nodes: int, n_tris: int,
               times, extra=()) -> None:
    """The XDMF sidecar: the grid, and one temporal grid per frame whose ``dCp`` is row
    ``k`` of ``/dcp`` (a hyperslab), plus the per-node statistics and the ``extra``
    ``(name, dataset)`` node fields."""
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
    fields = [(n, f"/stats/{n}") for n in ("dcp_mean", "dcp_rms")] + list(extra)
    for name, ds in fields:
        lines += [f'<Attribute Name="{name}" AttributeType="Scalar" Center="Node">',
                  f'<DataItem Dimensions="{n_nodes}" NumberType="Float" Precision="4" '
                  f'Format="HDF">{h5}:{escape(ds)}</DataItem>', "</Attribute>"]
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


def _f4(a) -> bytes:
    return np.ascontiguousarray(a, dtype="<f4").tobytes()


def write_node_files(h5file, paths: dict, *, work=None, coverage=None,
                     node_block: int | None = None) -> None:
    """The per-node flat files of :data:`FLAT_FILES` (all but the two time histories) from
    the run's output file ``h5file`` (open) into ``paths`` (name -> path).

    Parameters
    ----------
    work : h5py.File, optional
        Phase 1's work file: its ``values`` (uint16 codes, ``values_scale`` per frame)
        give ``intensity_avg``, ``intensity_rms`` and ``intensity_ratio_0``, read in
        blocks of ``node_block`` nodes (default a chunk column). Without it those three
        files are NaN.
    coverage : (N,) array_like, optional
        Cameras seeing each node (:func:`camera_coverage`); NaN without it.
    """
    pts = h5file["grid/points"][()]
    N = len(pts)
    cond = json.loads(h5file.attrs["conditions"])
    steady = np.asarray(h5file["steady/cp"][()], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        steady = np.where(steady > STEADY_CP_MAX, np.nan, steady)
    values = {
        "X": pts[:, 0], "Y": pts[:, 1], "Z": pts[:, 2],
        "avg": h5file["stats/dcp_mean"][()], "rms": h5file["stats/dcp_rms"][()],
        "gain": h5file["steady/gain"][()], "steady_state": steady,
        "model_temp": np.full(N, float(cond.get("surface_temperature", np.nan))),
        "coverage": np.full(N, np.nan) if coverage is None else np.asarray(coverage),
    }
    i_avg, i_rms, i_ratio = (np.full(N, np.nan) for _ in range(3))
    if work is not None:
        from selfillum.unsteady.work import decode_columns

        ds, scale = work["values"], work["values_scale"][()]
        nc = int(node_block or ds.chunks[1])
        for a in range(0, N, nc):  # blocks of nodes: one chunk column at a time
            x = decode_columns(ds[:, a:a + nc], scale)
            with np.errstate(invalid="ignore", divide="ignore"), \
                    warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a node never seen
                i_avg[a:a + nc] = np.nanmean(x, axis=0)
                i_rms[a:a + nc] = np.sqrt(np.nanmean(x * x, axis=0))
                i_ratio[a:a + nc] = i_avg[a:a + nc] / x[0] - 1.0
    values.update(intensity_avg=i_avg, intensity_rms=i_rms, intensity_ratio_0=i_ratio)
    for name, path in paths.items():
        with open(path, "wb") as fh:
            fh.write(_f4(values[name]))


def camera_coverage(grid, cameras, max_obliqueness: float) -> np.ndarray:
    """(N,) float32: how many of ``cameras`` (each in its first frame's pose) see each grid
    node, as ``psp_process``'s ``coverage`` (its projection of an image of ones, summed
    over the cameras): a node is seen by a camera when a pixel lands on a face around it,
    faces more oblique than ``max_obliqueness`` degrees left out."""
    from resection.surface.surface_map import SurfaceMap

    count = np.zeros(len(grid.mesh.vertices), np.float32)
    for cam in cameras:
        sm = SurfaceMap(grid.mesh, cam, max_obliqueness=max_obliqueness)
        count += ~sm.to_nodes(np.ones(sm.shape, np.float32)).unseen
    return grid.to_nodes(count)


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
