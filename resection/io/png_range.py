"""Float images to 16-bit PNG, by a stated linear map (``backproject --png-range``).

PNG holds integers (8 or 16 bits) and no NaN. A float image (interpolated surface values,
NaN off the model) is written to PNG only

* as it is, when every pixel is finite and already an integer in 0..65535 (e.g. counts
  backprojected with ``--interpolation nearest`` over a camera image), or
* through a stated linear map: ``--png-range MIN,MAX`` (or ``auto``: the image's finite
  minimum and maximum) sends MIN to 1 and MAX to 65535, ``count = 1 + round((v - MIN) /
  (MAX - MIN) * 65534)``, values outside clipped; NaN pixels get 0. The map is printed, so
  that ``v = MIN + (count - 1) / 65534 * (MAX - MIN)`` reads the values back.

Otherwise the write is refused with these choices (or a float ``.tif`` / ``.npy``).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["parse_png_range", "png_counts"]


def parse_png_range(text: str | None):
    """``None``, ``"auto"`` or ``(MIN, MAX)`` from the option's text."""
    if text is None or text.strip().lower() == "auto":
        return None if text is None else "auto"
    try:
        lo, hi = (float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"--png-range: expected MIN,MAX or auto, got {text!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
        raise InputError(f"--png-range: need finite MIN < MAX, got {text!r}")
    return lo, hi


def png_counts(image: np.ndarray, png_range, out: str) -> tuple[np.ndarray, str]:
    """The uint16 image to write to the PNG ``out`` and a sentence saying how it was made.

    Parameters
    ----------
    image : (H, W) float array
    png_range : None, "auto" or (MIN, MAX)
        See the module docstring.

    Raises
    ------
    InputError
        ``png_range`` is None and the image is not finite integers in 0..65535; or "auto"
        with no finite pixel.
    """
    img = np.asarray(image, dtype=np.float64)
    finite = np.isfinite(img)
    if png_range is None:
        if finite.all() and img.size and img.min() >= 0 and img.max() <= 65535 \
                and np.all(img == np.rint(img)):
            return img.astype(np.uint16), "integer values written as they are"
        vals = img[finite]
        what = (f"values {vals.min():.6g}..{vals.max():.6g}" if vals.size else "no value")
        nan = f", {int((~finite).sum())} NaN pixels" if (~finite).any() else ""
        raise InputError(f"{out}: PNG holds integers 0..65535 and no NaN; the image has "
                         f"{what}{nan}: write .tif or .npy (float, NaN kept), or give "
                         "--png-range auto (or MIN,MAX) to map values linearly to 1..65535 "
                         "with NaN as 0")
    if png_range == "auto":
        if not finite.any():
            raise InputError(f"{out}: --png-range auto: the image has no finite value")
        lo, hi = float(img[finite].min()), float(img[finite].max())
        if hi == lo:
            hi = lo + 1.0
    else:
        lo, hi = png_range
    scaled = 1.0 + np.rint((np.clip(img, lo, hi) - lo) / (hi - lo) * 65534.0)
    counts = np.where(finite, scaled, 0.0).astype(np.uint16)
    return counts, (f"PNG counts: {lo:.9g} -> 1, {hi:.9g} -> 65535, linear "
                    f"(v = {lo:.9g} + (count - 1) / 65534 * {hi - lo:.9g}), NaN -> 0")
