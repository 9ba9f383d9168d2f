"""Reading the frames of a sequence."""

from __future__ import annotations

import os

import numpy as np

from ..errors import InputError


def _load_image(frame) -> np.ndarray:
    if isinstance(frame, np.ndarray):
        img = frame
    else:
        from ..io.images import read_image

        img = read_image(frame, mask_saturated=True)  # saturated pixels -> NaN, masked
    if img.ndim != 2:
        raise InputError(f"expected a 2-D image, got shape {img.shape}")
    return img


def _frame_name(frame) -> str:
    return "" if isinstance(frame, np.ndarray) else os.fspath(frame)
