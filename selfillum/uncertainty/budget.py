"""The uncertainty budget: each source's standard uncertainty per face, their combination,
what was stated, estimated or missing, and the pictures.

The sources are independent of each other (different physical causes), so the combined
standard uncertainty (k = 1) is the root sum of squares of the parts
(:func:`combine`). Within a source, the errors of different faces are either independent
(noise, ray sampling, the model temperature's non-uniformity) or shared by every face of
the model (registration: per camera; reflectance; unseen faces; the calibration's ``A``
and ``B``; tunnel conditions): :data:`CORRELATION` says which, so that an average over
many faces keeps the shared parts whole and divides the independent ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Budget", "combine", "shares", "CORRELATION"]

#: How a source's errors are correlated between faces (nodes).
CORRELATION = {
    "noise": "independent between faces",
    "registration": "shared by the faces of a camera (its pose)",
    "si_rays": "independent between faces",
    "reflectance": "shared by every face",
    "unseen": "shared by every face",
    "calibration": "shared by every face (the fit's A and B, correlated as stated)",
    "temperature": "independent between faces (non-uniformity)",
    "tunnel": "shared by every face",
    "gain": "shared by every node and frame",
}


def combine(parts: dict) -> np.ndarray:
    """Root sum of squares of the parts (NaN where any part is NaN)."""
    arrs = [np.asarray(v, np.float64) for v in parts.values()]
    if not arrs:
        raise ValueError("combine: no part")
    return np.sqrt(sum(a * a for a in arrs))


@dataclass
class Budget:
    """An uncertainty budget of one quantity.

    Attributes
    ----------
    quantity : str
        ``"p"``, ``"cp"`` or ``"dcp"``.
    method : str
        ``"linear"`` or ``"mc"`` (GUM Supplement 1).
    parts : dict
        Source -> (F,) standard uncertainty (k = 1) of the quantity.
    combined : (F,) ndarray
        Root sum of squares of the parts.
    status : dict
        Source -> ``"stated"``, ``"estimated: ..."``, ``"missing: ..."`` or
        ``"zero: ..."`` (cancels exactly).
    info : dict
        Other figures (the taps' scatter ratio, samples, ...), JSON-ready.
    full : dict
        Source -> (F,): its whole effect, its share through the taps' fit included (the
        parts give that share to ``calibration``); what a Monte Carlo of that source alone
        gives.
    """

    quantity: str
    method: str
    parts: dict
    combined: np.ndarray
    status: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    full: dict = field(default_factory=dict)

    def missing(self) -> list:
        return [k for k, v in self.status.items() if v.startswith("missing")]

    def summary(self, area=None, mask=None) -> dict:
        """JSON-ready: status, correlation and area share of every source."""
        sh = shares(self.parts, area, mask)
        fin = np.isfinite(self.combined) if mask is None else mask & np.isfinite(self.combined)
        c = self.combined[fin]
        return {
            "quantity": self.quantity, "method": self.method,
            "combined_median": float(np.median(c)) if c.size else None,
            "combined_p95": float(np.percentile(c, 95)) if c.size else None,
            "sources": {k: {"status": self.status.get(k, "stated"),
                            "correlation": CORRELATION.get(k, ""),
                            "share": sh.get(k)} for k in
                        dict.fromkeys([*self.parts, *self.status])},
            **self.info,
        }


def shares(parts: dict, area=None, mask=None) -> dict:
    """Each source's share of the area-weighted mean variance over the faces (``mask``:
    the painted, measured ones)."""
    if not parts:
        return {}
    n = len(next(iter(parts.values())))
    w = np.ones(n) if area is None else np.asarray(area, np.float64)
    ok = np.ones(n, bool) if mask is None else np.asarray(mask, bool)
    for v in parts.values():
        ok &= np.isfinite(v)
    var = {k: float(np.sum(w[ok] * np.asarray(v)[ok] ** 2)) for k, v in parts.items()}
    tot = sum(var.values())
    return {k: (v / tot if tot > 0 else 0.0) for k, v in var.items()}
