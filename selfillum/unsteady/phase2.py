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

The nodes seen in every frame (all of them for a fixed model) go through one compiled pass
(:func:`phase2_block`: the ratio, the fit by the basis' pseudo-inverse, dCp, its mean and
mean square, reading the work file's uint16 intensities as they are, with their per-frame
scale, :mod:`selfillum.unsteady.work`); the others through the NumPy path
(:func:`intensity_ratio`, :func:`detrend`: weighted normal equations per node).
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from resection._threads import run_blocks, split_range
from resection.errors import InputError

__all__ = ["DETREND_ORDER", "intensity_ratio", "detrend", "dcp_block", "phase2_block",
           "node_gain", "run_phase2", "seen_ranges"]

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
    return phase2_block(intensity, times, gain, q, order=order)[0]


def phase2_block(intensity, times, gain, q: float, *, scale=None, raw=None, raw_scale=None,
                 order: int = DETREND_ORDER, basis=None, workers: int | None = None,
                 return_share: bool = False):
    """dCp of a ``(T, n)`` block and its per-node statistics, in one pass.

    Parameters
    ----------
    intensity : (T, n) array_like
        Node intensities: float (NaN or <= 0 unseen), or the work file's uint16 codes with
        ``scale`` (0 unseen; intensity = code / scale of its frame).
    times : (T,) array_like
    gain : (n,) array_like
        psi per unit of ``I'``.
    q : float
        psf.
    scale : (T,) array_like, optional
        Per-frame scale of uint16 codes (:func:`selfillum.unsteady.work.encode_rows`).
    raw, raw_scale : optional
        The same block without the SI removal: the change of dCp it makes is returned.
    basis : tuple, optional
        ``legendre_basis(times, order)`` when the caller has it (one a run).
    workers : int, optional
        Threads over groups of nodes (default: the available cores).
    return_share : bool
        Also return ``share`` (n,): the share of frames where each node's dCp is finite
        (0 for a node without dCp), for :func:`selfillum.unsteady.spectra.welch_block`.

    Returns
    -------
    dcp : (T, n) float32
    mean, rms : (n,) float32
        Mean and RMS about zero of dCp over the frames seen (NaN for a node never seen).
    change : (n,) float32 or None
        RMS over time of dCp minus dCp without the SI removal (with ``raw``).
    """
    I = np.asarray(intensity)
    if I.ndim != 2:
        raise InputError(f"phase 2: expected a (frames, nodes) block, got shape {I.shape}")
    T, n = I.shape
    g = np.asarray(gain, dtype=np.float64)
    if g.shape != (n,):
        raise InputError(f"dcp_block: {g.size} gains for {n} nodes")
    if np.shape(times) != (T,):
        raise InputError(f"detrend: {np.size(times)} times for {T} frames")
    G = g * (144.0 / float(q))
    if basis is None and T > order:
        basis = legendre_basis(times, order)
    d, mean, ms, share = _dcp_stats(I, scale, times, G, order, basis, workers)
    change = None
    if raw is not None:
        d0 = _dcp_stats(np.asarray(raw), raw_scale, times, G, order, basis, workers)[0]
        change = np.empty(n, np.float32)
        kern = _kernels()[1]
        run_blocks(lambda b: kern(d, d0, change, b[0], b[1]), _col_blocks(n, workers),
                   workers)
        del d0
    with np.errstate(invalid="ignore"):
        rms = np.sqrt(ms).astype(np.float32)
    if return_share:
        return d, mean.astype(np.float32), rms, change, share
    return d, mean.astype(np.float32), rms, change


def _decoded(I, scale) -> np.ndarray:
    """Float64 intensities of a block (NaN where unseen: NaN, <= 0, or code 0)."""
    x = np.asarray(I, dtype=np.float64)
    if scale is not None:
        x = x / np.asarray(scale, dtype=np.float64)[:, None]
    return np.where(x > 0, x, np.nan)


def legendre_basis(times, order: int = DETREND_ORDER) -> tuple[np.ndarray, np.ndarray]:
    """``V`` (T, order + 1), the Legendre basis on the frame times mapped to [-1, 1], and
    its pseudo-inverse ``P`` (order + 1, T): the fit of a series ``y`` is ``V (P y)``."""
    V = _vandermonde(times, order)
    return np.ascontiguousarray(V), np.ascontiguousarray(np.linalg.pinv(V))


