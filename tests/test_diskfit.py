"""The compiled disk-model fit (resection.markers._diskfit) against independent references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from resection.markers import _diskfit, _diskmodel


def _model(x0, y0, R, blur, W, R_nodes=None):
    """The compiled model, with the quadrature size of radius ``R_nodes`` (default R)."""
    q = _diskfit.n_nodes(R if R_nodes is None else R_nodes, blur)
    sizes, sn, cs, wc = _diskfit.node_table(q + 8)
    k = int(np.searchsorted(sizes, q))
    M = np.empty((W, W, 4))
    _diskfit._model(x0, y0, R, *_diskfit.edge_table(blur), sn[k], cs[k], wc[k], sizes[k], M,
                    np.empty((W + 1, 3)), np.empty((W + 1, 3)))
    return M


@pytest.mark.parametrize("radius,blur,x0,y0", [(3.2, 0.8, 10.3, 9.77), (1.5, 0.5, 10.0, 10.45),
                                               (4.6, 0.3, 9.61, 10.2)])
def test_model_matches_brute_force_supersampling(radius, blur, x0, y0):
    # independent reference: 64x64 point-sampled disk per pixel, Gaussian filter, box average
    S, W = 64, 21
    c = (np.arange(W * S) + 0.5) / S - 0.5
    X, Y = np.meshgrid(c, c)
    disk = ((X - x0) ** 2 + (Y - y0) ** 2 <= radius**2).astype(float)
    ref = gaussian_filter(disk, blur * S, mode="constant", truncate=6).reshape(W, S, W, S)
    ref = ref.mean(axis=(1, 3))
    M = _model(x0, y0, radius, blur, W)
    # the supersampling errs by ~0.08 / S at sharp edges (1.2e-3 at S = 64, blur 0.3)
    assert np.abs(M[..., 0] - ref).max() < 2e-3
    assert M[..., 0].sum() == pytest.approx(np.pi * radius**2, rel=1e-5)


@pytest.mark.parametrize("radius,blur", [(3.1, 0.6), (1.2, 0.2), (6.5, 1.1)])
def test_model_derivatives_match_finite_differences(radius, blur):
    W, x0, y0, e = 25, 12.27, 11.62, 1e-4
    M = _model(x0, y0, radius, blur, W)
    fd = [_model(x0 + dx, y0 + dy, radius + dr, blur, W, radius)
          - _model(x0 - dx, y0 - dy, radius - dr, blur, W, radius)
          for dx, dy, dr in ((e, 0, 0), (0, e, 0), (0, 0, e))]
    for k in range(3):
        d = fd[k][..., 0] / (2 * e)
        assert np.abs(M[..., k + 1] - d).max() < 1e-5 * max(1.0, np.abs(d).max())
    # and the closed-form batch model of _diskmodel (many more quadrature nodes)
    ar = np.arange(W, dtype=float)
    ref, dref = _diskmodel.windows([x0], [y0], [radius], blur, ar, ar, 512, jacobian=True)
    assert np.abs(M[..., 0] - ref[0]).max() < 2e-5
    for k in range(3):
        assert np.abs(M[..., k + 1] - dref[k][0]).max() < 1e-4


def _windows(n, R, blur, snr, rng, W=19):
    ar = np.arange(W, dtype=float)
    c = (W - 1) / 2
    x0, y0 = c + rng.uniform(-0.5, 0.5, n), c + rng.uniform(-0.5, 0.5, n)
    img = _diskmodel.windows(x0, y0, np.full(n, R), blur, ar, ar, 256)
    a, b = 100.0, 1000.0
    win = b + a * img + (rng.normal(0, a / snr, img.shape) if snr else 0.0)
    p0 = np.column_stack([x0 + rng.normal(0, 0.3, n), y0 + rng.normal(0, 0.3, n),
                          np.full(n, R * 1.1), np.full(n, 0.8 * a), np.full(n, b + 5),
                          np.zeros(n), np.zeros(n)])
    return win, p0, x0, y0


def _fit(win, p0, blur, tol=1e-4):
    p, cost, _ = _diskfit.fit_windows(win, np.ones_like(win), p0, *_diskfit.edge_table(blur),
                                      0.3, 12.0, 30, tol,
                                      *_diskfit.node_table(_diskfit.n_nodes(12.0, blur)))
    return p, cost


def test_fit_recovers_noiseless_disks_exactly():
    rng = np.random.default_rng(3)
    win, p0, x0, y0 = _windows(40, 3.0, 0.6, None, rng)
    p, cost = _fit(win, p0, 0.6)
    assert np.abs(p[:, 0] - x0).max() < 1e-4
    assert np.abs(p[:, 1] - y0).max() < 1e-4
    assert np.abs(p[:, 2] - 3.0).max() < 1e-3
    assert np.abs(p[:, 3] - 100.0).max() < 0.05


def test_fit_reaches_the_cramer_rao_bound():
    # 400 noisy windows at SNR 20: RMS error per coordinate within sampling noise of the
    # bound of the same model (5 unknowns), computed independently from _diskmodel
    from resection.markers.detect import position_crb

    rng = np.random.default_rng(4)
    win, p0, x0, y0 = _windows(400, 3.0, 0.6, 20.0, rng)
    p, _ = _fit(win, p0, 0.6)
    rms = np.sqrt(np.mean(np.concatenate([p[:, 0] - x0, p[:, 1] - y0]) ** 2))
    crb = position_crb(6.0, 0.6, 100.0, 5.0, half=9)
    # 800 samples: the RMS is within about 5 % of its expectation (2.5 sigma: 12 %); the
    # fit also estimates the background's two slopes (a few per cent above the bound)
    assert 0.85 * crb < rms < 1.2 * crb


def test_fit_without_contrast_at_the_start_converges():
    # a start with no contrast (a = 0: the centre and radius have no gradient) on a steep
    # background: the linear parameters are solved first, then the disk; the noiseless
    # windows are fitted to the stopping rule's tolerance (1e-4 px a step, the centres within
    # a few 1e-4 px), with no step running off the window (the first step of the centre was
    # thousands of pixels before)
    rng = np.random.default_rng(6)
    win, p0, x0, y0 = _windows(20, 2.8, 0.6, None, rng)
    W = win.shape[1]
    vv, uu = np.mgrid[0:W, 0:W] - (W - 1) / 2
    win = win + 6.0 * uu - 4.0 * vv  # 6 and -4 counts a pixel along u and v
    p0[:, 3] = 1e-12
    p, cost = _fit(win, p0, 0.6)
    assert np.abs(p[:, 0] - x0).max() < 1e-3 and np.abs(p[:, 1] - y0).max() < 1e-3
    assert np.abs(p[:, 3] - 100.0).max() < 0.1
    assert np.abs(p[:, 5] - 6.0).max() < 1e-3 and np.abs(p[:, 6] + 4.0).max() < 1e-3
