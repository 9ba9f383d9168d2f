"""Local maxima above a threshold (resection.markers._peaks) against scipy's maximum filter."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from resection.markers import _peaks


@pytest.mark.parametrize("size", [3, 5, 7, 11])
@pytest.mark.parametrize("dense", [False, True])
def test_local_maxima_equal_maximum_filter(size, dense, monkeypatch):
    rng = np.random.default_rng(size)
    img = ndimage.gaussian_filter(rng.normal(size=(120, 97)), 1.5).astype(np.float32)
    img[40:43, 50:53] = img.max() + 1.0  # a plateau: every pixel of it is a maximum
    img[0, 0] = img.max() + 2.0  # on the border
    thr = float(np.quantile(img, 0.9))
    # force either branch (the cost model picks the dense one for such a small image)
    monkeypatch.setattr(_peaks, "_DENSE_RATIO", 0.0 if dense else 1e9)
    rows, cols = _peaks.local_maxima(img, size, thr)
    ref = (img == ndimage.maximum_filter(img, size=size, mode="nearest")) & (img > thr)
    rr, rc = np.nonzero(ref)
    assert len(rr) > 5
    np.testing.assert_array_equal(rows, rr)
    np.testing.assert_array_equal(cols, rc)


def test_local_maxima_none_above():
    rows, cols = _peaks.local_maxima(np.zeros((10, 10)), 3, 0.5)
    assert rows.size == 0 and cols.size == 0


@pytest.mark.parametrize("shape", [(41, 60), (300, 517), (1024, 64), (7, 9)])
@pytest.mark.parametrize("diameter,kind", [(3.0, "tophat"), (6.0, "cone"), (11.0, "tophat")])
def test_merit_equals_direct_correlation_of_the_mirrored_frame(shape, diameter, kind):
    # the detector's merit (two discrete cosine transforms) against SciPy's direct
    # correlation of the frame padded by NumPy's mirror symmetry (the (7, 9) frame is
    # smaller than the 11 px template: reflected more than once)
    from scipy.signal import correlate

    from resection.markers import _prep
    from resection.markers import detect as markers

    x = np.random.default_rng(1).normal(size=shape).astype(np.float32)
    tmpl = markers.marker_template(diameter, kind)
    ref = correlate(np.pad(x.astype(float), tmpl.shape[0] // 2, mode="symmetric"), tmpl,
                    mode="valid", method="direct")
    work = np.empty((shape[0], shape[1] + 3), np.float32)[:, :shape[1]]  # a strided buffer
    work[:] = x
    merit = _prep.merit(work, tmpl)
    assert merit.shape == ref.shape == shape
    assert np.abs(merit - ref).max() < 1e-5  # float32 rounding of a unit-noise image
