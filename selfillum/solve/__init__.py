"""The solve stage: emission from radiosity and back.

Takes in ``F`` (from :mod:`selfillum.transport`), the reflectance and the radiosity ``B``
seen on some or all faces; gives out the emission ``E`` (``B = E + diag(rho) F B``), with
the stated assumption for unseen faces, or the glossy (GGX) transport.

- :mod:`~selfillum.solve.radiosity`: :func:`forward`, :func:`correct`;
- :mod:`~selfillum.solve.unseen`: what unseen faces emit, and how much it matters;
- :mod:`~selfillum.solve.fields`: per-face inputs (the reflectance), checked;
- :mod:`~selfillum.solve.brdf`: glossy paint (diffuse + GGX lobe).
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "GlossyPaint": ".brdf",
    "GlossyTransport": ".brdf",
    "SolveInfo": ".radiosity",
    "UNSEEN_CHOICES": ".radiosity",
    "WARN_AREA": ".unseen",
    "WARN_LEVEL": ".unseen",
    "check_form_factors": ".radiosity",
    "check_reflectance": ".fields",
    "correct": ".radiosity",
    "describe_unseen": ".unseen",
    "forward": ".radiosity",
    "glossy_correct": ".brdf",
    "glossy_forward": ".brdf",
    "read_unpainted": ".unseen",
    "read_unseen": ".unseen",
    "transport_matrix": ".brdf",
    "unseen_warning": ".unseen",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
