"""Fault cases (issue 10 and later): each test drives the CLI or the API as a user would
and checks that a bad or surprising input ends in a clear decision (a one-line error with
exit status 2, a warning, or a refusal), never a traceback, a lost file or a silently wrong
answer. One section per fault family; the families of files read, outputs written and
`track` runs are in tests/test_faults_files.py, test_faults_outputs.py and
test_faults_track.py."""

from __future__ import annotations

import numpy as np
import pytest
from fault_files import corner_files

from resection import InputError
from resection.io.cameras import write_camera

# --------------------------------------------------------------------------------------
# Decisions on computed floats: a stated tolerance, not the sign of a rounding error
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("tiny", [2.2e-16, -2.2e-16, 4.4e-16, -4.4e-16, 0.0])
def test_constant_ratio_is_not_significant_whatever_the_rounding(tiny):
    """A ratio that does not vary with the pressure is 'not significant', whether the
    least-squares slope comes out as +1e-16, -1e-16 or exactly 0 (the CI failure of
    issue 10 item 1 was B = -8.3e-17 read as 'negative')."""
    from selfillum.images.psp import fit_stern_volmer

    p = np.array([80.0, 95.0, 110.0, 130.0])
    # the ratio is 1 up to one or two units in the last place, growing or falling with p:
    # the fitted slope has that rounding's sign, and the decision must not depend on it
    ratio = 1.0 + tiny * (p - p.min()) / np.ptp(p)
    with pytest.raises(InputError, match="not significantly") as err:
        fit_stern_volmer(ratio, p, 100.0)
    assert "must grow" not in str(err.value)
    # two taps: no scatter estimate at all, only the rounding tolerance decides
    with pytest.raises(InputError, match="not significantly"):
        fit_stern_volmer(ratio[[0, -1]], p[[0, -1]], 100.0)


def test_falling_ratio_is_refused_as_negative():
    """A ratio that clearly falls with the pressure (wind-on and wind-off swapped) gets the
    'must grow' message, not the 'not significant' one."""
    from selfillum.images.psp import SternVolmer, fit_stern_volmer

    p = np.array([80.0, 95.0, 110.0, 130.0])
    swapped = 1.0 / SternVolmer(0.15, 0.85, 100.0).ratio(p)
    with pytest.raises(InputError, match="must grow"):
        fit_stern_volmer(swapped, p, 100.0)
    with pytest.raises(InputError, match="must grow"):
        fit_stern_volmer(swapped[[0, -1]], p[[0, -1]], 100.0)


def test_look_at_with_eye_on_target_up_to_rounding_is_refused():
    """``Camera.look_at`` tested ``|target - eye| == 0``: an eye equal to the target up to
    rounding gave a camera looking along the rounding error. Tolerance stated (1e-12)."""
    from resection import Camera

    K = [[500.0, 0, 99.5], [0, 500.0, 74.5], [0, 0, 1]]
    target = np.array([0.1, 0.2, 0.3])
    for eye in (target, target + 1e-17, target * (1 + 2e-16)):
        with pytest.raises(InputError, match="coincide"):
            Camera.look_at(eye, target, [0, 0, 1], K=K, width=200, height=150)
    cam = Camera.look_at(target + [0, -1e-6, 0], target, [0, 0, 1], K=K, width=200,
                         height=150)  # a micrometre away is a direction
    np.testing.assert_allclose(cam.R[2], [0, 1, 0], atol=1e-9)


# --------------------------------------------------------------------------------------
# calibrate: intrinsics that the views do not determine are refused, and named
# --------------------------------------------------------------------------------------


def _planar_view(eye, *, noise=0.1, seed=4):
    """One view of an 11 x 8 calibration card (3 cm pitch), and the true camera."""
    from resection import Camera

    gx, gy = np.meshgrid(np.arange(11) * 0.03, np.arange(8) * 0.03)
    board = np.column_stack([gx.ravel() - 0.15, gy.ravel() - 0.105, np.zeros(88)])
    K = np.array([[1150.0, 0.0, 650.5], [0.0, 1158.0, 470.2], [0.0, 0.0, 1.0]])
    cam = Camera.look_at(eye, [0, 0, 0], [0, -1, 0], K=K, width=1280, height=960)
    uv, valid = cam.project(board, return_valid=True)
    assert valid.all() and cam.in_image(uv).all()
    uv = uv + np.random.default_rng(seed).normal(scale=noise, size=uv.shape)
    return board, uv, cam


