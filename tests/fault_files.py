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


def isolated(script_argv: list) -> list:
    """The command line that runs ``python -c SCRIPT ARGS...`` where the script can mount a
    file system of its own (a small or read-only tmpfs): in a new user and mount namespace
    (``unshare -rm``) when the system allows it, with ``mount`` as the script's last
    argument; else as it is, with ``nomount`` (the script then fills or locks its folder
    another way: a file-size limit, a folder without write permission; the latter holds
    for a user other than root only, as root can unshare on the systems seen so far)."""
    import subprocess
    import sys

    ok = subprocess.run(["unshare", "-rm", "true"], capture_output=True).returncode == 0 \
        if _has("unshare") else False
    base = [sys.executable, "-c", *map(str, script_argv)]
    return ["unshare", "-rm", *base, "mount"] if ok else [*base, "nomount"]


def _has(program: str) -> bool:
    import shutil

    return shutil.which(program) is not None
