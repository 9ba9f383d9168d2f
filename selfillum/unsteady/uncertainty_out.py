"""``selfillum unsteady --uncertainty``: the per-node uncertainty fields written next to
dCp (:func:`write_uncertainty`; the models: :mod:`selfillum.uncertainty.unsteady`).

Written into the output file::

    /dcp_u                      (N,) standard uncertainty of one frame's dCp (random part):
                                the root sum of squares of the next three
    /dcp_u_noise                (N,) its noise part (the run's white floor, the camera's
                                noise model stated or measured on wind-off frames)
    /dcp_u_mapping              (N,) its mapping part: a field varying over the pixels a node
                                averages (:mod:`selfillum.uncertainty.mapping`)
    /dcp_u_registration         (N,) its tracked poses' part (``--registration track`` with
                                ``--u marker=``: each frame's pose covariance times the
                                node's mapped image gradient,
                                :mod:`selfillum.unsteady.uncertainty_images`)
    /dcp_u_gain                 (N,) relative standard uncertainty of the gain (systematic)
    /stats/dcp_rms_signal       (N,) RMS of dCp with the noise's variance removed
    /stats/dcp_rms_signal_u     (N,) its standard uncertainty (random part)
    /psd/noise_floor            (N,) the PSD's level in the highest band (dCp^2/Hz)
    attribute "uncertainty"     JSON: method, each source's status, medians

The noise, in order of preference: the stated camera gain and read noise; the wind-off
frames' (``--wind-off`` stacks of two frames or more, :func:`wind_off_noise`); else the
run's own frames after their mean and fitted trend are removed (the white floor of dCp's
PSD, :func:`selfillum.uncertainty.unsteady.noise_from_floor`).

``--uncertainty mc --samples S``: the noise by Monte Carlo through Phase 1
(:func:`selfillum.unsteady.uncertainty_chain.chain_noise`: drawn pixels, registration
refitted or poses drawn, mapping, self-illumination, Phase 2 linearised), and the gain's
inputs (``a .. f``, ``T0``, ``Tinf``, the model temperature, ``q``, ``p_inf``; or the
in-situ fit's ``A, B`` from their covariance) drawn ``S`` times from their normal
distributions. The mapping's part is the same model in both methods.
"""

from __future__ import annotations

import numpy as np

from selfillum.unsteady.output import json_attr

__all__ = ["write_uncertainty"]


def _frame0_maps(grid, runs) -> list:
    """Each camera's map of frame 0 (its pose in the first frame)."""
    from resection.surface.surface_map import SurfaceMap

    return [SurfaceMap(grid.mesh, r.camera) for r in runs]


def _effective_pixels(grid, maps, n_nodes: int) -> np.ndarray:
    """Per node, the effective number of pixels of frame 0 (every camera's pixels on the
    faces around it, area-weighted as the node value): ``(sum a)^2 / sum (a^2 / n_f)``."""
    mesh = grid.mesh
    counts = np.zeros(len(mesh.faces))
    for m in maps:
        counts += m.pixel_counts
    a = np.asarray(mesh.area_faces, np.float64)
    tri = np.asarray(grid.triangles)
    ok = counts > 0
    s1 = np.zeros(n_nodes)
    s2 = np.zeros(n_nodes)
    for k in range(3):
        np.add.at(s1, tri[ok, k], a[ok])
        np.add.at(s2, tri[ok, k], a[ok] ** 2 / counts[ok])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s2 > 0, s1 * s1 / s2, np.nan)


def wind_off_noise(cfg):
    """The camera's noise (:class:`selfillum.uncertainty.noise.PixelNoise`) measured on
    the wind-off frames: with ``--uncertainty``, no stated ``camera_gain`` and ``--wind-off``
    stacks of at least two frames, the photon transfer curve of their temporal variance
    against their mean (:func:`selfillum.uncertainty.noise.estimate_noise`, every camera's
    pixels on one curve: one sensor model); else None. Read before any heavy step (a stack
    whose variance does not grow with the level is refused here)."""
    from selfillum.uncertainty.noise import estimate_noise
    from selfillum.uncertainty.psp_io import read_condition

    stated = cfg.stated
    if cfg.uncertainty is None or not cfg.wind_off or (
            stated is not None and stated.camera_gain is not None):
        return None
    means, counts, variances = read_condition(cfg.wind_off, len(cfg.wind_off), "--wind-off")
    pairs = [(m, v) for m, v in zip(means, variances, strict=True) if v is not None]
    if not pairs:
        return None
    pn = estimate_noise([m for m, _ in pairs], [v for _, v in pairs],
                        f"{cfg.wind_off[0]}: the wind-off frames")
    from dataclasses import replace

    return replace(pn, source=f"estimated from the wind-off frames' temporal variance "
                   f"({min(c for c in counts if c > 1)}+ frames)")


