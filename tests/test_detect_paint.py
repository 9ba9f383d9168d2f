"""Detection on real-looking paint (issue 21): the screen before the fit against a NumPy
reference, targets inside or beside saturated glare, and on the frames of
``scenes.revolution.paint_frame`` (speckle, glare, taps) every target found and the accuracy
at SNR 20 against the generator's truth, beside OpenCV's blob detector.

The paint-frame seeds here (200-207) are neither those used to develop the detector (0-15)
nor that of the asv benchmark ``bench_markers.DetectPaintVsOpenCV`` (100; the former
bench script used 100-111).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import cKDTree

from resection.markers import _screen
from resection.markers.detect import detect_markers
from scenes.marker_images import render_markers


# ----------------------------------------------------------------------------- the screen
def _screen_reference(img, pu, pv, diameter):
    """The screen's measures by NumPy: a least-squares plane (``lstsq``) through the ring,
    fitted again without the pixels more than 3 robust spreads off; the clutter 1.4826
    times the median absolute deviation about it; the core's mean height; the second
    moments of the positive height within R + 1.5."""
    R, r_in, r1, r2 = _screen.radii(diameter)
    half = int(np.ceil(r2))
    dv, du = np.mgrid[-half:half + 1, -half:half + 1]
    rr = np.hypot(du, dv)
    ring = (rr >= r1) & (rr <= r2)
    out = []
    for u, v in zip(pu, pv, strict=True):
        z = img[v - half:v + half + 1, u - half:u + half + 1].astype(float)
        A = np.column_stack([np.ones(ring.sum()), du[ring], dv[ring]])
        coef = np.linalg.lstsq(A, z[ring], rcond=None)[0]
        res = z[ring] - A @ coef
        s = 1.4826 * np.median(np.abs(res - np.median(res)))
        keep = np.abs(res - np.median(res)) <= 3.0 * s
        if 8 <= keep.sum() < keep.size:
            coef = np.linalg.lstsq(A[keep], z[ring][keep], rcond=None)[0]
            res = z[ring] - A @ coef
            s = 1.4826 * np.median(np.abs(res - np.median(res)))
        h = z - (coef[0] + coef[1] * du + coef[2] * dv)
        contrast = h[rr <= r_in].mean()
        sel = (rr <= R + 1.5) & (h > 0)
        w = h[sel]
        x, y = du[sel], dv[sel]
        cx, cy = (w * x).sum() / w.sum(), (w * y).sum() / w.sum()
        cov = np.cov(np.vstack([x, y]), aweights=w, bias=True)
        lam = np.linalg.eigvalsh(cov)
        out.append((contrast, s, np.sqrt(lam.sum()), np.sqrt(lam[1] / lam[0]), cx, cy))
    return np.array(out)


def test_screen_measures_equal_numpy():
    rng = np.random.default_rng(21)
    speckle = ndimage.gaussian_filter(rng.normal(size=(120, 160)), 1.2)
    img = 100.0 + 0.3 * np.arange(160)[None, :] + 8.0 * speckle / speckle.std()
    img += render_markers((120, 160), np.array([[40.3, 50.6], [100.8, 70.2]]), 5.0,
                          contrast=60.0, background=0.0, polarity="bright", blur=0.7,
                          snr=None, dtype=np.float64)
    img[51, 45] += 300.0  # an outlier in the first marker's ring (a tap, a hot pixel)
    pu = np.array([40, 101, 20, 130, 75])
    pv = np.array([51, 70, 20, 100, 33])
    c, s, z, e = _screen.measure(img, np.zeros((0, 0), bool), np.inf, 1.0, pu, pv,
                                 *_screen.radii(5.0))
    ref = _screen_reference(img, pu, pv, 5.0)
    np.testing.assert_allclose(c, ref[:, 0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s, ref[:, 1], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(z, ref[:, 2], rtol=1e-9)
    np.testing.assert_allclose(e, ref[:, 3], rtol=1e-9)
    # the markers stand out of their clutter, the outlier in the ring left out of the plane
    assert c[0] > 4 * s[0] and c[1] > 4 * s[1]
    # dark polarity reads the negated frame, from an integer frame as from a float one
    img8 = np.clip(np.rint(255.0 - img), 0, 254).astype(np.uint8)
    c8, s8, *_ = _screen.measure(img8, np.zeros((0, 0), bool), 255.0, -1.0, pu, pv,
                                 *_screen.radii(5.0))
    ref8 = _screen_reference(-img8.astype(float), pu, pv, 5.0)
    np.testing.assert_allclose(c8, ref8[:, 0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s8, ref8[:, 1], rtol=1e-9, atol=1e-9)


# ----------------------------------------------------------------------------- saturation
def _glare_frame(rng):
    """8-bit frame (SNR 20 for a 105-count dark target on a 150-count paint) with two
    glare spots saturating their cores (amplitude 180 counts, sigma 12 px; saturated within
    12.5 px of their centres): target A at the first spot's centre (only its core stays
    under 255), target B beside it (its ring reaches into the saturation, its core does not)
    and target C far from both; the second spot has no target."""
    uv = np.array([[80.3, 60.6], [95.7, 63.2], [150.4, 40.8]])  # A, B, C
    img = render_markers((120, 200), uv, 5.0, contrast=105.0, background=150.0, blur=0.7,
                         snr=20.0, rng=rng, dtype=np.float64)
    vv, uu = np.mgrid[0:120, 0:200]
    for gu, gv in ((80.0, 60.0), (150.0, 90.0)):
        img += 180.0 * np.exp(-((uu - gu) ** 2 + (vv - gv) ** 2) / (2 * 12.0**2))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), uv


def test_target_in_saturated_glare_is_reported_saturated_not_missed():
    """The rule: a dark target whose rim and ring the glare saturates (only its core under
    the saturation level) has no edge left to fit; it is not a candidate but is reported in
    ``Candidates.saturated`` (the centroid of its unsaturated core, within a few tenths of a
    pixel). A target whose ring only partly saturates is fitted from its unsaturated
    pixels, a glare spot without a target reports nothing."""
    for seed in range(4):
        img, uv = _glare_frame(np.random.default_rng(seed))
        c = detect_markers(img, 5.0)
        assert c.n_masked > 300  # the two glare cores
        d_a = np.hypot(*(c.uv - uv[0]).T).min() if len(c) else np.inf
        assert d_a > 1.5  # A is not a candidate ...
        assert len(c.saturated) == 1  # ... but reported, and nothing else
        assert np.hypot(*(c.saturated[0] - uv[0])) < 0.5
        e = cKDTree(c.uv).query(uv[1:])[0]
        assert e[0] < 0.25  # B: fitted beside the saturation
        assert e[1] < 0.15  # C: far from it


# ----------------------------------------------------------------------------- paint frames
def _opencv(img, d):
    """OpenCV's blob detector set as in the asv benchmark ``bench_markers.DetectPaintVsOpenCV``."""
    cv2 = pytest.importorskip("cv2")
    p = cv2.SimpleBlobDetector_Params()
    p.filterByColor, p.blobColor = True, 0
    p.filterByArea = True
    area = np.pi * d**2 / 4
    p.minArea, p.maxArea = 0.3 * area, 3.0 * area
    p.filterByCircularity = p.filterByConvexity = p.filterByInertia = False
    p.minThreshold, p.maxThreshold, p.thresholdStep = 10, 250, 10
    p.minDistBetweenBlobs = d
    return np.array([k.pt for k in cv2.SimpleBlobDetector_create(p).detect(img)]).reshape(-1, 2)


