"""GUM Supplement 1 Monte Carlo through the ``selfillum psp`` chain
(``--uncertainty mc --samples N``): :func:`mc_budget`.

Each sample re-runs the whole chain (:func:`selfillum.uncertainty.psp_chain.run_chain`) with
every input drawn from its stated distribution, centred on the value used:

* the images: each pixel plus Gaussian noise of the pixel noise model's variance
  (:mod:`selfillum.uncertainty.noise`) at its measured level;
* the poses: ``theta ~ N(0, Sigma)`` per camera, a new surface map cast for the drawn pose
  (:mod:`selfillum.uncertainty.registration`);
* the form factors: cast again with another seed (``seed + 1 + sample``) and as many rays;
* the reflectance ``rho + u_rho z``; the unseen faces' scale ``1 + eps``,
  ``eps ~ U(-r, r)``;
* the model temperature: the wind-on emission times ``1 + s dT_i``, ``dT_i ~ N(0, u_T)``
  per face;
* the taps' pressures ``+ u_tap z``; with a ``.wtd``, ``PS`` and ``Q`` drawn and the taps'
  pressures ``PS + Cp Q``.

The standard uncertainty is the samples' standard deviation. Each source is run alone
(``samples`` draws each: its part), then all together (the combined value, not the root
sum of squares of the parts: any non-linearity or interaction shows there).
"""

from __future__ import annotations

import numpy as np

from selfillum.uncertainty.budget import Budget
from selfillum.uncertainty.psp_chain import PSPInputs, run_chain
from selfillum.uncertainty.registration import perturbed

__all__ = ["mc_budget", "draw_chain"]


def draw_chain(inp: PSPInputs, S, stated, on: set, rng: np.random.Generator, sample: int):
    """One run of the chain with the sources in ``on`` drawn."""
    from resection.surface.surface_map import SurfaceMap

    kw = {}
    if "registration" in on and S.covariances is not None:
        maps = []
        for m, C in zip(inp.maps, S.covariances, strict=True):
            th = rng.multivariate_normal(np.zeros(6), C)
            maps.append(SurfaceMap(inp.mesh, perturbed(m.camera, th),
                                   max_obliqueness=m.max_obliqueness, caster=inp.caster))
        kw["maps"] = maps
    if "noise" in on and S.noise is not None:
        kw["off"] = [o + np.sqrt(nm[0].variance(o, k)) * rng.standard_normal(o.shape)
                     for o, nm, k in zip(inp.off, S.noise, inp.off_frames, strict=True)]
        kw["on"] = [o + np.sqrt(nm[1].variance(o, k)) * rng.standard_normal(o.shape)
                    for o, nm, k in zip(inp.on, S.noise, inp.on_frames, strict=True)]
    if "si_rays" in on and inp.correct_si:
        from selfillum.transport.viewfactors import view_factors

        kw["F"] = view_factors(inp.mesh, rays_per_face=inp.rays, seed=inp.seed + 1 + sample,
                               caster=inp.caster)
    if "reflectance" in on and stated.reflectance is not None and inp.correct_si:
        kw["reflectance"] = np.clip(inp.reflectance + stated.reflectance
                                    * rng.standard_normal(), 0.0, 0.999)
    if "unseen" in on and S.unseen_range > 0:
        kw["unseen_scale"] = rng.uniform(-S.unseen_range, S.unseen_range)
    if "temperature" in on and S.temperature is not None:
        s, uT = S.temperature
        kw["on_factor"] = 1.0 + s * uT * rng.standard_normal(len(inp.mesh.faces))
    if "tunnel" in on and inp.tunnel is not None:
        ps, q, _ = inp.tunnel
        kw["tunnel"] = (ps + (stated.p_inf or 0.0) * rng.standard_normal(),
                        q + (stated.q or 0.0) * rng.standard_normal())
    if "calibration" in on and S.u_tap > 0:
        base = np.asarray(inp.taps.pressure, np.float64)
        if "tunnel" in kw:
            base = kw["tunnel"][0] + np.asarray(inp.tunnel[2]) * kw["tunnel"][1]
        kw["tap_pressure"] = base + S.u_tap * rng.standard_normal(base.shape)
    return run_chain(inp, **kw)


def _active(S, inp, stated) -> list:
    names = [n for n in ("noise", "registration", "si_rays", "reflectance", "unseen",
                         "temperature") if n in S.independent or n in S.shared]
    if S.u_tap > 0:
        names.append("calibration")
    if inp.tunnel is not None and (stated.q is not None or stated.p_inf is not None):
        names.append("tunnel")
    return names


def mc_budget(inp: PSPInputs, state, S, stated, samples: int, seed: int = 0,
              progress=None) -> dict:
    """``{"p": Budget, "cp": Budget}`` by GUM S1 Monte Carlo, ``samples`` draws for each
    source alone and for all of them together."""
    rng = np.random.default_rng(seed)
    names = _active(S, inp, stated)
    runs = [(n, {n}) for n in names] + [("combined", set(names))]
    std_p, std_cp = {}, {}
    done = 0
    for label, on in runs:
        P, CP = [], []
        for s in range(samples):
            st = draw_chain(inp, S, stated, on, rng, s)
            P.append(st.result.pressure)
            if st.cp is not None:
                CP.append(st.cp)
            done += 1
            if progress is not None:
                progress(done, len(runs) * samples)
        std_p[label] = np.std(np.asarray(P), axis=0, ddof=1)
        if CP:
            std_cp[label] = np.std(np.asarray(CP), axis=0, ddof=1)
    status = dict(S.status)
    if "calibration" in names:
        status["calibration"] = "stated (taps' pressures drawn)"
    info = {"samples": int(samples), "runs": [r[0] for r in runs]}
    out = {"p": Budget("p", "mc", {n: std_p[n] for n in names}, std_p["combined"], status,
                       info)}
    if std_cp:
        out["cp"] = Budget("cp", "mc", {n: std_cp[n] for n in names if n != "tunnel"},
                           std_cp["combined"], dict(status, tunnel="zero: Cp is anchored on "
                                                    "the taps' Cp (PS and Q cancel)"), info)
    return out
