"""File formats, time histories and the unsteady run's outputs against the bare library
call or the format's own reader, and Phase 2's compute against SciPy's Welch."""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ._peers import ROOT, best_times, ratio_of_best


def cache_dir(name: str) -> Path:
    """A folder kept between the benchmarks of one run (files written once)."""
    p = Path(tempfile.gettempdir()) / "wto-asv" / name
    p.mkdir(parents=True, exist_ok=True)
    return p


class Plot3dReadVsPlot3d:
    """A binary multi-block Plot3D grid of 150,000 points read by ``read_plot3d`` against
    the ``plot3d`` package's ``read_plot3D``."""

    timeout = 300

    def setup(self):
        import plot3d

        from resection.io.plot3d import read_plot3d, write_plot3d

        from ._scenes import grid_blocks

        self.path = cache_dir("plot3d") / "g.x"
        write_plot3d(self.path, grid_blocks(150_000), records=False)
        self.read, self.plot3d = read_plot3d, plot3d

    def _peer(self):
        self.plot3d.read_plot3D(str(self.path), binary=True, big_endian=False,
                                read_double=True, fortran=False)

    def time_read_plot3d(self):
        self.read(self.path)

    def time_plot3d_package(self):
        self._peer()

    def track_ratio_to_plot3d(self):
        return ratio_of_best(lambda: self.read(self.path), self._peer)

    track_ratio_to_plot3d.unit = "ours / plot3d"


class VtuWriteVsMeshio:
    """A per-face field written to ``.vtu`` by ``write_fields`` against a bare
    ``meshio.write`` of the same mesh and data (about 300,000 faces)."""

    timeout = 300

    def setup(self):
        import meshio

        from resection.io.fields import write_fields
        from resection.io.meshes import plot3d_to_mesh

        from ._scenes import grid_blocks

        self.mesh = plot3d_to_mesh(grid_blocks(150_000))
        self.vals = np.random.default_rng(0).normal(size=len(self.mesh.faces))
        self.m = meshio.Mesh(np.asarray(self.mesh.vertices),
                             [("triangle", np.asarray(self.mesh.faces))],
                             cell_data={"p": [self.vals]})
        self.dir, self.write_fields, self.meshio = cache_dir("vtu"), write_fields, meshio

    def _ours(self):
        self.write_fields(self.dir / "f.vtu", self.mesh, {"p": self.vals},
                          include_attributes=False)

    def _bare(self):
        self.meshio.write(self.dir / "g.vtu", self.m)

    def time_write_fields(self):
        self._ours()

    def time_meshio_write(self):
        self._bare()

    def track_ratio_to_meshio(self):
        return ratio_of_best(self._ours, self._bare)

    track_ratio_to_meshio.unit = "ours / meshio"


def _frames_16bit():
    return np.random.default_rng(1).integers(0, 4095, (100, 512, 640)).astype(np.uint16)


def _sum_frames(path) -> float:
    from resection.io.video import iter_frames

    total = 0.0
    _, it = iter_frames(path)
    for _, img in it:
        total += float(img[0, 0])
    return total


class MrawFramesVsPyMRAW:
    """100 frames of 640 x 512, 16-bit, from a Photron ``.mraw`` through ``iter_frames``
    (float32 frames, checks) against ``pyMRAW.load_images`` (memory map) frame by frame."""

    timeout = 300

    def setup(self):
        import pyMRAW

        folder = cache_dir("mraw")
        self.mraw, _ = pyMRAW.save_mraw(_frames_16bit(), str(folder / "run.cih"), bit_depth=16)
        self.pyMRAW = pyMRAW

    def _bare(self):
        imgs = self.pyMRAW.load_images(self.mraw, 512, 640, 100, bit=16, roll_axis=False)
        return sum(float(imgs[i].astype(np.float32)[0, 0]) for i in range(100))

    def time_iter_frames(self):
        _sum_frames(self.mraw)

    def time_pymraw(self):
        self._bare()

    def track_ratio_to_pymraw(self):
        return ratio_of_best(lambda: _sum_frames(self.mraw), self._bare)

    track_ratio_to_pymraw.unit = "ours / pyMRAW"


