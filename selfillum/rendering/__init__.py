"""Mitsuba 3 renders of a painted model: the independent reference.

Takes in a mesh, per-face emission and reflectance and a :class:`~resection.camera.Camera`;
gives out an image rendered with all bounces or emission only (:func:`render`).
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "RenderResult": ".mitsuba_render",
    "available_variants": "selfillum.mitsuba_variants",
    "choose_variant": "selfillum.mitsuba_variants",
    "mitsuba_scene": ".mitsuba_render",
    "render": ".mitsuba_render",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
