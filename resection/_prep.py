"""Preparation of a frame for marker detection, and the merit image. Internal module of
:func:`resection.markers.detect_markers`.

* :func:`prepare`: one compiled pass over the (integer or float) frame: the masked pixels
  (NaN, infinite, saturated, user mask) are flagged, the sign of dark markers flipped, the
  fill level subtracted (masked pixels read 0, the fill level), and the result written as
  float32 twice: once for the fit, once as the input of the merit's transform (which
  overwrites it). No float64 copy of the frame. The float32 values are exact for 8- and
  16-bit frames (integers under 2^24, the fill level a half-integer).
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
def _prepare(img, mask, sat, sign, fill, out_a, out_b, bad):
    """The compiled pass of :func:`prepare`; returns the number of masked pixels."""
    H, W = img.shape
    use_mask = mask.shape[0] == H and mask.shape[1] == W
    n_bad = 0
    for i in range(H):
        for j in range(W):
            x = float(img[i, j])
            b = not (math.isfinite(x) and x < sat)
            if use_mask and mask[i, j]:
                b = True
            if b:
                n_bad += 1
                val = 0.0
            else:
                val = sign * x - fill
            bad[i, j] = b
            out_a[i, j] = val
            out_b[i, j] = val
    return n_bad


def prepare(img: np.ndarray, mask: np.ndarray | None, saturation: float | None,
            sign: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float]:
    """Masked pixels, fill level and the frame as float32, in one pass.

    Parameters
    ----------
    img : (H, W) integer or float array
        The searched part of the frame.
    mask : (H, W) bool array or None
        True where pixels must be ignored.
    saturation : float or None
        Pixels ``>=`` this value are masked (None: none; NaN and infinite pixels always).
    sign : float
        -1 for dark markers (the frame is negated), +1 for bright ones.

    Returns
    -------
    signal : (H, W) float32 array
        ``sign * img - fill``, 0 at masked pixels.
    work : (H, W) float32 array
        The same values, in a buffer with a padded row stride (the input of :func:`merit`,
        which overwrites it).
    bad : (H, W) bool array
        Masked pixels.
    n_bad : int
        Their number.
    fill : float
        Fill level, image units after the sign: the median of a regular subsample of about
        16,000 unmasked pixels (of all unmasked pixels if the subsample has none).
    """
    if img.dtype.kind == "f" and img.dtype.itemsize not in (4, 8):  # half, long double
        img = img.astype(np.float64)
    elif not img.dtype.isnative:
        img = img.astype(img.dtype.newbyteorder("="))
    if mask is not None:
        mask = np.ascontiguousarray(mask, dtype=np.bool_)
    H, W = img.shape
    sat = np.inf if saturation is None else float(saturation)
    m = np.zeros((0, 0), np.bool_) if mask is None else mask
    # the fill level from a regular subsample (masked pixels of the subsample left out)
    k = max(1, int(np.sqrt(img.size / 16_000)))
    sub = np.asarray(img[::k, ::k], dtype=np.float64)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(sub) & (sub < sat)
    if mask is not None:
        ok &= ~mask[::k, ::k]
    signal = np.empty((H, W), np.float32)
    work = np.empty((H, W + _STRIDE_PAD), np.float32)[:, :W]
    bad = np.empty((H, W), np.bool_)
    if ok.any():
        fill = float(np.median(sign * sub[ok]))
        n_bad = int(_prepare(img, m, sat, float(sign), fill, work, signal, bad))
    else:  # the whole subsample is masked: the median of every unmasked pixel
        n_bad = int(_prepare(img, m, sat, float(sign), 0.0, work, signal, bad))
        good = ~bad
        fill = float(np.median(signal[good])) if n_bad < img.size else 0.0
        signal[good] -= np.float32(fill)
        work[good] -= np.float32(fill)
    return signal, work, bad, n_bad, fill


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