def write_uncertainty(f, cfg, grid, runs, s1, stats, spectra, fps: float, frames, gain,
                      cond, cp, coeffs, off_noise=None, chain=None) -> dict:
    """Write the uncertainty fields into the open output file ``f`` (see the module notes);
    returns the JSON summary. ``off_noise``: :func:`wind_off_noise`'s camera noise;
    ``chain``: Phase 1's inputs for the Monte Carlo
    (:func:`selfillum.unsteady.uncertainty_chain.chain_noise`)."""
    from selfillum.uncertainty.stated import Stated
    from selfillum.uncertainty.unsteady import (
        floor_dof,
        gain_relative_u,
        noise_from_camera,
        noise_from_floor,
        signal_rms,
    )

    stated = cfg.stated if cfg.stated is not None else Stated()
    T, N = s1["values"].shape
    maps = _frame0_maps(grid, runs)
    gf = np.asarray(gain, np.float64) * 144.0 / cond.q
    rms = np.asarray(stats["rms"], np.float64)
    status = {}
    floor = None
    dof = float(T)
    if spectra is not None and spectra.n_bands:
        sig_floor, floor = noise_from_floor(f["psd/band_psd"][()], fps)
        dof = floor_dof(spectra.freq, spectra.edges, T, spectra.nperseg)
        f.require_group("psd").create_dataset("noise_floor", data=floor.astype(np.float32))
    info = {"method": cfg.uncertainty}
    npx = camera_noise = None
    if stated.camera_gain is not None or off_noise is not None:
        g, r = ((stated.camera_gain, float(stated.read_noise or 0.0))
                if stated.camera_gain is not None else (off_noise.gain, off_noise.read_noise))
        scale0 = float(s1["values_scale"][0])
        I0 = s1["values"][0].astype(np.float64) / scale0
        npx = _effective_pixels(grid, maps, N)
        sigma = noise_from_camera(np.where(I0 > 0, I0, np.nan), npx, g, r, gf)
        how = "stated" if stated.camera_gain is not None else off_noise.source
        status["noise"] = (f"{how}: gain {g:.4g} e-/count, read noise {r:.3g} e-, frame 0's "
                           "pixels per node")
        info["camera_noise"] = {"gain": float(g), "read_noise": float(r)}
        camera_noise = (g, r)
    elif floor is not None:
        sigma = sig_floor
        status["noise"] = ("estimated: the run's dCp PSD in its highest band "
                           f"({spectra.edges[-2]:.4g}-{spectra.edges[-1]:.4g} Hz), white")
    else:
        sigma = rms.copy()
        status["noise"] = ("estimated: upper bound, the whole RMS of dCp (no --psd-bands to "
                           "measure the noise floor)")
    T_f = cond.surface_temperature
    urel, gstatus = gain_relative_u(coeffs, stated, T_f, cp, cond.q, cond.p_inf)
    status.update(gstatus)
    method = cfg.uncertainty
    if method == "mc":
        from selfillum.unsteady.uncertainty_chain import chain_noise

        if npx is None:
            npx = _effective_pixels(grid, maps, N)
        sigma_mc, sigma_reg_mc, drawn = chain_noise(cfg, grid, runs, chain or {}, T, gf,
                                                    sigma, npx, camera_noise,
                                                    int(cfg.samples))
        urel_mc = _gain_monte_carlo(cfg, gain, cond, cp, coeffs, T_f)
        info.update(samples=int(cfg.samples), chain=drawn,
                    linear_median={"dcp_u_noise": _med(sigma), "dcp_u_gain": _med(urel)})
        status["noise"] += (f"; Monte Carlo through Phase 1: {drawn['frames']} frames x "
                            f"{drawn['draws']} draws of the {drawn['pixels']}, poses "
                            f"{drawn['poses']}")
        sigma = sigma_mc
        urel = urel_mc if urel_mc is not None else urel
    covs = _pose_covariances(cfg, runs)
    u_map, used, u_reg = _mapping(f, grid, runs, maps, chain or {}, cfg, sigma, rms, gf, covs)
    status["mapping"] = ("estimated: the node's pixels' first and second moments about it "
                         "(frame 0, through Phase 1's weights) times the measured field's "
                         "gradient and curvature (a quartic over three rings of nodes), RMS "
                         f"over {used} frames")
    parts = [sigma, u_map]
    if u_reg is not None:
        if method == "mc":
            u_reg = sigma_reg_mc
        parts.append(u_reg)
        status["registration"] = (f"stated: markers {stated.marker:.3g} px, each frame's "
                                  "tracked pose's least-squares covariance, the pixels' "
                                  "displacement times frame 0's image gradient")
        f.create_dataset("dcp_u_registration", data=u_reg.astype(np.float32))
    elif cfg.registration == "track":
        status["registration"] = ("missing: give --u marker=..px (the tracked poses' "
                                  "covariance)")
    else:
        status["registration"] = (f"in the noise: the {cfg.registration} registration's "
                                  "error is white over the frames (the floor holds it; "
                                  "not with a stated camera noise model)"
                                  if cfg.registration == "first-frame" else
                                  "zero: the model does not move (registration none)")
    u_all = np.sqrt(sum(p * p for p in parts))
    f.create_dataset("dcp_u", data=u_all.astype(np.float32))
    f.create_dataset("dcp_u_noise", data=sigma.astype(np.float32))
    f.create_dataset("dcp_u_mapping", data=u_map.astype(np.float32))
    if urel is not None:
        f.create_dataset("dcp_u_gain", data=np.broadcast_to(urel, (N,)).astype(np.float32))
    rs, u_rs = signal_rms(rms, sigma, T, dof)
    st = f.require_group("stats")
    st.create_dataset("dcp_rms_signal", data=rs.astype(np.float32))
    st.create_dataset("dcp_rms_signal_u", data=u_rs.astype(np.float32))
    info.update(sources=status, dcp_u_median=_med(u_all),
                dcp_u_noise_median=_med(sigma), dcp_u_mapping_median=_med(u_map),
                dcp_u_gain_median=_med(urel) if urel is not None else None,
                missing=[k for k, v in status.items() if v.startswith("missing")])
    f.attrs["uncertainty"] = json_attr(info)
    return info


