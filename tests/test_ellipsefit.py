"""The compiled elliptical marker model and fit (resection.markers._ellipsefit) against
independent references: a rotated ellipse given by its axes and angle, rendered by brute-force
supersampling and SciPy's Gaussian filter; finite differences; the disk model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from resection.markers import _diskfit, _diskmodel, _ellipsefit, refine_markers


def _shape(a, b, phi):
    """``X, H, k`` of the ellipse of semi-axes ``a, b`` whose ``a`` axis is at ``phi`` (rad)
    from the u axis: from its quadratic form ``[x y] Q [x y]^T <= 1``, the chord at ``x``
    is centred at ``-Q01 x / Q11`` and the middle one's half-height is ``1 / sqrt(Q11)``."""
    c, s = np.cos(phi), np.sin(phi)
    Rm = np.array([[c, -s], [s, c]])
    Q = Rm @ np.diag([1 / a**2, 1 / b**2]) @ Rm.T
    k = -Q[0, 1] / Q[1, 1]
    return 1 / np.sqrt(Q[0, 0] - Q[0, 1] ** 2 / Q[1, 1]), 1 / np.sqrt(Q[1, 1]), k, Q


def _model(x0, y0, X, H, k, blur, W, reach=None):
    rx, ry = _ellipsefit._reach(X, H, k) if reach is None else reach
    q = _diskfit.n_nodes(max(rx, ry), blur)
    sizes, sn, cs, wc = _diskfit.node_table(q + 8)
    j = int(np.searchsorted(sizes, q))
    M = np.empty((W, W, 6))
    _ellipsefit._model(x0, y0, X, H, k, *_diskfit.edge_table(blur), sn[j], cs[j], wc[j],
                       sizes[j], M, np.empty((W + 1, 3)), np.empty((W + 1, 3)),
                       np.empty((W + 1, W, 3)))
    return M


def _render(x0, y0, Q, blur, W, S=64):
    """Brute force: the ellipse point-sampled S x S times a pixel, SciPy's Gaussian filter,
    the box average over each pixel."""
    c = (np.arange(W * S) + 0.5) / S - 0.5
    U, V = np.meshgrid(c - x0, c - y0)
    inside = (Q[0, 0] * U * U + 2 * Q[0, 1] * U * V + Q[1, 1] * V * V <= 1).astype(float)
    out = gaussian_filter(inside, blur * S, mode="constant", truncate=6)
    return out.reshape(W, S, W, S).mean(axis=(1, 3))


@pytest.mark.parametrize("a,b,phi,blur", [(6.0, 3.5, 0.6, 0.6), (5.0, 2.0, -1.1, 0.8),
                                          (4.0, 4.0, 0.0, 0.5)])
def test_model_matches_a_rotated_ellipse_rendered_by_supersampling(a, b, phi, blur):
    W, x0, y0 = 23, 11.3, 10.8
    X, H, k, Q = _shape(a, b, phi)
    M = _model(x0, y0, X, H, k, blur, W)
    ref = _render(x0, y0, Q, blur, W)
    # the supersampling errs by ~0.08 / S at sharp edges
    assert np.abs(M[..., 0] - ref).max() < 2e-3
    assert M[..., 0].sum() == pytest.approx(np.pi * a * b, rel=1e-5)


def test_model_of_a_circle_is_the_disk_model():
    W, x0, y0, R, blur = 25, 12.27, 11.62, 5.1, 0.6
    M = _model(x0, y0, R, R, 0.0, blur, W)
    ar = np.arange(W, dtype=float)
    ref, dref = _diskmodel.windows([x0], [y0], [R], blur, ar, ar, 512, jacobian=True)
    assert np.abs(M[..., 0] - ref[0]).max() < 2e-5
    assert np.abs(M[..., 1] - dref[0][0]).max() < 1e-4
    assert np.abs(M[..., 2] - dref[1][0]).max() < 1e-4
    # a change of R is a change of both X and H
    assert np.abs(M[..., 3] + M[..., 4] - dref[2][0]).max() < 1e-4


