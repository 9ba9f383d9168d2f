"""Windows, weights and starting values of the disk fit, one compiled pass over the
candidates. Internal module of :func:`resection.markers.refine.refine_markers`.

For each start (rounded to its pixel, the window's centre) the window of ``2 half + 1``
pixels a side is read straight from the frame, and:

* the weights: 1 inside the circle of radius ``half + 0.5``, 0 at masked pixels, outside
  the frame, and within ``near_r`` of a neighbouring candidate (so that close markers do not
  pull each other);
* the local background: the median of the window's pixels farther than ``R + 1.5`` from its
  centre (masked ones left out);
* the start of the centre: the centroid of the pixels within ``R + 1`` weighted by their
  height above that background; of the contrast: their volume above it over ``pi R^2``
  (their mean height is returned as well);
* the masked fraction of the disk of radius ``R + 0.5``.

Conventions: ``img[v, u]``; the window's rows are ``v = iv - half ... iv + half``, its
columns ``u = iu - half ... iu + half``; parameters in window coordinates (the centre of the
window's top-left pixel at (0, 0)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from resection.markers._prep import _is_bad


@njit(cache=True)
def _median(a, n):
    """Median of ``a[:n]`` (n > 0; the mean of the two middle values for even n), by
    quickselect in place (``a[:n]`` is reordered). The partitions are branch-free (a swap
    and a counter per value, no mispredicted jumps): two passes, values below the pivot,
    then equal to it (many ties in integer frames)."""
    k = n // 2
    lo, hi = 0, n
    m = 0.0
    while True:
        if hi - lo <= 16:  # a few values left: insertion sort
            for i in range(lo + 1, hi):
                v = a[i]
                j = i - 1
                while j >= lo and a[j] > v:
                    a[j + 1] = a[j]
                    j -= 1
                a[j + 1] = v
            m = a[k]
            break
        x, y, z = a[lo], a[(lo + hi) // 2], a[hi - 1]
        pivot = max(min(x, y), min(max(x, y), z))
        store = lo
        for i in range(lo, hi):
            v = a[i]
            a[i] = a[store]
            a[store] = v
            store += v < pivot
        if k < store:
            hi = store
            continue
        eq = store
        for i in range(store, hi):
            v = a[i]
            a[i] = a[eq]
            a[eq] = v
            eq += v <= pivot
        if k < eq:
            m = pivot
            break
        lo = eq
    if n % 2 == 1:
        return m
    below = a[0]  # the largest value left of k (all are <= a[k]): the other middle value
    for i in range(1, k):
        below = max(below, a[i])
    return 0.5 * (below + m)


@njit(cache=True)
def windows(img, mask, sat, sign, fill, iu, iv, sel, half, R0, nb_off, nb_idx, uv_all,
            near_r):
    """Windows, weights and starts of the candidates ``sel``.

    Parameters
    ----------
    img : (H, W) integer or float array
        Frame; the fitted signal is ``sign * img - fill`` (markers brighter than the
        background).
    mask : (H, W) bool array, or (0, 0) for none
        Masked pixels, besides NaN, infinite ones and those ``>= sat``.
    sat : float
        Saturation level of ``img`` (``inf``: none).
    sign, fill : float
    iu, iv : (n_all,) int arrays
        Window centres (the rounded starts) of every candidate.
    sel : (n,) int array
        Candidates to prepare.
    half : int
        Half-size of the window.
    R0 : float
        Expected radius, pixels.
    nb_off, nb_idx : int arrays
        Neighbours of candidate ``c``: ``nb_idx[nb_off[c]:nb_off[c + 1]]`` (CSR).
    uv_all : (n_all, 2) float array
        Starts of every candidate (the neighbours' positions).
    near_r : float
        Pixels closer than this to a neighbour get weight 0.

    Returns
    -------
    win, w : (n, 2 half + 1, 2 half + 1) float64 arrays
        Data (0 where masked or outside the frame) and weights.
    p0 : (n, 7) float64 array
        Starting parameters ``x, y, R, a, b, 0, 0`` (window coordinates).
    height : (n,) float64 array
        Mean height above the background of the pixels within ``R + 1`` (at least 1e-12).
    masked_fraction : (n,) float64 array
    n_weighted : (n,) float64 array
        Pixels of weight 1.
    """
    H, W = img.shape
    use_mask = mask.shape[0] == H and mask.shape[1] == W
    n = sel.size
    Wn = 2 * half + 1
    win = np.zeros((n, Wn, Wn))
    w = np.zeros((n, Wn, Wn))
    p0 = np.zeros((n, 7))
    masked_fraction = np.zeros(n)
    n_weighted = np.zeros(n)
    height = np.zeros(n)
    wbad = np.empty((Wn, Wn), np.bool_)
    ring = np.empty(Wn * Wn)
    # each pixel's class by its distance r from the window's centre: bit 1 r <= R + 1
    # (centroid), 2 r > R + 1.5 (background ring), 4 r <= half + 0.5 (weighted), 8
    # r <= R + 0.5 (disk)
    cls = np.zeros((Wn, Wn), np.int64)
    n_disk = 0
    for a in range(Wn):
        for b in range(Wn):
            r = math.sqrt(float((a - half) ** 2 + (b - half) ** 2))
            cls[a, b] = ((r <= R0 + 1.0) * 1 + (r > R0 + 1.5) * 2 + (r <= half + 0.5) * 4
                         + (r <= R0 + 0.5) * 8)
            n_disk += r <= R0 + 0.5
    near2 = near_r * near_r
    for k in range(n):
        c = sel[k]
        ox, oy = iu[c] - half, iv[c] - half
        # the window, masked pixels and the background ring
        n_ring = 0
        for a in range(Wn):
            row = oy + a
            for b in range(Wn):
                col = ox + b
                ok = 0 <= row < H and 0 <= col < W
                x = 0.0
                if ok:
                    x = float(img[row, col])
                    ok = not (_is_bad(x, sat) or (use_mask and mask[row, col]))
                if ok:
                    v = sign * x - fill
                    wbad[a, b] = False
                    win[k, a, b] = v
                    if cls[a, b] & 2:
                        ring[n_ring] = v
                        n_ring += 1
                else:
                    wbad[a, b] = True
        bg = _median(ring, n_ring) if n_ring > 0 else 0.0
        # weights: inside the circle, not masked, not near another candidate
        s_w = 0.0
        s_u = 0.0
        s_v = 0.0
        s_in = 0.0
        n_in = 0
        n_masked = 0
        nb0, nb1 = nb_off[c], nb_off[c + 1]
        for a in range(Wn):
            for b in range(Wn):
                q = cls[a, b]
                if wbad[a, b]:
                    n_masked += (q & 8) > 0
                    continue
                if q & 1:  # the centroid's pixels
                    v = win[k, a, b]
                    s_in += v
                    n_in += 1
                    if v > bg:
                        s_w += v - bg
                        s_u += (v - bg) * (ox + b)
                        s_v += (v - bg) * (oy + a)
                if not q & 4:
                    continue
                near = False
                for j in range(nb0, nb1):
                    du = ox + b - uv_all[nb_idx[j], 0]
                    dv = oy + a - uv_all[nb_idx[j], 1]
                    if du * du + dv * dv < near2:
                        near = True
                        break
                if not near:
                    w[k, a, b] = 1.0
                    n_weighted[k] += 1.0
        if s_w > 0.0:
            cu, cv = s_u / s_w, s_v / s_w
        else:
            cu, cv = float(iu[c]), float(iv[c])
        height[k] = max(s_in / max(n_in, 1) - bg, 1e-12)
        p0[k, 0] = cu - ox
        p0[k, 1] = cv - oy
        p0[k, 2] = R0
        # the contrast: the volume above the background over the disk's area (the blur
        # and the pixels keep the volume, nearly all of it within R + 1)
        p0[k, 3] = max((s_in - n_in * bg) / (math.pi * R0 * R0), 1e-12)
        p0[k, 4] = bg
        masked_fraction[k] = n_masked / n_disk
    return win, w, p0, height, masked_fraction, n_weighted
