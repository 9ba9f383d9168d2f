"""Levenberg-Marquardt fit of the blurred, pixel-integrated disk model to many windows.

Internal module of the marker detector (:func:`resection.markers.detect.refine_markers`). The model
is the one of :mod:`resection.markers._diskmodel` (same quadrature in θ, same closed form along the
other axis), evaluated by a compiled (numba) kernel one window at a time:

* the 1-D edge profile (the pixel-integrated Gaussian ``g``, its antiderivative and
  derivatives) is tabulated once per PSF and read by cubic Hermite interpolation (1e-7
  of the contrast) instead of calling ``erf`` and ``exp`` at every pixel edge; a pixel
  is a whole number of table steps, so the interpolation weights are computed once per
  chord end, not per pixel;
* each quadrature node touches only the pixels within ``5 s + 0.5`` of its chord
  (``Phi(-5)`` is 3e-7 of the contrast): a small rectangle, not the whole window; the
  nodes ``±θ`` share their row factors;
* the Jacobian is never stored: the normal equations ``J^T J`` (7 x 7) and ``J^T r`` are
  accumulated pixel by pixel in scalars (the pixels the disk does not reach touch only the
  background's three columns) and solved by a Cholesky factorisation;
* the quadrature size follows the current radius, ``3 R / s + 8`` nodes (under 1e-5 of the
  contrast, against ~1e-2 for the noise of an SNR-100 image);
* a Gauss-Newton step whose error left in the centre (its size times its ratio to the
  step before) is under ``tol`` ends the iterations without one more evaluation: from the
  starts of :mod:`resection.markers._starts` (the contrast from the marker's volume), 2 or 3
  evaluations a marker (3.5 from the former starts with a bare step-size rule).

The result agrees with :func:`resection.markers._diskmodel.windows` to ~1e-7
(tests/test_diskfit.py).

Parameters of a window (window coordinates: the centre of the top-left pixel at (0, 0)):
``x, y`` centre, ``R`` radius, ``a`` contrast, ``b`` background, ``bu, bv`` slopes of the
background along ``u`` and ``v`` (per pixel, from the window's centre).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit
from scipy.special import erfc, roots_legendre

NP = 7  # parameters of a window
_ZC = 5.0  # support of the PSF edge, in standard deviations (Phi(-5) = 3e-7)
_Q_PER_R, _Q_MIN = 3.0, 8.0  # quadrature size: _Q_PER_R R / s + _Q_MIN nodes


def _levels(q_max: int) -> list[int]:
    """Quadrature sizes on offer: 16, then steps of about 12 %, up to ``q_max``."""
    out = [16]
    while out[-1] < q_max:
        out.append(min(max(out[-1] + 4, int(out[-1] * 1.125) // 4 * 4), q_max))
    return out


@lru_cache(maxsize=8)
def node_table(q_max: int):
    """Gauss-Legendre nodes of θ on [-π/2, π/2] for a ladder of sizes up to ``q_max``.

    Returns ``(sizes, sin θ, cos θ, weight · cos θ)``: ``sizes`` (L,) int, the others
    (L, q_max), row ``k`` holding the ``sizes[k]`` nodes of that size (the rest zero)."""
    sizes = np.array(_levels(max(int(q_max), 16)), dtype=np.int64)
    L, q = sizes.size, int(sizes[-1])
    sn, cs, wc = np.zeros((L, q)), np.zeros((L, q)), np.zeros((L, q))
    for k, m in enumerate(sizes):
        # SciPy's roots (Newton's iterations from asymptotic starts) agree with NumPy's
        # leggauss (a companion matrix's eigenvalues) to 1e-16 in the nodes and 5e-14 in
        # the weights, in 0.1 s instead of 0.25 s for the tracker's 36 sizes up to 733
        x, w = roots_legendre(int(m))
        th, w = x * (np.pi / 2), w * (np.pi / 2)
        sn[k, :m], cs[k, :m], wc[k, :m] = np.sin(th), np.cos(th), w * np.cos(th)
    for a in (sizes, sn, cs, wc):
        a.setflags(write=False)
    return sizes, sn, cs, wc


def n_nodes(radius: float, blur: float) -> int:
    """Quadrature size for a disk of ``radius`` under a PSF of ``blur`` (pixels): about
    1e-5 of the contrast (``_diskmodel.default_nodes`` without its margin)."""
    return int(np.ceil(4.0 * max(radius, 0.5) / max(blur, 0.3) + 8.0))


@lru_cache(maxsize=16)
def edge_table(blur: float) -> tuple[np.ndarray, float, float]:
    """The 1-D pixel-integrated Gaussian ``g`` of standard deviation ``blur`` (pixels),
    tabulated for cubic Hermite interpolation.

    Returns ``(table, T, h)``: ``table[k] = (C, g, dg/dt, d2g/dt2)`` at ``t = -T + k h``,
    ``C`` the antiderivative of ``g`` (0 at ``-inf``, 1 at ``+inf``); ``T = 0.5 + 5 blur``,
    beyond which ``g`` is taken as zero (3e-7); ``h = 1 / max(32, ceil(16 / blur))`` (at most
    ``blur / 16`` and ``1 / 32``, a whole number of steps a pixel). The interpolation
    error, about ``h^4 / 384`` times the fourth derivative, is under 1e-7 for ``dg/dt`` at
    ``blur = 0.6``.
    """
    s = max(float(blur), 1e-3)
    T = 0.5 + _ZC * s
    h = 1.0 / max(32, int(np.ceil(16.0 / s)))  # at most s / 16 and 1 / 32; 1 / h whole
    K = int(np.ceil(2.0 * T / h)) + 2
    t = -T + h * np.arange(K)
    zp, zm = (t + 0.5) / s, (t - 0.5) / s
    Pp, Pm = 0.5 * erfc(-zp / np.sqrt(2.0)), 0.5 * erfc(-zm / np.sqrt(2.0))
    pp = np.exp(-0.5 * zp * zp) / np.sqrt(2.0 * np.pi)
    pm = np.exp(-0.5 * zm * zm) / np.sqrt(2.0 * np.pi)
    C = s * ((zp * Pp + pp) - (zm * Pm + pm))
    g = Pp - Pm
    g1 = (pp - pm) / s
    g2 = (-zp * pp + zm * pm) / s**2
    table = np.ascontiguousarray(np.column_stack([C, g, g1, g2]))
    table.setflags(write=False)
    return table, float(T), float(h)


@njit(cache=True)
def _basis(T, h, t):
    """Cubic Hermite interpolation at ``t`` in the table of :func:`edge_table`: the index
    ``k`` (``t = -T + (k + f) h``, ``0 <= f < 1``; negative left of the table) and the
    weights of ``tab[k, c]``, ``tab[k + 1, c]``, ``tab[k, c + 1]``, ``tab[k + 1, c + 1]``
    (the value of channel ``c``, whose derivative is channel ``c + 1``). The same weights
    serve ``t + m`` at index ``k + m / h`` for whole ``m``."""
    x = (t + T) / h
    k = math.floor(x)
    f = x - k
    f2 = f * f
    f3 = f2 * f
    h00 = 2.0 * f3 - 3.0 * f2 + 1.0
    return int(k), h00, 1.0 - h00, (f3 - 2.0 * f2 + f) * h, (f3 - f2) * h


@njit(cache=True, fastmath=True)
def chord_rows(tab, T, h, step, j0, n, yc, hq, cq, sB):
    """The row factors of one quadrature node's chord, centred at ``yc`` with the
    half-length ``hq``, for the ``n`` rows from ``j0``, in place in ``sB`` (n, 3): ``B =
    C(v - yc + hq) - C(v - yc - hq)``, its derivative in ``yc`` and in ``hq`` times
    ``cq`` (the chord's half-length over the radius). ``step``: table steps a pixel. Rows
    wholly inside the chord get exactly ``(1, 0, 0)``. Shared by the disk's and the
    ellipse's models."""
    kp, p0, p1, p2, p3 = _basis(T, h, j0 - yc + hq)
    km, m0, m1, m2, m3 = _basis(T, h, j0 - yc - hq)
    for k in range(n):
        t = j0 + k - yc
        if t + hq >= T and t - hq <= -T:  # a row inside the chord
            sB[k, 0], sB[k, 1], sB[k, 2] = 1.0, 0.0, 0.0
            continue
        Cp = gp = Cm = gm = 0.0
        if t + hq >= T:
            Cp = 1.0
        elif t + hq > -T:
            a = kp + k * step
            Cp = p0 * tab[a, 0] + p1 * tab[a + 1, 0] + p2 * tab[a, 1] + p3 * tab[a + 1, 1]
            gp = p0 * tab[a, 1] + p1 * tab[a + 1, 1] + p2 * tab[a, 2] + p3 * tab[a + 1, 2]
        if t - hq >= T:
            Cm = 1.0
        elif t - hq > -T:
            a = km + k * step
            Cm = m0 * tab[a, 0] + m1 * tab[a + 1, 0] + m2 * tab[a, 1] + m3 * tab[a + 1, 1]
            gm = m0 * tab[a, 1] + m1 * tab[a + 1, 1] + m2 * tab[a, 2] + m3 * tab[a + 1, 2]
        sB[k, 0] = Cp - Cm
        sB[k, 1] = gm - gp
        sB[k, 2] = (gp + gm) * cq


@njit(cache=True, fastmath=True)
def _model(x0, y0, R, tab, T, h, sn, cs, wc, Q, M, sA, sB):
    """Unit-contrast disk image and its derivatives in x0, y0, R, in place:
    ``M[j, i] = (image, d/dx0, d/dy0, d/dR)`` at row ``j``, column ``i`` (``M`` is
    (W, W, 4)). ``sA`` and ``sB`` are (W + 1, 3) scratch arrays.

    The nodes come in pairs ``±θ`` (Gauss-Legendre is symmetric): the two chords of a pair
    have the same half-length, so they share the row factors, and their column factors
    are added before the product."""
    W = M.shape[0]
    M.fill(0.0)
    step = int(round(1.0 / h))  # table steps a pixel (1 / h is a whole number)
    for q in range((Q + 1) // 2):
        sq, cq, wq = abs(sn[q]), cs[q], wc[q]
        if 2 * q + 1 == Q:  # the middle node of an odd size: counted once
            wq *= 0.5
        xp = x0 + R * sq
        xm = x0 - R * sq
        hq = R * cq
        i0 = max(int(math.ceil(xm - T)), 0)
        i1 = min(int(math.floor(xp + T)), W - 1)
        j0 = max(int(math.ceil(y0 - hq - T)), 0)
        j1 = min(int(math.floor(y0 + hq + T)), W - 1)
        if i1 < i0 or j1 < j0:
            continue
        Rw = R * wq
        # columns: A = (g(u - x+) + g(u - x-)) R w and its derivatives in x0 and R; the
        # columns are one pixel apart, a whole number of table steps: the interpolation
        # weights of each chord end are computed once
        kp, p0, p1, p2, p3 = _basis(T, h, i0 - xp)
        km, m0, m1, m2, m3 = _basis(T, h, i0 - xm)
        for k in range(i1 - i0 + 1):
            gp = dgp = gm = dgm = 0.0
            tp = i0 + k - xp
            if -T < tp < T:
                a = kp + k * step
                gp = p0 * tab[a, 1] + p1 * tab[a + 1, 1] + p2 * tab[a, 2] + p3 * tab[a + 1, 2]
                dgp = p0 * tab[a, 2] + p1 * tab[a + 1, 2] + p2 * tab[a, 3] + p3 * tab[a + 1, 3]
            tm = i0 + k - xm
            if -T < tm < T:
                a = km + k * step
                gm = m0 * tab[a, 1] + m1 * tab[a + 1, 1] + m2 * tab[a, 2] + m3 * tab[a + 1, 2]
                dgm = m0 * tab[a, 2] + m1 * tab[a + 1, 2] + m2 * tab[a, 3] + m3 * tab[a + 1, 3]
            sA[k, 0] = (gp + gm) * Rw
            sA[k, 1] = -(dgp + dgm) * Rw
            sA[k, 2] = (gp + gm) * wq - (dgp - dgm) * sq * Rw
        # rows: B = C(v - y0 + h) - C(v - y0 - h) and its derivatives in y0 and R
        chord_rows(tab, T, h, step, j0, j1 - j0 + 1, y0, hq, cq, sB)
        # the pair's term of the quadrature: products of the row and column factors
        for k in range(j1 - j0 + 1):
            j = j0 + k
            B, By, BR = sB[k, 0], sB[k, 1], sB[k, 2]
            for kk in range(i1 - i0 + 1):
                i = i0 + kk
                A = sA[kk, 0]
                M[j, i, 0] += B * A
                M[j, i, 1] += B * sA[kk, 1]
                M[j, i, 2] += By * A
                M[j, i, 3] += BR * A + B * sA[kk, 2]


@njit(cache=True)
def _normal(win, w, p, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJ, JTr):
    """Weighted cost of parameters ``p`` on one window, with ``J^T J`` and ``J^T r``
    (``r = data - model``) accumulated into ``JTJ`` (7, 7) and ``JTr`` (7,)."""
    W = win.shape[0]
    x0, y0, R, a, b, bu, bv = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    need = math.ceil(_Q_PER_R * max(R, 0.5) / max((T - 0.5) / _ZC, 0.3) + _Q_MIN)
    k = 0
    while k < sizes.size - 1 and sizes[k] < need:
        k += 1
    _model(x0, y0, R, tab, T, h, sn[k], cs[k], wc[k], sizes[k], M, sA, sB)
    # the disk's image is zero outside [i0, i1] x [j0, i1]: only the background there
    i0 = max(int(math.ceil(x0 - R - T)), 0)
    i1 = min(int(math.floor(x0 + R + T)), W - 1)
    j0 = max(int(math.ceil(y0 - R - T)), 0)
    j1 = min(int(math.floor(y0 + R + T)), W - 1)
    c = (W - 1) / 2.0
    # the sums of J^T J (lower triangle) and J^T r in scalars (registers, not memory)
    s00 = s10 = s11 = s20 = s21 = s22 = s30 = s31 = s32 = s33 = 0.0
    s40 = s41 = s42 = s43 = s50 = s51 = s52 = s53 = s60 = s61 = s62 = s63 = 0.0
    s44 = s54 = s55 = s64 = s65 = s66 = 0.0
    r0 = r1 = r2 = r3 = r4 = r5 = r6 = 0.0
    cost = 0.0
    for j in range(W):
        dv = j - c
        inside_row = j0 <= j <= j1
        for i in range(W):
            wt = w[j, i]
            if wt == 0.0:
                continue
            du = i - c
            w4, w5, w6 = wt, du * wt, dv * wt
            if inside_row and i0 <= i <= i1:
                m = M[j, i, 0]
                r = (win[j, i] - (a * m + b + bu * du + bv * dv)) * wt
                J0 = a * M[j, i, 1] * wt
                J1 = a * M[j, i, 2] * wt
                J2 = a * M[j, i, 3] * wt
                J3 = m * wt
                r0 += J0 * r
                r1 += J1 * r
                r2 += J2 * r
                r3 += J3 * r
                s00 += J0 * J0
                s10 += J1 * J0
                s11 += J1 * J1
                s20 += J2 * J0
                s21 += J2 * J1
                s22 += J2 * J2
                s30 += J3 * J0
                s31 += J3 * J1
                s32 += J3 * J2
                s33 += J3 * J3
                s40 += w4 * J0
                s41 += w4 * J1
                s42 += w4 * J2
                s43 += w4 * J3
                s50 += w5 * J0
                s51 += w5 * J1
                s52 += w5 * J2
                s53 += w5 * J3
                s60 += w6 * J0
                s61 += w6 * J1
                s62 += w6 * J2
                s63 += w6 * J3
            else:  # background only: the last three columns of J
                r = (win[j, i] - (b + bu * du + bv * dv)) * wt
            r4 += w4 * r
            r5 += w5 * r
            r6 += w6 * r
            s44 += w4 * w4
            s54 += w5 * w4
            s55 += w5 * w5
            s64 += w6 * w4
            s65 += w6 * w5
            s66 += w6 * w6
            cost += r * r
    JTJ[0, 0], JTJ[1, 0], JTJ[1, 1], JTJ[2, 0], JTJ[2, 1], JTJ[2, 2] = s00, s10, s11, s20, s21, s22
    JTJ[3, 0], JTJ[3, 1], JTJ[3, 2], JTJ[3, 3] = s30, s31, s32, s33
    JTJ[4, 0], JTJ[4, 1], JTJ[4, 2], JTJ[4, 3], JTJ[4, 4] = s40, s41, s42, s43, s44
    JTJ[5, 0], JTJ[5, 1], JTJ[5, 2], JTJ[5, 3], JTJ[5, 4], JTJ[5, 5] = s50, s51, s52, s53, s54, s55
    JTJ[6, 0], JTJ[6, 1], JTJ[6, 2], JTJ[6, 3] = s60, s61, s62, s63
    JTJ[6, 4], JTJ[6, 5], JTJ[6, 6] = s64, s65, s66
    JTr[0], JTr[1], JTr[2], JTr[3], JTr[4], JTr[5], JTr[6] = r0, r1, r2, r3, r4, r5, r6
    for kk in range(NP):
        for ll in range(kk):
            JTJ[ll, kk] = JTJ[kk, ll]
    return cost


@njit(cache=True)
def _solve_damped(JTJ, JTr, lam, step):
    """``step`` = solution of ``(J^T J + lam (diag + 1e-12)) step = J^T r`` by Cholesky;
    False (step zero) where the damped matrix is not positive definite."""
    n = JTJ.shape[0]
    L = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            v = JTJ[i, j]
            if i == j:
                v += lam * (JTJ[i, i] + 1e-12)
            for k in range(j):
                v -= L[i, k] * L[j, k]
            if i == j:
                if not (v > 0.0):
                    step.fill(0.0)
                    return False
                L[i, i] = math.sqrt(v)
            else:
                L[i, j] = v / L[j, j]
    y = np.empty(n)
    for i in range(n):
        v = JTr[i]
        for k in range(i):
            v -= L[i, k] * y[k]
        y[i] = v / L[i, i]
    for i in range(n - 1, -1, -1):
        v = y[i]
        for k in range(i + 1, n):
            v -= L[k, i] * step[k]
        step[i] = v / L[i, i]
    return True


@njit(cache=True, nogil=True)
def fit_windows(win, w, p0, tab, T, h, rmin, rmax, iterations, tol, sizes, sn, cs, wc):
    """Levenberg-Marquardt fit of every window.

    Parameters
    ----------
    win, w : (n, W, W) float arrays
        Data and weights (0 for pixels left out), window coordinates.
    p0 : (n, 7) float array
        Starting parameters ``x, y, R, a, b, bu, bv`` (window coordinates).
    tab, T, h : the edge profile, from :func:`edge_table`.
    rmin, rmax : float
        Bounds of the radius.
    iterations : int
        Maximum iterations a window.
    tol : float
        Convergence: the error a step of the centre leaves is under ``tol`` pixels (not
        forced small by the damping). The error it leaves is taken as the step itself
        times its ratio to the previous step (the contraction of the iterations; the
        first step: the step itself).
    sizes, sn, cs, wc : arrays from :func:`node_table`.

    Returns
    -------
    p : (n, 7) array
    cost : (n,) array
        Weighted sum of squared residuals.
    evaluations : (n,) int array
        Model evaluations a window.
    """
    n, W = win.shape[0], win.shape[1]
    p = p0.copy()
    cost = np.empty(n)
    nev = np.zeros(n, np.int64)
    M = np.empty((W, W, 4))
    sA = np.empty((W + 1, 3))
    sB = np.empty((W + 1, 3))
    JTJ = np.empty((NP, NP))
    JTr = np.empty(NP)
    JTJt = np.empty((NP, NP))
    JTrt = np.empty(NP)
    step = np.empty(NP)
    pt = np.empty(NP)
    for c in range(n):
        pc = p[c]
        ww = w[c]
        wn = win[c]
        cc = _normal(wn, ww, pc, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJ, JTr)
        last = 0.0  # the last step taken (centre, pixels); 0: none yet
        lam = 1e-3
        nev[c] = 1
        if iterations > 0:
            # a start far off in contrast (the volume above the ring's median, biased on a
            # steep background, the more so with the ring partly masked; none at all: the
            # centre and radius have no gradient, their step is unbounded): the linear
            # parameters (contrast, background, slopes) are solved first with the disk held
            # where it starts, when they change the contrast by more than half (a 4 x 4
            # solve, no model evaluation, decides)
            step.fill(0.0)
            if (_solve_damped(JTJ[3:, 3:], JTr[3:], 0.0, step[3:]) and pc[3] + step[3] > 0
                    and not abs(step[3]) <= 0.5 * pc[3]):
                for k in range(NP):
                    pt[k] = pc[k] + step[k]
                ct = _normal(wn, ww, pt, tab, T, h, sizes, sn, cs, wc, M, sA, sB, JTJ, JTr)
                nev[c] += 1
                cc = ct
                for k in range(NP):
                    pc[k] = pt[k]
        for _ in range(iterations):
            _solve_damped(JTJ, JTr, lam, step)
            for k in range(NP):
                pt[k] = pc[k] + step[k]
            pt[2] = min(max(pt[2], rmin), rmax)
            finite = True
            for k in range(NP):
                finite = finite and math.isfinite(pt[k])
            if not finite:
                break
            d = max(abs(step[0]), abs(step[1]))
            left = d * min(1.0, d / last) if last > 0.0 else d  # the error it leaves
            if lam <= 1e-2 and left < tol:
                # converged: a Gauss-Newton step (hardly damped) that leaves an error under
                # the tolerance is taken without evaluating the model once more (from a
                # start within 0.1 px the second step is ~20 times smaller than the first)
                for k in range(NP):
                    pc[k] = pt[k]
                break
            ct = _normal(wn, ww, pt, tab, T, h, sizes, sn, cs, wc, M, sA, sB,
                         JTJt, JTrt)
            nev[c] += 1
            better = ct < cc
            if better:
                cc = ct
                for k in range(NP):
                    pc[k] = pt[k]
                    JTr[k] = JTrt[k]
                    for kk in range(NP):
                        JTJ[k, kk] = JTJt[k, kk]
                lam = max(lam * 0.3, 1e-9)
                last = d
            else:
                lam = min(lam * 10.0, 1e9)
            # converged all the same: a small step that was not forced small by damping
            small = d < tol and (better or lam < 1e2)
            if small or lam >= 1e9 or not math.isfinite(ct):
                break
        cost[c] = cc
    return p, cost, nev
