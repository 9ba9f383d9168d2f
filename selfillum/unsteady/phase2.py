"""Phase 2: node intensities over time to pressure coefficient fluctuations, block by block.

Per node (uPSP's ``psp_process``, :mod:`selfillum.unsteady.conditions` for the formulas):
``I' = mean_t(I) / I``; a polynomial of order 6 in time fitted to ``I'`` and subtracted
(it takes out the slow drifts: paint photo-degradation, lamp warm-up, temperature);
``P = (I' - fit) Gain``; ``dCp = P 144 / q``.

A block is ``(T, n)``: every frame of ``n`` nodes, the shape of the HDF5 dataset's chunk
columns (:mod:`selfillum.unsteady.output`), so that Phase 2 reads along its chunks with
memory bounded by the block, whatever the number of nodes.

Frames where a node is unseen (NaN) are left out of its mean and of its fit, and stay NaN;
a node seen in fewer than half the frames (or fewer than ``order + 2``) gets NaN throughout:
its drift cannot be told from its signal.
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["DETREND_ORDER", "intensity_ratio", "detrend", "dcp_block", "node_gain",
           "run_phase2"]

#: Order of the polynomial in time fitted to ``I'`` and subtracted (uPSP: 6).
DETREND_ORDER = 6


def intensity_ratio(intensity) -> np.ndarray:
    """``I' = mean_t(I) / I`` per column of a ``(T, n)`` block (NaN frames left out of the
    mean and kept NaN; non-positive intensities are NaN)."""
    I = np.asarray(intensity, dtype=np.float64)
    ok = I > 0  # False on NaN too
    n = ok.sum(axis=0, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(ok, I, 0.0).sum(axis=0, keepdims=True) / n
        return np.where(ok, mean / np.where(ok, I, 1.0), np.nan)


def _vandermonde(times, order: int) -> np.ndarray:
    t = np.asarray(times, dtype=np.float64)
    span = t.max() - t.min() if t.size > 1 else 1.0
    x = (2.0 * (t - t.min()) / (span if span > 0 else 1.0)) - 1.0  # in [-1, 1]
    return np.polynomial.legendre.legvander(x, order)  # same fit as powers, well conditioned


def detrend(ratio, times, order: int = DETREND_ORDER) -> np.ndarray:
    """Subtract a least-squares polynomial of ``order`` in time from every column.

    Parameters
    ----------
    ratio : (T, n) array_like
        ``I'`` per frame and node (NaN where unseen).
    times : (T,) array_like
        Frame times (any unit; frame numbers as uPSP).
    order : int

    Returns
    -------
    (T, n) float64
        ``I' - fit``; NaN where ``ratio`` is NaN and in columns with too few frames.
    """
    y = np.asarray(ratio, dtype=np.float64)
    if y.ndim != 2:
        raise InputError(f"detrend: expected a (frames, nodes) block, got shape {y.shape}")
    T = y.shape[0]
    if np.shape(times) != (T,):
        raise InputError(f"detrend: {np.size(times)} times for {T} frames")
    V = _vandermonde(times, order)
    fin = np.isfinite(y)
    nfin = fin.sum(axis=0)
    out = np.full_like(y, np.nan)
    full = nfin == T
    if full.any() and T > order:
        # least squares by the pseudo-inverse of the (T, order + 1) Legendre basis: one
        # product for every column (np.linalg.lstsq would factor V for each call)
        yf = y[:, full]
        out[:, full] = yf - V @ (np.linalg.pinv(V) @ yf)
    part = np.flatnonzero(~full & (nfin >= max(order + 2, (T + 1) // 2)))
    if part.size:  # weighted normal equations, all such columns at once
        w = fin[:, part].astype(np.float64)
        yz = np.where(fin[:, part], y[:, part], 0.0)
        A = np.einsum("ti,tn,tj->nij", V, w, V)
        b = np.einsum("ti,tn->ni", V, w * yz)
        coef = np.linalg.solve(A, b[..., None])[..., 0]
        out[:, part] = np.where(fin[:, part], y[:, part] - V @ coef.T, np.nan)
    return out


def dcp_block(intensity, times, gain, q: float, order: int = DETREND_ORDER) -> np.ndarray:
    """dCp of a ``(T, n)`` block of node intensities: ``(I' - fit) Gain 144 / q``.

    Parameters
    ----------
    intensity : (T, n) array_like
        Node intensities (counts, NaN unseen), frames in time order.
    times : (T,) array_like
    gain : (n,) array_like
        Per node, psi per unit of ``I'`` (:func:`node_gain`).
    q : float
        Dynamic pressure, psf.

    Returns
    -------
    (T, n) float32
    """
    g = np.asarray(gain, dtype=np.float64)
    I = np.asarray(intensity)
    if g.shape != (I.shape[1],):
        raise InputError(f"dcp_block: {g.size} gains for {I.shape[1]} nodes")
    res = detrend(intensity_ratio(I), times, order)
    return (res * (g * 144.0 / float(q))[None, :]).astype(np.float32)


def node_gain(calibration, surface_temperature, cp_steady, conditions) -> np.ndarray:
    """Per-node gain ``a + bT + cT^2 + (d + eT + fT^2) Pss`` with ``Pss = Cp q + p_inf``.

    Parameters
    ----------
    calibration : resection.io.upsp_inputs.PaintCalibration
    surface_temperature : float or (n,) array_like
        deg F.
    cp_steady : (n,) array_like
        Steady Cp per node.
    conditions : selfillum.unsteady.conditions.Conditions
    """
    from selfillum.unsteady.conditions import steady_pressure

    pss = steady_pressure(cp_steady, conditions.q, conditions.p_inf)
    return np.asarray(calibration.gain(surface_temperature, pss), dtype=np.float64)


def run_phase2(intensity, out, times, gain, q: float, *, raw=None, block: int | None = None,
               order: int = DETREND_ORDER, spectra=None, progress=None) -> dict:
    """Phase 2 over a whole run, block by block of nodes.

    Parameters
    ----------
    intensity : (T, N) array-like readable by column slices (an h5py dataset)
        Node intensities, SI removed.
    out : (T, N) array-like writable by column slices
        Receives dCp (float32).
    times : (T,) array_like
    gain : (N,) array_like
    q : float
        psf.
    raw : (T, N) array-like, optional
        Node intensities without the SI removal: the change of dCp it makes is reported.
    block : int, optional
        Nodes per block (default: the chunk width of ``out``, else 4096): memory holds
        ``T x block`` values at a time (:func:`selfillum.unsteady.budget.plan_blocks`).
    spectra : selfillum.unsteady.spectra.Spectra, optional
        Receives every block's dCp (Welch spectra, no second pass over the run).
    progress : callable, optional
        Called with the number of nodes done after each block.

    Returns
    -------
    dict
        ``mean``, ``rms`` (RMS about zero) of dCp per node and ``si_change`` (RMS over time
        of dCp minus dCp without SI; NaN without ``raw``), each (N,) float32.
    """
    import warnings

    T, N = intensity.shape
    nc = block or (getattr(out, "chunks", None) or (None, 4096))[1]
    g = np.asarray(gain, dtype=np.float64)
    mean = np.full(N, np.nan, np.float32)
    rms = np.full(N, np.nan, np.float32)
    change = np.full(N, np.nan, np.float32)
    for a in range(0, N, nc):  # blocks of nodes: whole chunk columns
        b = min(a + nc, N)
        d = dcp_block(intensity[:, a:b], times, g[a:b], q, order)
        out[:, a:b] = d
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN nodes
            mean[a:b] = np.nanmean(d, axis=0)
            rms[a:b] = np.sqrt(np.nanmean(d.astype(np.float64) ** 2, axis=0))
            if raw is not None:
                d0 = dcp_block(raw[:, a:b], times, g[a:b], q, order)
                change[a:b] = np.sqrt(np.nanmean((d.astype(np.float64) - d0) ** 2, axis=0))
                del d0
        if spectra is not None:
            spectra.add(a, d)
        del d
        if progress is not None:
            progress(b)
    return {"mean": mean, "rms": rms, "si_change": change}
