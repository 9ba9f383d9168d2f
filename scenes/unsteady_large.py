"""A large unsteady run made cheaply, for speed and memory at scale (the asv benchmark
``bench_unsteady.UnsteadyCasesVsRead``, the whole command's memory test): the slab-and-block
model as a Plot3D grid of about ``nodes`` nodes, one ``width`` x ``height`` 12-bit camera (a
uint16 NPY stack of ``frames`` frames: the model rendered once, a 120 Hz tone of 1 % in its
light and 0.5 % noise), the ``.wtd``, the paint calibration, the steady Cp and a ``resection
track`` folder of the true poses of a vibrating model (``vibration_deg`` pitch and a 0.6 mm
heave per 0.1 degree at 30 Hz). Unlike :func:`scenes.unsteady_run.make_unsteady_run` no frame
is rendered with its own pose or self-illumination: the frames are for throughput and memory,
not for accuracy."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["make_large_run"]


def make_large_run(folder: Path, nodes: int, frames: int, width: int, height: int,
                   fps: float = 2000.0, seed: int = 0, vibration_deg: float = 0.1) -> dict:
    """Write the run's files into ``folder`` (see the module notes); returns ``nodes``,
    ``faces``, ``fps`` and ``vibration_px`` (the largest move of a point in the image)."""
    from resection.io.cameras import write_camera
    from resection.surface.surface_map import SurfaceMap
    from scenes.slab_block import paint, slab_block, write_slab_block
    from scenes.unsteady_run import CONDITIONS, PAINT, _camera, _pitch, write_node_function
    from selfillum.unsteady.grid import load_run_grid

    rng = np.random.default_rng(seed)
    sc = slab_block(2 * nodes, half=(0.35, 0.25), box=(0.04, 0.03, 0.04), rho_paint=0.6,
                    rho_box=0.6)
    write_slab_block(sc, folder / "model.grid")
    grid = load_run_grid(folder / "model.grid")
    cam = _camera(width, height)
    write_camera(folder / "cam01.json", cam)
    centres = np.asarray(grid.mesh.triangles_center)
    base = SurfaceMap(grid.mesh, cam, max_obliqueness=None).to_image(
        1500.0 * paint(centres), background=30.0).astype(np.float32)
    video = np.lib.format.open_memmap(folder / "cam01.npy", "w+", np.uint16,
                                      (frames, height, width))
    t = np.arange(frames) / fps
    for k in range(frames):  # generation, not timed
        img = base * (1.0 + 0.01 * np.sin(2 * np.pi * 120.0 * t[k]))
        img *= 1.0 + 0.005 * rng.standard_normal(img.shape, dtype=np.float32)
        video[k] = np.clip(np.rint(img), 0, 4095).astype(np.uint16)
    video.flush()
    del video
    # the moving model's poses, as a track folder
    from scipy.spatial.transform import Rotation

    from resection.sequence.results import MARKER_COLUMNS, POSE_COLUMNS

    theta = np.radians(vibration_deg) * np.sin(2 * np.pi * 30.0 * t)
    heave = 0.0006 * vibration_deg / 0.1 * np.sin(2 * np.pi * 30.0 * t + 0.7)
    tr = folder / "track1"
    tr.mkdir(exist_ok=True)
    rows = [",".join(POSE_COLUMNS)]
    for k in range(frames):
        M, d = _pitch(theta[k], heave[k])
        c = cam.with_pose(R=cam.R @ M, t=cam.R @ d + cam.t)
        rv = Rotation.from_matrix(c.R).as_rotvec()
        rows.append(",".join([str(k), f"f{k}", "ok", "", "0", "0", "0", "0", "0", "0", "0.1",
                              "20", *(repr(float(v)) for v in rv),
                              *(repr(float(v)) for v in c.t)]))
    (tr / "poses.csv").write_text("\n".join(rows) + "\n")
    X = grid.points[::max(1, grid.n_nodes // 5000)]
    uv0 = cam.project(X)
    amp = max(float(np.nanmax(np.abs(cam.with_pose(R=cam.R @ _pitch(a, b)[0],
                                                   t=cam.R @ _pitch(a, b)[1] + cam.t)
                                     .project(X) - uv0)))
              for a, b in zip(theta[:200], heave[:200], strict=True))
    (tr / "markers.csv").write_text(",".join(MARKER_COLUMNS) + "\n")
    # the rest of the inputs
    write_node_function(folder / "steady.f", grid, -0.3 + 0.4 * grid.points[:, 0])
    names = list(CONDITIONS)
    (folder / "run.wtd").write_text("# " + "\t".join(names) + "\n"
                                    + "\t".join(repr(CONDITIONS[n]) for n in names) + "\n")
    (folder / "paint.txt").write_text("".join(f"{k} = {v!r}\n" for k, v in PAINT.items()))
    return {"nodes": grid.n_nodes, "faces": len(grid.mesh.faces), "fps": fps,
            "vibration_px": amp}
