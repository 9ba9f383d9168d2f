"""uPSP's ``filter = gaussian``: a NaN-aware Gaussian low-pass of a frame, compiled.

The frame is smoothed by a ``size`` x ``size`` Gaussian (OpenCV's sigma for a kernel size,
``0.3 ((size - 1) / 2 - 1) + 0.8``, as uPSP's ``psp_process`` takes it), with the pixels
that are not finite left out and the weights of those kept renormalised: each finite
pixel's value is ``sum w f / sum w`` over the finite pixels of its window; a pixel that is
not finite stays NaN. The borders reflect (``d c b a | a b c d | d c b a``).

This is what ``scipy.ndimage.gaussian_filter`` gives for the frame with its NaN set to
zero, divided by the same filter of the finite mask (``mode="reflect"``, ``truncate``
at the kernel's radius), in one separable pass over blocks of rows on the package's
threads instead of two whole-frame filters and four whole-frame temporaries: the
unsteady run filters every frame (a moving model every frame's pixels carried back
onto its reference), so this cost is per frame.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["gaussian_sigma", "gaussian_lowpass"]


def gaussian_sigma(size: int) -> float:
    """OpenCV's standard deviation (pixels) of a Gaussian kernel of ``size`` pixels."""
    return 0.3 * ((int(size) - 1) * 0.5 - 1) + 0.8


def gaussian_lowpass(image, size: int, workers: int | None = None) -> np.ndarray:
    """The NaN-aware Gaussian low-pass of ``image`` (see the module notes).

    Parameters
    ----------
    image : (H, W) array_like
        A frame, counts; NaN (or inf) where a pixel has no value.
    size : int
        Odd kernel size, pixels (uPSP's ``filter_size``), at least 3.
    workers : int, optional
        Threads over blocks of rows (default: the cores this process may use).

    Returns
    -------
    (H, W) float64 ndarray
        NaN where ``image`` is not finite.
    """
    from resection._threads import run_blocks, split_range

    size = int(size)
    if size < 3 or size % 2 == 0:
        raise ValueError(f"size must be an odd number >= 3, got {size}")
    img = np.ascontiguousarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {img.shape}")
    r = (size - 1) // 2
    sigma = gaussian_sigma(size)
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    w /= w.sum()
    out = np.empty_like(img)
    H = img.shape[0]
    run_blocks(lambda b: _lowpass_rows(img, w, b[0], b[1], out),
               split_range(H, workers, min_size=64), workers)
    return out


def _reflect(i: int, n: int) -> int:  # pragma: no cover - compiled inline
    """ndimage's ``reflect`` index: ``d c b a | a b c d | d c b a``."""
    while i < 0 or i >= n:
        i = -i - 1 if i < 0 else 2 * n - i - 1
    return i


_reflect_jit = numba.njit(cache=True, inline="always")(_reflect)


@numba.njit(cache=True, nogil=True)
def _lowpass_rows(img, w, r0, r1, out):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the low-pass: the horizontal pass of the rows they need (``r``
    above and below, reflected at the frame's edges), then the vertical pass."""
    H, W = img.shape
    r = (w.size - 1) // 2
    n = r1 - r0 + 2 * r
    num = np.empty((n, W))
    den = np.empty((n, W))
    for j in range(n):
        src = _reflect_jit(r0 - r + j, H)
        row = img[src]
        for u in range(W):
            s = 0.0
            d = 0.0
            for k in range(-r, r + 1):
                v = row[_reflect_jit(u + k, W)] if (u + k < 0 or u + k >= W) else row[u + k]
                if np.isfinite(v):
                    s += w[k + r] * v
                    d += w[k + r]
            num[j, u] = s
            den[j, u] = d
    for i in range(r0, r1):
        j0 = i - r0
        for u in range(W):
            if not np.isfinite(img[i, u]):
                out[i, u] = np.nan
                continue
            s = 0.0
            d = 0.0
            for k in range(2 * r + 1):
                s += w[k] * num[j0 + k, u]
                d += w[k] * den[j0 + k, u]
            out[i, u] = s / d
