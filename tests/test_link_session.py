"""Linking by clicking without a browser: the session's answers, the server's rules, the
command line, and the way in from an internal calibration (issue 24, issue 20 item 13).

The frame is the real-looking one of :mod:`scenes.real_traits` (camera 0); the truth is the
scene's (true target positions in the image, the true camera). The browser test is
``tests/test_link_page.py``.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import urllib.error
import urllib.request

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from resection.camera.model import Camera
from resection.cli import main
from resection.errors import InputError, SolveError
from resection.io.cameras import read_camera, write_camera
from resection.markers.detect import Candidates
from resection.markers.link import numbered, read_links
from resection.markers.link_server import serve_links
from resection.markers.link_session import open_session, plan_axes
from scenes.real_traits import real_traits, write_scene

START = ("T01", "T04", "T09", "T14")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    s = real_traits(scale=1.0)
    folder = tmp_path_factory.mktemp("link_session")
    paths = write_scene(s, folder)
    paths["intrinsics"] = str(folder / "internal.json")  # uPSP file without rmat/tvec
    write_camera(paths["intrinsics"], s.cameras[0], format="upsp", intrinsics_only=True)
    paths["identity"] = str(folder / "identity.json")  # the same, as the package's JSON
    write_camera(paths["identity"], read_camera(paths["intrinsics"]))
    return s, paths


def _session(paths, tmp_path, camera="intrinsics", **kw):
    return open_session(paths["image0"], paths["markers"], paths[camera], diameter=5.0,
                        save_links=tmp_path / "links.csv", save_camera=tmp_path / "cam.json",
                        **kw)


def _truth(session, s):
    """Candidate number of each target camera 0 sees (within 1 px of its true position)."""
    d, j = cKDTree(session.candidates.uv).query(np.nan_to_num(s.uv[0], nan=-1e6))
    return {k: int(j[i]) for i, k in enumerate(s.marker_ids) if d[i] < 1.0}


def test_four_links_give_the_pose_predictions_and_right_offers(scene, tmp_path):
    s, paths = scene
    ses = _session(paths, tmp_path)
    truth = _truth(ses, s)
    assert len(truth) >= 12
    for n in range(1, 4):  # no approximate pose: four links are needed
        r = ses.solve([[k, truth[k]] for k in START[:n]])
        assert r["status"] == "waiting" and not r["predicted"] and not r["offers"]
    r = ses.solve([[k, truth[k]] for k in START])
    assert r["status"] == "accepted", r["message"]
    assert all(lk["residual"] < 2.0 and not lk["rejected"] for lk in r["links"])
    # every other target seen is predicted within 2.5 px of its true position
    pred = {p["id"]: (p["u"], p["v"]) for p in r["predicted"]}
    rest = set(truth) - set(START)
    assert rest <= set(pred)
    for k in rest:
        assert np.hypot(*(np.subtract(pred[k], s.uv[0][s.marker_ids.index(k)]))) < 2.5
    # every offer is the true candidate, and every other target found is offered
    offers = {o["id"]: o["candidate"] for o in r["offers"]}
    assert offers == {k: truth[k] for k in rest}
    assert r["gate"] > 0 and all(o["distance"] <= r["gate"] for o in r["offers"])
    # the plan, as the camera sees it: the solved pose's normalised coordinates
    cam = read_camera(paths["camera0"])
    xy = np.array(r["plan"]["xy"], float)
    xc = cam.to_camera_frame(s.surveyed)
    np.testing.assert_allclose(xy, xc[:, :2] / xc[:, 2:], atol=0.01)


def test_a_wrong_link_is_marked_rejected_and_nothing_is_saved(scene, tmp_path):
    s, paths = scene
    ses = _session(paths, tmp_path)
    truth = _truth(ses, s)
    wrong = [[k, truth[k]] for k in START] + [["T07", truth["T10"]]]
    r = ses.solve(wrong)
    assert r["status"] == "refused"
    assert [lk["id"] for lk in r["links"] if lk["rejected"]] == ["T07"]
    assert "T07" in r["message"]
    with pytest.raises(SolveError, match="nothing saved"):
        ses.save(wrong)
    assert not (tmp_path / "links.csv").exists() and not (tmp_path / "cam.json").exists()
    with pytest.raises(InputError, match="linked twice"):
        ses.solve([["T01", 0], ["T02", 0]])
    with pytest.raises(InputError, match="unknown target"):
        ses.solve([["NOPE", 0]])


def test_three_links_with_an_approximate_pose(scene, tmp_path):
    s, paths = scene
    true = s.cameras[0]
    rot = Rotation.from_rotvec([0.01, -0.008, 0.005]).as_matrix()  # about 0.8 degree off
    approx = true.with_pose(R=rot @ true.R, t=true.t + [0.01, -0.005, 0.01])
    write_camera(tmp_path / "approx.json", approx)
    ses = open_session(paths["image0"], paths["markers"], tmp_path / "approx.json",
                       save_links=tmp_path / "l.csv")
    assert ses.has_pose and 3 < ses.diameter < 7  # from the marker file through the pose
    truth = _truth(ses, s)
    assert ses.solve([[k, truth[k]] for k in START[:2]])["status"] == "waiting"
    r = ses.solve([[k, truth[k]] for k in START[:3]])
    assert r["status"] == "accepted", r["message"]
    assert max(lk["residual"] for lk in r["links"]) < 1e-6  # exact: no redundancy
    cam = Camera.from_dict(r["camera"])
    assert np.linalg.norm(cam.center - true.center) < 0.02 * np.linalg.norm(true.center)


def test_save_writes_what_pose_and_track_read(scene, tmp_path, capsys):
    """Save after four links; ``pose --image --links`` then finds every other target in
    view again (the intrinsics-only camera file is enough with links) and lists the ones it
    did not use."""
    s, paths = scene
    ses = _session(paths, tmp_path, save_linked=tmp_path / "linked.csv")
    truth = _truth(ses, s)
    out = ses.save([[k, truth[k]] for k in START])
    assert out["written"] == ["links.csv", "cam.json", "linked.csv"]
    ids, uv, index = read_links(tmp_path / "links.csv", ses.candidates)
    assert ids == START and list(index) == [truth[k] for k in START]
    # four links surveyed to 0.5-1.5 px: the pose predicts every seen target within 4 px
    cam = read_camera(tmp_path / "cam.json")
    seen = [s.marker_ids.index(k) for k in truth]
    assert np.linalg.norm(cam.project(s.markers[seen]) - s.uv[0][seen], axis=1).max() < 4.0
    rc = main(["pose", "--image", paths["image0"], "--markers", paths["markers"], "--camera",
               paths["intrinsics"], "--links", str(tmp_path / "links.csv"), "--diameter", "5",
               "--out", str(tmp_path / "posed.json")])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    m = re.search(r"targets: (\d+) used \((\d+) found again\) of (\d+) expected", printed)
    assert m, printed
    used, again = int(m.group(1)), int(m.group(2))
    in_view = np.isfinite(s.uv[0]).all(axis=1) & s.cameras[0].in_image(np.nan_to_num(s.uv[0]))
    assert used == int(in_view.sum()) == 15  # TE, cut by the border, found in its window too
    assert again == used - len(START)
    # the ones not used are listed with why (those off the image here)
    for k in set(s.marker_ids) - set(truth) - {"TE"}:
        assert re.search(rf"^\s+{k}: ", printed, re.M), (k, printed)
    # track reads the same linking file (candidate numbers of the same detection) and the
    # saved camera: its first frame is linked by hand and solved with every target seen
    from resection.sequence import track

    res = track([paths["image0"]], cam, paths["markers"], link=str(tmp_path / "links.csv"),
                diameter=5.0, out_dir=tmp_path / "track", workers=1, progress=False)
    assert res.ok.all(), res.reason
    got = res.marker_positions(list(START))[0]
    np.testing.assert_allclose(got, ses.candidates.uv[[truth[k] for k in START]], atol=0.05)


def test_outputs_never_overwrite_inputs(scene, tmp_path):
    _, paths = scene
    with pytest.raises(InputError, match="refusing to overwrite"):
        open_session(paths["image0"], paths["markers"], paths["intrinsics"], diameter=5.0,
                     save_links=paths["markers"])
    with pytest.raises(InputError, match="no pose.*--diameter"):
        open_session(paths["image0"], paths["markers"], paths["intrinsics"],
                     save_links=tmp_path / "l.csv")


def _get(url, headers=None, data=None):
    req = urllib.request.Request(url, headers=headers or {}, data=data)
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def test_server_answers_only_with_its_token_on_loopback(scene, tmp_path):
    s, paths = scene
    ses = _session(paths, tmp_path)
    truth = _truth(ses, s)
    server = serve_links(ses)
    try:
        host, port = server.server_address
        assert host == "127.0.0.1"
        base = f"http://127.0.0.1:{port}"
        tok = server.token
        assert len(tok) >= 24
        assert _get(server.url)[0] == 200
        assert _get(base + "/")[0] == 403  # no token
        assert _get(base + "/api/session?token=wrong")[0] == 403
        # a page of another site reaching the port through its own host name is refused
        assert _get(f"{base}/api/session?token={tok}", {"Host": f"evil.example:{port}"})[0] \
            == 403
        # no path from the browser: only the page's own files and the endpoints
        for p in ("/../pyproject.toml", "/link_page/index.html", "/etc/passwd",
                  "/api/frame/../../x"):
            assert _get(f"{base}{p}?token={tok}")[0] == 404, p
        st, body = _get(f"{base}/api/session", {"X-Link-Token": tok})
        info = json.loads(body)
        assert st == 200 and info["width"] == 320 and info["has_pose"] is False
        st, body = _get(f"{base}/api/frame", {"X-Link-Token": tok})
        assert st == 200 and len(body) == 2 * 320 * 240
        frame = np.frombuffer(body, "<u2").reshape(240, 320).astype(float)
        img = s.images[0].astype(float)
        assert np.corrcoef(frame[img < 255], img[img < 255])[0, 1] > 0.999
        links = json.dumps({"links": [[k, truth[k]] for k in START]}).encode()
        hdr = {"X-Link-Token": tok, "Content-Type": "application/json"}
        st, body = _get(f"{base}/api/solve", hdr, links)
        assert st == 200 and json.loads(body)["status"] == "accepted"
        assert _get(f"{base}/api/solve", hdr, b"not json")[0] == 400
        assert _get(f"{base}/api/solve", {"Content-Type": "application/json"}, links)[0] == 403
        st, body = _get(f"{base}/api/save", hdr, json.dumps({"links": [["T01", 0]]}).encode())
        assert st == 409 and "nothing saved" in json.loads(body)["error"]
    finally:
        server.shutdown()
        server.server_close()


def test_link_serve_command(scene, tmp_path):
    """``resection link --serve`` prints the page's address, serves it, stops on SIGINT."""
    _, paths = scene
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
         os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "resection.cli", "link", "--serve", paths["image0"],
           "--markers", paths["markers"], "--camera", paths["intrinsics"], "--diameter", "5",
           "--save-links", str(tmp_path / "l.csv"), "--pose", str(tmp_path / "c.json")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        assert "candidates" in lines[0] and "without a pose" in lines[0], lines
        url = lines[1].split()[-1]
        assert url.startswith("http://127.0.0.1:") and "token=" in url
        st, body = _get(url)
        assert st == 200 and b"link.js?token=" in body
    finally:
        proc.send_signal(2)
        proc.wait(timeout=20)
    assert proc.returncode == 130  # Ctrl+C: as every command (issue 34 item 18)
    # bad input: one line, exit 2
    r = subprocess.run(cmd[:-4], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 2 and "--save-links" in r.stderr and len(r.stderr.splitlines()) == 1
    r = subprocess.run([*cmd[:12], "--save-links", paths["image0"]], capture_output=True,
                       text=True, env=env, timeout=60)
    assert r.returncode == 2 and "refusing to overwrite" in r.stderr


@pytest.mark.parametrize("camera", ["intrinsics", "identity"])
@pytest.mark.parametrize("diameter", [[], ["--diameter", "5"]])
@pytest.mark.parametrize("mesh", [False, True])
def test_pose_names_a_camera_without_a_pose(scene, tmp_path, capsys, camera, diameter, mesh):
    """Issue 20 item 13: not 'marker diameter unknown' nor 'camera facing away?'. With
    --mesh the markers are read (and moved onto the surface) before the check: the message
    still names their file, not a placeholder."""
    _, paths = scene
    extra = ["--mesh", paths["grid"]] if mesh else []
    rc = main(["pose", "--image", paths["image0"], "--markers", paths["markers"], "--camera",
               paths[camera], "--out", str(tmp_path / "o.json"), *diameter, *extra])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.splitlines()) == 1
    assert f"{paths[camera]}: this camera has no pose" in err
    assert "resection link --serve" in err and paths["markers"] in err
    assert "MARKERS" not in err
    assert "diameter unknown" not in err and "facing away" not in err
    assert not (tmp_path / "o.json").exists()


