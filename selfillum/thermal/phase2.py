"""Phase 2 of the thermal run, block by block of nodes: the nodes' signals (Phase 1's work
file) to surface temperature (:func:`ir_temperature`, :func:`tsp_temperature`), then the
heat flux along each node's history (:mod:`selfillum.thermal.heatflux`), the heat-transfer
coefficient and Stanton number (:mod:`selfillum.thermal.stanton`): :func:`run_phase2`."""

from __future__ import annotations

import numpy as np

from selfillum.thermal.balance import pixel_emissivity, view_cosines
from selfillum.thermal.heatflux import fill_gaps, heat_flux
from selfillum.unsteady.work import decode_columns

__all__ = ["ir_temperature", "tsp_temperature", "run_phase2", "BYTES_PER_CELL"]

#: Bytes a (frame, node) cell of a block costs at Phase 2's peak: 139 measured with
#: tracemalloc for the view angles, the balance, the gaps and the heat flux (200 frames,
#: 5,000 nodes, float64), plus the block's decoded signals, its outputs and their float32
#: copies.
BYTES_PER_CELL = 200


def ir_temperature(rad, raw, values, rho_h, cosines, wall, eps=None):
    """Temperature (K) of a block from the measured signal ``raw`` (T, n) (``U = S - O``)
    and ``values`` (``raw - rho_h F raw``, or None without view factors): the balance of
    :mod:`selfillum.thermal.balance`; ``eps`` (T, n) the emissivity at the pixels' view
    angles (:func:`selfillum.thermal.balance.pixel_emissivity`), else that at ``cosines``
    (the nodes' view angles). Returns ``(T, out_of_range)`` (samples outside the
    calibration's range, NaN)."""
    pl = rad.planck
    Uw = float(pl.radiance(rad.reflected_temperature))
    H = wall[None, :] * Uw
    if values is not None and rho_h > 0:
        H = H + (raw - values) / rho_h
    if eps is None:
        eps = rad.emissivity.of_cosine(cosines) if rad.emissivity.directional else \
            rad.emissivity.value
    with np.errstate(divide="ignore", invalid="ignore"):
        U = (raw - (1.0 - eps) * H) / eps
    T = pl.temperature(np.where(cosines > 0, U, np.nan))
    bad = 0
    if pl.t_range is not None:
        lo, hi = pl.signal_range()
        S = raw + pl.O
        out = np.isfinite(raw) & ((S < lo) | (S > hi))
        bad = int(np.count_nonzero(out))
        T[out] = np.nan
    return T, bad


#: frames between two evaluations of the pixels' emissivity (:func:`_pixel_emissivity`)
EMISSIVITY_EVERY = 8


def _pixel_emissivity(emissivity, centres, geom, nodes, cosines, max_obliqueness):
    """``(T, n)`` emissivity at the pixels' view angles
    (:func:`selfillum.thermal.balance.pixel_emissivity`) as the emissivity at each node's
    own view angle in each frame times the ratio of the two, the ratio evaluated every
    :data:`EMISSIVITY_EVERY` frames (and at the last) and linear in time between: the ratio
    follows the slow change of the view angles, whose second-order part over those
    frames it leaves out (a degree of pitch over them moves it by about 1e-5)."""
    own = emissivity.of_cosine(cosines)
    T = own.shape[0]
    ks = np.unique(np.r_[np.arange(0, T, EMISSIVITY_EVERY), T - 1])
    at = pixel_emissivity(emissivity, np.asarray(centres)[:, ks], geom, nodes, cosines[ks],
                          max_obliqueness)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(own[ks] > 0, at / own[ks], 1.0)
    if ks.size == 1:
        return own * ratio
    t = np.arange(T)
    j = np.clip(np.searchsorted(ks, t, side="right") - 1, 0, ks.size - 2)
    slope = np.diff(ratio, axis=0) / np.diff(ks)[:, None]  # per frame, (K - 1, n)
    factor = slope[j]
    factor *= (t - ks[j])[:, None]
    factor += ratio[j]
    own *= factor
    return own


