"""The compiled windows and starts of the disk fit (resection.markers._starts) against the NumPy
expressions they replace, and its median against NumPy's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from resection.markers import _starts
from resection.markers.refine import _neighbours


def _reference(signal, bad, uv, strength, half, R0, near_r, min_dist):
    """Windows, weights and starts with NumPy (fancy indexing over all candidates)."""
    H, W = signal.shape
    n = len(uv)
    iu, iv = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    ar = np.arange(-half, half + 1)
    rows, cols = iv[:, None] + ar[None, :], iu[:, None] + ar[None, :]
    inside = ((rows >= 0) & (rows < H))[:, :, None] & ((cols >= 0) & (cols < W))[:, None, :]
    rc, cc = np.clip(rows, 0, H - 1), np.clip(cols, 0, W - 1)
    win = signal[rc[:, :, None], cc[:, None, :]]
    wbad = bad[rc[:, :, None], cc[:, None, :]] | ~inside
    win = np.where(wbad, 0.0, win)
    gu, gv = cols.astype(float), rows.astype(float)
    # pixels near another, separate and strong enough start
    near = np.zeros(win.shape, bool)
    for i, js in enumerate(cKDTree(uv).query_ball_point(uv, 2.0 * half + 1.0)):
        for j in js:
            if (j != i and np.hypot(*(uv[i] - uv[j])) >= min_dist
                    and strength[j] >= 0.3 * strength[i]):
                d2 = (gu[i][None, :] - uv[j, 0]) ** 2 + (gv[i][:, None] - uv[j, 1]) ** 2
                near[i] |= d2 < near_r**2
    rr = np.hypot(ar[None, :], ar[:, None])
    w = (~(wbad | near) & (rr <= half + 0.5)[None]).astype(float)
    ring = (rr > R0 + 1.5)[None] & ~wbad
    bg = np.array([np.median(win[k][ring[k]]) if ring[k].any() else 0.0 for k in range(n)])
    inner = (rr <= R0 + 1.0)[None] & ~wbad
    wc = np.clip(win - bg[:, None, None], 0, None) * inner
    sw = wc.sum(axis=(1, 2))
    cu = np.where(sw > 0, (wc * gu[:, None, :]).sum(axis=(1, 2)) / np.maximum(sw, 1e-300), iu)
    cv = np.where(sw > 0, (wc * gv[:, :, None]).sum(axis=(1, 2)) / np.maximum(sw, 1e-300), iv)
    s_in = (win * inner).sum(axis=(1, 2))
    n_in = inner.sum(axis=(1, 2))
    height = np.clip(s_in / np.maximum(n_in, 1) - bg, 1e-12, None)
    volume = np.clip((s_in - n_in * bg) / (np.pi * R0**2), 1e-12, None)
    disk = rr <= R0 + 0.5
    masked = (wbad & disk[None]).sum(axis=(1, 2)) / disk.sum()
    p0 = np.column_stack([cu - (iu - half), cv - (iv - half), np.full(n, R0), volume, bg,
                          np.zeros(n), np.zeros(n)])
    return win, w, p0, height, masked, w.sum(axis=(1, 2))


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.uint16])
def test_windows_equal_numpy(dtype):
    rng = np.random.default_rng(5)
    H, W, R0, half = 70, 90, 3.0, 9
    img = rng.normal(1000.0, 20.0, (H, W))
    yy, xx = np.mgrid[:H, :W]
    uv = np.array([[20.3, 30.6], [26.8, 33.1], [5.2, 4.9], [85.4, 64.6], [50.0, 40.0],
                   [44.6, 41.2]])
    for u, v in uv:
        img -= 300.0 * (np.hypot(xx - u, yy - v) <= R0)  # dark markers
    img = np.rint(img).astype(dtype)
    mask = rng.uniform(size=(H, W)) < 0.03
    mask[38:43, 48:52] = True  # part of a disk masked
    sat = 1060.0  # a few bright noise pixels saturated
    bad = mask | (img >= sat)
    signal = np.where(bad, 0.0, -img.astype(float) - 17.5)  # sign and fill level
    strength = np.array([10.0, 9.0, 5.0, 7.0, 1.0, 8.0])
    near_r, min_dist = R0 + 2.3, 1.5 * R0 + 1.0
    off, idx = _neighbours(uv, strength, 2.0 * half + 1.0, min_dist)
    iu, iv = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
    got = _starts.windows(img, mask, sat, -1.0, 17.5, iu, iv, np.arange(len(uv)), half, R0,
                          off, idx, uv, near_r)
    ref = _reference(signal, bad, uv, strength, half, R0, near_r, min_dist)
    assert ref[1].sum(axis=(1, 2)).min() > 0 and ref[4].max() > 0  # masks and borders hit
    # the neighbour of candidate 0 (candidate 1) is left out of its weights
    alone = _reference(signal, bad, uv, np.array([1.0, 0, 0, 0, 0, 0]), half, R0, near_r,
                       min_dist)
    assert (alone[1][0] - ref[1][0]).sum() > 10
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)


def test_median_equals_numpy():
    rng = np.random.default_rng(2)
    for n in (1, 2, 3, 4, 16, 17, 33, 250, 251, 1000):
        for x in (rng.normal(size=n), rng.integers(0, 5, n).astype(float), np.full(n, 2.0)):
            assert _starts._median(x.copy(), n) == np.median(x)
