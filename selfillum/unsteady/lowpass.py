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
unsteady run filters every frame (a moving model's in its own pixels, before it is read
at the reference's points: :mod:`selfillum.unsteady.spot_filter`), so this cost is per
frame. A strip of rows whose every value is finite (a fixed map's frame, its spots
patched) skips the mask's sums and the division: 2.5-2.9 ms instead of 3.8-4.5 ms on a
1280 x 800 frame, one core.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["gaussian_sigma", "gaussian_weights", "gaussian_lowpass"]


def gaussian_sigma(size: int) -> float:
    """OpenCV's standard deviation (pixels) of a Gaussian kernel of ``size`` pixels."""
    return 0.3 * ((int(size) - 1) * 0.5 - 1) + 0.8


def gaussian_weights(size: int) -> np.ndarray:
    """(size,) the separable kernel's weights, summing to 1 (the 2-D kernel is their outer
    product)."""
    size = int(size)
    if size < 3 or size % 2 == 0:
        raise ValueError(f"size must be an odd number >= 3, got {size}")
    r = (size - 1) // 2
    x = np.arange(-r, r + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / gaussian_sigma(size)) ** 2)
    return w / w.sum()


def gaussian_lowpass(image, size: int, workers: int | None = None,
                     out: np.ndarray | None = None, share=None) -> np.ndarray:
    """The NaN-aware Gaussian low-pass of ``image`` (see the module notes).

    Parameters
    ----------
    image : (H, W) array_like
        A frame, counts; NaN (or inf) where a pixel has no value. A video's integer
        counts are read as they are (no float copy of the frame).
    size : int
        Odd kernel size, pixels (uPSP's ``filter_size``), at least 3.
    workers : int, optional
        Threads over blocks of rows (default: the cores this process may use).
    out : (H, W) float64 ndarray, optional
        Written into (C-contiguous, not ``image``): a run filtering frame after frame
        reuses one buffer.
    share : selfillum.unsteady.frames.Helping, optional
        Blocks of rows shared with a caller that waits for this thread (instead of
        ``workers``).

    Returns
    -------
    (H, W) float64 ndarray
        NaN where ``image`` is not finite.
    """
    from resection._threads import run_blocks, split_range

    w = gaussian_weights(size)
    img = np.asarray(image)
    if img.dtype.kind not in "iu" or img.dtype.itemsize > 4:
        img = img.astype(np.float64, copy=False)
    img = np.ascontiguousarray(img)
    if img.ndim != 2:
        raise ValueError(f"image must be 2-D, got shape {img.shape}")
    if out is None:
        out = np.empty(img.shape)
    elif (out.shape != img.shape or out.dtype != np.float64 or not out.flags.c_contiguous
          or np.shares_memory(out, img)):
        raise ValueError("out must be a C-contiguous float64 array of the image's shape, "
                         "not the image")
    H = img.shape[0]
    if share is not None:
        share.run(lambda b: _lowpass_rows(img, w, b[0], b[1], out), H, SHARED_ROWS)
        return out
    run_blocks(lambda b: _lowpass_rows(img, w, b[0], b[1], out),
               split_range(H, workers, min_size=64), workers)
    return out


def _reflect(i: int, n: int) -> int:  # pragma: no cover - compiled inline
    """ndimage's ``reflect`` index: ``d c b a | a b c d | d c b a``."""
    while i < 0 or i >= n:
        i = -i - 1 if i < 0 else 2 * n - i - 1
    return i


_reflect_jit = numba.njit(cache=True, inline="always")(_reflect)


#: Rows of a block shared with a waiting caller (:func:`gaussian_lowpass`'s ``share``).
SHARED_ROWS = 128


