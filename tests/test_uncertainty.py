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
    covariance of 5000 fits of noisy ratios (fit_stern_volmer) matches it."""
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
                                           p, p_ref)).A, f.B] for _ in range(5000)])
    np.testing.assert_allclose(np.cov(ab.T), C, rtol=0.08, atol=1e-9)
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
         "temperature": ("paint_temperature", "temperature"), "calibration": ("taps",),
         "registration": ("marker",), "si_rays": ()}
ALL = ("noise", "registration", "si_rays", "reflectance", "temperature", "calibration")


def _coverage(case, sources, n_runs, seed):
    """|error| / u over n_runs measurements with ``sources`` drawn (every face of every
    run); u: the source's whole effect (one source) or the combined uncertainty."""
    from selfillum.uncertainty.psp_chain import run_chain
    from selfillum.uncertainty.psp_run import noise_models, psp_uncertainty

    c = case[0]
    truth = run_chain(_inputs(case, c.draw(np.random.default_rng(0), set()))).result.pressure
    st = _stated(case, sum((_KEYS[s] for s in sources), ()))
    rng = np.random.default_rng(seed)
    z = []
    for _ in range(n_runs):
        d = c.draw(rng, set(sources))
        rays = 256 if "si_rays" in sources else 4096
        state, b = psp_uncertainty(_inputs(case, d, rays), st,
                                   noise=noise_models(st, 1) if "noise" in sources else None)
        u = b["p"].combined if len(sources) > 1 else b["p"].full[sources[0]]
        e = state.result.pressure - truth
        ok = np.isfinite(e) & np.isfinite(u)
        assert ok.sum() > 0.9 * len(e)
        z.append(np.abs(e[ok]) / u[ok])
    return np.concatenate(z)


def test_noise_coverage(case):
    """Only the pixel noise on (stated gain and read noise): the k = 1 and k = 2 intervals
    cover about 68 % and 95 % of the errors of 8 measurements (every face)."""
    z = _coverage(case, ["noise"], 8, 1)
    assert 0.62 < np.mean(z <= 1) < 0.74
    assert 0.93 <= np.mean(z <= 2) <= 0.97


@pytest.mark.slow
def test_coverage_all_sources(case):
    """Every source drawn at once (noise, pose, rays, reflectance, temperature, taps), 30
    measurements: the k = 2 intervals of the combined uncertainty cover 93-97 % of the
    faces' errors (k = 1: about 68 %)."""
    z = _coverage(case, list(ALL), 30, 2)
    assert 0.93 <= np.mean(z <= 2) <= 0.97
    assert 0.62 < np.mean(z <= 1) < 0.76


@pytest.mark.slow
@pytest.mark.parametrize("source", ["registration", "si_rays", "reflectance", "temperature",
                                    "calibration"])
def test_coverage_each_source(case, source):
    """One source drawn at a time, its own budget line: k = 2 covers 93-97 % of the errors
    for a source independent between faces; for a source shared by every face (one draw a
    measurement: reflectance, the taps) the 40 draws allow the binomial spread. The pixels
    changing face make the registration's error lumpy (most faces none, a few a whole
    pixel): its k = 1 coverage is above 68 %, not at it."""
    shared = source in ("reflectance", "calibration")
    n = 40
    z = _coverage(case, [source], n, 3)
    k2 = np.mean(z <= 2)
    if shared:
        half = 2.6 * np.sqrt(0.954 * 0.046 / n) + 0.01
        assert 0.954 - half <= k2 <= 0.954 + half
    else:
        assert 0.93 <= k2 <= 0.97
        if source != "registration":
            assert 0.62 < np.mean(z <= 1) < 0.75


@pytest.mark.slow
def test_linear_agrees_with_monte_carlo(case):
    """One measurement with every source stated: the linear budget against the GUM S1
    Monte Carlo (80 draws a source, the whole chain re-run: images, a surface map cast for
    each drawn pose, form factors cast with a new seed, reflectance, temperature, taps).
    Median over the faces of u_linear / u_mc within 20 % for every source and 12 % for
    the combined value."""
    from selfillum.uncertainty.psp_run import noise_models, psp_uncertainty

    c = case[0]
    d = c.draw(np.random.default_rng(11), set(ALL))
    inp = _inputs(case, d, rays=256)
    st = _stated(case, sum((_KEYS[s] for s in ALL), ()))
    nm = noise_models(st, 1)
    _, lin = psp_uncertainty(inp, st, noise=nm)
    _, mc = psp_uncertainty(inp, st, noise=nm, method="mc", samples=80, seed=5)
    L, M = lin["p"], mc["p"]
    assert set(M.parts) == set(ALL)
    for src in ALL:
        ratio = np.nanmedian(L.full[src] / M.parts[src])
        assert 0.8 < ratio < 1.25, (src, ratio)
    ratio = np.nanmedian(L.combined / M.combined)
    assert 0.88 < ratio < 1.12, ratio


