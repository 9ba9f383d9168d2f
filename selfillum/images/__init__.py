"""The camera-image stage: self-illumination removed from camera images.

Takes in camera images, their cameras (:mod:`resection`) and a mesh; gives out corrected
images and per-face fields: one image (:func:`correct_image`), several cameras merged
(:func:`merge_views`), and the PSP workflow (:func:`psp_images`, Stern-Volmer on taps).
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "DEFAULT_MAX_OBLIQUENESS": ".image_correction",
    "ImageCorrection": ".image_correction",
    "MergedViews": ".multiview",
    "Overlap": ".multiview",
    "PSPResult": ".psp",
    "SternVolmer": ".psp",
    "Taps": ".psp",
    "UnseenFacesWarning": ".image_correction",
    "correct_image": ".image_correction",
    "correct_image_file": ".image_correction",
    "fit_stern_volmer": ".psp",
    "merge_views": ".multiview",
    "psp_images": ".psp",
    "psp_pressure": ".psp",
    "read_reflectance": ".image_correction",
    "read_taps": ".psp",
    "tap_faces": ".psp",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
