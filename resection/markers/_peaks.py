"""Local maxima of an image above a threshold. Internal module of the marker detector."""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy import ndimage

#: the dense maximum filter is used where the pixels above the threshold, times the
#: neighbourhood's size, exceed this many times the image's pixels (a thresholded texture)
_DENSE_RATIO = 50.0


@njit(cache=True, fastmath=True)
def _scan(image, threshold, r, limit):
    """Row-major scan: the pixels above ``threshold`` that are the maximum within ``r``
    (clipped), as ``(rows, cols, True)``; ``(.., .., False)`` once more than ``limit``
    pixels are above the threshold (the caller then takes the dense path)."""
    H, W = image.shape
    cap = 1024
    rows = np.empty(cap, np.int64)
    cols = np.empty(cap, np.int64)
    n = 0
    n_above = 0
    for i in range(H):
        row = image[i]
        for j0 in range(0, W, 16):  # blocks of 16 pixels: most are all under the threshold
            j1 = min(j0 + 16, W)
            top = row[j0]
            for j in range(j0 + 1, j1):  # (fastmath: a vectorised maximum; no NaN here)
                top = max(top, row[j])
            if not top > threshold:
                continue
            for j in range(j0, j1):
                v = row[j]
                if not v > threshold:
                    continue
                n_above += 1
                if n_above > limit:
                    return rows[:0], cols[:0], False
                # the 8 nearest neighbours first: most pixels above the threshold are on a
                # marker's slope and have a larger one among them
                is_max = True
                for a in range(max(i - 1, 0), min(i + 1, H - 1) + 1):
                    for b in range(max(j - 1, 0), min(j + 1, W - 1) + 1):
                        if image[a, b] > v:
                            is_max = False
                    if not is_max:
                        break
                if not is_max:
                    continue
                for a in range(max(i - r, 0), min(i + r, H - 1) + 1):
                    for b in range(max(j - r, 0), min(j + r, W - 1) + 1):
                        if image[a, b] > v:
                            is_max = False
                            break
                    if not is_max:
                        break
                if is_max:
                    if n == cap:
                        cap *= 2
                        rows2 = np.empty(cap, np.int64)
                        cols2 = np.empty(cap, np.int64)
                        rows2[:n] = rows[:n]
                        cols2[:n] = cols[:n]
                        rows, cols = rows2, cols2
                    rows[n] = i
                    cols[n] = j
                    n += 1
    return rows[:n], cols[:n], True


def local_maxima(image: np.ndarray, size: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels above ``threshold`` that are the maximum of their
    ``size`` x ``size`` neighbourhood (``size`` odd; clipped at the image border; ties all
    kept). Row-major order.

    The same set as ``(image == maximum_filter(image, size, mode="nearest")) &
    (image > threshold)``, found in one compiled scan that compares only the pixels above
    the threshold with their neighbours (stopping at the first larger one): on an image of
    markers these are a few per cent of the pixels, so the cost follows the markers, not the
    image. Where more pixels are above the threshold (their number times the neighbourhood's
    size over ``_DENSE_RATIO`` times the image's pixels: a thresholded texture), SciPy's
    maximum filter is used.
    """
    limit = int(_DENSE_RATIO * image.size / (size * size))
    # the threshold in the image's type, as NumPy compares a float32 image with a float
    rows, cols, sparse = _scan(image, image.dtype.type(threshold), size // 2, limit)
    if not sparse:
        peaks = image == ndimage.maximum_filter(image, size=size, mode="nearest")
        peaks &= image > threshold
        return np.nonzero(peaks)
    return rows, cols
