"""The pictures of ``selfillum psp --uncertainty``, drawn with Pillow: the standard
uncertainty on the model as a camera sees it, with a colour bar (:func:`map_picture`), and
the budget chart (:func:`budget_chart`).

No plotting library is imported: the picture is the camera's surface map (already cast
for the measurement) coloured pixel by pixel, so that the pictures cost a small part of
the command (issue 36: the uncertainty adds at most 30 % to ``psp``). The colour map is
Green's *cubehelix* (Bull. Astr. Soc. India 39, 2011), a closed form whose lightness grows
monotonically with the value, readable in grey too.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cubehelix", "map_picture", "budget_chart"]

BACKGROUND = (255, 255, 255)
OFF_MODEL = (215, 215, 215)
INK = (0, 0, 0)


def cubehelix(t, start: float = 0.5, rotations: float = -1.5, hue: float = 1.2,
              lo: float = 0.12, hi: float = 0.92) -> np.ndarray:
    """(..., 3) uint8 colours of ``t`` in [0, 1] (clipped), lightness from ``lo`` to
    ``hi``."""
    t = np.clip(np.asarray(t, np.float64), 0.0, 1.0)
    lam = lo + (hi - lo) * t
    a = hue * lam * (1.0 - lam) / 2.0
    phi = 2.0 * np.pi * (start / 3.0 + rotations * t)
    c, s = np.cos(phi), np.sin(phi)
    rgb = np.stack([lam + a * (-0.14861 * c + 1.78277 * s),
                    lam + a * (-0.29227 * c - 0.90649 * s),
                    lam + a * (1.97294 * c)], axis=-1)
    return np.round(255.0 * np.clip(rgb, 0.0, 1.0)).astype(np.uint8)


def _font():
    from PIL import ImageFont

    return ImageFont.load_default()


def map_picture(smap, face_values, path, title: str, label: str) -> None:
    """PNG of ``face_values`` (F,) on the model through ``smap``'s camera (grey off the
    faces with a value), colours from 0 to the 99th percentile (above it: the top colour),
    with a colour bar labelled ``label`` and ``title`` above."""
    from PIL import Image, ImageDraw

    img = np.asarray(smap.to_image(np.asarray(face_values, np.float64)), np.float64)
    fin = img[np.isfinite(img)]
    vmax = float(np.percentile(fin, 99)) if fin.size else 1.0
    vmax = vmax if vmax > 0 else (float(fin.max()) if fin.size and fin.max() > 0 else 1.0)
    rgb = np.empty(img.shape + (3,), np.uint8)
    rgb[...] = OFF_MODEL
    ok = np.isfinite(img)
    rgb[ok] = cubehelix(img[ok] / vmax)
    H, W = img.shape
    top, bar_w, right = 24, 16, 110
    canvas = Image.new("RGB", (W + right, H + top + 18), BACKGROUND)
    canvas.paste(Image.fromarray(rgb), (0, top))
    draw = ImageDraw.Draw(canvas)
    font = _font()
    draw.text((6, 6), title, fill=INK, font=font)
    # the colour bar: value 0 at the bottom
    ramp = cubehelix(np.linspace(1.0, 0.0, H))[:, None, :].repeat(bar_w, axis=1)
    x0 = W + 12
    canvas.paste(Image.fromarray(ramp), (x0, top))
    draw.rectangle((x0, top, x0 + bar_w - 1, top + H - 1), outline=INK)
    for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
        y = top + round((1.0 - frac) * (H - 1))
        draw.line((x0 + bar_w, y, x0 + bar_w + 3, y), fill=INK)
        draw.text((x0 + bar_w + 6, y - 5), f"{frac * vmax:.3g}", fill=INK, font=font)
    draw.text((x0, top + H + 4), label, fill=INK, font=font)
    canvas.save(path, format="PNG", compress_level=1)  # zlib level 1: fast


def budget_chart(budget, path, area=None, mask=None) -> None:
    """PNG bar chart of each source's share of the variance over the painted area
    (:func:`selfillum.uncertainty.budget.shares`), largest first, with the median of its
    standard uncertainty."""
    from PIL import Image, ImageDraw

    from selfillum.uncertainty.budget import shares

    sh = shares(budget.parts, area, mask)
    names = sorted(sh, key=sh.get, reverse=True)
    ok = np.ones(len(budget.combined), bool) if mask is None else np.asarray(mask, bool)
    row, left, bar_max, top = 22, 150, 300, 34
    canvas = Image.new("RGB", (left + bar_max + 190, top + row * len(names) + 26),
                       BACKGROUND)
    draw = ImageDraw.Draw(canvas)
    font = _font()
    draw.text((8, 8), f"{budget.quantity} uncertainty budget ({budget.method}, k = 1): "
              "share of the variance over the painted area", fill=INK, font=font)
    colours = cubehelix(np.linspace(0.15, 0.75, max(len(names), 1)))
    for i, name in enumerate(names):
        y = top + i * row
        v = np.asarray(budget.parts[name])[ok]
        v = v[np.isfinite(v)]
        med = float(np.median(v)) if v.size else float("nan")
        draw.text((8, y + 5), name, fill=INK, font=font)
        w = round(bar_max * sh[name])
        if w > 0:
            draw.rectangle((left, y + 3, left + w, y + row - 4),
                           fill=tuple(int(c) for c in colours[i]))
        draw.text((left + w + 6, y + 5), f"{100 * sh[name]:.1f} %  median {med:.3g}",
                  fill=INK, font=font)
    y = top + row * len(names) + 6
    draw.line((left, top - 2, left, y), fill=INK)
    draw.text((left, y + 2), "0 %", fill=INK, font=font)
    draw.text((left + bar_max - 18, y + 2), "100 %", fill=INK, font=font)
    canvas.save(path, format="PNG", compress_level=1)  # zlib level 1: fast
