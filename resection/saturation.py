"""Saturated pixels: their true value is unknown, so they are masked, never used as values.

A pixel at the full scale of its format (255 in an 8-bit file, 65535 in a 16-bit one, ``2**bits
- 1`` for a sensor of ``bits`` bits), or at or above a level the user states
(``--saturation``), recorded less light than it received. Averaged onto a face it would pull
the face's value down by an unknown amount; corrected for self-illumination it would come
out as a plausible but wrong number. So such pixels are NaN where values are computed, the
faces they fall on are unknown (NaN, unseen) where a face's value is computed from its
pixels, and the commands count them and say so in one line (:func:`report`).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["faces_touched", "level_of", "mask_saturated", "report"]


def level_of(dtype, saturation=None, bits: int | None = None) -> float | None:
    """The saturation level of images of ``dtype``: ``saturation`` when given (a number),
    else the full scale of the sensor (``2**bits - 1``) or of the integer type; None for
    float images without a stated level (nothing is masked)."""
    if saturation is not None:
        try:
            level = float(saturation)
        except (TypeError, ValueError):
            raise InputError(f"saturation: expected a number, got {saturation!r}") from None
        if not np.isfinite(level):
            raise InputError(f"saturation: must be finite, got {saturation!r}")
        return level
    if bits is not None and int(bits) > 0:
        return float(2 ** int(bits) - 1)
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        return float(np.iinfo(dtype).max)
    return None


def mask_saturated(image, level: float | None) -> tuple[np.ndarray, np.ndarray]:
    """``(float32 image with the saturated pixels NaN, boolean mask of them)`` (float32 as
    :func:`resection.io.images.read_image` and the frame readers give); ``level`` None
    masks nothing."""
    img = np.asarray(image)
    sat = np.zeros(img.shape, bool) if level is None else (img >= level)
    out = img.astype(np.float32)
    out[sat] = np.nan
    return out, sat


def faces_touched(face_index: np.ndarray, on_model: np.ndarray, saturated: np.ndarray,
                  n_faces: int) -> np.ndarray:
    """``(n_faces,)`` or ``(T, n_faces)`` bool: the faces at least one saturated pixel of
    the model falls on (``face_index``, ``on_model``: a surface map's per-pixel face and
    mask; ``saturated``: ``(H, W)`` or ``(T, H, W)``)."""
    sat = np.asarray(saturated, bool)
    if sat.shape[-2:] != np.shape(on_model):
        raise InputError(f"image: shape {sat.shape[-2:]} is not the camera's (H, W) = "
                         f"{np.shape(on_model)}")
    stack = sat if sat.ndim == 3 else sat[None]
    out = np.zeros((len(stack), n_faces), bool)
    for t, s in enumerate(stack):  # loop over frames, not pixels
        hit = s & on_model
        out[t, np.unique(face_index[hit])] = True
    return out if sat.ndim == 3 else out[0]


def report(n_pixels: int, level: float | None, n_faces: int | None = None) -> str | None:
    """The one line that says what was masked, or None when nothing was."""
    if not n_pixels:
        return None
    faces = "" if n_faces is None else f", {n_faces} faces unknown"
    return (f"saturated pixels: {n_pixels} at or above {level:g} masked as unknown "
            f"(not corrected, not averaged{faces})")
