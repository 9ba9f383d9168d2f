"""``resection map / backproject / align / view`` end to end on files, checked against
closed-form plane geometry."""
import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest

from resection.cli.main import main
from resection.io.cameras import write_camera
from resection.io.meshes import write_plot3d
from scenes.psp_pair import HALF_X, HALF_Y, plane_hits, psp_pair, render


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli_surface")
    pp = psp_pair(width=160, height=120, noise=0.0)
    xs, ys = np.linspace(-HALF_X, HALF_X, 25), np.linspace(-HALF_Y, HALF_Y, 17)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    write_plot3d(d / "panel.xyz", [np.stack([X, Y, np.zeros_like(X)], axis=-1)], binary=False)
    write_camera(d / "off.json", pp.camera_off)
    write_camera(d / "on.json", pp.camera_on)
    P, on = plane_hits(pp.camera_off)
    np.save(d / "xcoord.npy", np.where(on, P[..., 0], np.nan))
    np.save(d / "tex.npy", render(pp.camera_on))
    return d, pp, P, on


def _surface_values(d):
    """A field file of the panel made here (``map``), so that a test run on its own does
    not depend on the ``surf.csv`` that test_map_then_backproject writes."""
    path = d / "surf_own.csv"
    if not path.exists():
        assert main(["map", "--mesh", str(d / "panel.xyz"), "--camera", str(d / "off.json"),
                     "--image", str(d / "xcoord.npy"), "--out", str(path)]) == 0
    return path


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
    rc = main(["view", "--mesh", str(d / "panel.xyz"), "--values", str(_surface_values(d)),
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
    rc = main(["view", "--mesh", str(d / "panel.xyz"), "--values", str(_surface_values(d)),
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
    rc = main(["view", "--mesh", str(d / "panel.xyz"), "--values", str(_surface_values(d)),
               "--cmap", "nosuch", "--out", str(d / "v.png")])
    assert rc == 2 and "colour map 'nosuch'" in capsys.readouterr().err


def test_map_max_obliqueness(tmp_path, capsys):
    """The slab's -y edge is seen at about 76 degrees (closed form below): unseen by default
    (70), seen with --max-obliqueness 90; a cut-off outside (0, 90] is a one-line error."""
    import trimesh

    from resection import Camera

    box = trimesh.creation.box(extents=(1.0, 0.6, 0.05))
    v, f = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(box.vertices, box.faces))
    trimesh.Trimesh(v, f, process=False).export(tmp_path / "slab.stl")
    K = [[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]
    cam = Camera.look_at([0.0, -0.8, 2.0], [0.0, 0.0, 0.0], [0, 1, 0], K=K, width=320,
                         height=240)
    write_camera(tmp_path / "cam.json", cam)
    np.save(tmp_path / "img.npy", np.ones((240, 320)))
    # angle between the -y side's normal and the view from its centre line (y = -0.3)
    side_angle = np.degrees(np.arctan2(2.0, 0.5))
    assert 75.0 < side_angle < 77.0
    counts = {}
    for opt in ([], ["--max-obliqueness", "90"]):
        out = tmp_path / f"surf{len(opt)}.csv"
        rc = main(["map", "--mesh", str(tmp_path / "slab.stl"), "--camera",
                   str(tmp_path / "cam.json"), "--image", str(tmp_path / "img.npy"),
                   "--out", str(out)] + opt)
        assert rc == 0
        df = pd.read_csv(out)
        side = np.isclose(df["cy"], -0.3)
        counts[len(opt)] = int(df["img_count"][side].sum())
        top = np.isclose(df["cz"], 0.025)
        assert df["img_seen"][top].sum() == top.sum() == 32
    assert counts[0] == 0 and counts[2] > 20
    rc = main(["map", "--mesh", str(tmp_path / "slab.stl"), "--camera",
               str(tmp_path / "cam.json"), "--image", str(tmp_path / "img.npy"),
               "--out", str(tmp_path / "bad.csv"), "--max-obliqueness", "95"])
    err = capsys.readouterr().err
    assert rc == 2 and "max_obliqueness" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "bad.csv").exists()
