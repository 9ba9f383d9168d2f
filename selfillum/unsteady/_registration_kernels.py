"""The compiled kernels of :mod:`selfillum.unsteady.registration` (numba).

Module-level functions, so that numba's on-disk cache finds them again in the next
process: a kernel made in a factory that closes over another compiled function is keyed
by that function's pickle, which changes from one process to the next, and was compiled
anew by every run (about 1-2.5 s of each ``unsteady`` command with ``registration =
pixel``). Imported only when a registration is fitted or applied (numba's import is not
paid by the commands that do not use it).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["affine_sample", "affine_warp_rows", "gauss_newton", "residual"]


@numba.njit(cache=True, nogil=True)
def residual(img, A, x, y, s, c, ref, sd, out):  # pragma: no cover - compiled
    """``out = sd^T (img(warp(x, y)) - ref)``: the frame sampled bilinearly (edges
    clamped, as ``map_coordinates(mode="nearest")``) where the warp ``A`` (normalised
    coordinates, scale ``s`` about ``c``) sends each of the fit's pixels."""
    H, W = img.shape
    # six scalar sums (kept in registers; an accumulation into ``out`` stored each of them
    # at every pixel: 1.2-1.5 times slower), added in the same order: the same numbers
    g0 = g1 = g2 = g3 = g4 = g5 = 0.0
    for i in range(x.size):
        uw = (A[0, 0] * x[i] + A[0, 1] * y[i] + A[0, 2]) * s + c[0]
        vw = (A[1, 0] * x[i] + A[1, 1] * y[i] + A[1, 2]) * s + c[1]
        uw = min(max(uw, 0.0), W - 1.0)
        vw = min(max(vw, 0.0), H - 1.0)
        u0 = min(int(uw), W - 2) if W > 1 else 0
        v0 = min(int(vw), H - 2) if H > 1 else 0
        fu = uw - u0
        fv = vw - v0
        u1 = min(u0 + 1, W - 1)
        v1 = min(v0 + 1, H - 1)
        val = ((1.0 - fv) * ((1.0 - fu) * img[v0, u0] + fu * img[v0, u1])
               + fv * ((1.0 - fu) * img[v1, u0] + fu * img[v1, u1]))
        e = val - ref[i]
        g0 += sd[i, 0] * e
        g1 += sd[i, 1] * e
        g2 += sd[i, 2] * e
        g3 += sd[i, 3] * e
        g4 += sd[i, 4] * e
        g5 += sd[i, 5] * e
    out[0] = g0
    out[1] = g1
    out[2] = g2
    out[3] = g3
    out[4] = g4
    out[5] = g5


