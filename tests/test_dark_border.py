"""The frame's dark border (issue 34 item 9): rows and columns at the edges of a real
frame that hold no light were mapped as about 0 counts. ``map`` masks them as unknown and
says so; the face values equal those of the same frame with the border removed by hand."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from resection import Camera
from resection.border import dark_border, mask_dark_border
from resection.cli.main import main
from resection.io.cameras import write_camera
from resection.io.images import write_image
from resection.io.meshes import read_face_fields

W, H = 320, 240


def _plate(n=24, half=1.2):
    xs = np.linspace(-half, half, n + 1)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    return trimesh.Trimesh(V, np.vstack([np.column_stack([a, b, c]),
                                         np.column_stack([a, c, d])]), process=False)


def _frame(seed=0):
    """A 12-bit frame the model fills: lamp fall-off, glare, speckle; 2 rows at the
    bottom and 3 columns at the left hold only read noise (0..4 counts)."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W]
    lit = 2200.0 - 500.0 * ((u - 200) ** 2 + (v - 90) ** 2) / (W * W)
    lit += 900.0 * np.exp(-((u - 250) ** 2 + (v - 60) ** 2) / 200.0)  # glare
    lit *= rng.gamma(40.0, 1 / 40.0, size=lit.shape)  # speckle
    img = np.clip(np.rint(lit), 0, 4095)
    img[-2:] = rng.integers(0, 5, size=(2, W))
    img[:, :3] = rng.integers(0, 5, size=(H, 3))
    return img.astype(np.uint16)


def test_dark_border_found_and_only_it():
    img = _frame()
    assert dark_border(img) == (0, 2, 3, 0)
    out, border = mask_dark_border(img)
    assert border == (0, 2, 3, 0)
    assert np.isnan(out[-2:]).all() and np.isnan(out[:, :3]).all()
    assert np.isfinite(out[:-2, 3:]).all()
    # dark background along an edge with the model crossing it: 90 % of the line is not
    # dark, nothing is taken; a dark patch inside the frame is no border
    scene = _frame(1)[:-2, 3:].astype(float)
    scene[:30, :200] = 3.0
    scene[100:140, 100:160] = 2.0
    assert dark_border(scene) == (0, 0, 0, 0)
    # a frame of one level, a ramp (its first row the darkest), signed values: no dark
    # level, no border
    assert dark_border(np.full((50, 60), 7.0)) == (0, 0, 0, 0)
    assert dark_border(np.linspace(1.0, 2.0, 72 * 96).reshape(72, 96)) == (0, 0, 0, 0)
    assert dark_border(np.linspace(-1.0, 1.0, 72 * 96).reshape(72, 96)) == (0, 0, 0, 0)


def test_map_masks_the_dark_border(tmp_path, capsys):
    mesh = _plate()
    mesh.export(tmp_path / "plate.ply")
    cam = Camera.look_at([0.05, -0.03, 2.0], [0, 0, 0], [0, 1, 0],
                         K=[[260.0, 0, 159.5], [0, 262.0, 119.5], [0, 0, 1]], width=W,
                         height=H, dist=[-0.05, 0.01, 0, 0, 0])
    write_camera(tmp_path / "cam.json", cam)
    img = _frame()
    write_image(tmp_path / "frame.png", img, dtype=np.uint16)
    by_hand = img.astype(np.float32)
    by_hand[-2:] = np.nan
    by_hand[:, :3] = np.nan
    write_image(tmp_path / "clean.tif", by_hand)
    args = ["map", "--mesh", str(tmp_path / "plate.ply"), "--camera",
            str(tmp_path / "cam.json"), "--saturation", "4095"]
    assert main([*args, "--image", str(tmp_path / "frame.png"), "--out",
                 str(tmp_path / "a.csv")]) == 0
    out = capsys.readouterr().out
    assert "a dark border masked as unknown (2 rows at the bottom, 3 columns at the left" \
        in out
    assert main([*args, "--image", str(tmp_path / "clean.tif"), "--out",
                 str(tmp_path / "b.csv")]) == 0
    nf = len(mesh.faces)
    got = read_face_fields(tmp_path / "a.csv", nf)["frame"]
    ref = read_face_fields(tmp_path / "b.csv", nf)["clean"]
    np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_allclose(got, ref, rtol=1e-6, equal_nan=True)
    # nothing near zero was mapped: every seen face holds lit counts
    assert np.nanmin(got) > 1000.0
    # --keep-border maps it as it is (the border pulls its faces down)
    assert main([*args, "--image", str(tmp_path / "frame.png"), "--keep-border", "--out",
                 str(tmp_path / "c.csv")]) == 0
    kept = read_face_fields(tmp_path / "c.csv", nf)["frame"]
    assert np.nanmin(kept) < 500.0


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
def test_dark_border_other_frame_types(dtype):
    img = (_frame(2).astype(float) / 16.0).astype(dtype)
    assert dark_border(img) == (0, 2, 3, 0)