def test_calibrate_single_planar_view_refused_naming_the_centre(tmp_path, capsys):
    """One view of a planar card with the principal point free: on today's main this
    exited 0 with the focal length 3 % off (reported error 8 %) and no warning. It is
    refused, naming cx, cy, and nothing is written."""
    from resection.cli.main import main
    from resection.io.markers import write_markers, write_points

    board, uv, _ = _planar_view([0.25, 0.2, -0.45])
    ids = [f"T{i}" for i in range(len(board))]
    write_markers(tmp_path / "board.csv", ids, board)
    write_points(tmp_path / "view1.csv", ids, uv)
    out = tmp_path / "cam.json"
    for fix in ([], ["--fix", "k3"], ["--fix", "aspect"]):
        rc = main(["calibrate", "--markers", str(tmp_path / "board.csv"), "--points",
                   str(tmp_path / "view1.csv"), "--size", "1280x960", "--out", str(out),
                   *fix])
        err = capsys.readouterr().err
        assert rc == 2, fix
        assert "not determined" in err and "cx, cy" in err and len(err.splitlines()) == 1
        assert not out.exists()


def test_calibrate_single_planar_view_with_centre_fixed_is_accepted():
    """The same view with the principal point held (as the message advises) still
    calibrates: the refusal is a rule on what the views determine, not on one view."""
    from resection import Camera, calibrate

    board, uv, cam = _planar_view([0.25, 0.2, -0.45])
    res = calibrate([(board, uv)], (1280, 960), fix=("cx", "cy", "k1", "k2", "p1", "p2", "k3"),
                    initial=Camera(1280, 960, cam.K))
    assert res.parameters == ("fx", "fy")
    for i, nm in ((0, "fx"), (1, "fy")):
        assert abs(res.camera.K[i, i] - cam.K[i, i]) < 4 * res.std[nm]


# --------------------------------------------------------------------------------------
# A run that sees nothing is not a success; unit mismatches named (issue 10 item 5)
# --------------------------------------------------------------------------------------


def _map_args(tmp_path, camera_file):
    return ["map", "--mesh", str(tmp_path / "corner.ply"), "--camera", str(camera_file),
            "--image", str(tmp_path / "img.npy"), "--out", str(tmp_path / "faces.csv")]


def test_map_with_camera_facing_away_fails(tmp_path, capsys):
    """``resection map`` with a camera that sees none of the mesh printed "0 of N faces
    seen", exited 0 and wrote an all-NaN file."""
    from resection import Camera
    from resection.cli.main import main

    sc, cam, _ = corner_files(tmp_path)
    centre = np.asarray(sc.mesh.vertices).mean(axis=0)
    away = Camera.look_at(cam.center, 2 * cam.center - centre, [0, 0, 1], K=cam.K,
                          width=cam.width, height=cam.height)
    write_camera(tmp_path / "away.json", away)
    rc = main(_map_args(tmp_path, tmp_path / "away.json"))
    err = capsys.readouterr().err
    assert rc == 2 and "sees none of the" in err and "facing away" in err, err
    assert len(err.splitlines()) == 1 and not (tmp_path / "faces.csv").exists()
    # the camera that faces the model maps it
    assert main(_map_args(tmp_path, tmp_path / "cam.json")) == 0
    assert (tmp_path / "faces.csv").exists()


