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

from .brdf import GlossyPaint, GlossyTransport, glossy_correct, glossy_forward, transport_matrix
from .correct_image import ImageCorrection, correct_image
from .multiview import MergedViews, merge_views
from .psp import PSPResult, SternVolmer, fit_stern_volmer, psp_images, psp_pressure, read_taps
from .radiosity import SolveInfo, correct, forward
from .rendering import RenderResult, choose_variant, render
from .viewfactors import enforce_reciprocity, view_factors

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
