"""A synthetic IR run where the model's parts light each other: a slab with a block on it
(:mod:`scenes.slab_block`), both of one grey material of emissivity ``eps``, heated by a
known heat flux and filmed by a fixed IR camera from above.

The truth: ``q = q0(x, z) (1 - exp(-t / tau))`` with ``q0`` rising along ``x`` and up the
block (twice at its top), on a semi-infinite substrate; the surface temperature is its
closed form (:func:`scenes.ir_run.truth_temperature`). What leaves each face is its
radiosity ``J = eps U(T) + (1 - eps) (F J + f_wall U(T_wall))`` (``f_wall = 1 - sum_j
F_ij``, the walls at ``T_wall``), solved by a sparse LU with view factors of 4,096 rays a
face and another seed than a run uses; the camera sees ``J`` of the face under each pixel
(the surface is diffuse: the emissivity is the same in every direction), in FLIR's Planck
form with 16-bit counts and Gaussian noise. Faces near the block's foot see the block's
hotter sides: there the model's own radiation is a large part of the signal.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["IRBlockRun", "make_ir_block_run"]


@dataclass(frozen=True)
class IRBlockRun:
    """Paths and truth: ``q``, ``T`` (T, N) at the grid nodes; ``q0`` (N,); ``plate`` (N,)
    nodes on the slab's top away from the block's edges; ``near`` (N,) those of them
    within 4 cm of the block; ``cos0`` (N,) the cosine of the camera's view angle."""

    folder: Path
    grid: Path
    video: Path
    calibration: Path
    radiometry: Path
    substrate: Path
    fps: float
    q: np.ndarray
    T: np.ndarray
    q0: np.ndarray
    plate: np.ndarray
    near: np.ndarray
    cos0: np.ndarray


def make_ir_block_run(folder: str | os.PathLike, *, faces: int = 2500, frames: int = 30,
                      fps: float = 50.0, width: int = 320, height: int = 240,
                      eps: float = 0.6, q_max: float = 2.0e4, tau: float = 0.1,
                      noise: float = 1.0, seed: int = 0) -> IRBlockRun:
    """Write the run into ``folder`` (created) and return its paths and truth."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from resection.io.cameras import write_camera
    from resection.surface.surface_map import SurfaceMap
    from scenes.ir_run import PLANCK, SUBSTRATE, truth_temperature
    from scenes.slab_block import slab_block, slab_camera, write_slab_block
    from selfillum.transport.viewfactors import view_factors
    from selfillum.unsteady.grid import load_run_grid

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    a, b, c, d, h = 0.35, 0.25, 0.04, 0.03, 0.04
    sc = slab_block(faces, half=(a, b), box=(c, d, h))
    grid_path = out / "model.grid"
    write_slab_block(sc, grid_path)
    grid = load_run_grid(grid_path)
    mesh = grid.mesh
    e = float(np.sqrt(SUBSTRATE["rho"] * SUBSTRATE["c"] * SUBSTRATE["k"]))
    T_i = T_wall = 295.0
    times = np.arange(frames) / fps

    def q0_at(p):
        return q_max * (0.5 + 0.5 * (p[:, 0] + a) / (2 * a)) * \
            (1.0 + np.clip(p[:, 2], 0.0, None) / h)

    R, B, F_, O = PLANCK["R"], PLANCK["B"], PLANCK["F"], PLANCK["O"]

    def U(T):
        return R / (np.exp(B / T) - F_)

    Tf, _ = truth_temperature(q0_at(np.asarray(mesh.triangles_center)), times, e, tau, T_i)
    F = view_factors(mesh, rays_per_face=4096, seed=12345, progress=False)
    nf = len(mesh.faces)
    rho = 1.0 - eps
    wall = np.clip(1.0 - np.asarray(F.sum(axis=1)).ravel(), 0.0, 1.0)
    lu = spla.splu(sp.csc_matrix(sp.identity(nf) - rho * F))
    Uw = U(T_wall)
    J = lu.solve(np.ascontiguousarray((eps * U(Tf) + rho * wall[None, :] * Uw).T)).T
    cam = slab_camera(width, height, zoom=1.0)
    smap = SurfaceMap(mesh, cam, max_obliqueness=None)
    video = np.empty((frames, height, width), np.uint16)
    for k in range(frames):  # the renderer is vectorised over pixels
        img = smap.to_image(J[k], background=Uw) + O
        img = img + noise * rng.standard_normal(img.shape)
        video[k] = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
    np.save(out / "ir.npy", video)
    write_camera(out / "cam01.json", cam)
    (out / "R.json").write_text(json.dumps({**PLANCK, "emissivity": eps,
                                            "reflected_temperature": T_wall}))
    (out / "S.json").write_text(json.dumps(SUBSTRATE))
    pn = grid.points
    Tn, qn = truth_temperature(q0_at(pn), times, e, tau, T_i)
    x, y, z = pn.T
    gap = np.maximum(np.abs(x) - c, np.abs(y) - d)
    plate = (np.abs(z) < 1e-9) & (gap > 0.01) & (np.abs(x) < a - 0.01) & \
        (np.abs(y) < b - 0.01)
    near = plate & (gap < 0.04)
    v = cam.center[None, :] - pn
    cos0 = v[:, 2] / np.linalg.norm(v, axis=1)  # the slab's top faces +z
    return IRBlockRun(out, grid_path, out / "ir.npy", out / "cam01.json", out / "R.json",
                      out / "S.json", fps, qn, Tn, q0_at(pn), plate, near, cos0)
