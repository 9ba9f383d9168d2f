"""Photon shot noise and read noise of the camera's pixels: :class:`PixelNoise`.

Model: a pixel of ``I`` counts (dark level removed) holds ``I g`` photo-electrons (``g``
the conversion gain, e-/count), Poisson, plus a read noise of ``sigma_r`` electrons, so

``var(I) = I / g + (sigma_r / g)^2``  (counts^2),

and the mean of ``n`` frames has ``var / n``. ``g`` and ``sigma_r`` are the stated
``camera_gain`` and ``read_noise``; without them they are estimated from several frames of
one condition (the photon transfer curve: the temporal variance of each pixel against its
mean, a straight line ``var = I / g + c`` fitted over the pixels,
:func:`estimate_noise`). Left out: fixed-pattern noise (it cancels in the wind-off /
wind-on ratio of the same pixels), the camera's non-linearity, and any spatial correlation
of the noise (the pixels are taken as independent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.errors import InputError

__all__ = ["PixelNoise", "estimate_noise", "frame_mean"]


@dataclass(frozen=True)
class PixelNoise:
    """``var(I) = I / gain + (read_noise / gain)^2`` counts^2 for one frame.

    Attributes
    ----------
    gain : float
        e-/count.
    read_noise : float
        Electrons RMS.
    source : str
        ``"stated"`` or how it was estimated.
    """

    gain: float
    read_noise: float
    source: str = "stated"

    def variance(self, image, frames: int = 1) -> np.ndarray:
        """Variance (counts^2) of each pixel of ``image`` (counts), the mean of ``frames``
        frames (NaN stays NaN)."""
        I = np.asarray(image, dtype=np.float64)
        return (np.maximum(I, 0.0) / self.gain + (self.read_noise / self.gain) ** 2) / frames


def frame_mean(stack, name: str) -> tuple[np.ndarray, int, np.ndarray | None]:
    """Mean image of a ``(n, H, W)`` stack (or one ``(H, W)`` image), the number of frames,
    and the per-pixel temporal variance (None for one frame)."""
    a = np.asarray(stack, dtype=np.float64)
    if a.ndim == 2:
        return a, 1, None
    if a.ndim != 3 or a.shape[0] < 1:
        raise InputError(f"{name}: expected an image or a stack of images, got shape {a.shape}")
    if a.shape[0] == 1:
        return a[0], 1, None
    return a.mean(axis=0), a.shape[0], a.var(axis=0, ddof=1)


def estimate_noise(means, variances, name: str = "frames") -> PixelNoise:
    """Gain and read noise from the photon transfer curve of several stacks.

    Parameters
    ----------
    means, variances : sequence of (H, W) arrays
        Each stack's temporal mean and variance per pixel (counts, counts^2).

    Fits ``var = I / g + c`` by least squares over the finite pixels (binned by level, so
    that the fit is not dominated by the most common level), ``read_noise = g sqrt(c)``
    (0 if ``c <= 0``). Raises :class:`InputError` when the levels do not spread enough to
    separate the two terms and the fitted slope is not positive.
    """
    m = np.concatenate([np.asarray(x, np.float64).ravel() for x in means])
    v = np.concatenate([np.asarray(x, np.float64).ravel() for x in variances])
    ok = np.isfinite(m) & np.isfinite(v) & (m > 0)
    if ok.sum() < 10:
        raise InputError(f"{name}: too few pixels to estimate the camera noise")
    m, v = m[ok], v[ok]
    edges = np.unique(np.quantile(m, np.linspace(0, 1, 33)))
    idx = np.clip(np.searchsorted(edges, m, side="right") - 1, 0, len(edges) - 2)
    cnt = np.bincount(idx, minlength=len(edges) - 1)
    use = cnt > 0
    mb = np.bincount(idx, m, len(edges) - 1)[use] / cnt[use]
    vb = np.bincount(idx, v, len(edges) - 1)[use] / cnt[use]
    if mb.size >= 2 and np.ptp(mb) > 0.05 * mb.mean():
        slope, c = np.polyfit(mb, vb, 1, w=np.sqrt(cnt[use]))
    else:  # one level: all of the variance taken as shot noise (read noise not separable)
        slope, c = float(vb.mean() / mb.mean()), 0.0
    if not slope > 0:
        raise InputError(f"{name}: the pixels' temporal variance does not grow with their "
                         "level (fitted slope <= 0): give --u camera_gain=.. and read_noise")
    g = 1.0 / slope
    return PixelNoise(g, float(g * np.sqrt(c)) if c > 0 else 0.0,
                      "estimated from the frames' temporal variance")
