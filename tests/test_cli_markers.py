"""``resection detect / link / match`` and ``resection pose --image``, end to end on a
synthetic image whose markers sit at the exact projections of a known camera."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from resection.camera.model import Camera
from resection.cli.main import main
from resection.io.cameras import read_camera, write_camera
from resection.io.images import write_image
from resection.io.markers import write_markers
from resection.markers.detect import read_candidates
from resection.markers.link import read_links
from scenes.marker_images import render_markers

K = [[1200.0, 0, 320], [0, 1200.0, 240], [0, 0, 1]]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("markers_cli")
    rng = np.random.default_rng(42)
    n = 24
    xyz = np.column_stack([rng.uniform(-0.2, 0.2, n), rng.uniform(-0.14, 0.14, n),
                           rng.uniform(0.0, 0.05, n)])
    ids = [f"T{k}" for k in range(n)]
    true = Camera.look_at([0.05, -0.1, 1.0], [0, 0, 0], [0, 1, 0], K=K, width=640, height=480)
    uv = true.project(xyz)
    spurious = np.column_stack([rng.uniform(20, 620, 12), rng.uniform(20, 460, 12)])
    keep = np.min(np.hypot(*(spurious[:, None] - uv[None]).transpose(2, 0, 1)), axis=1) > 15
    img = render_markers((480, 640), np.vstack([uv, spurious[keep]]), 6.0, contrast=80,
                         background=600, blur=0.7, snr=40, rng=1, dtype=np.uint16)
    write_image(d / "img.tif", img)
    write_markers(d / "markers.csv", ids, xyz, np.full(n, 0.005))
    dR = Rotation.from_rotvec([0.004, -0.003, 0.002]).as_matrix()
    approx = true.with_pose(R=dR @ true.R, t=true.t + [0.003, -0.002, 0.004])
    write_camera(d / "approx.json", approx)
    return {"dir": d, "ids": ids, "xyz": xyz, "uv": uv, "true": true}


def _run(args, capsys):
    rc = main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out.out, out.err


def _candidates(d, capsys):
    """A candidate file of the scene's image made here, so that a test run on its own
    does not depend on the file another test writes."""
    path = d / "c_own.csv"
    if not path.exists():
        rc, _, _ = _run(["detect", d / "img.tif", "--diameter", 6, "-o", path], capsys)
        assert rc == 0
    return path


def test_detect_match_link_pose(scene, capsys):
    d = scene["dir"]
    rc, out, _ = _run(["detect", d / "img.tif", "--diameter", 6, "-o", d / "c.csv"], capsys)
    assert rc == 0 and "candidates" in out
    cand, ids = read_candidates(d / "c.csv")
    assert ids is None and len(cand) >= len(scene["uv"])
    # every true marker found within 0.05 px
    dist = np.min(np.hypot(*(cand.uv[:, None] - scene["uv"][None]).transpose(2, 0, 1)), axis=0)
    assert dist.max() < 0.05

    # with enhancement and a roi: the same markers inside the box
    rc, out, _ = _run(["detect", d / "img.tif", "--diameter", 6, "--enhance", "background",
                       "--roi", 0, 0, 319, 479, "-o", d / "c_roi.csv"], capsys)
    assert rc == 0
    c_roi, _ = read_candidates(d / "c_roi.csv")
    left = scene["uv"][scene["uv"][:, 0] < 312]
    dist = np.min(np.hypot(*(c_roi.uv[:, None] - left[None]).transpose(2, 0, 1)), axis=0)
    assert dist.max() < 0.05 and np.all(c_roi.u < 320)

    rc, out, _ = _run(["match", "--candidates", d / "c.csv", "--markers", d / "markers.csv",
                       "--camera", d / "approx.json", "-o", d / "m.csv", "--pose",
                       d / "pose.json"], capsys)
    assert rc == 0, out
    m, mids = read_candidates(d / "m.csv")
    assert len(mids) == len(scene["ids"])
    truth = dict(zip(scene["ids"], scene["uv"], strict=True))
    assert all(np.hypot(*(p - truth[k])) < 0.05 for k, p in zip(mids, m.uv, strict=True))
    cam = read_camera(d / "pose.json")
    assert np.abs(cam.project(scene["xyz"]) - scene["uv"]).max() < 0.05

    # match against the previous frame
    rc, out, _ = _run(["match", "--candidates", d / "c.csv", "--markers", d / "markers.csv",
                       "--reference", d / "m.csv", "-o", d / "m2.csv"], capsys)
    assert rc == 0
    assert read_candidates(d / "m2.csv")[1] == mids

    # linking by hand: drawing, suggestion, reading
    rc, out, _ = _run(["link", d / "img.tif", "--candidates", d / "c.csv", "--camera",
                       d / "approx.json", "--markers", d / "markers.csv", "--png",
                       d / "link.png", "--suggest", d / "links.csv"], capsys)
    assert rc == 0
    import imageio.v3 as iio

    png = iio.imread(d / "link.png")[..., :3].astype(int)
    assert png.shape[0] >= 480 and png.shape[1] >= 640
    # every candidate's ring is drawn (orange-red) where the candidate is, every projected
    # marker's cross (cyan) where the approximate camera puts it
    sc = png.shape[1] / 640.0
    red = (png[..., 0] > 200) & (png[..., 1] < 130) & (png[..., 2] < 80)
    cyan = (png[..., 0] < 90) & (png[..., 1] > 200) & (png[..., 2] > 200)

    def near(mask, u, v, r):
        r0, c0 = int((v + 0.5) * sc), int((u + 0.5) * sc)
        return mask[max(r0 - r, 0):r0 + r + 1, max(c0 - r, 0):c0 + r + 1].any()

    ring = cand.diameter / 2 + 2.0
    assert all(near(red, u + r, v, 3) for (u, v), r in zip(cand.uv, ring, strict=True))
    proj = read_camera(d / "approx.json").project(scene["xyz"])
    assert all(near(cyan, u, v, 2) for u, v in proj)
    assert red.mean() < 0.05 and cyan.mean() < 0.05  # marks, not a painted-over image
    lids, luv, _ = read_links(d / "links.csv", cand)
    assert set(lids) == set(scene["ids"])
    assert all(np.hypot(*(p - truth[k])) < 0.05 for k, p in zip(lids, luv, strict=True))
    rc, out, _ = _run(["link", d / "img.tif", "--candidates", d / "c.csv", "--links",
                       d / "links.csv", "-o", d / "linked.csv"], capsys)
    assert rc == 0 and "thrown away" in out
    linked, lk = read_candidates(d / "linked.csv")
    assert len(lk) == len(scene["ids"]) < len(cand)

    # pose straight from the image: automatic matching, then from the linking file
    for extra in ([], ["--links", d / "links.csv", "--candidates", d / "c.csv"]):
        rc, out, err = _run(["pose", "--camera", d / "approx.json", "--markers",
                             d / "markers.csv", "--image", d / "img.tif", "--out",
                             d / "p.json", *extra], capsys)
        assert rc == 0, err
        cam = read_camera(d / "p.json")
        assert np.abs(cam.project(scene["xyz"]) - scene["uv"]).max() < 0.05


def test_cli_errors(scene, capsys):
    d = scene["dir"]
    c = _candidates(d, capsys)
    rc, _, err = _run(["detect", d / "none.tif", "--diameter", 6, "-o", d / "x.csv"], capsys)
    assert rc == 2 and "none.tif" in err
    rc, _, err = _run(["detect", d / "img.tif", "--diameter", -6, "-o", d / "x.csv"], capsys)
    assert rc == 2 and "diameter" in err
    rc, _, err = _run(["match", "--candidates", c, "--markers", d / "markers.csv",
                       "-o", d / "x.csv"], capsys)
    assert rc == 2 and "--camera" in err
    bad = d / "bad_links.csv"
    bad.write_text("id,candidate\nT0,99999\n")
    rc, _, err = _run(["link", d / "img.tif", "--candidates", c, "--links", bad,
                       "-o", d / "x.csv"], capsys)
    assert rc == 2 and "99999" in err
    bad.write_text("id,candidate\nT0,1\nT0,2\n")
    rc, _, err = _run(["link", d / "img.tif", "--candidates", c, "--links", bad,
                       "-o", d / "x.csv"], capsys)
    assert rc == 2 and "twice" in err
    # spurious-only candidates: matching refuses, pose --image refuses
    (d / "junk.csv").write_text("u,v\n10,10\n200,30\n400,400\n100,300\n")
    rc, _, err = _run(["match", "--candidates", d / "junk.csv", "--markers", d / "markers.csv",
                       "--camera", d / "approx.json", "-o", d / "x.csv"], capsys)
    assert rc == 2 and "match_markers" in err


def test_cli_image_size_saturation_and_enhance_windows(scene, capsys):
    import tifffile

    d = scene["dir"]
    img = tifffile.imread(d / "img.tif")
    # an image of another size than the camera's is refused, not silently solved
    tifffile.imwrite(d / "half.tif", img[:, :320])
    rc, _, err = _run(["pose", "--camera", d / "approx.json", "--markers", d / "markers.csv",
                       "--image", d / "half.tif", "--out", d / "x.json"], capsys)
    assert rc == 2 and "320x480" in err and "640x480" in err
    tifffile.imwrite(d / "t.tif", np.ascontiguousarray(img.T))
    rc, _, err = _run(["link", d / "t.tif", "--candidates", _candidates(d, capsys), "--camera",
                       d / "approx.json", "--markers", d / "markers.csv", "--png",
                       d / "x.png"], capsys)
    assert rc == 2 and "480x640" in err
    # saturated pixels of a 16-bit file are masked and counted
    sat = img.copy()
    sat[400:410, 600:630] = 65535
    tifffile.imwrite(d / "sat.tif", sat)
    rc, out, _ = _run(["detect", d / "sat.tif", "--diameter", 6, "-o", d / "cs.csv"], capsys)
    assert rc == 0 and "300 masked pixels" in out
    # enhancement inside windows: only markers wholly inside a window are found
    rc, out, _ = _run(["detect", d / "img.tif", "--diameter", 6, "--enhance", "background",
                       "--enhance-window", 0, 0, 299, 239, "--enhance-window", 340, 240,
                       639, 479, "-o", d / "cw.csv"], capsys)
    assert rc == 0
    cw, _ = read_candidates(d / "cw.csv")
    uv = scene["uv"]
    inside = (((uv[:, 0] <= 293) & (uv[:, 1] <= 233))
              | ((uv[:, 0] >= 346) & (uv[:, 1] >= 246)))
    assert inside.sum() >= 5
    dist = np.min(np.hypot(*(cw.uv[:, None] - uv[inside][None]).transpose(2, 0, 1)), axis=0)
    assert dist.max() < 0.05
    in_win = ((cw.u <= 299.5) & (cw.v <= 239.5)) | ((cw.u >= 339.5) & (cw.v >= 239.5))
    assert np.all(in_win)
    rc, _, err = _run(["detect", d / "img.tif", "--diameter", 6, "--enhance-window", 0, 0, 9,
                       9, "-o", d / "x.csv"], capsys)
    assert rc == 2 and "enhancement method" in err


def test_pose_image_with_enhance_windows_and_links_need_image(scene, capsys):
    d = scene["dir"]
    # pose --image with enhancement restricted to a window covering the whole model: the
    # pose is right (every marker found inside the window, markers cut by it dropped)
    rc, out, err = _run(["pose", "--camera", d / "approx.json", "--markers", d / "markers.csv",
                         "--image", d / "img.tif", "--enhance", "background",
                         "--enhance-window", 0, 0, 639, 479, "--out", d / "pw.json"], capsys)
    assert rc == 0, err
    cam = read_camera(d / "pw.json")
    assert np.abs(cam.project(scene["xyz"]) - scene["uv"]).max() < 0.05
    # a window without a method is refused by the same rule as for detect
    rc, _, err = _run(["pose", "--camera", d / "approx.json", "--markers", d / "markers.csv",
                       "--image", d / "img.tif", "--enhance-window", 0, 0, 99, 99,
                       "--out", d / "x.json"], capsys)
    assert rc == 2 and "enhancement method" in err
    # --links without --image names what is missing
    rc, _, err = _run(["pose", "--camera", d / "approx.json", "--markers", d / "markers.csv",
                       "--links", d / "links.csv", "--out", d / "x.json"], capsys)
    assert rc == 2 and "--image" in err


def test_link_png_without_a_camera_draws_the_candidates(scene, capsys):
    """``link --png`` with candidates only (no camera, no markers) used to exit 0 and write
    nothing; the PNG must be written, and be a picture of the image (read back by
    imageio, an independent PNG reader) at least as large as the frame."""
    import imageio.v3 as iio

    d = scene["dir"]
    png = d / "numbered.png"
    rc, out, err = _run(["link", d / "img.tif", "--candidates", _candidates(d, capsys),
                         "--png", png], capsys)
    assert rc == 0, err
    assert f"drawing written to {png}" in out
    picture = iio.imread(png)
    assert picture.ndim == 3 and picture.shape[0] >= 480 and picture.shape[1] >= 640
    assert picture[..., :3].std() > 1.0  # not a blank page
