"""Camera model against OpenCV (independent reference) and closed forms."""
import json
import math

import cv2
import numpy as np
import pytest

from resection import Camera, InputError, effective_focal_length
from resection.camera.model import max_monotonic_radius
from resection.io.cameras import read_camera, write_camera

W, H = 1280, 960
K = np.array([[1210.0, 0.0, 637.3], [0.0, 1195.0, 481.9], [0.0, 0.0, 1.0]])
DIST = np.array([-0.21, 0.08, 0.0012, -0.0007, -0.01])


def _camera(dist=DIST, **kw):
    return Camera.from_opencv(K, dist, [0.1, -0.25, 0.05], [0.05, -0.02, 2.0], W, H, **kw)


def _points(rng, n=500):
    X = rng.uniform(-0.6, 0.6, (n, 3))
    return X


def test_project_matches_opencv():
    rng = np.random.default_rng(0)
    cam = _camera()
    X = _points(rng)
    uv, valid = cam.project(X, return_valid=True)
    assert valid.all()
    K_, d_, rv, tv = cam.to_opencv()
    ref, _ = cv2.projectPoints(X, rv, tv, K_, d_)
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6, rtol=0)


def test_project_matches_opencv_random_cameras():
    rng = np.random.default_rng(1)
    for _ in range(20):
        dist = rng.normal(scale=[0.1, 0.05, 0.001, 0.001, 0.01])
        Kr = np.array([[rng.uniform(500, 3000), 0, rng.uniform(400, 900)],
                       [0, 0, rng.uniform(300, 700)], [0, 0, 1.0]])
        Kr[1, 1] = Kr[0, 0] * rng.uniform(0.98, 1.02)
        rv, tv = rng.normal(size=3), np.array([0, 0, 3.0]) + rng.normal(scale=0.3, size=3)
        cam = Camera.from_opencv(Kr, dist, rv, tv, W, H)
        X = rng.uniform(-0.5, 0.5, (200, 3))
        uv, valid = cam.project(X, return_valid=True)
        ref, _ = cv2.projectPoints(X, rv, tv, Kr, dist)
        ref = ref.reshape(-1, 2)
        assert valid.sum() > 150
        np.testing.assert_allclose(uv[valid], ref[valid], atol=1e-6, rtol=0)


def test_undistort_matches_opencv_and_inverts_distort():
    rng = np.random.default_rng(2)
    cam = _camera()
    uv = rng.uniform([0, 0], [W - 1, H - 1], (400, 2))
    ours = cam.undistort(uv)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
        ref = cv2.undistortPointsIter(uv.reshape(-1, 1, 2), K, DIST, None, K, crit)
    else:  # OpenCV 5: criteria moved into undistortPoints
        ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), K, DIST, R=None, P=K, criteria=crit)
    ref = ref.reshape(-1, 2)
    np.testing.assert_allclose(ours, ref, atol=1e-6, rtol=0)
    np.testing.assert_allclose(cam.distort(ours), uv, atol=1e-8, rtol=0)


def test_rays_pass_through_points():
    rng = np.random.default_rng(3)
    cam = _camera()
    X = _points(rng, 300)
    o, d = cam.rays(cam.project(X))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(o, np.broadcast_to(cam.center, o.shape), atol=1e-12)
    v = X - o
    dist_to_line = np.linalg.norm(v - (v * d).sum(1, keepdims=True) * d, axis=1)
    assert dist_to_line.max() < 1e-9
    assert np.all((v * d).sum(1) > 0)  # in front, not behind
    # the centre is -R^T t (OpenCV convention): it projects nowhere and X = C + s d
    Rm, _ = cv2.Rodrigues(cam.rvec)
    np.testing.assert_allclose(cam.center, -Rm.T @ cam.t, atol=1e-12)


