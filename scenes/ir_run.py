"""A synthetic infrared run with a known heat flux: the top of a launcher (a cylinder and a
truncated cone) in a supersonic tunnel, filmed by an IR camera, with the traits of the
paper's worked example.

* **Heat flux** (the truth), on a semi-infinite substrate of effusivity ``e``:
  ``q(x, phi, t) = q0(x, phi) (1 - exp(-t / tau))`` (the flow establishing over ``tau``),
  ``q0`` rising towards the nose and on the windward side. The surface temperature is its
  closed form ``T = T_i + q0 2 / (e sqrt(pi)) (sqrt(t) - sqrt(tau) D(sqrt(t / tau)))``
  (``D`` Dawson's integral), independent of the package's heat-flux code.
* **Markers**: plaster-filled holes of lower effusivity (``e / marker_ratio``): they heat
  faster and show as bright spots, starting at no contrast (the model starts at the walls'
  temperature, so at ``t = 0`` the whole model is as bright as its background).
* **Motion**: the model moves 8 px along the image over the first 0.8 s (the flow
  establishing, a smooth S-curve), then vibrates (pitch, yaw and heave, about 0.5 px).
* **Emissivity** falls at grazing angles: a smooth dielectric (Fresnel) of normal
  emissivity ``eps_n``; the camera sees ``eps(theta) U(T) + (1 - eps(theta)) U(T_wall)``
  (:mod:`selfillum.thermal.radiometry`), FLIR's Planck form with the constants of a FLIR
  file (exiftool's sample ``FLIR.jpg``).
* **Frames**: 16-bit counts, Gaussian read noise, a few saturated pixels (a hot reflection
  at the frame's corner), 50 frames/s.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.camera import Camera

__all__ = ["IRRun", "make_ir_run", "PLANCK", "truth_temperature"]

#: FLIR's calibration form S = R / (exp(B / T) - F) + O with a FLIR file's constants
#: (exiftool's sample FLIR.jpg: PlanckR1 13799.269, PlanckR2 0.022241818, PlanckB 1374.5,
#: PlanckF 1.35, PlanckO -6646, i.e. R = R1 / R2 and O = -PlanckO).
PLANCK = {"R": 13799.269 / 0.022241818, "B": 1374.5, "F": 1.35, "O": 6646.0}
#: PEEK-like model material (SI).
SUBSTRATE = {"rho": 1300.0, "c": 1100.0, "k": 0.25}


@dataclass(frozen=True)
class IRRun:
    """Paths and truth of a synthetic IR run.

    ``q`` (T, N) and ``T`` (T, N): the true heat flux (W/m^2) and temperature (K) at the
    grid nodes; ``q0`` (N,); ``cos0`` (N,) the cosine of each node's view angle in frame 0
    (<= 0: facing away); ``near_marker`` (N,) nodes within 2 marker radii of a marker
    centre; ``poses`` (T, 4, 3) the camera's true pose per frame (R rows 0-2, t row 3);
    ``shift_px`` (T,) the model's image displacement of its centre."""

    folder: Path
    grid: Path
    targets: Path
    video: Path
    calibration: Path
    radiometry: Path
    substrate: Path
    wtd: Path
    fps: float
    times: np.ndarray
    q: np.ndarray
    T: np.ndarray
    q0: np.ndarray
    cos0: np.ndarray
    near_marker: np.ndarray
    poses: np.ndarray
    shift_px: np.ndarray
    video2: Path | None = None
    calibration2: Path | None = None


def _radius(x, xc, xe, R0, Re):
    return np.where(x <= xc, R0, R0 - (x - xc) * (R0 - Re) / (xe - xc))


def truth_temperature(q0, t, e, tau, T_i):
    """Closed-form surface temperature (K) of a semi-infinite body of effusivity ``e``
    under ``q0 (1 - exp(-t / tau))`` from ``t = 0``: ``(T, q) (len(t), len(q0))``."""
    from scipy.special import dawsn

    t = np.asarray(t, float)[:, None]
    phi = 2.0 / (e * np.sqrt(np.pi)) * (np.sqrt(t) - np.sqrt(tau) * dawsn(np.sqrt(t / tau)))
    return T_i + q0[None, :] * phi, q0[None, :] * (1.0 - np.exp(-t / tau))


