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
    /frames/source        (T,)   str       what each frame was read from (its file's name and
                                           a digest of its content; "" when not given)
    /inputs               ()     str       JSON: what the frames were computed from
    /values/000000 ...    (N,) float32     frame k's values, one dataset (one chunk) a frame;
                                           N = V (per node) or F (per face); NaN = unseen

Root attributes: ``per`` (``"node"`` or ``"face"``), ``n_frames`` (frames committed).

Frames are written as they finish: the values first, then the frame's time and camera,
then ``n_frames`` is raised and the file flushed. A frame is committed when ``n_frames``
counts it and the file has been flushed; an interrupted run keeps every committed frame,
and :class:`HistoryWriter` with ``resume=True`` drops whatever lies beyond ``n_frames`` and
carries on.

The committed frames survive whatever happens to the writes after them (a full disk, a
read-only remount, ``kill -9``, a crash of the process): the file is written through an
undo journal (:mod:`resection.io.journal`, ``P.h5.journal``) that keeps the bytes of the
committed file before they are overwritten. A failed write rolls the file back to its last
commit at once; a run that died leaves the journal, and the next writer rolls the file back,
while a reader reads the committed state through it without writing. The ``/inputs``
dataset (JSON) records what the frames were computed from (settings, images, camera): a
resumed run with other inputs is refused, as are committed frames whose times or cameras
differ from those of the resumed run. A file whose ``n_frames`` counts frames it does not
hold is refused as damaged. The sidecar carries the mark of this file
(:mod:`resection.io.marks`): an XDMF file of that name that is not ours is never replaced.

