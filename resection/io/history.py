"""Time histories: every frame of a run mapped onto the grid, in one HDF5 file (h5py), with
an XDMF sidecar so that ParaView opens it as a time series.

File layout (``format = "resection-history"``, ``version = 1`` in the root attributes)::

    /grid/points          (V, 3) float64   grid nodes, model units
    /grid/triangles       (F, 3) int64     faces (node indices)
    /frames/time          (T,)   float64   frame times, seconds
    /frames/index         (T,)   int64     frame numbers in the source sequence
    /frames/camera/K      (T, 3, 3)        each frame's camera (attributes width, height)
    /frames/camera/dist   (T, 5)
    /frames/camera/R      (T, 3, 3)        x_cam = R X + t: the pose relative to the model
    /frames/camera/t      (T, 3)
    /values/000000 ...    (N,) float32     frame k's values, one dataset (one chunk) a frame;
                                           N = V (per node) or F (per face); NaN = unseen

Root attributes: ``per`` (``"node"`` or ``"face"``), ``n_frames`` (frames committed).

Frames are written as they finish: the values first, then the frame's time and camera,
then ``n_frames`` is raised and the file flushed. A frame is committed when ``n_frames``
counts it; an interrupted run keeps every committed frame, and :class:`HistoryWriter` with
``resume=True`` drops whatever lies beyond ``n_frames`` and carries on. One dataset a frame
keeps memory flat over the run (nothing is held but the current frame) and lets the XDMF
sidecar point at each frame with a plain HDF5 path (readable by ParaView and by meshio's
XDMF time-series reader). The sidecar (``<file>.xdmf``, written to a temporary name and
renamed) is rewritten when the writer closes and every ``xdmf_every`` frames;
:func:`write_xdmf` rebuilds it from the HDF5 file alone.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import h5py
import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.io.outputs import atomic_path

__all__ = ["FORMAT", "HistoryWriter", "History", "read_history", "write_xdmf", "xdmf_path"]

FORMAT = "resection-history"
VERSION = 1
_CAM = {"K": (3, 3), "dist": (5,), "R": (3, 3), "t": (3,)}


def xdmf_path(path: str | os.PathLike) -> Path:
    """The sidecar of a history file: ``P.h5`` -> ``P.xdmf``."""
    return Path(path).with_suffix(".xdmf")


def _grid_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    try:
        points = np.asarray(mesh.vertices, dtype=np.float64)
        tris = np.asarray(mesh.faces, dtype=np.int64)
    except (AttributeError, TypeError, ValueError):
        raise InputError(f"mesh: expected a triangle mesh, got {type(mesh).__name__}") from None
    if points.ndim != 2 or points.shape[1] != 3 or tris.ndim != 2 or tris.shape[1] != 3:
        raise InputError("mesh: expected (V, 3) vertices and (F, 3) triangles")
    return points, tris


class HistoryWriter:
    """Append mapped frames to a time-history file as they finish.

    Parameters
    ----------
    path : path-like
        The HDF5 file (``.h5``). A file already there is continued with ``resume=True``
        and refused otherwise (never overwritten).
    mesh : trimesh.Trimesh
        The grid the values live on.
    per : {"node", "face"}
        Values per grid node or per face.
    resume : bool
        Continue a file written by an earlier (interrupted) run on the same grid.
    xdmf_every : int
        Rewrite the XDMF sidecar every so many frames (and at :meth:`close`).

    Examples
    --------
    >>> with HistoryWriter("p.h5", mesh, per="node") as w:       # doctest: +SKIP
    ...     for k, (img, cam) in enumerate(zip(frames, cameras)):
    ...         w.append(values_of(img, cam), time=k / fps, camera=cam)
    """

    def __init__(self, path, mesh, *, per: str = "node", resume: bool = False,
                 xdmf_every: int = 100):
        if per not in ("node", "face"):
            raise InputError(f"per must be 'node' or 'face', got {per!r}")
        self.path = Path(path)
        self.per = per
        self.xdmf_every = max(1, int(xdmf_every))
        points, tris = _grid_arrays(mesh)
        self.n_values = len(points) if per == "node" else len(tris)
        if self.path.suffix.lower() not in (".h5", ".hdf5", ".hdf"):
            raise InputError(f"{self.path}: a time history is an HDF5 file (.h5)")
        if self.path.exists() and not resume:
            raise InputError(f"{self.path}: exists (resume it, or remove it first)")
        try:
            if self.path.exists():
                self._f = h5py.File(self.path, "r+")
                self._check_resumable(points, tris)
            else:
                self._f = h5py.File(self.path, "w")
                self._create(points, tris)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write the time history ({exc})") from None
        self._since_xdmf = 0

    # ------------------------------------------------------------------ set-up
    def _create(self, points, tris) -> None:
        f = self._f
        f.attrs["format"] = FORMAT
        f.attrs["version"] = VERSION
        f.attrs["per"] = self.per
        f.attrs["n_frames"] = 0
        g = f.create_group("grid")
        g.create_dataset("points", data=points)
        g.create_dataset("triangles", data=tris)
        fr = f.create_group("frames")
        fr.create_dataset("time", shape=(0,), maxshape=(None,), dtype="f8", chunks=(1024,))
        fr.create_dataset("index", shape=(0,), maxshape=(None,), dtype="i8", chunks=(1024,))
        cam = fr.create_group("camera")
        for name, shape in _CAM.items():
            cam.create_dataset(name, shape=(0,) + shape, maxshape=(None,) + shape, dtype="f8",
                               chunks=(256,) + shape)
        f.create_group("values")
        f.flush()

    def _check_resumable(self, points, tris) -> None:
        f = self._f
        if f.attrs.get("format") != FORMAT:
            raise InputError(f"{self.path}: not a {FORMAT} file; cannot resume it")
        if f.attrs.get("per") != self.per:
            raise InputError(f"{self.path}: holds values per {f.attrs.get('per')}, not per "
                             f"{self.per}; cannot resume it")
        g = f["grid"]
        if g["points"].shape != points.shape or g["triangles"].shape != tris.shape \
                or not np.array_equal(g["triangles"][()], tris) \
                or not np.allclose(g["points"][()], points, rtol=0, atol=1e-9):
            raise InputError(f"{self.path}: written for another grid; cannot resume it")
        n = int(f.attrs["n_frames"])
        for name in list(f["values"]):  # a frame begun but not committed
            if int(name) >= n:
                del f["values"][name]
        fr = f["frames"]
        for ds in (fr["time"], fr["index"], *(fr["camera"][k] for k in _CAM)):
            ds.resize(n, axis=0)
        f.flush()

    # ------------------------------------------------------------------ writing
    @property
    def n_frames(self) -> int:
        """Frames committed so far (a resumed file starts with its earlier frames)."""
        return int(self._f.attrs["n_frames"])

    @property
    def done(self) -> np.ndarray:
        """Source frame numbers already committed (to skip when resuming)."""
        return self._f["frames/index"][()]

    def append(self, values, *, time: float, camera: Camera | None = None,
               index: int | None = None) -> None:
        """Commit one frame.

        Parameters
        ----------
        values : (N,) array_like
            The frame's per-node or per-face values (NaN where unseen); stored as float32.
        time : float
            Frame time, seconds.
        camera : Camera, optional
            The frame's camera (its pose relative to the model); NaN when not given.
        index : int, optional
            The frame's number in the source sequence (default: its position here).
        """
        v = np.asarray(values)
        if v.shape != (self.n_values,):
            raise InputError(f"values: expected ({self.n_values},) per {self.per}, got shape "
                             f"{v.shape}")
        n = self.n_frames
        f = self._f
        f["values"].create_dataset(f"{n:06d}", data=v.astype(np.float32, copy=False))
        fr = f["frames"]
        for ds, val in ((fr["time"], float(time)), (fr["index"], n if index is None else index)):
            ds.resize(n + 1, axis=0)
            ds[n] = val
        for name, shape in _CAM.items():
            ds = fr["camera"][name]
            ds.resize(n + 1, axis=0)
            ds[n] = np.full(shape, np.nan) if camera is None else getattr(camera, name)
        if camera is not None:
            fr["camera"].attrs["width"] = camera.width
            fr["camera"].attrs["height"] = camera.height
        f.attrs["n_frames"] = n + 1  # the commit
        f.flush()
        self._since_xdmf += 1
        if self._since_xdmf >= self.xdmf_every:
            self.write_xdmf()

    def write_xdmf(self) -> Path:
        """Rewrite the XDMF sidecar for the frames committed so far."""
        self._f.flush()
        self._since_xdmf = 0
        return _write_xdmf(self._f, self.path)

    def close(self) -> None:
        """Write the sidecar and close the file."""
        if getattr(self, "_f", None) is not None and self._f.id.valid:
            self.write_xdmf()
            self._f.close()

    def __enter__(self) -> HistoryWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --------------------------------------------------------------------------- XDMF
def _write_xdmf(f: h5py.File, path: Path) -> Path:
    n = int(f.attrs["n_frames"])
    per = str(f.attrs["per"])
    V, F = f["grid/points"].shape[0], f["grid/triangles"].shape[0]
    nv = V if per == "node" else F
    center = "Node" if per == "node" else "Cell"
    h5 = escape(path.name)
    times = f["frames/time"][:n]
    lines = [
        '<?xml version="1.0"?>',
        '<Xdmf Version="3.0" xmlns:xi="http://www.w3.org/2001/XInclude">',
        "<Domain>",
        '<Grid Name="grid" GridType="Uniform">',
        f'<Topology TopologyType="Triangle" NumberOfElements="{F}">',
        f'<DataItem Dimensions="{F} 3" NumberType="Int" Precision="8" Format="HDF">'
        f"{h5}:/grid/triangles</DataItem>",
        "</Topology>",
        '<Geometry GeometryType="XYZ">',
        f'<DataItem Dimensions="{V} 3" NumberType="Float" Precision="8" Format="HDF">'
        f"{h5}:/grid/points</DataItem>",
        "</Geometry>",
        "</Grid>",
        '<Grid Name="history" GridType="Collection" CollectionType="Temporal">',
    ]
    include = ('<xi:include xpointer="xpointer(//Grid[@Name=&quot;grid&quot;]/*'
               '[self::Topology or self::Geometry])"/>')
    for k in range(n):
        lines += [
            f'<Grid Name={quoteattr(f"frame {k}")} GridType="Uniform">',
            include,
            f'<Time Value="{float(times[k])!r}"/>',
            f'<Attribute Name="value" AttributeType="Scalar" Center="{center}">',
            f'<DataItem Dimensions="{nv}" NumberType="Float" Precision="4" Format="HDF">'
            f"{h5}:/values/{k:06d}</DataItem>",
            "</Attribute>",
            "</Grid>",
        ]
    lines += ["</Grid>", "</Domain>", "</Xdmf>", ""]
    out = xdmf_path(path)
    with atomic_path(out) as tmp:
        Path(tmp).write_text("\n".join(lines), encoding="utf-8")
    return out


def write_xdmf(path: str | os.PathLike) -> Path:
    """(Re)write the XDMF sidecar of a history file from the file alone (e.g. after an
    interrupted run). Returns the sidecar's path."""
    p = Path(path)
    with _open(p) as f:
        return _write_xdmf(f, p)