def test_map_with_camera_in_mm_names_the_unit_mismatch(tmp_path, capsys):
    """A camera solved with markers in mm looking at a mesh in m sees nothing: the
    message says which units."""
    from resection import Camera
    from resection.cli.main import main

    _, cam, _ = corner_files(tmp_path)
    write_camera(tmp_path / "mm.json",
                 Camera(cam.width, cam.height, cam.K, R=cam.R, t=1000.0 * cam.t))
    rc = main(_map_args(tmp_path, tmp_path / "mm.json"))
    err = capsys.readouterr().err
    assert rc == 2 and "unit mismatch: the mesh in m and the camera in mm?" in err, err
    assert not (tmp_path / "faces.csv").exists()


def _markers_and_candidates(sc, cam, n=14, seed=2):
    """Markers painted on the corner's faces (model units) and their detected
    candidates in ``cam`` (the exact projections)."""
    mesh = sc.mesh
    rng = np.random.default_rng(seed)
    from resection.surface.surface_map import SurfaceMap

    seen = np.flatnonzero(SurfaceMap(mesh, cam).seen_faces)
    faces = rng.choice(seen, size=n, replace=False)
    xyz = np.asarray(mesh.triangles_center)[faces]
    uv = cam.project(xyz)
    return xyz, uv


