"""calibrate against the synthetic truth and cv2.calibrateCamera on the same data."""

import cv2
import numpy as np
import pytest

from resection import Camera, DegenerateError, InputError, SolveError, calibrate

W, H = 1280, 960
K_TRUE = np.array([[1150.0, 0.0, 650.5], [0.0, 1158.0, 470.2], [0.0, 0.0, 1.0]])
D_TRUE = np.array([-0.22, 0.09, 0.0012, -0.0009, 0.0])


def _board():
    gx, gy = np.meshgrid(np.arange(11) * 0.03, np.arange(8) * 0.03)
    return np.column_stack([gx.ravel() - 0.15, gy.ravel() - 0.105, np.zeros(88)])


def _views(rng, target, n_views, noise=0.1, dist=D_TRUE, planar=True):
    views, cams = [], []
    while len(views) < n_views:
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) - (1.0 if planar else 0.0)
        eye = d / np.linalg.norm(d) * rng.uniform(0.45, 0.7)
        cam = Camera.look_at(eye, rng.normal(scale=0.03, size=3), [0, -1, 0.3], K=K_TRUE,
                             width=W, height=H, dist=dist)
        uv, valid = cam.project(target, return_valid=True)
        if not (valid.all() and cam.in_image(uv, margin=3).all()):
            continue
        views.append((target, uv + rng.normal(scale=noise, size=uv.shape)))
        cams.append(cam)
    return views, cams


def _within_std(res, k=4.0):
    """Every estimated parameter within k reported standard deviations of the truth."""
    K, d = res.camera.K, res.camera.dist
    est = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "k1": d[0],
           "k2": d[1], "p1": d[2], "p2": d[3], "k3": d[4]}
    tru = {"fx": K_TRUE[0, 0], "fy": K_TRUE[1, 1], "cx": K_TRUE[0, 2], "cy": K_TRUE[1, 2],
           "k1": D_TRUE[0], "k2": D_TRUE[1], "p1": D_TRUE[2], "p2": D_TRUE[3], "k3": D_TRUE[4]}
    for nm in res.parameters:
        assert abs(est[nm] - tru[nm]) < k * res.std[nm], (nm, est[nm], tru[nm], res.std[nm])


def _opencv(views, flags=0, K0=None):
    op = [v[0].astype(np.float32) for v in views]
    ip = [v[1].astype(np.float32) for v in views]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 300, 1e-15)
    return cv2.calibrateCamera(op, ip, (W, H), K0, np.zeros(5), flags=flags, criteria=crit)


def test_planar_views_recover_truth_and_match_opencv():
    rng = np.random.default_rng(0)
    views, cams = _views(rng, _board(), 8)
    res = calibrate(views, (W, H), fix=("k3",))
    K, d = res.camera.K, res.camera.dist
    # truth, within the reported uncertainty
    for i, nm in ((0, "fx"), (1, "fy")):
        assert abs(K[i, i] - K_TRUE[i, i]) < 4 * res.std[nm] + 1e-9
    assert abs(K[0, 2] - K_TRUE[0, 2]) < 4 * res.std["cx"]
    assert abs(K[1, 2] - K_TRUE[1, 2]) < 4 * res.std["cy"]
    assert abs(d[0] - D_TRUE[0]) < 4 * res.std["k1"]
    assert abs(d[1] - D_TRUE[1]) < 4 * res.std["k2"]
    _within_std(res)  # tangential p1, p2 too
    assert d[4] == 0.0 and "k3" not in res.parameters
    np.testing.assert_allclose(K, K_TRUE, rtol=3e-3, atol=3.0)
    assert res.rms == pytest.approx(0.1 * np.sqrt(2), rel=0.15)
    # OpenCV on the same data and model reaches the same minimum
    rms_cv, Kc, dc, _, _ = _opencv(views, cv2.CALIB_FIX_K3)
    assert res.rms == pytest.approx(rms_cv, rel=1e-4)
    np.testing.assert_allclose(K, Kc, rtol=0, atol=0.05)
    np.testing.assert_allclose(d, dc.ravel()[:5], rtol=0, atol=2e-4)
    # per-view poses and residuals
    assert len(res.poses) == 8 and len(res.residuals) == 8
    for cam, est, (X, uv), r in zip(cams, res.poses, views, res.residuals, strict=True):
        assert np.linalg.norm(est.center - cam.center) < 2e-3
        np.testing.assert_allclose(r, uv - est.project(X), atol=1e-9)


def test_full_distortion_model_matches_opencv():
    rng = np.random.default_rng(1)
    d_true = np.array([-0.25, 0.12, 0.001, 0.0005, -0.03])
    views, _ = _views(rng, _board(), 12, dist=d_true)
    res = calibrate(views, (W, H))
    # the five distortion coefficients and the intrinsics recover the truth
    for i, nm in enumerate(("k1", "k2", "p1", "p2", "k3")):
        assert abs(res.camera.dist[i] - d_true[i]) < 4 * res.std[nm], nm
    for nm, est, tru in (("fx", res.camera.K[0, 0], K_TRUE[0, 0]),
                         ("fy", res.camera.K[1, 1], K_TRUE[1, 1]),
                         ("cx", res.camera.K[0, 2], K_TRUE[0, 2]),
                         ("cy", res.camera.K[1, 2], K_TRUE[1, 2])):
        assert abs(est - tru) < 4 * res.std[nm], nm
    rms_cv, Kc, dc, _, _ = _opencv(views)
    assert res.rms == pytest.approx(rms_cv, rel=1e-4)
    np.testing.assert_allclose(res.camera.K, Kc, rtol=0, atol=0.1)
    np.testing.assert_allclose(res.camera.dist, dc.ravel()[:5], rtol=0, atol=5e-3)