def test_json_round_trip(tmp_path):
    cam = _camera(oof=0.012, name="cam A")
    p = tmp_path / "cam.json"
    write_camera(p, cam)
    back = read_camera(p)
    assert back == cam
    np.testing.assert_array_equal(back.K, cam.K)
    np.testing.assert_array_equal(back.dist, cam.dist)
    assert back.oof == 0.012 and back.name == "cam A"
    d = json.loads(p.read_text())
    assert set(d) == {"width", "height", "K", "dist", "R", "t", "oof", "name"}


@pytest.mark.parametrize(
    "change, match",
    [
        ({"colour": 3}, "unknown key"),
        ({"K": [[1, 0, 0], [0, 1, 0]]}, "shape"),
        ({"dist": [0.1, 0.2]}, "5 values"),
        ({"t": [0, float("nan"), 1]}, "NaN"),
        ({"R": [[1, 0, 0], [0, 1, 0], [0, 0.5, 1]]}, "rotation"),
        ({"R": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "rotation"),
        ({"width": 12.5}, "width"),
        ({"K": [[-10, 0, 0], [0, 10, 0], [0, 0, 1]]}, "positive"),
        ({"width": True}, "width"),
        ({"height": float("inf")}, "width/height"),
        ({"oof": "0.01"}, "oof"),
        ({"dist": ["a", 0, 0, 0, 0]}, r"dist\[0\]: not a number"),
        ({"t": [0, 0]}, "camera t"),
    ],
)
def test_json_bad_content(tmp_path, change, match):
    d = _camera().to_dict()
    d.update(change)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=match):
        read_camera(p)


def test_camera_copies_its_arrays():
    Km = np.array(K)
    cam = Camera(W, H, Km, DIST)
    Km[0, 0] = 5.0  # the caller's array stays writable and the camera keeps its own copy
    assert cam.K[0, 0] == K[0, 0] and not cam.K.flags.writeable


def test_json_missing_key_and_bad_file(tmp_path):
    d = _camera().to_dict()
    del d["R"]
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match="missing"):
        read_camera(p)
    p.write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        read_camera(p)
    with pytest.raises(InputError, match="not found"):
        read_camera(tmp_path / "nope.json")


def test_from_fov_closed_form():
    hf, vf = 40.0, 30.0
    cam = Camera.from_fov(hf, vf, W, H)
    # a point at half the horizontal field lands on the right edge of the sensor (W - 0.5)
    a = math.radians(hf / 2)
    uv = cam.project([[math.tan(a), 0.0, 1.0], [0.0, -math.tan(math.radians(vf / 2)), 1.0]])
    np.testing.assert_allclose(uv[0], [W - 0.5, (H - 1) / 2], atol=1e-9)
    np.testing.assert_allclose(uv[1], [(W - 1) / 2, -0.5], atol=1e-9)
    np.testing.assert_allclose(cam.fov(), (hf, vf), atol=1e-12)
    with pytest.raises(InputError, match="hfov"):
        Camera.from_fov(190.0, 30.0, W, H)


def test_refocus_closed_form():
    f, s_cal, s_new = 0.05, 2.0, 0.8  # metres
    for d in (0.0, 0.01, 0.03, f):
        cam = _camera(oof=d)
        new = cam.refocus(s_new, calibrated_focus=s_cal, lens_focal_length=f)
        M = lambda s, d=d: f * (s - d) / (s - f)  # noqa: E731
        ratio = M(s_new) / M(s_cal)
        np.testing.assert_allclose(new.K[0, 0], cam.K[0, 0] * ratio, rtol=1e-12)
        np.testing.assert_allclose(new.K[1, 1], cam.K[1, 1] * ratio, rtol=1e-12)
        np.testing.assert_array_equal(new.K[:2, 2], cam.K[:2, 2])
        if d == 0.0:  # thin lens: image distance v = f s / (s - f)
            v = lambda s: f * s / (s - f)  # noqa: E731
            np.testing.assert_allclose(ratio, v(s_new) / v(s_cal), rtol=1e-12)
        if d == f:  # stop at the front focal point: telecentric, constant M
            np.testing.assert_allclose(ratio, 1.0, rtol=1e-12)
    assert effective_focal_length(f, 1.0, 0.0) == pytest.approx(f * 1.0 / (1.0 - f))
    with pytest.raises(InputError, match="oof"):
        _camera().refocus(1.0, calibrated_focus=2.0, lens_focal_length=f)
    with pytest.raises(InputError, match="exceed"):
        effective_focal_length(0.05, 0.04, 0.0)