def test_pose_with_links_and_no_diameter_asks_for_it(scene, tmp_path, capsys):
    s, paths = scene
    ses = _session(paths, tmp_path)
    truth = _truth(ses, s)
    ses.save([[k, truth[k]] for k in START])
    rc = main(["pose", "--image", paths["image0"], "--markers", paths["markers"], "--camera",
               paths["intrinsics"], "--links", str(tmp_path / "links.csv"), "--out",
               str(tmp_path / "o.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "has no pose" in err and "--diameter PX" in err
    assert "diameter unknown" not in err


def test_plan_axes_look_from_the_normals_side():
    """The plan of points on z = 0 with normals +z is seen from +z: x right, y up (a
    camera above looking down with y up in the image), never mirrored."""
    rng = np.random.default_rng(1)
    X = np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-0.3, 0.3, 30), np.zeros(30)])
    A = plan_axes(X, np.tile([0, 0, 1.0], (30, 1)))
    view = np.cross(A[0], A[1])
    np.testing.assert_allclose(view, [0, 0, -1], atol=1e-12)  # looking down -z
    assert abs(A[0] @ [1, 0, 0]) > 0.99  # the long side across
    A2 = plan_axes(X, np.tile([0, 0, -1.0], (30, 1)))  # from below: mirrored x or y
    np.testing.assert_allclose(np.cross(A2[0], A2[1]), [0, 0, 1], atol=1e-12)


