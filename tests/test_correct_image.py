"""Image-level self-illumination correction against Mitsuba 3 renders (the independent
reference): a render with all interreflections, corrected, must match the emission-only
render of the same scene (``max_depth=1``) to within the render's own noise."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from scipy.ndimage import binary_erosion

from resection import Camera
from resection.errors import InputError
from resection.io.cameras import write_camera
from resection.surface.surface_map import SurfaceMap
from scenes.corner import corner
from selfillum import view_factors
from selfillum.cli.main import main
from selfillum.images.image_correction import UnseenFacesWarning, correct_image, read_reflectance
from selfillum.rendering.mitsuba_render import render


def corner_camera() -> Camera:
    K = [[160.0, 0.0, 95.5], [0.0, 160.0, 71.5], [0.0, 0.0, 1.0]]
    return Camera.look_at(
        [1.6, 0.5, 1.3], [0.3, 0.5, 0.3], [0.0, 1.0, 0.0], K=K, width=192, height=144
    )


@pytest.fixture(scope="module")
def renders():
    sc = corner(resolution=12)  # smooth emission pattern, reflectance 0.6
    cam = corner_camera()
    full = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=64, seed=1)
    again = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=64, seed=9)
    emit = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=1, spp=16, seed=2)
    smap = SurfaceMap(sc.mesh, cam)
    # pixels whose 5x5 neighbourhood lies on one plate (no silhouette or corner-line pixels)
    plate_img = np.where(smap.mask, sc.plate[np.maximum(smap.face_index, 0)], -1)
    inner = binary_erosion(plate_img == 0, iterations=2) | binary_erosion(
        plate_img == 1, iterations=2
    )
    noise = np.std((again.image - full.image)[inner] / emit.image[inner]) / np.sqrt(2)
    return sc, cam, smap, full.image, emit.image, inner, noise


@pytest.mark.parametrize("mode", ["subtract", "ratio"])
def test_corrected_render_matches_emission_only_render(renders, mode):
    sc, cam, smap, full, emit, inner, noise = renders
    r = correct_image(
        full, sc.mesh, cam, sc.reflectance, rays_per_face=1024, surface_map=smap, mode=mode
    )
    si = (full - emit)[inner] / emit[inner]
    err = (r.image - emit)[inner] / emit[inner]
    assert si.max() > 0.35 and si.mean() > 0.1  # a lot of self-illumination to remove
    # what is left is the render's own noise (plus < 0.5% of bias)
    assert np.sqrt(np.mean(err**2)) < 1.15 * noise + 0.005
    assert abs(err.mean()) < 0.005
    # per face, averaging the pixels, the residual is far below the SI
    face_err = smap.to_surface(np.where(inner, r.image - emit, np.nan)).values
    face_emit = smap.to_surface(np.where(inner, emit, np.nan)).values
    rel = np.abs(face_err / face_emit)
    assert np.nanmax(rel) < 0.03
    assert r.image.dtype == full.dtype and r.image.shape == full.shape
    np.testing.assert_array_equal(r.image[~smap.mask], full[~smap.mask])


def test_correction_is_smooth_across_face_edges(renders):
    """The per-pixel correction is interpolated over the surface: neighbouring pixels
    differ far less than the per-face values do from face to face."""
    sc, cam, smap, full, emit, inner, _ = renders
    r = correct_image(full, sc.mesh, cam, sc.reflectance, rays_per_face=256, surface_map=smap)
    nearest = smap.to_image(r.radiosity - r.emission, background=0.0, interpolation="nearest")

    def max_step(img):
        ok = inner[:, 1:] & inner[:, :-1]
        return np.abs(np.diff(img, axis=1))[ok].max()

    assert max_step(r.correction) < 0.3 * max_step(nearest)


def test_integer_image_keeps_dtype_and_background(renders):
    sc, cam, smap, full, emit, inner, noise = renders
    counts = np.rint(full * 4000 + 100 * ~smap.mask).astype(np.uint16)  # background = 100
    r = correct_image(counts, sc.mesh, cam, sc.reflectance, rays_per_face=256, surface_map=smap)
    assert r.image.dtype == np.uint16 and r.image.shape == counts.shape
    np.testing.assert_array_equal(r.image[~smap.mask], counts[~smap.mask])
    assert np.all(r.image[~smap.mask] >= 100)
    err = (r.image.astype(float) / 4000 - emit)[inner] / emit[inner]
    assert np.sqrt(np.mean(err**2)) < 1.15 * noise + 0.01


def test_partially_seen_model(renders):
    """Part of the wall is outside the image: those faces are estimated, the rest is still
    corrected well."""
    sc, cam, smap, full, emit, inner, noise = renders
    crop = cam.replace(width=150)  # same pinhole, the right-hand part cut off
    smap_c = SurfaceMap(sc.mesh, crop)
    r = correct_image(full[:, :150], sc.mesh, crop, sc.reflectance, surface_map=smap_c)
    assert r.info.method == "pcg" and 0 < r.info.n_hidden < len(sc.mesh.faces)
    inn = inner[:, :150]
    err = (r.image - emit[:, :150])[inn] / emit[:, :150][inn]
    assert np.sqrt(np.mean(err**2)) < 1.5 * noise + 0.01


def test_cli_correct_tiff_round_trip(renders, tmp_path, capsys):
    sc, cam, smap, full, emit, inner, noise = renders
    mesh_path, cam_path = tmp_path / "corner.ply", tmp_path / "cam.json"
    sc.mesh.export(mesh_path)
    write_camera(cam_path, cam)
    counts = np.rint(full * 4000).astype(np.uint16)
    tifffile.imwrite(tmp_path / "img.tif", counts)
    np.savetxt(
        tmp_path / "rho.csv",
        np.full(len(sc.mesh.faces), sc.reflectance),
        header="reflectance",
        comments="",
    )
    rc = main(
        [
            "correct",
            "--mesh",
            str(mesh_path),
            "--camera",
            str(cam_path),
            "--image",
            str(tmp_path / "img.tif"),
            "--reflectance",
            str(tmp_path / "rho.csv"),
            "--out",
            str(tmp_path / "out.tif"),
            "--surface",
            str(tmp_path / "faces.csv"),
            "--quiet",
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "self-illumination, seen faces  median" in printed and "99th" in printed
    assert "unseen faces emit              continue" in printed
    out = tifffile.imread(tmp_path / "out.tif")
    assert out.dtype == np.uint16 and out.shape == counts.shape
    err = (out.astype(float) / 4000 - emit)[inner] / emit[inner]
    assert np.sqrt(np.mean(err**2)) < 1.15 * noise + 0.01
    assert (tmp_path / "faces.csv").read_text().splitlines()[0].startswith("face,")
    # NPY in and out, float32, a scalar reflectance
    np.save(tmp_path / "img.npy", full)
    rc = main(
        [
            "correct",
            "--mesh",
            str(mesh_path),
            "--camera",
            str(cam_path),
            "--image",
            str(tmp_path / "img.npy"),
            "--reflectance",
            "0.6",
            "--out",
            str(tmp_path / "out.npy"),
            "--quiet",
            "--mode",
            "ratio",
        ]
    )
    assert rc == 0
    out = np.load(tmp_path / "out.npy")
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out[~smap.mask], full[~smap.mask])


def test_cli_correct_bad_input(renders, tmp_path, capsys):
    sc, cam, *_ = renders
    sc.mesh.export(tmp_path / "m.ply")
    write_camera(tmp_path / "c.json", cam)
    np.save(tmp_path / "small.npy", np.zeros((10, 10), np.float32))
    base = [
        "correct",
        "--mesh",
        str(tmp_path / "m.ply"),
        "--camera",
        str(tmp_path / "c.json"),
        "--out",
        str(tmp_path / "o.npy"),
        "--quiet",
    ]
    np.save(tmp_path / "rgb.npy", np.zeros((144, 192, 3), np.float32))
    cases = [
        (["--image", str(tmp_path / "small.npy"), "--reflectance", "0.6"], "does not match"),
        (["--image", str(tmp_path / "rgb.npy"), "--reflectance", "0.6"], "colour image"),
        (["--image", str(tmp_path / "none.npy"), "--reflectance", "0.6"], "no such image"),
        (["--image", str(tmp_path / "small.npy"), "--reflectance", "1.0"], "[0, 1)"),
    ]
    for extra, match in cases:
        assert main(base + extra) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and match in err, err


def test_read_reflectance(tmp_path):
    np.testing.assert_array_equal(read_reflectance("0.25", 3), [0.25] * 3)
    np.save(tmp_path / "r.npy", np.array([0.1, 0.2, 0.3]))
    np.testing.assert_array_equal(read_reflectance(tmp_path / "r.npy", 3), [0.1, 0.2, 0.3])
    (tmp_path / "r.csv").write_text("face,reflectance\n0,0.1\n1,0.2\n2,0.3\n")
    np.testing.assert_array_equal(read_reflectance(tmp_path / "r.csv", 3), [0.1, 0.2, 0.3])
    with pytest.raises(InputError, match="2 reflectance values for 3 faces"):
        read_reflectance(tmp_path / "r.npy", 2) if False else read_reflectance(
            _write(tmp_path / "two.npy", [0.1, 0.2]), 3
        )
    with pytest.raises(InputError, match="face 1"):
        read_reflectance(_write(tmp_path / "bad.npy", [0.1, 1.2, 0.3]), 3)
    with pytest.raises(FileNotFoundError):
        read_reflectance(tmp_path / "missing.csv", 3)


def _write(path, values):
    np.save(path, np.asarray(values))
    return path


def test_back_facing_model_refused(renders):
    sc, cam, *_ = renders
    flipped = sc.mesh.copy()
    flipped.invert()
    with pytest.raises(InputError, match="painted side"):
        correct_image(np.ones((144, 192)), flipped, cam, 0.5)


def test_stack_of_frames(renders):
    """A (T, H, W) stack: each frame corrected as on its own (F and the map reused); a
    frame with a masked (NaN) region is corrected with its own seen faces."""
    sc, cam, smap, full, emit, inner, noise = renders
    F = view_factors(sc.mesh, rays_per_face=256, seed=0)
    second = 0.5 * full
    second[:, 120:] = np.nan  # part of the wall masked in this frame
    stack = np.stack([full, second]).astype(np.float32)
    with pytest.warns(UnseenFacesWarning, match="frame 1"):  # the masked frame only
        r = correct_image(stack, sc.mesh, cam, sc.reflectance, F=F, surface_map=smap)
    assert len(r.warnings) == 1
    assert r.image.shape == stack.shape and r.image.dtype == np.float32
    assert r.emission.shape == (2, len(sc.mesh.faces)) and len(r.info) == 2
    one = correct_image(full, sc.mesh, cam, sc.reflectance, F=F, surface_map=smap)
    np.testing.assert_allclose(r.image[0], one.image, rtol=1e-6, atol=1e-7)
    assert r.info[0].method == "direct" and r.info[1].method == "pcg"
    assert np.all(np.isnan(r.image[1][:, 120:]))
    ok = inner & np.isfinite(second)
    err = (2 * r.image[1] - emit)[ok] / emit[ok]
    assert np.sqrt(np.mean(err**2)) < 1.5 * noise + 0.01


def test_cli_correct_stack(renders, tmp_path, capsys):
    """A (T, H, W) NPY stack through ``selfillum correct``: one corrected frame per input
    frame, the summary counts faces per frame (not over the stack)."""
    sc, cam, smap, full, emit, inner, noise = renders
    sc.mesh.export(tmp_path / "m.ply")
    write_camera(tmp_path / "c.json", cam)
    second = 0.5 * full
    second[:, 120:] = np.nan  # part of the wall masked in this frame
    np.save(tmp_path / "stack.npy", np.stack([full, second]))
    rc = main(["correct", "--mesh", str(tmp_path / "m.ply"), "--camera",
               str(tmp_path / "c.json"), "--image", str(tmp_path / "stack.npy"),
               "--reflectance", "0.6", "--out", str(tmp_path / "o.npy"), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    n = len(sc.mesh.faces)
    assert f"of {n}" in out and "2 frames" in out and "pcg" in out
    seen = int(out.split("faces seen")[1].split()[0])
    assert seen < n  # the smaller count, of the masked frame
    got = np.load(tmp_path / "o.npy")
    assert got.shape == (2, *full.shape) and got.dtype == full.dtype
    for frame, scale in ((got[0], 1.0), (got[1], 2.0)):
        ok = inner & np.isfinite(frame)
        err = (scale * frame - emit)[ok] / emit[ok]
        assert np.sqrt(np.mean(err**2)) < 1.5 * noise + 0.01


def test_cli_correct_8bit_writes_float_unless_asked(renders, tmp_path, capsys):
    """An 8-bit image's correction is often under one count: the output is float32 by
    default (TIFF and NPY), 8 bits only when asked, and an 8-bit PNG output is refused
    with the choices. On today's main the output was uint8 and the correction rounded."""
    from PIL import Image

    sc, cam, smap, full, emit, inner, noise = renders
    mesh_path, cam_path = tmp_path / "corner.ply", tmp_path / "cam.json"
    sc.mesh.export(mesh_path)
    write_camera(cam_path, cam)
    counts = np.clip(np.rint(full * 60), 0, 255).astype(np.uint8)
    Image.fromarray(counts).save(tmp_path / "img.png")

    def run(out, *extra):
        return main(["correct", "--mesh", str(mesh_path), "--camera", str(cam_path),
                     "--image", str(tmp_path / "img.png"), "--reflectance", "0.6",
                     "--out", str(tmp_path / out), "--quiet", *extra])

    assert run("out.tif") == 0 and run("out.npy") == 0
    tif = tifffile.imread(tmp_path / "out.tif")
    npy = np.load(tmp_path / "out.npy")
    assert tif.dtype == np.float32 and npy.dtype == np.float32
    np.testing.assert_array_equal(tif, npy)
    changed = np.abs(tif - counts) > 0
    fractional = changed & (np.abs(tif - np.rint(tif)) > 0.01)
    assert fractional.sum() > 0.5 * changed.sum() > 0  # sub-count corrections are kept
    assert run("out8.tif", "--dtype", "uint8") == 0
    out8 = tifffile.imread(tmp_path / "out8.tif")
    assert out8.dtype == np.uint8
    np.testing.assert_array_equal(out8, np.clip(np.rint(tif), 0, 255).astype(np.uint8))
    capsys.readouterr()
    assert run("out.png") == 2
    err = capsys.readouterr().err
    assert "out.png" in err and "--dtype uint16" in err and ".tif" in err
    assert not (tmp_path / "out.png").exists()
    assert run("out16.png", "--dtype", "uint16") == 0
    assert np.asarray(Image.open(tmp_path / "out16.png")).dtype == np.uint16
