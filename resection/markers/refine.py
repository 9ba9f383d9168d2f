"""Sub-pixel refinement of marker positions: a least-squares fit of the blurred,
pixel-integrated disk model on a window around each start, all candidates at once.

Used by :func:`resection.markers.detect.detect_markers` (which re-exports :func:`refine_markers`)
and by the tracker, which fits the markers in small windows around their predicted
positions. The windows, their weights and starting values come from one compiled pass
over the candidates (:mod:`resection.markers._starts`, reading the windows straight from the
frame), the fit from the kernel of :mod:`resection.markers._diskfit`; the neighbours whose pixels
are left out of each window are found here (a k-d tree).

Conventions: pixel ``(u, v)`` = (column, row), the centre of the top-left pixel at (0, 0),
``signal[v, u]``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from resection.errors import InputError
from resection.markers import _diskfit, _ellipsefit, _prep, _starts

__all__ = ["refine_markers"]


def _neighbours(uv, strength, reach, min_dist):
    """For each start, the other starts within ``reach`` that are at least ``min_dist``
    away (a separate marker, not a side lobe) and at least 0.3 times as strong, as CSR
    ``(offsets, indices)``."""
    n = len(uv)
    if n < 2:
        return np.zeros(n + 1, np.int64), np.zeros(0, np.int64)
    pairs = cKDTree(uv).query_pairs(reach, output_type="ndarray")
    I = np.concatenate([pairs[:, 0], pairs[:, 1]]).astype(np.int64)
    J = np.concatenate([pairs[:, 1], pairs[:, 0]]).astype(np.int64)
    keep = (np.hypot(*(uv[I] - uv[J]).T) >= min_dist) & (strength[J] >= 0.3 * strength[I])
    I, J = I[keep], J[keep]
    order = np.argsort(I, kind="stable")
    off = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(I, minlength=n), out=off[1:])
    return off, J[order]


def refine_markers(
    signal: np.ndarray,
    uv0,
    diameter: float,
    *,
    bad: np.ndarray | None = None,
    blur: float = 0.6,
    iterations: int = 30,
    half: int | None = None,
    strength=None,
    chunk: int = 1024,
    tol: float = 1e-4,
    shape: str = "disk",
    workers: int | None = 1,
) -> dict:
    """Sub-pixel centres of bright blobs by a least-squares disk fit, all at once.

    Parameters
    ----------
    signal : (H, W) float array
        Image with markers brighter than the background (negate dark markers).
    uv0 : (n, 2) array
        Starting centres, pixels (within about a radius of the truth).
    diameter : float
        Expected diameter, pixels (starting radius).
    bad : (H, W) bool array, optional
        Pixels to leave out of the fit (NaN and infinite ones are left out in any case).
    blur : float
        PSF standard deviation assumed by the model, pixels. A wrong value biases the
        fitted diameter, not the centre.
    iterations : int
        Levenberg-Marquardt iterations; 0: no fit, the starting values (a weighted
        centroid, the expected radius, the mean contrast inside it, the ring's median
        background) are returned, ``rms`` NaN.
    half : int, optional
        Half-size of the fitted window (default ``ceil(1.25 R + 3 blur + 3)``).
    strength : (n,) array, optional
        Merit of each start; the pixels of a neighbour at least 0.3 times as strong and
        at least ``1.5 R + 1`` away are left out of a candidate's fit.
    chunk : int
        Candidates fitted together (the memory of their windows grows with it).
    tol : float
        A candidate's iterations stop once the error its last step leaves in the centre is
        under ``tol`` pixels: the step's size times its ratio to the step before (the
        contraction of the iterations; for the first step its size), the step being taken
        without evaluating the model again. From the starts (centroid, contrast from the
        volume) 2 or 3 evaluations a candidate; the default leaves the centres within
        ~5e-5 px (median; 90 % within 3e-4 px) of a fit run to convergence, far under the
        Cramér-Rao bound (about 0.005 px at SNR 100).
    shape : {"disk", "ellipse"}
        The marker's model: a disk, or an ellipse (a round marker seen obliquely: its
        half-width, the half-height of its middle column and the slope of its columns'
        midpoints fitted besides; see :mod:`resection.markers._ellipsefit`). On a 35 px
        marker seen at an aspect of 0.6 the disk's fit needs about 30 evaluations and
        leaves the centre 0.1 px off; the ellipse's needs a few and leaves it at the noise.
        ``radius`` is then the radius of the disk of the same area, ``sqrt(X H)``.
    workers : int, optional
        Threads over the windows (None: the available cores). Each window's fit is its
        own: the result does not depend on it.

    Returns
    -------
    dict of (n,) arrays: ``u, v, radius, depth, background, rms, ok, masked_fraction``.
    """
    signal = np.asarray(signal)
    if bad is not None and np.shape(bad) != signal.shape:
        raise InputError(f"bad: shape {np.shape(bad)} differs from the signal's {signal.shape}")
    img, mask = _prep.native(signal, bad)
    return fit_frame(img, mask, np.inf, 1.0, 0.0, uv0, diameter, blur=blur,
                     iterations=iterations, half=half, strength=strength, chunk=chunk, tol=tol,
                     shape=shape, workers=workers)


def fit_frame(img, mask, sat, sign, fill, uv0, diameter, *, blur=0.6, iterations=30,
              half=None, strength=None, chunk=1024, tol=1e-4, shape="disk",
              workers=1) -> dict:
    """:func:`refine_markers` on the signal ``sign * img - fill`` of a frame ``img`` (any
    integer or float type of :func:`resection.markers._prep.native`), without converting it:
    pixels where ``mask`` (a bool array of the frame's shape, or (0, 0) for none) is True,
    NaN, infinite or ``>= sat`` are left out. The result's ``background`` is that of the
    signal. ``workers``: threads over the windows (None: the available cores)."""
    if shape not in ("disk", "ellipse"):
        raise InputError(f"shape: {shape!r} is not 'disk' or 'ellipse'")
    uv0 = np.asarray(uv0, float).reshape(-1, 2)
    n = len(uv0)
    R0 = diameter / 2.0
    if half is None:
        half = int(np.ceil(1.25 * R0 + 3.0 * blur + 3.0))
    strength = np.ones(n) if strength is None else np.asarray(strength, float)
    nbrs = _neighbours(uv0, strength, 2.0 * half + 1.0, 1.5 * R0 + 1.0)
    frame = (img, mask, float(sat), float(sign), float(fill))
    parts = [_refine_chunk(frame, uv0, nbrs, np.arange(k, min(k + chunk, n)), R0, blur,
                           iterations, half, tol, shape, workers)
             for k in range(0, n, max(int(chunk), 1))]
    keys = ("u", "v", "radius", "depth", "background", "rms", "ok", "masked_fraction")
    if not parts:
        return {k: np.zeros(0, bool if k == "ok" else float) for k in keys}
    return {k: np.concatenate([p[k] for p in parts]) for k in keys}


def _ellipse_starts(win, w, pe, reach, blur, rmin, rmax) -> None:
    """The ellipse's shape ``X, H, k`` started from the second moments of each window's
    height above its background within ``reach`` of its centroid (in place in ``pe``,
    (n, 9)): a uniform ellipse has ``<x x> = X^2 / 4``, ``<x y> = k X^2 / 4`` and
    ``<y y> = (H^2 + k^2 X^2) / 4``; the PSF adds ``blur^2`` to both variances. The
    contrast starts as the height's volume over the ellipse's area ``pi X H`` (the disk's
    start, the mean inside the expected radius, takes in the background above and below
    an obliquely seen marker: 0.6 of the contrast on the 609k run's targets, and the fit
    then spent an evaluation on the contrast alone; 5.4 -> 5.0 evaluations a window).
    Windows whose moments do not give an ellipse keep the disk's start."""
    n, W = win.shape[0], win.shape[1]
    if n == 0:
        return
    g = np.arange(W, dtype=float)
    du = g[None, None, :] - pe[:, 0, None, None]
    dv = g[None, :, None] - pe[:, 1, None, None]
    height = np.where((w > 0) & (du * du + dv * dv <= reach * reach),
                      np.maximum(win - pe[:, 6, None, None], 0.0), 0.0)
    vol = height.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        sxx = (height * du * du).sum(axis=(1, 2)) / vol - blur * blur
        syy = (height * dv * dv).sum(axis=(1, 2)) / vol - blur * blur
        sxy = (height * du * dv).sum(axis=(1, 2)) / vol
        k = sxy / sxx
        X = 2.0 * np.sqrt(sxx)
        H = 2.0 * np.sqrt(syy - k * sxy)
    ok = (vol > 0) & np.isfinite(X) & np.isfinite(H) & (X > rmin) & (H > rmin) \
        & (X < rmax) & (H < rmax) & (np.abs(k) < _ellipsefit.KMAX)
    pe[ok, 2], pe[ok, 3], pe[ok, 4] = X[ok], H[ok], k[ok]
    pe[ok, 5] = vol[ok] / (np.pi * X[ok] * H[ok])


def _fit_in_blocks(fit, win, w, p, args, workers):
    """``fit(win, w, p, *args)`` (a compiled ``fit_windows``, GIL released) over blocks of
    windows on ``workers`` threads: each window's fit is its own, so the blocks give what
    one call gives. Returns the parameters and the costs."""
    from resection._threads import run_blocks, split_range

    out = run_blocks(lambda b: fit(win[b[0]:b[1]], w[b[0]:b[1]], p[b[0]:b[1]], *args),
                     split_range(len(p), workers, min_size=2, per_worker=4), workers)
    if len(out) == 1:
        return out[0][0], out[0][1]
    return np.concatenate([o[0] for o in out]), np.concatenate([o[1] for o in out])


def _refine_chunk(frame, uv_all, nbrs, sel, R0, blur, iterations, half, tol, shape,
                  workers=1) -> dict:
    """Levenberg-Marquardt fit of the windows of the starts ``sel`` (see refine_markers),
    on ``workers`` threads."""
    uv0 = uv_all[sel]
    n = len(uv0)
    iu_all = np.rint(uv_all[:, 0]).astype(np.int64)
    iv_all = np.rint(uv_all[:, 1]).astype(np.int64)
    iu, iv = iu_all[sel], iv_all[sel]
    # windows read from the frame, weights (the pixels of a neighbouring marker, within
    # R + 3 blur + 0.5 of another candidate, are left out of the fit, so that close
    # markers do not pull each other), starts: a weighted centroid above the ring's median
    win, w, p, height, masked_fraction, n_weighted = _starts.windows(
        *frame, iu_all, iv_all, sel, half, R0, nbrs[0], nbrs[1], uv_all,
        R0 + 3.0 * blur + 0.5)
    # parameters: x, y, R, a, background, its slopes along u and v (window-centred)
    NP = 7
    rmin, rmax = 0.3, 3.0 * R0 + 2.0
    # the fit runs in window coordinates (centre of the window's top-left pixel at 0, 0)
    ox, oy = (iu - half).astype(float), (iv - half).astype(float)
    s = max(float(blur), 1e-3)
    if iterations > 0 and shape == "ellipse":
        # the ellipse's parameters x, y, X, H, k, a, b, bu, bv from the disk's start; its
        # bounding box reaches sqrt(H^2 + k^2 X^2): the nodes for up to twice rmax
        tables = _diskfit.node_table(min(_diskfit.n_nodes(2.0 * rmax, s), 2048))
        pe = np.column_stack([p[:, :3], p[:, 2], np.zeros(n), p[:, 3:]])
        _ellipse_starts(win, w, pe, R0 + 1.0, s, rmin, rmax)
        pe, cost = _fit_in_blocks(_ellipsefit.fit_windows, win, w, pe,
                                  (*_diskfit.edge_table(s), rmin, rmax, int(iterations),
                                   float(tol), *tables), workers)
        p = np.column_stack([pe[:, :2], np.sqrt(pe[:, 2] * pe[:, 3]), pe[:, 5:]])
        NP = _ellipsefit.NP
    elif iterations > 0:
        tables = _diskfit.node_table(min(_diskfit.n_nodes(rmax, s), 2048))
        p, cost = _fit_in_blocks(_diskfit.fit_windows, win, w, p,
                                 (*_diskfit.edge_table(s), rmin, rmax, int(iterations),
                                  float(tol), *tables), workers)
    else:  # no fit: the starting values
        p[:, 3] = height
        cost = np.full(n, np.nan)
    p[:, 0] += ox
    p[:, 1] += oy
    npix = np.maximum(n_weighted - NP, 1)
    ok = (
        np.all(np.isfinite(p), axis=1)
        & (p[:, 3] > 0)
        & (np.hypot(p[:, 0] - uv0[:, 0], p[:, 1] - uv0[:, 1]) <= R0 + 1.5)
        & (p[:, 2] > rmin * 1.01)
        & (p[:, 2] < 3.0 * R0 + 1.9)
    )
    return {
        "u": p[:, 0], "v": p[:, 1], "radius": p[:, 2], "depth": p[:, 3],
        "background": p[:, 4], "rms": np.sqrt(cost / npix), "ok": ok,
        "masked_fraction": masked_fraction,
    }
