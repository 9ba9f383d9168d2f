"""Uncertainty of PSP pressures: each source's model, their propagation (linear, and the
GUM Supplement 1 Monte Carlo) and the budget (``docs/uncertainty.md``).

Modules, one per source or concept:

- :mod:`~selfillum.uncertainty.stated`: the stated uncertainties (``--u KEY=VALUE``);
- :mod:`~selfillum.uncertainty.noise`: photon shot noise and read noise of the pixels;
- :mod:`~selfillum.uncertainty.registration`: the pose's covariance, as pixel displacements
  times the image gradient;
- :mod:`~selfillum.uncertainty.illumination`: view-factor ray sampling, reflectance, unseen
  faces;
- :mod:`~selfillum.uncertainty.calibration`: the Stern-Volmer fit, uPSP's gain coefficients;
- :mod:`~selfillum.uncertainty.temperature`, :mod:`~selfillum.uncertainty.tunnel`;
- :mod:`~selfillum.uncertainty.faces`: pixel quantities onto faces with the merge's weights;
- :mod:`~selfillum.uncertainty.budget`: combination, shares, the budget chart;
- :mod:`~selfillum.uncertainty.psp_chain`, :mod:`~selfillum.uncertainty.psp_linear`,
  :mod:`~selfillum.uncertainty.psp_mc`, :mod:`~selfillum.uncertainty.psp_run`: the
  ``selfillum psp`` chain and its two methods;
- :mod:`~selfillum.uncertainty.unsteady`: the unsteady run's per-node fields.
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "Budget": ".budget",
    "PSPInputs": ".psp_chain",
    "PixelNoise": ".noise",
    "Stated": ".stated",
    "parse_stated": ".stated",
    "psp_uncertainty": ".psp_run",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
