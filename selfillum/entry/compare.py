"""PSP against the Kulites: each Kulite placed by its ``.tgts`` ``*Virtuals`` /
``*Kulites`` row, the PSP's dCp averaged over the grid nodes on a ring just outside its
dark spot, the Kulite resampled to the frames' times, then both spectra on the same Welch
segments.

* **ring**: nodes at ``1.5 r`` to ``1.5 r + 2 h`` from the Kulite (``r`` its spot's
  radius, ``h`` the grid's median edge) on the Kulite's own surface (their normal within
  30 deg of the ``.tgts`` normal, and within a quarter of the ring's radius of its tangent
  plane: not a neighbouring part), with a dCp (the spot's own nodes are patched or left
  out by the run);
* **Kulite**: ``dCp = (p - mean(p)) 144 / q`` (``p`` psi, ``q`` psf), low-passed (8th-order
  Butterworth, forwards and backwards, at 0.45 of the frame rate) when it is sampled
  faster than the frames, then linearly interpolated at the frames' times (both clocks
  start at the first frame, plus the table's ``t0``), and the 6th-order polynomial in time
  that Phase 2 removes from the PSP removed from it too (the same footing below a few Hz);
* **statistics** (``scipy.signal``, the same segments of ``nperseg`` frames, default a
  quarter of the run up to 256, Hann windows, half overlap): the two
  PSDs, their coherence, the RMS ratio ``rms(PSP) / rms(Kulite)`` (about the means), and
  the widest band of contiguous frequencies (DC left out) where the PSDs agree within 1 dB.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.errors import InputError

__all__ = ["KuliteComparison", "compare_kulites", "ring_nodes", "node_normals",
           "agreement_band", "write_comparison"]


@dataclass(frozen=True)
class KuliteComparison:
    """One Kulite against the PSP (module notes): ``f`` (Hz), ``psd_psp``, ``psd_kulite``
    (dCp^2 / Hz), ``coherence``, ``rms_psp``, ``rms_kulite``, ``band`` (Hz, Hz: the widest
    band within 1 dB; NaN when none), ``nodes`` (the ring's grid nodes)."""

    name: str
    nodes: np.ndarray
    f: np.ndarray
    psd_psp: np.ndarray
    psd_kulite: np.ndarray
    coherence: np.ndarray
    rms_psp: float
    rms_kulite: float
    band: tuple

    @property
    def rms_ratio(self) -> float:
        return self.rms_psp / self.rms_kulite if self.rms_kulite > 0 else float("nan")

    def coherence_in_band(self) -> float:
        lo, hi = self.band
        if not np.isfinite(lo):
            return float("nan")
        m = (self.f >= lo) & (self.f <= hi)
        return float(np.median(self.coherence[m]))


def node_normals(points, triangles) -> np.ndarray:
    """Unit normals of the grid's nodes: the area-weighted normals of their triangles."""
    p = np.asarray(points, float)
    t = np.asarray(triangles)
    fn = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])  # 2 x area x normal
    n = np.zeros_like(p)
    for k in range(3):  # the three corners
        np.add.at(n, t[:, k], fn)
    ln = np.linalg.norm(n, axis=1)
    return n / np.where(ln > 0, ln, 1.0)[:, None]


def ring_nodes(points, edge: float, centre, radius: float, normal=None,
               normals=None) -> np.ndarray:
    """Grid nodes on the ring ``[1.5 r, 1.5 r + 2 edge]`` around ``centre``; with the
    Kulite's ``normal`` and the nodes' ``normals``, only those on its surface (module
    notes)."""
    rel = np.asarray(points) - np.asarray(centre)[None, :]
    d = np.linalg.norm(rel, axis=1)
    lo = 1.5 * radius
    hi = lo + 2.0 * edge
    ok = (d >= lo) & (d <= hi)
    if normal is not None:
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        ok &= np.abs(rel @ n) <= 0.25 * hi
        if normals is not None:
            ok &= np.asarray(normals) @ n >= np.cos(np.radians(30.0))
    return np.flatnonzero(ok)


def agreement_band(f, a, b, db: float = 1.0) -> tuple:
    """The widest run of contiguous frequencies (``f > 0``) where ``|10 log10(a / b)|`` is
    at most ``db``: ``(f_lo, f_hi)``, NaNs when there is none."""
    f = np.asarray(f)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = (f > 0) & (np.abs(10.0 * np.log10(np.asarray(a) / np.asarray(b))) <= db)
    if not ok.any():
        return (float("nan"), float("nan"))
    x = np.concatenate([[0], ok.astype(np.int8), [0]])
    starts = np.flatnonzero(np.diff(x) == 1)
    ends = np.flatnonzero(np.diff(x) == -1) - 1
    k = int(np.argmax(ends - starts))
    return (float(f[starts[k]]), float(f[ends[k]]))


