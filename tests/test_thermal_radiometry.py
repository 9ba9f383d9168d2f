"""Counts to temperature (selfillum.thermal.radiometry) against FLIR's formula as flirpy
implements it (``flirpy.util.raw.raw2temp``), on the constants of a file a FLIR camera
wrote (exiftool's sample ``FLIR.jpg``, shipped with flirpy, read with flirpy's exiftool);
the Fresnel emissivity against an independent writing of Fresnel's equations (Snell's law,
complex amplitudes) and SciPy's quadrature; bad radiometry files."""

from __future__ import annotations

import json
import subprocess
from importlib.resources import files

import numpy as np
import pytest

from resection.errors import InputError
from selfillum.thermal.radiometry import (
    Emissivity,
    Planck,
    Radiometry,
    fresnel_emissivity,
    read_radiometry,
)


def _flir_meta() -> dict:
    """The tags of exiftool's FLIR sample, read by flirpy's own exiftool."""
    from flirpy.util.exiftool import Exiftool

    jpg = files("flirpy").joinpath("bin/t/images/FLIR.jpg")
    text = subprocess.run(["perl", Exiftool().path, str(jpg)], capture_output=True,
                          text=True, check=True).stdout
    meta = {}
    for line in text.splitlines():
        k, _, v = line.partition(":")
        meta[k.strip()] = v.strip()
    return meta


def test_planck_matches_flirpy_raw2temp():
    from flirpy.util.raw import raw2temp

    meta = _flir_meta()
    assert meta["Planck O"] == "-6646"  # FLIR's file, as exiftool reads it
    med, rng = float(meta["Raw Value Median"]), float(meta["Raw Value Range"])
    raw = np.linspace(med - rng / 2, med + rng / 2, 41)
    planck = Planck.from_exif(meta)
    for eps, t_refl in ((1.0, 20.0), (0.80, 20.0), (0.6, 45.0)):
        m = dict(meta, **{"Object Distance": "0", "Emissivity": str(eps),
                          "Reflected Apparent Temperature": str(t_refl)})
        ref = raw2temp(raw, m) + 273.15  # flirpy: Celsius
        rad = Radiometry(planck, Emissivity("constant", eps), t_refl + 273.15)
        ours = rad.temperature(raw)
        np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9)
    # and back: the black body's counts give its temperature
    T = np.linspace(260.0, 420.0, 17)
    np.testing.assert_allclose(planck.temperature(planck.radiance(T)), T, rtol=1e-12)


def _fresnel_independent(theta, n):
    """1 - unpolarised reflectance, from Snell's law and the amplitude coefficients."""
    ti = theta
    tt = np.arcsin(np.sin(ti) / n)
    rs = (np.cos(ti) - n * np.cos(tt)) / (np.cos(ti) + n * np.cos(tt))
    rp = (n * np.cos(ti) - np.cos(tt)) / (n * np.cos(ti) + np.cos(tt))
    return 1.0 - 0.5 * (rs**2 + rp**2)


def test_fresnel_emissivity_and_hemispherical():
    from scipy.integrate import quad

    n = 1.5
    th = np.radians(np.linspace(0.0, 89.0, 90))
    np.testing.assert_allclose(fresnel_emissivity(th, n), _fresnel_independent(th, n),
                               atol=1e-12)
    assert fresnel_emissivity(0.0, n) == pytest.approx(4 * n / (n + 1) ** 2, abs=1e-12)
    assert fresnel_emissivity(np.pi / 2, n) == pytest.approx(0.0, abs=1e-12)
    e = Emissivity("fresnel", float(fresnel_emissivity(0.0, n)), n=n)
    ref = quad(lambda t: 2 * _fresnel_independent(t, n) * np.cos(t) * np.sin(t), 0,
               np.pi / 2, limit=200)[0]
    assert e.hemispherical() == pytest.approx(ref, abs=1e-6)
    assert e.hemispherical() < e(0.0)  # it falls at grazing angles
    # from the view angle's cosine (as the run takes it), each model
    np.testing.assert_allclose(e.of_cosine(np.cos(th)), _fresnel_independent(th, n),
                               atol=1e-12)
    tab = Emissivity("table", 0.9, angles=(0.0, 60.0, 90.0), values=(0.9, 0.8, 0.2))
    np.testing.assert_allclose(tab.of_cosine([1.0, 0.5, np.cos(np.radians(75.0)), 0.0]),
                               [0.9, 0.8, 0.5, 0.2], atol=1e-12)
    assert Emissivity("constant", 0.7).of_cosine([0.2, 1.0]).tolist() == [0.7, 0.7]