def _write_cli_case(case, tmp_path, frames: int):
    from scenes.psp_uncertainty import write_psp_files

    return write_psp_files(case[0], tmp_path, frames)


def test_psp_cli_uncertainty(case, tmp_path, capsys):
    """``selfillum psp --uncertainty`` with 6 frames a condition and the taps as Cp in a
    .wtd: cp and cp_u (and each source's part) per face and per node, the noise model
    estimated from the frames (the true gain, 4 e-/count, within 10 %), the unstated
    sources named, the pictures written; a Cp uncertainty that is never zero."""
    import json

    from PIL import Image

    from selfillum.cli.main import main

    args = _write_cli_case(case, tmp_path, 6)
    out = tmp_path / "out"
    rc = main(args + ["--uncertainty", "--markers", str(tmp_path / "model.tgts"),
                      "--u", "marker=0.05px", "--u", "taps=0.1psf", "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    t = np.genfromtxt(out / "pressure_faces.csv", delimiter=",", names=True)
    for col in ("cp", "cp_u", "cp_u_noise", "cp_u_registration", "cp_u_si_rays",
                "cp_u_calibration", "p_u", "p_u_noise"):
        assert col in t.dtype.names, col
    seen = np.isfinite(t["cp"])
    assert seen.sum() > 300 and np.all(t["cp_u"][seen] > 0)
    parts = [n for n in t.dtype.names if n.startswith("cp_u_")]
    rss = np.sqrt(sum(t[n][seen] ** 2 for n in parts))
    np.testing.assert_allclose(rss, t["cp_u"][seen], rtol=1e-6)
    np.testing.assert_allclose(t["cp_u"][seen], t["p_u"][seen] / 40.0, rtol=1e-6)
    nodes = np.genfromtxt(out / "pressure_nodes.csv", delimiter=",", names=True)
    assert len(nodes) == len(case[0].mesh.vertices) and "cp_u" in nodes.dtype.names
    doc = json.loads((out / "uncertainty.json").read_text())
    src = doc["cp"]["sources"]
    assert src["noise"]["status"].startswith("estimated from the frames")
    assert src["reflectance"]["status"].startswith("missing")
    assert src["temperature"]["status"].startswith("missing")
    assert src["tunnel"]["status"].startswith("zero")
    assert abs(sum(v["share"] or 0 for v in src.values()) - 1) < 1e-9
    assert "reflectance: missing" not in cap.out and "reflectance  missing" in cap.out
    import re

    g = float(re.search(r"gain ([0-9.]+) e-/count", cap.out).group(1))
    assert abs(g - 4.0) < 0.4
    for png in ("cp_u.png", "budget.png"):
        im = np.asarray(Image.open(out / png).convert("RGB"), float)
        assert im.std() > 10


def test_psp_cli_uncertainty_nothing_stated(case, tmp_path, capsys):
    """One frame a condition and no --u: the noise and the other sources are named as
    missing, the calibration comes from the fit's residuals, and cp_u is still > 0."""
    import json

    from selfillum.cli.main import main

    args = _write_cli_case(case, tmp_path, 1)
    rc = main(args + ["--uncertainty", "--out", str(tmp_path / "o")])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    doc = json.loads((tmp_path / "o" / "uncertainty.json").read_text())["cp"]["sources"]
    assert doc["noise"]["status"].startswith("missing")
    assert doc["registration"]["status"].startswith("missing")
    assert doc["calibration"]["status"].startswith("estimated: the fit's residuals")
    t = np.genfromtxt(tmp_path / "o" / "pressure_faces.csv", delimiter=",", names=True)
    seen = np.isfinite(t["cp"])
    assert np.all(t["cp_u"][seen] > 0)
    assert "missing" in cap.out


@pytest.mark.parametrize("extra, msg", [
    (["--uncertainty", "--u", "marker=-0.1px"], "marker must be >= 0"),
    (["--uncertainty", "--u", "reflectance=0.02px"], "reflectance is given in no unit"),
    (["--uncertainty", "--u", "q=nanpsf"], "finite"),
    (["--u", "q=1psf"], "--u given without --uncertainty"),
    (["--uncertainty", "mc", "--samples", "1"], "at least 2"),
])
def test_psp_cli_uncertainty_bad_input(case, tmp_path, capsys, extra, msg):
    from selfillum.cli.main import main

    args = _write_cli_case(case, tmp_path, 1)
    rc = main(args + extra + ["--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "o").exists()
