"""Cheap screening of marker candidates before the disk fit: contrast against the local
clutter, size and shape from image moments, one compiled pass over the candidates.
Internal module of :func:`resection.markers.detect_markers`.

On real paint most local maxima of the merit are not markers: the speckle of the paint
(a grain of 1-3 px and a contrast of 5-15 %), the silhouette of the model, glare. Each such
candidate would cost a full disk fit (tens of model evaluations when the fit does not
converge). The screen measures, for every candidate, in a window around its pixel:

* the local background: a plane fitted by least squares to the ring ``r1 <= r <= r2``
  (the merit template's ring), masked pixels left out;
* the *clutter*: the robust standard deviation (1.4826 times the median absolute
  deviation) of the ring's pixels about that plane: the paint's speckle, the noise, and the
  model's edge where the ring crosses it;
* the *contrast*: the mean height above the plane of the pixels within ``r_in`` of the
  centre (the marker's core);
* the *moments* of the height above the plane (its positive part) within ``R + 1.5``:
  the size ``sqrt(l1 + l2)`` and the elongation ``sqrt(l1 / l2)`` from the eigenvalues
  ``l1 >= l2`` of the second central moments.

A marker has a contrast of several times the clutter, the size of a blurred disk of its
diameter, and an elongation near 1 (up to about 3 for a disk seen at 70 degrees); a
speckle grain has the contrast of the clutter, an edge of the model a large clutter and
an elongated shape.

Conventions: ``img[v, u]``, candidates at integer pixels ``(pu, pv)`` of ``img``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from resection.markers._prep import _is_bad
from resection.markers._starts import _median


@njit(cache=True, nogil=True)
def _plane(x, y, z, n, keep):
    """Least-squares plane ``(a, b, c)``, ``z = a + b x + c y``, through the points
    ``i < n`` where ``keep[i]``; NaN for ``a`` with fewer than 3 points."""
    s0 = sx = sy = sxx = syy = sxy = sz = sxz = syz = 0.0
    for i in range(n):
        if not keep[i]:
            continue
        xi, yi, zi = x[i], y[i], z[i]
        s0 += 1.0
        sx += xi
        sy += yi
        sxx += xi * xi
        syy += yi * yi
        sxy += xi * yi
        sz += zi
        sxz += xi * zi
        syz += yi * zi
    if s0 < 3.0:
        return math.nan, 0.0, 0.0
    # solve [[s0 sx sy] [sx sxx sxy] [sy sxy syy]] (a, b, c) = (sz, sxz, syz)
    a11, a12, a13, a22, a23, a33 = s0, sx, sy, sxx, sxy, syy
    det = (a11 * (a22 * a33 - a23 * a23) - a12 * (a12 * a33 - a23 * a13)
           + a13 * (a12 * a23 - a22 * a13))
    if abs(det) < 1e-9 * s0 * s0 * s0:  # the points on a line: a level only
        return sz / s0, 0.0, 0.0
    pa = (sz * (a22 * a33 - a23 * a23) - a12 * (sxz * a33 - a23 * syz)
          + a13 * (sxz * a23 - a22 * syz)) / det
    pb = (a11 * (sxz * a33 - a23 * syz) - sz * (a12 * a33 - a23 * a13)
          + a13 * (a12 * syz - sxz * a13)) / det
    pc = (a11 * (a22 * syz - sxz * a23) - a12 * (a12 * syz - sxz * a13)
          + sz * (a12 * a23 - a22 * a13)) / det
    return pa, pb, pc


@njit(cache=True, nogil=True)
def _spread(x, y, z, n, pa, pb, pc, res, tmp):
    """Median and robust spread (1.4826 MAD) of the residuals of the points ``i < n``
    about the plane; the residuals are left in ``res``."""
    for i in range(n):
        res[i] = z[i] - (pa + pb * x[i] + pc * y[i])
        tmp[i] = res[i]
    med = _median(tmp, n)
    for i in range(n):
        tmp[i] = abs(res[i] - med)
    return med, 1.4826 * _median(tmp, n)


@njit(cache=True, nogil=True)
def measure(img, mask, sat, sign, pu, pv, R, r_in, r1, r2):  # pragma: no cover - compiled
    """Per candidate: ``contrast, clutter, size, elongation`` (float64 arrays; NaN where
    the ring has fewer than 8 valid pixels, and all but the clutter where more than a
    tenth of the disk of radius ``R + 1.5`` is masked).

    The pixels are read from the frame ``img`` itself (any integer or float type): the
    signal is ``sign * img``; masked are the pixels where ``mask`` (bool, of the frame's
    shape, or (0, 0) for none) is True, NaN, infinite or ``>= sat``."""
    n = pu.size
    H, W = img.shape
    use_mask = mask.shape[0] == H and mask.shape[1] == W
    half = int(math.ceil(r2))
    rm = R + 1.5
    # the window's offsets, by class: the ring (r1 <= r <= r2) and the disk of the
    # moments (r <= R + 1.5; the core r <= r_in inside it)
    ring_u = np.empty((2 * half + 1) ** 2, np.int64)
    ring_v = np.empty_like(ring_u)
    in_u = np.empty_like(ring_u)
    in_v = np.empty_like(ring_u)
    in_core = np.empty(ring_u.size, np.bool_)
    n_ring = n_in = 0
    for dv in range(-half, half + 1):
        for du in range(-half, half + 1):
            rr = math.sqrt(du * du + dv * dv)
            if r1 <= rr <= r2:
                ring_u[n_ring], ring_v[n_ring] = du, dv
                n_ring += 1
            if rr <= rm:
                in_u[n_in], in_v[n_in] = du, dv
                in_core[n_in] = rr <= r_in
                n_in += 1
    contrast = np.full(n, np.nan)
    clutter = np.full(n, np.nan)
    size = np.full(n, np.nan)
    elong = np.full(n, np.nan)
    bx = np.empty(n_ring)
    by = np.empty(n_ring)
    bz = np.empty(n_ring)
    res = np.empty(n_ring)
    tmp = np.empty(n_ring)
    keep = np.ones(n_ring, np.bool_)
    for k in range(n):
        cu, cv = pu[k], pv[k]
        # the ring's valid pixels (x, y centred on the candidate's pixel)
        m = 0
        for i in range(n_ring):
            u, v = cu + ring_u[i], cv + ring_v[i]
            if u < 0 or u >= W or v < 0 or v >= H:
                continue
            x = float(img[v, u])
            if _is_bad(x, sat) or (use_mask and mask[v, u]):
                continue
            bx[m], by[m], bz[m] = ring_u[i], ring_v[i], sign * x
            m += 1
        if m < 8:
            continue
        # the local background: a plane through the ring, fitted again without the pixels
        # more than 3 spreads from the first fit (a neighbouring marker or tap in the
        # ring would tilt it); the clutter: the ring's robust spread about it
        for i in range(m):
            keep[i] = True
        pa, pb, pc = _plane(bx, by, bz, m, keep)
        med, s = _spread(bx, by, bz, m, pa, pb, pc, res, tmp)
        if s > 0.0:
            n_keep = 0
            for i in range(m):
                keep[i] = abs(res[i] - med) <= 3.0 * s
                n_keep += keep[i]
            if n_keep < m and n_keep >= 8:
                pa, pb, pc = _plane(bx, by, bz, m, keep)
                med, s = _spread(bx, by, bz, m, pa, pb, pc, res, tmp)
        clutter[k] = s
        # the core's mean height above the plane; the moments of the positive height
        ci = 0.0
        ni = 0
        m0 = mx = my = mxx = myy = mxy = 0.0
        nd = nbad = 0
        for i in range(n_in):
            du, dv = in_u[i], in_v[i]
            u, v = cu + du, cv + dv
            if u < 0 or u >= W or v < 0 or v >= H:
                continue
            nd += 1
            x = float(img[v, u])
            if _is_bad(x, sat) or (use_mask and mask[v, u]):
                nbad += 1
                continue
            xf, yf = float(du), float(dv)
            h = sign * x - (pa + pb * xf + pc * yf)
            if in_core[i]:
                ci += h
                ni += 1
            if h > 0.0:
                m0 += h
                mx += h * xf
                my += h * yf
                mxx += h * xf * xf
                myy += h * yf * yf
                mxy += h * xf * yf
        if nbad > 0.1 * nd:  # a masked core (saturated): not judged here
            continue
        if ni > 0:
            contrast[k] = ci / ni
        if m0 > 0.0:
            cx, cy = mx / m0, my / m0
            ixx = mxx / m0 - cx * cx
            iyy = myy / m0 - cy * cy
            ixy = mxy / m0 - cx * cy
            tr = ixx + iyy
            dd = math.sqrt(max((ixx - iyy) ** 2 + 4.0 * ixy * ixy, 0.0))
            l1, l2 = 0.5 * (tr + dd), 0.5 * (tr - dd)
            size[k] = math.sqrt(max(tr, 0.0))
            elong[k] = math.sqrt(l1 / l2) if l2 > 1e-12 else np.inf
    return contrast, clutter, size, elong


def radii(diameter: float) -> tuple[float, float, float, float]:
    """``R, r_in, r1, r2`` for a marker of ``diameter`` px: the core and the merit
    template's ring (see :func:`resection.markers.marker_template`)."""
    R = diameter / 2.0
    return R, max(R - 0.5, 1.0), R + 1.0, R + 1.0 + max(2.0, R)


