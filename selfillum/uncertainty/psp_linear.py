"""Linear propagation of every source through the ``selfillum psp`` chain
(``--uncertainty`` / ``--uncertainty linear``): :func:`linear_budget`.

Each source is a relative error of the face ratio ``R = E_off / E_on``, either independent
between faces (a variance per face: noise, ray sampling, temperature) or shared (a few
sensitivity vectors: registration, reflectance, unseen faces); both go through the
Stern-Volmer fit on the taps to the pressure (:mod:`selfillum.uncertainty.calibration`).
Costs a few sparse products, one extra merge of pixel planes per source and, with faces no
camera sees, one extra solve per image.
"""

from __future__ import annotations

import numpy as np

from selfillum.uncertainty import calibration as cal
from selfillum.uncertainty.budget import Budget, combine
from selfillum.uncertainty.faces import MergeWeights
from selfillum.uncertainty.illumination import (
    ROWS_CHECKED,
    hidden_response,
    rays_variance,
    reflectance_vector,
    rqmc_ratio,
    unseen_vector,
)
from selfillum.uncertainty.psp_chain import PSPInputs
from selfillum.uncertainty.registration import (
    pose_covariance,
    ratio_sensitivity,
    switching_variance,
)
from selfillum.uncertainty.temperature import ratio_variance
from selfillum.uncertainty.tunnel import pressure_u

__all__ = ["Sources", "model_sources", "linear_budget", "DEFAULT_UNSEEN_RANGE"]

#: Half-width of the unseen faces' range when none is stated: from nothing to twice the
#: continuation.
DEFAULT_UNSEEN_RANGE = 1.0


class Sources:
    """The sources' models for a run: ``independent`` (name -> (F,) relative variance of
    ``R``), ``shared`` (name -> (K, F) relative sensitivities), the pose covariances, the
    pixel noise models and ``status`` (name -> stated / estimated / missing)."""

    def __init__(self):
        self.independent: dict = {}
        self.shared: dict = {}
        self.status: dict = {}
        self.covariances: list | None = None
        self.noise: list | None = None  # per camera (off, on) PixelNoise
        self.temperature: tuple | None = None  # (sensitivity, u_T)
        self.unseen_range: float = 0.0
        self.u_tap: float = 0.0
        self.kappa: float | None = None  # quasi-random rays' variance / independent rays'


def model_sources(inp: PSPInputs, state, stated, noise_models) -> Sources:
    """Every source's model on the nominal run ``state``.

    Parameters
    ----------
    noise_models : list of (PixelNoise, PixelNoise) or None
        Per camera, the wind-off and wind-on pixel noise (stated or estimated); None:
        noise missing.
    """
    S = Sources()
    mesh_n = len(inp.mesh.faces)
    R = state.result.ratio
    W = MergeWeights.from_merge(inp.maps, [np.where(np.isfinite(n), o, np.nan)
                                           for o, n in zip(inp.off, inp.on, strict=True)],
                                state.merged_off,
                                pixel_weights_=state.extra.get("pixel_weights"))
    # ---- noise
    if noise_models is not None:
        v_off = W.variance([nm[0].variance(o, k) for nm, o, k in
                            zip(noise_models, inp.off, inp.off_frames, strict=True)])
        v_on = W.variance([nm[1].variance(o, k) for nm, o, k in
                           zip(noise_models, inp.on, inp.on_frames, strict=True)])
        with np.errstate(invalid="ignore", divide="ignore"):
            S.independent["noise"] = v_off / state.e_off**2 + v_on / state.e_on**2
        S.noise = noise_models
        S.status["noise"] = "; ".join(
            f"{nm[0].source}: camera {c + 1} gain {nm[0].gain:.4g} e-/count, read noise "
            f"{nm[0].read_noise:.3g} e-" for c, nm in enumerate(noise_models))
    else:
        S.status["noise"] = ("missing: no camera gain and read noise stated and one frame "
                             "per condition (give --u camera_gain= read_noise=, or stacks)")
    # ---- registration
    if inp.markers is not None and stated.marker is not None:
        S.covariances = [pose_covariance(m.camera, inp.markers, stated.marker)
                         for m in inp.maps]
        S.shared["registration"] = ratio_sensitivity(W, inp.off, inp.on, S.covariances)
        S.independent["registration_pixels"] = switching_variance(W, inp.off, inp.on,
                                                                  S.covariances)
        S.status["registration"] = "stated (marker accuracy, pose least squares)"
    else:
        S.status["registration"] = ("missing: give --markers and --u marker=..px for the "
                                    "poses' covariance")
    # ---- self-illumination
    if inp.correct_si:
        r = stated.unseen if stated.unseen is not None else DEFAULT_UNSEEN_RANGE
        b_off, b_on, d_off, d_on = _hidden(inp, state, r)
        bound = rays_variance(inp.F, b_off, b_on, state.e_off, state.e_on, inp.reflectance,
                              inp.rays)
        kappa = _rqmc_kappa(inp, state, b_off, b_on, bound)
        S.independent["si_rays"] = kappa * bound
        S.kappa = kappa
        S.status["si_rays"] = (f"estimated: {inp.rays} rays a face; the quasi-random rays' "
                               f"variance {kappa:.3g} x the independent-ray formula "
                               f"({ROWS_CHECKED} rows cast again)")
        if stated.reflectance is not None:
            S.shared["reflectance"] = reflectance_vector(inp.F, b_off, b_on, state.e_off,
                                                         state.e_on, stated.reflectance)[None]
            S.status["reflectance"] = "stated"
        else:
            S.status["reflectance"] = "missing: give --u reflectance="
        if state.hidden_emission is not None:
            S.unseen_range = r
            if r > 0:
                with np.errstate(invalid="ignore", divide="ignore"):
                    e_on = state.e_on + d_on
                    shifted = np.where(state.seen & (e_on > 0),
                                       (state.e_off + d_off) / e_on, np.nan)
                S.shared["unseen"] = unseen_vector(R, shifted)[None]
            S.status["unseen"] = ("stated" if stated.unseen is not None else
                                  f"estimated: default range +-{100 * r:.0f} %")
    # ---- temperature
    if stated.paint_temperature is not None and stated.temperature is not None:
        S.temperature = (stated.paint_temperature, stated.temperature)
        S.independent["temperature"] = ratio_variance(*S.temperature, mesh_n)
        S.status["temperature"] = "stated"
    else:
        S.status["temperature"] = ("missing: give --u paint_temperature=..%/K and "
                                   "temperature=..K")
    S.u_tap = float(stated.taps or 0.0)
    return S


