"""Dark markers inside saturated glare: the pits of unsaturated pixels that saturation
encloses. Internal module of :func:`resection.markers.detect.detect_markers`.

Where glare saturates the paint around a dark marker, the marker's rim and its ring are
clipped and only the darkest part of its core, a few pixels, stays under the saturation
level: a small island of unsaturated pixels enclosed by saturated ones. The disk fit has
nothing to fit there (the edge that locates a marker is clipped), so such a marker is not a
sub-pixel candidate; it is reported apart, at the centroid of its island weighted by the
depth under saturation, a position good to a few tenths of a pixel.

Conventions: ``img[v, u]``, pixel ``(u, v)`` = (column, row), the centre of the top-left
pixel at (0, 0).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["saturated_pits"]


def saturated_pits(img: np.ndarray, mask: np.ndarray, sat: float, diameter: float,
                   min_depth: float) -> np.ndarray:
    """Centres of the islands of unsaturated pixels enclosed by saturated ones that may
    be dark markers.

    Parameters
    ----------
    img : (H, W) integer or float array
        The frame (dark markers darker than their surroundings).
    mask : (H, W) bool array, or (0, 0) for none
        User-masked pixels: neither saturated nor part of an island.
    sat : float
        Saturation level: pixels ``>= sat`` are saturated (``inf``: none).
    diameter : float
        Marker diameter, pixels: an island larger than the disk of radius
        ``diameter / 2 + 1`` is not a marker's core.
    min_depth : float
        The island's deepest pixel must lie at least this far under ``sat`` (image units).

    Returns
    -------
    (K, 2) float array
        ``(u, v)`` of each island: its centroid weighted by ``sat - img``.
    """
    empty = np.zeros((0, 2))
    if not math.isfinite(sat):
        return empty
    with np.errstate(invalid="ignore"):
        s = img >= sat
    if mask.shape == img.shape:
        s &= ~mask
    rows = np.flatnonzero(s.any(axis=1))
    if rows.size == 0:
        return empty
    cols = np.flatnonzero(s.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    box = img[r0:r1, c0:c1].astype(np.float64)
    free = ~s[r0:r1, c0:c1] & np.isfinite(box)
    if mask.shape == img.shape:
        free &= ~mask[r0:r1, c0:c1]
    labels, n = ndimage.label(free)
    if n == 0:
        return empty
    # islands: components that do not reach the box's edge are enclosed by saturation
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    idx = np.setdiff1d(np.arange(1, n + 1), edge)
    if idx.size == 0:
        return empty
    depth = np.where(free, sat - box, 0.0)
    area = ndimage.sum_labels(free, labels, idx)
    deepest = ndimage.maximum(depth, labels, idx)
    R = diameter / 2.0
    ok = (area <= math.pi * (R + 1.0) ** 2) & (deepest >= min_depth)
    idx = idx[ok]
    if idx.size == 0:
        return empty
    cm = np.array(ndimage.center_of_mass(depth, labels, idx), dtype=float).reshape(-1, 2)
    return np.column_stack([cm[:, 1] + c0, cm[:, 0] + r0])