def test_png_numbers_only_what_can_be_read(scene, tmp_path):
    """Item 5: with a camera, only candidates near a projected target are numbered; without,
    the candidates the detector ranks unlikely (SNR < 5) are left out, the rest capped."""
    from resection.markers.link import LIKELY_SNR, MAX_LABELS, draw_links

    s, paths = scene
    cam = s.cameras[0]
    rng = np.random.default_rng(3)
    true_uv = s.uv[0][np.isfinite(s.uv[0]).all(axis=1)]
    true_uv = true_uv[cam.in_image(true_uv)]
    noise_uv = rng.uniform([0, 0], [319, 239], (400, 2))  # a speckled paint's tangle
    uv = np.vstack([true_uv, noise_uv])
    snr = np.concatenate([np.full(len(true_uv), 60.0), rng.uniform(3, 12, 400)])
    cand = Candidates(u=uv[:, 0], v=uv[:, 1], diameter=np.full(len(uv), 5.0),
                      depth=snr, merit=snr, snr=snr)
    from resection.io.markers import read_markers

    ms = read_markers(paths["markers"])
    near = numbered(cand, camera=cam, markers=ms)
    proj = cam.project(ms.xyz)
    proj = proj[cam.in_image(proj)]
    d = cKDTree(proj).query(uv)[0]
    np.testing.assert_array_equal(near, np.flatnonzero(d <= 15.0))
    assert set(range(len(true_uv))) <= set(near.tolist()) and len(near) < 0.5 * len(uv)
    likely = numbered(cand)
    assert len(likely) <= MAX_LABELS and np.all(cand.snr[likely] >= LIKELY_SNR)
    assert set(range(len(true_uv))) <= set(likely.tolist())  # the strongest are kept
    img = s.images[0].astype(float)
    drawn = draw_links(tmp_path / "a.png", img, cand)
    np.testing.assert_array_equal(drawn, likely)
    import imageio.v3 as iio

    png = iio.imread(tmp_path / "a.png")
    assert png.shape[1] > 1600  # enlarged until the drawn candidates lie two labels apart
    drawn = draw_links(tmp_path / "b.png", img, cand, camera=cam, markers=ms)
    np.testing.assert_array_equal(drawn, near)


