"""Whole commands as a user runs them, each in a fresh process (start-up, imports, reading
and writing included), against a bare peer in the same run; the serial share of their
2-core time (Amdahl, from the same command pinned to 1 and to 2 cores); and ``track`` in
one process against the same pipeline built from OpenCV parts."""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from ._peers import best_times, run_command, serial_share
from .bench_io import cache_dir

#: uPSP's grid size: ``selfillum correct`` is measured at the size users run
CORRECT_FACES = 609_000


class SelfillumCorrectCommand:
    """``selfillum correct --mesh --camera --image --reflectance 0.5 --unpainted --out`` on
    the slab and block of ``scenes.slab_block`` (609,000 faces requested: 610,704; one
    1280 x 1024 camera; files written once: PLY, camera JSON, image NPY) in a fresh
    process, against a bare one-thread Embree pass of 256 cosine rays from every face in
    this process (its scene build and ``run``; target: the command at most 1.5 times it).
    Tracked beside: the command's serial share of its 2-core time (target 20 %) and its
    peak resident memory."""

    timeout = 1800
    number = 1
    repeat = (1, 3, 600.0)

    def setup(self):
        from ._scenes import slab_files

        self.files, self.mesh = slab_files(CORRECT_FACES, cache_dir(f"slab_{CORRECT_FACES}"))
        self.out = cache_dir("correct_out") / "corrected.npy"

    def _cmd(self):
        f = self.files
        return [sys.executable, "-m", "selfillum.cli", "correct", "--mesh", f["mesh"],
                "--camera", f["camera"], "--image", f["image"], "--reflectance", "0.5",
                "--unpainted", f["unpainted"], "--quiet", "--out", str(self.out)]

    def _bare(self):
        from ._scenes import bare_embree

        return bare_embree(self.mesh)

    def time_command(self):
        run_command(self._cmd())

    def time_bare_embree(self):
        self._bare()

    def track_ratio_to_bare_embree(self):
        ours = peer = float("inf")
        for _ in range(2):  # interleaved: peer, ours, peer
            peer = min(peer, self._bare())
            ours = min(ours, run_command(self._cmd())[0])
        return ours / min(peer, self._bare())

    track_ratio_to_bare_embree.unit = "command / bare Embree"

    def track_serial_share(self):
        t = {1: float("inf"), 2: float("inf")}
        for _ in range(2):
            for cores in (1, 2):
                t[cores] = min(t[cores], run_command(self._cmd(), cores=cores)[0])
        return serial_share(t[1], t[2])

    track_serial_share.unit = "share of the 2-core time"

    def track_peak_memory(self):
        return run_command(self._cmd())[1]

    track_peak_memory.unit = "MiB"


OPENCV_RUNNER = """
import sys, json, numpy as np
from benchmarks._scenes import opencv_pipeline
from resection.io.cameras import read_camera
from resection.io.markers import read_markers
args = json.load(open(sys.argv[1]))
cam = read_camera(args["camera"]); ms = read_markers(args["markers"])
rv, tv, uv = opencv_pipeline(args["frames"], cam, ms.ids, ms.xyz, np.array(args["rvec0"]),
                             np.array(args["tvec0"]), 5.0, step=10)
np.save(args["out"], np.hstack([rv, tv]))
"""

PERIOD = 200  # frames of one period of the body of revolution's motion


def revolution_files():
    """The 200 frames of ``scenes.revolution`` (1280 x 800 8-bit, speckle, glare,
    vibration, 36 targets all around), its camera, markers and the link of frame 0,
    written once."""
    from scipy.spatial import cKDTree

    from resection.io.images import read_image
    from resection.markers import detect_markers
    from scenes.revolution import revolution_model, write_sequence

    cache = cache_dir("revolution")
    model = revolution_model(PERIOD)
    done = cache / "done.json"
    if not done.is_file():
        write_sequence(model, cache)
        done.write_text("{}")
    cands = detect_markers(read_image(cache / "frame_00000.npy", mask_saturated=True), 5.0)
    vis = model.visible(0)
    d, j = cKDTree(cands.uv).query(model.uv(0)[vis])
    with open(cache / "link.csv", "w", encoding="utf-8") as fh:
        fh.write("id,candidate\n")
        for k, i, e in zip(model.ids[vis], j, d, strict=True):
            if e < 1.0:
                fh.write(f"{k},{i}\n")
    return model, cache, {"frames": [str(cache / f"frame_{k:05d}.npy") for k in range(PERIOD)],
                          "camera": str(cache / "camera.json"),
                          "markers": str(cache / "markers.csv"), "link": str(cache / "link.csv")}


