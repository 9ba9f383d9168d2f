"""``selfillum unsteady --uncertainty mc``: the frames' random error by Monte Carlo through
Phase 1 (:func:`chain_noise`), the GUM S1 way on what a frame's dCp is made of.

What is perturbed. ``K`` frames spread over the run (:data:`CHAIN_FRAMES`), each drawn
``S`` times (``--samples``, at most :data:`MAX_CHAIN_SAMPLES`): every pixel of every
camera gets a draw of the camera's noise (``N(0, I / g + (r / g)^2)`` with the stated or
the wind-off frames' gain and read noise; without either, a relative noise per pixel set
so that a node's noise is the run's white floor, ``sigma / (G 144 / q) sqrt(n_px)``). The
drawn frames then go through Phase 1 exactly as the run's own
(:func:`selfillum.unsteady.phase1.map_run` with the run's options): the registration
onto frame 0 fitted again on the noisy frame (``first-frame``), or the frame's tracked
pose drawn from its covariance (``track``, with ``--u marker=`` and the targets: the
resection's least squares, :func:`selfillum.uncertainty.registration.pose_covariance`; in
frames of their own, the pixels held: each source alone);
the dark spots patched or left out; the cameras merged with frame 0's gains; the
self-illumination removed with the run's form factors, its hidden faces continued. The
drawn node intensity ``I + dI`` then enters Phase 2 linearised (``dCp = (I' - fit) G 144 /
q`` with ``I' = mean(I) / I``: ``d dCp = -G 144 / q dI / I``, the mean and the detrend of
``T`` frames moving by ``O(1 / T)`` of it).

The perturbations are drawn about the measured frames (the frames already hold one
realisation of the noise): the spread of the drawn results about the unperturbed one is
the chain's response to the noise, including what the registration and the mapping make
of it. Frame 0, the reference (its map, gains, registration template and the
self-illumination's full solve), is held: its error is common to every frame (a part of
the gain's systematic error, not of a frame's random one).
"""

from __future__ import annotations

import numpy as np

__all__ = ["chain_noise", "CHAIN_FRAMES", "MAX_CHAIN_SAMPLES"]

#: Frames drawn (spread over the run).
CHAIN_FRAMES = 8
#: Draws of each frame at most (the cost: ``CHAIN_FRAMES`` x draws frames of Phase 1).
MAX_CHAIN_SAMPLES = 50


class _DrawnFrames:
    """A camera's video with virtual frames ``T + s K + j``: frame ``real[j]`` plus draw
    ``s`` of the pixel noise."""

    def __init__(self, frames, T: int, real, noise, seed: int, camera: int,
                 draws: int | None = None):
        self.frames, self.T, self.real = frames, T, list(real)
        self.noise, self.seed, self.camera = noise, seed, camera
        self.draws = draws  # draws from this one on: the frame as it is (poses alone)

    @property
    def shape(self):
        return self.frames.shape

    def __getitem__(self, v):
        v = int(v)
        if v < self.T:
            return self.frames[v]
        s, j = divmod(v - self.T, len(self.real))
        img = np.asarray(self.frames[self.real[j]], np.float64)
        if self.draws is not None and s >= self.draws:
            return img
        rng = np.random.default_rng((self.seed, self.camera, s, j))
        return img + self.noise(img) * rng.standard_normal(img.shape)


class _DrawnPoses:
    """A camera's tracked poses with virtual frames drawn from the pose covariance."""

    def __init__(self, poses, T: int, real, cov, seed: int, camera: int, draws: int = 0):
        self.poses, self.T, self.real, self.cov = poses, T, list(real), cov
        self.seed, self.camera = seed, camera
        self.draws = draws  # draws before this one: the pose as tracked (pixels alone)

    def __len__(self):
        return len(self.poses)

    def __getitem__(self, v):
        v = int(v)
        if v < self.T:
            return self.poses[v]
        from selfillum.uncertainty.registration import perturbed

        s, j = divmod(v - self.T, len(self.real))
        cam = self.poses[self.real[j]]
        if self.cov is None or s < self.draws:
            return cam
        rng = np.random.default_rng((self.seed, self.camera, s, j, 1))
        return perturbed(cam, rng.multivariate_normal(np.zeros(6), self.cov))