@numba.njit(cache=True, nogil=True)
def gauss_newton(img, M, x, y, s, c, ref, sd, Hinv, iterations, tol):  # pragma: no cover
    """Inverse-compositional steps on the normalised warp ``M`` (3 x 3, updated in
    place) until a step moves no pixel of the fit by ``tol`` or more; returns the
    steps taken. ``dp = H^-1 sd^T e``, ``M <- M D(dp)^-1`` (``D`` affine: its inverse
    in closed form).

    On a real frame the steps shrink only linearly (about 0.75 a step: the bilinear
    sampling smooths the frame's speckle, so the template's gradient overstates the
    warped frame's); the steps are therefore mixed by Anderson acceleration of depth
    one on the warp's six entries (the step's output moved along its last change by
    the factor that best cancels the change of the residual): half the steps on the
    609k run's frames, and closer to the converged warp."""
    g = np.empty(6)
    A = np.empty((2, 3))
    gx = np.empty(6)
    f = np.empty(6)
    gp = np.empty(6)
    fp = np.empty(6)
    have_prev = False
    for it in range(iterations):
        for i in range(2):
            for j in range(3):
                A[i, j] = M[i, j]
        residual(img, A, x, y, s, c, ref, sd, g)
        dp = np.zeros(6)
        for i in range(6):
            for j in range(6):
                dp[i] += Hinv[i, j] * g[j]
        a, b, tx = 1.0 + dp[0], dp[1], dp[2]
        d, e, ty = dp[3], 1.0 + dp[4], dp[5]
        det = a * e - b * d
        # D^-1 = [[e, -b, b ty - e tx], [-d, a, d tx - a ty], [0, 0, det]] / det
        Di = np.array([[e / det, -b / det, (b * ty - e * tx) / det],
                       [-d / det, a / det, (d * tx - a * ty) / det],
                       [0.0, 0.0, 1.0]])
        for i in range(2):  # G(M): the plain step's warp, its top two rows
            for j in range(3):
                gx[3 * i + j] = M[i, 0] * Di[0, j] + M[i, 1] * Di[1, j] + M[i, 2] * Di[2, j]
        step = s * (abs(dp[0]) + abs(dp[1]) + abs(dp[3]) + abs(dp[4])
                    + abs(dp[2]) + abs(dp[5]))
        for k in range(6):
            f[k] = gx[k] - M[k // 3, k % 3]
        if step < tol:  # converged: the plain step's warp
            for k in range(6):
                M[k // 3, k % 3] = gx[k]
            return it + 1
        gam = 0.0
        if have_prev:
            num = 0.0
            den = 0.0
            for k in range(6):
                df = f[k] - fp[k]
                num += df * f[k]
                den += df * df
            if den > 0.0:
                gam = num / den
            if not (abs(gam) < 10.0):  # a wild mix: the plain step
                gam = 0.0
        for k in range(6):
            fp[k] = f[k]
            nxt = gx[k] - gam * (gx[k] - gp[k]) if have_prev else gx[k]
            gp[k] = gx[k]
            M[k // 3, k % 3] = nxt
        have_prev = True
    return iterations


@numba.njit(cache=True, nogil=True, inline="always")
def _bilinear(img, uw, vw, H, W):  # pragma: no cover - compiled
    """``img`` (H, W) at ``(uw, vw)``, bilinear: NaN outside ``[0, W-1] x [0, H-1]`` or
    where a neighbour of non-zero weight is NaN. Without branches, checked again by
    weights only where it gave NaN."""
    if not (uw >= 0.0 and uw <= W - 1.0 and vw >= 0.0 and vw <= H - 1.0):
        return np.nan
    u0 = min(int(uw), W - 2) if W > 1 else 0
    v0 = min(int(vw), H - 2) if H > 1 else 0
    u1 = min(u0 + 1, W - 1)
    v1 = min(v0 + 1, H - 1)
    fu = uw - u0
    fv = vw - v0
    i00, i01, i10, i11 = img[v0, u0], img[v0, u1], img[v1, u0], img[v1, u1]
    val = ((1.0 - fv) * (i00 + fu * (i01 - i00))
           + fv * (i10 + fu * (i11 - i10)))
    if val != val:  # a NaN neighbour: left out where its weight is zero
        val = 0.0
        w00 = (1.0 - fu) * (1.0 - fv)
        w01 = fu * (1.0 - fv)
        w10 = (1.0 - fu) * fv
        w11 = fu * fv
        if w00 > 0.0:
            val += w00 * i00
        if w01 > 0.0:
            val += w01 * i01
        if w10 > 0.0:
            val += w10 * i10
        if w11 > 0.0:
            val += w11 * i11
    return val


@numba.njit(cache=True, nogil=True)
def affine_sample(img, A, pixels, out):  # pragma: no cover - compiled
    """Bilinear sample of ``img`` at ``A [u, v, 1]`` of each pixel ``p = v W + u``:
    NaN outside ``[0, W-1] x [0, H-1]`` or where a neighbour of non-zero weight is
    NaN (as ``scipy.ndimage.map_coordinates(order=1)`` with a NaN mask). The pixels
    come sorted: one division a row, not two a pixel; the interpolation without
    branches, checked again by weights only where it gave NaN."""
    H, W = img.shape
    row = -1
    start = -W
    a00, a01, a02 = A[0, 0], A[0, 1], A[0, 2]
    a10, a11, a12 = A[1, 0], A[1, 1], A[1, 2]
    for i in range(pixels.size):
        p = pixels[i]
        if p < start or p >= start + W:  # a new image row
            row = p // W
            start = row * W
        u = p - start
        uw = a00 * u + a01 * row + a02
        vw = a10 * u + a11 * row + a12
        out[i] = _bilinear(img, uw, vw, H, W)



@numba.njit(cache=True, nogil=True, error_model="numpy")
def affine_warp_rows(img, A, r0, r1, out):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of :func:`affine_sample` over every pixel of ``out`` (H, W): the
    same values, the warped position stepped along each row instead of a pixel list (no
    index array, no division a pixel)."""
    H, W = img.shape
    Wo = out.shape[1]
    a00, a01, a02 = A[0, 0], A[0, 1], A[0, 2]
    a10, a11, a12 = A[1, 0], A[1, 1], A[1, 2]
    for row in range(r0, r1):
        dst = out[row]
        for u in range(Wo):
            uw = a00 * u + a01 * row + a02
            vw = a10 * u + a11 * row + a12
            dst[u] = _bilinear(img, uw, vw, H, W)
