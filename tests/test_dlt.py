"""DLT, its decomposition and the planar homography against the synthetic truth and
OpenCV (decomposeProjectionMatrix, findHomography, warpPerspective)."""

import cv2
import numpy as np
import pytest

from resection import (
    Camera,
    DegenerateError,
    InputError,
    apply_homography,
    camera_from_dlt,
    decompose_projection,
    dewarp,
    dlt_project,
    fit_dlt,
    fit_homography,
)
from resection.pose.dlt import dlt_coefficients

W, H = 1024, 768


def _camera(rng, skew=0.0, dist=None):
    f = rng.uniform(800, 2000)
    K = np.array([[f, skew, rng.uniform(480, 540)], [0, f * rng.uniform(0.97, 1.03),
                  rng.uniform(360, 400)], [0, 0, 1.0]])
    d = rng.normal(size=3)
    return Camera.look_at(d / np.linalg.norm(d) * 3.0, rng.normal(scale=0.1, size=3),
                          rng.normal(size=3), K=K, width=W, height=H,
                          dist=np.zeros(5) if dist is None else dist)


def test_dlt_exact_recovery_and_decomposition():
    rng = np.random.default_rng(0)
    for skew in (0.0, 3.5):
        cam = _camera(rng, skew)
        X = rng.uniform(-0.5, 0.5, (12, 3))
        uv = cam.project(X)
        P = fit_dlt(X, uv)
        np.testing.assert_allclose(dlt_project(P, X), uv, atol=1e-8)
        K, R, t = decompose_projection(P)
        np.testing.assert_allclose(K, cam.K, rtol=1e-8, atol=1e-7)
        np.testing.assert_allclose(R, cam.R, atol=1e-9)
        np.testing.assert_allclose(t, cam.t, atol=1e-9)
        # P is scaled so that its third row gives depths in model units
        np.testing.assert_allclose(np.column_stack([X, np.ones(12)]) @ P[2],
                                   cam.to_camera_frame(X)[:, 2], rtol=1e-9)
        # the 11 coefficients in the collinearity form
        L = dlt_coefficients(P)
        den = X @ L[8:11] + 1
        np.testing.assert_allclose((X @ L[0:3] + L[3]) / den, uv[:, 0], atol=1e-8)
        np.testing.assert_allclose((X @ L[4:7] + L[7]) / den, uv[:, 1], atol=1e-8)
        np.testing.assert_allclose(dlt_project(L, X), uv, atol=1e-8)
        back = camera_from_dlt(X, uv, W, H)
        np.testing.assert_allclose(back.project(X), uv, atol=1e-7)
        np.testing.assert_allclose(back.center, cam.center, atol=1e-9)


def test_decomposition_matches_opencv():
    rng = np.random.default_rng(1)
    cam = _camera(rng, 1.2)
    K, R, t = decompose_projection(-2.7 * cam.P)  # arbitrary scale and sign
    Kc, Rc, Ch = cv2.decomposeProjectionMatrix(2.7 * cam.P)[:3]  # OpenCV keeps the sign
    Kc = Kc / Kc[2, 2]
    np.testing.assert_allclose(K, Kc, rtol=1e-9, atol=1e-8)
    np.testing.assert_allclose(R, Rc, atol=1e-10)
    C = (Ch[:3] / Ch[3]).ravel()
    np.testing.assert_allclose(-R.T @ t, C, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)


def test_dlt_normalisation_far_from_origin():
    """Model in millimetres far from the origin: Hartley's normalisation keeps it exact."""
    rng = np.random.default_rng(2)
    cam = _camera(rng)
    X = rng.uniform(-0.5, 0.5, (10, 3))
    uv = cam.project(X)
    offset = np.array([5000.0, -3000.0, 2000.0])
    Xmm = X * 1000.0 + offset
    P = fit_dlt(Xmm, uv)
    np.testing.assert_allclose(dlt_project(P, Xmm), uv, atol=1e-6)
    K, _, _ = decompose_projection(P)
    np.testing.assert_allclose(K, cam.K, rtol=1e-7, atol=1e-5)


def test_dlt_with_noise_is_close():
    rng = np.random.default_rng(3)
    cam = _camera(rng)
    X = rng.uniform(-0.5, 0.5, (60, 3))
    uv = cam.project(X) + rng.normal(scale=0.1, size=(60, 2))
    back = camera_from_dlt(X, uv, W, H)
    assert np.linalg.norm(back.center - cam.center) < 0.01 * np.linalg.norm(cam.center)
    assert back.K[0, 0] == pytest.approx(cam.K[0, 0], rel=0.02)


