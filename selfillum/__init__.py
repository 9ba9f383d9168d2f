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
* :func:`run_unsteady`: the unsteady PSP run (uPSP's ``psp_process``, SI removed per frame);
* :func:`psp_uncertainty`: the PSP pressures' uncertainty source by source (linear and GUM
  S1 Monte Carlo, :mod:`selfillum.uncertainty`);
* :mod:`selfillum.corner`: the corner case end to end.
"""

from __future__ import annotations

from resection._lazy import attach

#: Public name -> the submodule that defines it. Submodules are imported on first use
#: (PEP 562), so a command pays only for what it calls (as scikit-image's lazy loading).
_EXPORTS: dict[str, str] = {
    "ImageCorrection": ".images.image_correction",
    "correct_image": ".images.image_correction",
    "psp_uncertainty": ".uncertainty.psp_run",
    "GlossyPaint": ".solve.brdf",
    "GlossyTransport": ".solve.brdf",
    "glossy_correct": ".solve.brdf",
    "glossy_forward": ".solve.brdf",
    "transport_matrix": ".solve.brdf",
    "MergedViews": ".images.multiview",
    "merge_views": ".images.multiview",
    "PSPResult": ".images.psp",
    "SternVolmer": ".images.psp",
    "fit_stern_volmer": ".images.psp",
    "psp_images": ".images.psp",
    "psp_pressure": ".images.psp",
    "read_taps": ".images.psp",
    "SolveInfo": ".solve.radiosity",
    "correct": ".solve.radiosity",
    "forward": ".solve.radiosity",
    "RenderResult": ".rendering.mitsuba_render",
    "choose_variant": ".mitsuba_variants",
    "render": ".rendering.mitsuba_render",
    "enforce_reciprocity": ".transport.viewfactors",
    "view_factors": ".transport.viewfactors",
    "UnsteadyConfig": ".unsteady.config",
    "run_unsteady": ".unsteady.run",
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
    "psp_uncertainty",
    "UnsteadyConfig",
    "run_unsteady",
]

__getattr__, __dir__ = attach(__name__, _EXPORTS)
