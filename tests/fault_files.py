"""Users' files for the fault tests: a small corner scene written as a user would."""

from __future__ import annotations

import numpy as np

from resection.io.cameras import write_camera


def corner_files(folder, resolution=4, size=(96, 72)):
    """A small corner mesh (PLY), a camera JSON that sees it (facing it), its image and
    per-face values, as a user's files."""
    from resection.surface.plots import virtual_camera
    from scenes.corner import corner

    sc = corner(resolution=resolution)
    sc.mesh.export(folder / "corner.ply")
    cam = virtual_camera(sc.mesh, 225.0, 30.0, width=size[0], height=size[1])
    write_camera(folder / "cam.json", cam)
    img = np.linspace(1.0, 2.0, size[0] * size[1], dtype=np.float32).reshape(size[::-1])
    np.save(folder / "img.npy", img)
    return sc, cam, img
