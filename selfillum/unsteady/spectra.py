"""Power spectra of dCp per node: Welch's method (:func:`scipy.signal.welch`), computed on
the blocks of nodes Phase 2 already holds, so that spectra cost no second pass over the
run and memory stays bounded by the block.

Conventions: one-sided power spectral density of dCp, ``dCp^2 / Hz``, Hann window of
``nperseg`` frames, half overlap, each segment's mean removed (SciPy's defaults); its
integral over frequency is the variance of dCp. Frames where a node is unseen (NaN) are
set to zero (dCp after the detrend has zero mean) and the PSD is divided by the share of
frames seen, so that the total power of a node seen part of the time is kept; a node seen
in no frame has NaN.

Two products (:class:`Spectra`):

* ``probes``: the full PSD at the probe nodes (``--psd N1,N2,...``);
* ``bands``: per node, the PSD averaged over ``n_bands`` frequency bands, equally spaced
  in log frequency from the second Welch bin to Nyquist (``/psd/band_psd``, one column a
  band; ``/psd/band_edges`` in Hz), and the mean PSD over all the nodes seen
  (``/psd/mean``).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["welch_block", "band_edges", "band_average", "Spectra", "default_bands",
           "DEFAULT_BANDS"]

#: Bands of the per-node band PSD by default.
DEFAULT_BANDS = 8


def default_bands(n_frames: int, nperseg: int | None = None) -> int:
    """:data:`DEFAULT_BANDS`, or the spectrum's frequencies above 0 when it has fewer
    (segments of ``min(nperseg or 256, n_frames)`` frames)."""
    nper = int(min(nperseg or 256, n_frames))
    return max(0, min(DEFAULT_BANDS, nper // 2))


def _hann(n: int) -> np.ndarray:
    """The periodic Hann window of ``n`` samples (SciPy's ``get_window("hann", n)``,
    without importing :mod:`scipy.signal`: a second of a short run's start-up)."""
    n = int(n)
    if n <= 1:
        return np.ones(max(n, 0))
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)