def test_dlt_bad_input():
    rng = np.random.default_rng(4)
    cam = _camera(rng)
    X = rng.uniform(-0.5, 0.5, (8, 3))
    uv = cam.project(X)
    Xp = X.copy()
    Xp[:, 2] = 0.3
    with pytest.raises(DegenerateError, match="coplanar.*homography"):
        fit_dlt(Xp, cam.project(Xp))
    line = np.outer(np.arange(8.0), [1, 1, 0.5])
    with pytest.raises(DegenerateError, match="collinear"):
        fit_dlt(line, uv)
    with pytest.raises(InputError, match="at least 6"):
        fit_dlt(X[:5], uv[:5])
    with pytest.raises(InputError, match="differ"):
        fit_dlt(X, uv[:7])
    bad = uv.copy()
    bad[4, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        fit_dlt(X, bad)


def _plane_camera(rng, dist=None):
    """A camera looking at the plane z = 0 obliquely; H = K [r1 r2 t]."""
    K = np.array([[1500.0, 0, 510.0], [0, 1500.0, 385.0], [0, 0, 1.0]])
    return Camera.look_at([0.4, -0.6, 1.5], [0.02, -0.03, 0.0], [0, 1, 0], K=K, width=W,
                          height=H, dist=np.zeros(5) if dist is None else dist)


def test_homography_exact_and_vs_opencv():
    rng = np.random.default_rng(5)
    cam = _plane_camera(rng)
    xy = rng.uniform(-0.3, 0.3, (20, 2))
    uv = cam.project(np.column_stack([xy, np.zeros(20)]))
    Hm = fit_homography(xy, uv)
    truth = cam.K @ np.column_stack([cam.R[:, 0], cam.R[:, 1], cam.t])
    np.testing.assert_allclose(Hm, truth / truth[2, 2], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(apply_homography(Hm, xy), uv, atol=1e-8)
    Hc, _ = cv2.findHomography(xy, uv, 0)
    np.testing.assert_allclose(Hm, Hc, rtol=1e-6, atol=1e-8)
    # noisy: the same least-squares fit quality as OpenCV's
    noisy = uv + rng.normal(scale=0.2, size=uv.shape)
    Hn = fit_homography(xy, noisy)
    Hc, _ = cv2.findHomography(xy, noisy, 0)
    e_ours = np.linalg.norm(apply_homography(Hn, xy) - noisy, axis=1)
    e_cv = np.linalg.norm(apply_homography(Hc, xy) - noisy, axis=1)
    assert np.sqrt(np.mean(e_ours**2)) <= 1.02 * np.sqrt(np.mean(e_cv**2))
    with pytest.raises(InputError, match="at least 4"):
        fit_homography(xy[:3], uv[:3])
    with pytest.raises(DegenerateError, match="collinear"):
        fit_homography(np.column_stack([np.arange(5.0), 2 * np.arange(5.0)]), uv[:5])


def _pattern(x, y):
    return 100.0 + 40.0 * np.sin(25.0 * x) * np.cos(18.0 * y) + 30.0 * x


def _render_plane(cam):
    """Camera image of the pattern on z = 0: ray-plane intersection for every pixel."""
    vv, uu = np.mgrid[0:H, 0:W]
    o, d = cam.rays(np.column_stack([uu.ravel(), vv.ravel()]).astype(float))
    s = -o[:, 2] / d[:, 2]
    P = o + s[:, None] * d
    return _pattern(P[:, 0], P[:, 1]).reshape(H, W).astype(np.float32)


@pytest.mark.parametrize("with_distortion", [False, True])
def test_dewarp_recovers_the_plane(with_distortion):
    rng = np.random.default_rng(6)
    dist = np.array([-0.15, 0.03, 0.0005, -0.0003, 0.0]) if with_distortion else None
    cam = _plane_camera(rng, dist)
    img = _render_plane(cam)
    xy = rng.uniform(-0.25, 0.25, (16, 2))
    uv = cam.project(np.column_stack([xy, np.zeros(16)]))
    Hm = fit_homography(xy, cam.undistort(uv))
    extent, res = (-0.2, 0.2, -0.15, 0.15), 0.002
    out = dewarp(img, Hm, extent, res, camera=cam if with_distortion else None)
    assert out.shape == (151, 201) and out.dtype == np.float32
    gx, gy = np.meshgrid(np.arange(201) * res - 0.2, np.arange(151) * res - 0.15)
    truth = _pattern(gx, gy)
    ok = np.isfinite(out)
    assert ok.mean() > 0.99
    err = np.abs(out[ok] - truth[ok])
    assert np.median(err) < 0.5 and err.max() < 4.0  # bilinear resampling of a 140-range
    if not with_distortion:
        # cv2.warpPerspective with the same mapping (output pixel -> image pixel)
        S = np.array([[res, 0, -0.2], [0, res, -0.15], [0, 0, 1.0]])
        ref = cv2.warpPerspective(img, Hm @ S, (201, 151),
                                  flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                  borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        both = ok & np.isfinite(ref)
        # OpenCV interpolates with 5-bit fixed-point weights: agreement to ~1/32 of a step
        assert np.abs(out[both] - ref[both]).max() < 0.6
        assert np.median(np.abs(out[both] - ref[both])) < 0.05


def test_dewarp_outside_and_bad_input():
    img = np.ones((40, 50), np.float32)
    Hm = np.eye(3)  # plane coordinates are pixels
    out = dewarp(img, Hm, (-10, 59, 0, 39), 1.0)
    assert np.isnan(out[:, :9]).all() and np.isnan(out[:, 60:]).all()
    assert np.all(out[:, 10:59] == 1.0)
    with pytest.raises(InputError, match="2-D"):
        dewarp(np.ones((4, 4, 3)), Hm, (0, 1, 0, 1), 0.1)
    with pytest.raises(InputError, match="resolution"):
        dewarp(img, Hm, (0, 1, 0, 1), 0.0)
    with pytest.raises(InputError, match="empty extent"):
        dewarp(img, Hm, (1, 0, 0, 1), 0.1)
    with pytest.raises(InputError, match="shape"):
        dewarp(img, np.eye(2), (0, 1, 0, 1), 0.1)
