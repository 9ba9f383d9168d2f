"""``resection map / backproject / align / view`` end to end on files, checked against
closed-form plane geometry."""

import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest

from resection.cli import main
from resection.io.meshes import write_plot3d
from scenes.psp_pair import HALF_X, HALF_Y, plane_hits, psp_pair, render


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_surface")
    pp = psp_pair(width=160, height=120, noise=0.0)
    xs, ys = np.linspace(-HALF_X, HALF_X, 25), np.linspace(-HALF_Y, HALF_Y, 17)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    write_plot3d(d / "panel.xyz", [np.stack([X, Y, np.zeros_like(X)], axis=-1)], binary=False)
    pp.camera_off.write(d / "off.json")
    pp.camera_on.write(d / "on.json")
    P, on = plane_hits(pp.camera_off)
    np.save(d / "xcoord.npy", np.where(on, P[..., 0], np.nan))
    np.save(d / "tex.npy", render(pp.camera_on))
    return d, pp, P, on


def test_map_then_backproject(files, capsys):
    d, pp, P, on = files
    rc = main(["map", "--mesh", str(d / "panel.xyz"), "--camera", str(d / "off.json"),
               "--image", str(d / "xcoord.npy"), "--out", str(d / "surf.csv")])
    assert rc == 0 and "faces seen" in capsys.readouterr().out
    df = pd.read_csv(d / "surf.csv")
    assert {"xcoord", "xcoord_count", "xcoord_seen", "block"} <= set(df.columns)
    inside = pp.camera_off.in_image(pp.camera_off.project(df[["cx", "cy", "cz"]].to_numpy()),
                                    margin=12)
    many = (df["xcoord_count"] > 15).to_numpy() & inside
    assert many.sum() > 50
    # the mean of x over a face's pixels is its centroid's x within a pixel footprint
    np.testing.assert_allclose(df["xcoord"][many], df["cx"][many], atol=1.5e-3)
    rc = main(["backproject", "--mesh", str(d / "panel.xyz"), "--camera", str(d / "off.json"),
               "--values", str(d / "surf.csv"), "--field", "xcoord", "--background", "-5",
               "--out", str(d / "back.npy")])
    assert rc == 0
    back = np.load(d / "back.npy")
    # away from the image border, where faces are only partly seen (faces ~17 px wide)
    inner = np.zeros_like(on)
    inner[40:80, 45:115] = True
    np.testing.assert_allclose(back[inner], P[..., 0][inner], atol=1e-3)
    assert np.all(back[~on] == -5)


def test_align_and_view(files):
    d, pp, P, on = files
    rc = main(["align", "--mesh", str(d / "panel.xyz"), "--source-camera", str(d / "on.json"),
               "--target-camera", str(d / "off.json"), "--image", str(d / "tex.npy"),
               "--order", "3", "--out", str(d / "aligned.npy")])
    assert rc == 0
    out = np.load(d / "aligned.npy")
    direct = render(pp.camera_off)
    m = np.isfinite(out) & on
    m[:4], m[-4:], m[:, :4], m[:, -4:] = False, False, False, False
    assert m.sum() > 0.7 * on.sum()
    assert np.max(np.abs(out[m] / direct[m] - 1)) < 0.01
    rc = main(["view", "--mesh", str(d / "panel.xyz"), "--values", str(d / "surf.csv"),
               "--field", "xcoord", "--size", "200x150", "--out", str(d / "view.png")])
    assert rc == 0
    png = iio.imread(d / "view.png")
    assert png.shape[0] > 150 and png.shape[1] > 200 and png.ndim == 3


def test_errors_are_one_line(files, capsys):
    d, *_ = files
    np.save(d / "small.npy", np.zeros((10, 10)))
    rc = main(["map", "--mesh", str(d / "panel.xyz"), "--camera", str(d / "off.json"),
               "--image", str(d / "small.npy"), "--out", str(d / "x.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "(10, 10)" in err and "(120, 160)" in err
    rc = main(["view", "--mesh", str(d / "panel.xyz"), "--values", str(d / "surf.csv"),
               "--field", "nope", "--out", str(d / "v.png")])
    assert rc == 2 and "no field 'nope'" in capsys.readouterr().err
    rc = main(["map", "--mesh", str(d / "missing.xyz"), "--camera", str(d / "off.json"),
               "--image", str(d / "small.npy"), "--out", str(d / "x.csv")])
    assert rc == 2 and "not found" in capsys.readouterr().err
    # two images with the same file name would overwrite each other's field
    (d / "sub").mkdir(exist_ok=True)
    np.save(d / "sub" / "tex.npy", np.load(d / "tex.npy"))
    rc = main(["map", "--mesh", str(d / "panel.xyz"), "--camera", str(d / "off.json"),
               "--image", str(d / "tex.npy"), str(d / "sub" / "tex.npy"), "--out",
               str(d / "x.csv")])
    assert rc == 2 and "several images named 'tex'" in capsys.readouterr().err
    assert not (d / "x.csv").exists()
    rc = main(["view", "--mesh", str(d / "panel.xyz"), "--values", str(d / "surf.csv"),
               "--cmap", "nosuch", "--out", str(d / "v.png")])
    assert rc == 2 and "colour map 'nosuch'" in capsys.readouterr().err
