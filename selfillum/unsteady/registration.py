"""uPSP's registration: every frame warped onto the first by an affine pixel registration.

``psp_process`` maps every frame through the first frame's projection, after warping the
frame onto the first one with an affine transform found from the pixels ("pixel" image
registration). :class:`AffineRegistration` does the same with the inverse-compositional
Lucas-Kanade algorithm (Baker & Matthews 2004): Gauss-Newton on the sum of squared
differences between the first frame and the warped frame over the model's pixels,
the first frame's gradients computed once. Each frame starts from the previous frame's
warp. What an affine warp cannot follow (perspective, parallax, occlusions, the silhouette)
stays as error: the reason this project maps every frame with its own pose instead.

Warp convention: frame ``k``'s pixel ``(u', v')`` that shows what frame 0 shows at
``(u, v)`` is ``[u', v'] = A [u, v, 1]`` (``A`` 2 x 3); the registered frame is frame ``k``
sampled at ``A [u, v, 1]`` (bilinear, NaN outside).
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["AffineRegistration"]


class AffineRegistration:
    """Register frames onto a reference frame (the first) by an affine warp.

    Parameters
    ----------
    reference : (H, W) array_like
        Frame 0.
    mask : (H, W) bool
        Pixels that enter the fit (the model's pixels of frame 0, NaN-free).
    iterations : int
        Most Gauss-Newton steps per frame.
    tol : float
        Stop when the update moves no pixel of the mask by more than this (pixels).
    max_pixels : int
        Pixels of the mask the fit uses, evenly spread over it (an affine warp has six
        parameters: 40,000 pixels pin it to a few thousandths of a pixel on a noisy frame,
        at a twentieth of the cost of a megapixel's).
    """

    def __init__(self, reference, mask, *, iterations: int = 50, tol: float = 1e-3,
                 max_pixels: int = 40_000):
        ref = np.asarray(reference, dtype=np.float64)
        m = np.asarray(mask, bool) & np.isfinite(ref)
        m[[0, -1], :] = False
        m[:, [0, -1]] = False
        gy, gx = np.gradient(np.where(np.isfinite(ref), ref, 0.0))
        v, u = np.nonzero(m)
        if u.size > max_pixels:
            pick = np.linspace(0, u.size - 1, int(max_pixels)).astype(np.int64)
            v, u = v[pick], u[pick]
        self._c = np.array([u.mean(), v.mean()]) if u.size else np.zeros(2)
        self._s = max(float(np.ptp(u)) if u.size else 1.0, float(np.ptp(v)) if v.size else 1.0,
                      1.0)
        x = (u - self._c[0]) / self._s
        y = (v - self._c[1]) / self._s
        gxm, gym = gx[v, u] * self._s, gy[v, u] * self._s  # d/dx in normalised units
        self._sd = np.column_stack([gxm * x, gxm * y, gxm, gym * x, gym * y, gym])
        self._H = self._sd.T @ self._sd
        self._Hinv = np.linalg.pinv(self._H) if u.size else np.zeros((6, 6))
        self._x, self._y, self._u, self._v = x, y, u, v
        self._ref = ref[v, u]
        self.iterations = int(iterations)
        self.tol = float(tol)
        self._M = np.eye(3)  # current warp in normalised coordinates
        self.shape = ref.shape

    def fit(self, frame) -> np.ndarray:
        """The warp ``A`` (2 x 3, pixels) of ``frame`` onto the reference (see the module
        notes); starts from the previous call's warp."""
        img = np.asarray(frame)
        if img.dtype.kind == "f" and not np.isfinite(img).all():
            img = np.where(np.isfinite(img), img, 0.0)
        elif img.dtype.kind not in "fiu":
            img = img.astype(np.float64)
        img = np.ascontiguousarray(img)
        # the Gauss-Newton steps in one compiled call that releases the GIL (a run maps
        # frames in another thread meanwhile): no Python between the steps
        M = np.ascontiguousarray(self._M, dtype=np.float64).copy()
        _gauss_newton_kernel()(img, M, self._x, self._y, float(self._s), self._c, self._ref,
                               self._sd, self._Hinv, self.iterations, self.tol)
        self._M = M
        S = np.array([[self._s, 0, self._c[0]], [0, self._s, self._c[1]], [0, 0, 1]])
        return (S @ M @ np.linalg.inv(S))[:2]

    def warp(self, frame, A, pixels=None) -> np.ndarray:
        """``frame`` sampled at ``A [u, v, 1]`` for every pixel of the reference (bilinear;
        NaN where that falls outside the frame or on a NaN pixel); with ``pixels`` (flat
        indices) only those are sampled, the others are NaN. A compiled loop over the
        pixels (:func:`_affine_kernel`), reading the frame as stored."""
        H, W = self.shape
        if pixels is not None:
            out = np.full(H * W, np.nan)
            out[np.asarray(pixels, dtype=np.int64)] = self.sample(frame, A, pixels)
            return out.reshape(H, W)
        return self.sample(frame, A, np.arange(H * W, dtype=np.int64)).reshape(H, W)

    def sample(self, frame, A, pixels, workers: int | None = None) -> np.ndarray:
        """The values of :meth:`warp` at the reference's ``pixels`` (flat indices) only,
        (n,) float64; the compiled kernel on ``workers`` threads (default: the available
        cores; blocks of pixels)."""
        from resection._threads import run_blocks, split_range

        img = np.asarray(frame)
        if img.dtype.kind not in "fiu":
            img = img.astype(np.float64)
        img = np.ascontiguousarray(img)
        idx = np.asarray(pixels, dtype=np.int64)
        A = np.asarray(A, np.float64)
        vals = np.empty(idx.size)
        kern = _affine_kernel()
        run_blocks(lambda b: kern(img, A, idx[b[0]:b[1]], vals[b[0]:b[1]]),
                   split_range(idx.size, workers, min_size=65536), workers)
        return vals


@functools.cache
def _residual_kernel():
    import numba

    @numba.njit(cache=True, nogil=True)
    def residual(img, A, x, y, s, c, ref, sd, out):  # pragma: no cover - compiled
        """``out = sd^T (img(warp(x, y)) - ref)``: the frame sampled bilinearly (edges
        clamped, as ``map_coordinates(mode="nearest")``) where the warp ``A`` (normalised
        coordinates, scale ``s`` about ``c``) sends each of the fit's pixels."""
        H, W = img.shape
        for j in range(6):
            out[j] = 0.0
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
            for j in range(6):
                out[j] += sd[i, j] * e

    return residual


@functools.cache
def _gauss_newton_kernel():
    import numba

    residual = _residual_kernel()

    @numba.njit(cache=True, nogil=True)
    def gauss_newton(img, M, x, y, s, c, ref, sd, Hinv, iterations, tol):  # pragma: no cover
        """Inverse-compositional steps on the normalised warp ``M`` (3 x 3, updated in
        place) until a step moves no pixel of the fit by ``tol`` or more; returns the
        steps taken. ``dp = H^-1 sd^T e``, ``M <- M D(dp)^-1`` (``D`` affine: its inverse
        in closed form)."""
        g = np.empty(6)
        A = np.empty((2, 3))
        T = np.empty((3, 3))
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
            for i in range(3):
                for j in range(3):
                    T[i, j] = M[i, 0] * Di[0, j] + M[i, 1] * Di[1, j] + M[i, 2] * Di[2, j]
            for i in range(3):
                for j in range(3):
                    M[i, j] = T[i, j]
            step = s * (abs(dp[0]) + abs(dp[1]) + abs(dp[3]) + abs(dp[4])
                        + abs(dp[2]) + abs(dp[5]))
            if step < tol:
                return it + 1
        return iterations

    return gauss_newton


@functools.cache
def _affine_kernel():
    import numba

    @numba.njit(cache=True, nogil=True)
    def affine_sample(img, A, pixels, out):  # pragma: no cover - compiled
        """Bilinear sample of ``img`` at ``A [u, v, 1]`` of each pixel ``p = v W + u``:
        NaN outside ``[0, W-1] x [0, H-1]`` or where a neighbour of non-zero weight is
        NaN (as ``scipy.ndimage.map_coordinates(order=1)`` with a NaN mask)."""
        H, W = img.shape
        row = -1
        start = 0
        for i in range(pixels.size):
            p = pixels[i]
            if p < start or p >= start + W:  # a new image row: one division a row, not
                # two a pixel (the pixels come sorted), the loop's cost otherwise
                row = p // W
                start = row * W
            u = p - start
            v = row
            uw = A[0, 0] * u + A[0, 1] * v + A[0, 2]
            vw = A[1, 0] * u + A[1, 1] * v + A[1, 2]
            if not (uw >= 0.0 and uw <= W - 1.0 and vw >= 0.0 and vw <= H - 1.0):
                out[i] = np.nan
                continue
            u0 = min(int(uw), W - 2) if W > 1 else 0
            v0 = min(int(vw), H - 2) if H > 1 else 0
            fu = uw - u0
            fv = vw - v0
            u1 = min(u0 + 1, W - 1)
            v1 = min(v0 + 1, H - 1)
            acc = 0.0
            w00 = (1.0 - fu) * (1.0 - fv)
            w01 = fu * (1.0 - fv)
            w10 = (1.0 - fu) * fv
            w11 = fu * fv
            if w00 > 0.0:
                acc += w00 * img[v0, u0]
            if w01 > 0.0:
                acc += w01 * img[v0, u1]
            if w10 > 0.0:
                acc += w10 * img[v1, u0]
            if w11 > 0.0:
                acc += w11 * img[v1, u1]
            out[i] = acc

    return affine_sample
