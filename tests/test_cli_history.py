"""``resection map --out P.h5``: a frame sequence mapped into one time history, with
``--track`` (the poses solved by ``resection track``) and ``--resume``; checked against the
scene's truth (paint field at the nodes, true poses), read back by h5py and meshio."""
import h5py
import meshio
import numpy as np
import pytest

from resection.cli.main import main
from resection.io.cameras import write_camera
from resection.io.history import read_history, xdmf_path
from scenes.moving_model import pitch_oscillation, write_sequence
from scenes.moving_surface import model_surface, paint_field, render_surface


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("history")
    model = pitch_oscillation(25, shape=(160, 160))
    mesh = model_surface(face_size=0.02)
    mesh.export(d / "model.ply")
    write_camera(d / "camera.json", model.camera)
    return d, model, mesh


def test_map_sequence_resume_and_xdmf(scene, capsys):
    d, model, mesh = scene
    # the model at rest in every frame (no --track: one camera for the sequence)
    paths = []
    for k in range(5):
        p = d / f"paint_{k}.npy"
        np.save(p, render_surface(model, 0) + np.float32(k))  # a known change per frame
        paths.append(str(p))
    out = d / "rest.h5"
    base = ["map", "--mesh", str(d / "model.ply"), "--camera", str(d / "camera.json"),
            "--out", str(out), "--fps", "50"]
    assert main(base + ["--image", *paths[:3]]) == 0  # a run that stopped after 3 frames
    assert "3 frames mapped" in capsys.readouterr().out
    rc = main(base + ["--image", *paths])
    err = capsys.readouterr().err
    assert rc == 2 and "exists" in err and len(err.strip().splitlines()) == 1
    assert main(base + ["--image", *paths, "--resume"]) == 0
    assert "2 frames mapped" in capsys.readouterr().out
    h = read_history(out)
    assert h.n_frames == 5 and h.per == "node"
    np.testing.assert_allclose(h.times, np.arange(5) / 50.0, rtol=1e-15)
    truth = paint_field(h.points)  # the grid as the command read it
    seen = np.isfinite(h.values[0])
    assert seen.sum() > 300
    for k in range(5):
        err = h.values[k][seen] - (truth[seen] + k)
        # first-order bound of node values (see test_sequence_mapping): |grad f| * face
        assert np.abs(err).max() < 5100 * 0.02
        assert np.median(np.abs(err)) < 10
    with h5py.File(out, "r") as f:
        np.testing.assert_array_equal(f["frames/camera/R"][4], model.camera.R)
    with meshio.xdmf.TimeSeriesReader(xdmf_path(out)) as r:
        r.read_points_cells()
        assert r.num_steps == 5
        t, pd, _ = r.read_data(4)
        assert t == pytest.approx(0.08)
        np.testing.assert_array_equal(pd["value"], h.values[4])


def test_track_then_map(scene, capsys):
    d, model, mesh = scene
    files = write_sequence(model, d / "frames", frames=range(0, 25, 4))
    trk = d / "track"
    rc = main(["track", *files["frames"], "--camera", files["camera"], "--markers",
               files["markers"], "--diameter", "5", "--out", str(trk), "--workers", "1",
               "--no-progress"])
    assert rc == 0
    capsys.readouterr()
    out = d / "moving.h5"
    rc = main(["map", "--mesh", str(d / "model.ply"), "--camera", files["camera"],
               "--track", str(trk), "--image", *files["frames"], "--out", str(out),
               "--fps", "12.5", "--per", "face"])
    assert rc == 0
    h = read_history(out)
    assert h.n_frames == 7 and h.per == "face" and h.values.shape == (7, len(h.triangles))
    np.testing.assert_allclose(h.times, np.arange(7) / 12.5)
    for i, k in enumerate(range(0, 25, 4)):  # each frame's camera is its solved pose
        true = model.camera_at(k)
        assert np.linalg.norm(h.cameras[i].center - true.center) < 2e-3
        cosang = (np.trace(h.cameras[i].R @ true.R.T) - 1) / 2
        assert np.degrees(np.arccos(min(1.0, cosang))) < 0.1
    # the marker frames show a background of 1000 counts with dark disks on the wing
    v = h.values[3]
    v = v[np.isfinite(v)]
    assert v.size > 200 and abs(np.median(v) - 1000) < 30
    rc = main(["map", "--mesh", str(d / "model.ply"), "--camera", files["camera"],
               "--image", files["frames"][0], "--track", str(trk), "--out",
               str(d / "x.csv")])
    assert rc == 2 and "time history" in capsys.readouterr().err
