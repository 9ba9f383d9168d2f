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
The tables (edge profile, nodes) and the damped solve are :mod:`resection.markers._diskfit`'s.

Two things differ from the disk's fit, both for markers the model cannot match exactly
(paint speckle, a render or a sensor without the assumed blur: the residual stays large):

* **The curvature seen along the last step.** Gauss-Newton takes ``J^T J`` for the cost's
  curvature and leaves out the residual's own term, which is large there. On the
  point-sampled, speckled 35 px targets of the 609,000-face uPSP run the steps overshot
  by a factor of about 1.4 (each the previous one's -0.4 times) and the fits took
  7.2 evaluations a window for 1e-3 px. After each accepted step ``s`` the gradient's
  change ``y`` gives the curvature along it; where it is larger than ``J^T J``'s, a
  rank-one term makes the next step's matrix agree with it along ``s`` (a secant
  correction, as NL2SOL's for large-residual least squares, Dennis, Gay and Welsch 1981;
  kept for one step only). On model-like data the two curvatures agree and nothing
  changes; on those targets 5.4 evaluations a window (5.0 with the start's contrast
  from the ellipse's moments, :func:`resection.markers.refine._ellipse_starts`).
* **The shape's step in the stopping rule.** The centre can stop moving while the shape is
  still far from its optimum (a start whose moments were cut short by the window: a
  step of 1.4 px in the half-width with 3e-3 px in the centre), and it moves again as
  the shape converges; a window stops only once the shape's step is under
  :data:`SHAPE_TOL` times ``tol`` too. Stopped on the centre alone, 1 % of those
  windows stopped 0.02-0.2 px from their optimum.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from resection.markers._diskfit import _Q_MIN, _Q_PER_R, _ZC, _basis, _solve_damped, chord_rows

NP = 9  # parameters of a window
KMAX = 8.0  # bound of the shear |k| (a chord's centre moves 8 px a pixel: edge-on)
#: a fit stops only once its step of the shape (``X``, ``H``, and ``k X``, pixels) is under
#: this many times the centre's ``tol`` too (near the optimum the shape's steps run about 3
#: times the centre's in pixels, so this holds back only a fit whose shape is still far off)
SHAPE_TOL = 30.0
#: bounds of the curvature ratio taken along the last step (its correction never lowers the
#: Gauss-Newton matrix, and at most quadruples it along the step)
CURVATURE_MAX = 4.0


@njit(cache=True, fastmath=True)
def _model(x0, y0, X, H, k, tab, T, h, sn, cs, wc, Q, M, sA, sB, D):
    """Unit-contrast ellipse image and its derivatives, in place: ``(image,
    d/dx0, d/dy0, d/dX, d/dH, d/dk)`` at row ``j``, column ``i`` in ``M[j, i]`` (``M`` is
    (W, W, 6)). ``sA`` and ``sB`` (W + 1, 3) and ``D`` (W + 1, W, 3) are scratch arrays.

    The rows wholly inside a node's chord (most of them) all add the same column factors
    to the image and its derivatives in x0 and X, and nothing to the others: they are
    added as a difference at the block's two ends (``D``) and summed down the rows once
    at the end, not row by row."""
    W = M.shape[0]
    M.fill(0.0)
    D.fill(0.0)
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
        chord_rows(tab, T, h, step, j0, j1 - j0 + 1, yc, hq, cq, sB)
        ks, Xs = k * sq, X * sq  # d yc / dX and d yc / dk
        ja, jb = W, -1  # the block of rows inside the chord
        for r in range(j1 - j0 + 1):
            j = j0 + r
            B, By, BH = sB[r, 0], sB[r, 1], sB[r, 2]
            if By == 0.0 and BH == 0.0 and B == 1.0:
                ja, jb = min(ja, j), max(jb, j)
                continue
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
        if jb >= ja:
            for c in range(i1 - i0 + 1):
                i = i0 + c
                D[ja, i, 0] += sA[c, 0]
                D[ja, i, 1] += sA[c, 1]
                D[ja, i, 2] += sA[c, 2]
                D[jb + 1, i, 0] -= sA[c, 0]
                D[jb + 1, i, 1] -= sA[c, 1]
                D[jb + 1, i, 2] -= sA[c, 2]
    for j in range(W):  # the inner blocks, summed down the rows (in place in D)
        for i in range(W):
            if j > 0:
                D[j, i, 0] += D[j - 1, i, 0]
                D[j, i, 1] += D[j - 1, i, 1]
                D[j, i, 2] += D[j - 1, i, 2]
            M[j, i, 0] += D[j, i, 0]
            M[j, i, 1] += D[j, i, 1]
            M[j, i, 3] += D[j, i, 2]


@njit(cache=True)
def _reach(X, H, k):
    """Half-width and half-height of the ellipse's bounding box (pixels)."""
    return X, math.sqrt(H * H + k * k * X * X)


@njit(cache=True)
def _normal(win, w, p, tab, T, h, sizes, sn, cs, wc, M, sA, sB, D, JTJ, JTr):
    """Weighted cost of parameters ``p`` on one window, with ``J^T J`` (9, 9) and ``J^T r``
    (9,) (``r = data - model``); the sums in scalars (registers, not memory: twice as fast
    as a loop over a Jacobian row; generated, one line a term)."""
    W = win.shape[0]
    x0, y0, X, H, k = p[0], p[1], p[2], p[3], p[4]
    a, b, bu, bv = p[5], p[6], p[7], p[8]
    rx, ry = _reach(X, H, k)
    s = max((T - 0.5) / _ZC, 0.3)
    need = math.ceil(_Q_PER_R * max(rx, ry, 0.5) / s + _Q_MIN)
    q = 0
    while q < sizes.size - 1 and sizes[q] < need:
        q += 1
    _model(x0, y0, X, H, k, tab, T, h, sn[q], cs[q], wc[q], sizes[q], M, sA, sB, D)
    i0 = max(int(math.ceil(x0 - rx - T)), 0)
    i1 = min(int(math.floor(x0 + rx + T)), W - 1)
    j0 = max(int(math.ceil(y0 - ry - T)), 0)
    j1 = min(int(math.floor(y0 + ry + T)), W - 1)
    c = (W - 1) / 2.0
    s00 = 0.0
    s10 = s11 = 0.0
    s20 = s21 = s22 = 0.0
    s30 = s31 = s32 = s33 = 0.0
    s40 = s41 = s42 = s43 = s44 = 0.0
    s50 = s51 = s52 = s53 = s54 = s55 = 0.0
    s60 = s61 = s62 = s63 = s64 = s65 = s66 = 0.0
    s70 = s71 = s72 = s73 = s74 = s75 = s76 = s77 = 0.0
    s80 = s81 = s82 = s83 = s84 = s85 = s86 = s87 = s88 = 0.0
    r0 = r1 = r2 = r3 = r4 = r5 = r6 = r7 = r8 = 0.0
    cost = 0.0
    for j in range(W):
        dv = j - c
        inside_row = j0 <= j <= j1
        for i in range(W):
            wt = w[j, i]
            if wt == 0.0:
                continue
            du = i - c
            J6, J7, J8 = wt, du * wt, dv * wt
            if inside_row and i0 <= i <= i1:
                m = M[j, i, 0]
                r = (win[j, i] - (a * m + b + bu * du + bv * dv)) * wt
                aw = a * wt
                J0 = aw * M[j, i, 1]
                J1 = aw * M[j, i, 2]
                J2 = aw * M[j, i, 3]
                J3 = aw * M[j, i, 4]
                J4 = aw * M[j, i, 5]
                J5 = m * wt
                r0 += J0 * r
                r1 += J1 * r
                r2 += J2 * r
                r3 += J3 * r
                r4 += J4 * r
                r5 += J5 * r
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
                s40 += J4 * J0
                s41 += J4 * J1
                s42 += J4 * J2
                s43 += J4 * J3
                s44 += J4 * J4
                s50 += J5 * J0
                s51 += J5 * J1
                s52 += J5 * J2
                s53 += J5 * J3
                s54 += J5 * J4
                s55 += J5 * J5
                s60 += J6 * J0
                s61 += J6 * J1
                s62 += J6 * J2
                s63 += J6 * J3
                s64 += J6 * J4
                s65 += J6 * J5
                s70 += J7 * J0
                s71 += J7 * J1
                s72 += J7 * J2
                s73 += J7 * J3
                s74 += J7 * J4
                s75 += J7 * J5
                s80 += J8 * J0
                s81 += J8 * J1
                s82 += J8 * J2
                s83 += J8 * J3
                s84 += J8 * J4
                s85 += J8 * J5
            else:  # background only: the last three columns of J
                r = (win[j, i] - (b + bu * du + bv * dv)) * wt
            r6 += J6 * r
            r7 += J7 * r
            r8 += J8 * r
            s66 += J6 * J6
            s76 += J7 * J6
            s77 += J7 * J7
            s86 += J8 * J6
            s87 += J8 * J7
            s88 += J8 * J8
            cost += r * r
    JTJ[0, 0] = s00
    JTJ[1, 0] = s10
    JTJ[0, 1] = s10
    JTJ[1, 1] = s11
    JTJ[2, 0] = s20
    JTJ[0, 2] = s20
    JTJ[2, 1] = s21
    JTJ[1, 2] = s21
    JTJ[2, 2] = s22
    JTJ[3, 0] = s30
    JTJ[0, 3] = s30
    JTJ[3, 1] = s31
    JTJ[1, 3] = s31
    JTJ[3, 2] = s32
    JTJ[2, 3] = s32
    JTJ[3, 3] = s33
    JTJ[4, 0] = s40
    JTJ[0, 4] = s40
    JTJ[4, 1] = s41
    JTJ[1, 4] = s41
    JTJ[4, 2] = s42
    JTJ[2, 4] = s42
    JTJ[4, 3] = s43
    JTJ[3, 4] = s43
    JTJ[4, 4] = s44
    JTJ[5, 0] = s50
    JTJ[0, 5] = s50
    JTJ[5, 1] = s51
    JTJ[1, 5] = s51
    JTJ[5, 2] = s52
    JTJ[2, 5] = s52
    JTJ[5, 3] = s53
    JTJ[3, 5] = s53
    JTJ[5, 4] = s54
    JTJ[4, 5] = s54
    JTJ[5, 5] = s55
    JTJ[6, 0] = s60
    JTJ[0, 6] = s60
    JTJ[6, 1] = s61
    JTJ[1, 6] = s61
    JTJ[6, 2] = s62
    JTJ[2, 6] = s62
    JTJ[6, 3] = s63
    JTJ[3, 6] = s63
    JTJ[6, 4] = s64
    JTJ[4, 6] = s64
    JTJ[6, 5] = s65
    JTJ[5, 6] = s65
    JTJ[6, 6] = s66
    JTJ[7, 0] = s70
    JTJ[0, 7] = s70
    JTJ[7, 1] = s71
    JTJ[1, 7] = s71
    JTJ[7, 2] = s72
    JTJ[2, 7] = s72
    JTJ[7, 3] = s73
    JTJ[3, 7] = s73
    JTJ[7, 4] = s74
    JTJ[4, 7] = s74
    JTJ[7, 5] = s75
    JTJ[5, 7] = s75
    JTJ[7, 6] = s76
    JTJ[6, 7] = s76
    JTJ[7, 7] = s77
    JTJ[8, 0] = s80
    JTJ[0, 8] = s80
    JTJ[8, 1] = s81
    JTJ[1, 8] = s81
    JTJ[8, 2] = s82
    JTJ[2, 8] = s82
    JTJ[8, 3] = s83
    JTJ[3, 8] = s83
    JTJ[8, 4] = s84
    JTJ[4, 8] = s84
    JTJ[8, 5] = s85
    JTJ[5, 8] = s85
    JTJ[8, 6] = s86
    JTJ[6, 8] = s86
    JTJ[8, 7] = s87
    JTJ[7, 8] = s87
    JTJ[8, 8] = s88
    JTr[0] = r0
    JTr[1] = r1
    JTr[2] = r2
    JTr[3] = r3
    JTr[4] = r4
    JTr[5] = r5
    JTr[6] = r6
    JTr[7] = r7
    JTr[8] = r8
    return cost


@njit(cache=True)
def _clamp(pt, rmin, rmax):
    pt[2] = min(max(pt[2], rmin), rmax)
    pt[3] = min(max(pt[3], rmin), rmax)
    pt[4] = min(max(pt[4], -KMAX), KMAX)


@njit(cache=True)
def _curvature(JTJ, JTr0, JTr1, p0, p1, u):
    """The rank-one term that makes ``J^T J`` (at ``p1``) agree along the step ``s = p1 -
    p0`` with the curvature the gradients show (``y = J^T r`` at ``p0`` minus at ``p1``,
    the gradient of half the cost being ``-J^T r``): ``u = J^T J s`` (in place) and the
    factor ``f`` of ``f u u^T``, so that ``(J^T J + f u u^T) s`` has the component
    ``s . y`` along ``s``. Only a larger curvature is taken (``f >= 0``: the matrix stays
    positive definite), at most :data:`CURVATURE_MAX` times ``J^T J``'s."""
    su = 0.0
    sy = 0.0
    for q in range(NP):
        acc = 0.0
        for qq in range(NP):
            acc += JTJ[q, qq] * (p1[qq] - p0[qq])
        u[q] = acc
        su += (p1[q] - p0[q]) * acc
        sy += (p1[q] - p0[q]) * (JTr0[q] - JTr1[q])
    if not su > 0.0 or not math.isfinite(sy):
        return 0.0
    ratio = min(max(sy / su, 1.0), CURVATURE_MAX)
    return (ratio - 1.0) / su


@njit(cache=True, nogil=True)
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
        Maximum iterations a window; convergence as
        :func:`resection.markers._diskfit.fit_windows` (the error the centre's step
        leaves under ``tol`` pixels), and the shape's step under ``SHAPE_TOL * tol``.
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
    D = np.empty((W + 1, W, 3))
    JTJ = np.empty((NP, NP))
    JTr = np.empty(NP)
    JTJt = np.empty((NP, NP))
    JTrt = np.empty(NP)
    step = np.empty(NP)
    pt = np.empty(NP)
    A = np.empty((NP, NP))  # J^T J and the curvature seen along the last step
    u = np.empty(NP)
    for c in range(n):
        pc = p[c]
        ww = w[c]
        wn = win[c]
        cc = _normal(wn, ww, pc, tab, T, h, sizes, sn, cs, wc, M, sA, sB, D, JTJ, JTr)
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
                cc = _normal(wn, ww, pt, tab, T, h, sizes, sn, cs, wc, M, sA, sB, D, JTJ, JTr)
                nev[c] += 1
                for q in range(NP):
                    pc[q] = pt[q]
        extra = 0.0  # the rank-one curvature term: extra * u u^T
        u.fill(0.0)
        for _ in range(iterations):
            for q in range(NP):
                for qq in range(NP):
                    A[q, qq] = JTJ[q, qq] + extra * u[q] * u[qq]
            _solve_damped(A, JTr, lam, step)
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
            shaped = max(abs(step[2]), abs(step[3]), abs(step[4]) * pc[2]) < SHAPE_TOL * tol
            if lam <= 1e-2 and left < tol and shaped:
                for q in range(NP):
                    pc[q] = pt[q]
                break
            ct = _normal(wn, ww, pt, tab, T, h, sizes, sn, cs, wc, M, sA, sB, D, JTJt, JTrt)
            nev[c] += 1
            better = ct < cc
            if better:
                extra = _curvature(JTJt, JTr, JTrt, pc, pt, u)
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
            small = d < tol and shaped and (better or lam < 1e2)
            if small or lam >= 1e9 or not math.isfinite(ct):
                break
        cost[c] = cc
    return p, cost, nev