def _resample(x, rate, t0, times):
    from scipy import signal

    fps = 1.0 / np.median(np.diff(times))
    y = np.asarray(x, float)
    if rate > fps * 1.0001:
        sos = signal.butter(8, 0.45 * fps, fs=rate, output="sos")
        y = signal.sosfiltfilt(sos, y)
    tk = t0 + np.arange(len(y)) / rate
    if times[0] < tk[0] - 0.5 / rate or times[-1] > tk[-1] + 0.5 / rate:
        raise InputError(f"the Kulites cover {tk[0]:.4g} to {tk[-1]:.4g} s, the frames "
                         f"{times[0]:.4g} to {times[-1]:.4g} s")
    return np.interp(times, tk, y)


def _detrend(y, order: int | None = None):
    """``y`` less its least-squares polynomial of ``order`` in time (default Phase 2's
    :data:`selfillum.unsteady.phase2.DETREND_ORDER`)."""
    from selfillum.unsteady.phase2 import DETREND_ORDER

    order = DETREND_ORDER if order is None else order
    x = np.linspace(-1.0, 1.0, len(y))
    c = np.polynomial.legendre.legfit(x, y, min(order, len(y) - 1))
    return y - np.polynomial.legendre.legval(x, c)


def compare_kulites(h5_path, kulites, positions: dict, radii: dict, q: float,
                    nperseg: int | None = None, normals: dict | None = None) -> list:
    """Each Kulite of ``kulites`` (:class:`~selfillum.entry.kulites.KuliteSeries`) that has
    a position (``positions``/``radii``/``normals``: name -> model point, spot radius,
    surface normal) against the unsteady run's ``/dcp`` in ``h5_path``. A Kulite without
    a position, or whose ring has no dCp, is left out (the caller names them)."""
    import h5py
    from scipy import signal

    out = []
    with h5py.File(h5_path, "r") as f:
        pts = f["grid/points"][()]
        tri = f["grid/triangles"][()]
        times = f["frames/time"][()]
        e = np.linalg.norm(pts[tri] - pts[np.roll(tri, 1, axis=1)], axis=2)
        edge = float(np.median(e))
        nn = node_normals(pts, tri) if normals else None
        fps = 1.0 / float(np.median(np.diff(times)))
        T = len(times)
        nps = int(min(T, nperseg or max(8, min(256, T // 4))))
        for k, name in enumerate(kulites.names):
            if name not in positions:
                continue
            idx = ring_nodes(pts, edge, positions[name], radii[name],
                             (normals or {}).get(name), nn)
            if idx.size == 0:
                continue
            cols = f["dcp"][:, np.sort(idx)]  # a few columns of the run
            good = np.isfinite(cols).all(axis=0)
            if not good.any():
                continue
            psp = cols[:, good].mean(axis=1).astype(float)
            kul = (kulites.data[k] - kulites.data[k].mean()) * 144.0 / q
            kul = _detrend(_resample(kul, kulites.rate, kulites.t0, times))
            psp = psp - psp.mean()
            kul = kul - kul.mean()
            fr, p1 = signal.welch(psp, fs=fps, nperseg=nps)
            _, p2 = signal.welch(kul, fs=fps, nperseg=nps)
            _, coh = signal.coherence(psp, kul, fs=fps, nperseg=nps)
            out.append(KuliteComparison(name, np.sort(idx)[good], fr, p1, p2, coh,
                                        float(np.sqrt(np.mean(psp ** 2))),
                                        float(np.sqrt(np.mean(kul ** 2))),
                                        agreement_band(fr, p1, p2)))
    return out


def write_comparison(folder, comps) -> list:
    """``kulites.csv`` (one row a Kulite) and ``<name>_psd.png`` per Kulite in ``folder``;
    returns the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from resection.io._write import atomic_text

    rows = ["kulite,nodes,rms_psp,rms_kulite,rms_ratio,band_lo_hz,band_hi_hz,"
            "coherence_in_band"]
    files = []
    for c in comps:
        rows.append(f"{c.name},{len(c.nodes)},{c.rms_psp:.6g},{c.rms_kulite:.6g},"
                    f"{c.rms_ratio:.6g},{c.band[0]:.6g},{c.band[1]:.6g},"
                    f"{c.coherence_in_band():.6g}")
        fig, (a1, a2) = plt.subplots(2, 1, figsize=(5, 4.5), sharex=True,
                                     height_ratios=(3, 1))
        m = c.f > 0
        a1.loglog(c.f[m], c.psd_kulite[m], label="Kulite", color="k")
        a1.loglog(c.f[m], c.psd_psp[m], label=f"PSP ({len(c.nodes)} nodes)", color="C3")
        if np.isfinite(c.band[0]):
            a1.axvspan(c.band[0], c.band[1], color="C2", alpha=0.15, label="within 1 dB")
        a1.set_ylabel("PSD, dCp$^2$/Hz")
        a1.set_title(f"{c.name}: RMS ratio {c.rms_ratio:.3f}")
        a1.legend(fontsize=7)
        a2.semilogx(c.f[m], c.coherence[m], color="C0")
        a2.set_ylim(0, 1.05)
        a2.set_ylabel("coherence")
        a2.set_xlabel("frequency, Hz")
        fig.tight_layout()
        p = folder / f"{c.name}_psd.png"
        fig.savefig(p, dpi=80)
        plt.close(fig)
        files.append(p)
    p = folder / "kulites.csv"
    atomic_text(p, "\n".join(rows) + "\n")
    return [p, *files]
