"""Several cameras merged onto one grid (resection.surface.merge) on the real-traits scene: gains
matched on the overlap against the scene's true gains, and the seam level at the images'
edges measured against the true paint luminescence."""

from __future__ import annotations

import numpy as np
import pytest

from resection import InputError
from resection.surface.merge import angle_weights, boundary_pixels, merge_views, pixel_weights
from resection.surface.surface_map import SurfaceMap
from scenes.real_traits import real_traits


@pytest.fixture(scope="module")
def scene():
    sc = real_traits()
    maps = [SurfaceMap(sc.mesh, c) for c in sc.cameras]
    images = [np.where(i == 255, np.nan, i.astype(float)) for i in sc.images]  # saturated out
    return sc, maps, images


def seam_level(sc, maps, mv):
    """90th percentile of the step of ``merged / truth`` between adjacent plate faces on
    either side of an image's coverage boundary, and the same inside (for scale). Faces
    carrying a target or tap dot, or glare, are left out (the truth has neither)."""
    mesh = sc.mesh
    cen = np.asarray(mesh.vertices)[np.asarray(mesh.faces)].mean(axis=1)
    dots = np.vstack([sc.markers, sc.taps])[:, :2]
    near = np.min(np.linalg.norm(cen[:, None, :2] - dots[None], axis=2), axis=1) < 0.015
    glare = np.zeros(len(cen), bool)
    for m, g in zip(maps, sc.glare, strict=True):
        glare |= np.nan_to_num(m.to_surface(g).values) > 0.5
    clean = sc.painted & ~near & ~glare
    adj = np.asarray(mesh.face_adjacency)
    e = mv.values / sc.truth - 1.0
    ok = clean[adj].all(axis=1) & np.isfinite(e[adj]).all(axis=1)
    cross = np.zeros(len(adj), bool)
    for m in maps:  # where each image's footprint ends
        s = m.seen_faces
        cross |= s[adj[:, 0]] != s[adj[:, 1]]
    step = np.abs(e[adj[:, 0]] - e[adj[:, 1]])
    assert (ok & cross).sum() > 40 and (ok & ~cross).sum() > 1000
    return np.percentile(step[ok & cross], 90), np.percentile(step[ok & ~cross], 90)


def test_gain_matched_on_overlap(scene):
    sc, maps, images = scene
    mv = merge_views(maps, images)
    true_ratio = sc.gains[1] / sc.gains[0]
    assert mv.gains[0] == 1.0
    assert mv.gains[1] == pytest.approx(true_ratio, rel=0.01)
    (o,) = mv.overlaps
    assert o.cameras == (0, 1) and o.n_faces > 300
    assert o.median_before == pytest.approx(true_ratio - 1.0, abs=0.01)
    assert abs(o.median_after) < 0.005
    assert "gain ratio" in mv.report() and "cameras 0-1" in mv.report()
    # the merge is in camera 0's counts: the painted faces agree with the truth there
    # (vignetting, up to 12 % at the corners, is the only systematic left)
    clean = sc.painted & mv.seen
    rel = mv.values[clean] / sc.truth[clean] - 1.0
    assert np.all(np.isfinite(rel)) and -0.12 < np.median(rel) < 0.0


def test_no_seam_on_raw_counts(scene):
    """The seam level of the merge is that of the texture-free interior; a plain weighted
    mean (no gain matching, no feathering) shows a step of several per cent."""
    sc, maps, images = scene
    seam, inside = seam_level(sc, maps, merge_views(maps, images))
    plain, _ = seam_level(sc, maps, merge_views(maps, images, match_gain=False, feather_px=0))
    sharp, _ = seam_level(sc, maps, merge_views(maps, images, feather_px=0))
    assert seam < 0.012 and seam < 2.0 * inside
    assert plain > 0.05  # the 25 % gain difference shows
    assert seam < 0.75 * sharp  # feathering removes what vignetting leaves at the edges