def test_model_derivatives_match_finite_differences():
    W, blur, e = 27, 0.6, 1e-4
    p = np.array([13.2, 12.7, 6.3, 3.9, 0.45])
    reach = _ellipsefit._reach(*p[2:])
    M = _model(*p, blur, W)
    for n in range(5):
        d = np.zeros(5)
        d[n] = e
        fd = (_model(*(p + d), blur, W, reach)[..., 0]
              - _model(*(p - d), blur, W, reach)[..., 0]) / (2 * e)
        assert np.abs(M[..., n + 1] - fd).max() < 1e-5 * max(1.0, np.abs(fd).max()), n


def _ellipses(rng, a, b, phi, blur, n, S):
    """``n`` rotated ellipses of unit contrast side by side in 64 px squares (brute-force
    rendering, ``S`` x ``S`` samples a pixel), and their centres."""
    W = 64
    truth = np.column_stack([32 + 64 * np.arange(n) + rng.uniform(-0.5, 0.5, n),
                             32 + rng.uniform(-0.5, 0.5, n)])
    _, _, _, Q = _shape(a, b, phi)
    img = np.zeros((W, W * n))
    for i, (u, v) in enumerate(truth):
        img[:, 64 * i:64 * (i + 1)] = _render(u - 64 * i, v, Q, blur, W, S)
    return img, truth


def _frame(rng, a, b, phi, blur, snr, n=12, S=16):
    """A frame of ``n`` rotated ellipses (brute-force rendering), contrast 100 on 1000."""
    img, truth = _ellipses(rng, a, b, phi, blur, n, S)
    return 1000 + 100 * img + rng.normal(0, 100 / snr, img.shape), truth


def _count_evaluations(monkeypatch) -> list:
    """The model evaluations of each window of every ``fit_windows`` call from now on,
    appended to the list returned."""
    evaluations = []
    fit = _ellipsefit.fit_windows

    def counted(*args):
        out = fit(*args)
        evaluations.append(out[2])
        return out

    monkeypatch.setattr(_ellipsefit, "fit_windows", counted)
    return evaluations


def test_fit_finds_the_centre_of_an_oblique_marker_where_the_disk_cannot(monkeypatch):
    # a 30 px marker seen at an aspect of 0.55, rotated: the ellipse's fit is at the noise
    # (SNR 100: a few 0.001 px) in a few evaluations; the disk's is off by tenths
    rng = np.random.default_rng(7)
    img, truth = _frame(rng, 15.0, 8.25, 0.5, 0.6, 100.0)
    start = truth + rng.normal(0, 0.5, truth.shape)
    evaluations = _count_evaluations(monkeypatch)
    e = refine_markers(img, start, 30.0, shape="ellipse")
    d = refine_markers(img, start, 30.0, shape="disk")
    err_e = np.hypot(e["u"] - truth[:, 0], e["v"] - truth[:, 1])
    err_d = np.hypot(d["u"] - truth[:, 0], d["v"] - truth[:, 1])
    assert e["ok"].all()
    assert err_e.max() < 0.02
    assert np.median(err_d) > 5 * np.median(err_e)
    assert np.median(np.concatenate(evaluations)) <= 5
    # the radius reported is that of the disk of the same area
    assert np.abs(e["radius"] - np.sqrt(15.0 * 8.25)).max() < 0.05


def test_fit_of_round_markers_agrees_with_the_disk_fit():
    rng = np.random.default_rng(8)
    img, truth = _frame(rng, 4.0, 4.0, 0.0, 0.6, 50.0, n=20)
    start = truth + rng.normal(0, 0.3, truth.shape)
    e = refine_markers(img, start, 8.0, shape="ellipse")
    d = refine_markers(img, start, 8.0, shape="disk")
    assert e["ok"].all() and d["ok"].all()
    err_e = np.hypot(e["u"] - truth[:, 0], e["v"] - truth[:, 1])
    err_d = np.hypot(d["u"] - truth[:, 0], d["v"] - truth[:, 1])
    # two more free parameters: the noise grows a little, not the bias
    assert np.sqrt(np.mean(err_e**2)) < 1.3 * np.sqrt(np.mean(err_d**2)) + 0.002
    assert np.abs(e["radius"] - 4.0).max() < 0.05