def chain_noise(cfg, grid, runs, chain: dict, T: int, gf, sigma, npx, camera_noise,
                samples: int) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """Per node the standard deviation of a frame's dCp from the drawn frames (see the
    module notes), that of the drawn poses alone (None when none is drawn), and what was
    drawn. The pixels' noise and the poses are drawn in separate frames (each source
    alone: ``S`` draws of the pixels with the tracked poses, then ``S`` of the poses with
    the measured pixels).

    Parameters
    ----------
    chain : dict
        The run's Phase 1 inputs: ``spots``, ``unpainted``, ``F``, ``rho`` (``F`` None:
        no self-illumination removal).
    gf : (N,) ``G 144 / q`` per node.
    sigma, npx : (N,)
        The linear method's noise per node and effective pixels (the relative pixel noise
        without a camera model).
    camera_noise : (gain, read_noise) or None
    """
    from dataclasses import replace

    from selfillum.unsteady.phase1 import SelfIllumination, map_run

    K = max(1, min(CHAIN_FRAMES, T - 1))
    real = np.unique(np.linspace(1, T - 1, K).round().astype(int)) if T > 1 else np.array([0])
    K = len(real)
    S = int(max(2, min(samples, MAX_CHAIN_SAMPLES)))
    seed = int(cfg.seed)
    if camera_noise is not None:
        g, r = camera_noise

        def noise(img):
            return np.sqrt(np.maximum(img, 0.0) / g + (r / g) ** 2)
        how = f"camera noise (gain {g:.4g} e-/count, read noise {r:.3g} e-)"
        rel_px = None
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            rel = np.asarray(sigma) / np.asarray(gf) * np.sqrt(np.asarray(npx))
        rel_px = float(np.nanmedian(rel[np.isfinite(rel)])) if np.isfinite(rel).any() else 0.0

        def noise(img):
            return rel_px * np.abs(img)
        how = f"relative pixel noise {rel_px:.3g} (the run's white floor)"
    stated = cfg.stated
    covs = [None] * len(runs)
    if (cfg.registration == "track" and stated is not None and stated.marker is not None
            and cfg.targets is not None):
        from resection.io.markers import read_markers
        from selfillum.uncertainty.registration import pose_covariance

        xyz = read_markers(cfg.targets).xyz
        covs = [pose_covariance(r.camera, xyz, stated.marker, str(cfg.targets))
                for r in runs]
    posed = any(c is not None for c in covs)
    drawn = []
    for c, r_ in enumerate(runs):  # cameras
        poses = None if r_.poses is None else _DrawnPoses(r_.poses, T, real, covs[c], seed, c,
                                                          draws=S)
        drawn.append(replace(r_, frames=_DrawnFrames(r_.frames, T, real, noise, seed, c,
                                                     draws=S if posed else None),
                             poses=poses))
    si = None
    if chain.get("F") is not None:
        si = SelfIllumination(grid.mesh, chain["F"], chain["rho"], chain.get("unpainted"))
    virtual = [T + s * K + j for s in range(2 * S if posed else S) for j in range(K)]
    order = [0, *real.tolist(), *virtual]
    base = {}
    acc, cnt = np.zeros((2, grid.n_nodes)), np.zeros((2, grid.n_nodes))
    for fn in map_run(grid, drawn, order, spots=chain.get("spots"),
                      registration=cfg.registration, patcher=cfg.target_patcher,
                      overlap=cfg.overlap, filter=cfg.filter, filter_size=cfg.filter_size,
                      max_obliqueness=cfg.oblique_angle, si=si,
                      unpainted=chain.get("unpainted"), fast=cfg.fast, plan_frames=order):
        k = int(fn.index)
        v = np.asarray(fn.values, np.float64)
        if k < T:
            base[k] = v
            continue
        s, j = divmod(k - T, K)
        I0 = base[int(real[j])]
        with np.errstate(invalid="ignore", divide="ignore"):
            e = -np.asarray(gf) * (v - I0) / I0
        fin = np.isfinite(e)
        part = int(s >= S)  # 0: the pixels drawn, 1: the poses
        acc[part] += np.where(fin, e * e, 0.0)
        cnt[part] += fin
    with np.errstate(invalid="ignore", divide="ignore"):
        out, out_pose = np.sqrt(acc / cnt)
    info = {"frames": int(K), "draws": int(S), "pixels": how,
            "poses": "drawn from the covariance" if covs[0] is not None else
            ("refitted on the noisy frames" if cfg.registration == "first-frame" else "held"),
            "relative_pixel_noise": rel_px}
    return out, (out_pose if posed else None), info
