"""A synthetic unsteady PSP run with a known dCp: a painted plate and a painted block on it,
filmed by a high-speed camera while the model vibrates.

The truth, per grid node and frame (``t`` seconds):

* on the plate: ``dCp = A_tone sin(2 pi f_tone t) + A_wave sin(2 pi (f_wave t - x / lam))``
  (a tone everywhere and a wave convected along +x);
* on the block (painted too): ``dCp = A_block sin(2 pi f_block t)``, its own tone, which
  reaches the plate only as light reflected from the block (self-illumination);
* steady Cp ``-0.3 + 0.4 x`` and the tunnel's ``q``, ``PS``, ``T0``, ``MACH``.

The paint follows uPSP's Phase 2 model exactly: with the gain ``G`` of each face (the paint
calibration at its steady pressure and the recovery temperature) and ``p = dCp q / 144``
(psi), the emission is ``E = E0(x) drift(t) / (1 + p / G)`` (so that ``I' - fit`` times
``G`` gives ``p`` back to second order), ``drift`` a slow photo-degradation of the paint
(-1 % over the run). The radiosity ``B = (I - rho F)^-1 E`` is computed with view factors
of 4096 rays a face and another seed than the run uses. Each frame is rendered through the
camera's pose in that frame (the model pitches and heaves a little), targets, taps and
Kulites darkened where their disks lie on the surface, and Gaussian noise added.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from resection.camera import Camera

__all__ = ["UnsteadyRun", "make_unsteady_run", "PAINT", "CONDITIONS"]

#: Paint calibration a..f (uPSP's gain file).
PAINT = {"a": 1.5, "b": 0.002, "c": 1e-6, "d": 1e-4, "e": 1e-7, "f": 0.0}
#: .wtd conditions (Q and PS in psf, TTF in deg F).
CONDITIONS = {"MACH": 0.8, "ALPHA": 2.0, "PTOT": 2300.0, "TTF": 100.0, "PS": 1500.0,
              "Q": 600.0}


@dataclass(frozen=True)
class UnsteadyRun:
    """Paths of the run's files and its truth.

    Attributes
    ----------
    folder : Path
    deck, grid, wtd, paint, steady, targets, video, calibration : Path
    fps : float
    truth : (T, N) float64
        dCp per frame and grid node (file order); NaN at nodes shared by plate and block.
    plate, block : (N,) bool
        Nodes of the plate top and of the block (not the seam).
    near : (N,) bool
        Plate-top nodes within ``near_distance`` of the block's footprint, on the sides
        the camera sees.
    around : (N,) bool
        Plate-top nodes within 0.025 (about an inch) of the block's footprint, on every
        side: also beside the block's sides that camera 1 does not see (or sees beyond the
        70-degree obliqueness cut-off), which light them with the block's tone.
    freqs : dict
        ``tone``, ``wave``, ``block``, ``vibration`` (Hz); ``amps``: the dCp amplitudes.
    poses : (C, T, 4, 3)
        Each camera's true pose in each frame: ``R`` (rows 0-2) and ``t`` (row 3).
    """

    folder: Path
    deck: Path
    grid: Path
    wtd: Path
    paint: Path
    steady: Path
    targets: Path
    video: Path
    calibration: Path
    fps: float
    truth: np.ndarray
    plate: np.ndarray
    block: np.ndarray
    near: np.ndarray
    freqs: dict
    amps: dict
    poses: np.ndarray
    around: np.ndarray | None = None


def _camera(width, height, second: bool = False, index: int | None = None) -> Camera:
    """Camera 1 from the (-x, -y) side, camera 2 from the (+x, +y) side, cameras 3 and 4
    from (-x, +y) and (+x, -y) (``index`` 0-3; ``second`` is index 1)."""
    f = 1.0 * width
    K = [[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]]
    i = (1 if second else 0) if index is None else int(index)
    sx, sy = [(-1, -1), (1, 1), (-1, 1), (1, -1)][i]
    eye = [0.22 * sx if i != 1 else 0.24, 0.24 * sy if i != 1 else 0.22, 0.33]
    target = [-0.03 * sx, -0.02 * sy, 0.0] if i != 1 else [-0.03, -0.02, 0.0]
    return Camera.look_at(eye, target, [0.0, 0.0, 1.0], K=K, width=width, height=height)


def _in_spots(points, spots, radii) -> np.ndarray:
    """(n,) bool: points within ``radii`` of a spot centre (a loop over the few spots)."""
    dark = np.zeros(len(points), bool)
    for c, r in zip(spots, radii, strict=True):  # the spots, a few dozen
        dark |= np.einsum("ij,ij->i", points - c, points - c) <= r * r
    return dark


def _pitch(theta, heave):
    c, s = np.cos(theta), np.sin(theta)
    M = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return M, np.array([0.0, 0.0, heave])


#: the block's half sizes in x and y and its height (m)
BOX = (0.04, 0.03, 0.04)


def plate_targets(cams, box=BOX, margin: float = 12.0) -> np.ndarray:
    """The points of a 9 cm lattice on the plate in view of one of ``cams`` (``margin``
    px inside the image) and 5 cm clear of the block."""
    gx, gy = np.meshgrid(np.arange(-0.24, 0.34, 0.09), np.arange(-0.2, 0.25, 0.09))
    cand = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    ok = np.zeros(len(cand), bool)
    for c in cams:  # in view of a camera
        uv, v = c.project(cand, return_valid=True)
        ok |= v & c.in_image(np.where(v[:, None], uv, 0.0), margin=margin)
    ok &= np.maximum(np.abs(cand[:, 0]) - box[0], np.abs(cand[:, 1]) - box[1]) > 0.05
    return cand[ok]


def write_node_function(path, grid, values) -> None:
    """Write one value a node of ``grid`` (its file order) as a Plot3D function file,
    one block a grid block (``i`` fastest)."""
    from resection.io.plot3d import write_plot3d_function

    blocks, a = [], 0
    for d in grid.dims:  # a few blocks
        n = int(np.prod(d))
        blocks.append(values[a:a + n].reshape(d, order="F"))
        a += n
    write_plot3d_function(path, blocks)


def make_unsteady_run(folder: str | os.PathLike, *, faces: int = 2500, frames: int = 100,
                      fps: float = 1000.0, width: int = 200, height: int = 150,
                      noise: float = 0.003, vibration_deg: float = 0.5, texture: float = 0.08,
                      cameras: int = 1, stern_volmer=None, seed: int = 0,
                      options: dict | None = None, freqs: dict | None = None,
                      heave_m: float = 0.003, drift_deg: float = 0.0, bits: int | None = None,
                      video_format: str = "npy", truth_rays: int = 4096,
                      cameras0=None, targets=None, amplitude: float = 1.0,
                      pixel_noise: tuple | None = None,
                      wind_off_frames: int = 0, smooth: bool = False) -> UnsteadyRun:
    """Write a run into ``folder`` (created) and return its paths and truth; ``cameras``
    1 to 4 (the second from the opposite side, seeing the block's other sides; the third
    and fourth from the other two diagonals).

    The deck's ``@options`` are uPSP's usual ones (``target_patcher = polynomial``,
    ``registration = pixel``, ``overlap = average_view``, ``oblique_angle = 70``,
    ``number_frames = -1``) updated by ``options``; the ``.wtd`` is laid out as NASA's
    data system writes it (a ``RUN`` line first).

    ``freqs`` overrides the frequencies (Hz) of ``tone``, ``wave``, ``block`` and
    ``vibration``; ``heave_m`` is the heave's amplitude, ``drift_deg`` a pitch drift over the
    run on top of the vibration. ``bits`` quantises the frames to unsigned integers of that
    depth (else float32), ``video_format`` is ``"npy"`` or ``"mraw"`` (a Photron ``.mraw``
    + ``.cih``, 16-bit words, needs ``bits``). ``truth_rays``: rays a face of the truth's
    view factors (a Neumann series replaces the sparse LU above 50,000 faces).

    ``cameras0``: the cameras' poses on the model in the first frame (default: the scene's
    own, one or two); ``targets``: (M, 3) painted targets on the plate (default: the
    points of a 9 cm lattice in view of a camera and clear of the block).

    ``stern_volmer = (A, B, p_ref)`` (p_ref in psf): the paint follows
    ``I_ref / I = A + B p / p_ref`` instead of the paint calibration, and a wind-off image
    per camera at ``p_ref`` is written (``wind_off_camNN.npy``) for the in-situ fit.
    ``amplitude`` scales the three dCp amplitudes (small signals: the errors that grow with
    the signal then stay below the noise).

    ``pixel_noise = (g, r)``: the camera's noise instead of ``noise`` (relative): each
    pixel of ``I`` counts gets ``N(0, I / g + (r / g)^2)`` (``g`` e-/count, ``r`` e-
    read noise: shot and read noise), in the run's frames and the wind-off ones.
    ``wind_off_frames``: the wind-off file is a stack of that many frames (each with its
    own noise), also without ``stern_volmer`` (then at the steady pressure, the emission
    ``E0``): the frames the noise can be measured on.

    ``smooth``: each pixel shows the emission of its own surface point (the dCp field, the
    paint and the gain evaluated there; the reflected light, smooth, interpolated from the
    faces) instead of the faces' values interpolated over the vertices, whose
    piecewise-linear field bends only at the edges: a field that varies within a face as
    the paint's does (for the mapping's error against the field at the node)."""
    from resection.io.cameras import write_camera
    from resection.surface.surface_map import SurfaceMap
    from scenes.slab_block import paint, slab_block, write_slab_block
    from selfillum.solve.radiosity import check_reflectance
    from selfillum.transport.viewfactors import view_factors
    from selfillum.unsteady.conditions import Conditions
    from selfillum.unsteady.grid import load_run_grid

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    deck_options = {"target_patcher": "polynomial", "registration": "pixel",
                    "overlap": "average_view", "filter": "none", "filter_size": 3,
                    "oblique_angle": 70, "number_frames": -1, **(options or {})}
    rng = np.random.default_rng(seed)
    box = BOX
    sc = slab_block(faces, half=(0.35, 0.25), box=box, rho_paint=0.6, rho_box=0.6)
    grid_path = out / "model.grid"
    write_slab_block(sc, grid_path)
    grid = load_run_grid(grid_path)
    mesh = grid.mesh
    nf = len(mesh.faces)
    part = np.asarray(mesh.face_attributes["block"]) - 1  # blocks count from 1 in the file
    on_block = part >= 6
    # ------------------------------------------------------------------ the truth
    freqs = {"tone": 120.0, "wave": 70.0, "block": 200.0, "vibration": 30.0, **(freqs or {})}
    amps = {"tone": 0.03 * amplitude, "wave": 0.02 * amplitude, "block": 0.1 * amplitude,
            "lam": 0.3}
    t = np.arange(frames) / fps

    def dcp(points, is_block, t=t):
        x = points[:, 0]
        plate = (amps["tone"] * np.sin(2 * np.pi * freqs["tone"] * t)[:, None]
                 + amps["wave"] * np.sin(2 * np.pi * (freqs["wave"] * t[:, None]
                                                      - x[None, :] / amps["lam"])))
        blk = np.broadcast_to(amps["block"] * np.sin(2 * np.pi * freqs["block"] * t)[:, None],
                              plate.shape)
        return np.where(is_block[None, :], blk, plate)

    def cp_steady(points):
        return -0.3 + 0.4 * points[:, 0]

    cond = Conditions(CONDITIONS["MACH"], CONDITIONS["Q"], CONDITIONS["PS"], CONDITIONS["TTF"],
                      0.0)
    from selfillum.unsteady.conditions import freestream_temperature

    tinf = float(freestream_temperature(cond.t0, cond.mach))
    Ts = 0.896 * (cond.t0 - tinf) + tinf
    centres = np.asarray(mesh.triangles_center)

    def gain(points):
        pss = cp_steady(points) * cond.q + cond.p_inf
        P = PAINT
        return (P["a"] + P["b"] * Ts + P["c"] * Ts**2
                + (P["d"] + P["e"] * Ts + P["f"] * Ts**2) * pss)

    p_face = dcp(centres, on_block) * cond.q / 144.0  # psi, (T, F)
    drift = 1.0 - 0.01 * (t / t[-1]) + 0.003 * (t / t[-1]) ** 2
    tex = 1.0 + texture * rng.uniform(-1.0, 1.0, nf)  # the paint's texture, per face
    E0 = 1000.0 * paint(centres) * tex

    def emission_at(X, fidx, k):
        """The emission of frame ``k`` (None: wind-off) at surface points ``X`` on faces
        ``fidx``."""
        e0 = 1000.0 * paint(X) * tex[fidx]
        if k is None:
            return e0 if stern_volmer is None else e0 / (stern_volmer[0] + stern_volmer[1])
        pk = dcp(X, on_block[fidx], t[k:k + 1])[0] * cond.q / 144.0
        if stern_volmer is None:
            return e0 * drift[k] / (1.0 + pk / gain(X))
        A_sv, B_sv, p_ref = stern_volmer
        pa = cp_steady(X) * cond.q + cond.p_inf + 144.0 * pk
        return e0 * drift[k] / (A_sv + B_sv * pa / p_ref)

    def render(smap, B_k, E_k, k):
        """The image of radiosity ``B_k`` (emission ``E_k``) per face, frame ``k``."""
        if not smooth:
            return smap.to_image(B_k, background=30.0)
        img = smap.to_image(B_k - E_k, background=30.0).reshape(-1)  # reflected light
        fi = smap.face_index.ravel()
        hit = np.flatnonzero(fi >= 0)
        img[hit] += emission_at(smap.points.reshape(-1, 3)[hit], fi[hit], k)
        return img.reshape(smap.shape)
    if stern_volmer is None:  # uPSP's paint calibration
        E = E0[None, :] * drift[:, None] / (1.0 + p_face / gain(centres)[None, :])
    else:  # I_ref / I = A + B p / p_ref, p = Pss + dCp q (psf)
        A_sv, B_sv, p_ref = stern_volmer
        p_abs = cp_steady(centres)[None, :] * cond.q + cond.p_inf + 144.0 * p_face
        E = E0[None, :] * drift[:, None] / (A_sv + B_sv * p_abs / p_ref)
    rho = check_reflectance(np.full(nf, 0.6), nf)
    F = view_factors(mesh, rays_per_face=truth_rays, seed=12345, progress=False)
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    if nf <= 50_000:
        lu = spla.splu(sp.csc_matrix(sp.identity(nf) - sp.diags(rho) @ F))
        solve = lu.solve
    else:  # B = sum_k (rho F)^k E, to 1e-9 of E
        RF = sp.csr_matrix(sp.diags(rho) @ F, dtype=np.float64)

        def solve(rhs):
            term = np.array(rhs, dtype=np.float64)
            acc = term.copy()
            for _ in range(200):
                term = RF @ term
                acc += term
                if np.abs(term).max() <= 1e-9 * np.abs(acc).max():
                    break
            return acc
    B = solve(np.ascontiguousarray(E.T)).T  # (T, F)
    B_off = None if stern_volmer is None else \
        solve(E0 / (stern_volmer[0] + stern_volmer[1]))  # wind-off: p = p_ref
    if B_off is None and wind_off_frames:
        B_off = solve(E0)
    E0_off = E0 if stern_volmer is None else E0 / (stern_volmer[0] + stern_volmer[1])

    def noisy(img):
        if pixel_noise is None:
            return img * (1.0 + noise * rng.standard_normal(img.shape))
        g, r = pixel_noise
        return img + np.sqrt(np.maximum(img, 0.0) / g + (r / g) ** 2) \
            * rng.standard_normal(img.shape)
    # ------------------------------------------------------------------ targets and spots
    cams0 = list(cameras0) if cameras0 is not None else \
        [_camera(width, height, index=c) for c in range(cameras)]
    cameras = len(cams0)
    if targets is None:
        targets = plate_targets(cams0, box)
    tpts = np.vstack([np.asarray(targets, float).reshape(-1, 3),
                      [[-0.02, -0.015, box[2]], [0.02, 0.015, box[2]]]])
    tdia = np.full(len(tpts), 0.014)
    kul = np.array([[-0.08, -0.05, 0.0], [-0.05, -0.075, 0.0]])
    taps = np.array([[-0.195, -0.065, 0.0], [-0.105, 0.115, 0.0], [0.165, 0.115, 0.0],
                     [0.255, -0.065, 0.0], [-0.105, 0.025, 0.0], [0.075, -0.155, 0.0]])
    rows = ["# synthetic unsteady run", "*Targets"]
    k = 1
    for i, p in enumerate(tpts):
        rows.append(f"{k} {p[0]:.9g} {p[1]:.9g} {p[2]:.9g} 0 0 1 {tdia[i]:.9g} 1 1 1 T{i + 1}")
        k += 1
    rows.append("*Taps")
    for i, p in enumerate(taps):
        rows.append(f"{k} {p[0]:.9g} {p[1]:.9g} {p[2]:.9g} 0 0 1 0.004 1 1 1 CP{i + 1:02d}")
        k += 1
    rows.append("*Virtuals")
    for i, p in enumerate(kul):
        rows.append(f"{k} {p[0]:.9g} {p[1]:.9g} {p[2]:.9g} 0 0 1 0.006 1 1 1 K{i + 1:02d}")
        k += 1
    (out / "model.tgts").write_text("\n".join(rows) + "\n")
    spots = np.vstack([tpts, taps, kul])
    srad = 0.5 * np.concatenate([tdia, np.full(len(taps), 0.004), [0.006, 0.006]])
    # ------------------------------------------------------------------ frames
    theta = (np.radians(vibration_deg) * np.sin(2 * np.pi * freqs["vibration"] * t)
             + np.radians(drift_deg) * t / max(t[-1], 1e-300))
    heave = heave_m * np.sin(2 * np.pi * freqs["vibration"] * t + 0.7)
    if video_format not in ("npy", "mraw") or (video_format == "mraw" and bits is None):
        raise ValueError("video_format 'npy', or 'mraw' with bits")
    from resection.surface.visibility import RayCaster

    caster = RayCaster(mesh)
    poses = np.empty((cameras, frames, 4, 3))
    for c, camc in enumerate(cams0):  # cameras
        video = np.empty((frames, height, width), np.float32 if bits is None else np.uint16)
        for k in range(frames):  # frames (the renderer is vectorised over pixels)
            M, d = _pitch(theta[k], heave[k])
            cam = camc.with_pose(R=camc.R @ M, t=camc.R @ d + camc.t)
            poses[c, k, :3], poses[c, k, 3] = cam.R, cam.t
            smap = SurfaceMap(mesh, cam, max_obliqueness=None, caster=caster)
            img = render(smap, B[k], E[k], k)
            pts = smap.points.reshape(-1, 3)
            hit = np.flatnonzero(np.isfinite(pts[:, 0]))
            flat = img.reshape(-1)
            flat[hit[_in_spots(pts[hit], spots, srad)]] *= 0.12
            img = noisy(flat.reshape(height, width))
            video[k] = img if bits is None else np.clip(np.rint(img), 0, (1 << bits) - 1)
        if video_format == "mraw":
            import pyMRAW

            pyMRAW.save_mraw(video, str(out / f"cam{c + 1:02d}.cih"), bit_depth=16,
                             info_dict={"Record Rate(fps)": float(fps)})
        else:
            np.save(out / f"cam{c + 1:02d}.npy", video)
        if B_off is not None:  # the wind-off image, frame 0's pose, no vibration
            smap = SurfaceMap(mesh, camc, max_obliqueness=None)
            img = render(smap, B_off, E0_off, None).reshape(-1)
            pts = smap.points.reshape(-1, 3)
            hit = np.isfinite(pts[:, 0])
            dist = np.linalg.norm(pts[hit][:, None, :] - spots[None, :, :], axis=2)
            idx = np.flatnonzero(hit)[(dist <= srad[None, :]).any(axis=1)]
            img[idx] = 0.12 * img[idx]
            img = img.reshape(height, width)
            k_off = max(int(wind_off_frames), 1)
            stack = np.stack([noisy(img) for _ in range(k_off)])  # a few frames
            np.save(out / f"wind_off_cam{c + 1:02d}.npy",
                    (stack if wind_off_frames else stack[0]).astype(np.float32))
        write_camera(out / f"cam{c + 1:02d}.json", camc)
    # ------------------------------------------------------------------ other inputs
    ext = "mraw" if video_format == "mraw" else "npy"
    write_node_function(out / "steady.f", grid, cp_steady(grid.points))
    names = list(CONDITIONS)
    (out / "run.wtd").write_text("RUN 1 1\n#  " + "\t".join(names) + "\n"
                                 + "\t".join(repr(CONDITIONS[n]) for n in names) + "\n"
                                 + "# Tap CP\n" + "".join(
                                     f"{k + 1}\t{c:.9g}\n"
                                     for k, c in enumerate(cp_steady(taps))))
    (out / "paint.txt").write_text("".join(f"{k} = {v!r}\n" for k, v in PAINT.items()))
    (out / "run.inp").write_text(
        "@general\n    test = synthetic\n    run = 1\n    sequence = 1\n"
        f"@vars\n    dir = {out}\n"
        "@all\n    sds = $dir/run.wtd\n    grid = $dir/model.grid\n"
        "    targets = $dir/model.tgts\n"
        + "".join(f"@camera\n    number = {c}\n    filename = $dir/cam{c:02d}.{ext}\n"
                  f"    calibration = $dir/cam{c:02d}.json\n" for c in range(1, cameras + 1))
        + "@options\n" + "".join(f"    {k} = {v}\n" for k, v in deck_options.items())
        + "@output\n    dir = $dir\n")
    # ------------------------------------------------------------------ truth per node
    nblock_of_node = np.concatenate([np.full(int(np.prod(d)), b) for b, d in enumerate(grid.dims)])
    vb = np.zeros(len(mesh.vertices), bool)
    vp = np.zeros(len(mesh.vertices), bool)
    vb[np.asarray(mesh.faces)[on_block].ravel()] = True
    vp[np.asarray(mesh.faces)[part == 0].ravel()] = True
    seam = grid.to_nodes(vb & vp)
    is_block = (nblock_of_node >= 6) & ~seam
    plate = (nblock_of_node == 0) & ~seam
    truth = dcp(grid.points, is_block)
    truth[:, seam] = np.nan
    x, y = grid.points[:, 0], grid.points[:, 1]
    gap = np.maximum(np.abs(x) - box[0], np.abs(y) - box[1])
    near = plate & (gap < 0.06) & ((x < -box[0]) | (y < -box[1]))
    around = plate & (gap < 0.025)
    return UnsteadyRun(out, out / "run.inp", grid_path, out / "run.wtd", out / "paint.txt",
                       out / "steady.f", out / "model.tgts", out / f"cam01.{ext}",
                       out / "cam01.json", fps, truth, plate, is_block, near, freqs, amps,
                       poses, around)
