"""Levenberg-Marquardt fit of the blurred, pixel-integrated *elliptical* marker model to many
windows: a round marker seen obliquely.

Internal module of :func:`resection.markers.refine.refine_markers` (``shape="ellipse"``),
used by the tracker. A round marker on a surface seen at an angle images as an ellipse; the
disk model of :mod:`resection.markers._diskfit` does not fit one: on a 35 px marker seen at
an aspect of 0.6 its fit took a median of 31 model evaluations a window (2 on a disk) and
left the centre 0.08 px off (median; 0.3 px at worst) where this model takes a few and
leaves it at the noise.

The model. The ellipse's vertical chords: the chord at ``x = x0 + X sin θ`` is centred at
``y0 + k X sin θ`` (the midpoints of an ellipse's parallel chords lie on a line, the
conjugate diameter) and has the half-length ``H cos θ``. ``X`` is the half-width, ``H`` the
half-height of the middle chord and ``k`` the slope of the conjugate diameter: any ellipse,
the disk being ``X = H = R, k = 0`` (where this model equals the disk model). With a
Gaussian PSF of standard deviation ``s`` and square pixels, a pixel's value is

    I(u, v) = ∫ g(u - x) [C(v - yc(x) + h(x)) - C(v - yc(x) - h(x))] dx

(``g`` the pixel-integrated Gaussian, ``C`` its antiderivative: the closed form along the
chord), the integral in ``x`` by Gauss-Legendre quadrature in ``θ`` (``dx = X cos θ dθ``).
The nodes ``±θ`` no longer share their chords (their centres differ by the shear), so each
node's term is added alone, over the few columns within ``0.5 + 5 s`` of its chord (the
disk kernel's pairs run over every column between their two chords).

Parameters of a window (window coordinates: the centre of the top-left pixel at (0, 0)):
``x, y`` centre, ``X``, ``H``, ``k`` the shape, ``a`` contrast, ``b`` background, ``bu, bv``
slopes of the background along ``u`` and ``v`` (per pixel, from the window's centre).
The tables (edge profile, nodes), the damped solve and the stopping rule are
:mod:`resection.markers._diskfit`'s.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from resection.markers._diskfit import _Q_MIN, _Q_PER_R, _ZC, _basis, _solve_damped

NP = 9  # parameters of a window
KMAX = 8.0  # bound of the shear |k| (a chord's centre moves 8 px a pixel: edge-on)


@njit(cache=True, fastmath=True)
def _model(x0, y0, X, H, k, tab, T, h, sn, cs, wc, Q, M, sA, sB):
    """Unit-contrast ellipse image and its derivatives, in place: ``M[j, i] = (image,
    d/dx0, d/dy0, d/dX, d/dH, d/dk)`` at row ``j``, column ``i`` (``M`` is (W, W, 6)).
    ``sA`` and ``sB`` are (W + 1, 3) scratch arrays."""
    W = M.shape[0]
    M.fill(0.0)
    step = int(round(1.0 / h))  # table steps a pixel (1 / h is a whole number)
    for q in range(Q):
        sq, cq, wq = sn[q], cs[q], wc[q]
        xq = x0 + X * sq
        yc = y0 + k * X * sq
        hq = H * cq
        i0 = max(int(math.ceil(xq - T)), 0)
        i1 = min(int(math.floor(xq + T)), W - 1)
        j0 = max(int(math.ceil(yc - hq - T)), 0)
        j1 = min(int(math.floor(yc + hq + T)), W - 1)
        if i1 < i0 or j1 < j0:
            continue
        Xw = X * wq
        # columns: X w g(u - xq), its derivative in x0, and in X (through the weight and
        # the chord's place); one pixel apart, a whole number of table steps
        kp, p0, p1, p2, p3 = _basis(T, h, i0 - xq)
        for c in range(i1 - i0 + 1):
            g = dg = 0.0
            t = i0 + c - xq
            if -T < t < T:
                a = kp + c * step
                g = p0 * tab[a, 1] + p1 * tab[a + 1, 1] + p2 * tab[a, 2] + p3 * tab[a + 1, 2]
                dg = p0 * tab[a, 2] + p1 * tab[a + 1, 2] + p2 * tab[a, 3] + p3 * tab[a + 1, 3]
            sA[c, 0] = g * Xw
            sA[c, 1] = -dg * Xw
            sA[c, 2] = g * wq - dg * sq * Xw
        # rows: B = C(v - yc + hq) - C(v - yc - hq), dB/dyc and dB/dhq times cos θ
        kp, p0, p1, p2, p3 = _basis(T, h, j0 - yc + hq)
        km, m0, m1, m2, m3 = _basis(T, h, j0 - yc - hq)
        for r in range(j1 - j0 + 1):
            t = j0 + r - yc
            if t + hq >= T and t - hq <= -T:  # a row inside the chord
                sB[r, 0], sB[r, 1], sB[r, 2] = 1.0, 0.0, 0.0
                continue
            Cp = gp = Cm = gm = 0.0
            if t + hq >= T:
                Cp = 1.0
            elif t + hq > -T:
                a = kp + r * step
                Cp = p0 * tab[a, 0] + p1 * tab[a + 1, 0] + p2 * tab[a, 1] + p3 * tab[a + 1, 1]
                gp = p0 * tab[a, 1] + p1 * tab[a + 1, 1] + p2 * tab[a, 2] + p3 * tab[a + 1, 2]
            if t - hq >= T:
                Cm = 1.0
            elif t - hq > -T:
                a = km + r * step
                Cm = m0 * tab[a, 0] + m1 * tab[a + 1, 0] + m2 * tab[a, 1] + m3 * tab[a + 1, 1]
                gm = m0 * tab[a, 1] + m1 * tab[a + 1, 1] + m2 * tab[a, 2] + m3 * tab[a + 1, 2]
            sB[r, 0] = Cp - Cm
            sB[r, 1] = gm - gp
            sB[r, 2] = (gp + gm) * cq
        ks, Xs = k * sq, X * sq  # d yc / dX and d yc / dk
        for r in range(j1 - j0 + 1):
            j = j0 + r
            B, By, BH = sB[r, 0], sB[r, 1], sB[r, 2]
            for c in range(i1 - i0 + 1):
                i = i0 + c
                A = sA[c, 0]
                P = By * A
                M[j, i, 0] += B * A
                M[j, i, 1] += B * sA[c, 1]
                M[j, i, 2] += P
                M[j, i, 3] += B * sA[c, 2] + ks * P
                M[j, i, 4] += BH * A
                M[j, i, 5] += Xs * P


@njit(cache=True)
def _reach(X, H, k):
    """Half-width and half-height of the ellipse's bounding box (pixels)."""
    return X, math.sqrt(H * H + k * k * X * X)