def test_points_behind_and_beyond_monotonic_radius_flagged():
    k1 = -0.5
    dist = np.array([k1, 0, 0, 0, 0])
    r_max = math.sqrt(-1.0 / (3.0 * k1))  # d/dr [r (1 + k1 r^2)] = 0
    assert max_monotonic_radius(dist) == pytest.approx(r_max, rel=1e-12)
    cam = Camera(W, H, K, dist)
    X = np.array([[0.1, 0.0, 1.0],            # fine
                  [0.0, 0.0, -1.0],           # behind
                  [0.0, 0.1, 0.0],            # on the camera plane
                  [0.99 * r_max, 0.0, 1.0],   # just inside
                  [1.01 * r_max, 0.0, 1.0]])  # just beyond: would fold back
    uv, valid = cam.project(X, return_valid=True)
    assert valid.tolist() == [True, False, False, True, False]
    assert np.isnan(uv[~valid]).all() and np.isfinite(uv[valid]).all()
    # undistort of a pixel beyond the fold is refused, not mapped to a wrong place
    far = np.array([[K[0, 2] + K[0, 0] * 2.0, K[1, 2]]])
    assert np.isnan(cam.undistort(far)).all()


def test_opencv_round_trip_and_look_at():
    rng = np.random.default_rng(4)
    rv, tv = rng.normal(size=3) * 0.5, rng.normal(size=3)
    cam = Camera.from_opencv(K, DIST, rv, tv, W, H)
    K2, d2, rv2, tv2 = cam.to_opencv()
    np.testing.assert_allclose(cv2.Rodrigues(rv2)[0], cv2.Rodrigues(rv)[0], atol=1e-12)
    np.testing.assert_allclose(tv2.ravel(), tv, atol=1e-15)
    with pytest.raises(InputError, match="beyond k3"):
        Camera.from_opencv(K, [0, 0, 0, 0, 0, 0.1, 0, 0], rv, tv, W, H)
    with pytest.raises(InputError, match="expected 4, 5"):
        Camera.from_opencv(K, [0.1, 0.01], rv, tv, W, H)
    # trailing zeros of OpenCV's 8/12/14-term models are accepted
    c8 = Camera.from_opencv(K, [*DIST, 0, 0, 0], rv, tv, W, H)
    np.testing.assert_array_equal(c8.dist, DIST)
    eye, target = np.array([1.0, 2.0, -3.0]), np.array([0.1, 0.2, 0.3])
    cam = Camera.look_at(eye, target, [0, 0, 1], K=K, width=W, height=H)
    np.testing.assert_allclose(cam.center, eye, atol=1e-12)
    np.testing.assert_allclose(cam.project(target)[0], K[:2, 2], atol=1e-9)
    # "up" points up in the image: a point above the target has a smaller v
    assert cam.project(target + [0, 0, 0.1])[0, 1] < K[1, 2]
    with pytest.raises(InputError, match="coincide"):
        Camera.look_at(eye, eye, [0, 0, 1], K=K, width=W, height=H)


