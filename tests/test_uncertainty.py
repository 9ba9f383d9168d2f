"""Uncertainty of PSP pressures (selfillum.uncertainty, docs/uncertainty.md).

References: closed forms (the least-squares covariance of a straight line, the photon
transfer curve of Poisson + Gaussian pixels), Monte Carlo of the fit with NumPy draws,
and the coverage of the stated uncertainty over synthetic measurements whose every input
is drawn from its stated distribution (scenes/psp_uncertainty.py): the error against the
chain run with every input at its true value."""

from __future__ import annotations

import numpy as np
import pytest

from resection import InputError
from selfillum.images.psp import SternVolmer, Taps, fit_stern_volmer
from selfillum.uncertainty import calibration as cal
from selfillum.uncertainty.noise import PixelNoise, estimate_noise
from selfillum.uncertainty.stated import Stated, parse_stated


def test_stated_values_and_bad_input():
    st = parse_stated(["marker=0.04px", "paint_temperature=1%/K", "temperature=0.9F",
                       "camera_gain=4 e/count", "q=2psf"])
    assert st.marker == 0.04 and st.paint_temperature == pytest.approx(0.01)
    assert st.temperature == pytest.approx(0.5) and st.camera_gain == 4.0 and st.q == 2.0
    for bad, msg in (("marker=-0.1px", ">= 0"), ("marker=nanpx", "finite"),
                     ("marker=0.1mm", "not 'mm'"), ("temperature=1", "not 'no unit'"),
                     ("q=2", "psf"), ("nope=1", "unknown key"), ("marker", "KEY=VALUE"),
                     ("camera_gain=0e/count", "> 0")):
        with pytest.raises(InputError, match=msg):
            parse_stated([bad])
    with pytest.raises(InputError, match="twice"):
        parse_stated(["q=1psf", "q=2psf"])


def test_stern_volmer_covariance_closed_form():
    """Equal variances: C_AB is sigma^2 (M^T M)^-1, whose closed forms are
    var B = s2 / Sxx, var A = s2 sum x^2 / (n Sxx), cov = -s2 xbar / Sxx; and the
    covariance of 20000 fits of noisy ratios (fit_stern_volmer) matches it."""
    p_ref, law = 100.0, SternVolmer(0.15, 0.85, 100.0)
    p = np.array([70.0, 80, 92, 100, 108, 115, 130])
    x = p / p_ref
    s = 0.003
    M, G = cal.design(p, p_ref)
    C = cal.fit_covariance(G, np.full(p.size, s * s), law)
    Sxx = np.sum((x - x.mean()) ** 2)
    assert C[1, 1] == pytest.approx(s * s / Sxx, rel=1e-12)
    assert C[0, 0] == pytest.approx(s * s * np.sum(x * x) / (p.size * Sxx), rel=1e-12)
    assert C[0, 1] == pytest.approx(-s * s * x.mean() / Sxx, rel=1e-12)
    rng = np.random.default_rng(0)
    ab = np.array([[(f := fit_stern_volmer(law.ratio(p) + s * rng.standard_normal(p.size),
                                           p, p_ref)).A, f.B] for _ in range(20000)])
    np.testing.assert_allclose(np.cov(ab.T), C, rtol=0.05, atol=1e-9)
    # the tap pressures' uncertainty enters as (B u / p_ref)^2 on each ratio
    C2 = cal.fit_covariance(G, np.zeros(p.size), law, u_tap=0.5)
    np.testing.assert_allclose(C2, (0.85 * 0.5 / p_ref / s) ** 2 * C, rtol=1e-12)
    # a face's pressure: (p_ref / B)^2 m^T C m
    u = cal.pressure_u(C, law, np.array([100.0]))
    assert u[0] == pytest.approx(p_ref / law.B * np.sqrt(C[0, 0] + 2 * C[0, 1] + C[1, 1]))


def test_photon_transfer_estimate():
    """Pixels of Poisson electrons (gain 3.5 e-/count) plus 12 e- read noise: the gain and
    read noise come back from 40 frames."""
    rng = np.random.default_rng(1)
    level = np.linspace(200, 3000, 120 * 90).reshape(120, 90)
    g, r = 3.5, 12.0
    frames = (rng.poisson(level * g, (40,) + level.shape)
              + r * rng.standard_normal((40,) + level.shape)) / g
    pn = estimate_noise([frames.mean(0)], [frames.var(0, ddof=1)])
    assert pn.gain == pytest.approx(g, rel=0.03)
    assert pn.read_noise == pytest.approx(r, rel=0.25)
    np.testing.assert_allclose(PixelNoise(g, r).variance(level), level / g + (r / g) ** 2)


# ---------------------------------------------------------------- the synthetic chain
@pytest.fixture(scope="module")
def case():
    from resection.surface.visibility import RayCaster
    from scenes.psp_uncertainty import psp_uncertainty_case
    from selfillum.transport.viewfactors import view_factors

    c = psp_uncertainty_case(exact_rays=4096)
    caster = RayCaster(c.mesh)
    F = view_factors(c.mesh, rays_per_face=4096, seed=12345, caster=caster)
    return c, caster, F


def _inputs(case, d, rays=4096):
    from resection.surface.surface_map import SurfaceMap
    from scenes.psp_uncertainty import P_REF
    from selfillum.transport.viewfactors import view_factors
    from selfillum.uncertainty.psp_chain import PSPInputs

    c, caster, F = case
    m = SurfaceMap(c.mesh, d["camera"], caster=caster)
    if d["rays_seed"]:
        F = view_factors(c.mesh, rays_per_face=rays, seed=d["rays_seed"], caster=caster)
    taps = Taps(c.tap_ids, c.tap_points, d["taps"])
    return PSPInputs(c.mesh, [m], [d["off"]], [d["on"]], [1], [1], taps, P_REF, F,
                     np.full(len(c.mesh.faces), d["reflectance"]), rays, 0, None,
                     c.markers, caster)


def _stated(case, keys):
    return Stated(**{k: v for k, v in case[0].sources.items() if k in keys})


_KEYS = {"noise": ("camera_gain", "read_noise"), "reflectance": ("reflectance",),
         "temperature": ("paint_temperature", "temperature"), "calibration": ("taps",)}


def _coverage(case, sources, n_runs, seed, whole=False):
    """|error| / u over n_runs measurements (every face of every run)."""
    from selfillum.uncertainty.psp_chain import run_chain
    from selfillum.uncertainty.psp_run import noise_models, psp_uncertainty

    c = case[0]
    truth = run_chain(_inputs(case, c.draw(np.random.default_rng(0), set()))).result.pressure
    keys = sum((_KEYS[s] for s in sources), ())
    st = _stated(case, keys)
    rng = np.random.default_rng(seed)
    z = []
    for _ in range(n_runs):
        d = c.draw(rng, set(sources))
        inp = _inputs(case, d)
        state, b = psp_uncertainty(inp, st, noise=noise_models(st, 1))
        u = b["p"].combined if whole else b["p"].full[sources[0]]
        e = state.result.pressure - truth
        ok = np.isfinite(e) & np.isfinite(u)
        z.append(np.abs(e[ok]) / u[ok])
    return np.concatenate(z)


def test_noise_coverage(case):
    """Only the pixel noise on (stated gain and read noise): the k = 1 and k = 2 intervals
    cover about 68 % and 95 % of the errors of 12 measurements (every face)."""
    z = _coverage(case, ["noise"], 12, 1)
    assert 0.62 < np.mean(z <= 1) < 0.74
    assert 0.93 <= np.mean(z <= 2) <= 0.97
