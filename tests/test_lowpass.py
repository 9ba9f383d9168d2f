"""uPSP's gaussian filter (``selfillum.unsteady.lowpass``) against SciPy's filters: the
frame with its NaN set to zero, filtered, over the same filter of the finite mask
(``scipy.ndimage.gaussian_filter``, reflected borders, truncated at the kernel's radius)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from selfillum.unsteady.lowpass import gaussian_lowpass, gaussian_sigma


def _scipy(img, size):
    sigma = gaussian_sigma(size)
    r = (size - 1) // 2
    fin = np.isfinite(img)
    num = ndimage.gaussian_filter(np.where(fin, img, 0.0), sigma, truncate=r / sigma)
    den = ndimage.gaussian_filter(fin.astype(float), sigma, truncate=r / sigma)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(fin, num / den, np.nan)


@pytest.mark.parametrize("shape,size,workers", [((120, 97), 5, None), ((37, 23), 3, 1),
                                                ((5, 9), 7, 2), ((64, 64), 9, 3),
                                                ((2, 300), 5, 2)])
def test_matches_scipy_with_nan_and_borders(shape, size, workers):
    rng = np.random.default_rng(size)
    img = rng.uniform(0.0, 4095.0, shape)
    img[rng.random(shape) < 0.07] = np.nan
    img[:3, :4] = np.nan  # a NaN corner: the reflected borders read it
    ours = gaussian_lowpass(img, size, workers=workers)
    ref = _scipy(img, size)
    assert np.array_equal(np.isnan(ours), np.isnan(ref))
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-9, equal_nan=True)


def test_opencv_sigma_and_a_flat_frame_unchanged():
    assert gaussian_sigma(5) == pytest.approx(1.1)
    assert gaussian_sigma(3) == pytest.approx(0.8)
    flat = np.full((40, 50), 1234.5)
    flat[10, 10] = np.nan
    out = gaussian_lowpass(flat, 5)
    assert np.isnan(out[10, 10])
    np.testing.assert_allclose(np.delete(out.ravel(), 10 * 50 + 10), 1234.5, rtol=1e-14)


@pytest.mark.parametrize("size", [2, 1, 4])
def test_even_or_small_size_refused(size):
    with pytest.raises(ValueError, match="odd number"):
        gaussian_lowpass(np.zeros((8, 8)), size)


@pytest.mark.parametrize("size,workers", [(5, 1), (3, 2), (9, None)])
def test_frames_without_nan_and_strips_far_from_one_match_scipy(size, workers):
    # strips of rows whose every value is finite take the shorter way (no mask to filter,
    # no division): a finite frame, and one NaN whose strip alone takes the general way
    rng = np.random.default_rng(size)
    img = rng.uniform(0.0, 4095.0, (150, 71))
    np.testing.assert_allclose(gaussian_lowpass(img, size, workers=workers),
                               _scipy(img, size), rtol=1e-12, atol=1e-9)
    img[100, 7] = np.nan
    ours = gaussian_lowpass(img, size, workers=workers)
    ref = _scipy(img, size)
    assert np.array_equal(np.isnan(ours), np.isnan(ref))
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-9, equal_nan=True)
    # the rows near the NaN renormalise their weights: they differ from the plain filter
    plain = _scipy(np.where(np.isnan(img), 0.0, img), size)
    assert np.abs(ours[99, 7:9] - plain[99, 7:9]).min() > 1.0


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32])
def test_integer_counts_read_as_they_are_into_a_given_buffer(dtype):
    """A video's counts (8, 12 or 16 bits) are filtered without a float copy of the frame,
    into the buffer given: the same as SciPy on the counts as floats; the buffer may not
    be the image, nor of another shape."""
    rng = np.random.default_rng(7)
    img = rng.integers(0, 255 if dtype == np.uint8 else 4096, (70, 130)).astype(dtype)
    buf = np.full(img.shape, np.nan)
    got = gaussian_lowpass(img, 5, workers=2, out=buf)
    assert got is buf
    np.testing.assert_allclose(got, _scipy(img.astype(np.float64), 5), rtol=1e-12)
    f = img.astype(np.float64)
    with pytest.raises(ValueError, match="out must be"):
        gaussian_lowpass(f, 5, out=f)
    with pytest.raises(ValueError, match="out must be"):
        gaussian_lowpass(f, 5, out=np.empty((70, 129)))