def test_the_page_is_package_data():
    """A non-editable install ships the page: every file of ``link_page/`` matches the
    package-data globs of pyproject.toml, and the server reads them through the package."""
    import fnmatch
    import tomllib
    from pathlib import Path

    from resection.markers import link_server

    root = Path(__file__).resolve().parents[1]
    conf = tomllib.loads((root / "pyproject.toml").read_text())
    globs = conf["tool"]["setuptools"]["package-data"]["resection.markers"]
    page = Path(link_server.__file__).parent / "link_page"
    files = sorted(p.name for p in page.iterdir() if p.is_file())
    assert files == sorted(link_server.PAGE_FILES)
    for name in files:
        assert any(fnmatch.fnmatch(f"link_page/{name}", g) for g in globs), name
        assert link_server._page_file(name) == (page / name).read_bytes()


def _segment_meets_box(C, P, lo, hi) -> bool:
    """Closed form (slab method): does the segment C -> P cross the box [lo, hi] before P?"""
    d = np.asarray(P, float) - C
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - C) / d, (hi - C) / d
    tmin, tmax = np.max(np.minimum(t1, t2)), np.min(np.maximum(t1, t2))
    return bool(tmin < tmax and 0 < tmax and tmin < 0.999)


def test_targets_hidden_by_the_mesh_are_not_predicted(scene, tmp_path):
    """With ``--mesh``, a target behind the black block (hidden from camera 0 by the slab
    test, yet inside its image) is neither predicted nor offered; without it, it is."""
    from resection.io.markers import read_markers, write_markers
    from scenes.real_traits import BOX

    s, paths = scene
    ms = read_markers(paths["markers"])
    hidden = np.array([0.045, 0.04, 0.0])
    a, b, h = BOX
    cam = s.cameras[0]
    assert _segment_meets_box(cam.center, hidden, np.array([-a, -b, 0]), np.array([a, b, h]))
    assert cam.in_image(cam.project(hidden[None]))[0]
    write_markers(tmp_path / "m.csv", [*ms.ids, "TH"], np.vstack([ms.xyz, hidden]),
                  np.append(ms.diameter, 0.006))
    common = dict(diameter=5.0, save_links=tmp_path / "l.csv")
    plain = open_session(paths["image0"], tmp_path / "m.csv", paths["intrinsics"], **common)
    meshed = open_session(paths["image0"], tmp_path / "m.csv", paths["intrinsics"],
                          mesh=paths["grid"], **common)
    truth = _truth(plain, s)
    links = [[k, truth[k]] for k in START]
    p0 = {p["id"] for p in plain.solve(links)["predicted"]}
    p1 = {p["id"] for p in meshed.solve(links)["predicted"]}
    assert "TH" in p0 and p0 - p1 == {"TH"}


