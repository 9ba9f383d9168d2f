"""The frame's dark border: rows and columns at a frame's edges that hold no light (a
sensor's masked or unread lines, a frame padded out to its size, a lens that does not
cover the sensor's corners).

Mapped as they are they read as a few counts: a face seen there would get a value near
zero, as if its paint were black. So the lines of such a border are found from the frame
itself and masked as unknown (NaN: in no face's value) by :func:`mask_dark_border`, and
the commands say what they masked (:func:`border_report`).

A line (row or column) belongs to the border when it is dark almost all along (its 90th
percentile within :data:`DARK_SHARE` of the frame's range above its darkest level, the
0.1th percentile, itself at most :data:`DARK_LEVEL` of the lit level) and every line
between it and the edge is too; at most
:data:`MAX_BORDER_SHARE` of the frame's height or width is taken from each side. Dark
background along an edge is masked too, which costs nothing: no face is seen there.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DARK_LEVEL", "DARK_SHARE", "MAX_BORDER_SHARE", "border_report", "dark_border",
           "mask_dark_border"]

#: A border line's 90th percentile lies within this share of the frame's range (0.1th to
#: 99th percentile) above the darkest level: 60 counts of a 12-bit frame lit to 3,000.
DARK_SHARE = 0.02
#: At most this share of the frame's rows (columns) is taken from each side.
MAX_BORDER_SHARE = 0.05
#: The frame's darkest level must be at most this share of its lit level (99th
#: percentile) for a border to be looked for: light frames have one (no light: a few
#: counts, or the black level); a ramp or a field of other values has none.
DARK_LEVEL = 0.1


def dark_border(image) -> tuple[int, int, int, int]:
    """Rows and columns of the dark border of a frame: ``(top, bottom, left, right)``.

    Parameters
    ----------
    image : (H, W) array_like
        Counts (NaN: unknown, e.g. saturated).

    Returns
    -------
    tuple of 4 int
        Border rows at the top and the bottom, columns at the left and the right.
    """
    img = np.asarray(image)
    H, W = img.shape
    # the levels from a regular sample of about 20,000 pixels (a threshold, not a
    # statistic: a sample is enough, and a frame of a long run costs a few ms)
    step = max(1, img.size // 20_000)
    sample = img.reshape(-1)[::step].astype(np.float64)
    fin = sample[np.isfinite(sample)]
    if fin.size == 0:
        return 0, 0, 0, 0
    low, high = np.percentile(fin, [0.1, 99.0])
    if not (high > 0 and 0 <= low <= DARK_LEVEL * high):
        return 0, 0, 0, 0  # no dark level to tell (one level, a ramp, signed values)
    limit = low + DARK_SHARE * (high - low)

    def dark(lines: np.ndarray) -> np.ndarray:
        """Whether each line's 90th percentile is within the limit: at most a tenth of its
        finite pixels above it (a count, not a sort)."""
        x = np.asarray(lines)
        fin = np.isfinite(x)
        n = fin.sum(axis=1)
        with np.errstate(invalid="ignore"):
            over = (x > limit).sum(axis=1)
        return (n > 0) & (over <= 0.1 * n)

    def side(lines: np.ndarray) -> int:
        """Leading dark lines of ``lines`` (k, n), the edge's line first (the others
        looked at only when the edge's line is dark: most frames have no border)."""
        if not dark(lines[:1])[0]:
            return 0
        d = dark(lines)
        return int(np.argmin(d)) if not d.all() else len(d)

    kh, kw = max(1, int(MAX_BORDER_SHARE * H)), max(1, int(MAX_BORDER_SHARE * W))
    return (side(img[:kh]), side(img[::-1][:kh]), side(img.T[:kw]),
            side(img.T[::-1][:kw]))


def mask_dark_border(image, *, inplace: bool = False
                     ) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """``(float32 image with its dark border NaN, (top, bottom, left, right))``
    (:func:`dark_border`): a copy, or ``image`` itself when ``inplace`` and it is a
    float32 array already (a frame the caller owns)."""
    out = np.asarray(image, dtype=np.float32) if inplace else \
        np.array(image, dtype=np.float32)
    top, bottom, left, right = dark_border(out)
    if not (top or bottom or left or right):
        return out, (0, 0, 0, 0)
    H, W = out.shape
    out[:top] = np.nan
    out[H - bottom:] = np.nan
    out[:, :left] = np.nan
    out[:, W - right:] = np.nan
    return out, (top, bottom, left, right)


def border_report(border: tuple[int, int, int, int], source: str) -> str | None:
    """The one line that says what was masked (None when nothing was)."""
    if not any(border):
        return None
    names = ("rows at the top", "rows at the bottom", "columns at the left",
             "columns at the right")
    parts = [f"{n} {what}" for n, what in zip(border, names, strict=True) if n]
    return (f"{source}: a dark border masked as unknown ({', '.join(parts)}: no light "
            "there, not mapped)")
