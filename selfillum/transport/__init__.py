"""The transport stage: how light travels between faces.

Takes in a triangle mesh (vertices, faces); gives out form factors ``F`` (a sparse N x N
matrix, row sums <= 1, ``A_i F_ij = A_j F_ji``) by ray casting (Embree threads, or Mitsuba /
Dr.Jit), the exact unoccluded point-to-triangle factors (closed form), and the faces coupled
to a set of faces.

- :mod:`~selfillum.transport.viewfactors`: :func:`view_factors`, :func:`enforce_reciprocity`;
- :mod:`~selfillum.transport.sampling`: cosine-distributed RQMC rays;
- :mod:`~selfillum.transport.kernel`: closed-form factors;
- :mod:`~selfillum.transport.mitsuba_rays`: first hits through Mitsuba / Dr.Jit;
- :mod:`~selfillum.transport.mitsuba_factors`: rows of ``F`` sampled, traced and summed in
  Dr.Jit (``tracer="mitsuba"``);
- :mod:`~selfillum.transport.coupling`: faces coupled through ``F``.
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "MitsubaFactorTracer": ".mitsuba_factors",
    "MitsubaRayScene": ".mitsuba_rays",
    "RayScene": ".viewfactors",
    "RowTracer": ".viewfactors",
    "coupled_faces": ".coupling",
    "coupled_view_factors": ".coupling",
    "digital_shifts": ".sampling",
    "enforce_reciprocity": ".viewfactors",
    "pair_factors": ".kernel",
    "point_polygon_factor": ".kernel",
    "rqmc_points": ".sampling",
    "sample_rays": ".sampling",
    "tracing_variant": ".mitsuba_rays",
    "triangle_rule": ".kernel",
    "view_factors": ".viewfactors",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
