"""selfillum: self-illumination correction of luminescent-paint images.

Faces of a triangle mesh are the radiosity elements. ``B = E + diag(rho) F B`` links the
radiosity ``B`` (what a camera sees) to the emission ``E`` (what the paint emits).

* :func:`view_factors`: form factors ``F`` by Embree ray casting (sparse, N K entries);
* :func:`forward`: ``E -> B``; :func:`correct`: ``B -> E`` (all or part of the faces seen);
* :func:`correct_image`: a camera image corrected pixel by pixel;
* :func:`render`: Mitsuba 3 renders of the same scene (the independent reference);
* :class:`GlossyPaint` and :func:`glossy_forward` / :func:`glossy_correct`: non-Lambertian
  paint (diffuse + GGX lobe) with a view-dependent transport;
* :func:`merge_views`: several cameras merged before the inverse;
* :func:`psp_images`: the PSP workflow (wind-off / wind-on, Stern-Volmer fitted to taps);
* :mod:`selfillum.corner`: the corner case end to end.
"""

from __future__ import annotations

from resection._lazy import attach

# a function named as its module: bound here, before any import of the module could
# make the package attribute the module itself
from .correct_image import ImageCorrection, correct_image

#: Public name -> the submodule that defines it. Submodules are imported on first use
#: (PEP 562), so a command pays only for what it calls (as scikit-image's lazy loading).
_EXPORTS: dict[str, str] = {
    "GlossyPaint": ".brdf",
    "GlossyTransport": ".brdf",
    "glossy_correct": ".brdf",
    "glossy_forward": ".brdf",
    "transport_matrix": ".brdf",
    "MergedViews": ".multiview",
    "merge_views": ".multiview",
    "PSPResult": ".psp",
    "SternVolmer": ".psp",
    "fit_stern_volmer": ".psp",
    "psp_images": ".psp",
    "psp_pressure": ".psp",
    "read_taps": ".psp",
    "SolveInfo": ".radiosity",
    "correct": ".radiosity",
    "forward": ".radiosity",
    "RenderResult": ".rendering",
    "choose_variant": ".rendering",
    "render": ".rendering",
    "enforce_reciprocity": ".viewfactors",
    "view_factors": ".viewfactors",
}

__all__: list[str] = [
    "view_factors",
    "enforce_reciprocity",
    "forward",
    "correct",
    "SolveInfo",
    "correct_image",
    "ImageCorrection",
    "render",
    "RenderResult",
    "choose_variant",
    "GlossyPaint",
    "GlossyTransport",
    "transport_matrix",
    "glossy_forward",
    "glossy_correct",
    "merge_views",
    "MergedViews",
    "SternVolmer",
    "fit_stern_volmer",
    "read_taps",
    "psp_pressure",
    "psp_images",
    "PSPResult",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
