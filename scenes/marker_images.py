"""Synthetic images of circular markers at known sub-pixel positions.

Each marker is a uniform disk, blurred by a Gaussian PSF and integrated exactly over each
square pixel (closed form along one axis, Gauss-Legendre quadrature along the other; see
``resection.markers._diskmodel``), added to a uniform background, then noised. Only a small window
around each disk is rendered, all disks at once (no Python loop over disks or pixels), so a
sequence of hundreds of frames renders in seconds.

Conventions: pixel ``(u, v)`` = (column, row), the centre of the top-left pixel at (0, 0),
images indexed ``img[v, u]``.

Signal-to-noise ratio: ``snr = contrast / noise_std`` where ``contrast`` is the marker's
depth (dark) or height (bright) relative to the background, and ``noise_std`` is the noise
standard deviation at the background level (Gaussian noise), or the shot noise there
(Poisson noise, with the photon gain chosen to give that standard deviation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.errors import InputError
from resection.markers import _diskmodel

__all__ = ["MarkerScene", "render_markers", "random_positions", "make_scene"]


@dataclass(frozen=True)
class MarkerScene:
    """A synthetic image and its truth."""

    image: np.ndarray  #: (H, W) image
    uv: np.ndarray  #: (N, 2) true centres, pixels
    diameter: np.ndarray  #: (N,) true diameters, pixels
    contrast: float  #: marker contrast, image units (positive)
    noise_std: float  #: noise standard deviation at the background, image units
    blur: float  #: PSF sigma, pixels


def render_markers(
    shape: tuple[int, int],
    uv,
    diameter,
    *,
    contrast: float = 100.0,
    background: float = 1000.0,
    polarity: str = "dark",
    blur: float = 0.7,
    snr: float | None = None,
    noise: str = "gaussian",
    rng: np.random.Generator | int | None = None,
    dtype=np.float32,
    nodes: int | None = None,
) -> np.ndarray:
    """Render disks on a uniform background, optionally with noise.

    Parameters
    ----------
    shape : (H, W)
        Image size, pixels.
    uv : (N, 2) array_like
        Disk centres, pixels.
    diameter : float or (N,) array_like
        Disk diameters, pixels.
    contrast : float
        Marker contrast (image units, > 0); the disk interior is ``background - contrast``
        (dark) or ``background + contrast`` (bright) before blur.
    background : float
        Background level.
    polarity : {"dark", "bright"}
    blur : float
        PSF standard deviation, pixels (>= 0; 0 means a sharp disk, pixel-integrated).
    snr : float, optional
        ``contrast / noise_std``; None for a noiseless image.
    noise : {"gaussian", "poisson"}
    rng : Generator or seed
    dtype : numpy dtype
        Output type; integer types are rounded and clipped to the type's range (a way to
        make saturated pixels).
    nodes : int, optional
        Quadrature size (default resolves the PSF; accuracy ~1e-5 of the contrast).

    Returns
    -------
    (H, W) ndarray of ``dtype``.
    """
    H, W = (int(shape[0]), int(shape[1]))
    if H <= 0 or W <= 0:
        raise InputError(f"shape: must be positive, got {shape}")
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    d = np.broadcast_to(np.asarray(diameter, dtype=float), (len(uv),))
    if np.any(~np.isfinite(uv)) or np.any(~(d > 0)):
        raise InputError("uv/diameter: must be finite, diameters positive")
    if polarity not in ("dark", "bright"):
        raise InputError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    if blur < 0:
        raise InputError(f"blur: must be >= 0, got {blur}")
    sign = -1.0 if polarity == "dark" else 1.0
    img = np.full((H, W), float(background))
    if len(uv):
        R = d / 2.0
        half = int(np.ceil(R.max() + 5.0 * max(blur, 0.05) + 2.0))
        ar = np.arange(-half, half + 1)
        iu = np.rint(uv[:, 0]).astype(int)
        iv = np.rint(uv[:, 1]).astype(int)
        gu = iu[:, None] + ar[None, :]
        gv = iv[:, None] + ar[None, :]
        q = nodes or _diskmodel.default_nodes(float(R.max()), max(blur, 0.02), accurate=True)
        M = _diskmodel.windows(uv[:, 0], uv[:, 1], R, max(blur, 0.02), gu, gv, q)
        rows = np.broadcast_to(gv[:, :, None], M.shape)
        cols = np.broadcast_to(gu[:, None, :], M.shape)
        ok = (rows >= 0) & (rows < H) & (cols >= 0) & (cols < W)
        flat = np.zeros(H * W)
        np.add.at(flat, rows[ok] * W + cols[ok], M[ok])
        img += sign * contrast * flat.reshape(H, W)
    noise_std = 0.0
    if snr is not None:
        if not snr > 0:
            raise InputError(f"snr: must be positive, got {snr}")
        gen = np.random.default_rng(rng)
        noise_std = contrast / float(snr)
        if noise == "gaussian":
            img = img + noise_std * gen.standard_normal(img.shape, dtype=np.float32)
        elif noise == "poisson":
            if background <= 0:
                raise InputError("poisson noise needs a positive background")
            gain = background / noise_std**2  # photons per image unit
            img = gen.poisson(np.clip(img, 0, None) * gain) / gain
        else:
            raise InputError(f"noise: expected 'gaussian' or 'poisson', got {noise!r}")
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        info = np.iinfo(dtype)
        img = np.clip(np.rint(img), info.min, info.max)
    return img.astype(dtype)


def random_positions(
    shape: tuple[int, int],
    n: int,
    *,
    min_separation: float = 20.0,
    margin: float = 10.0,
    rng: np.random.Generator | int | None = None,
) -> np.ndarray:
    """``n`` random centres, at least ``min_separation`` apart and ``margin`` from the edges
    (rejection sampling on a grid of candidates, vectorised)."""
    gen = np.random.default_rng(rng)
    H, W = shape
    pts = np.empty((0, 2))
    for _ in range(50):  # rounds of batched proposals, not a loop over points
        prop = np.column_stack(
            [gen.uniform(margin, W - 1 - margin, 4 * n), gen.uniform(margin, H - 1 - margin, 4 * n)]
        )
        allp = np.vstack([pts, prop])
        dist = np.hypot(*(allp[:, None, :] - allp[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(dist, np.inf)
        keep = np.ones(len(allp), bool)
        close = np.tril(dist < min_separation)  # conflicts with earlier points
        for i in np.flatnonzero(close.any(axis=1)):
            if keep[i] and np.any(close[i, :i] & keep[:i]):
                keep[i] = False
        pts = allp[keep][:n]
        if len(pts) >= n:
            return pts
    raise InputError(f"cannot place {n} markers {min_separation} px apart in {shape}")


def make_scene(
    shape: tuple[int, int] = (256, 256),
    n: int = 40,
    diameter: float = 6.0,
    *,
    snr: float = 30.0,
    blur: float = 0.7,
    contrast: float = 100.0,
    background: float = 1000.0,
    polarity: str = "dark",
    noise: str = "gaussian",
    min_separation: float | None = None,
    rng: np.random.Generator | int | None = None,
    dtype=np.float32,
) -> MarkerScene:
    """Random markers of one diameter on a noisy image, with the truth."""
    gen = np.random.default_rng(rng)
    sep = min_separation if min_separation is not None else 2.5 * diameter + 6
    uv = random_positions(shape, n, min_separation=sep, margin=diameter + 4, rng=gen)
    img = render_markers(
        shape, uv, diameter, contrast=contrast, background=background, polarity=polarity,
        blur=blur, snr=snr, noise=noise, rng=gen, dtype=dtype,
    )
    return MarkerScene(img, uv, np.full(len(uv), float(diameter)), contrast,
                       contrast / snr if snr else 0.0, blur)