def _col_blocks(n: int, workers: int | None) -> list:
    """Column blocks for the threads (whole groups of 64 nodes, a few a thread)."""
    return [(a * 64, min(b * 64, n)) for a, b in split_range((n + 63) // 64, workers)]


def _dcp_stats(I, scale, times, G, order, basis, workers=None):
    """dCp (T, n) float32, mean and mean square (n,) float64 of a block."""
    T, n = I.shape
    d = np.empty((T, n), np.float32)
    mean = np.full(n, np.nan)
    ms = np.full(n, np.nan)
    count = np.zeros(n, np.int64)
    if T > order and n:
        V, P = basis
        inv = np.ones(T) if scale is None else 1.0 / np.asarray(scale, dtype=np.float64)
        blk = np.ascontiguousarray(
            I if I.dtype in (np.uint16, np.float32, np.float64) else I.astype(np.float64))
        kern = _kernels()[0]
        run_blocks(lambda b: kern(blk, inv, P, V, G, d, mean, ms, count, b[0], b[1]),
                   _col_blocks(n, workers), workers)
    else:
        d[:] = np.nan
    need = max(order + 2, (T + 1) // 2)  # frames a node needs (as detrend)
    part = np.flatnonzero((count != T) & (count >= need))
    step = max(1, n // 4)  # the NumPy path's float64 copies: a quarter of the block
    for i in range(0, part.size, step):  # nodes unseen in some frames: weighted fits
        cols = part[i:i + step]
        dp = (detrend(intensity_ratio(_decoded(I[:, cols], scale)), times, order)
              * G[cols]).astype(np.float32)
        d[:, cols] = dp
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # nodes never seen
            mean[cols] = np.nanmean(dp, axis=0, dtype=np.float64)
            ms[cols] = np.nanmean(np.square(dp, dtype=np.float64), axis=0)
    share = np.where(count >= need, count / max(T, 1), 0.0)
    return d, mean, ms, share


@functools.cache
def _kernels():
    import numba

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def full_columns(block, inv_scale, P, V, G, out, mean, ms, count, c0, c1):
        """Nodes ``c0 .. c1`` seen in every frame: ``I' = mean / I``, the fit ``V (P I')``,
        dCp, its mean and mean square; ``count`` = frames seen; the other nodes' dCp NaN
        (the caller redoes those seen in enough frames). Nodes in groups of 64, frames in
        the inner sweeps (rows read contiguously)."""  # pragma: no cover - compiled
        T = block.shape[0]
        K = P.shape[0]
        W = 64
        for a in range(c0, c1, W):
            w = min(W, c1 - a)
            cnt = np.zeros(w, np.int64)
            s = np.zeros(w)
            for t in range(T):
                f = inv_scale[t]
                for j in range(w):
                    v = block[t, a + j] * f
                    if v > 0.0:  # False on NaN
                        cnt[j] += 1
                        s[j] += v
            mu = np.ones(w)
            full = np.zeros(w, np.bool_)
            for j in range(w):
                count[a + j] = cnt[j]
                if cnt[j] == T:
                    mu[j] = s[j] / T
                    full[j] = True
            if not full.any():  # nodes unseen in some frame (most often: in all)
                for t in range(T):
                    for j in range(w):
                        out[t, a + j] = np.nan
                continue
            coef = np.zeros((K, w))
            y = np.empty(w)
            for t in range(T):
                f = inv_scale[t]
                for j in range(w):
                    y[j] = mu[j] / (block[t, a + j] * f)
                for k in range(K):
                    pk = P[k, t]
                    for j in range(w):
                        coef[k, j] += pk * y[j]
            sd = np.zeros(w)
            sdd = np.zeros(w)
            fit = np.empty(w)
            for t in range(T):
                f = inv_scale[t]
                for j in range(w):
                    y[j] = mu[j] / (block[t, a + j] * f)
                    fit[j] = 0.0
                for k in range(K):
                    vk = V[t, k]
                    for j in range(w):
                        fit[j] += vk * coef[k, j]
                for j in range(w):
                    dv = np.float32((y[j] - fit[j]) * G[a + j])
                    out[t, a + j] = dv if full[j] else np.nan
                    sd[j] += dv
                    sdd[j] += np.float64(dv) * dv
            for j in range(w):
                if cnt[j] == T:
                    mean[a + j] = sd[j] / T
                    ms[a + j] = sdd[j] / T

    @numba.njit(cache=True, nogil=True, error_model="numpy")
    def rms_difference(d, d0, out, c0, c1):  # pragma: no cover - compiled
        """RMS over the frames where both are finite of ``d - d0``, per column ``c0 ..
        c1`` (NaN if none)."""
        T = d.shape[0]
        W = 64
        for a in range(c0, c1, W):
            w = min(W, c1 - a)
            s = np.zeros(w)
            k = np.zeros(w, np.int64)
            for t in range(T):
                for j in range(w):
                    x = np.float64(d[t, a + j]) - d0[t, a + j]
                    if x == x:  # finite both
                        s[j] += x * x
                        k[j] += 1
            for j in range(w):
                out[a + j] = np.sqrt(s[j] / k[j]) if k[j] > 0 else np.nan

    return full_columns, rms_difference


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
               order: int = DETREND_ORDER, spectra=None, progress=None, scale=None,
               raw_scale=None) -> dict:
    """Phase 2 over a whole run, block by block of nodes.

    Parameters
    ----------
    intensity : (T, N) array-like readable by column slices (an h5py dataset)
        Node intensities, SI removed: float, or uint16 codes with ``scale``.
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
    scale, raw_scale : (T,) array_like, optional
        Per-frame scales of uint16 ``intensity`` / ``raw`` (:mod:`selfillum.unsteady.work`).

    Returns
    -------
    dict
        ``mean``, ``rms`` (RMS about zero) of dCp per node and ``si_change`` (RMS over time
        of dCp minus dCp without SI; NaN without ``raw``), each (N,) float32.
    """
    from threadpoolctl import threadpool_limits

    T, N = intensity.shape
    nc = block or (getattr(out, "chunks", None) or (None, 4096))[1]
    g = np.asarray(gain, dtype=np.float64)
    mean = np.full(N, np.nan, np.float32)
    rms = np.full(N, np.nan, np.float32)
    change = np.full(N, np.nan, np.float32)
    basis = legendre_basis(times, order) if T > order else None
    with threadpool_limits(1, "blas"):  # small products; the threads are over nodes
        _phase2_blocks(intensity, out, times, g, q, raw, nc, order, spectra, progress,
                       scale, raw_scale, basis, mean, rms, change)
    return {"mean": mean, "rms": rms, "si_change": change}


def seen_ranges(seen, chunks, offset: int = 0) -> list[tuple[int, int]]:
    """``(start, stop)`` ranges of a block's columns (block starting at column ``offset``
    of a dataset chunked ``chunks``) to write: the whole block without chunks, else the
    runs of chunk columns holding a True of ``seen``. An HDF5 chunk never written is not
    stored and reads as the fill value (NaN for ``/dcp``, 0 = unseen for the work file's
    codes): nodes no camera sees cost no bytes."""
    n = len(seen)
    if not chunks or n == 0:
        return [(0, n)]
    nc = int(chunks[1])
    first = offset // nc * nc - offset  # the block's first chunk column (may start before)
    starts = np.arange(first, n, nc)
    any_ = np.maximum.reduceat(np.asarray(seen, bool), np.maximum(starts, 0))
    out = []
    for k in np.flatnonzero(any_):
        c, e = max(int(starts[k]), 0), min(int(starts[k]) + nc, n)
        if out and out[-1][1] == c:
            out[-1] = (out[-1][0], e)
        else:
            out.append((c, e))
    return out


def _phase2_blocks(intensity, out, times, g, q, raw, nc, order, spectra, progress, scale,
                   raw_scale, basis, mean, rms, change) -> None:
    N = intensity.shape[1]
    for a in range(0, N, nc):  # blocks of nodes: whole chunk columns
        b = min(a + nc, N)
        d, mean[a:b], rms[a:b], ch, share = phase2_block(
            intensity[:, a:b], times, g[a:b], q, scale=scale,
            raw=raw[:, a:b] if raw is not None else None, raw_scale=raw_scale, order=order,
            basis=basis, return_share=True)
        if ch is not None:
            change[a:b] = ch
        for c, e in seen_ranges(share > 0, getattr(out, "chunks", None), a):
            out[:, a + c:a + e] = d[:, c:e]  # chunks of nodes without dCp stay unwritten
        if spectra is not None:
            spectra.add(a, d, share=share)
        del d
        if progress is not None:
            progress(b)
