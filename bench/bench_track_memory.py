"""Memory of ``resection.sequence.track`` over a long run (issue 13 item 4).

A 256 x 256 sequence of ``scenes.moving_model.pitch_oscillation`` is periodic over 100
frames (pitch at 1 Hz, roll at 0.5 Hz, 50 frames/s): its 100 frames are rendered once and
their files listed again and again, in order, to make a continuous run of ``--frames``
frames (default 10,000). ``track`` runs in this process (``workers=1``) while a thread
samples the process' resident memory (RSS, ``psutil``) every 0.2 s together with the number
of frames finished (their files in ``out/frames``).

It prints the RSS when 10 %, 25 %, 50 %, 75 % and 100 % of the frames are finished, the
peak, and the size of the returned ``TrackResult`` (its arrays: the poses and every
matched marker of every frame, the output itself). Flat memory means: the RSS between
10 % and 100 % grows by no more than the result's own arrays.

Run: ``.venv/bin/python bench/bench_track_memory.py [--frames 10000]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from resection.io.cameras import read_camera


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--chunk-size", type=int, default=50)
    args = ap.parse_args()

    import psutil

    from resection.sequence import track
    from scenes.moving_model import pitch_oscillation, write_sequence

    proc = psutil.Process()
    period = 100
    model = pitch_oscillation(period)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        files = write_sequence(model, tmp / "frames")
        cam = read_camera(files["camera"])
        frames = [files["frames"][k % period] for k in range(args.frames)]
        out = tmp / "out"
        samples = []  # (seconds, frames finished, rss bytes)
        stop = threading.Event()
        t0 = time.perf_counter()

        def sample():
            while not stop.is_set():
                try:
                    n = sum(1 for _ in os.scandir(out / "frames"))
                except OSError:
                    n = 0
                samples.append((time.perf_counter() - t0, n, proc.memory_info().rss))
                stop.wait(0.2)

        rss0 = proc.memory_info().rss
        th = threading.Thread(target=sample, daemon=True)
        th.start()
        res = track(frames, cam, files["markers"], diameter=5.6, out_dir=out, workers=1,
                    progress=False, chunk_size=args.chunk_size)
        stop.set()
        th.join()
        dt = time.perf_counter() - t0
    truth = np.degrees(model.angles[np.arange(args.frames) % period])
    err = np.nanmax(np.abs(res.angles - truth))
    nbytes = sum(getattr(res, f).nbytes for f in ("frame", "file", "status", "reason", "angles",
                                                   "translation", "rms", "n_markers", "rvec",
                                                   "tvec", "marker_frame", "marker_id",
                                                   "marker_uv", "marker_residual"))
    print(f"{args.frames} frames 256x256, {len(model.ids)} markers, chunks of "
          f"{args.chunk_size}: {args.frames / dt:.1f} frames/s, {int(res.ok.sum())} solved, "
          f"max attitude error {err:.4f} deg")
    print(f"RSS before the run: {rss0 / 2**20:.1f} MiB")
    s = np.array(samples, float)
    for q in (0.10, 0.25, 0.50, 0.75, 1.0):
        k = np.flatnonzero(s[:, 1] >= q * args.frames)
        if k.size:
            print(f"  {100 * q:5.0f} % of the frames finished: RSS {s[k[0], 2] / 2**20:7.1f} MiB "
                  f"(t = {s[k[0], 0]:.1f} s)")
    print(f"peak RSS during the run: {s[:, 2].max() / 2**20:.1f} MiB; after: "
          f"{proc.memory_info().rss / 2**20:.1f} MiB")
    print(f"TrackResult arrays: {nbytes / 2**20:.1f} MiB "
          f"({nbytes / args.frames / 1024:.2f} KiB a frame)")


if __name__ == "__main__":
    main()
