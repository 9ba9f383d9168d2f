"""Imported by the fork server of :mod:`resection.sequence.pool` only, before it forks
any worker: the tracking code, and its compiled kernels loaded from numba's cache (numba
loads a kernel at its first call in a process, 0.2-0.4 s for a tracked frame's kernels).
Loading them here, once, spares every worker that cost; the server does it while the run's
process works on the reference frame and the first chunk.

Importing this module runs :func:`load_kernels`; nothing else imports it.
"""

from __future__ import annotations

import numpy as np

import resection.sequence.process  # noqa: F401  (what the workers run)
from resection.markers.detect import detect_markers
from resection.markers.refine import refine_markers


def load_kernels() -> None:
    """Detect and refine two dark dots on a small synthetic frame: the calls a tracked
    frame makes (its results are not used)."""
    v, u = np.mgrid[0:48, 0:64]
    img = np.full((48, 64), 200.0)
    for cu, cv in ((20.3, 22.6), (44.8, 25.1)):
        img[(u - cu) ** 2 + (v - cv) ** 2 <= 2.5**2] = 60.0
    cands = detect_markers(img, 5.0)
    refine_markers(255.0 - img, np.asarray(cands.uv, float).reshape(-1, 2), 5.0)


load_kernels()