def tsp_temperature(cal, values, off):
    """Temperature (K) of a block from the wind-on intensity ``values`` (T, n) and the
    wind-off one ``off`` (n,), both with the self-illumination removed. Returns
    ``(T, out_of_range)``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = values / off[None, :]
    T = cal.temperature(r)
    bad = int(np.count_nonzero(np.isfinite(r) & np.isnan(T)))
    return T, bad


def run_phase2(s1, f, *, mode, rad, cal, off, rho_h, geom, centres, sub, method, dt,
               flow, block, probes, progress=None, max_obliqueness=None) -> dict:
    """Every block of nodes: read the work file ``s1``, write ``/temperature``,
    ``/heat_flux`` (and ``/heat_transfer_coefficient``, ``/stanton`` with ``flow``) into
    ``f``. Returns ``seen`` (nodes with a heat flux), ``out_of_range``, the probes'
    histories. A directional emissivity is taken at the pixels' view angles
    (:func:`selfillum.thermal.balance.pixel_emissivity`, faces within
    ``max_obliqueness`` degrees) where ``geom`` has its faces and ``max_obliqueness`` is
    given, else at the nodes'."""
    from threadpoolctl import threadpool_limits

    from selfillum.thermal.heatflux import impulse_response

    vals = s1["values"]
    T, N = vals.shape
    has_raw = "raw" in s1
    vs, rs = s1["values_scale"][()], (s1["raw_scale"][()] if has_raw else None)
    h = impulse_response(sub, T, dt) if method == "impulse" else None
    dT, dq = f["temperature"], f["heat_flux"]
    dh = f["heat_transfer_coefficient"] if flow is not None else None
    dst = f["stanton"] if flow is not None else None
    probes = np.asarray(probes, dtype=np.int64)
    pT = np.full((T, probes.size), np.nan)
    pq = np.full((T, probes.size), np.nan)
    seen = np.zeros(N, bool)
    bad = 0
    with threadpool_limits(1, "blas"):
        for a in range(0, N, block):  # blocks of nodes (each a (T, block) array)
            b = min(a + block, N)
            v = decode_columns(vals[:, a:b], vs)
            cols = np.flatnonzero(np.isfinite(v).any(axis=0))  # nodes seen at all
            Tb = np.full(v.shape, np.nan)
            qb = np.full(v.shape, np.nan)
            if cols.size:
                v = v[:, cols]
                if mode == "ir":
                    raw = decode_columns(s1["raw"][:, a:b], rs)[:, cols] if has_raw else v
                    nodes = a + cols
                    cos = view_cosines(centres, geom.points[nodes], geom.normals[nodes])
                    eps = None
                    if (rad.emissivity.directional and max_obliqueness is not None
                            and geom.node_faces is not None):
                        eps = _pixel_emissivity(rad.emissivity, centres, geom, nodes, cos,
                                                max_obliqueness)
                    Tc, nb = ir_temperature(rad, raw, v if has_raw else None, rho_h, cos,
                                            geom.wall[nodes], eps)
                else:
                    Tc, nb = tsp_temperature(cal, v, off[a:b][cols])
                bad += nb
                Tf, ok = fill_gaps(Tc)
                qc = np.full(Tc.shape, np.nan)
                if ok.any():
                    qc[:, ok] = heat_flux(Tf[:, ok], dt, sub, method, h=h)
                qc[np.isnan(Tc)] = np.nan
                Tb[:, cols], qb[:, cols] = Tc, qc
            seen[a:b] = np.isfinite(qb).any(axis=0)
            if cols.size:  # chunks of nodes never seen stay unwritten (the fill is NaN)
                dT[:, a:b] = Tb.astype(np.float32)
                dq[:, a:b] = qb.astype(np.float32)
                if flow is not None:
                    hb = flow.coefficient(qb, Tb)
                    dh[:, a:b] = hb.astype(np.float32)
                    dst[:, a:b] = (hb / flow.rho_u_cp).astype(np.float32)
            sel = (probes >= a) & (probes < b)
            pT[:, sel] = Tb[:, probes[sel] - a]
            pq[:, sel] = qb[:, probes[sel] - a]
            if progress is not None:
                progress(b)
    return {"seen": seen, "out_of_range": bad, "probe_T": pT, "probe_q": pq}