class CineFramesVsCineReader:
    """The same 100 frames from a Phantom ``.cine`` through ``iter_frames`` against
    ``cine_reader.Cine.load_frame`` frame by frame."""

    timeout = 300

    def setup(self):
        sys.path.insert(0, str(ROOT / "tests"))
        try:
            from test_io_video import _write_cine
        finally:
            sys.path.remove(str(ROOT / "tests"))
        from cine_reader import Cine

        self.path = cache_dir("cine") / "run.cine"
        _write_cine(self.path, _frames_16bit())
        self.Cine = Cine

    def _bare(self):
        c = self.Cine(self.path, keep_annotations=False)
        total = 0.0
        for i in range(100):
            c.load_frame(int(c.file_header.FirstImageNo) + i)
            total += float(c.pixel_array[::-1].astype(np.float32)[0, 0])
        c.close_file()
        return total

    def time_iter_frames(self):
        _sum_frames(self.path)

    def time_cine_reader(self):
        self._bare()

    def track_ratio_to_cine_reader(self):
        return ratio_of_best(lambda: _sum_frames(self.path), self._bare)

    track_ratio_to_cine_reader.unit = "ours / cine_reader"


class HistoryAppendVsRawWrite:
    """``HistoryWriter.append`` (each frame committed and flushed, the undo journal kept)
    of 100 frames of 600,625 node values against appending the same bytes to one raw file
    (``write`` + ``flush``), interleaved frame by frame. Tracked beside: the resident
    memory's growth over the frames (MB; flat: nothing is kept but the frame written)."""

    timeout = 600

    def setup(self):
        from resection import Camera
        from resection.io.history import HistoryWriter

        from ._scenes import plate

        self.mesh = plate(775)
        self.cam = Camera.look_at([0.2, -0.6, 1.1], [0, 0, 0], [0, 1, 0],
                                  K=[[1100.0, 0, 511.5], [0, 1100.0, 511.5], [0, 0, 1]],
                                  width=1024, height=1024)
        self.values = np.random.default_rng(0).normal(1000, 10, len(self.mesh.vertices))
        self.values = self.values.astype(np.float32)
        self.dir, self.Writer = cache_dir("history"), HistoryWriter

    def _run(self, frames: int = 100):
        from ._scenes import rss_mb

        path, raw = self.dir / "history.h5", self.dir / "peer.bin"
        for p in (path, path.with_suffix(".xdmf"), raw):
            p.unlink(missing_ok=True)
        t_ours = t_raw = 0.0
        mem = []
        with self.Writer(path, self.mesh, per="node") as w, open(raw, "wb") as peer:
            for k in range(frames):
                t0 = time.perf_counter()
                w.append(self.values, time=k / 50.0, camera=self.cam, index=k)
                t1 = time.perf_counter()
                peer.write(self.values.tobytes())
                peer.flush()
                t_raw += time.perf_counter() - t1
                t_ours += t1 - t0
                if k in (frames // 10, frames - 1):
                    mem.append(rss_mb())
        return t_ours, t_raw, mem[-1] - mem[0]

    def time_history_and_raw_write(self):
        self._run()

    def time_raw_write_alone(self):
        with open(self.dir / "alone.bin", "wb") as fh:
            for _ in range(100):
                fh.write(self.values.tobytes())
                fh.flush()

    def track_ratio_to_raw_write(self):
        t_ours, t_raw, _ = self._run()
        return t_ours / t_raw

    track_ratio_to_raw_write.unit = "HistoryWriter / raw write"

    def track_memory_growth(self):
        return self._run()[2]

    track_memory_growth.unit = "MB"


class GuardedH5VsH5py:
    """The unsteady run's (T, N) float32 dataset written through ``guarded_h5`` (a Python
    file object under HDF5: a full disk is one error, not a crash) against h5py's own file
    driver: 1,000 frames x 20,000 nodes in the run's chunks, by blocks of nodes."""

    timeout = 300

    def setup(self):
        import h5py

        from resection.io.guarded import guarded_h5
        from selfillum.unsteady.output import chunk_shape

        self.data = np.random.default_rng(0).standard_normal((1000, 20_000)).astype(np.float32)
        self.chunks = chunk_shape(*self.data.shape)
        self.block = self.chunks[1] * 4
        self.dir, self.h5py, self.guarded = cache_dir("guarded"), h5py, guarded_h5

    def _fill(self, f):
        ds = f.create_dataset("dcp", self.data.shape, "f4", chunks=self.chunks,
                              fillvalue=np.nan)
        for a in range(0, self.data.shape[1], self.block):
            ds[:, a:a + self.block] = self.data[:, a:a + self.block]

    def _h5py(self):
        p = self.dir / "h5py.h5"
        p.unlink(missing_ok=True)
        with self.h5py.File(p, "w") as f:
            self._fill(f)

    def _ours(self):
        p = self.dir / "guarded.h5"
        p.unlink(missing_ok=True)
        with self.guarded(p) as (f, check):
            self._fill(f)
            check()

    def time_guarded_h5(self):
        self._ours()

    def time_h5py_driver(self):
        self._h5py()

    def track_ratio_to_h5py(self):
        return ratio_of_best(self._ours, self._h5py)

    track_ratio_to_h5py.unit = "guarded / h5py"


class DcpReadVsUpspFiles:
    """The unsteady run's dCp dataset (one chunked HDF5 dataset, the chunks of
    ``chunk_shape``; 1,000 frames x 40,000 nodes) read one frame and one node's whole
    history, warm, against uPSP's two flat files (``pressure``, a row a frame, and
    ``pressure_transpose``, a row a node: twice the storage). Tracked beside: a node's
    history from the same dataset chunked a frame per chunk, over ours."""

    timeout = 600

    def setup(self):
        import h5py

        from selfillum.unsteady.output import chunk_shape, write_flat

        T, N = 1000, 40_000
        self.T, self.N = T, N
        d = cache_dir("dcp")
        self.ours, self.per_frame = d / "ours.h5", d / "per_frame.h5"
        done = d / "done"
        if not done.exists():
            base = np.random.default_rng(0).standard_normal((16, N)).astype(np.float32)
            for path, ch in ((self.ours, chunk_shape(T, N)), (self.per_frame, (1, N))):
                with h5py.File(path, "w") as f:
                    ds = f.create_dataset("dcp", (T, N), "f4", chunks=ch)
                    for a in range(0, T, 16):
                        k = np.arange(a, min(a + 16, T))
                        ds[a:k[-1] + 1] = base[k % 16] + k[:, None].astype(np.float32)
            with h5py.File(self.ours) as f:
                write_flat(f, d / "pressure", d / "pressure_transpose")
            done.write_text("")
        self.fo = h5py.File(self.ours, "r", rdcc_nbytes=0)
        self.fp = h5py.File(self.per_frame, "r", rdcc_nbytes=0)
        self.pr = np.memmap(d / "pressure", "<f4", "r", shape=(T, N))
        self.pt = np.memmap(d / "pressure_transpose", "<f4", "r", shape=(N, T))
        rng = np.random.default_rng(1)
        self.frames, self.nodes = rng.integers(0, T, 5), rng.integers(0, N, 5)

    def teardown(self):
        self.fo.close()
        self.fp.close()

    def _ours(self):
        for k, n in zip(self.frames, self.nodes, strict=True):
            self.fo["dcp"][int(k)]
            self.fo["dcp"][:, int(n)]

    def _upsp(self):
        for k, n in zip(self.frames, self.nodes, strict=True):
            np.array(self.pr[int(k)])
            np.array(self.pt[int(n)])

    def time_ours_frames_and_nodes(self):
        self._ours()

    def time_upsp_flat_files(self):
        self._upsp()

    def track_ratio_to_upsp_files(self):
        return ratio_of_best(self._ours, self._upsp)

    track_ratio_to_upsp_files.unit = "ours / uPSP's files"

    def track_frame_chunks_node_slowdown(self):
        a, b = best_times(lambda: [self.fp["dcp"][:, int(n)] for n in self.nodes],
                          lambda: [self.fo["dcp"][:, int(n)] for n in self.nodes])
        return a / b

    track_frame_chunks_node_slowdown.unit = "frame chunks / ours"


class Phase2VsScipyWelch:
    """Phase 2's compute on a chunk column (2,000 frames x 4,369 nodes of 12-bit-like
    intensities as the work file's uint16 codes): dCp, its statistics and the Welch PSD
    (nperseg 256) with the default threads, against ``scipy.signal.welch`` alone on the
    same dCp block (float64, one call)."""

    timeout = 600

    def setup(self):
        from scipy.signal import welch

        from selfillum.unsteady.phase2 import legendre_basis, phase2_block
        from selfillum.unsteady.spectra import welch_block
        from selfillum.unsteady.work import encode_rows

        T, n = 2000, 4369
        rng = np.random.default_rng(0)
        self.t = np.arange(T)
        self.codes, self.scale = encode_rows(
            (1500 * (1 + 0.01 * rng.standard_normal((T, n)))).astype(np.float32))
        self.g = np.full(n, 0.5)
        self.basis = legendre_basis(self.t)
        self.phase2, self.welch_block, self.welch = phase2_block, welch_block, welch
        self.dcp = self._ours()

    def _ours(self):
        d, _, _, _, share = self.phase2(self.codes, self.t, self.g, 300.0, scale=self.scale,
                                        basis=self.basis, workers=None, return_share=True)
        self.welch_block(d, 2000.0, 256, workers=None, share=share)
        return d

    def _scipy(self):
        self.welch(np.asarray(self.dcp, np.float64), fs=2000.0, nperseg=256, axis=0)

    def time_phase2_block(self):
        self._ours()

    def time_scipy_welch(self):
        self._scipy()

    def track_ratio_to_scipy_welch(self):
        return ratio_of_best(self._ours, self._scipy)

    track_ratio_to_scipy_welch.unit = "ours / SciPy welch"
