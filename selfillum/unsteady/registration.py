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
from scipy import ndimage

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
    """

    def __init__(self, reference, mask, *, iterations: int = 50, tol: float = 1e-3):
        ref = np.asarray(reference, dtype=np.float64)
        m = np.asarray(mask, bool) & np.isfinite(ref)
        m[[0, -1], :] = False
        m[:, [0, -1]] = False
        gy, gx = np.gradient(np.where(np.isfinite(ref), ref, 0.0))
        v, u = np.nonzero(m)
        self._c = np.array([u.mean(), v.mean()]) if u.size else np.zeros(2)
        self._s = max(float(np.ptp(u)) if u.size else 1.0, float(np.ptp(v)) if v.size else 1.0,
                      1.0)
        x = (u - self._c[0]) / self._s
        y = (v - self._c[1]) / self._s
        gxm, gym = gx[v, u] * self._s, gy[v, u] * self._s  # d/dx in normalised units
        self._sd = np.column_stack([gxm * x, gxm * y, gxm, gym * x, gym * y, gym])
        self._H = self._sd.T @ self._sd
        self._x, self._y, self._u, self._v = x, y, u, v
        self._ref = ref[v, u]
        self.iterations = int(iterations)
        self.tol = float(tol)
        self._M = np.eye(3)  # current warp in normalised coordinates
        self.shape = ref.shape

    def _pixels(self, M):
        xw = M[0, 0] * self._x + M[0, 1] * self._y + M[0, 2]
        yw = M[1, 0] * self._x + M[1, 1] * self._y + M[1, 2]
        return xw * self._s + self._c[0], yw * self._s + self._c[1]

    def fit(self, frame) -> np.ndarray:
        """The warp ``A`` (2 x 3, pixels) of ``frame`` onto the reference (see the module
        notes); starts from the previous call's warp."""
        img = np.asarray(frame, dtype=np.float64)
        filled = np.where(np.isfinite(img), img, 0.0)
        M = self._M.copy()
        for _ in range(self.iterations):  # Gauss-Newton steps (a few), not pixels
            uw, vw = self._pixels(M)
            warped = ndimage.map_coordinates(filled, [vw, uw], order=1, mode="nearest")
            err = warped - self._ref
            dp = np.linalg.solve(self._H, self._sd.T @ err)
            D = np.array([[1 + dp[0], dp[1], dp[2]], [dp[3], 1 + dp[4], dp[5]], [0, 0, 1]])
            M = M @ np.linalg.inv(D)
            step = self._s * (np.abs(dp[[0, 1, 3, 4]]).sum() + np.abs(dp[[2, 5]]).sum())
            if step < self.tol:
                break
        self._M = M
        S = np.array([[self._s, 0, self._c[0]], [0, self._s, self._c[1]], [0, 0, 1]])
        return (S @ M @ np.linalg.inv(S))[:2]

    def warp(self, frame, A) -> np.ndarray:
        """``frame`` sampled at ``A [u, v, 1]`` for every pixel of the reference (bilinear;
        NaN where that falls outside the frame or on a NaN pixel)."""
        img = np.asarray(frame, dtype=np.float64)
        H, W = self.shape
        v, u = np.mgrid[0:H, 0:W]
        uw = A[0, 0] * u + A[0, 1] * v + A[0, 2]
        vw = A[1, 0] * u + A[1, 1] * v + A[1, 2]
        nanm = ~np.isfinite(img)
        out = ndimage.map_coordinates(np.where(nanm, 0.0, img), [vw, uw], order=1,
                                      mode="constant", cval=np.nan)
        if nanm.any():
            bad = ndimage.map_coordinates(nanm.astype(np.float64), [vw, uw], order=1,
                                          mode="constant", cval=1.0)
            out[bad > 0] = np.nan
        out[(uw < 0) | (uw > W - 1) | (vw < 0) | (vw > H - 1)] = np.nan
        return out
