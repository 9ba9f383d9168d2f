"""The synthetic scene with the traits of real PSP frames (scenes.real_traits): what it
claims to contain is checked against OpenCV's projection and the Plot3D reader."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from resection.io.images import read_image
from resection.io.markers import read_markers
from resection.io.meshes import load_mesh, read_plot3d
from scenes.real_traits import BOX, TARGET_D, real_traits, write_scene


@pytest.fixture(scope="module")
def scene():
    return real_traits()


def _cv_project(cam, X):
    rvec, _ = cv2.Rodrigues(cam.R)
    uv, _ = cv2.projectPoints(np.asarray(X, float), rvec, cam.t, cam.K, cam.dist)
    return uv.reshape(-1, 2)


def test_files_round_trip(scene, tmp_path):
    paths = write_scene(scene, tmp_path)
    blocks = read_plot3d(paths["grid"])
    assert len(blocks) == 11  # 3 x 2 plate blocks, block top and four sides
    mesh = load_mesh(paths["grid"])
    assert len(mesh.faces) == len(scene.mesh.faces)
    # the plate blocks share their interface nodes: the plate is one connected sheet
    plate = np.asarray(mesh.face_attributes["block"]) <= 6  # blocks 1-6
    sub = mesh.submesh([np.flatnonzero(plate)], append=True)
    assert len(sub.split(only_watertight=False)) == 1
    for c in range(2):
        img = read_image(paths[f"image{c}"])
        assert img.shape == scene.images[c].shape
        assert np.array_equal(img, scene.images[c].astype(np.float32))
    ms = read_markers(paths["markers"])
    assert list(ms.ids) == list(scene.marker_ids)
    assert np.allclose(ms.diameter, TARGET_D)


def test_real_traits(scene):
    cam0, cam1 = scene.cameras
    assert all(img.dtype == np.uint8 for img in scene.images)
    # glare saturates camera 0's frame, camera 1 is not saturated; gains differ by 25 %
    assert (scene.images[0] == 255).sum() > 50 and (scene.images[1] == 255).sum() == 0
    assert scene.gains[1] / scene.gains[0] == pytest.approx(1.25)
    # survey error 0.5..1.5 px equivalent at camera 0's distance, along the surface
    err = np.linalg.norm(scene.surveyed - scene.markers, axis=1)
    px = np.linalg.norm(scene.markers - cam0.center, axis=1) / cam0.K[0, 0]
    assert np.all((err / px > 0.5 - 1e-9) & (err / px < 1.5 + 1e-9))
    assert np.allclose(scene.surveyed[:, 2], scene.markers[:, 2])
    # the edge target: at u ~ 1 in camera 0 (OpenCV projection of its true position)
    ids = list(scene.marker_ids)
    uv_e = _cv_project(cam0, scene.markers[[ids.index("TE")]])[0]
    assert 0.5 < uv_e[0] < 1.5 and 0 < uv_e[1] < cam0.height - 1
    # the block target sits on the block's top and is a dark dot of low contrast there
    tb = scene.markers[ids.index("TB")]
    assert tb[2] == pytest.approx(BOX[2]) and abs(tb[0]) < BOX[0] and abs(tb[1]) < BOX[1]
    u, v = np.rint(_cv_project(cam0, tb[None])[0]).astype(int)
    img = scene.images[0].astype(float)
    ring = np.concatenate([img[v - 6, u - 6:u + 7], img[v + 6, u - 6:u + 7]])
    contrast = np.median(ring) - img[v - 1:v + 2, u - 1:u + 2].mean()
    assert 3 < contrast < 20  # visible, but 10x weaker than on the paint
    # taps: dark dots in the paint (distractors), not in the marker file
    uv_t = _cv_project(cam1, scene.taps)
    inside = cam1.in_image(uv_t, margin=8)
    assert inside.sum() >= 8
    img1 = scene.images[1].astype(float)
    for u, v in np.rint(uv_t[inside]).astype(int)[:4]:
        assert img1[v, u] < np.median(img1[v - 6:v + 7, u - 6:u + 7]) - 10
    assert len(scene.marker_ids) == len(scene.markers) and len(scene.taps) > 10
