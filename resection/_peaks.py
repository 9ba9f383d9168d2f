"""Local maxima of an image above a threshold. Internal module of the marker detector."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

#: at most this many (pixel, neighbour) comparisons (memory); more: the dense filter
_GATHER_BUDGET = 20_000_000
#: cost model, nanoseconds: the dense filter per image pixel; the comparisons per (pixel,
#: neighbour) and per neighbour offset (NumPy call overhead)
_DENSE_NS, _PAIR_NS, _OFFSET_NS = 25.0, 3.0, 6000.0


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
    gather = size * size * (_OFFSET_NS + _PAIR_NS * flat.size)
    if gather > _DENSE_NS * image.size or flat.size * size * size > _GATHER_BUDGET:
        peaks = image == ndimage.maximum_filter(image, size=size, mode="nearest")
        peaks &= image > threshold
        return np.nonzero(peaks)
    flat_img = image.ravel()
    rows, cols = np.divmod(flat, W)
    val = flat_img[flat]
    keep = np.ones(flat.size, bool)
    rr = [np.minimum(np.maximum(rows + dv, 0), H - 1) * W for dv in range(-r, r + 1)]
    cc = [np.minimum(np.maximum(cols + du, 0), W - 1) for du in range(-r, r + 1)]
    for a, ra in enumerate(rr):  # a loop over the size^2 offsets, batched over the pixels
        for b, cb in enumerate(cc):
            if a != r or b != r:
                keep &= flat_img[ra + cb] <= val
    return rows[keep], cols[keep]