@njit(cache=True)
def _normal(win, w, p, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJ, JTr, J):
    """Weighted cost of parameters ``p`` on one window, with ``J^T J`` (9, 9) and ``J^T r``
    (9,) (``r = data - model``); ``J`` is a (9,) scratch array."""
    W = win.shape[0]
    x0, y0, X, H, k = p[0], p[1], p[2], p[3], p[4]
    a, b, bu, bv = p[5], p[6], p[7], p[8]
    rx, ry = _reach(X, H, k)
    s = max((T - 0.5) / _ZC, 0.3)
    need = math.ceil(_Q_PER_R * max(rx, ry, 0.5) / s + _Q_MIN)
    q = 0
    while q < sizes.size - 1 and sizes[q] < need:
        q += 1
    _model(x0, y0, X, H, k, tab, T, h, sn[q], cs[q], wc[q], sizes[q], M, sA, sB)
    i0 = max(int(math.ceil(x0 - rx - T)), 0)
    i1 = min(int(math.floor(x0 + rx + T)), W - 1)
    j0 = max(int(math.ceil(y0 - ry - T)), 0)
    j1 = min(int(math.floor(y0 + ry + T)), W - 1)
    c = (W - 1) / 2.0
    JTJ.fill(0.0)
    JTr.fill(0.0)
    cost = 0.0
    for j in range(W):
        dv = j - c
        inside_row = j0 <= j <= j1
        for i in range(W):
            wt = w[j, i]
            if wt == 0.0:
                continue
            du = i - c
            J[6], J[7], J[8] = wt, du * wt, dv * wt
            if inside_row and i0 <= i <= i1:
                m = M[j, i, 0]
                r = (win[j, i] - (a * m + b + bu * du + bv * dv)) * wt
                aw = a * wt
                for n in range(5):
                    J[n] = aw * M[j, i, n + 1]
                J[5] = m * wt
                for n in range(NP):
                    JTr[n] += J[n] * r
                    for l in range(n + 1):
                        JTJ[n, l] += J[n] * J[l]
            else:  # background only: the last three columns of J
                r = (win[j, i] - (b + bu * du + bv * dv)) * wt
                for n in range(6, NP):
                    JTr[n] += J[n] * r
                    for l in range(6, n + 1):
                        JTJ[n, l] += J[n] * J[l]
            cost += r * r
    for n in range(NP):
        for l in range(n):
            JTJ[l, n] = JTJ[n, l]
    return cost


