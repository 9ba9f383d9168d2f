"""Preparation of a frame for marker detection, and the merit image. Internal module of
:func:`resection.markers.detect.detect_markers`.

* :func:`prepare`: one compiled pass over the (integer or float) frame: the masked pixels
  (NaN, infinite, saturated, user mask) are counted, the sign of dark markers flipped, the
  fill level subtracted (masked pixels read 0, the fill level; saturated ones their
  saturation level, ``sign * sat - fill``, a bound on their true value: a dark marker
  inside saturated glare stands out of it, a bright one's saturated core stays bright), and
  the result written as float32, the input of the merit's transform (which overwrites
  it). No float64 copy of the frame; the fit reads its windows from the frame itself. The
  float32 values are exact for 8- and 16-bit frames (integers under 2^24, the fill level a
  half-integer). The mask of bad pixels is written only where there are some.
* :func:`merit`: the correlation of the prepared frame with the marker template, the frame
  extended by mirror symmetry at its borders (``np.pad(mode="symmetric")``), at every pixel
  of the frame. The template is even in each axis, so this symmetric convolution is
  diagonal in the type-II discrete cosine transform: one forward and one inverse 2-D DCT of
  the frame's own size (no padding, no complex spectrum), the template's eigenvalues cached
  per size.

Conventions: ``img[v, u]``, pixel ``(u, v)`` = (column, row).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from numba import njit

#: extra float32 columns of the transform's buffer: a row stride that is not a multiple of
#: a large power of two (a 1024-column frame's 4096 bytes make the column transforms ~2.5x
#: slower through cache-set conflicts)
_STRIDE_PAD = 16


@njit(cache=True)
def _is_bad(x, sat):
    """A masked value: NaN (fails both comparisons), infinite or ``>= sat``."""
    return not ((x < sat) & (x > -np.inf))


@njit(cache=True)
def _prepare(img, mask, sat, sign, fill, out):
    """The compiled pass of :func:`prepare`: ``out = sign * img - fill``, 0 where masked
    (``mask`` of shape (0, 0): none; NaN, infinite), ``sign * sat - fill`` where saturated
    (``>= sat``, finite, not in ``mask``); returns the number of masked pixels (saturated
    ones included). Branch-free per pixel, so that the rows vectorise."""
    H, W = img.shape
    use_mask = mask.shape[0] == H and mask.shape[1] == W
    n_bad = 0
    at_sat = np.float32(sign * sat - fill) if math.isfinite(sat) else np.float32(0.0)
    for i in range(H):
        for j in range(W):
            x = float(img[i, j])
            b = _is_bad(x, sat)
            void = not math.isfinite(x)
            if use_mask:
                b = b | mask[i, j]
                void = void | mask[i, j]
            n_bad += b
            v = np.float32(sign * x - fill)
            v = at_sat if b else v
            out[i, j] = np.float32(0.0) if void else v
    return n_bad


@njit(cache=True)
def _flag(img, mask, sat, bad):
    """``bad`` = the masked pixels of ``img`` (as :func:`_prepare` counts them)."""
    H, W = img.shape
    use_mask = mask.shape[0] == H and mask.shape[1] == W
    for i in range(H):
        for j in range(W):
            b = _is_bad(float(img[i, j]), sat)
            if use_mask:
                b = b | mask[i, j]
            bad[i, j] = b


def native(img: np.ndarray, mask: np.ndarray | None = None):
    """``img`` in a type the compiled kernels take (half and long-double floats as float64,
    byte-swapped types in the machine's order) and ``mask`` as a bool array (a (0, 0)
    array for none)."""
    if img.dtype.kind == "f" and img.dtype.itemsize not in (4, 8):
        img = img.astype(np.float64)
    elif not img.dtype.isnative:
        img = img.astype(img.dtype.newbyteorder("="))
    mask = np.zeros((0, 0), np.bool_) if mask is None else np.asarray(mask, dtype=np.bool_)
    return img, mask


def median(x: np.ndarray) -> float:
    """``np.median`` of a 1-D array of finite values (the mean of the two middle values for
    an even size), by one partition: several times faster than ``np.median``'s two."""
    n = x.size
    part = np.partition(x, n // 2)
    hi = float(part[n // 2])
    if n % 2:
        return hi
    return (float(part[:n // 2].max()) + hi) / 2.0


def prepare(img: np.ndarray, mask: np.ndarray, sat: float,
            sign: float) -> tuple[np.ndarray, np.ndarray | None, int, float]:
    """Fill level and the frame as float32, masked pixels counted, in one pass.

    Parameters
    ----------
    img : (H, W) integer or float array
        The searched part of the frame, from :func:`native`.
    mask : (H, W) bool array, or (0, 0) for none
        True where pixels must be ignored, from :func:`native`.
    sat : float
        Pixels ``>=`` this value are masked (``inf``: none); NaN and infinite ones always.
    sign : float
        -1 for dark markers (the frame is negated), +1 for bright ones.

    Returns
    -------
    work : (H, W) float32 array
        ``sign * img - fill``, 0 at masked pixels (``sign * sat - fill`` at saturated
        ones), in a buffer with a padded row stride
        (the input of :func:`merit`, which overwrites it).
    bad : (H, W) bool array, or None where no pixel is masked
        Masked pixels.
    n_bad : int
        Their number.
    fill : float
        Fill level, image units after the sign: the median of a regular subsample of about
        16,000 unmasked pixels (of all unmasked pixels if the subsample has none).
    """
    H, W = img.shape
    # the fill level from a regular subsample (masked pixels of the subsample left out)
    k = max(1, int(np.sqrt(img.size / 16_000)))
    sub = np.asarray(img[::k, ::k], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(sub) & (sub < sat)
    if mask.shape == img.shape:
        ok &= ~mask[::k, ::k]
    work = np.empty((H, W + _STRIDE_PAD), np.float32)[:, :W]
    if ok.any():
        fill = median(sign * sub[ok])
        n_bad = int(_prepare(img, mask, sat, float(sign), fill, work))
    else:  # the whole subsample is masked: the median of every unmasked pixel
        n_bad = int(_prepare(img, mask, sat, float(sign), 0.0, work))
        fill = 0.0
    bad = None
    if n_bad:
        bad = np.empty((H, W), np.bool_)
        _flag(img, mask, sat, bad)
        if not ok.any() and n_bad < img.size:
            fill = median(work[~bad].astype(np.float64))
            _prepare(img, mask, sat, float(sign), fill, work)  # again, with the fill level
    return work, bad, n_bad, fill


@njit(cache=True)
def second_differences(img, mask, k):
    """The second differences ``x[i-1] - 2 x[i] + x[i+1]`` along every ``k``-th row and
    every ``k``-th column of ``img`` (float64), those touching a masked pixel (``mask``, or
    NaN / infinite) left out: the samples of :func:`resection.markers.detect.estimate_noise`.
    ``mask`` of shape (0, 0): none."""
    H, W = img.shape
    use_mask = mask.shape[0] == H and mask.shape[1] == W
    nr, nc = (H + k - 1) // k, (W + k - 1) // k
    out = np.empty(nr * max(W - 2, 0) + nc * max(H - 2, 0))
    n = 0
    for i in range(0, H, k):  # along rows
        for j in range(W - 2):
            a, b, c = float(img[i, j]), float(img[i, j + 1]), float(img[i, j + 2])
            ok = math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
            if use_mask:
                ok = ok and not (mask[i, j] or mask[i, j + 1] or mask[i, j + 2])
            if ok:
                out[n] = a - 2.0 * b + c
                n += 1
    for i in range(H - 2):  # along columns
        for j in range(0, W, k):
            a, b, c = float(img[i, j]), float(img[i + 1, j]), float(img[i + 2, j])
            ok = math.isfinite(a) and math.isfinite(b) and math.isfinite(c)
            if use_mask:
                ok = ok and not (mask[i, j] or mask[i + 1, j] or mask[i + 2, j])
            if ok:
                out[n] = a - 2.0 * b + c
                n += 1
    return out[:n]


@lru_cache(maxsize=8)
def _eigenvalues(template: bytes, t: int, shape: tuple[int, int]) -> np.ndarray:
    """The DCT-II eigenvalues of the symmetric convolution with a (t, t) even template
    (given as float64 bytes), for a frame of ``shape``; float32, read-only."""
    T = np.frombuffer(template, dtype=np.float64).reshape(t, t)
    h = t // 2
    k = np.arange(-h, h + 1)
    H, W = shape
    cH = np.cos(np.pi * np.arange(H)[:, None] * k[None, :] / H)
    cW = np.cos(np.pi * np.arange(W)[:, None] * k[None, :] / W)
    lam = (cH @ T @ cW.T).astype(np.float32)
    lam.setflags(write=False)
    return lam


def merit(work: np.ndarray, template: np.ndarray) -> np.ndarray:
    """Correlation of the frame with an even template, mirror-extended at the borders.

    Equal to ``scipy.signal.correlate(np.pad(work, t // 2, mode="symmetric"), template,
    mode="valid")`` for a (t, t) template even in each axis (``template[::-1] == template``
    and ``template[:, ::-1] == template``), for any frame size (reflected again where the
    template is larger than the frame).

    Parameters
    ----------
    work : (H, W) float32 array
        The frame; overwritten (the transforms run in place).
    template : (t, t) float array, t odd
        The correlation template.

    Returns
    -------
    (H, W) float32 array
        The merit (it may share ``work``'s memory).
    """
    t = template.shape[0]
    lam = _eigenvalues(np.ascontiguousarray(template, dtype=np.float64).tobytes(), t,
                       work.shape)
    spec = sfft.dctn(work, type=2, overwrite_x=True)
    spec *= lam
    return sfft.idctn(spec, type=2, overwrite_x=True)