One dataset a frame keeps memory flat over the run (nothing is held but the current frame)
and lets the XDMF sidecar point at each frame with a plain HDF5 path (readable by ParaView
and by meshio's XDMF time-series reader). The sidecar (``<file>.xdmf``, written to a
temporary name and renamed) is rewritten when the writer closes and every ``xdmf_every``
frames; :func:`write_xdmf` rebuilds it from the HDF5 file alone.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import h5py
import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.io.journal import JournaledFile, committed_view, discard
from resection.io.marks import claim_side_file, xml_mark
from resection.io.outputs import atomic_path
from resection.io.paths import as_os_error

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
    inputs : dict, optional
        What the frames are computed from (JSON-able: settings, image identities, camera),
        stored in ``/inputs``; a resumed file must record the same.
    opener : callable, optional
        ``opener(path, mode)`` opening the file and its journal (tests inject failing
        writes through it); default :func:`open`.

    Examples
    --------
    >>> with HistoryWriter("p.h5", mesh, per="node") as w:       # doctest: +SKIP
    ...     for k, (img, cam) in enumerate(zip(frames, cameras)):
    ...         w.append(values_of(img, cam), time=k / fps, camera=cam)
    """

    def __init__(self, path, mesh, *, per: str = "node", resume: bool = False,
                 xdmf_every: int = 100, inputs: dict | None = None, opener=open):
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
        claim_side_file(xdmf_path(self.path), self.path, "XDMF sidecar")
        self._inputs = None if inputs is None else json.dumps(inputs, sort_keys=True)
        self._f = self._jf = None
        if not self.path.exists():  # made whole under a temporary name, then renamed
            discard(self.path)  # a journal left by a file of that name that is gone
            try:
                with atomic_path(self.path) as tmp, h5py.File(tmp, "w") as f:
                    self._create(f, points, tris)
            except OSError as exc:  # HDF5's text: the system's errno and message in it
                raise as_os_error(exc, self.path) from None
        try:
            try:
                self._jf = JournaledFile(self.path, opener=opener)
            except BlockingIOError:
                raise InputError(f"{self.path}: another process has this time history "
                                 "open (writing it, or reading it for more than "
                                 "2 s)") from None
            try:
                self._f = h5py.File(self._jf, "r+")
            except OSError as exc:
                if self._jf.failed is not None:
                    raise
                msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                raise InputError(f"{self.path}: not a readable HDF5 file ({msg}); cannot "
                                 "resume it") from None
            self._check_resumable(points, tris)
            self._f.flush()
            self._raise_failed()
            self._jf.commit()
        except BaseException:
            self._abandon()
            raise
        self._since_xdmf = 0

    # ------------------------------------------------------------------ set-up
    def _create(self, f, points, tris) -> None:
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
        fr.create_dataset("source", shape=(0,), maxshape=(None,), dtype=h5py.string_dtype(),
                          chunks=(256,))
        cam = fr.create_group("camera")
        for name, shape in _CAM.items():
            cam.create_dataset(name, shape=(0,) + shape, maxshape=(None,) + shape, dtype="f8",
                               chunks=(256,) + shape)
        f.create_group("values")
        if self._inputs is not None:
            f.create_dataset("inputs", data=self._inputs)

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
        n = _committed(f, self.path)
        if self._inputs is not None:
            old = f["inputs"][()].decode() if "inputs" in f else None
            if old != self._inputs:
                raise InputError(f"{self.path}: {_input_difference(old, self._inputs)}; "
                                 "cannot resume it (write to another file)")
        for name in list(f["values"]):  # a frame begun but not committed
            if int(name) >= n:
                del f["values"][name]
        fr = f["frames"]
        for ds in (fr["time"], fr["index"], *(fr["camera"][k] for k in _CAM)):
            ds.resize(n, axis=0)
        if "source" in fr:
            fr["source"].resize(n, axis=0)

    # ------------------------------------------------------------------ writing
    @property
    def n_frames(self) -> int:
        """Frames committed so far (a resumed file starts with its earlier frames)."""
        return int(self._f.attrs["n_frames"])

    def committed_frames(self) -> dict:
        """``index``, ``time`` and the cameras (``K``, ``dist``, ``R``, ``t``) of the
        committed frames, as arrays."""
        n, fr = self.n_frames, self._f["frames"]
        out = {"index": fr["index"][:n], "time": fr["time"][:n],
               "source": (fr["source"].asstr()[:n] if "source" in fr
                          else np.full(n, None, dtype=object))}
        out.update({k: fr["camera"][k][:n] for k in _CAM})
        return out

    @property
    def done(self) -> np.ndarray:
        """Source frame numbers already committed (to skip when resuming)."""
        return self._f["frames/index"][()]

    def append(self, values, *, time: float, camera: Camera | None = None,
               index: int | None = None, source: str = "") -> None:
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
        source : str, optional
            What the frame was read from (a name and a content digest), compared when the
            file is resumed.
        """
        v = np.asarray(values)
        if v.shape != (self.n_values,):
            raise InputError(f"values: expected ({self.n_values},) per {self.per}, got shape "
                             f"{v.shape}")
        if not np.isfinite(float(time)):
            raise InputError(f"time: must be finite, got {time}")
        try:
            with interrupt_after():  # Ctrl-C waits for the commit (never inside HDF5)
                self._append(v, float(time), camera, index, str(source))
        except BaseException:
            self._abandon()  # the file goes back to its last commit
            self._raise_failed()
            raise
        self._raise_failed()
        self._since_xdmf += 1
        if self._since_xdmf >= self.xdmf_every:
            self.write_xdmf()

    def _append(self, v, time, camera, index, source) -> None:
        n = self.n_frames
        f = self._f
        f["values"].create_dataset(f"{n:06d}", data=v.astype(np.float32, copy=False))
        fr = f["frames"]
        for ds, val in ((fr["time"], float(time)), (fr["index"], n if index is None else index),
                        (fr["source"], source)):
            ds.resize(n + 1, axis=0)
            ds[n] = val
        for name, shape in _CAM.items():
            ds = fr["camera"][name]
            ds.resize(n + 1, axis=0)
            ds[n] = np.full(shape, np.nan) if camera is None else getattr(camera, name)
        if camera is not None:
            fr["camera"].attrs["width"] = camera.width
            fr["camera"].attrs["height"] = camera.height
        f.attrs["n_frames"] = n + 1
        f.flush()
        if self._jf.failed is None:
            self._jf.commit()  # the commit: the file as flushed is what survives

    def _raise_failed(self) -> None:
        """After a write of the file failed (a full disk): roll back, raise its OSError."""
        failed = self._jf.failed if self._jf is not None else None
        if failed is None or isinstance(failed, _Abandoned):
            return
        self._abandon()
        raise OSError(failed.errno, failed.strerror or str(failed), str(self.path))
    def write_xdmf(self) -> Path:
        """Rewrite the XDMF sidecar for the frames committed so far."""
        self._f.flush()
        self._since_xdmf = 0
        return _write_xdmf(self._f, self.path)

    def close(self) -> None:
        """Write the sidecar and close the file."""
        if getattr(self, "_f", None) is None or not self._f.id.valid:
            return
        try:
            self.write_xdmf()
            self._f.close()
            self._raise_failed()
            self._jf.commit()
            self._jf.close()
        except BaseException:
            self._abandon()
            raise

    def _abandon(self) -> None:
        """Close without keeping anything written since the last commit (the file is
        rolled back to it)."""
        jf = getattr(self, "_jf", None)
        if jf is not None and jf.failed is None:
            jf.fail(_Abandoned())  # nothing more reaches the file
        f = getattr(self, "_f", None)
        if f is not None and f.id.valid:
            try:
                f.close()
            except Exception:  # noqa: BLE001 - the writes go nowhere; rolled back below
                pass
        if jf is not None and not jf.closed:
            jf.close()

    def __enter__(self) -> HistoryWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:  # interrupted (Ctrl-C) or failed: keep what is committed, and the sidecar
            self._abandon()
            if self.path.exists():
                with contextlib.suppress(Exception):
                    write_xdmf(self.path)