def _rqmc_kappa(inp, state, b_off, b_on, bound) -> float:
    """:func:`selfillum.uncertainty.illumination.rqmc_ratio` on ``ROWS_CHECKED`` seen
    faces with reflected light (chosen with the run's seed)."""
    from selfillum.transport.viewfactors import view_factors

    cand = np.flatnonzero(state.seen & np.isfinite(bound) & (bound > 0))
    if not cand.size:
        return 1.0
    rng = np.random.default_rng(inp.seed)
    rows = np.sort(rng.choice(cand, min(ROWS_CHECKED, cand.size), replace=False))
    again = view_factors(inp.mesh, rays_per_face=inp.rays, seed=inp.seed + 7919, rows=rows,
                         caster=inp.caster)
    return rqmc_ratio(inp.F, again, rows, b_off, b_on, state.e_off, state.e_on,
                      inp.reflectance, bound)


def _hidden(inp, state, r: float):
    """Radiosity of every face (measured where seen, the chain's emission solved forward
    on the hidden ones) and the seen faces' emission change when the hidden ones emit
    ``1 + r`` times the continuation
    (:func:`selfillum.uncertainty.illumination.hidden_response`), wind-off and wind-on."""
    if state.seen.all():
        z = np.zeros_like(state.b_off)
        return state.b_off, state.b_on, z, z
    (b_off, b_on), (d_off, d_on) = hidden_response(
        inp.F, inp.reflectance, state.seen, (state.b_off, state.b_on),
        (state.e_off, state.e_on), r)
    return b_off, b_on, d_off, d_on


def linear_budget(inp: PSPInputs, state, S: Sources, stated) -> dict:
    """``{"p": Budget, "cp": Budget}`` (``cp`` with a ``.wtd``) by linear propagation."""
    res = state.result
    law, R, p = res.stern_volmer, res.ratio, res.pressure
    ok = np.isfinite(R[res.tap_faces])  # the taps the fit used
    tf = res.tap_faces[ok]
    p_taps = np.asarray(inp.taps.pressure, np.float64)[ok]
    M, G = cal.design(p_taps, law.p_ref)
    k = law.p_ref / law.B
    parts, full = {}, {}
    var_taps = np.zeros(len(tf))
    for name, v in S.independent.items():
        own = k * np.abs(R) * np.sqrt(np.maximum(v, 0.0))
        parts[name] = own
        vt = np.nan_to_num(v[tf]) * R[tf] ** 2
        var_taps += vt
        full[name] = np.hypot(own, cal.pressure_u(cal.fit_covariance(G, vt, law), law, p))
    D_taps = []
    for name, D in S.shared.items():
        parts[name] = cal.propagate_shared(D, R, tf, G, law, p)
        full[name] = parts[name]
        D_taps.append(np.nan_to_num(D[:, tf]) * R[tf])
    resid = R[tf] - law.ratio(p_taps)
    u_tap_r2 = (law.B * S.u_tap / law.p_ref) ** 2
    Dt = np.concatenate(D_taps) if D_taps else None
    info = {}
    if "noise" in S.independent:
        C = cal.fit_covariance(G, var_taps, law, S.u_tap)
        status = "stated" if S.u_tap else "estimated: the sources at the taps"
        info["tap_scatter_ratio"] = cal.scatter_ratio(M, G, resid, var_taps, Dt, u_tap_r2)
    else:
        C = cal.residual_covariance(M, resid)
        status = "estimated: the fit's residuals at the taps"
    for d in (parts, full):  # the pixels changing face are part of the registration
        if "registration_pixels" in d:
            d["registration"] = np.hypot(d.pop("registration_pixels"),
                                         d.get("registration", 0.0))
    parts["calibration"] = cal.pressure_u(C, law, p)
    full["calibration"] = cal.pressure_u(
        cal.fit_covariance(G, np.zeros(len(tf)), law, S.u_tap), law, p)
    info["stern_volmer_covariance"] = C.tolist()
    status_all = dict(S.status, calibration=status)
    budgets = {}
    if inp.tunnel is not None:
        ps, q, _ = inp.tunnel
        cp = state.cp
        cparts = {n: v / q for n, v in parts.items()}
        budgets["cp"] = Budget("cp", "linear", cparts, combine(cparts),
                               dict(status_all, tunnel="zero: Cp is anchored on the taps' "
                                    "Cp (PS and Q cancel)"), dict(info))
        if stated.q is not None or stated.p_inf is not None:
            parts["tunnel"] = np.broadcast_to(pressure_u(cp, stated.p_inf, stated.q),
                                              p.shape).copy()
            status_all["tunnel"] = "stated"
        else:
            status_all["tunnel"] = "missing: give --u q=..psf p_inf=..psf"
    budgets["p"] = Budget("p", "linear", parts, combine(parts), status_all, info)
    budgets["p"].full = full  # each source with its effect through the taps' fit
    return budgets
