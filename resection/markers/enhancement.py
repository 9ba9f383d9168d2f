"""Enhancement of low-contrast images (infrared thermography) before marker detection.

Three operations, over the whole image or only inside given windows (``(u_min, v_min,
u_max, v_max)`` inclusive pixel boxes, e.g. around the predicted markers), NaN-aware:

* :func:`subtract_background`: remove the large-scale background (heating pattern,
  vignetting offset) estimated by a coarse median (block medians, bilinearly interpolated)
  or a normalised Gaussian filter;
* :func:`normalize_contrast`: local contrast normalisation ``(I - mean) / std`` over a
  Gaussian neighbourhood, which equalises markers seen under very different gains;
* :func:`clahe`: contrast-limited adaptive histogram equalisation (tile histograms clipped
  and redistributed, per-pixel bilinear blend of the four nearest tile mappings).

All return ``float32`` arrays of the input's shape; NaN pixels stay NaN. Pixel conventions:
``img[v, u]``.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import ndimage
from scipy.interpolate import RectBivariateSpline

from resection.errors import InputError

__all__ = ["subtract_background", "normalize_contrast", "clahe", "enhance"]


def _as_float(image) -> np.ndarray:
    img = np.asarray(image)
    if img.dtype == np.bool_ or img.dtype.kind not in "uif":
        raise InputError(f"image: expected a numeric image, got dtype {img.dtype}")
    if img.ndim != 2:
        raise InputError(f"image: expected a 2-D array, got shape {img.shape}")
    img = img.astype(np.float64)
    if not np.isfinite(img).any():
        raise InputError("image: no finite pixel")
    return img


def _positive(name, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a number, got {value!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise InputError(f"{name}: must be positive, got {value!r}")
    return v


def _gauss_nan(img, sigma):
    """Normalised Gaussian filter ignoring NaN: (mean, valid weight)."""
    ok = np.isfinite(img)
    num = ndimage.gaussian_filter(np.where(ok, img, 0.0), sigma, mode="reflect")
    den = ndimage.gaussian_filter(ok.astype(float), sigma, mode="reflect")
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den, den


def _background(img: np.ndarray, size: float, method: str) -> np.ndarray:
    if method == "gaussian":
        mean, _ = _gauss_nan(img, size / 2.0)
        return mean
    if method != "median":
        raise InputError(f"method: expected 'median' or 'gaussian', got {method!r}")
    H, W = img.shape
    b = max(int(round(size)), 1)
    nv, nu = -(-H // b), -(-W // b)
    pad = np.full((nv * b, nu * b), np.nan)
    pad[:H, :W] = img
    blocks = pad.reshape(nv, b, nu, b).transpose(0, 2, 1, 3).reshape(nv, nu, b * b)
    with warnings.catch_warnings():  # all-NaN blocks are handled below
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(blocks, axis=2)
    if np.isnan(med).any():  # blocks without a finite pixel: fill from the neighbours
        idx = ndimage.distance_transform_edt(np.isnan(med), return_distances=False,
                                             return_indices=True)
        med = med[tuple(idx)]
    # block centres at (k + 0.5) b - 0.5 (the last block is partial: its pixels' mean
    # position); bilinear interpolation back to every pixel, linear extrapolation at the edges
    cv = np.minimum((np.arange(nv) + 0.5) * b, (np.arange(nv) * b + H) / 2.0) - 0.5
    cu = np.minimum((np.arange(nu) + 0.5) * b, (np.arange(nu) * b + W) / 2.0) - 0.5
    if nv == 1 and nu == 1:
        return np.full((H, W), med[0, 0])
    # smooth (cubic where there are enough blocks) so that no kink looks like a marker;
    # the spline's boundary polynomials extrapolate to the image edges
    kv, ku = min(3, nv - 1) or 1, min(3, nu - 1) or 1
    if nv == 1:
        med, cv = np.vstack([med, med]), np.array([-0.5, H - 0.5])
    if nu == 1:
        med, cu = np.hstack([med, med]), np.array([-0.5, W - 0.5])
    spl = RectBivariateSpline(cv, cu, med, kx=kv, ky=ku,
                              bbox=[min(cv[0], -0.5), max(cv[-1], H - 0.5),
                                    min(cu[0], -0.5), max(cu[-1], W - 0.5)])
    return spl(np.arange(H, dtype=float), np.arange(W, dtype=float))


def _in_windows(func, img, windows, **kw):
    """Apply ``func`` to the whole image, or to each window separately (rest untouched)."""
    if windows is None:
        return func(img, **kw)
    out = img.copy()
    H, W = img.shape
    arr = np.asarray(windows, dtype=float)
    if arr.ndim == 1:
        arr = arr[None]
    if arr.ndim != 2 or arr.shape[1] != 4 or not np.all(np.isfinite(arr)):
        raise InputError("windows: expected boxes (u_min, v_min, u_max, v_max)")
    for u0, v0, u1, v1 in np.rint(arr).astype(int).tolist():  # a loop over windows, not pixels
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)
        if u1 <= u0 or v1 <= v0:
            raise InputError(f"windows: box {(u0, v0, u1, v1)} is empty or outside the image")
        out[v0:v1 + 1, u0:u1 + 1] = func(img[v0:v1 + 1, u0:u1 + 1], **kw)
    return out


def subtract_background(image, size: float = 31.0, *, method: str = "median",
                        windows=None) -> np.ndarray:
    """Image minus its large-scale background.

    Parameters
    ----------
    image : (H, W) array_like
    size : float
        Scale of the background, pixels: block size of the median (``"median"``), twice the
        Gaussian sigma (``"gaussian"``). Take it several times the marker diameter.
    method : {"median", "gaussian"}
        The median ignores markers and defects; the Gaussian is smoother.
    windows : sequence of (u_min, v_min, u_max, v_max), optional
        Process only inside these boxes (each on its own); the rest is returned unchanged.

    Returns
    -------
    (H, W) float32 array, about 0 on the background.
    """
    img = _as_float(image)
    size = _positive("size", size)
    return _in_windows(lambda x: x - _background(x, size, method), img, windows).astype(
        np.float32)


def normalize_contrast(image, size: float = 15.0, *, eps: float | None = None,
                       windows=None) -> np.ndarray:
    """Local contrast normalisation ``(I - m) / sqrt(s^2 + eps^2)``.

    ``m`` and ``s`` are the mean and standard deviation over a Gaussian neighbourhood of
    sigma ``size / 2`` pixels (NaN ignored). ``eps`` (image units, default 1e-3 of the
    image's robust spread) keeps flat regions from blowing up.
    """
    img = _as_float(image)
    size = _positive("size", size)

    def f(x):
        mean, _ = _gauss_nan(x, size / 2.0)
        sq, _ = _gauss_nan(x * x, size / 2.0)
        var = np.clip(sq - mean * mean, 0, None)
        e = eps
        if e is None:
            fin = x[np.isfinite(x)]
            e = 1e-3 * max(float(np.subtract(*np.percentile(fin, [99, 1]))), 1e-12)
        return (x - mean) / np.sqrt(var + e * e)

    return _in_windows(f, img, windows).astype(np.float32)


def clahe(image, tiles: tuple[int, int] = (8, 8), *, clip_limit: float = 2.0, bins: int = 256,
          windows=None) -> np.ndarray:
    """Contrast-limited adaptive histogram equalisation, output in [0, 1].

    Parameters
    ----------
    tiles : (nv, nu)
        Number of tiles along v and u.
    clip_limit : float
        Histogram bins are clipped at ``clip_limit`` times the mean bin count; the excess is
        spread evenly (1 gives plain intensity rescaling, large values plain equalisation).
    bins : int
        Grey levels of the histograms (the image is scaled to its finite min..max).
    """
    img = _as_float(image)
    clip_limit = _positive("clip_limit", clip_limit)
    try:
        nv, nu = (int(t) for t in tiles)
    except (TypeError, ValueError):
        raise InputError(f"tiles: expected (nv, nu), got {tiles!r}") from None
    if nv < 1 or nu < 1 or int(bins) < 2:
        raise InputError("tiles and bins: must be positive (bins >= 2)")

    def f(x):
        H, W = x.shape
        tv, tu = min(nv, H), min(nu, W)
        ok = np.isfinite(x)
        lo, hi = np.nanmin(x), np.nanmax(x)
        q = np.zeros(x.shape, int)
        if hi > lo:
            scaled = np.where(ok, (x - lo) / (hi - lo), 0.0)
            q = np.clip(np.floor(scaled * bins).astype(int), 0, bins - 1)
        # tile index of every pixel, histograms of all tiles in one bincount
        iv = np.minimum(np.arange(H) * tv // H, tv - 1)
        iu = np.minimum(np.arange(W) * tu // W, tu - 1)
        tile = iv[:, None] * tu + iu[None, :]
        hist = np.bincount((tile * bins + q)[ok], minlength=tv * tu * bins).reshape(
            tv * tu, bins).astype(float)
        count = hist.sum(axis=1, keepdims=True)
        limit = np.maximum(clip_limit * count / bins, 1.0)
        excess = np.clip(hist - limit, 0, None).sum(axis=1, keepdims=True)
        hist = np.minimum(hist, limit) + excess / bins
        cdf = np.cumsum(hist, axis=1)
        cdf = (cdf - hist / 2.0) / np.maximum(cdf[:, -1:], 1e-12)  # mid-bin, in (0, 1)
        maps = cdf.reshape(tv, tu, bins)
        # bilinear blend between the four nearest tile centres
        cv = (np.arange(tv) + 0.5) * H / tv - 0.5
        cu = (np.arange(tu) + 0.5) * W / tu - 0.5
        fv = np.clip(np.interp(np.arange(H), cv, np.arange(tv)), 0, tv - 1)
        fu = np.clip(np.interp(np.arange(W), cu, np.arange(tu)), 0, tu - 1)
        v0 = np.floor(fv).astype(int)
        u0 = np.floor(fu).astype(int)
        v1, u1 = np.minimum(v0 + 1, tv - 1), np.minimum(u0 + 1, tu - 1)
        wv, wu = (fv - v0)[:, None], (fu - u0)[None, :]
        V0, V1 = v0[:, None], v1[:, None]
        U0, U1 = u0[None, :], u1[None, :]
        out = ((1 - wv) * (1 - wu) * maps[V0, U0, q] + (1 - wv) * wu * maps[V0, U1, q]
               + wv * (1 - wu) * maps[V1, U0, q] + wv * wu * maps[V1, U1, q])
        return np.where(ok, out, np.nan)

    return _in_windows(f, img, windows).astype(np.float32)


def enhance(image, method: str = "background", *, windows=None, **kwargs) -> np.ndarray:
    """Dispatch to :func:`subtract_background` (``"background"``),
    :func:`normalize_contrast` (``"normalize"``) or :func:`clahe` (``"clahe"``)."""
    funcs = {"background": subtract_background, "normalize": normalize_contrast,
             "clahe": clahe}
    if method not in funcs:
        raise InputError(f"method: expected one of {sorted(funcs)}, got {method!r}")
    return funcs[method](image, windows=windows, **kwargs)
