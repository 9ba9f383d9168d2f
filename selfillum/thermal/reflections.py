"""The model's own radiation removed frame by frame while the model heats:
:class:`HeatingSelfIllumination`.

The unsteady run removes ``rho F B`` per frame. Faces no camera sees (hidden, or beyond the
obliqueness cut-off) get the radiosity of one full solve of the first frame, their
emission then scaled in each frame as that of the nearest seen face of the same part
(:class:`selfillum.unsteady.phase1.SelfIllumination`, :mod:`selfillum.unsteady.hidden`).
That suits a paint whose light fluctuates about a steady level. A heating model's hidden
faces warm by amounts one seen face's ratio does not tell (the sides of a block seen
edge-on, whose top heats faster than its foot). Here the full solve is made again whenever
the seen faces' signal has drifted by more than ``refresh`` (relative, the median over the
seen faces) since the last one, and the hidden faces send light to the seen ones at all.
The hidden faces' emission is then continued smoothly from the seen ones
(:func:`selfillum.solve.radiosity.correct`). Frames between two solves cost what the
unsteady run's do.

A run resumed after an interruption solves again at its first frame, so its frames after
that may differ from an uninterrupted run's by what the drift allows (``refresh`` of the
hidden faces' light).
"""

from __future__ import annotations

import numpy as np

from selfillum.unsteady.phase1 import SelfIllumination

__all__ = ["HeatingSelfIllumination", "DEFAULT_REFRESH"]

#: Relative drift of the seen faces' signal that triggers a new solve.
DEFAULT_REFRESH = 0.01


class HeatingSelfIllumination(SelfIllumination):
    """:class:`~selfillum.unsteady.phase1.SelfIllumination` with the hidden faces' solve
    made again when the seen signal drifts by more than ``refresh``; ``solves`` counts the
    solves."""

    def __init__(self, mesh, F, reflectance, unpainted=None, refresh: float = DEFAULT_REFRESH):
        super().__init__(mesh, F, reflectance, unpainted)
        self.refresh = float(refresh)
        self.solves = 0
        self._ref = None

    def __call__(self, B, seen) -> np.ndarray:
        B = np.asarray(B, dtype=np.float64)
        if self._ref is not None:
            both = seen & self._ref[1] & (self._ref[0] > 0)
            if both.any():
                drift = float(np.median(np.abs(B[both] / self._ref[0][both] - 1.0)))
                if drift > self.refresh and self._coupled(seen):
                    self.hidden = None
            else:
                self.hidden = None
        if self.hidden is None:
            self.reference(B, seen)
            self.solves += 1
            self._ref = (B.copy(), np.asarray(seen, bool).copy())
        return super().__call__(B, seen)

    def _coupled(self, seen) -> bool:
        """Do the faces no camera sees send light to the seen ones (else a new solve
        changes nothing: a convex model)?"""
        seen = np.asarray(seen, bool)
        sub = self.F[np.flatnonzero(seen)][:, np.flatnonzero(~seen)]
        return sub.nnz > 0