def test_a_taken_port_is_one_line(scene, tmp_path):
    _, paths = scene
    ses = _session(paths, tmp_path)
    server = serve_links(ses)
    try:
        from resection.markers.link_server import LinkServer

        with pytest.raises(InputError, match=r"port \d+: cannot listen on 127.0.0.1"):
            LinkServer(ses, server.server_address[1])
    finally:
        server.shutdown()
        server.server_close()


def test_links_that_cannot_give_a_pose_are_refused_not_an_error(scene, tmp_path):
    """Four links on one line of targets: the page is told why, nothing breaks."""
    from resection.io.markers import write_markers

    s, paths = scene
    ids = ["L1", "L2", "L3", "L4"]
    xyz = np.array([[-0.2, -0.1, 0.0], [-0.1, -0.1, 0.0], [0.0, -0.1, 0.0], [0.1, -0.1, 0.0]])
    write_markers(tmp_path / "line.csv", ids, xyz, np.full(4, 0.006))
    ses = open_session(paths["image0"], tmp_path / "line.csv", paths["intrinsics"],
                       diameter=5.0, save_links=tmp_path / "l.csv")
    r = ses.solve([[k, i] for i, k in enumerate(ids)])
    assert r["status"] == "refused" and "collinear" in r["message"], r["message"]
    assert not r["predicted"] and not r["offers"]


def test_link_png_with_a_camera_without_a_pose(scene, tmp_path, capsys):
    """``link --png`` with an internal calibration numbers the likely candidates (not the few
    near targets projected through the identity pose); ``--suggest`` names the missing pose."""
    s, paths = scene
    ses = _session(paths, tmp_path)
    from resection.markers.detect import write_candidates

    write_candidates(tmp_path / "c.csv", ses.candidates)
    base = ["link", paths["image0"], "--candidates", str(tmp_path / "c.csv"), "--camera",
            paths["intrinsics"], "--markers", paths["markers"]]
    assert main([*base, "--png", str(tmp_path / "a.png")]) == 0
    assert "has no pose" in capsys.readouterr().out
    assert (tmp_path / "a.png").stat().st_size > 0
    rc = main([*base, "--suggest", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "this camera has no pose" in err and "link --serve" in err
    assert not (tmp_path / "s.csv").exists()