def screen(img, mask, sat: float, sign: float, pu, pv, diameter: float, ideal_size: float,
           *, min_contrast: float, size_range=(0.5, 1.6), max_elongation: float = 3.5):
    """``(keep, measures)``: the candidates whose core contrast is at least
    ``min_contrast`` times the ring's clutter, whose size lies within ``size_range`` of
    ``ideal_size`` (that of the blurred disk of the expected diameter) and whose
    elongation is at most ``max_elongation``.

    ``img`` is the frame (any type of :func:`resection.markers._prep.native`), read as
    ``sign * img`` (markers brighter than their surroundings); ``mask`` a bool array of its
    shape or (0, 0) for none; pixels ``>= sat`` (and NaN, infinite ones) are masked."""
    R, r_in, r1, r2 = radii(diameter)
    c, s, z, e = measure(img, mask, float(sat), float(sign),
                         np.ascontiguousarray(pu, np.int64),
                         np.ascontiguousarray(pv, np.int64), R, r_in, r1, r2)
    # a measure that cannot be made (a masked core, too few ring pixels) rejects nothing
    with np.errstate(invalid="ignore"):
        keep = (~(c < min_contrast * s) & ~(z < size_range[0] * ideal_size)
                & ~(z > size_range[1] * ideal_size) & ~(e > max_elongation))
    return keep, {"contrast": c, "clutter": s, "size": z, "elongation": e}