#: Rows of the frame filtered at a time within a block: the strip's two horizontal
#: passes ((STRIP + 2 r) x W float64 each, 0.7 MB at a 1280-pixel width and r = 2) stay
#: in a core's cache and are reused strip after strip. A whole block's passes at once
#: (16 MB on a 1280 x 800 frame) took 6-13 ms a frame on one core, where this takes 2-3.
STRIP = 32


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lowpass_rows(img, w, r0, r1, out):  # pragma: no cover - compiled
    """Rows ``r0:r1`` of the low-pass, a strip of :data:`STRIP` rows at a time: the
    horizontal pass of the rows a strip needs (``r`` above and below, reflected at the
    frame's edges) into two small buffers, then the vertical pass. Each pass adds one
    weighted, shifted row at a time (the innermost loop runs along the row, so the
    compiler vectorises it); a value that is not finite weighs zero."""
    H, W = img.shape
    r = (w.size - 1) // 2
    m = min(STRIP, max(r1 - r0, 1)) + 2 * r
    num = np.empty((m, W))
    den = np.empty((m, W))
    val = np.empty(W + 2 * r)  # a source row, its edges reflected, NaN as 0
    fin = np.empty(W + 2 * r)  # 1 where that value is finite
    s = np.empty(W)
    d = np.empty(W)
    for s0 in range(r0, r1, STRIP):
        s1 = min(s0 + STRIP, r1)
        n = s1 - s0 + 2 * r
        clean = True  # every value the strip reads is finite: the weights sum to 1
        for j in range(n):
            row = img[_reflect_jit(s0 - r + j, H)]
            acc = 0.0
            for u in range(W):
                acc += row[u] - row[u]  # NaN once a value is not finite
            if acc != 0.0:
                clean = False
                break
        if clean:
            _plain_strip(img, w, s0, s1, num, val, s, out)
            continue
        for j in range(n):
            row = img[_reflect_jit(s0 - r + j, H)]
            for u in range(W):  # the row, then its reflected edges
                v = row[u]
                ok = v - v == 0.0  # finite (NaN and inf give NaN)
                val[u + r] = v if ok else 0.0
                fin[u + r] = 1.0 if ok else 0.0
            for e in range(r):
                a = _reflect_jit(e - r, W) + r
                b = _reflect_jit(W + e, W) + r
                val[e], fin[e] = val[a], fin[a]
                val[W + r + e], fin[W + r + e] = val[b], fin[b]
            nj = num[j]
            dj = den[j]
            for u in range(W):
                nj[u] = w[0] * val[u]
                dj[u] = w[0] * fin[u]
            for k in range(1, 2 * r + 1):
                wk = w[k]
                for u in range(W):
                    nj[u] += wk * val[u + k]
                    dj[u] += wk * fin[u + k]
        for i in range(s0, s1):
            j0 = i - s0
            for u in range(W):
                s[u] = w[0] * num[j0, u]
                d[u] = w[0] * den[j0, u]
            for k in range(1, 2 * r + 1):
                wk = w[k]
                nk = num[j0 + k]
                dk = den[j0 + k]
                for u in range(W):
                    s[u] += wk * nk[u]
                    d[u] += wk * dk[u]
            src = img[i]
            dst = out[i]
            for u in range(W):
                dst[u] = s[u] / d[u] if src[u] - src[u] == 0.0 else np.nan


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plain_strip(img, w, s0, s1, num, val, s, out):  # pragma: no cover - compiled
    """Rows ``s0:s1`` of the low-pass where every value they read is finite: the weights
    of a window then sum to 1, so the sums of the finite mask and the division are left
    out (half the work of :func:`_lowpass_rows`' general strip; the same values to the
    rounding of a sum of weights, 1e-16)."""
    H, W = img.shape
    r = (w.size - 1) // 2
    n = s1 - s0 + 2 * r
    for j in range(n):
        row = img[_reflect_jit(s0 - r + j, H)]
        for u in range(W):
            val[u + r] = row[u]
        for e in range(r):
            val[e] = val[_reflect_jit(e - r, W) + r]
            val[W + r + e] = val[_reflect_jit(W + e, W) + r]
        nj = num[j]
        for u in range(W):
            nj[u] = w[0] * val[u]
        for k in range(1, 2 * r + 1):
            wk = w[k]
            for u in range(W):
                nj[u] += wk * val[u + k]
    for i in range(s0, s1):
        j0 = i - s0
        for u in range(W):
            s[u] = w[0] * num[j0, u]
        for k in range(1, 2 * r + 1):
            wk = w[k]
            nk = num[j0 + k]
            for u in range(W):
                s[u] += wk * nk[u]
        dst = out[i]
        for u in range(W):
            dst[u] = s[u]
