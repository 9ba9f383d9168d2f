"""Outlines (silhouettes and creases, never grid-block interfaces) and framing of
``resection view``, checked against the scene's closed-form geometry and OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from resection import Camera, InputError
from resection.io.meshes import load_mesh
from resection.surface.outline import outline_edges, visible_segments
from resection.surface.plots import frame_camera
from scenes.real_traits import BOX, HALF_X, HALF_Y, real_traits, write_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    sc = real_traits()
    paths = write_scene(sc, tmp_path_factory.mktemp("outline"))
    return sc, paths


def _length(seg):
    return float(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).sum())


def _on_plate_interior(seg):
    """Segments lying on the plate (z = 0) away from its border and from the block's foot."""
    a, b, _ = BOX
    P = seg.reshape(-1, 3)
    flat = np.all(P[:, 2] == 0)
    inside = (np.abs(P[:, 0]) < HALF_X - 1e-9) & (np.abs(P[:, 1]) < HALF_Y - 1e-9)
    foot = (np.abs(P[:, 0]) <= a + 1e-9) & (np.abs(P[:, 1]) <= b + 1e-9)
    ok = (inside & ~foot).reshape(-1, 2).any(axis=1)
    return flat & ok if np.ndim(flat) else (np.all(seg[:, :, 2] == 0, axis=1) & ok)


@pytest.mark.parametrize("merge", [True, False])
def test_block_interfaces_are_not_outlines(scene, merge):
    """The plate's 3 x 2 blocks meet along x = +-0.1 and y = 0 across flat paint: no outline
    edge there (merged nodes or not), while the block's creases and the free edges are."""
    sc, paths = scene
    mesh = load_mesh(paths["grid"], merge_vertices=merge)
    seg = outline_edges(mesh, 30.0)
    assert not _on_plate_interior(seg).any()
    a, b, h = BOX
    plate_border = 2 * (2 * HALF_X + 2 * HALF_Y)
    rim = 2 * (2 * a + 2 * b)
    # plate border + block top rim (creases) + 4 vertical creases + block foot (free edges)
    assert _length(seg) == pytest.approx(plate_border + rim + 4 * h + rim, rel=1e-9)
    # the 90-degree creases go above a 95-degree threshold; the free edges stay
    seg95 = outline_edges(mesh, 95.0)
    assert _length(seg95) == pytest.approx(plate_border + rim, rel=1e-9)
    # and the block structure of the grid is there to be ignored: 11 blocks
    assert len(np.unique(mesh.face_attributes["block"])) == 11


def test_silhouette_of_a_sphere():
    """Silhouette edges of a sphere seen from distance d project onto its apparent
    circle, radius f tan(asin(r / d)) about the principal point (closed form)."""
    r, d, f = 1.0, 5.0, 400.0
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=r)
    K = [[f, 0, 199.5], [0, f, 199.5], [0, 0, 1]]
    cam = Camera.look_at([0, 0, d], [0, 0, 0], [0, 1, 0], K=K, width=400, height=400)
    seg = outline_edges(mesh, 60.0, camera=cam)
    assert len(seg) > 50
    assert len(outline_edges(mesh, 60.0)) == 0  # no crease, no free edge
    rvec, _ = cv2.Rodrigues(cam.R)
    uv, _ = cv2.projectPoints(seg.reshape(-1, 3), rvec, cam.t, cam.K, cam.dist)
    rad = np.linalg.norm(uv.reshape(-1, 2) - [199.5, 199.5], axis=1)
    apparent = f * np.tan(np.arcsin(r / d))
    assert np.all(rad < apparent * 1.0001) and np.all(rad > apparent * 0.99)


def test_hidden_outline_is_not_drawn(scene):
    """Camera 0 looks from -x, -y, above: the block's vertical edge at (-a, -b) faces it,
    the one at (+a, +b) is behind the block."""
    sc, _ = scene
    a, b, h = BOX
    cam = sc.cameras[0]
    seg = np.array([[[-a, -b, 0.0], [-a, -b, h]], [[a, b, 0.0], [a, b, h]]])
    assert visible_segments(sc.mesh, cam, seg).tolist() == [True, False]


def test_frame_camera_target_zoom_and_box(scene):
    sc, _ = scene
    cam = sc.cameras[0]
    X = np.array([[0.0, 0.0, BOX[2]], [0.05, -0.03, 0.0], [-0.1, 0.08, 0.0]])
    rvec, _ = cv2.Rodrigues(cam.R)

    def cv(c, P):
        uv, _ = cv2.projectPoints(P, rvec, c.t, c.K, c.dist)
        return uv.reshape(-1, 2)

    z = frame_camera(cam, target=X[0], zoom=2.5)
    centre = np.array([(cam.width - 1) / 2, (cam.height - 1) / 2])
    ref = cv(cam, X)
    # a magnified crop of the same view, distortion included
    assert np.allclose(cv(z, X), centre + 2.5 * (ref - ref[0]), atol=1e-6)
    assert (z.width, z.height) == (cam.width, cam.height)
    lo, hi = np.array([-0.05, -0.04, 0.0]), np.array([0.05, 0.04, BOX[2]])
    zb = frame_camera(cam, box=[lo, hi], margin=1.1)
    corners = np.array([[x, y, zz] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for zz in (lo[2], hi[2])])
    uv = cv(zb, corners)
    assert zb.in_image(uv).all()
    span = (uv.max(axis=0) - uv.min(axis=0)) / [cam.width - 1, cam.height - 1]
    assert span.max() == pytest.approx(1 / 1.1, rel=1e-6)
    with pytest.raises(InputError, match="not both"):
        frame_camera(cam, target=X[0], box=[lo, hi])
    with pytest.raises(InputError, match="behind"):
        frame_camera(cam, target=cam.center + 2 * (cam.center - X[0]))
    with pytest.raises(InputError, match="zoom"):
        frame_camera(cam, target=X[0], zoom=0)


def test_cli_view_frames_a_region(scene, tmp_path, capsys):
    import imageio.v3 as iio

    from resection.cli.main import main

    sc, p = scene
    vals = tmp_path / "v.npy"
    np.save(vals, sc.truth)
    out = tmp_path / "box.png"
    rc = main(["view", "--mesh", p["grid"], "--values", str(vals), "--size", "320x240",
               "--box", "-0.08", "-0.07", "0", "0.08", "0.07", "0.04", "--out", str(out)])
    assert rc == 0 and iio.imread(out).ndim == 3
    rc = main(["view", "--mesh", p["grid"], "--values", str(vals), "--camera", p["camera0"],
               "--target", "0", "0", "0.04", "--zoom", "3", "--crease", "45",
               "--out", str(tmp_path / "t.png")])
    assert rc == 0 and (tmp_path / "t.png").stat().st_size > 1000
    capsys.readouterr()
    rc = main(["view", "--mesh", p["grid"], "--values", str(vals), "--camera", p["camera0"],
               "--target", "0", "0", "0.04", "--zoom", "-1", "--out", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert rc == 2 and "zoom" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.png").exists()
