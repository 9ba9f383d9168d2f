"""``selfillum thermal`` end to end as a user runs it (issue 37 item 6: 50 frames/s on 2
cores for 640 x 512 16-bit IR frames onto a 100k-node grid, moving model), the whole
command in a fresh process against two bare floors in the same run: the read of every
frame, and Phase 1's per-frame work done by bare library calls.

Folded from ``bench/bench_thermal.py``; its inputs at ``WTO_BENCH_SIZE=issue`` are the
paper's run, as the script measured it with ``--frames 500 --q-max 15000`` (100,000
nodes, 500 frames of 640 x 512: 10 s at 50 images/s, 16 rays a face, a largest heat flux
of 1.5e4 W/m^2, which keeps 500 frames within the 16-bit range, 2 cores). The process's
start-up (about 1 s of imports) and set-up are in the figure: on 200 frames the same
machine made 37-45 frames/s where 500 frames made 61-69::

    WTO_BENCH_SIZE=issue .venv/bin/asv run --python=same --quick -b ThermalCommandVsFloor
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ._peers import bench_size, run_command
from .bench_io import cache_dir

#: ``make_ir_run``'s size, the command's rays and cores, at each ``WTO_BENCH_SIZE``.
THERMAL = {"small": dict(nodes=20_000, frames=50, width=640, height=512, rays=16,
                         q_max=3.0e4, threads=2),
           "issue": dict(nodes=100_000, frames=500, width=640, height=512, rays=16,
                         q_max=1.5e4, threads=2)}


def ir_scene(size: str) -> Path:
    """The folder of the synthetic IR run of :mod:`scenes.ir_run` at ``size`` (the
    launcher top as a Plot3D grid, uint16 frames at 50 frames/s, markers that appear, 8 px
    settling then vibration, Fresnel emissivity), written once."""
    from scenes.ir_run import make_ir_run

    s = THERMAL[size]
    folder = cache_dir(f"thermal_{size}_{s['frames']}")
    if not (folder / "run.wtd").is_file():  # the last file make_ir_run writes
        nphi = int(round(np.sqrt(s["nodes"] / 1.6)))
        nx = int(round(s["nodes"] / (nphi + 1)))
        make_ir_run(folder, frames=s["frames"], width=s["width"], height=s["height"],
                    nx=nx, nphi=nphi, q_max=s["q_max"])
    return folder


#: the floor of Phase 1's per-frame work: every frame read, carried by ``cv2.remap``
#: (bilinear, a sub-pixel shift of the whole frame) and taken to the nodes by one SciPy
#: sparse product with about as many entries as the run's pixel-to-node operator (3 for
#: each of the 24 % of the pixels that see the model in this scene)
_FLOOR = ("import sys, numpy as np, scipy.sparse as sp, cv2; "
          "from resection.io.video import open_frames; "
          "s = open_frames(sys.argv[1]); n = int(sys.argv[2]); H, W = s.shape; "
          "rng = np.random.default_rng(0); "
          "px = rng.choice(H * W, min(H * W, int(0.24 * H * W)), replace=False); "
          "M = sp.csr_matrix((rng.random(3 * px.size), (rng.integers(0, n, 3 * px.size), "
          "np.repeat(px, 3))), shape=(n, H * W)); "
          "mx, my = np.meshgrid(np.arange(W, dtype=np.float32) + 0.3, "
          "np.arange(H, dtype=np.float32) + 0.2); "
          "import time; t = time.perf_counter(); "
          "[M @ cv2.remap(s.native(k).astype(np.float32), mx, my, "
          "cv2.INTER_LINEAR).ravel() for k in range(len(s))]; "
          "print(time.perf_counter() - t)")
#: the bare read of every frame through the package's reader (the I/O floor)
_READ = ("import sys, time; from resection.io.video import open_frames; "
         "s = open_frames(sys.argv[1]); t = time.perf_counter(); "
         "[s.native(k).sum() for k in range(len(s))]; print(time.perf_counter() - t)")


def _loop_seconds(code: str, args: list[str], cores: int, env: dict) -> float:
    """The seconds a fresh process pinned to ``cores`` CPUs spends in ``code``'s loop over
    the frames (what it prints: its start-up, imports and set-up left out, as in the
    script this was folded from)."""
    import os
    import subprocess

    from ._peers import ROOT

    cpus = ",".join(map(str, sorted(os.sched_getaffinity(0))[:cores]))
    done = subprocess.run(["taskset", "-c", cpus, sys.executable, "-c", code, *args],
                          capture_output=True, text=True, check=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT), **env})
    return float(done.stdout.strip().splitlines()[-1])


class ThermalCommandVsFloor:
    """``selfillum thermal --grid --targets --video --calibration --radiometry --substrate
    --sds --fps 50 --rays 16 --no-plots`` (its own tracking of the markers, the view
    factors, Cook-Felderman) on the IR run of ``ir_scene`` (``THERMAL``: 20,000 nodes and
    50 frames at ``small``; 100,000 nodes and 500 frames of 640 x 512 at ``issue``), the
    whole command in a fresh process pinned to 2 cores (``taskset``), against a fresh
    process on the same cores doing Phase 1's per-frame work by bare library calls
    (``_FLOOR``: read, ``cv2.remap``, one sparse product a frame; its loop over the frames
    timed, as the script did). Tracked beside: the
    command's frames/s over the whole process (target 50), and its time over the bare read
    of every frame (``_READ``: the I/O floor)."""

    timeout = 3600
    number = 1
    repeat = (1, 2, 600.0)
    params = [bench_size()]
    param_names = ["size"]

    def setup(self, size):
        self.s = THERMAL[size]
        self.folder = ir_scene(size)
        self.out = cache_dir("thermal_out") / "thermal.h5"
        t = str(self.s["threads"])
        self.env = {"OMP_NUM_THREADS": t, "NUMBA_NUM_THREADS": t, "OPENBLAS_NUM_THREADS": t}

    def _command(self):
        f = self.folder
        for p in self.out.parent.glob("thermal*"):
            if p.is_file():
                p.unlink()
        cmd = [sys.executable, "-m", "selfillum.cli", "thermal", "--grid",
               str(f / "model.grid"), "--targets", str(f / "model.tgts"), "--video",
               str(f / "ir.npy"), "--calibration", str(f / "cam01.json"), "--radiometry",
               str(f / "R.json"), "--substrate", str(f / "S.json"), "--sds",
               str(f / "run.wtd"), "--fps", "50.0", "--out", str(self.out), "--rays",
               str(self.s["rays"]), "--no-plots", "--quiet"]
        return run_command(cmd, cores=self.s["threads"], env=self.env)

    def _floor(self):
        return _loop_seconds(_FLOOR, [str(self.folder / "ir.npy"), str(self.s["nodes"])],
                             self.s["threads"], self.env)

    def _read(self):
        return _loop_seconds(_READ, [str(self.folder / "ir.npy")], self.s["threads"],
                             self.env)

    def _ratio(self, peer):
        """Best of 2 of the command's wall time over best of 2 of ``peer``'s loop, the
        two in turn."""
        ours = theirs = float("inf")
        for _ in range(2):
            ours = min(ours, self._command()[0])
            theirs = min(theirs, peer())
        return ours / theirs

    def time_command(self, size):
        self._command()

    def time_floor(self, size):
        self._floor()

    def time_read_frames(self, size):
        self._read()

    def track_ratio_to_floor(self, size):
        return self._ratio(self._floor)

    track_ratio_to_floor.unit = "command / bare remap and product"

    def track_frames_per_s(self, size):
        return self.s["frames"] / self._command()[0]

    track_frames_per_s.unit = "frames/s"

    def track_times_read(self, size):
        return self._ratio(self._read)

    track_times_read.unit = "command / bare read"


class EmissivityPixelsVsNode:
    """The emissivity a node's value carries when taken at each pixel's view angle on the
    map (the area-weighted mean over the seen faces around the node of the emissivity at
    each face's view angle: the pixels on a face see it along nearly one line of sight)
    against the emissivity at the node's own view angle (its area-weighted normal), at
    frame 0's pose, on the grid of ``ir_scene`` (issue 37 item 2). Tracked: the relative
    difference's 95th percentile over the nodes seen under 60 degrees and at 60-70 (the
    run's cut-off), and the time of the pixels' way over the node's.

    Folded from ``bench/bench_thermal_view_angle.py``."""

    timeout = 1800
    params = [bench_size()]
    param_names = ["size"]

    def setup(self, size):
        import scipy.sparse as sp

        from resection.io.cameras import read_camera
        from selfillum.thermal.balance import NodeGeometry
        from selfillum.thermal.radiometry import read_radiometry
        from selfillum.unsteady.grid import load_run_grid

        d = ir_scene(size)
        self.grid = load_run_grid(d / "model.grid")
        cam = read_camera(d / "cam01.json")
        self.eps = read_radiometry(d / "R.json").emissivity
        geom = NodeGeometry.from_grid(self.grid)
        self.centre = -cam.R.T @ np.asarray(cam.t, float)
        mesh = self.grid.mesh
        self.faces = np.asarray(mesh.faces)
        self.fn, self.fc = np.asarray(mesh.face_normals), np.asarray(mesh.triangles_center)
        self.area = np.asarray(mesh.area_faces)
        self.points, self.normals = geom.points, geom.normals
        self.nv = len(mesh.vertices)
        self._sp = sp
        self.angle = np.degrees(np.arccos(np.clip(self._cosine(self.points, self.normals),
                                                  0.0, 1.0)))

    def _cosine(self, p, n):
        v = self.centre - p
        return np.abs(np.einsum("ij,ij->i", n, v)) / np.linalg.norm(v, axis=1)

    def _pixels(self):
        cf = self._cosine(self.fc, self.fn)
        seen = ((np.einsum("ij,ij->i", self.fn, self.centre - self.fc) > 0)
                & (cf > np.cos(np.radians(70.0))))
        nf = len(self.faces)
        W = self._sp.csr_matrix((np.repeat(self.area * seen, 3),
                                 (self.faces.ravel(), np.repeat(np.arange(nf), 3))),
                                shape=(self.nv, nf))
        with np.errstate(invalid="ignore", divide="ignore"):
            per = (W @ self.eps.of_cosine(cf)) / np.asarray(W.sum(axis=1)).ravel()
        return self.grid.to_nodes(per[None, :])[0]

    def _node(self):
        return self.eps.of_cosine(self._cosine(self.points, self.normals))

    def _p95(self, lo, hi):
        a, b = self._pixels(), self._node()
        sel = np.isfinite(a) & (self.angle >= lo) & (self.angle < hi)
        return float(np.percentile(np.abs(a - b)[sel] / b[sel], 95))

    def time_pixels(self, size):
        self._pixels()

    def time_node(self, size):
        self._node()

    def track_ratio_to_node(self, size):
        from ._peers import ratio_of_best

        return ratio_of_best(self._pixels, self._node)

    track_ratio_to_node.unit = "pixels' emissivity / node's"

    def track_p95_under_60(self, size):
        return self._p95(0.0, 60.0)

    track_p95_under_60.unit = "relative difference"

    def track_p95_60_to_70(self, size):
        return self._p95(60.0, 70.0)

    track_p95_60_to_70.unit = "relative difference"
