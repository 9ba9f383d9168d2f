"""Deformation: triangulation against OpenCV, closed-form stereo and scipy; displacements of
a known deformation with one and two cameras."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from resection import Camera, DegenerateError, InputError
from resection.sequence.deformation import (
    displacements_3d,
    marker_displacements,
    pair_by_id,
    stack_views,
    triangulate,
)

K = np.array([[1400.0, 0.0, 640.0], [0.0, 1400.0, 500.0], [0.0, 0.0, 1.0]])


def _stereo(dist1=(0, 0, 0, 0, 0), dist2=(0, 0, 0, 0, 0)):
    c1 = Camera.look_at([-0.7, -0.4, 1.9], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000,
                        dist=dist1)
    c2 = Camera.look_at([0.6, -0.5, 2.0], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000,
                        dist=dist2)
    return c1, c2


def _points(n=200, seed=0):
    return np.random.default_rng(seed).uniform([-0.3, -0.3, -0.1], [0.3, 0.3, 0.1], (n, 3))


def test_triangulate_against_opencv_triangulate_points():
    c1, c2 = _stereo()
    X = _points()
    uv = np.stack([c1.project(X), c2.project(X)])
    # noise-free: both equal the truth
    ref = cv2.triangulatePoints(c1.P, c2.P, uv[0].T, uv[1].T)
    ref = (ref[:3] / ref[3]).T
    tri = triangulate([c1, c2], uv)
    np.testing.assert_allclose(ref, X, atol=1e-9)
    np.testing.assert_allclose(tri.points, X, atol=1e-10)
    np.testing.assert_allclose(tri.linear, ref, atol=1e-9)
    assert np.all(tri.rms < 1e-7)
    # noisy: the refined points are the maximum-likelihood ones, so they reproject at least as
    # well as OpenCV's linear ones, marker by marker, and stay close to them
    rng = np.random.default_rng(1)
    uvn = uv + rng.normal(0.0, 0.3, uv.shape)
    ref = cv2.triangulatePoints(c1.P, c2.P, uvn[0].T, uvn[1].T)
    ref = (ref[:3] / ref[3]).T
    tri = triangulate([c1, c2], uvn)
    e_cv = np.sqrt(((np.stack([c1.project(ref), c2.project(ref)]) - uvn) ** 2).sum(2).mean(0))
    assert np.all(tri.rms <= e_cv + 1e-9)
    assert np.median(e_cv - tri.rms) > 1e-4  # the refinement does something
    assert np.abs(tri.points - ref).max() < 2e-3
    assert np.abs(tri.points - X).max() < 5e-3


def test_triangulate_closed_form_rectified_stereo_with_distortion():
    # rectified pair (same R, baseline B along x): Z = f B / disparity on undistorted pixels
    B = 0.3
    d1, d2 = [-0.12, 0.05, 0.001, -0.0005, 0.0], [0.08, -0.02, 0.0, 0.001, 0.0]
    c1 = Camera(1280, 1000, K, d1, np.eye(3), [0.0, 0.0, 2.0])
    c2 = Camera(1280, 1000, K, d2, np.eye(3), [-B, 0.0, 2.0])
    X = _points(100, seed=2)
    uv = np.stack([c1.project(X), c2.project(X)])
    # undistort with OpenCV (independent of the package), then the closed form
    und = [cv2.undistortPoints(uv[m].reshape(-1, 1, 2), K, np.array(d), P=K).reshape(-1, 2)
           for m, d in enumerate((d1, d2))]
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    Z = f * B / (und[0][:, 0] - und[1][:, 0])
    Xcf = np.column_stack([(und[0][:, 0] - cx) * Z / f, (und[0][:, 1] - cy) * Z / f, Z])
    Xcf[:, 2] -= 2.0  # camera 1 frame -> model frame
    tri = triangulate([c1, c2], uv)
    np.testing.assert_allclose(tri.points, Xcf, atol=1e-7)
    np.testing.assert_allclose(tri.points, X, atol=1e-9)


def test_refinement_matches_scipy_least_squares():
    c1, c2 = _stereo([-0.1, 0.03, 0.0, 0.0, 0.0], [0.05, 0.0, 0.001, 0.0, 0.0])
    c3 = Camera.look_at([0.0, 0.8, 1.8], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000)
    X = _points(12, seed=3)
    cams = [c1, c2, c3]
    rng = np.random.default_rng(4)
    uv = np.stack([c.project(X) for c in cams]) + rng.normal(0.0, 0.5, (3, len(X), 2))
    tri = triangulate(cams, uv)
    for i in range(len(X)):
        def res(p, i=i):
            return np.concatenate([c.project(p[None])[0] - uv[m, i] for m, c in enumerate(cams)])

        sol = least_squares(res, X[i] + 0.01, xtol=1e-15, ftol=1e-15, gtol=1e-15)
        np.testing.assert_allclose(tri.points[i], sol.x, atol=1e-9)
        np.testing.assert_allclose(tri.rms[i], np.sqrt(np.mean(sol.fun.reshape(3, 2) ** 2) * 2),
                                   rtol=1e-6)


def test_missing_views_and_angles():
    c1, c2 = _stereo()
    c3 = Camera.look_at([0.0, 0.8, 1.8], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000)
    X = _points(5, seed=5)
    uv = np.stack([c.project(X) for c in (c1, c2, c3)])
    uv[0, 1] = np.nan  # marker 1 seen by cameras 2, 3 only
    uv[0, 2] = np.nan
    uv[1, 2] = np.nan  # marker 2 seen by camera 3 only
    tri = triangulate([c1, c2, c3], uv)
    assert tri.n_views.tolist() == [3, 2, 1, 3, 3]
    np.testing.assert_allclose(np.delete(tri.points, 2, 0), np.delete(X, 2, 0), atol=1e-9)
    assert np.all(np.isnan(tri.points[2])) and np.isnan(tri.rms[2]) and np.isnan(tri.angle[2])
    assert np.all(np.isnan(tri.residuals[0, 1]))
    # angle between the lines of sight of camera 1 and 2 for marker 0, computed directly
    d1 = X[0] - c1.center
    d2 = X[0] - c2.center
    d3 = X[0] - c3.center
    angs = [np.degrees(np.arccos(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b)))
            for a, b in ((d1, d2), (d1, d3), (d2, d3))]
    np.testing.assert_allclose(tri.angle[0], max(angs), atol=1e-6)


def _wing_markers():
    x, y = np.meshgrid(np.linspace(-0.1, 0.1, 5), np.linspace(-0.3, 0.3, 9), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def _bend(X, a=0.15, twist_deg=1.5):
    # bending w = a y^2 and a linear twist about the y axis (exact rotation of each chord)
    th = np.radians(twist_deg) * X[:, 1] / 0.3
    Y = X.copy()
    Y[:, 0] = X[:, 0] * np.cos(th)
    Y[:, 2] = -X[:, 0] * np.sin(th) + a * X[:, 1] ** 2
    return Y


def test_displacements_3d_of_known_bending():
    c1, c2 = _stereo([-0.08, 0.0, 0.0, 0.0, 0.0], [0.05, 0.0, 0.0, 0.0, 0.0])
    X0 = _wing_markers()
    X1 = _bend(X0)
    uv0 = np.stack([c1.project(X0), c2.project(X0)])
    uv1 = np.stack([c1.project(X1), c2.project(X1)])
    res = displacements_3d([c1, c2], uv0, uv1)
    np.testing.assert_allclose(res.displacement, X1 - X0, atol=1e-9)
    # with 0.05 px of image noise the error stays at the noise level: 0.05 px is 70 um across
    # the line of sight at 2 m, about 3 times more along it for these 35-degree rays
    rng = np.random.default_rng(6)
    res = displacements_3d([c1, c2], uv0 + rng.normal(0, 0.05, uv0.shape),
                           uv1 + rng.normal(0, 0.05, uv1.shape))
    err = np.linalg.norm(res.displacement - (X1 - X0), axis=1)
    assert np.sqrt(np.mean(err**2)) < 4e-4 and err.max() < 1e-3
    assert np.abs(res.displacement[:, 2]).max() > 0.01  # the bending itself is 13 mm


def test_one_camera_displacements_in_known_plane():
    cam = Camera.look_at([0.3, -0.9, 1.4], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000,
                         dist=[-0.05, 0.0, 0.0, 0.0, 0.0])
    X0 = _wing_markers()
    ids = np.array([f"m{i}" for i in range(len(X0))])
    # the bending moves markers in planes of constant y (spanwise stations known)
    X1 = _bend(X0)
    uv0 = cam.project(X0)
    uv1 = cam.project(X1)
    # tables in different orders, one marker missing wind-on, one unknown id wind-off
    perm = np.random.default_rng(7).permutation(len(X0))
    keep = perm[1:]
    res = marker_displacements(cam, ids, X0, np.r_[ids, ["extra"]], np.vstack([uv0, [5, 5]]),
                               ids[keep], uv1[keep], normal=[0.0, 1.0, 0.0])
    assert len(res.ids) == len(X0) - 1 and perm[0] not in [int(i[1:]) for i in res.ids]
    idx = np.array([int(i[1:]) for i in res.ids])
    assert np.all(idx[:-1] < idx[1:])  # order of the wind-off table
    np.testing.assert_allclose(res.duv, uv1[idx] - uv0[idx], atol=1e-12)
    np.testing.assert_allclose(res.X_ref, X0[idx], atol=1e-10)
    np.testing.assert_allclose(res.dX, X1[idx] - X0[idx], atol=1e-10)
    # default plane: normal to the optical axis; a motion in that plane is recovered
    shift = np.cross(cam.R[2], [0.0, 0.0, 1.0]) * 0.004 + np.cross(cam.R[2], [1.0, 0, 0]) * 0.002
    res = marker_displacements(cam, ids, X0, ids, uv0, ids, cam.project(X0 + shift))
    np.testing.assert_allclose(res.dX, np.broadcast_to(shift, X0.shape), atol=1e-10)


def test_one_camera_displacements_along_a_surface():
    import trimesh

    cam = Camera.look_at([0.3, -0.9, 1.4], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000,
                         dist=[-0.05, 0.0, 0.0, 0.0, 0.0])
    # a cylinder of radius 0.2 about the y axis; markers slide along it (known arc motion)
    r = 0.2
    cyl = trimesh.creation.cylinder(radius=r, height=1.0, sections=2048,
                                    transform=trimesh.transformations.rotation_matrix(
                                        np.pi / 2, [1, 0, 0]))
    th = np.linspace(-0.5, 0.5, 7)
    y = np.linspace(-0.3, 0.3, 5)
    T, Y = np.meshgrid(th, y, indexing="ij")

    def on_cyl(t, yy):
        return np.column_stack([r * np.sin(t.ravel()), yy.ravel(), r * np.cos(t.ravel())])

    X0 = on_cyl(T, Y)
    X1 = on_cyl(T + 0.03, Y + 0.004)  # a slide of 6 mm round and 4 mm along the axis
    ids = np.array([f"c{i}" for i in range(len(X0))])
    res = marker_displacements(cam, ids, X0, ids, cam.project(X0), ids, cam.project(X1),
                               surface=cyl)
    # the faceted cylinder (2048 sections) differs from the true one by < r (pi/2048)^2 / 2
    tol = r * (np.pi / 2048) ** 2
    np.testing.assert_allclose(res.X_ref, X0, atol=tol)
    np.testing.assert_allclose(res.dX, X1 - X0, atol=2 * tol)
    # a plane constraint would not give this: the displacement has a normal component
    assert np.abs(np.einsum("ij,j->i", X1 - X0, cam.R[2])).max() > 1e-3
    with pytest.raises(InputError, match="not both"):
        marker_displacements(cam, ids, X0, ids, cam.project(X0), ids, cam.project(X1),
                             surface=cyl, normal=[0, 1, 0])


def test_stack_views_feeds_triangulation():
    c1, c2 = _stereo()
    c3 = Camera.look_at([0.0, 0.8, 1.8], [0, 0, 0], [1, 0, 0], K=K, width=1280, height=1000)
    X = _points(6, seed=8)
    ids = np.array([f"p{i}" for i in range(6)])
    tabs = []
    for m, c in enumerate((c1, c2, c3)):
        keep = np.random.default_rng(m).permutation(np.arange(m, 6))  # some missing, shuffled
        tabs.append((ids[keep], c.project(X)[keep]))
    got_ids, uv = stack_views([t[0] for t in tabs], [t[1] for t in tabs])
    idx = [int(k[1:]) for k in got_ids]
    tri = triangulate([c1, c2, c3], uv)
    np.testing.assert_allclose(tri.points, X[idx], atol=1e-9)
    assert got_ids.tolist() == ["p1", "p2", "p3", "p4", "p5"]  # p0: one camera only
    assert np.isnan(uv[2, 0]).all() and np.isfinite(uv[:, 1:]).all()
    with pytest.raises(InputError, match="duplicate marker id 'p1'"):
        stack_views([["p1", "p1"]], [[[0, 0], [1, 1]]])


def test_bad_input():
    c1, c2 = _stereo()
    X = _points(4)
    uv = np.stack([c1.project(X), c2.project(X)])
    with pytest.raises(InputError, match="at least 2 cameras"):
        triangulate([c1], uv[:1])
    with pytest.raises(InputError, match="expected shape"):
        triangulate([c1, c2], uv[0])
    with pytest.raises(DegenerateError, match="same perspective centre"):
        triangulate([c1, c1.replace(K=K * [[1.1], [1.1], [1]])], uv)
    with pytest.raises(InputError, match="infinite"):
        triangulate([c1, c2], np.where(uv > 600, np.inf, uv))
    with pytest.raises(InputError, match="duplicate marker id 'a'"):
        pair_by_id(["a", "a"], [[0, 0], [1, 1]], ["a"], [[0, 0]])
    with pytest.raises(InputError, match="no marker id common"):
        marker_displacements(c1, ["a"], [[0, 0, 0]], ["b"], [[1, 1]], ["b"], [[1, 1]])
    with pytest.raises(InputError, match="min_cos"):
        marker_displacements(c1, ["a"], [[0, 0, 0]], ["a"], [[1, 1]], ["a"], [[1, 1]],
                             min_cos=float("nan"))
    # markers seen by no camera: NaN, without a warning
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tri = triangulate([c1, c2], np.full_like(np.asarray(uv, float), np.nan))
    assert np.isnan(tri.points).all() and np.isnan(tri.angle).all()