def make_ir_run(folder: str | os.PathLike, *, frames: int = 60, fps: float = 50.0,
                width: int = 320, height: int = 240, nx: int = 61, nphi: int = 48,
                q_max: float = 3.0e4, tau: float = 0.1, eps_n: float = 0.95,
                marker_ratio: float = 2.0, noise: float = 2.0, settle_px: float = 8.0,
                settle_s: float = 0.8, tsp: dict | None = None, second_camera: bool = False,
                seed: int = 0) -> IRRun:
    """Write the run into ``folder`` (created): the Plot3D grid, ``.tgts``, the NPY stack
    (uint16), the camera, ``R.json``, ``S.json``, ``run.wtd``; return its paths and truth.

    ``tsp = {"E_over_R": K}``: a TSP run instead. The paint (a texture of +-10 % on the
    surface, 20,000 counts at ``T_ref = 295 K``) follows the Arrhenius law
    ``I = I_ref exp(E_over_R (1 / T - 1 / T_ref))``, the markers are dark dots (15 % of the
    paint, heating as the model: ``marker_ratio`` 1), ``noise`` counts of read noise; the
    wind-off image ``wind_off.npy`` is the paint at 295 K in the calibration's pose; the
    calibration ``tsp.json`` is written instead of ``R.json`` (``radiometry`` names it).
    """
    from resection.io.cameras import write_camera
    from resection.io.meshes import write_plot3d
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster
    from selfillum.thermal.radiometry import fresnel_emissivity
    from selfillum.unsteady.grid import load_run_grid

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    R0, Re, x0, xc, xe = 0.05, 0.012, -0.22, 0.08, 0.22
    # ------------------------------------------------------------------ grid (outward)
    xs = np.linspace(x0, xe, nx)
    ph = np.linspace(0.0, 2.0 * np.pi, nphi + 1)
    X, P = np.meshgrid(xs, ph, indexing="ij")  # i along x, j around
    r = _radius(X, xc, xe, R0, Re)
    block = np.stack([X, r * np.cos(P), r * np.sin(P)], axis=-1)
    grid_path = out / "model.grid"
    write_plot3d(grid_path, [block])
    grid = load_run_grid(grid_path)
    mesh = grid.mesh
    fn = np.asarray(mesh.face_normals)
    rad_dir = np.asarray(mesh.triangles_center).copy()
    rad_dir[:, 0] = 0.0
    if np.mean(np.einsum("ij,ij->i", fn, rad_dir)) < 0:  # faces point inwards: flip j
        write_plot3d(grid_path, [block[:, ::-1]])
        grid = load_run_grid(grid_path)
        mesh = grid.mesh
    # ------------------------------------------------------------------ camera, motion
    f = 1.1 * width
    K = [[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]]
    cam0 = Camera.look_at([0.0, 0.18, 0.42], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], K=K,
                          width=width, height=height)
    times = np.arange(frames) / fps
    z0 = float(np.linalg.norm(cam0.to_camera_frame(np.zeros((1, 3)))[0]))
    D = settle_px * z0 / f  # model units for settle_px pixels at the model's distance
    s = np.clip(times / settle_s, 0.0, 1.0)
    dx = D * 0.5 * (1.0 - np.cos(np.pi * s))
    after = np.clip(times - settle_s, 0.0, None)
    ramp = np.clip(after / 0.1, 0.0, 1.0)
    pitch = np.radians(0.08) * ramp * np.sin(2 * np.pi * 7.0 * after)
    yaw = np.radians(0.06) * ramp * np.sin(2 * np.pi * 11.0 * after + 0.5)
    heave = 0.2 * z0 / f * ramp * np.sin(2 * np.pi * 9.0 * after + 1.0)
    Rc, tc = cam0.R, cam0.t
    poses = np.empty((frames, 4, 3))
    cams, motion = [], []
    for k in range(frames):  # a pose a frame
        cy, sy = np.cos(yaw[k]), np.sin(yaw[k])
        cp, sp_ = np.cos(pitch[k]), np.sin(pitch[k])
        M = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ \
            np.array([[cp, 0.0, sp_], [0.0, 1.0, 0.0], [-sp_, 0.0, cp]])
        d = np.array([dx[k], heave[k], 0.0])
        cam = cam0.with_pose(R=Rc @ M, t=Rc @ d + tc)
        poses[k, :3], poses[k, 3] = cam.R, cam.t
        cams.append(cam)
        motion.append((M, d))
    shift = np.array([np.linalg.norm(c.project(np.zeros((1, 3)))[0]
                                     - cam0.project(np.zeros((1, 3)))[0]) for c in cams])
    # ------------------------------------------------------------------ markers
    mx = np.linspace(x0 + 0.04, xc + 0.08, 6)
    mph = np.radians([60.0, 90.0, 120.0])
    MX, MP = np.meshgrid(mx, mph, indexing="ij")
    MX = MX + rng.uniform(-0.006, 0.006, MX.shape)
    MP = MP + np.radians(rng.uniform(-6.0, 6.0, MP.shape))
    mr = _radius(MX, xc, xe, R0, Re)
    mpts = np.column_stack([MX.ravel(), (mr * np.cos(MP)).ravel(), (mr * np.sin(MP)).ravel()])
    mdia = 0.008
    rows = ["# synthetic IR run: plaster-filled holes", "*Targets"]
    for i, p in enumerate(mpts):
        nrm = np.array([0.0, p[1], p[2]]) / np.hypot(p[1], p[2])
        rows.append(f"{i + 1} {p[0]:.9g} {p[1]:.9g} {p[2]:.9g} {nrm[0]:.6g} {nrm[1]:.6g} "
                    f"{nrm[2]:.6g} {mdia:.9g} 1 1 1 T{i + 1}")
    (out / "model.tgts").write_text("\n".join(rows) + "\n")
    # ------------------------------------------------------------------ the truth
    e = float(np.sqrt(SUBSTRATE["rho"] * SUBSTRATE["c"] * SUBSTRATE["k"]))
    T_i = T_wall = 295.0

    def q0_at(p):
        x = p[:, 0]
        phi = np.arctan2(p[:, 2], p[:, 1])
        return q_max * (0.55 + 0.45 * (x - x0) / (xe - x0)) * (0.75 + 0.25 * np.sin(phi))

    def slope_normal(p):
        x = p[:, 0]
        rr = np.hypot(p[:, 1], p[:, 2])
        sl = np.where(x <= xc, 0.0, (R0 - Re) / (xe - xc))
        n = np.column_stack([sl, p[:, 1] / rr, p[:, 2] / rr])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    Rr, Bb, Ff, Oo = PLANCK["R"], PLANCK["B"], PLANCK["F"], PLANCK["O"]

    def U(Tk):
        return Rr / (np.exp(Bb / Tk) - Ff)

    n_eps = (2.0 - eps_n + 2.0 * np.sqrt(1.0 - eps_n)) / eps_n
    Uw = U(T_wall)
    if tsp is not None:
        marker_ratio = 1.0

    def texture(p):  # the TSP paint's non-uniformity, fixed on the surface
        return 1.0 + 0.1 * np.sin(40.0 * p[:, 0]) * np.cos(3.0 * np.arctan2(p[:, 2], p[:, 1]))

    def tsp_image(smap, p, hit, Tpix, dist):
        ratio = np.exp(tsp["E_over_R"] * (1.0 / Tpix - 1.0 / T_i))
        sig = np.zeros(height * width)
        sig[hit] = 20000.0 * texture(p) * ratio * np.where(dist <= 0.5 * mdia, 0.15, 1.0)
        return sig.reshape(height, width) + 100.0 + noise * rng.standard_normal((height,
                                                                                 width))
    caster = RayCaster(mesh)
    bases = [cam0]
    if second_camera:  # from the +x side, higher
        bases.append(Camera.look_at([0.16, 0.14, 0.38], [0.02, 0.0, 0.0], [0.0, 1.0, 0.0],
                                    K=K, width=width, height=height))
    for ci, base in enumerate(bases):  # a camera or two
        if ci:
            cams = [base.with_pose(R=base.R @ M, t=base.R @ d + base.t) for M, d in motion]
        video = np.empty((frames, height, width), np.uint16)
        for k in range(frames):  # frames; the renderer is vectorised over pixels
            smap = SurfaceMap(mesh, cams[k], max_obliqueness=None, caster=caster)
            pts = smap.points.reshape(-1, 3)
            hit = np.flatnonzero(np.isfinite(pts[:, 0]))
            p = pts[hit]
            dist = np.linalg.norm(p[:, None, :] - mpts[None, :, :], axis=2).min(axis=1)
            ratio = np.where(dist <= 0.5 * mdia, marker_ratio, 1.0)
            Tt, _ = truth_temperature(q0_at(p), times[k:k + 1], e, tau, T_i)
            Tpix = T_i + (Tt[0] - T_i) * ratio
            if tsp is not None:
                img = tsp_image(smap, p, hit, Tpix, dist)
                img[:3, :3] = 70000.0
                video[k] = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
                continue
            C = -cams[k].R.T @ cams[k].t
            v = C[None, :] - p
            cosv = np.einsum("ij,ij->i", slope_normal(p), v) / np.linalg.norm(v, axis=1)
            eps = fresnel_emissivity(np.arccos(np.clip(cosv, 0.0, 1.0)), n_eps)
            sig = np.full(height * width, Uw)
            sig[hit] = eps * U(Tpix) + (1.0 - eps) * Uw
            img = sig.reshape(height, width) + Oo + noise * rng.standard_normal((height, width))
            img[:3, :3] = 70000.0  # a hot reflection at the corner: saturated
            video[k] = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
        np.save(out / ("ir.npy" if ci == 0 else f"ir{ci + 1}.npy"), video)
        write_camera(out / f"cam{ci + 1:02d}.json", base)
    if tsp is None:
        (out / "R.json").write_text(json.dumps({
            **PLANCK, "emissivity": {"model": "fresnel", "normal": eps_n},
            "reflected_temperature": T_wall, "range_K": [250.0, 500.0]}, indent=1))
    else:
        smap = SurfaceMap(mesh, cam0, max_obliqueness=None, caster=caster)
        pts = smap.points.reshape(-1, 3)
        hit = np.flatnonzero(np.isfinite(pts[:, 0]))
        p = pts[hit]
        dist = np.linalg.norm(p[:, None, :] - mpts[None, :, :], axis=2).min(axis=1)
        off = tsp_image(smap, p, hit, np.full(len(p), T_i), dist)
        np.save(out / "wind_off.npy", np.clip(np.rint(off), 0, 65535).astype(np.uint16))
        (out / "tsp.json").write_text(json.dumps({"model": "arrhenius", "E_over_R":
                                                  tsp["E_over_R"], "T_ref": T_i}))
    (out / "S.json").write_text(json.dumps(SUBSTRATE, indent=1))
    (out / "run.wtd").write_text("# MACH\tQ\tPS\tTTF\n2.0\t1200.0\t300.0\t200.0\n")
    # ------------------------------------------------------------------ truth at nodes
    pn = grid.points
    Tn, qn = truth_temperature(q0_at(pn), times, e, tau, T_i)
    C0 = -cam0.R.T @ cam0.t
    v0 = C0[None, :] - pn
    cos0 = np.einsum("ij,ij->i", slope_normal(pn), v0) / np.linalg.norm(v0, axis=1)
    near = np.linalg.norm(pn[:, None, :] - mpts[None, :, :], axis=2).min(axis=1) < mdia
    return IRRun(out, grid_path, out / "model.tgts", out / "ir.npy", out / "cam01.json",
                 out / ("R.json" if tsp is None else "tsp.json"), out / "S.json",
                 out / "run.wtd", fps, times, qn, Tn, q0_at(pn), cos0, near, poses, shift,
                 out / "ir2.npy" if second_camera else None,
                 out / "cam02.json" if second_camera else None)