def welch_block(dcp, fs: float, nperseg: int, workers: int | None = None, share=None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Welch PSD of every column of a ``(T, n)`` block.

    The estimate of :func:`scipy.signal.welch` (its defaults: periodic Hann window,
    ``nperseg // 2`` overlap, each segment's mean removed, density scaling, one-sided),
    computed segment by segment on the block as it is (float32 blocks in float32 FFTs,
    the powers summed in float64; relative difference to SciPy's float64 about 1e-6),
    without SciPy's float64 copies of every segment.

    Parameters
    ----------
    dcp : (T, n) array_like
        dCp per frame and node (NaN unseen).
    fs : float
        Frame rate, Hz.
    nperseg : int
        Frames per Welch segment (at most ``T``).
    workers : int, optional
        Threads over groups of nodes (default: the available cores).
    share : (n,) array_like, optional
        The share of frames where each column is finite, when the caller knows it (Phase
        2 does): 1 = no NaN, 0 = nothing seen (not computed).

    Returns
    -------
    freq : (K,) float64
        Hz.
    psd : (n, K) float64
        ``dCp^2 / Hz``; NaN for a node never seen.
    """
    from resection._threads import run_blocks, split_range

    d = np.asarray(dcp)
    if d.dtype not in (np.float32, np.float64):
        d = d.astype(np.float64)
    if d.ndim != 2:
        raise InputError(f"welch_block: expected a (frames, nodes) block, got {d.shape}")
    T, n = d.shape
    nper = int(min(nperseg, T))
    if nper < 2:
        raise InputError(f"welch_block: {T} frames are too few for a spectrum")
    if share is None:
        share = np.isfinite(d).mean(axis=0)
    share = np.asarray(share, dtype=np.float64)
    win64 = _hann(nper)
    win = win64.astype(d.dtype)[:, None]
    acc = np.full((nper // 2 + 1, n), np.nan)
    # columns seen in every frame as they are (runs of them, small gaps of unseen
    # columns computed along: their result is dropped), those seen in some frames with
    # the unseen frames set to zero
    blocks = [(a + c, a + e) for a, b in _runs(share > 0) for c, e in
              split_range(b - a, workers, min_size=256)]
    run_blocks(lambda b: _welch_sum(d[:, b[0]:b[1]], win, acc[:, b[0]:b[1]]), blocks,
               workers)
    part = np.flatnonzero((share > 0) & (share < 1))
    if part.size:
        dp = d[:, part]
        sub = np.zeros((acc.shape[0], part.size))
        _welch_sum(np.where(np.isfinite(dp), dp, dp.dtype.type(0)), win, sub)
        acc[:, part] = sub
    nseg = (T - nper) // (nper - nper // 2) + 1
    acc *= 1.0 / (fs * float(win64 @ win64) * nseg)
    if nper % 2:
        acc[1:] *= 2.0
    else:
        acc[1:-1] *= 2.0
    with np.errstate(invalid="ignore", divide="ignore"):
        p = np.where(share > 0, acc / share, np.nan)
    return np.fft.rfftfreq(nper, 1.0 / float(fs)), p.T


def _runs(mask, gap: int = 64) -> list[tuple[int, int]]:
    """``(start, stop)`` of the runs of True in ``mask``, runs closer than ``gap`` merged."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    cut = np.flatnonzero(np.diff(idx) > gap)
    starts = np.concatenate([[idx[0]], idx[cut + 1]])
    stops = np.concatenate([idx[cut], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def _welch_sum(d, win, acc) -> None:
    """``acc`` = the sum over the half-overlapping segments of ``|rfft((seg - mean) win)|^2``
    for the columns of ``d`` (T, m)."""
    from scipy import fft

    nper = len(win)
    step = nper - nper // 2
    nseg = (d.shape[0] - nper) // step + 1
    acc[...] = 0.0
    for s0 in range(0, nseg * step, step):  # segments: (nper, m) each
        seg = d[s0:s0 + nper]
        X = fft.rfft((seg - seg.mean(axis=0, keepdims=True)) * win, axis=0)
        acc += X.real * X.real
        acc += X.imag * X.imag


def band_edges(freq, n_bands: int) -> np.ndarray:
    """``n_bands + 1`` edges (Hz), log-spaced from the second bin of ``freq`` to its last."""
    f = np.asarray(freq, dtype=np.float64)
    if n_bands < 1:
        raise InputError(f"psd bands: need at least 1, got {n_bands}")
    if f.size < 3:
        raise InputError("psd bands: the spectrum has fewer than 3 frequencies")
    return np.geomspace(f[1], f[-1], int(n_bands) + 1)


def band_average(freq, psd, edges) -> np.ndarray:
    """Mean PSD of every row of ``psd`` (n, K) over each band ``[edges[i], edges[i+1])``
    (the last band closed); a band holding no bin takes the bin nearest its centre.

    The bins of a band are contiguous (``freq`` ascending): each band is one sum over a
    slice (:func:`numpy.add.reduceat`), so memory is the ``(n, bands)`` answer, never a
    ``(K, bands)`` matrix."""
    f = np.asarray(freq, dtype=np.float64)
    e = np.asarray(edges, dtype=np.float64)
    p = np.asarray(psd, dtype=np.float64)
    nb = len(e) - 1
    b = np.searchsorted(e, f, side="right") - 1
    b[f == e[-1]] = nb - 1
    inb = (b >= 0) & (b < nb)
    count = np.bincount(b[inb], minlength=nb)
    out = np.empty((p.shape[0], nb))
    full = np.flatnonzero(count > 0)
    if full.size:
        idx = np.flatnonzero(inb)  # the bins inside the bands: contiguous, band by band
        lo = idx[0]
        starts = np.searchsorted(b[idx], full)  # first bin of each non-empty band
        sums = np.add.reduceat(p[:, lo:idx[-1] + 1], starts, axis=1)
        out[:, full] = sums / count[full]
    empty = np.flatnonzero(count == 0)
    if empty.size:
        centre = np.sqrt(e[:-1] * e[1:])[empty]
        hi = np.clip(np.searchsorted(f, centre), 1, f.size - 1)
        near = np.where(np.abs(f[hi - 1] - centre) <= np.abs(f[hi] - centre), hi - 1, hi)
        out[:, empty] = p[:, near]
    return out


class Spectra:
    """Welch spectra accumulated block by block of nodes (Phase 2 calls :meth:`add`).

    Parameters
    ----------
    n_nodes : int
    fs : float
        Hz.
    n_frames : int
    probes : sequence of int, optional
        Node numbers (grid file order, from 0) whose full PSD is kept.
    n_bands : int
        Bands of the per-node band-averaged PSD (0: none).
    nperseg : int
        Frames per Welch segment (default ``min(T, 256)``).
    band_out : (N, n_bands) writable array, optional
        Receives the per-node band PSD block by block (an HDF5 dataset); default kept in
        memory (``N n_bands`` float32).
    """

    def __init__(self, n_nodes: int, fs: float, n_frames: int, probes=(), n_bands: int = 0,
                 nperseg: int | None = None, band_out=None):
        self.N = int(n_nodes)
        self.fs = float(fs)
        self.nperseg = int(min(nperseg or 256, n_frames))
        if self.nperseg < 8:
            raise InputError(f"psd: {n_frames} frames (segments of {self.nperseg}) are too "
                             "few for a spectrum (at least 8)")
        self.probes = np.asarray(list(probes), dtype=np.int64)
        if self.probes.size and (self.probes.min() < 0 or self.probes.max() >= self.N):
            bad = self.probes[(self.probes < 0) | (self.probes >= self.N)][0]
            raise InputError(f"--psd: node {bad} is not a grid node (0 to {self.N - 1})")
        self.freq = np.fft.rfftfreq(self.nperseg, 1.0 / self.fs)
        K = self.freq.size
        self.probe_psd = np.full((self.probes.size, K), np.nan)
        self.n_bands = int(n_bands)
        if self.n_bands > K - 1:
            raise InputError(f"--psd-bands {self.n_bands}: more bands than the spectrum's "
                             f"{K - 1} frequencies above 0 (Welch segments of "
                             f"{self.nperseg} frames); at most {K - 1}")
        self.edges = band_edges(self.freq, self.n_bands) if self.n_bands else None
        if self.n_bands:
            self.band = band_out if band_out is not None else np.full(
                (self.N, self.n_bands), np.nan, np.float32)
        self._sum = np.zeros(K)
        self._count = 0

    @property
    def bytes_per_node(self) -> int:
        """Bytes a node of a Phase 2 block costs here beyond its dCp: its Welch sums and
        PSD (float64, ``K`` frequencies, three arrays at the peak) and its band averages
        (float64 and their float32 copy)."""
        return 24 * self.freq.size + 12 * self.n_bands

    def add(self, a: int, dcp_block, psd=None, share=None) -> None:
        """Spectra of nodes ``a:a + n`` from their ``(T, n)`` dCp block (or their
        ``psd`` (n, K), :func:`welch_block` of it, computed elsewhere; ``share``: see
        :func:`welch_block`)."""
        if psd is None:
            freq, p = welch_block(dcp_block, self.fs, self.nperseg, share=share)
        else:
            freq, p = self.freq, np.asarray(psd)
        n = p.shape[0]
        sel = (self.probes >= a) & (self.probes < a + n)
        if sel.any():
            self.probe_psd[sel] = p[self.probes[sel] - a]
        ok = np.isfinite(p).all(axis=1)
        self._sum += p[ok].sum(axis=0)
        self._count += int(ok.sum())
        if self.n_bands:
            self.band[a:a + n] = band_average(freq, p, self.edges).astype(np.float32)

    @property
    def mean_psd(self) -> np.ndarray:
        """Mean PSD over the nodes seen, (K,)."""
        return self._sum / self._count if self._count else np.full_like(self._sum, np.nan)

    def write(self, group) -> None:
        """``frequency``, ``mean``, ``probe_nodes``, ``probe_psd`` (and ``band_edges``;
        ``band_psd`` when kept in memory) into an HDF5 group."""
        group.create_dataset("frequency", data=self.freq)
        group.create_dataset("mean", data=self.mean_psd)
        group.create_dataset("probe_nodes", data=self.probes)
        group.create_dataset("probe_psd", data=self.probe_psd)
        group.attrs.update(nperseg=self.nperseg, window="hann", noverlap=self.nperseg // 2,
                           scaling="density", units="dCp^2/Hz", fs=self.fs)
        if self.n_bands:
            group.create_dataset("band_edges", data=self.edges)
            if isinstance(self.band, np.ndarray):
                group.create_dataset("band_psd", data=self.band)
