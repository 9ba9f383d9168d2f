"""The compiled preparation of a frame for detection (resection.markers._prep.prepare) against the
NumPy expressions it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from resection.markers import _prep


def _reference(img, mask, saturation, sign):
    """The NumPy preparation: masked pixels, fill level, signal (float64): 0 at NaN,
    infinite and user-masked pixels, ``sign * saturation - fill`` at the other saturated
    ones."""
    x = img.astype(np.float64)
    void = ~np.isfinite(x)
    if mask is not None:
        void |= mask
    saturated = np.zeros(x.shape, bool)
    if saturation is not None:
        with np.errstate(invalid="ignore"):
            saturated = (x >= saturation) & ~void
    bad = void | saturated
    k = max(1, int(np.sqrt(img.size / 16_000)))
    sub_ok = ~bad[::k, ::k]
    fill = float(np.median(sign * x[::k, ::k][sub_ok]))
    signal = np.where(void, 0.0, np.where(saturated, sign * (saturation or 0.0) - fill,
                                          sign * x - fill))
    return signal, bad, fill


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.float32, np.float64,
                                   np.float16, ">u2"])
@pytest.mark.parametrize("sign", [-1.0, 1.0])
@pytest.mark.parametrize("with_mask", [False, True])
def test_prepare_equals_numpy(dtype, sign, with_mask):
    rng = np.random.default_rng(7)
    shape = (300, 257)
    dt = np.dtype(dtype)
    top = 250 if dt.itemsize == 1 else 3000
    img = rng.integers(0, top, shape).astype(dt)
    if dt.kind == "f":
        img = (img + rng.uniform(0, 1, shape)).astype(dt)
        img[5, 7], img[9, 1], img[200, 3] = np.nan, np.inf, -np.inf
    saturation = 240 if dt.itemsize == 1 else 2900
    mask = rng.uniform(size=shape) < 0.05 if with_mask else None
    work, bad, n_bad, fill = _prep.prepare(*_prep.native(img, mask), saturation, sign)
    ref, ref_bad, ref_fill = _reference(img, mask, saturation, sign)
    np.testing.assert_array_equal(bad, ref_bad)
    assert n_bad == ref_bad.sum() > 0
    assert fill == ref_fill
    assert work.dtype == np.float32
    # float32 is exact for integers under 2^24 and the half-integer fill; float frames
    # are rounded to float32 (relative 6e-8 of values under 4000)
    tol = 0.0 if dt.kind in "ui" else 4e-4
    assert np.abs(work - ref).max() <= tol
    assert work.strides[0] == 4 * (shape[1] + _prep._STRIDE_PAD)  # the padded row stride


def test_prepare_without_masked_pixels():
    img = np.arange(120 * 130, dtype=np.uint16).reshape(120, 130)
    work, bad, n_bad, fill = _prep.prepare(*_prep.native(img), np.inf, -1.0)
    assert bad is None and n_bad == 0
    ref, _, ref_fill = _reference(img, None, None, -1.0)
    assert fill == ref_fill
    np.testing.assert_array_equal(work, ref)


def test_prepare_fill_when_the_subsample_is_masked():
    # every pixel of the regular subsample masked: the fill level is the median of all
    # unmasked pixels
    img = np.full((400, 400), 1000, np.uint16)
    k = int(np.sqrt(img.size / 16_000))
    mask = np.zeros(img.shape, bool)
    mask[::k, ::k] = True
    img[1::2] = 3000
    work, bad, n_bad, fill = _prep.prepare(*_prep.native(img, mask), np.inf, 1.0)
    good = ~mask
    assert fill == np.median(img[good].astype(float))
    assert n_bad == mask.sum()
    np.testing.assert_array_equal(bad, mask)
    np.testing.assert_array_equal(work[good], img[good] - fill)
    assert np.all(work[mask] == 0)


def test_median_equals_numpy_and_noise_samples_equal_numpy():
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 10, 11, 1000, 50_001):
        x = rng.normal(size=n)
        assert _prep.median(x) == np.median(x)
        xi = rng.integers(0, 7, n).astype(float)  # ties
        assert _prep.median(xi) == np.median(xi)
    # the second differences of every k-th row and column against NumPy slicing
    img = rng.normal(100.0, 3.0, (61, 47))
    img[5, 7] = np.nan
    mask = rng.uniform(size=img.shape) < 0.05
    for k in (1, 4):
        d = _prep.second_differences(img, mask, k)
        bad = mask | ~np.isfinite(img)
        ref = []
        for x, b in ((img[::k], bad[::k]), (img[:, ::k].T, bad[:, ::k].T)):
            dd = x[:, :-2] - 2.0 * x[:, 1:-1] + x[:, 2:]
            ok = ~(b[:, :-2] | b[:, 1:-1] | b[:, 2:])
            ref.append(dd[ok])
        np.testing.assert_allclose(np.sort(d), np.sort(np.concatenate(ref)), rtol=0, atol=1e-12)
