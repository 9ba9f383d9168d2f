"""TSP ratio to temperature (selfillum.thermal.tsp) against the Arrhenius law solved by a
root finder; the Stanton number and heat-transfer coefficient (selfillum.thermal.stanton)
against the free stream's density from its static pressure (the ideal gas) instead of the
dynamic pressure; bad calibration files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from resection.errors import InputError
from selfillum.thermal.stanton import PSF, FlowReference
from selfillum.thermal.tsp import GAS_CONSTANT, read_tsp_calibration
from selfillum.unsteady.conditions import Conditions


def test_arrhenius_against_a_root_finder(tmp_path):
    from scipy.optimize import brentq

    p = tmp_path / "tsp.json"
    E_nr = 35_000.0  # J/mol
    p.write_text(json.dumps({"model": "arrhenius", "E_nr": E_nr, "T_ref": 293.0}))
    cal = read_tsp_calibration(p)
    ratios = np.array([0.3, 0.5, 0.8, 1.0, 1.2])
    ours = cal.temperature(ratios)
    for r, T in zip(ratios, ours, strict=True):
        ref = brentq(lambda x, r=r: np.exp(E_nr / GAS_CONSTANT * (1 / x - 1 / 293.0)) - r,
                     150.0, 900.0, xtol=1e-12)
        assert T == pytest.approx(ref, abs=1e-8)
    assert cal.temperature(0.0) != cal.temperature(0.0)  # NaN: no temperature


def test_polynomial_and_range(tmp_path):
    p = tmp_path / "tsp.json"
    c = [400.0, -120.0, 13.0]
    p.write_text(json.dumps({"model": "polynomial", "coefficients": c, "T_ref": 293.0,
                             "range_K": [280.0, 380.0]}))
    cal = read_tsp_calibration(p)
    r = np.array([0.5, 0.9, 1.0])
    np.testing.assert_allclose(cal.temperature(r), np.polyval(c[::-1], r))
    assert np.isnan(cal.temperature(0.1))  # 390 K, outside the range


@pytest.mark.parametrize("d, words", [
    ({"model": "arrhenius", "T_ref": 293.0}, "needs E_nr"),
    ({"model": "arrhenius", "E_nr": 3e4, "T_ref": -5.0}, "T_ref -5.0 K is below 0 K"),
    ({"model": "polynomial", "T_ref": 293.0}, "needs coefficients"),
    ({"model": "stern-volmer", "T_ref": 293.0}, "unknown"),
])
def test_bad_tsp_calibration_one_line(tmp_path, d, words):
    p = tmp_path / "tsp.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError) as ei:
        read_tsp_calibration(p)
    assert str(p) in str(ei.value) and words in str(ei.value)


def test_stanton_against_the_ideal_gas_density():
    M, ps_psf, t0_f = 2.0, 300.0, 200.0
    q_psf = 0.5 * 1.4 * ps_psf * M**2  # the .wtd's Q consistent with PS and MACH
    cond = Conditions(M, q_psf, ps_psf, t0_f, (t0_f + 459.67) / 1.8 - 459.67)
    flow = FlowReference.from_conditions(cond, recovery_factor=0.85)
    T0 = (t0_f + 459.67) * 5 / 9
    Tinf = T0 / 1.8
    rho = ps_psf * PSF / (287.05 * Tinf)
    u = M * np.sqrt(1.4 * 287.05 * Tinf)
    cp = 1.4 * 287.05 / 0.4
    Taw = Tinf + 0.85 * (T0 - Tinf)
    assert flow.t_aw == pytest.approx(Taw, rel=1e-12)
    qw, Tw = np.array([1.0e4, 2.0e4]), np.array([300.0, 320.0])
    np.testing.assert_allclose(flow.coefficient(qw, Tw), qw / (Taw - Tw), rtol=1e-12)
    np.testing.assert_allclose(flow.stanton(qw, Tw), qw / (rho * u * cp * (Taw - Tw)),
                               rtol=1e-9)
    assert np.isnan(flow.coefficient(1e4, Taw - 0.1))  # at the recovery temperature
