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

import contextlib

import numpy as np

from resection.errors import InputError
from selfillum.unsteady.phase1 import CameraRun, SelfIllumination, map_run
from selfillum.unsteady.work import decode_columns

__all__ = ["tap_nodes", "insitu_gain", "insitu_inputs", "insitu_fit"]


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


def insitu_inputs(cfg, grid):
    """Taps, their grid nodes and the wind-off images, checked (no paint calibration)."""
    from selfillum.images.psp import read_taps
    from selfillum.uncertainty.psp_io import read_condition
    from selfillum.unsteady.insitu import tap_nodes

    if cfg.taps is None:
        raise InputError("no paint calibration: give --paint-calibration CAL.txt (uPSP's a..f "
                         "gain file), or --taps with --wind-off and --p-ref for the in-situ "
                         "Stern-Volmer fit")
    if not cfg.wind_off or len(cfg.wind_off) != len(cfg.cameras):
        n = len(cfg.wind_off or [])
        raise InputError(f"--taps: the in-situ fit needs one --wind-off image per camera "
                         f"({len(cfg.cameras)} cameras, {n} images)")
    if cfg.p_ref is None or not cfg.p_ref > 0:
        raise InputError("--taps: the in-situ fit needs --p-ref (the wind-off pressure, psf)")
    positions = cfg.tap_positions if cfg.tap_positions is not None else cfg.targets
    taps = read_taps(cfg.taps, positions=positions)
    nodes = tap_nodes(grid, taps.points, taps.ids, str(cfg.taps))
    # one image, or a stack (a multi-page TIFF / NPY) averaged, per camera
    offs = read_condition(cfg.wind_off, len(cfg.cameras), "--wind-off")[0]
    return taps, nodes, offs


def insitu_fit(cfg, grid, runs, work, taps, nodes, offs, spots, unpainted, F, rho, gains,
               out: dict | None = None):
    """Stern-Volmer ``A, B`` from the wind-off / time-mean intensity ratio at the taps
    (``out``, when given, receives that ratio as ``"ratio"``: the fit's uncertainty)."""
    from selfillum.images.psp import fit_stern_volmer

    order, inverse = np.unique(nodes, return_inverse=True)  # h5py reads sorted columns
    with _quiet():
        on = np.nanmean(decode_columns(work["values"][:, order], work["values_scale"][()]),
                        axis=0)[inverse]
    off_runs = [CameraRun(r.number, r.camera, [img]) for r, img in zip(runs, offs,
                                                                         strict=True)]
    si = SelfIllumination(grid.mesh, F, rho, unpainted) if F is not None else None
    fn = next(map_run(grid, off_runs, [0], spots=spots, registration="none",
                      patcher=cfg.target_patcher, overlap=cfg.overlap, filter=cfg.filter,
                      filter_size=cfg.filter_size, max_obliqueness=cfg.oblique_angle, si=si,
                      unpainted=unpainted, gains=gains if cfg.overlap == "merge" else None))
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = fn.values[nodes] / on
    if out is not None:
        out["ratio"] = ratio
    try:
        return fit_stern_volmer(ratio, taps.pressure, cfg.p_ref)
    except InputError as e:
        raise InputError(f"{cfg.taps}: {e}") from None


@contextlib.contextmanager
def _quiet():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield
