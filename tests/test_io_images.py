"""One image reader for every command: PNG, TIFF (8/16-bit, float, multi-page), NPY, checked
against imageio and tifffile writing the files; bad files named on one line."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from resection import InputError, read_image, write_image
from resection.io.cameras import write_camera
from resection.io.images import read_native


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32])
def test_tiff_written_by_tifffile(tmp_path, dtype):
    rng = np.random.default_rng(0)
    a = (rng.random((30, 40)) * 200).astype(dtype)
    tifffile.imwrite(tmp_path / "a.tif", a)
    got = read_image(tmp_path / "a.tif")
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, a.astype(np.float32))
    assert read_native(tmp_path / "a.tif").dtype == dtype


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_written_by_imageio_and_read_back(tmp_path, dtype):
    a = np.arange(24 * 32, dtype=np.int64).reshape(24, 32) % (np.iinfo(dtype).max + 1)
    a = a.astype(dtype)
    iio.imwrite(tmp_path / "a.png", a)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), a.astype(np.float32))
    write_image(tmp_path / "b.png", a)
    np.testing.assert_array_equal(iio.imread(tmp_path / "b.png"), a)


def test_multipage_tiff_is_a_stack(tmp_path):
    stack = np.random.default_rng(1).integers(0, 4095, (3, 20, 25)).astype(np.uint16)
    tifffile.imwrite(tmp_path / "s.tif", stack, photometric="minisblack")
    with pytest.raises(InputError, match=r"s.tif: a stack of 3 frames.*iter_frames"):
        read_image(tmp_path / "s.tif")
    np.testing.assert_array_equal(read_native(tmp_path / "s.tif"), stack)


@pytest.mark.parametrize("channels, kind", [(2, "grey \\+ alpha"), (4, "RGBA")])
def test_png_with_alpha_is_refused(tmp_path, channels, kind):
    a = np.zeros((10, 12, channels), np.uint8)
    iio.imwrite(tmp_path / "a.png", a)
    with pytest.raises(InputError, match=kind) as err:
        read_image(tmp_path / "a.png")
    assert "a.png" in str(err.value) and "\n" not in str(err.value)


def test_truncated_png_and_tiff(tmp_path):
    a = np.arange(400, dtype=np.uint16).reshape(20, 20)
    for name in ("a.png", "a.tif"):
        write_image(tmp_path / name, a)
        data = (tmp_path / name).read_bytes()
        (tmp_path / name).write_bytes(data[: len(data) // 3])
        with pytest.raises(InputError, match=name) as err:
            read_image(tmp_path / name)
        assert "\n" not in str(err.value)


def test_selfillum_correct_takes_png(tmp_path, capsys):
    """``selfillum correct`` refused PNG, which ``resection`` reads: the one reader now
    serves both, and an 8-bit PNG comes back as an 8-bit PNG of the same shape when 8 bits
    are asked for (without ``--dtype`` an 8-bit PNG output is refused: the correction would
    be rounded away; tests/test_correct_image.py)."""
    from resection import Camera
    from scenes.corner import corner
    from selfillum.cli.main import main

    sc = corner(resolution=4)
    sc.mesh.export(tmp_path / "corner.ply")
    K = [[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]]
    write_camera(tmp_path / "cam.json",
                 Camera.look_at([1.6, 0.5, 1.3], [0.3, 0.5, 0.3], [0.0, 1.0, 0.0], K=K,
                                width=64, height=48))
    img = np.full((48, 64), 120, np.uint8)
    iio.imwrite(tmp_path / "frame.png", img)
    rc = main(["correct", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--image", str(tmp_path / "frame.png"),
               "--reflectance", "0.5", "--rays", "32", "--out", str(tmp_path / "out.png"),
               "--quiet", "--dtype", "uint8"])
    assert rc == 0, capsys.readouterr().err
    out = iio.imread(tmp_path / "out.png")
    assert out.dtype == np.uint8 and out.shape == img.shape
    assert out.max() <= 120 and out.min() < 120  # light removed where the model is seen
