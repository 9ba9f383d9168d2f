"""Detection of circular markers with sub-pixel accuracy.

Markers are disks 3 to 10 pixels across, darker or brighter than the model around them.
:func:`detect_markers` works in five steps:

1. **Merit image**: correlation (FFT) of the image with a zero-mean template of the
   marker's diameter: a top-hat (uniform disk) or a cone, minus the mean of a surrounding
   ring. For the top-hat the merit is the marker's contrast (inner mean minus ring mean).
2. **Threshold**: by default ``k`` times the merit's noise, the image noise being estimated
   robustly (median absolute deviation of neighbour differences, insensitive to markers
   and smooth backgrounds).
3. **Local maxima** of the merit above the threshold (only the pixels above it are compared
   with their neighbours).
4. **Screen** (:mod:`resection.markers._screen`), one compiled pass over the local maxima: the
   core's contrast against the robust spread of the surrounding ring about its plane (the
   local clutter: noise, paint speckle, an edge of the model), the size and elongation
   from the image moments. Speckle grains, edges and glare are rejected here, before the
   fit (``screen_contrast``; ``n_rejected["screen"]``).
5. **Sub-pixel refinement**, all candidates at once: a weighted centroid, then a
   Levenberg-Marquardt fit of a pixel-integrated, Gaussian-blurred disk model (centre,
   radius, contrast, local background) on a window around each candidate, by a compiled
   kernel (:mod:`resection.markers._diskfit`). Candidates cut by the border, doubles and failed
   fits are rejected. ``refine=False`` stops at the centroid (a coarse pass: fit what
   matters afterwards with :func:`refine_markers`).

Cost: on a 1 Mpx frame with 400 markers, about the time of OpenCV's blob detector (see
the asv benchmark ``bench_markers.DetectVsOpenCV``); a ``roi`` reads and searches only
its part of the frame.

NaN, infinite and saturated pixels (and a user mask) are masked: excluded from the noise
estimate, the screen and the fit, counted in :attr:`Candidates.n_masked`. Saturated pixels
enter the merit at their saturation level (a bound on their true value), so a dark marker
beside saturated glare stands out; a dark marker inside it (only its core under saturation,
its edge clipped all around) is not fitted but reported in :attr:`Candidates.saturated`
(:mod:`resection.markers._saturated`).

Conventions: pixel ``(u, v)`` = (column, row), the centre of the top-left pixel at (0, 0),
``img[v, u]``. Candidate CSV files: ``u,v,diameter,depth,merit,snr`` (+ ``id`` once matched).
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from resection.errors import InputError
from resection.markers import _diskmodel, _peaks, _prep, _saturated, _screen
from resection.markers.refine import fit_frame, refine_markers

__all__ = [
    "Candidates",
    "detect_markers",
    "refine_markers",
    "marker_template",
    "estimate_noise",
    "position_crb",
    "read_candidates",
    "write_candidates",
]

CANDIDATE_FIELDS = ("u", "v", "diameter", "depth", "merit", "snr")
#: Levenberg-Marquardt iterations of a candidate's disk fit in detection. A marker converges
#: in 2 or 3 model evaluations from its start; a speckle grain or noise blob does not
#: converge and would use them all (30 took 1.75 times as long on speckled paint, for the
#: same markers: the asv benchmark ``bench_markers.DetectPaintVsOpenCV``).
FIT_ITERATIONS = 10


@dataclass(frozen=True)
class Candidates:
    """Marker candidates found in one image (arrays of equal length N).

    Attributes
    ----------
    u, v : (N,) float arrays
        Sub-pixel centre, pixels.
    diameter : (N,) float array
        Fitted diameter, pixels (blur-dependent; the position does not depend on it).
    depth : (N,) float array
        Fitted contrast against the local background, image units, positive for the
        requested polarity.
    merit : (N,) float array
        Template correlation at the candidate.
    snr : (N,) float array
        ``depth / noise``.
    n_masked : int
        Masked pixels in the searched image (NaN, infinite, saturated, user mask).
    noise : float
        Robust noise standard deviation of the image, image units.
    threshold : float
        Merit threshold used.
    polarity : str
    n_rejected : dict
        Local maxima rejected at each step: ``screen``, ``border``, ``masked``, ``fit``
        (failed or too faint fit), ``double``.
    saturated : (K, 2) float array
        Dark markers inside saturated glare, not among the candidates: islands of
        unsaturated pixels (a marker's core) enclosed by saturated ones, at their centroid
        weighted by the depth under saturation, ``(u, v)`` pixels (a few tenths of a pixel:
        the edge that would locate them is clipped). Not written to candidate files.
    """

    u: np.ndarray
    v: np.ndarray
    diameter: np.ndarray
    depth: np.ndarray
    merit: np.ndarray
    snr: np.ndarray
    n_masked: int = 0
    noise: float = float("nan")
    threshold: float = float("nan")
    polarity: str = "dark"
    n_rejected: dict = field(default_factory=dict)
    saturated: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    def __post_init__(self):
        n = None
        for name in CANDIDATE_FIELDS:
            a = np.asarray(getattr(self, name), dtype=float).ravel()
            if n is None:
                n = a.size
            elif a.size != n:
                raise InputError(f"candidates: field {name!r} has {a.size} values, expected {n}")
            object.__setattr__(self, name, a)
        object.__setattr__(self, "saturated",
                           np.asarray(self.saturated, dtype=float).reshape(-1, 2))

    def __len__(self) -> int:
        return self.u.size

    @property
    def uv(self) -> np.ndarray:
        """(N, 2) array of ``(u, v)``."""
        return np.column_stack([self.u, self.v])

    def subset(self, index) -> Candidates:
        """Candidates selected by a boolean mask or integer index."""
        kw = {f: getattr(self, f)[index] for f in CANDIDATE_FIELDS}
        return Candidates(**kw, n_masked=self.n_masked, noise=self.noise,
                          threshold=self.threshold, polarity=self.polarity,
                          n_rejected=dict(self.n_rejected), saturated=self.saturated)

    @classmethod
    def from_uv(cls, uv, diameter=np.nan) -> Candidates:
        """Candidates from bare positions (other fields NaN, diameter as given)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        n = len(uv)
        nan = np.full(n, np.nan)
        return cls(uv[:, 0], uv[:, 1], np.broadcast_to(diameter, (n,)).astype(float),
                   nan, nan, nan)


# ----------------------------------------------------------------------------- helpers
def _as_image(image) -> np.ndarray:
    try:
        img = np.asarray(image)
    except Exception as exc:  # pragma: no cover - exotic objects
        raise InputError(f"image: not an array ({exc})") from None
    if img.dtype == np.bool_ or img.dtype.kind not in "uif":
        raise InputError(f"image: expected a numeric image, got dtype {img.dtype}")
    if img.ndim != 2:
        raise InputError(f"image: expected a 2-D single-channel array, got shape {img.shape}")
    if min(img.shape) < 3:
        raise InputError(f"image: too small ({img.shape})")
    return img


def check_diameter(diameter) -> float:
    try:
        d = float(diameter)
    except (TypeError, ValueError):
        raise InputError(f"diameter: expected a number of pixels, got {diameter!r}") from None
    if not np.isfinite(d) or d < 1.0 or d > 200.0:
        raise InputError(f"diameter: must be between 1 and 200 pixels, got {diameter!r}")
    return d


def _check_mask(mask, shape) -> np.ndarray:
    """The user mask as a bool array of the image's ``shape``."""
    mask = np.asarray(mask)
    if mask.shape != shape:
        raise InputError(f"mask: shape {mask.shape} differs from the image's {shape}")
    return mask.astype(bool, copy=False)


def estimate_noise(image, mask=None) -> float:
    """Robust noise standard deviation of an image, image units.

    The median absolute deviation of the second differences along rows and columns
    (``x[i-1] - 2 x[i] + x[i+1]``, variance ``6 sigma^2`` for white noise): insensitive to
    linear and smooth backgrounds and to a few markers or defects. Masked (``True``), NaN
    and infinite pixels are left out.
    """
    img = np.asarray(image)
    if mask is not None and np.shape(mask) != img.shape:
        raise InputError(f"mask: shape {np.shape(mask)} differs from the image's {img.shape}")
    # on large images a regular subset of rows / columns (about 2 x 25 000 samples, a
    # relative error of the estimate of about 0.5 %) is enough; one compiled pass
    k = max(1, int(img.size // 25_000))
    d = _prep.second_differences(*_prep.native(img, mask), k)
    if d.size < 10:
        raise InputError("image: too few valid pixels to estimate the noise")
    mad = _prep.median(np.abs(d - _prep.median(d)))
    sigma = 1.4826 * mad / np.sqrt(6.0)
    if sigma == 0:  # quantised, noiseless images: fall back on the standard deviation
        sigma = np.std(d) / np.sqrt(6.0)
    return float(sigma)


def marker_template(diameter: float, kind: str = "tophat") -> np.ndarray:
    """Zero-mean correlation template for a marker of ``diameter`` pixels.

    The inner part (a pixel-integrated disk for ``"tophat"``, a cone ``1 - r/R`` for
    ``"cone"``) is normalised to sum 1, the surrounding ring (from ``R + 1`` to
    ``R + 1 + max(2, R)``) to sum -1, so a constant or linear background gives 0 and, for
    the top-hat, a marker of contrast ``c`` gives about ``c``.
    """
    d = check_diameter(diameter)
    if kind not in ("tophat", "cone"):
        raise InputError(f"template: expected 'tophat' or 'cone', got {kind!r}")
    return _template(d, kind).copy()


@lru_cache(maxsize=32)
def _template(d: float, kind: str) -> np.ndarray:
    """marker_template's array, computed once per (diameter, kind); read-only."""
    R = d / 2.0
    r_out0 = R + 1.0
    r_out1 = r_out0 + max(2.0, R)
    half = int(np.ceil(r_out1 + 0.5))
    ar = np.arange(-half, half + 1, dtype=float)
    if kind == "tophat":
        inner = _diskmodel.windows([0.0], [0.0], [R], 0.3, ar, ar)[0]
    else:
        rr = np.hypot(ar[None, :], ar[:, None])
        inner = np.clip(1.0 - rr / (R + 0.5), 0.0, None)
    rr = np.hypot(ar[None, :], ar[:, None])
    ring = ((rr >= r_out0) & (rr <= r_out1)).astype(float)
    out = inner / inner.sum() - ring / ring.sum()
    out.setflags(write=False)
    return out


@lru_cache(maxsize=32)
def _ideal_size(d: float, blur: float) -> float:
    """The screen's size (second moments) of a noiseless blurred disk of diameter ``d``."""
    R, _, _, r2 = _screen.radii(d)
    half = int(np.ceil(r2)) + 2
    ar = np.arange(-half, half + 1, dtype=float)
    img = _diskmodel.windows([0.0], [0.0], [R], max(blur, 1e-3), ar, ar)[0]
    _, meas = _screen.screen(img, np.zeros((0, 0), np.bool_), np.inf, 1.0, np.array([half]),
                             np.array([half]), d, 1.0, min_contrast=0.0)
    return float(meas["size"][0])


def _parse_roi(roi, shape) -> tuple[int, int, int, int]:
    H, W = shape
    if roi is None:
        return 0, 0, W - 1, H - 1
    try:
        u0, v0, u1, v1 = (int(round(float(x))) for x in roi)
    except (TypeError, ValueError):
        raise InputError(f"roi: expected (u_min, v_min, u_max, v_max), got {roi!r}") from None
    u0, v0 = max(u0, 0), max(v0, 0)
    u1, v1 = min(u1, W - 1), min(v1, H - 1)
    if u1 - u0 < 2 or v1 - v0 < 2:
        raise InputError(f"roi: {roi!r} leaves no usable part of the {W}x{H} image")
    return u0, v0, u1, v1


# ----------------------------------------------------------------------------- detection
def detect_markers(
    image,
    diameter: float,
    polarity: str = "dark",
    template: str = "tophat",
    roi=None,
    threshold: float | None = None,
    mask=None,
    *,
    k_sigma: float = 5.0,
    blur: float = 0.6,
    saturation: float | None = None,
    max_masked: float = 0.75,
    min_separation: float | None = None,
    max_candidates: int = 20000,
    min_snr: float = 3.0,
    diameter_range: tuple[float, float] = (0.5, 2.0),
    refine: bool = True,
    screen_contrast: float | None = 2.5,
    shape: str = "disk",
) -> Candidates:
    """Find circular markers and locate them to sub-pixel accuracy.

    Parameters
    ----------
    image : (H, W) array_like
        8/16-bit integer or float image, ``img[v, u]``.
    diameter : float
        Marker diameter, pixels (1 to 200; markers are typically 3 to 10).
    polarity : {"dark", "bright"}
        Markers darker or brighter than their surroundings.
    template : {"tophat", "cone"}
        Correlation template (see :func:`marker_template`).
    roi : (u_min, v_min, u_max, v_max), optional
        Inclusive pixel bounds of the searched region; markers cut by its border are
        rejected like those cut by the image's.
    threshold : float, optional
        Merit threshold, image units (for the top-hat: the contrast). Default:
        ``k_sigma`` times the merit's noise, from :func:`estimate_noise`.
    mask : (H, W) bool array, optional
        True where pixels must be ignored (added to NaN, infinite and saturated ones).
    k_sigma : float
        Automatic threshold in noise standard deviations of the merit.
    blur : float
        PSF standard deviation of the fitted model, pixels.
    saturation : float, optional
        Pixels ``>=`` this value are masked. Default: the integer type's maximum (none
        for float images).
    max_masked : float
        Candidates whose disk has more than this fraction of masked pixels are rejected.
        The default lets through bright markers with saturated centres, whose rim still
        locates them (to about 0.01 px at SNR 40, see the tests).
    min_separation : float, optional
        Candidates closer than this (pixels) are doubles: the weaker is rejected.
        Default ``0.75 * diameter`` (at least 1.5 px).
    max_candidates : int
        Keep at most this many local maxima (the strongest) before refinement.
    min_snr : float
        Reject fitted candidates whose contrast is below this many noise standard
        deviations (such faint blobs are residual background structure, or markers whose
        position would be off by a large fraction of a pixel).
    diameter_range : (float, float)
        Reject fitted candidates whose diameter is outside ``diameter_range`` times
        ``diameter`` (counted as ``fit``): steps, edges of masked regions and noise
        blobs fit as disks far too small or too large.
    refine : bool
        Fit the disk model to every candidate (the default: positions on the Cramér-Rao
        bound). False: a coarse pass, the weighted centroid of each candidate (a few
        hundredths to a tenth of a pixel), ``diameter`` the expected one and ``depth`` the
        merit; about half the time on a 1 Mpx frame with hundreds of markers. Fit the
        ones that matter afterwards with :func:`refine_markers`.
    screen_contrast : float or None
        Before the fit, reject the local maxima whose core contrast is under this many
        times the local clutter (the robust spread of the ring around the candidate about
        its fitted plane: noise, paint speckle, a model edge), or whose size (second
        moments) is outside 0.5-1.6 times that of a disk of ``diameter``, or whose
        elongation exceeds 3.5 (a disk seen beyond about 73 degrees). Cheap (one compiled
        pass); on speckled paint most local maxima never reach the fit. None: no screen.
    shape : {"disk", "ellipse"}
        The fitted model (see :func:`refine_markers`): "ellipse" for markers seen
        obliquely (the tracker's choice).

    Returns
    -------
    Candidates
        Sorted by decreasing merit. ``n_rejected`` counts the maxima rejected at each step
        (``screen``, ``border``, ``masked``, ``fit``, ``double``); the candidates fitted
        are the maxima less those screened out. ``saturated``: dark markers inside
        saturated glare (islands of unsaturated pixels enclosed by saturation, no larger
        than the marker), located to a few tenths of a pixel, not among the candidates.

    Raises
    ------
    InputError
        Not a 2-D numeric image, bad diameter, polarity, template, roi, threshold or
        diameter_range, a mask of another shape, or no valid pixel.
    """
    img = _as_image(image)
    d = check_diameter(diameter)
    if polarity not in ("dark", "bright"):
        raise InputError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    if template not in ("tophat", "cone"):
        raise InputError(f"template: expected 'tophat' or 'cone', got {template!r}")
    if threshold is not None and not (np.isfinite(threshold) and threshold > 0):
        raise InputError(f"threshold: must be a positive number, got {threshold!r}")
    try:
        lo_d, hi_d = (float(x) for x in diameter_range)
    except (TypeError, ValueError):
        raise InputError(f"diameter_range: expected (min, max) factors, got "
                         f"{diameter_range!r}") from None
    if not (0.0 <= lo_d < hi_d):
        raise InputError(f"diameter_range: need 0 <= min < max, got {diameter_range!r}")
    u0, v0, u1, v1 = _parse_roi(roi, img.shape)
    R = d / 2.0
    tmpl = _template(d, template)
    th = tmpl.shape[0] // 2
    pad = th + int(np.ceil(R + 3 * blur + 3))
    # work on the roi plus a margin
    cu0, cv0 = max(u0 - pad, 0), max(v0 - pad, 0)
    cu1, cv1 = min(u1 + pad, img.shape[1] - 1), min(v1 + pad, img.shape[0] - 1)
    # only the roi and its margin are read (a small roi costs little on a large frame)
    part, mpart = _prep.native(img[cv0:cv1 + 1, cu0:cu1 + 1], None if mask is None else
                               _check_mask(mask, img.shape)[cv0:cv1 + 1, cu0:cu1 + 1])
    if saturation is None and img.dtype.kind in "ui":
        saturation = np.iinfo(img.dtype).max
    sat = np.inf if saturation is None else float(saturation)
    sign = -1.0 if polarity == "dark" else 1.0
    # one compiled pass: sign, fill level removed, float32 (masked pixels 0, saturated
    # ones their saturation level), masked pixels counted (and flagged, where there are
    # some)
    work, bad, n_bad, fill = _prep.prepare(part, mpart, sat, sign)
    if n_bad == work.size:
        raise InputError("image: every pixel is masked (NaN, infinite or saturated)"
                         if roi is None else "image: every pixel of the roi is masked")
    n_masked = 0 if bad is None else int(bad[v0 - cv0:v1 - cv0 + 1, u0 - cu0:u1 - cu0 + 1].sum())
    noise = estimate_noise(work, bad)
    # dark markers inside saturated glare: islands of unsaturated pixels that saturation
    # encloses, reported apart (``Candidates.saturated``)
    pits = np.zeros((0, 2))
    if sign < 0 and n_bad:
        pits = _saturated.saturated_pits(part, mpart, sat, d, min_snr * noise) + (cu0, cv0)
        pits = pits[(pits[:, 0] >= u0) & (pits[:, 0] <= u1) & (pits[:, 1] >= v0)
                    & (pits[:, 1] <= v1)]
    # the merit, the frame mirrored at its borders (zero padding would make the image edge
    # look like a marker); float32 after removing the fill level: the rounding of the
    # transforms stays far under the noise
    merit = _prep.merit(work, tmpl)
    merit_noise = noise * float(np.sqrt((tmpl**2).sum()))
    thr = float(threshold) if threshold is not None else k_sigma * max(merit_noise, 1e-12)
    size = max(3, 2 * int(np.floor(R)) + 1)
    pv, pu = _peaks.local_maxima(merit, size, thr)
    # candidates must lie inside the roi
    gu_, gv_ = pu + cu0, pv + cv0
    inside = (gu_ >= u0) & (gu_ <= u1) & (gv_ >= v0) & (gv_ <= v1)
    pu, pv = pu[inside], pv[inside]
    m = merit[pv, pu].astype(np.float64)
    order = np.argsort(-m, kind="stable")[:max_candidates]
    pu, pv, m = pu[order], pv[order], m[order]
    rejected = {"screen": 0, "border": 0, "masked": 0, "fit": 0, "double": 0}
    empty = Candidates(*(np.zeros(0) for _ in CANDIDATE_FIELDS), n_masked=n_masked, noise=noise,
                       threshold=thr, polarity=polarity, n_rejected=rejected, saturated=pits)
    if pu.size and screen_contrast is not None:
        # read from the frame itself: ``work`` now holds the merit (the transforms ran in
        # place)
        keep, _ = _screen.screen(part, mpart, sat, sign, pu, pv, d, _ideal_size(d, blur),
                                 min_contrast=float(screen_contrast))
        rejected["screen"] = int((~keep).sum())
        pu, pv, m = pu[keep], pv[keep], m[keep]
    if pu.size == 0:
        return empty
    # the fit reads its windows from the frame itself (sign and fill level applied there)
    fit = fit_frame(part, mpart, sat, sign, fill, np.column_stack([pu, pv]).astype(float), d,
                    blur=blur, strength=m, iterations=FIT_ITERATIONS if refine else 0,
                    shape=shape)
    if not refine:  # the merit is the better contrast estimate of an unfitted marker
        fit["depth"] = m
    fu, fv, fr = fit["u"], fit["v"], fit["radius"]
    ok = fit["ok"]
    ok &= fit["depth"] >= min_snr * noise
    ok &= (2.0 * fr >= lo_d * d) & (2.0 * fr <= hi_d * d)
    rejected["fit"] = int((~ok).sum())
    masked_ok = fit["masked_fraction"] <= max_masked
    rejected["masked"] = int((ok & ~masked_ok).sum())
    ok &= masked_ok
    # cut by the border of the roi (in sub-image coordinates) or of the image
    reach = np.maximum(fr, R) + 1.0
    bu0, bv0 = u0 - cu0 - 0.5, v0 - cv0 - 0.5
    bu1, bv1 = u1 - cu0 + 0.5, v1 - cv0 + 0.5
    with np.errstate(invalid="ignore"):
        inb = (fu - reach >= bu0) & (fu + reach <= bu1) & (fv - reach >= bv0) & (fv + reach <= bv1)
    rejected["border"] = int((ok & ~inb).sum())
    ok &= inb
    kept = np.flatnonzero(ok)
    if len(pits) and kept.size:
        # a candidate on an island of unsaturated pixels with more than half its disk
        # saturated has its edge clipped all around: no sub-pixel position (the island is
        # reported instead); with most of its disk seen, the fit locates it
        near = cKDTree(pits).query(np.column_stack([fu[kept] + cu0, fv[kept] + cv0]),
                                   distance_upper_bound=R + 1.0)[0] <= R + 1.0
        clipped = near & (fit["masked_fraction"][kept] > 0.5)
        rejected["masked"] += int(clipped.sum())
        ok[kept[clipped]] = False
    idx = np.flatnonzero(ok)
    # doubles: keep the stronger merit (idx is sorted by decreasing merit)
    sep = min_separation if min_separation is not None else max(0.75 * d, 1.5)
    if idx.size > 1:
        pts = np.column_stack([fu[idx], fv[idx]])
        pairs = cKDTree(pts).query_pairs(sep, output_type="ndarray")
        keep = np.ones(idx.size, bool)
        if pairs.size:
            pairs = np.sort(pairs, axis=1)
            pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
            for i, j in pairs:  # loop over the few close pairs only
                if keep[i]:
                    keep[j] = False
        rejected["double"] = int((~keep).sum())
        idx = idx[keep]
    depth = fit["depth"][idx]
    if len(pits) and idx.size:  # an island that was fitted all the same is a candidate
        pits = pits[cKDTree(np.column_stack([fu[idx] + cu0, fv[idx] + cv0])).query(pits)[0]
                    > R + 1.0]
    return Candidates(
        u=fu[idx] + cu0,
        v=fv[idx] + cv0,
        diameter=2.0 * fr[idx],
        depth=depth,
        merit=m[idx],
        snr=depth / max(noise, 1e-12),
        n_masked=n_masked,
        noise=noise,
        threshold=thr,
        polarity=polarity,
        n_rejected=rejected,
        saturated=pits,
    )


# ----------------------------------------------------------------------------- CRB
def position_crb(diameter: float, blur: float, contrast: float, noise: float,
                 *, n_positions: int = 16, half: int | None = None) -> float:
    """Cramér-Rao bound on the standard deviation of one coordinate of a marker centre.

    The model is the pixel-integrated blurred disk with 5 unknowns (u, v, radius, contrast,
    background) under white Gaussian noise of standard deviation ``noise``; the Fisher
    information ``J^T J / noise^2`` comes from the model's analytic gradient. The bound
    depends slightly on the sub-pixel position: it is averaged (as a variance) over a grid
    of ``n_positions`` positions in the pixel. (The detector also fits the background's
    slopes, 7 unknowns; on a uniform background that costs only a few per cent.)

    Returns
    -------
    float
        Bound on the standard deviation of ``u`` (pixels).
    """
    R = diameter / 2.0
    if half is None:
        half = int(np.ceil(R + 4.0 * blur + 3.0))
    ar = np.arange(-half, half + 1, dtype=float)
    k = int(np.ceil(np.sqrt(n_positions)))
    off = (np.arange(k) + 0.5) / k - 0.5
    ox, oy = (a.ravel() for a in np.meshgrid(off, off))
    n = ox.size
    M, (dx, dy, dR) = _diskmodel.windows(ox, oy, np.full(n, R), blur, ar, ar, jacobian=True)
    J = np.stack([contrast * dx, contrast * dy, contrast * dR, M, np.ones_like(M)], axis=-1)
    J = J.reshape(n, -1, 5)
    F = np.swapaxes(J, 1, 2) @ J / noise**2
    cov = np.linalg.inv(F)
    return float(np.sqrt(cov[:, 0, 0].mean()))


# ----------------------------------------------------------------------------- CSV
def write_candidates(path: str | os.PathLike, candidates: Candidates, ids=None) -> None:
    """Write candidates as CSV ``u,v,diameter,depth,merit,snr`` (+ ``id`` if ids given;
    candidates whose id is None or empty are left out)."""
    path = Path(path)
    cols = [getattr(candidates, f) for f in CANDIDATE_FIELDS]
    rows = range(len(candidates))
    if ids is not None:
        ids = list(ids)
        if len(ids) != len(candidates):
            raise InputError(f"ids: {len(ids)} ids for {len(candidates)} candidates")
        rows = [i for i in rows if ids[i] not in (None, "")]
    with open(path, "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow((["id"] if ids is not None else []) + list(CANDIDATE_FIELDS))
        for i in rows:
            vals = [f"{c[i]:.6g}" if f not in ("u", "v") else f"{c[i]:.4f}"
                    for f, c in zip(CANDIDATE_FIELDS, cols, strict=True)]
            wr.writerow(([str(ids[i])] if ids is not None else []) + vals)


def read_candidates(path: str | os.PathLike) -> tuple[Candidates, list[str] | None]:
    """Read a candidate CSV. Returns ``(candidates, ids)``, ``ids`` None without an ``id``
    column. Columns other than ``u,v`` may be missing (NaN); unknown columns are an error."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such candidate file")
    with open(path, newline="") as fh:
        rd = csv.reader(fh)
        try:
            header = [h.strip() for h in next(rd)]
        except StopIteration:
            raise InputError(f"{path}: empty file, expected a header u,v,...") from None
        rows = [r for r in rd if r and any(c.strip() for c in r)]
    unknown = set(header) - set(CANDIDATE_FIELDS) - {"id"}
    if unknown:
        raise InputError(f"{path}: unknown column(s) {sorted(unknown)}")
    if "u" not in header or "v" not in header:
        raise InputError(f"{path}: columns 'u' and 'v' are required")
    data = {f: np.full(len(rows), np.nan) for f in CANDIDATE_FIELDS}
    ids = [] if "id" in header else None
    for k, r in enumerate(rows):
        if len(r) != len(header):
            raise InputError(f"{path}: line {k + 2} has {len(r)} fields, expected {len(header)}")
        for name, val in zip(header, r, strict=True):
            if name == "id":
                ids.append(val.strip())
                continue
            try:
                data[name][k] = float(val)
            except ValueError:
                raise InputError(f"{path}: line {k + 2}: {name}={val!r} is not a number") \
                    from None
    if np.any(~np.isfinite(data["u"])) or np.any(~np.isfinite(data["v"])):
        raise InputError(f"{path}: u and v must be finite numbers")
    return Candidates(**data), ids
