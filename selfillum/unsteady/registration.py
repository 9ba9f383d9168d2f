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
        from selfillum.unsteady._registration_kernels import gauss_newton

        M = np.ascontiguousarray(self._M, dtype=np.float64).copy()
        gauss_newton(img, M, self._x, self._y, float(self._s), self._c, self._ref,
                               self._sd, self._Hinv, self.iterations, self.tol)
        self._M = M
        S = np.array([[self._s, 0, self._c[0]], [0, self._s, self._c[1]], [0, 0, 1]])
        return (S @ M @ np.linalg.inv(S))[:2]

    def warp(self, frame, A, pixels=None) -> np.ndarray:
        """``frame`` sampled at ``A [u, v, 1]`` for every pixel of the reference (bilinear;
        NaN where that falls outside the frame or on a NaN pixel); with ``pixels`` (flat
        indices) only those are sampled, the others are NaN. A compiled loop over the
        pixels (``_registration_kernels.affine_sample``), reading the frame as stored."""
        H, W = self.shape
        if pixels is not None:
            out = np.full(H * W, np.nan)
            out[np.asarray(pixels, dtype=np.int64)] = self.sample(frame, A, pixels)
            return out.reshape(H, W)
        return self.warp_all(frame, A)

    def warp_all(self, frame, A, workers: int | None = None) -> np.ndarray:
        """:meth:`warp` of every pixel, (H, W) float64: the compiled kernel over blocks of
        rows on ``workers`` threads (default: the available cores)."""
        from resection._threads import run_blocks, split_range
        from selfillum.unsteady._registration_kernels import affine_warp_rows

        img = np.asarray(frame)
        if img.dtype.kind not in "fiu":
            img = img.astype(np.float64)
        img = np.ascontiguousarray(img)
        A = np.asarray(A, np.float64)
        out = np.empty(self.shape)
        run_blocks(lambda b: affine_warp_rows(img, A, b[0], b[1], out),
                   split_range(self.shape[0], workers, min_size=32), workers)
        return out

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
        from selfillum.unsteady._registration_kernels import affine_sample as kern

        run_blocks(lambda b: kern(img, A, idx[b[0]:b[1]], vals[b[0]:b[1]]),
                   split_range(idx.size, workers, min_size=65536), workers)
        return vals
