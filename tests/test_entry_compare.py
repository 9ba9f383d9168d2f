"""PSP against a Kulite, on a run whose answer is known in closed form: a tone of amplitude
A at every node plus independent white noise of standard deviation s per node, and the
Kulite the same tone sampled faster (an odd rate, so the resampling is exercised)."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from selfillum.entry.compare import agreement_band, compare_kulites, ring_nodes
from selfillum.entry.kulites import KuliteSeries


def test_agreement_band_exact():
    f = np.arange(10.0)
    a = np.ones(10)
    b = np.array([1, 1, 1.3, 1.1, 1.2, 1.25, 0.9, 2, 1, 1])  # 1 dB: ratio 0.794..1.259
    assert agreement_band(f, a, b) == (3.0, 6.0)  # DC left out; 1.3 and 2 break the runs
    assert np.isnan(agreement_band(f, a, 3 * a)[0])


def test_compare_closed_form(tmp_path):
    rng = np.random.default_rng(1)
    fps, T, f0, A, s = 2000.0, 1024, 250.0, 0.02, 0.01
    x, y = np.meshgrid(np.linspace(-0.1, 0.1, 41), np.linspace(-0.1, 0.1, 41))
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    n = 41
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    v0 = (j * n + i).ravel()
    tri = np.vstack([np.column_stack([v0, v0 + 1, v0 + n + 1]),
                     np.column_stack([v0, v0 + n + 1, v0 + n])])
    t = np.arange(T) / fps
    dcp = A * np.sin(2 * np.pi * f0 * t)[:, None] + s * rng.standard_normal((T, len(pts)))
    h5 = tmp_path / "unsteady.h5"
    with h5py.File(h5, "w") as f:
        f["grid/points"], f["grid/triangles"] = pts, tri
        f["frames/time"] = t
        f["dcp"] = dcp.astype(np.float32)
    rate, q, p0 = 7777.0, 600.0, 10.0
    tk = np.arange(int(T / fps * rate) + 20) / rate
    psi = p0 + A * np.sin(2 * np.pi * f0 * tk) * q / 144.0
    ks = KuliteSeries(("K01", "K09"), np.array([psi, psi]), rate)
    centre = np.array([0.0, 0.0, 0.0])
    (c,) = compare_kulites(h5, ks, {"K01": centre}, {"K01": 0.004}, q)
    ring = ring_nodes(pts, 0.005, centre, 0.004)
    np.testing.assert_array_equal(c.nodes, ring)
    M = len(ring)
    assert M >= 8
    # the closed form: the ring's average keeps the tone and s^2 / M of noise
    expect = np.sqrt(A ** 2 / 2 + s ** 2 / M) / np.sqrt(A ** 2 / 2)
    assert c.rms_ratio == pytest.approx(expect, rel=0.02)
    assert c.rms_kulite == pytest.approx(A / np.sqrt(2), rel=0.01)
    k = int(np.argmin(np.abs(c.f - f0)))
    assert abs(10 * np.log10(c.psd_psp[k] / c.psd_kulite[k])) < 0.5
    assert c.coherence[k] > 0.98
    assert c.band[0] <= f0 <= c.band[1]
    # the Kulite without a place is left out
    assert [x.name for x in compare_kulites(h5, ks, {"K01": centre}, {"K01": 0.004}, q)] \
        == ["K01"]
