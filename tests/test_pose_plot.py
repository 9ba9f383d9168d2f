"""``resection pose --plot``: the overlay of the paper's Figure 20 from the command line."""
import cv2
import numpy as np
import trimesh
from matplotlib.image import imread
from matplotlib.quiver import Quiver

from resection import Camera, write_markers, write_points
from resection.cli.main import main
from resection.io.cameras import write_camera
from resection.pose.figure20 import plot_pose
from resection.pose.solve import solve_pose

W, H = 640, 480
K = np.array([[900.0, 0, 319.5], [0, 900.0, 239.5], [0, 0, 1.0]])


def _scene():
    """A block on a plate, markers on both; one marker's image point 9 px off."""
    rng = np.random.default_rng(3)
    plate = trimesh.creation.box(extents=[0.6, 0.4, 0.02])
    plate.apply_translation([0, 0, -0.01])
    block = trimesh.creation.box(extents=[0.12, 0.1, 0.06])
    block.apply_translation([0.05, 0.0, 0.03])
    mesh = trimesh.util.concatenate([plate, block])
    X = np.column_stack([rng.uniform(-0.25, 0.25, 12), rng.uniform(-0.17, 0.17, 12),
                         np.zeros(12)])
    X[0] = [0.05, 0.0, 0.06]  # on the block's top
    cam = Camera.look_at([0.2, -0.55, 0.75], [0, 0, 0], [0, 0, 1], K=K, width=W, height=H)
    uv = cam.project(X) + rng.normal(scale=0.15, size=(12, 2))
    uv[5] += [7.0, -5.5]
    ids = [f"M{i}" for i in range(12)]
    return mesh, cam, X, uv, ids


def test_plot_pose_draws_figure20():
    mesh, cam, X, uv, ids = _scene()
    res = solve_pose(cam, X, uv, ids=ids)
    assert res.acceptance.outliers == ("M5",)
    fig = plot_pose(res, X, uv, mesh=mesh, ids=ids)
    ax = fig.axes[0]
    # RMS in the title: the used markers' residuals against OpenCV's projection
    keep = res.used
    Kc, d, rv, tv = res.camera.to_opencv()
    proj, _ = cv2.projectPoints(X[keep], rv, tv, Kc, d)
    rms = np.sqrt(np.mean(np.sum((uv[keep] - proj.reshape(-1, 2)) ** 2, axis=1)))
    title = ax.get_title()
    assert f"RMS residual {rms:.3f} px (11 markers)" in title and "threshold" in title
    labels = set(ax.get_legend_handles_labels()[1])
    assert {"model outline", "detected", "reprojected", "residual",
            "outlier, dropped"} <= labels
    arrows = [c for c in ax.collections if isinstance(c, Quiver)]
    assert len(arrows) == 1 and arrows[0].N == 11  # one vector per used marker
    texts = [t.get_text() for t in ax.texts]
    assert any(t.startswith("residual vectors x ") for t in texts)
    assert {f"M{i}" for i in range(12) if i != 5} <= set(texts) and "M5 (dropped)" in texts
    outline = [c for c in ax.collections if c.get_label() == "model outline"][0]
    assert len(outline.get_segments()) >= 8  # the block's and the plate's visible edges


def test_pose_command_plot(tmp_path, capsys):
    mesh, cam, X, uv, ids = _scene()
    mesh.export(tmp_path / "model.stl")
    write_markers(tmp_path / "m.csv", ids, X)
    write_points(tmp_path / "p.csv", ids, uv)
    write_camera(tmp_path / "cam.json", cam.replace(R=np.eye(3), t=np.zeros(3)))
    base = ["pose", "--camera", str(tmp_path / "cam.json"), "--markers",
            str(tmp_path / "m.csv"), "--points", str(tmp_path / "p.csv"), "--out",
            str(tmp_path / "out.json")]
    assert main([*base, "--plot", str(tmp_path / "fig20.png"), "--mesh",
                 str(tmp_path / "model.stl")]) == 0
    out = capsys.readouterr().out
    assert "overlay written to" in out and "outlier, dropped" in out
    png = imread(tmp_path / "fig20.png")
    assert png.shape[0] > 300 and png.shape[1] >= 640 and png.std() > 0.05
    # written through a temporary name: none left behind; --mesh alone is a one-line error
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert main([*base, "--mesh", str(tmp_path / "model.stl")]) == 2
    assert "--mesh is for refinding (--image) and the overlay" in capsys.readouterr().err
