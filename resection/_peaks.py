"""Local maxima of an image above a threshold. Internal module of the marker detector."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: above this many (pixel, neighbour) comparisons the dense maximum filter is cheaper
_GATHER_BUDGET = 20_000_000


def local_maxima(image: np.ndarray, size: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels above ``threshold`` that are the maximum of their
    ``size`` x ``size`` neighbourhood (clipped at the image border; ties all kept).

    The same set as ``(image == maximum_filter(image, size, mode="nearest")) &
    (image > threshold)``, found by comparing only the pixels above the threshold with their
    neighbours: on an image of markers these are a few per cent of the pixels, so the cost
    follows the markers, not the image. Row-major order.
    """
    H, W = image.shape
    flat = np.flatnonzero(image > threshold)
    r = size // 2
    if flat.size * size * size > _GATHER_BUDGET:  # dense: a thresholded texture, huge markers
        peaks = (image == ndimage.maximum_filter(image, size=size, mode="nearest"))
        peaks &= image > threshold
        return np.nonzero(peaks)
    flat_img = image.ravel()
    rows, cols = np.divmod(flat, W)
    val = flat_img[flat]
    for dv in range(-r, r + 1):  # loop over the size^2 offsets, batched over the pixels
        rr = np.clip(rows + dv, 0, H - 1) * W
        keep = np.ones(rows.size, bool)
        for du in range(-r, r + 1):
            if dv or du:
                keep &= flat_img[rr + np.clip(cols + du, 0, W - 1)] <= val
        rows, cols, val = rows[keep], cols[keep], val[keep]  # survivors only
    return rows, cols