def _found_or_saturated(c, truth, img, d):
    """Per target: found (a candidate within 1.5 px), else reported saturated (an entry of
    ``c.saturated`` within 1.5 px, with most pixels within the marker's radius + 2 px
    saturated). Returns (found, saturated) bool arrays."""
    found = cKDTree(c.uv).query(truth)[0] < 1.5
    sat = np.zeros(len(truth), bool)
    if len(c.saturated):
        sat = ~found & (cKDTree(c.saturated).query(truth)[0] < 1.5)
    vv, uu = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    for k in np.flatnonzero(sat):  # a loop over the few reported
        near = np.hypot(uu - truth[k, 0], vv - truth[k, 1]) <= d / 2 + 2
        assert (img[near] == 255).mean() > 0.5
    return found, sat


def _every_target(seeds):
    from scenes.revolution import paint_frame

    for seed in seeds:
        img, truth, d, _ = paint_frame(seed)
        c = detect_markers(img, d)
        found, sat = _found_or_saturated(c, truth, img, d)
        assert (found | sat).all(), f"seed {seed}: {int((~found & ~sat).sum())} missed"
        assert found.mean() > 0.9
        # the screen sends at most a quarter of the local maxima to the disk fit (17 % at
        # most on the development and bench seeds, where it had been half before)
        maxima = len(c) + sum(c.n_rejected.values())
        assert maxima - c.n_rejected["screen"] <= 0.25 * maxima


def test_every_target_found_on_speckled_paint():
    _every_target([200, 201])


@pytest.mark.slow
def test_every_target_found_on_speckled_paint_eight_seeds():
    _every_target(range(200, 208))


def _accuracy(seeds):
    """Pooled errors (px) of ours and OpenCV's on plain paint (no speckle) at SNR 20 (the
    median target's drawn depth over the noise: ``paint_frame``'s definition)."""
    from scenes.revolution import paint_frame

    ours, cv = [], []
    for seed in seeds:
        img, truth, d, _ = paint_frame(seed, speckle=0.0, snr=20.0)
        c = detect_markers(img, d)
        e = cKDTree(c.uv).query(truth)[0]
        assert (e < 1.5).all()
        ours.append(e)
        e_cv = cKDTree(_opencv(img, d)).query(truth)[0]
        cv.append(e_cv[e_cv < 1.5])
    return np.concatenate(ours), np.concatenate(cv)


@pytest.mark.slow  # 7 s; speckled paint's test stays in the default run
def test_accuracy_on_plain_paint_snr20():
    # two frames, 38 targets: the median error's sampling spread is about 12 %, so the
    # issue's 0.05 px is asserted on eight frames (below); here 0.049 px, OpenCV 0.077 px
    ours, cv = _accuracy([202, 203])
    assert np.median(ours) <= 0.06
    assert np.median(ours) < 0.8 * np.median(cv)


@pytest.mark.slow
def test_accuracy_on_plain_paint_snr20_eight_seeds():
    # the target: 8 frames, 153 targets seen within 60 degrees of face-on, some
    # near the glare: median error 0.046 px here, OpenCV 0.072 px. On fresh seeds 300-315
    # 0.0425 px (301 targets), on the bench's 100-111 0.0425 px, on 300-305 0.042 px over
    # 12 noise draws each, where the per-target Cramer-Rao bound puts the median at
    # 0.037 px (docs/benchmark_history.md, issue 21). The seeds fix the frames; the margin (8 %) is
    # far above float rounding and about one sampling spread of a median of 150 targets
    ours, cv = _accuracy(range(200, 208))
    assert np.median(ours) <= 0.05
    assert np.median(ours) < 0.8 * np.median(cv)