class TrackCommandVsOpenCV:
    """``resection track`` of 200 frames of the body of revolution (``--link`` of frame 0,
    its own choice of workers) in a fresh process, against the OpenCV-parts pipeline
    (``SimpleBlobDetector``, nearest neighbour within 5 px of the markers projected with
    the previous pose, ``solvePnP`` from it; seeded with the exact frame-0 pose) in a fresh
    process too, imports included. Tracked beside: the serial share of the command's
    2-core time (target 20 %), its peak resident memory, and the largest attitude error of
    ``track`` against the known motion (degrees)."""

    timeout = 1800
    number = 1
    repeat = (1, 3, 600.0)

    def setup(self):
        self.model, cache, f = revolution_files()
        self.out = cache / "out"
        self.track_cmd = [sys.executable, "-m", "resection.cli", "track", *f["frames"],
                          "--camera", f["camera"], "--markers", f["markers"], "--link",
                          f["link"], "--diameter", "5", "--out", str(self.out),
                          "--no-progress", "--no-resume"]
        cam0 = self.model.camera_at(0)
        args = cache / "cv.json"
        args.write_text(json.dumps({"camera": f["camera"], "markers": f["markers"],
                                    "frames": f["frames"], "rvec0": cam0.rvec.tolist(),
                                    "tvec0": np.asarray(cam0.t).tolist(),
                                    "out": str(cache / "cv.npy")}))
        self.cv_cmd = [sys.executable, "-c", OPENCV_RUNNER, str(args)]

    def time_track_command(self):
        run_command(self.track_cmd)

    def time_opencv_pipeline(self):
        run_command(self.cv_cmd)

    def track_ratio_to_opencv(self):
        ours = peer = float("inf")
        for _ in range(2):
            ours = min(ours, run_command(self.track_cmd)[0])
            peer = min(peer, run_command(self.cv_cmd)[0])
        return ours / peer

    track_ratio_to_opencv.unit = "track / OpenCV parts"

    def track_serial_share(self):
        t = {1: float("inf"), 2: float("inf")}
        for _ in range(2):
            for cores in (1, 2):
                t[cores] = min(t[cores], run_command(self.track_cmd, cores=cores)[0])
        return serial_share(t[1], t[2])

    track_serial_share.unit = "share of the 2-core time"

    def track_peak_memory(self):
        return run_command(self.track_cmd)[1]

    track_peak_memory.unit = "MiB"

    def track_attitude_error(self):
        from resection.sequence import read_track

        run_command(self.track_cmd)
        res = read_track(self.out)
        truth = np.degrees(self.model.angles[np.arange(PERIOD)])
        return float(np.abs(res.angles - (truth - truth[0])).max())

    track_attitude_error.unit = "deg"


class TrackInProcessVsOpenCV:
    """``resection.sequence.track`` in this process (one worker, frame 0 linked by hand)
    on 40 frames of 1024 x 1024 of ``scenes.moving_model.pitch_oscillation`` (34 markers
    of about 4 px, pitch of 2 degrees at 1 Hz), against the same job from OpenCV parts
    frame after frame. Tracked beside: the largest attitude error of each (degrees)."""

    timeout = 900
    number = 1

    def setup(self):
        from scipy.spatial import cKDTree

        from resection.io.cameras import read_camera
        from resection.io.images import read_image
        from resection.markers.detect import detect_markers
        from resection.sequence import relative_motion, track
        from scenes.moving_model import pitch_oscillation, write_sequence

        n, size = 40, 1024
        self.model = pitch_oscillation(n, shape=(size, size), marker_diameter=3.8 / size)
        self.diameter = float(np.median(self.model.diameters_px(0)))
        self.dir = cache_dir("pitch_1024")
        done = self.dir / "done.json"
        if not done.is_file():
            (self.dir / "files.json").write_text(json.dumps(
                write_sequence(self.model, self.dir / "frames"), default=str))
            done.write_text("{}")
        files = json.loads((self.dir / "files.json").read_text())
        self.cam, self.frames, self.markers = (read_camera(files["camera"]), files["frames"],
                                               files["markers"])
        cands = detect_markers(read_image(self.frames[0], mask_saturated=True), self.diameter)
        dist, near = cKDTree(cands.uv).query(self.model.uv(0))
        self.link = {str(k): int(j) for k, j, e in zip(self.model.ids, near, dist, strict=True)
                     if e < 1.0}
        self.track, self.relative_motion = track, relative_motion
        self.truth = np.degrees(self.model.angles)

    def _track(self):
        return self.track(self.frames, self.cam, self.markers, diameter=self.diameter,
                          out_dir=self.dir / f"o{time.perf_counter_ns()}", workers=1,
                          progress=False, chunk_size=50, link=self.link)

    def _opencv(self):
        from ._scenes import opencv_pipeline

        cam0 = self.model.camera_at(0)
        return opencv_pipeline(self.frames, self.cam, self.model.ids, self.model.points3d,
                               cam0.rvec, np.asarray(cam0.t), self.diameter)

    def time_track(self):
        self._track()

    def time_opencv_pipeline(self):
        self._opencv()

    def track_ratio_to_opencv(self):
        a, b = best_times(self._track, self._opencv, repeat=2)
        return a / b

    track_ratio_to_opencv.unit = "track / OpenCV parts"

    def track_attitude_error(self):
        return float(np.nanmax(np.abs(self._track().angles - self.truth)))

    track_attitude_error.unit = "deg"

    def track_opencv_attitude_error(self):
        rv, tv, _ = self._opencv()
        return float(np.nanmax(np.abs(self.relative_motion(rv, tv, 0)[0] - self.truth)))

    track_opencv_attitude_error.unit = "deg"


