"""Local maxima of an image above a threshold. Internal module of the marker detector."""

from __future__ import annotations

import numpy as np
from numba import njit
from scipy import ndimage

#: the dense maximum filter is used where the pixels above the threshold, times the
#: neighbourhood's size, exceed this many times the image's pixels (a thresholded texture)
_DENSE_RATIO = 50.0


@njit(cache=True)
def _is_max(image, rows, cols, r):
    """True where ``image[rows[k], cols[k]]`` is >= every pixel within ``r`` (clipped)."""
    H, W = image.shape
    out = np.ones(rows.size, np.bool_)
    for k in range(rows.size):
        i, j = rows[k], cols[k]
        v = image[i, j]
        for a in range(max(i - r, 0), min(i + r, H - 1) + 1):
            for b in range(max(j - r, 0), min(j + r, W - 1) + 1):
                if image[a, b] > v:
                    out[k] = False
                    break
            if not out[k]:
                break
    return out


def local_maxima(image: np.ndarray, size: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels above ``threshold`` that are the maximum of their
    ``size`` x ``size`` neighbourhood (``size`` odd; clipped at the image border; ties all
    kept). Row-major order.

    The same set as ``(image == maximum_filter(image, size, mode="nearest")) &
    (image > threshold)``, found by comparing only the pixels above the threshold with their
    neighbours (a compiled loop that stops at the first larger neighbour): on an image of
    markers these are a few per cent of the pixels, so the cost follows the markers, not the
    image.
    """
    flat = np.flatnonzero(image > threshold)
    if flat.size * size * size > _DENSE_RATIO * image.size:
        peaks = image == ndimage.maximum_filter(image, size=size, mode="nearest")
        peaks &= image > threshold
        return np.nonzero(peaks)
    rows, cols = np.divmod(flat, image.shape[1])
    keep = _is_max(image, rows, cols, size // 2)  # any layout (the merit is strided)
    return rows[keep], cols[keep]
