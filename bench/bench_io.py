"""File formats: readers and writers against the bare library call or a peer, same run.

* Plot3D grid read (binary, multi-block) against the ``plot3d`` package's ``read_plot3D``;
* per-face field write (``.vtu``) through :func:`resection.io.fields.write_fields` against a
  bare ``meshio.write`` of the same mesh and data, and against ``numpy.save`` (the floor);
* frame sequences through :func:`resection.io.video.iter_frames` (float32 frames, checks)
  against the bare readers: ``pyMRAW.load_images`` (memory map) for ``.mraw``, and
  ``cine_reader.Cine.load_frame`` for ``.cine``.

Run: ``.venv/bin/python bench/bench_io.py [--faces N] [--frames N]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _timing import best_of  # noqa: E402

from resection.io.fields import write_fields  # noqa: E402
from resection.io.meshes import plot3d_to_mesh  # noqa: E402
from resection.io.plot3d import read_plot3d, write_plot3d  # noqa: E402
from resection.io.video import iter_frames  # noqa: E402


def grid_blocks(n_points: int):
    side = int(np.sqrt(n_points / 4))
    blocks = []
    for k in range(4):
        x, y = np.meshgrid(np.linspace(0, 1, side) + k, np.linspace(0, 1, side), indexing="ij")
        blocks.append(np.stack([x, y, 0.1 * np.sin(3 * x) * y], -1)[:, :, None, :])
    return blocks


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--faces", type=int, default=300_000)
    ap.add_argument("--frames", type=int, default=200)
    args = ap.parse_args()
    import meshio
    import plot3d
    import pyMRAW
    from cine_reader import Cine
    from test_io_video import _write_cine

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        blocks = grid_blocks(args.faces // 2)
        write_plot3d(tmp / "g.x", blocks, records=False)
        t_ours, _ = best_of(lambda: read_plot3d(tmp / "g.x"))
        t_peer, _ = best_of(lambda: plot3d.read_plot3D(str(tmp / "g.x"), binary=True,
                                                       big_endian=False, read_double=True,
                                                       fortran=False))
        npts = sum(int(np.prod(b.shape[:3])) for b in blocks)
        print(f"Plot3D read, {npts} points: ours {t_ours:.3f} s, plot3d {t_peer:.3f} s, "
              f"ratio ours/plot3d {t_ours / t_peer:.2f}")

        mesh = plot3d_to_mesh(blocks)
        nf = len(mesh.faces)
        vals = np.random.default_rng(0).normal(size=nf)
        t_ours, _ = best_of(lambda: write_fields(tmp / "f.vtu", mesh, {"p": vals},
                                                 include_attributes=False))
        m = meshio.Mesh(np.asarray(mesh.vertices), [("triangle", np.asarray(mesh.faces))],
                        cell_data={"p": [vals]})
        t_bare, _ = best_of(lambda: meshio.write(tmp / "g.vtu", m))
        t_npy, _ = best_of(lambda: np.save(tmp / "f.npy", vals))
        print(f"field write .vtu, {nf} faces: ours {t_ours:.3f} s, bare meshio.write "
              f"{t_bare:.3f} s, ratio {t_ours / t_bare:.2f}; np.save {t_npy:.4f} s")

        n, h, w = args.frames, 512, 640
        frames = np.random.default_rng(1).integers(0, 4095, (n, h, w)).astype(np.uint16)
        mraw, cih = pyMRAW.save_mraw(frames, str(tmp / "run.cih"), bit_depth=16)

        def ours(path):
            total = 0.0
            _, it = iter_frames(path)
            for _, img in it:
                total += float(img[0, 0])
            return total

        def bare_mraw():
            imgs = pyMRAW.load_images(mraw, h, w, n, bit=16, roll_axis=False)
            total = 0.0
            for i in range(n):
                total += float(imgs[i].astype(np.float32)[0, 0])
            return total

        _write_cine(tmp / "run.cine", frames)

        def bare_cine():
            c = Cine(tmp / "run.cine", keep_annotations=False)
            total = 0.0
            for i in range(n):
                c.load_frame(int(c.file_header.FirstImageNo) + i)
                total += float(c.pixel_array[::-1].astype(np.float32)[0, 0])
            c.close_file()
            return total

        for label, path, bare in (("mraw", mraw, bare_mraw), ("cine", tmp / "run.cine",
                                                                bare_cine)):
            t_o = t_b = float("inf")
            for _ in range(3):  # interleaved
                t0 = time.perf_counter()
                ours(path)
                t_o = min(t_o, time.perf_counter() - t0)
                t0 = time.perf_counter()
                bare()
                t_b = min(t_b, time.perf_counter() - t0)
            mb = n * h * w * 2 / 1e6
            print(f".{label} {n} frames {w}x{h} 16-bit ({mb:.0f} MB): iter_frames {t_o:.3f} s "
                  f"({n / t_o:.0f} frames/s), bare reader {t_b:.3f} s, ratio {t_o / t_b:.2f}")


if __name__ == "__main__":
    main()