def _pose_covariances(cfg, runs) -> list:
    """Per camera the (6, 6) covariance of a tracked frame's pose from the markers'
    least squares (``--registration track`` with ``--u marker=`` and the targets), else
    None."""
    stated = cfg.stated
    if (cfg.registration != "track" or stated is None or stated.marker is None
            or cfg.targets is None):
        return [None] * len(runs)
    from resection.io.markers import read_markers
    from selfillum.uncertainty.registration import pose_covariance

    xyz = read_markers(cfg.targets).xyz
    return [pose_covariance(r.camera, xyz, stated.marker, str(cfg.targets)) for r in runs]


def _mapping(f, grid, runs, maps, chain, cfg, sigma, rms, gf, covs):
    """``(u_map, used, u_reg)``: per node the mapping's error
    (:mod:`selfillum.uncertainty.mapping`) over up to ``MAX_FRAMES`` frames of ``/dcp``,
    read in a few blocks of consecutive frames spread over the run, and the number of
    frames; the registration's part of a frame's dCp from the poses' covariances ``covs``
    (None when none is given). The moments and the pose sensitivities are frame 0's
    images mapped through Phase 1 in one pass
    (:mod:`selfillum.unsteady.uncertainty_images`)."""
    from selfillum.uncertainty.mapping import (
        MAX_FRAMES,
        mapping_operator,
        mapping_u,
        node_weights,
    )
    from selfillum.unsteady.uncertainty_images import (
        pose_images,
        pose_sensitivity,
        support_moments,
    )

    mesh = grid.mesh
    nv = len(mesh.vertices)
    frame0 = [np.asarray(r.frames[0], np.float64) for r in runs]
    C = len(runs)
    posed = [c for c in range(C) if covs[c] is not None]
    extra = None
    if posed:  # six images a camera whose pose is uncertain, the others' pixels at 0
        pim = {c: pose_images(maps[c], frame0[c]) for c in posed}
        extra = [[pim[c][k] if c == cc else np.zeros_like(frame0[c])
                  for cc in posed for k in range(6)] for c in range(C)]
    delta, Q, ext = support_moments(grid, runs, maps, frame0, chain, cfg, extra)
    u_reg = None
    if posed:
        sens = ext.reshape(len(posed), 6, -1)
        u_reg = np.asarray(gf, np.float64) * pose_sensitivity(sens, [covs[c] for c in posed])
    node_of = np.empty(nv, np.int64)  # one grid node a vertex (seam copies share a value)
    node_of[grid.node_vertex] = np.arange(len(grid.node_vertex))
    dset = f["dcp"]
    T = dset.shape[0]
    blocks = 8
    size = max(1, min(T, MAX_FRAMES) // blocks)
    starts = np.unique(np.linspace(0, T - size, min(blocks, max(T // size, 1))).astype(int))

    def frames():
        for a in starts:  # a few blocks of frames
            x = np.asarray(dset[a:a + size, :], np.float64)
            yield x[:, node_of]

    # the fit's samples: the vertices with a value in every frame read (a node seen in
    # some frames only, at the view's edge, would enter as a jump)
    use = np.isfinite(np.asarray(rms))[node_of]
    for x in frames():
        use &= np.isfinite(x).all(axis=0)
    D = mapping_operator(mesh, delta[node_of], Q[node_of], use=use)
    counts = sum(m.pixel_counts for m in maps)
    W = node_weights(mesh, counts > 0)
    u, used = mapping_u(D, frames(), np.nan_to_num(np.asarray(sigma, np.float64))[node_of], W)
    out = u[grid.node_vertex]
    seen = np.isfinite(np.asarray(rms))
    if u_reg is not None:
        u_reg = np.where(seen, u_reg, np.nan)
    return np.where(seen, out, np.nan), used, u_reg


def _med(x):
    if x is None:
        return None
    v = np.asarray(x, np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if v.size else None


def _gain_monte_carlo(cfg, gain, cond, cp, coeffs, T_f):
    """GUM S1 of the gain: the relative spread of ``G 144 / q`` with the gain's inputs
    drawn (``a .. f``, ``T0``, ``Tinf``, the model temperature, ``q``, ``p_inf``; or the
    in-situ fit's ``A, B`` from their covariance); None when nothing is stated."""
    from resection.io.upsp_inputs import PaintCalibration
    from selfillum.uncertainty.temperature import RECOVERY

    rng = np.random.default_rng(cfg.seed)
    S = int(cfg.samples)
    urel = None
    from selfillum.uncertainty.stated import Stated

    st = cfg.stated if cfg.stated is not None else Stated()
    if coeffs is not None and len(coeffs) == 4 and coeffs[0] == "insitu":
        from selfillum.uncertainty.unsteady import insitu_covariance

        _, law, ratio, p_taps = coeffs
        C = insitu_covariance(law, ratio, p_taps)
        g0 = (law.A * law.p_ref / law.B + cp * cond.q + cond.p_inf) / cond.q
        ratios = []
        for _ in range(S):
            A, B = rng.multivariate_normal([law.A, law.B], C)
            q = cond.q + (st.q or 0.0) * rng.standard_normal()
            pinf = cond.p_inf + (st.p_inf or 0.0) * rng.standard_normal()
            ratios.append((A * law.p_ref / B + cp * q + pinf) / q / g0 - 1.0)
        return np.std(np.asarray(ratios), axis=0, ddof=1)
    uc = st.gain_coefficients()
    if coeffs is not None and (uc is not None or st.t0 is not None or st.tinf is not None
                               or st.temperature is not None or st.q is not None
                               or st.p_inf is not None):
        c0 = np.asarray(coeffs, np.float64)
        uc = np.zeros(6) if uc is None else np.asarray(uc)
        ratios = []
        g0 = PaintCalibration(*c0).gain(T_f, cp * cond.q + cond.p_inf) / cond.q
        for _ in range(S):
            c = c0 + uc * rng.standard_normal(6)
            dt0 = (st.t0 or 0.0) * rng.standard_normal()
            dti = dt0 if st.tinf is None else st.tinf * rng.standard_normal()
            dT = (RECOVERY * dt0 + (1 - RECOVERY) * dti
                  + (st.temperature or 0.0) * rng.standard_normal()) * 1.8  # K -> deg F
            q = cond.q + (st.q or 0.0) * rng.standard_normal()
            pinf = cond.p_inf + (st.p_inf or 0.0) * rng.standard_normal()
            g = PaintCalibration(*c).gain(T_f + dT, cp * q + pinf) / q
            ratios.append(g / g0 - 1.0)
        urel = np.std(np.asarray(ratios), axis=0, ddof=1)
    return urel
