"""Time-history writing against the mapping that produces the frames, in the same run.

* **map**: the per-frame map of a moving model on a grid of about 600,000 nodes
  (a 775 x 775 plate, 1.2 M faces) seen by a 1024 x 1024 camera: ``SurfaceMap`` from the
  frame's pose (Embree scene and undistortion map shared) + ``to_nodes``, a few frames;
* **write**: :class:`resection.io.history.HistoryWriter` appending 1,000 frames of 600,625
  float32 node values (each committed and flushed), with the process's resident memory
  sampled every 100 frames (flat: nothing is kept but the frame being written);
* peer: the same bytes appended to one raw file (``write`` + ``flush``), interleaved frame
  by frame with the history (the bare cost of putting the bytes on disk).

Run: ``.venv/bin/python bench/bench_history.py [--frames 1000] [--nodes-side 775]``
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from resection import Camera
from resection.io.history import HistoryWriter, read_history
from resection.sequence.mapping import map_frames


def rss_mb() -> float:
    """Resident memory of this process now, MB (Linux /proc)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def plate(n: int) -> trimesh.Trimesh:
    xs = np.linspace(-0.5, 0.5, n)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return trimesh.Trimesh(V, F, process=False)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--nodes-side", type=int, default=775, help="plate of side^2 nodes")
    ap.add_argument("--map-frames", type=int, default=4)
    ap.add_argument("--dir", default=None, help="folder for the files (default: a temp one)")
    args = ap.parse_args()
    mesh = plate(args.nodes_side)
    nv = len(mesh.vertices)
    K = [[1100.0, 0, 511.5], [0, 1100.0, 511.5], [0, 0, 1]]
    cam = Camera.look_at([0.2, -0.6, 1.1], [0, 0, 0], [0, 1, 0], K=K, width=1024,
                         height=1024, dist=[-0.08, 0.01, 0, 0, 0])
    print(f"grid {nv} nodes / {len(mesh.faces)} faces, image 1024 x 1024, "
          f"{args.frames} frames written")

    # map: one pose per frame (the plate pitching), frames of noise
    rng = np.random.default_rng(0)
    cams = [cam.with_pose(rvec=cam.rvec + [0.002 * k, 0, 0]) for k in range(args.map_frames)]
    imgs = [rng.normal(1000, 10, (1024, 1024)).astype(np.float32)
            for _ in range(args.map_frames)]
    t0 = time.perf_counter()
    stamps = []
    for r in map_frames(mesh, cams, imgs, per="node"):
        seen = r.seen.sum()
        stamps.append(time.perf_counter())
    t_first = stamps[0] - t0
    t_map = float(np.median(np.diff(stamps)))  # steady state: frames after the first
    print(f"[map]   {1 / t_map:7.2f} frames/s ({t_map:.3f} s a frame after the first; the "
          f"first {t_first:.1f} s builds the Embree scene of {len(mesh.faces)} faces and the "
          f"undistortion map; {seen} nodes seen)")

    folder = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="bench_history_"))
    path = folder / "history.h5"
    raw = folder / "peer.bin"
    values = rng.normal(1000, 10, nv).astype(np.float32)
    mem = []
    t_write = t_raw = 0.0
    with HistoryWriter(path, mesh, per="node") as w, open(raw, "wb") as peer:
        for k in range(args.frames):  # interleaved: both see the same disk and load
            values[k % nv] = np.nan
            t0 = time.perf_counter()
            w.append(values, time=k / 50.0, camera=cams[k % len(cams)], index=k)
            t1 = time.perf_counter()
            peer.write(values.tobytes())
            peer.flush()
            t_raw += time.perf_counter() - t1
            t_write += t1 - t0
            if k % 100 == 0:
                mem.append(rss_mb())
    t_write /= args.frames
    t_raw /= args.frames
    mem.append(rss_mb())
    size = path.stat().st_size / 1e9
    print(f"[write] {1 / t_write:7.1f} frames/s ({1e3 * t_write:.1f} ms a frame, "
          f"{size:.2f} GB file) | write / map speed {t_map / t_write:.0f}x")
    print(f"        resident memory every 100 frames, MB: "
          f"{' '.join(f'{m:.0f}' for m in mem)} (growth {mem[-1] - mem[1]:+.0f} MB after "
          "the first 100)")
    print(f"[peer]  the same bytes appended to one raw file (write + flush), interleaved: "
          f"{1 / t_raw:7.1f} frames/s | HistoryWriter / raw time {t_write / t_raw:.2f}")
    back = read_history(path, frames=[args.frames - 1])
    assert np.array_equal(back.values[0], values, equal_nan=True)
    for p in (path, path.with_suffix(".xdmf"), raw):
        p.unlink()
    if not args.dir:
        folder.rmdir()

if __name__ == "__main__":
    main()