# --------------------------------------------------------------------------- reading
def _open(p: Path) -> h5py.File:
    if not p.is_file():
        raise InputError(f"{p}: time history not found")
    try:
        f = h5py.File(p, "r")
    except OSError as exc:
        raise InputError(f"{p}: not a readable HDF5 file ({exc})") from None
    if f.attrs.get("format") != FORMAT:
        f.close()
        raise InputError(f"{p}: not a {FORMAT} file")
    return f


@dataclass(frozen=True)
class History:
    """A time history read back (:func:`read_history`).

    Attributes
    ----------
    points : (V, 3) float64
    triangles : (F, 3) int64
    per : {"node", "face"}
    times : (T,) float64
        Seconds.
    index : (T,) int64
        Source frame numbers.
    cameras : list of Camera or None
        Each frame's camera (None where none was recorded).
    values : (T, N) float32
        Every frame's values (NaN unseen); (T, len(items)) when read for some items.
    """

    points: np.ndarray
    triangles: np.ndarray
    per: str
    times: np.ndarray
    index: np.ndarray
    cameras: list
    values: np.ndarray

    @property
    def n_frames(self) -> int:
        return len(self.times)


def read_history(path: str | os.PathLike, *, frames=None, items=None) -> History:
    """Read a time history (the committed frames of a finished or interrupted run).

    Parameters
    ----------
    path : path-like
    frames : slice or array_like of int, optional
        Which frames to load (default all; the values of a long run can be large).
    items : array_like of int, optional
        Which nodes (or faces) to load: ``values`` is then (T, len(items)), the time
        history of those points (default all).
    """
    p = Path(path)
    with _open(p) as f:
        n = int(f.attrs["n_frames"])
        sel = np.arange(n)[frames] if frames is not None else np.arange(n)
        sel = np.atleast_1d(sel)
        fr = f["frames"]
        cam = {k: fr["camera"][k][:n] for k in _CAM}
        width = fr["camera"].attrs.get("width")
        height = fr["camera"].attrs.get("height")
        cameras = []
        for k in sel:
            if width is None or not np.all(np.isfinite(cam["K"][k])):
                cameras.append(None)
            else:
                cameras.append(Camera(int(width), int(height), cam["K"][k], cam["dist"][k],
                                      cam["R"][k], cam["t"][k]))
        nv = f["grid/points"].shape[0] if f.attrs["per"] == "node" \
            else f["grid/triangles"].shape[0]
        if items is None:
            values = np.empty((len(sel), nv), dtype=np.float32)
            for i, k in enumerate(sel):
                values[i] = f["values"][f"{k:06d}"][()]
        else:
            it = np.asarray(items, dtype=np.int64).ravel()
            if it.size and (it.min() < 0 or it.max() >= nv):
                raise InputError(f"items: indices must be in [0, {nv}) for this history")
            order, inverse = np.unique(it, return_inverse=True)  # h5py wants them sorted
            values = np.empty((len(sel), it.size), dtype=np.float32)
            for i, k in enumerate(sel):
                values[i] = f["values"][f"{k:06d}"][order][inverse]
        return History(f["grid/points"][()], f["grid/triangles"][()], str(f.attrs["per"]),
                       fr["time"][:n][sel], fr["index"][:n][sel], cameras, values)
