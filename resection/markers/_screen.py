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

from resection.markers._starts import _median


@njit(cache=True, nogil=True)
def measure(img, bad, has_bad, pu, pv, R, r_in, r1, r2):  # pragma: no cover - compiled
    """Per candidate: ``contrast, clutter, size, elongation`` (float64 arrays; NaN where
    the ring has fewer than 8 valid pixels, and but the clutter where more than a tenth of
    the disk of radius ``R + 1.5`` is masked)."""
    n = pu.size
    H, W = img.shape
    half = int(math.ceil(r2))
    contrast = np.full(n, np.nan)
    clutter = np.full(n, np.nan)
    size = np.full(n, np.nan)
    elong = np.full(n, np.nan)
    buf = np.empty((2 * half + 1) ** 2)
    rm = R + 1.5
    for k in range(n):
        cu, cv = pu[k], pv[k]
        # plane through the ring: sums of the normal equations (x, y centred on the pixel)
        s0 = sx = sy = sxx = syy = sxy = sz = sxz = syz = 0.0
        for dv in range(-half, half + 1):
            v = cv + dv
            if v < 0 or v >= H:
                continue
            for du in range(-half, half + 1):
                u = cu + du
                if u < 0 or u >= W:
                    continue
                rr = math.sqrt(du * du + dv * dv)
                if rr < r1 or rr > r2:
                    continue
                if has_bad and bad[v, u]:
                    continue
                z = img[v, u]
                x, y = float(du), float(dv)
                s0 += 1.0
                sx += x
                sy += y
                sxx += x * x
                syy += y * y
                sxy += x * y
                sz += z
                sxz += x * z
                syz += y * z
        if s0 < 8.0:
            continue
        # solve [[s0 sx sy] [sx sxx sxy] [sy sxy syy]] (a, b, c) = (sz, sxz, syz)
        a11, a12, a13, a22, a23, a33 = s0, sx, sy, sxx, sxy, syy
        det = (a11 * (a22 * a33 - a23 * a23) - a12 * (a12 * a33 - a23 * a13)
               + a13 * (a12 * a23 - a22 * a13))
        if abs(det) < 1e-12:
            pa, pb, pc = sz / s0, 0.0, 0.0
        else:
            pa = (sz * (a22 * a33 - a23 * a23) - a12 * (sxz * a33 - a23 * syz)
                  + a13 * (sxz * a23 - a22 * syz)) / det
            pb = (a11 * (sxz * a33 - a23 * syz) - sz * (a12 * a33 - a23 * a13)
                  + a13 * (a12 * syz - sxz * a13)) / det
            pc = (a11 * (a22 * syz - sxz * a23) - a12 * (a12 * syz - sxz * a13)
                  + sz * (a12 * a23 - a22 * a13)) / det
        # the ring's residuals about the plane: robust spread; the core's mean height;
        # the moments of the positive height within R + 1.5
        m = 0
        ci = 0.0
        ni = 0
        m0 = mx = my = mxx = myy = mxy = 0.0
        nd = nbad = 0
        for dv in range(-half, half + 1):
            v = cv + dv
            if v < 0 or v >= H:
                continue
            for du in range(-half, half + 1):
                u = cu + du
                if u < 0 or u >= W:
                    continue
                rr = math.sqrt(du * du + dv * dv)
                if rr <= rm:
                    nd += 1
                if has_bad and bad[v, u]:
                    nbad += rr <= rm
                    continue
                x, y = float(du), float(dv)
                h = img[v, u] - (pa + pb * x + pc * y)
                if r1 <= rr <= r2:
                    buf[m] = h
                    m += 1
                if rr <= r_in:
                    ci += h
                    ni += 1
                if rr <= rm and h > 0.0:
                    m0 += h
                    mx += h * x
                    my += h * y
                    mxx += h * x * x
                    myy += h * y * y
                    mxy += h * x * y
        med = _median(buf, m)
        for i in range(m):
            buf[i] = abs(buf[i] - med)
        clutter[k] = 1.4826 * _median(buf, m)
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


def screen(img, bad, pu, pv, diameter: float, ideal_size: float, *, min_contrast: float,
           size_range=(0.5, 1.6), max_elongation: float = 3.5):
    """``(keep, measures)``: the candidates whose core contrast is at least
    ``min_contrast`` times the ring's clutter, whose size lies within ``size_range`` of
    ``ideal_size`` (that of the blurred disk of the expected diameter) and whose
    elongation is at most ``max_elongation``."""
    R, r_in, r1, r2 = radii(diameter)
    has_bad = bad is not None
    b = bad if has_bad else np.zeros((1, 1), np.bool_)
    c, s, z, e = measure(img, b, has_bad, np.ascontiguousarray(pu, np.int64),
                         np.ascontiguousarray(pv, np.int64), R, r_in, r1, r2)
    # a measure that cannot be made (a masked core, too few ring pixels) rejects nothing
    with np.errstate(invalid="ignore"):
        keep = (~(c < min_contrast * s) & ~(z < size_range[0] * ideal_size)
                & ~(z > size_range[1] * ideal_size) & ~(e > max_elongation))
    return keep, {"contrast": c, "clutter": s, "size": z, "elongation": e}