def test_rays_of_the_whole_image_from_the_undistortion_map():
    """Camera.rays() (every pixel, from the map computed once) against OpenCV's
    undistortPoints for the same pixels, after a pose change too; the map is kept on the
    instance and on with_pose copies, and is not pickled."""
    import pickle

    w, h = 96, 72
    k = np.array([[90.0, 0.0, 47.2], [0.0, 88.0, 35.9], [0.0, 0.0, 1.0]])
    cam = Camera.from_opencv(k, DIST, [0.1, -0.25, 0.05], [0.05, -0.02, 2.0], w, h)
    vv, uu = np.mgrid[0:h, 0:w]
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, DIST, R=None, P=None,
                             criteria=crit).reshape(-1, 2) if not hasattr(
        cv2, "undistortPointsIter") else cv2.undistortPointsIter(
        uv.reshape(-1, 1, 2), k, DIST, None, None, crit).reshape(-1, 2)
    d_cam = np.column_stack([xy, np.ones(len(xy))])
    d_cam /= np.linalg.norm(d_cam, axis=1, keepdims=True)
    moved = cam.with_pose(rvec=[0.3, 0.2, -0.1], t=[0.2, 0.1, 1.5])
    for c in (cam, moved):
        o, d = c.rays()
        Rm, _ = cv2.Rodrigues(c.rvec)
        np.testing.assert_allclose(d, d_cam @ Rm, atol=1e-9)
        np.testing.assert_allclose(o, np.broadcast_to(c.center, o.shape), atol=1e-12)
        np.testing.assert_allclose(d, c.rays(uv)[1], atol=1e-12)  # the per-point path
    assert moved.undistortion_map() is cam.undistortion_map()  # computed once
    other = pickle.loads(pickle.dumps(moved))
    assert other == moved and "_icache" not in other.__dict__
    np.testing.assert_allclose(other.rays()[1], moved.rays()[1], atol=0)


def test_whole_image_rays_nan_beyond_the_monotonic_radius():
    """A wide lens with strong barrel distortion: the corner pixels lie beyond the radius
    where the distortion folds back; the map gives NaN there, as the per-point path does,
    and the same rays elsewhere."""
    k = np.array([[70.0, 0.0, 47.5], [0.0, 70.0, 35.5], [0.0, 0.0, 1.0]])
    cam = Camera(96, 72, k, [-0.3, 0.0, 0.0, 0.0, 0.0])
    vv, uu = np.mgrid[0:72, 0:96]
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
    grid, point = cam.rays()[1], cam.rays(uv)[1]
    bad = np.isnan(point[:, 0])
    assert 0 < bad.sum() < 0.5 * len(bad) and bad[0] and not bad[36 * 96 + 48]
    np.testing.assert_array_equal(np.isnan(grid[:, 0]), bad)
    np.testing.assert_allclose(grid[~bad], point[~bad], atol=1e-12)
    # r_max of k1 = -0.3: 1 + 3 k1 r^2 = 0, r = 1 / sqrt(0.9)
    assert cam.max_radius == pytest.approx(1 / math.sqrt(0.9), rel=1e-12)


def test_undistortion_map_of_a_large_image_over_threads_against_opencv():
    """A 1280 x 960 image with strong distortion (thread blocks of rows, each row started
    from its distorted first pixel, then from the cubic extrapolation of its neighbours):
    a regular subsample of every row block against OpenCV's undistortPoints."""
    from resection.camera.undistortion import undistortion_map

    w, h = 1280, 960
    k = np.array([[1100.0, 0.0, 652.3], [0.0, 1090.0, 471.8], [0.0, 0.0, 1.0]])
    dist = np.array([-0.32, 0.11, 0.0015, -0.0009, -0.012])
    cam = Camera.from_opencv(k, dist, [0.1, -0.25, 0.05], [0.05, -0.02, 2.0], w, h)
    m = undistortion_map(cam, workers=2)
    rng = np.random.default_rng(3)
    idx = np.unique(np.concatenate([rng.integers(0, w * h, 20_000),
                                    np.arange(0, w * h, w)]))  # every row's first pixel
    uv = np.column_stack([idx % w, idx // w]).astype(np.float64)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), k, dist, R=None, P=None,
                             criteria=crit).reshape(-1, 2)
    ref = np.column_stack([xy, np.ones(len(xy))])
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    ok = np.isfinite(m.directions[idx]).all(axis=1)
    assert ok.mean() > 0.99
    np.testing.assert_allclose(m.directions[idx][ok], ref[ok], atol=1e-9)
    np.testing.assert_allclose(m.directions, undistortion_map(cam, workers=1).directions,
                               atol=1e-12, equal_nan=True)