@contextlib.contextmanager
def interrupt_after():
    """Hold Ctrl-C (SIGINT) while the block runs and raise it when the block is done: a
    KeyboardInterrupt raised inside HDF5's calls into the journaled file could not be
    carried out of them. Only in the main thread (where Python delivers signals)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda *a: caught.append(a))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


class _Abandoned(Exception):
    """The writer was closed without a commit (an error elsewhere, Ctrl-C)."""


def _committed(f: h5py.File, path: Path) -> int:
    """The committed frame count, checked against what the file holds."""
    try:
        n = int(f.attrs["n_frames"])
        fr = f["frames"]
        lengths = [fr["time"].shape[0], fr["index"].shape[0],
                   *(fr["camera"][k].shape[0] for k in _CAM)]
        names = set(f["values"])
    except (KeyError, TypeError, ValueError, OSError):
        raise InputError(f"{path}: damaged time history (its frame tables are "
                         "unreadable)") from None
    missing = [k for k in range(min(n, 10**7)) if f"{k:06d}" not in names][:1]
    if n < 0 or n > min(lengths) or missing:
        raise InputError(f"{path}: damaged time history: n_frames says {n}, but "
                         f"{min(lengths) if n > min(lengths) else missing[0]} frames are "
                         "stored")
    return n


def _input_difference(old: str | None, new: str) -> str:
    if old is None:
        return "records no inputs (written before they were recorded, or not by map)"
    try:
        a, b = json.loads(old), json.loads(new)
        keys = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
    except (ValueError, AttributeError):
        keys = []
    return f"made from other inputs ({', '.join(keys) or 'unreadable record'})"


# --------------------------------------------------------------------------- XDMF
def _write_xdmf(f: h5py.File, path: Path) -> Path:
    n = _committed(f, path)
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
        xml_mark(path, "resection map"),  # ours: replaced by the next writer of `path`
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
    out = claim_side_file(xdmf_path(path), path, "XDMF sidecar")
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
@contextlib.contextmanager
def _open(p: Path):
    """The file opened for reading, as committed: through its journal when a run that
    wrote it stopped (or is still writing), without changing it."""
    if not p.is_file():
        raise InputError(f"{p}: time history not found")
    view = committed_view(p)
    try:
        try:
            f = h5py.File(p if view is None else view, "r")
        except OSError as exc:
            raise InputError(f"{p}: not a readable HDF5 file ({exc})") from None
        with f:
            if f.attrs.get("format") != FORMAT:
                raise InputError(f"{p}: not a {FORMAT} file")
            yield f
    finally:
        if view is not None:
            view.close()


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
        n = _committed(f, p)
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