def test_pixel_and_angle_weights(scene):
    sc, maps, _ = scene
    m = maps[0]
    W = m.shape[1]
    pw = pixel_weights(m, feather_px=8, edge_margin=1)
    bnd = boundary_pixels(m)
    assert np.all(pw[bnd] == 0) and np.all(pw[~m.mask] == 0)
    # block outline (occlusion and creases) is a boundary: the block's top face pixels
    # next to the plate are in it
    blk = np.asarray(sc.mesh.face_attributes["block"])
    top = (m.face_index >= 0) & (blk[np.maximum(m.face_index, 0)] == 7)
    assert (bnd & top).sum() > 10
    # at the image edge, far from boundaries: ramp d / (feather + 1), d = 1 on the edge
    row = m.shape[0] // 2
    far = ~bnd[row - 12:row + 12, :12].any()
    assert far
    assert pw[row, 0] == pytest.approx(1 / 9) and pw[row, 4] == pytest.approx(5 / 9)
    # default: 4 % of the smaller side (240 px -> 9.6 px)
    pwd = pixel_weights(m)
    assert pwd[row, 0] == pytest.approx(1 / 10.6) and pwd[row, 12] == 1.0
    assert pw[row, W // 4] == 1.0 or bnd[row, W // 4]
    # view-angle taper in closed form for the plate: cos t = z_cam / distance
    a = angle_weights(m, 70.0)
    cen = np.asarray(sc.mesh.vertices)[np.asarray(sc.mesh.faces)].mean(axis=1)
    d = m.camera.center[None, :] - cen
    cos = d[:, 2] / np.linalg.norm(d, axis=1)
    c0 = np.cos(np.radians(70))
    plate = blk < 6
    assert np.allclose(a[plate], np.clip((cos[plate] - c0) / (1 - c0), 0, 1), atol=1e-12)
    # faces seen beyond 70 degrees (and from behind) count as unseen
    mv = merge_views([m], [sc.images[0].astype(float)])
    n = sc.mesh.face_normals
    cosf = np.einsum("ij,ij->i", n, d) / np.linalg.norm(d, axis=1)
    assert not np.any(mv.seen & (cosf < c0 - 1e-9))


def test_given_gains_and_bad_input(scene):
    sc, maps, images = scene
    mv = merge_views(maps, images, gains=[1.0, 1.0])
    assert np.array_equal(mv.gains, [1.0, 1.0])
    assert mv.overlaps[0].median_after == pytest.approx(mv.overlaps[0].median_before)
    with pytest.raises(InputError, match="gains"):
        merge_views(maps, images, gains=[1.0])
    with pytest.raises(InputError, match="2 surface maps but 1 images"):
        merge_views(maps, images[:1])
    with pytest.raises(InputError, match="feather_px"):
        merge_views(maps, images, feather_px=-1)
    with pytest.raises(InputError, match="max_obliqueness"):
        merge_views(maps, images, max_obliqueness=95)
    with pytest.raises(InputError, match="shape"):
        merge_views(maps, [images[0], images[1][:-1]])


def test_cli_map_merges_two_cameras(scene, tmp_path, capsys):
    """``resection map`` with two (camera, image) pairs: the merged field of the files (8-bit
    PNGs with a saturated glare, Plot3D grid) is the library's merge, in camera 0's counts."""
    import pandas as pd

    from resection.cli.main import main
    from scenes.real_traits import write_scene

    sc, maps, images = scene
    p = write_scene(sc, tmp_path)
    out = tmp_path / "merged.csv"
    rc = main(["map", "--mesh", p["grid"], "--camera", p["camera0"], "--image", p["image0"],
               "--camera", p["camera1"], "--image", p["image1"], "--out", str(out)])
    text = capsys.readouterr().out
    assert rc == 0 and "cameras 0-1" in text and "gain ratio 1.2" in text
    df = pd.read_csv(out)
    assert {"merged", "merged_weight", "merged_cameras", "merged_seen", "cam0",
            "cam1_weight"} <= set(df.columns)
    mv = merge_views(maps, images)
    got = df["merged"].to_numpy()
    assert np.array_equal(np.isfinite(got), mv.seen)
    assert np.allclose(got[mv.seen], mv.values[mv.seen], rtol=1e-6)
    assert (df["merged_cameras"] == 2).sum() > 300
    # one image for two cameras: a one-line error, exit 2, nothing written
    rc = main(["map", "--mesh", p["grid"], "--camera", p["camera0"], "--image", p["image0"],
               "--camera", p["camera1"], "--out", str(tmp_path / "bad.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "1 images for 2 cameras" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad.csv").exists()