def _write(tmp_path, d):
    p = tmp_path / "R.json"
    p.write_text(json.dumps(d))
    return p


GOOD = {"R": 620420.0, "B": 1374.5, "F": 1.35, "O": 6646.0, "emissivity": 0.9,
        "reflected_temperature": 295.0}


def test_read_radiometry_models(tmp_path):
    r = read_radiometry(_write(tmp_path, dict(GOOD, emissivity={"model": "fresnel",
                                                                "normal": 0.95})))
    assert r.emissivity.model == "fresnel"
    assert r.emissivity(0.0) == pytest.approx(0.95, abs=1e-12)  # n found from the normal
    r = read_radiometry(_write(tmp_path, dict(GOOD, emissivity={
        "model": "table", "angles_deg": [0, 60, 80, 90], "values": [0.95, 0.93, 0.8, 0.3]})))
    assert r.emissivity(np.radians(70.0)) == pytest.approx(0.865)
    exif = {"PlanckR1": 13799.269, "PlanckR2": 0.022241818, "PlanckB": 1374.5,
            "PlanckF": 1.35, "PlanckO": -6646, "emissivity": 0.9,
            "reflected_temperature": 295.0}
    r = read_radiometry(_write(tmp_path, exif))
    assert r.planck.O == 6646.0 and r.planck.R == pytest.approx(13799.269 / 0.022241818)


@pytest.mark.parametrize("change, words", [
    ({"B": None}, "missing the calibration constant B"),
    ({"emissivity": 1.2}, "emissivity 1.2 is outside (0, 1]"),
    ({"emissivity": 0}, "emissivity 0.0 is outside (0, 1]"),
    ({"emissivity": {"model": "fresnel", "normal": -0.1}}, "outside (0, 1]"),
    ({"reflected_temperature": -3.0}, "reflected_temperature -3.0 K is below 0 K"),
    ({"range_K": [-10, 400]}, "range_K -10.0 K is below 0 K"),
    ({"emissivity": {"model": "lambert"}}, "emissivity model 'lambert' unknown"),
])
def test_bad_radiometry_one_line(tmp_path, change, words):
    d = dict(GOOD)
    for k, v in change.items():
        if v is None:
            d.pop(k)
        else:
            d[k] = v
    p = _write(tmp_path, d)
    with pytest.raises(InputError) as ei:
        read_radiometry(p)
    msg = str(ei.value)
    assert str(p) in msg and words in msg and "\n" not in msg


def test_table_calibration_against_the_planck_form(tmp_path):
    """A table of a black body's counts every 5 K (as a calibration bench gives it),
    against the closed form it was sampled from (itself checked against flirpy above)."""
    T = np.arange(250.0, 500.1, 5.0)
    p = _write(tmp_path, {"table": {"temperature_K": list(T),
                                    "counts": [float(c) for c in PL_FORM.signal(T)]},
                          "O": PL_FORM.O, "emissivity": 0.9, "reflected_temperature": 295.0})
    rad = read_radiometry(p)
    Tq = np.linspace(251.0, 499.0, 997)
    np.testing.assert_allclose(rad.planck.temperature(PL_FORM.radiance(Tq)), Tq, atol=2e-3)
    np.testing.assert_allclose(rad.planck.radiance(Tq), PL_FORM.radiance(Tq), rtol=2e-4)
    assert np.isnan(rad.planck.temperature(PL_FORM.radiance(520.0)))  # no extrapolation
    ref = Radiometry(PL_FORM, Emissivity("constant", 0.9), 295.0)
    counts = PL_FORM.signal(np.array([300.0, 350.0, 420.0]))
    np.testing.assert_allclose(rad.temperature(counts), ref.temperature(counts), atol=2e-3)


PL_FORM = Planck(620420.0, 1374.5, 1.35, 6646.0)


@pytest.mark.parametrize("table, words", [
    ({"temperature_K": [300, 290], "counts": [1e4, 2e4]}, "must both increase"),
    ({"temperature_K": [300, 310], "counts": [1e4]}, "as many temperature_K as counts"),
    ({"temperature_K": [-1, 310], "counts": [1e4, 2e4]}, "-1.0 K is below 0 K"),
    ({"temperature_K": [300, 310], "counts": [1000, 2e4]}, "at or below O"),
])
def test_bad_table_one_line(tmp_path, table, words):
    p = _write(tmp_path, {"table": table, "O": 6646.0, "emissivity": 0.9,
                          "reflected_temperature": 295.0})
    with pytest.raises(InputError) as ei:
        read_radiometry(p)
    assert str(p) in str(ei.value) and words in str(ei.value)