def test_3d_target_several_views():
    rng = np.random.default_rng(2)
    target = rng.uniform([-0.12, -0.1, -0.08], [0.12, 0.1, 0.08], (60, 3))
    views, cams = _views(rng, target, 4, planar=False)
    res = calibrate(views, (W, H), fix=("k3",))
    _within_std(res)
    rms_cv, Kc, dc, _, _ = _opencv(views, cv2.CALIB_FIX_K3 | cv2.CALIB_USE_INTRINSIC_GUESS,
                                   K0=np.array(res.camera.K))
    assert res.rms == pytest.approx(rms_cv, rel=1e-4)
    np.testing.assert_allclose(res.camera.K, Kc, atol=0.05)


def test_single_image_of_3d_target_through_dlt():
    rng = np.random.default_rng(3)
    target = rng.uniform([-0.3, -0.25, -0.2], [0.3, 0.25, 0.2], (150, 3))
    cam = Camera.look_at([0.1, -0.3, -1.2], [0, 0, 0], [0, -1, 0], K=K_TRUE, width=W,
                         height=H, dist=D_TRUE)
    uv, valid = cam.project(target, return_valid=True)
    keep = valid & cam.in_image(uv, margin=3)
    views = [(target[keep], uv[keep] + rng.normal(scale=0.1, size=(keep.sum(), 2)))]
    res = calibrate(views, (W, H), fix=("k3",))
    _within_std(res)
    np.testing.assert_allclose(res.camera.K, K_TRUE, rtol=0.02)
    assert np.linalg.norm(res.camera.center - cam.center) < 5e-3
    assert res.rms < 0.2


def test_single_planar_view_needs_fixed_centre():
    rng = np.random.default_rng(4)
    cam = Camera.look_at([0.25, 0.2, -0.45], [0, 0, 0], [0, -1, 0], K=K_TRUE, width=W,
                         height=H)  # board tilted by about 40 degrees
    uv, valid = cam.project(_board(), return_valid=True)
    assert valid.all() and cam.in_image(uv).all()
    views = [(_board(), uv + rng.normal(scale=0.1, size=uv.shape))]
    with pytest.raises(SolveError, match="do not determine"):
        calibrate(views, (W, H), fix=("k1", "k2", "p1", "p2", "k3"))
    K0 = np.array(K_TRUE)
    K0[0, 0], K0[1, 1] = 1000.0, 1000.0 * K_TRUE[1, 1] / K_TRUE[0, 0]
    res = calibrate(views, (W, H), fix=("cx", "cy", "aspect", "k1", "k2", "p1", "p2", "k3"),
                    initial=Camera(W, H, K0))
    assert res.parameters == ("f",)
    # with the centre and aspect fixed at the truth, the focal length comes out
    assert abs(res.camera.K[0, 0] - K_TRUE[0, 0]) < 4 * res.std["f"]
    assert res.std["f"] < 5.0


def test_calibrate_bad_input():
    rng = np.random.default_rng(5)
    views, _ = _views(rng, _board(), 3)
    with pytest.raises(InputError, match="no views"):
        calibrate([], (W, H))
    with pytest.raises(InputError, match="image_size|image size"):
        calibrate(views, (W, -1))
    with pytest.raises(InputError, match="unknown parameter"):
        calibrate(views, (W, H), fix=("k4",))
    X, uv = views[0]
    bad = uv.copy()
    bad[5] = np.nan
    with pytest.raises(InputError, match="view 1 points2d.*NaN"):
        calibrate([views[0], (X, bad)], (W, H))
    with pytest.raises(InputError, match="view 0"):
        calibrate([(X, uv[:10])], (W, H))
    with pytest.raises(InputError, match="at least 4"):
        calibrate([(X[:3], uv[:3])], (W, H))
    line = np.outer(np.arange(6.0), [1, 0.5, 0])
    with pytest.raises(DegenerateError, match="collinear"):
        calibrate([(line, uv[:6])], (W, H))
    with pytest.raises(InputError, match="observations"):
        calibrate([(X[::13][:7], uv[::13][:7])], (W, H))
    with pytest.raises(InputError, match="pair"):
        calibrate([X], (W, H))


def test_non_convergence_names_the_weakest_parameters():
    rng = np.random.default_rng(7)
    views, _ = _views(rng, _board(), 3)
    with pytest.raises(SolveError, match=r"did not converge in 2 iterations; the least "
                                         r"determined parameters are \w+"):
        calibrate(views, (W, H), max_iter=2)


def test_calibrate_wrong_image_size():
    """Points beyond the given image, or an initial camera of another size, are refused
    (a wrong size would silently bias the principal-point start)."""
    rng = np.random.default_rng(6)
    views, _ = _views(rng, _board(), 3)
    with pytest.raises(InputError, match=r"view 0: .*outside the 640x480 image"):
        calibrate(views, (640, 480))
    with pytest.raises(InputError, match="differs from the initial camera's 640x480"):
        calibrate(views, (W, H), initial=Camera(640, 480, K_TRUE))
    # the right size passes the same views
    assert calibrate(views, (W, H), fix=("k3",)).rms < 0.2