def test_match_with_markers_in_mm_names_the_unit_mismatch(tmp_path, capsys):
    """``match`` with the markers in mm and the camera in m said only "0 reference
    markers in view"; the message now names the unit mismatch. The same files in one
    unit match."""
    from resection.cli.main import main
    from resection.io.markers import write_markers

    sc, cam, _ = corner_files(tmp_path, resolution=8, size=(320, 240))
    xyz, uv = _markers_and_candidates(sc, cam)
    ids = [f"M{i}" for i in range(len(xyz))]
    (tmp_path / "cand.csv").write_text("u,v,diameter,depth,merit,snr\n" + "".join(
        f"{u:.6f},{v:.6f},6,20,50,30\n" for u, v in uv))
    write_markers(tmp_path / "m_mm.csv", ids, 1000.0 * xyz)
    write_markers(tmp_path / "m.csv", ids, xyz)
    base = ["match", "--candidates", str(tmp_path / "cand.csv"), "--camera",
            str(tmp_path / "cam.json"), "--out", str(tmp_path / "matched.csv")]
    rc = main([*base, "--markers", str(tmp_path / "m_mm.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "unit mismatch: the markers in mm and the camera in m?" in err, err
    assert not (tmp_path / "matched.csv").exists()
    rc = main([*base, "--markers", str(tmp_path / "m.csv")])
    assert rc == 0, capsys.readouterr().err


def test_correct_with_mesh_in_mm_names_units_not_winding(tmp_path, capsys):
    """``selfillum correct`` with the mesh in mm and the camera in m advised fixing the
    winding (the camera sits inside the model blown up 1000 times); or said only "check
    the pose". Both messages now name the unit mismatch."""
    import trimesh

    from resection import Camera
    from selfillum.cli.main import main

    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    cam = Camera.look_at([1.6, 1.3, 1.0], [0, 0, 0], [0, 0, 1],
                         K=[[90.0, 0, 47.5], [0, 90.0, 35.5], [0, 0, 1]], width=96, height=72)
    write_camera(tmp_path / "cam.json", cam)
    trimesh.Trimesh(box.vertices * 1000.0, box.faces).export(tmp_path / "box_mm.ply")
    box.export(tmp_path / "box.ply")
    np.save(tmp_path / "img.npy", np.ones((72, 96), np.float32))
    args = ["correct", "--camera", str(tmp_path / "cam.json"), "--image",
            str(tmp_path / "img.npy"), "--reflectance", "0.5", "--rays", "16", "--quiet",
            "--out", str(tmp_path / "out.npy")]
    rc = main([*args, "--mesh", str(tmp_path / "box_mm.ply")])
    err = capsys.readouterr().err
    assert rc == 2 and "unit mismatch: the mesh in mm and the camera in m?" in err, err
    assert "winding" not in err and not (tmp_path / "out.npy").exists()
    # the same box in metres is corrected
    assert main([*args, "--mesh", str(tmp_path / "box.ply")]) == 0, capsys.readouterr().err


def test_taps_in_mm_name_the_units(tmp_path):
    """Pressure taps in mm on a mesh in m: 'tap 0 is 480 from the surface' now says
    why."""
    from scenes.corner import corner
    from selfillum.images.psp import tap_faces

    mesh = corner(resolution=6).mesh
    taps = np.asarray(mesh.triangles_center)[[3, 20, 40, 55]]
    np.testing.assert_array_equal(tap_faces(mesh, taps), [3, 20, 40, 55])
    with pytest.raises(InputError, match="units"):
        tap_faces(mesh, 1000.0 * taps)


def test_spread_hint_decisions():
    """The spread comparison: a factor of 1000 or 25.4 between two point sets is named,
    a subset of the same surface in the same units is not."""
    from resection.camera.units import spread_hint

    rng = np.random.default_rng(0)
    mesh_pts = rng.uniform(0, 1, (500, 3))
    markers = mesh_pts[:40]
    assert spread_hint(markers, mesh_pts, "the markers", "the mesh") is None
    assert "in mm and the mesh in m" in spread_hint(markers * 1000, mesh_pts, "the markers",
                                                    "the mesh")
    assert "in mm and the mesh in inch" in spread_hint(markers * 25.4, mesh_pts,
                                                       "the markers", "the mesh")
    # markers clustered on a small part of the model (spread 1/25 of the model's): on it,
    # so not a unit mismatch
    cluster = 0.5 + (mesh_pts[:40] - 0.5) / 25.4
    assert spread_hint(cluster, mesh_pts, "the markers", "the mesh") is None
    # the same spread far off the model is one
    assert "in inch and the mesh in mm" in spread_hint(cluster + 5.0, mesh_pts,
                                                       "the markers", "the mesh")


def test_markers_in_mm_on_a_mesh_in_m_are_not_snapped_to_it(tmp_path):
    """``read_markers(path, mesh=...)`` moves targets under the surface out to it: markers
    in mm on a mesh in m were all 'under' it and moved by hundreds of units with a
    warning. A unit mismatch is refused, naming the units."""
    import warnings

    from resection.io.markers import read_markers, write_markers
    from scenes.corner import corner

    mesh = corner(resolution=6).mesh
    xyz = np.asarray(mesh.triangles_center)[::7]
    ids = [f"T{i}" for i in range(len(xyz))]
    write_markers(tmp_path / "m.csv", ids, xyz)
    write_markers(tmp_path / "mm.csv", ids, 1000.0 * xyz)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # markers on the surface: nothing to move
        np.testing.assert_allclose(read_markers(tmp_path / "m.csv", mesh=mesh).xyz, xyz)
    with pytest.raises(InputError, match=r"mm.csv: .*markers in mm and the mesh in m\?"):
        read_markers(tmp_path / "mm.csv", mesh=mesh)


def test_pose_from_image_with_markers_in_mm_names_the_unit_mismatch(tmp_path, capsys):
    """``resection pose --image`` (detect, match, solve) with the markers in mm and the
    approximate camera in m said only "0 reference markers in view"."""
    from resection.cli.main import main
    from resection.io.markers import write_markers

    sc, cam, _ = corner_files(tmp_path, resolution=8, size=(320, 240))
    xyz, uv = _markers_and_candidates(sc, cam)
    write_markers(tmp_path / "m_mm.csv", [f"M{i}" for i in range(len(xyz))], 1000.0 * xyz)
    vv, uu = np.mgrid[0:240, 0:320]
    img = np.full((240, 320), 200.0, np.float32)
    for u, v in uv:  # dark disks of 6 px where the markers are
        img[(uu - u) ** 2 + (vv - v) ** 2 <= 9.0] = 40.0
    np.save(tmp_path / "frame.npy", img)
    rc = main(["pose", "--camera", str(tmp_path / "cam.json"), "--markers",
               str(tmp_path / "m_mm.csv"), "--image", str(tmp_path / "frame.npy"),
               "--diameter", "6", "--out", str(tmp_path / "pose.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "unit mismatch: the markers in mm and the camera in m?" in err, err
    assert not (tmp_path / "pose.json").exists()