def test_unknown_shape_is_refused():
    from resection.errors import InputError

    with pytest.raises(InputError, match="shape"):
        refine_markers(np.zeros((20, 20)), [[10.0, 10.0]], 6.0, shape="square")


def _speckled_frame(rng, a, b, phi, n=24, speckle=0.08):
    """Dark rotated ellipses point-sampled (one sample a pixel, no blur: edges the model,
    blurred and pixel-integrated, cannot match) on paint whose reflectance varies by
    ``speckle`` from pixel to pixel: a residual that stays large at the optimum."""
    img, truth = _ellipses(rng, a, b, phi, 1e-6, n, 1)
    paint = 1.0 + speckle * rng.standard_normal(img.shape)
    return (1000.0 - 880.0 * img) * paint + rng.normal(0, 5, img.shape), truth


def test_fit_with_a_large_residual_stops_near_its_optimum_in_few_evaluations(monkeypatch):
    # markers larger than the diameter given (their start's moments cut short by it) on
    # speckled paint, point-sampled: Gauss-Newton's steps overshoot (its curvature leaves
    # out the large residual's) and the centre can stop moving while the shape is still
    # far off. Each fit to 1e-3 px must stop within 2e-3 px of the same fit run to
    # convergence (stopped on the centre alone, windows stopped 3-5e-3 px away), in
    # under 6.3 evaluations a window on average (7 without the curvature along the step)
    rng = np.random.default_rng(3)
    img, truth = _speckled_frame(rng, 22.0, 13.0, 0.3)
    start = truth + rng.normal(0, 0.3, truth.shape)
    evaluations = _count_evaluations(monkeypatch)
    got = refine_markers(-img, start, 35.0, shape="ellipse", tol=1e-3)
    used = np.concatenate(evaluations)
    converged = refine_markers(-img, start, 35.0, shape="ellipse", tol=1e-10, iterations=300)
    assert got["ok"].all() and converged["ok"].all()
    assert np.hypot(got["u"] - converged["u"], got["v"] - converged["v"]).max() < 2e-3
    assert used.mean() < 6.3
    # and the optimum is the marker's centre, to the point sampling's aliasing
    assert np.hypot(converged["u"] - truth[:, 0], converged["v"] - truth[:, 1]).max() < 0.15


def test_curvature_along_the_step_is_the_gradients_and_never_lowers_the_matrix():
    # a quadratic cost 0.5 s^T H s whose Gauss-Newton matrix is H / 2 along every
    # direction: the gradient's change along a step shows twice J^T J's curvature; the
    # rank-one term makes the matrix agree with it along the step. Where the gradient
    # shows less curvature than J^T J, nothing is taken
    rng = np.random.default_rng(4)
    B = rng.normal(size=(9, 9))
    H = B @ B.T + 9 * np.eye(9)
    JTJ = 0.5 * H
    p0, p1 = rng.normal(size=9), rng.normal(size=9)
    s = p1 - p0
    JTr0 = rng.normal(size=9)
    JTr1 = JTr0 - H @ s  # J^T r = -gradient: it falls by H s along the step
    u = np.empty(9)
    f = _ellipsefit._curvature(JTJ, JTr0, JTr1, p0, p1, u)
    A = JTJ + f * np.outer(u, u)
    assert s @ A @ s == pytest.approx(s @ H @ s, rel=1e-12)
    assert np.allclose(u, JTJ @ s)
    assert _ellipsefit._curvature(H, JTr0, JTr1 + 0.5 * H @ s, p0, p1, u) == 0.0
