"""The gain from the pressure taps when there is no paint calibration: the in-situ
Stern-Volmer fit of ``selfillum psp``, carried to the unsteady run.

With a wind-off image ``I_ref`` (uniform pressure ``p_ref``) the paint follows
``I_ref / I = A + B p / p_ref`` (:class:`selfillum.images.psp.SternVolmer`). ``A`` and ``B``
are fitted at the taps, whose steady pressures are known (``p = PS + Cp Q`` from the
``.wtd``, or a tap file), to the ratio of the wind-off node intensity to the run's
time-mean node intensity (:func:`selfillum.images.psp.fit_stern_volmer`). Around the mean,
``I' = mean(I) / I = (A + B p / p_ref) / (A + B Pss / p_ref)``, so a pressure fluctuation
is ``dp = (I' - 1) (A p_ref / B + Pss)``: the Phase 2 gain (psi per unit of ``I'``, as the
paint calibration's) is

``Gain = (A p_ref / B + Pss) / 144``   (``p_ref`` and ``Pss`` in psf).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["tap_nodes", "insitu_gain"]


def tap_nodes(grid, points, ids, source: str = "taps", max_distance: float | None = None
              ) -> np.ndarray:
    """The grid node nearest each tap (grid-file numbering).

    Raises
    ------
    InputError
        A tap farther than ``max_distance`` from every node (default: the grid's longest
        edge, or 1 % of its size if more): the message names it.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dist, idx = cKDTree(grid.points).query(pts)
    if max_distance is None:
        mesh = grid.mesh
        edge = float(mesh.edges_unique_length.max()) if len(mesh.faces) else 0.0
        limit = max(0.01 * float(np.ptp(grid.points, axis=0).max()), edge)
    else:
        limit = float(max_distance)
    far = np.flatnonzero(dist > limit)
    if far.size:
        k = int(far[0])
        raise InputError(f"{source}: tap {ids[k]} is {dist[k]:.3g} from the nearest grid node "
                         f"(more than {limit:.3g})")
    return np.asarray(idx, dtype=np.int64)


def insitu_gain(law, cp_steady, conditions) -> np.ndarray:
    """Per-node gain ``(A p_ref / B + Pss) / 144`` with ``Pss = Cp q + p_inf`` (psf)."""
    from selfillum.unsteady.conditions import steady_pressure

    pss = steady_pressure(cp_steady, conditions.q, conditions.p_inf)
    return (law.A * law.p_ref / law.B + pss) / 144.0
