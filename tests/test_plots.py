"""Pictures: what is drawn is checked against closed-form geometry and known residuals."""

import cv2
import imageio.v3 as iio
import numpy as np
import pytest
import trimesh
from matplotlib.collections import PolyCollection
from matplotlib.quiver import Quiver

from resection import Camera, InputError
from resection.surface.plots import plot_resection, plot_surface, virtual_camera


def plane(n=12):
    xs = np.linspace(-1, 1, n + 1)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    return trimesh.Trimesh(V, np.vstack([np.column_stack([a, b, c]),
                                         np.column_stack([a, c, d])]), process=False)


def test_surface_raster_shows_face_values(tmp_path):
    mesh = plane()
    values = (mesh.triangles_center[:, 0] > 0).astype(float)
    cam = virtual_camera(mesh, azimuth_deg=-90, elevation_deg=60, width=200, height=150,
                         up=(0, 1, 0))
    p = tmp_path / "surf.png"
    fig = plot_surface(mesh, values, cam, interpolation="nearest", label="Cp", path=p)
    shown = np.ma.filled(fig.axes[0].images[-1].get_array(), np.nan)
    assert shown.shape == (150, 200)
    # closed-form: x of the plane point each pixel sees
    vv, uu = np.mgrid[0:150, 0:200]
    o, d = cam.rays(np.column_stack([uu.ravel(), vv.ravel()]).astype(float))
    s = -o[:, 2] / d[:, 2]
    P = (o + s[:, None] * d).reshape(150, 200, 3)
    on = (np.abs(P[..., 0]) < 0.99) & (np.abs(P[..., 1]) < 0.99) & (np.abs(P[..., 0]) > 0.01)
    assert on.sum() > 2000
    np.testing.assert_array_equal(shown[on], (P[..., 0] > 0)[on].astype(float))
    off = (np.abs(P[..., 0]) > 1.01) | (np.abs(P[..., 1]) > 1.01)
    assert np.isnan(shown[off]).all()
    assert fig.axes[1].get_ylabel() == "Cp"  # the colour bar
    img = iio.imread(p)
    assert img.shape[0] > 150 and img.shape[1] > 200
    # given colour limits are used as given; bad ones are refused, not silently changed
    fig = plot_surface(mesh, values, cam, vmin=-1.0, vmax=3.0)
    assert fig.axes[0].images[-1].norm.vmin == -1.0
    assert fig.axes[0].images[-1].norm.vmax == 3.0
    with pytest.raises(InputError, match="vmax"):
        plot_surface(mesh, values, cam, vmin=2.0, vmax=1.0)
    with pytest.raises(InputError, match="colour map 'nosuch'"):
        plot_surface(mesh, values, cam, cmap="nosuch")
    with pytest.raises(InputError, match="picture format 'txt'"):
        plot_surface(mesh, values, cam, path=tmp_path / "surf.txt")
    assert not (tmp_path / "surf.txt").exists()


def test_surface_polygons_are_visible_faces_far_to_near():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    cam = virtual_camera(mesh, azimuth_deg=20, elevation_deg=10, width=160, height=120)
    fig = plot_surface(mesh, np.arange(len(mesh.faces), dtype=float), cam,
                       method="polygons")
    coll = [c for c in fig.axes[0].collections if isinstance(c, PolyCollection)][0]
    to_cam = cam.center - mesh.triangles_center
    facing = np.einsum("ij,ij->i", mesh.face_normals, to_cam) > 0
    drawn = np.asarray(coll.get_array()).astype(int)  # the face index of every polygon
    assert sorted(drawn.tolist()) == np.flatnonzero(facing).tolist()
    # painter's order: depth along the optical axis never increases
    depth = cam.to_camera_frame(mesh.triangles_center[drawn])[:, 2]
    assert np.all(np.diff(depth) <= 1e-12)
    # each polygon is its face projected with OpenCV
    kk, dd, rv, tv = cam.to_opencv()
    uv, _ = cv2.projectPoints(mesh.triangles[drawn[0]], rv, tv, kk, dd)
    np.testing.assert_allclose(coll.get_paths()[0].vertices[:3], uv.reshape(3, 2), atol=1e-9)
    with pytest.raises(InputError, match="faces"):
        plot_surface(mesh, np.zeros(3), cam)


def test_resection_picture_rms_and_residuals(tmp_path):
    K = np.array([[500.0, 0, 159.5], [0, 500.0, 119.5], [0, 0, 1]])
    cam = Camera.look_at([0.2, -0.3, 2.0], [0, 0, 0], [0, 1, 0], K=K, width=320, height=240,
                         dist=[-0.1, 0, 0, 0, 0])
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-0.5, 0.5, (10, 2)), np.zeros(10)])
    kk, dd, rv, tv = cam.to_opencv()
    uv, _ = cv2.projectPoints(X, rv, tv, kk, dd)
    offsets = rng.normal(scale=0.3, size=(10, 2))
    det = uv.reshape(-1, 2) + offsets
    det[9] = np.nan  # not detected
    rms = np.sqrt(np.mean(np.sum(offsets[:9] ** 2, axis=1)))
    p = tmp_path / "res.png"
    fig = plot_resection(np.zeros((240, 320)), cam, X, det, mesh=plane(4), path=p,
                         residual_scale=20.0)
    ax = fig.axes[0]
    assert f"RMS residual {rms:.3f} px (9 markers)" in ax.get_title()
    q = [c for c in ax.collections if isinstance(c, Quiver)][0]
    np.testing.assert_allclose(q.U, offsets[:9, 0] * 20.0, rtol=1e-6)
    np.testing.assert_allclose(q.V, offsets[:9, 1] * 20.0, rtol=1e-6)
    assert any("x 20" in t.get_text() for t in ax.texts)
    assert p.stat().st_size > 1000
    with pytest.raises(InputError, match=r"\(100, 100\)"):
        plot_resection(np.zeros((100, 100)), cam, X, det)
    with pytest.raises(InputError, match="10 rows"):
        plot_resection(np.zeros((240, 320)), cam, X, det[:5])
    # marker labels: one per marker, placed at the reprojections, with a dark halo
    ids = [f"M{k}" for k in range(10)]
    fig = plot_resection(np.ones((240, 320)), cam, X, det, ids=ids)
    labels = {t.get_text(): t for t in fig.axes[0].texts if t.get_text() in ids}
    assert sorted(labels) == sorted(ids)
    np.testing.assert_allclose(labels["M3"].xy, uv.reshape(-1, 2)[3], atol=1e-9)
    assert labels["M3"].get_path_effects()
    with pytest.raises(InputError, match="ids has 3 labels"):
        plot_resection(np.zeros((240, 320)), cam, X, det, ids=ids[:3])