@njit(cache=True)
def _clamp(pt, rmin, rmax):
    pt[2] = min(max(pt[2], rmin), rmax)
    pt[3] = min(max(pt[3], rmin), rmax)
    pt[4] = min(max(pt[4], -KMAX), KMAX)


@njit(cache=True)
def fit_windows(win, w, p0, tab, T, h, rmin, rmax, iterations, tol, sizes, sn, cs, wc):
    """Levenberg-Marquardt fit of every window to the elliptical model.

    Parameters
    ----------
    win, w : (n, W, W) float arrays
        Data and weights (0 for pixels left out), window coordinates.
    p0 : (n, 9) float array
        Starting parameters ``x, y, X, H, k, a, b, bu, bv`` (window coordinates).
    tab, T, h : the edge profile, from :func:`resection.markers._diskfit.edge_table`.
    rmin, rmax : float
        Bounds of ``X`` and ``H`` (pixels).
    iterations, tol :
        As :func:`resection.markers._diskfit.fit_windows` (the stopping rule on the
        centre's step).
    sizes, sn, cs, wc : arrays from :func:`resection.markers._diskfit.node_table`.

    Returns
    -------
    p : (n, 9) array
    cost : (n,) array
        Weighted sum of squared residuals.
    evaluations : (n,) int array
        Model evaluations a window.
    """
    n, W = win.shape[0], win.shape[1]
    p = p0.copy()
    cost = np.empty(n)
    nev = np.zeros(n, np.int64)
    M = np.empty((W, W, 6))
    sA = np.empty((W + 1, 3))
    sB = np.empty((W + 1, 3))
    JTJ = np.empty((NP, NP))
    JTr = np.empty(NP)
    JTJt = np.empty((NP, NP))
    JTrt = np.empty(NP)
    J = np.empty(NP)
    step = np.empty(NP)
    pt = np.empty(NP)
    for c in range(n):
        pc = p[c]
        ww = w[c]
        wn = win[c]
        cc = _normal(wn, ww, pc, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJ, JTr, J)
        last = 0.0
        lam = 1e-3
        nev[c] = 1
        if iterations > 0:
            # the linear parameters first where they change the contrast by more than half
            # (see the disk fit)
            step.fill(0.0)
            if (_solve_damped(JTJ[5:, 5:], JTr[5:], 0.0, step[5:]) and pc[5] + step[5] > 0
                    and not abs(step[5]) <= 0.5 * pc[5]):
                for q in range(NP):
                    pt[q] = pc[q] + step[q]
                cc = _normal(wn, ww, pt, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJ, JTr, J)
                nev[c] += 1
                for q in range(NP):
                    pc[q] = pt[q]
        for _ in range(iterations):
            _solve_damped(JTJ, JTr, lam, step)
            for q in range(NP):
                pt[q] = pc[q] + step[q]
            _clamp(pt, rmin, rmax)
            finite = True
            for q in range(NP):
                finite = finite and math.isfinite(pt[q])
            if not finite:
                break
            d = max(abs(step[0]), abs(step[1]))
            left = d * min(1.0, d / last) if last > 0.0 else d
            if lam <= 1e-2 and left < tol:
                for q in range(NP):
                    pc[q] = pt[q]
                break
            ct = _normal(wn, ww, pt, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJt, JTrt, J)
            nev[c] += 1
            better = ct < cc
            if better:
                cc = ct
                for q in range(NP):
                    pc[q] = pt[q]
                    JTr[q] = JTrt[q]
                    for qq in range(NP):
                        JTJ[q, qq] = JTJt[q, qq]
                lam = max(lam * 0.3, 1e-9)
                last = d
            else:
                lam = min(lam * 10.0, 1e9)
            small = d < tol and (better or lam < 1e2)
            if small or lam >= 1e9 or not math.isfinite(ct):
                break
        cost[c] = cc
    return p, cost, nev
