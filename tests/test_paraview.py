"""ParaView itself opens the XDMF files the commands write: ``pvbatch`` (Debian's ParaView
5.11, installed by ``tools/setup.sh`` when run as root) runs ``tools/paraview_frame.py``
on the unsteady run's ``run.xdmf`` and on ``map``'s ``.xdmf``, through ParaView's "Xdmf
Reader" and "Xdmf3 Reader"; the values it reads are checked against the HDF5 files read by
h5py, and the picture it draws against the colours of its colour map. Without a display
ParaView draws in a virtual one (``Xvfb``)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "tools" / "paraview_frame.py"

pytestmark = pytest.mark.slow


def paraview(*args: str) -> str:
    """``tools/paraview_frame.py ARGS``, which runs itself under ``pvbatch`` (in a virtual
    display when there is none); its output."""
    done = subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return done.stdout


def colours(png: Path) -> np.ndarray:
    """The distinct RGB colours of a picture (alpha dropped), as 0-255 integers."""
    import matplotlib.pyplot as plt

    rgb = np.rint(plt.imread(png)[..., :3] * 255).astype(int)
    return np.unique(rgb.reshape(-1, 3), axis=0)


@pytest.fixture(scope="module")
def outputs(tmp_path_factory):
    """A small unsteady run (``selfillum unsteady``) and frame 0 mapped (``resection
    map --out frame0.xdmf``)."""
    from resection import write_image
    from resection.cli.main import main as resection
    from scenes.unsteady_run import make_unsteady_run
    from selfillum.cli import main as selfillum

    d = tmp_path_factory.mktemp("paraview")
    run = make_unsteady_run(d / "scene", frames=16, faces=600, truth_rays=64)
    assert selfillum(["unsteady", str(run.deck), "--paint-calibration", str(run.paint),
                      "--steady", str(run.steady), "--fps", str(run.fps), "--out",
                      str(d / "run.h5"), "--quiet", "--no-plots"]) == 0
    write_image(d / "frame0.tif", np.load(run.video)[0])
    assert resection(["map", "--mesh", str(run.grid), "--camera", str(run.calibration),
                      "--image", str(d / "frame0.tif"), "--out", str(d / "frame0.xdmf")]) == 0
    return d


@pytest.mark.parametrize("reader", ["Xdmf Reader", "Xdmf3 Reader"])
def test_paraview_reads_and_draws_what_map_writes(outputs, reader, tmp_path):
    d = outputs
    out = paraview(str(d / "frame0.xdmf"), "--array", "frame0", "--reader", reader,
                   "--npy", str(tmp_path / "v.npy"), "--png", str(tmp_path / "v.png"),
                   "--size", "400,300")
    assert f"{reader}, 0 time steps" in out and "on the cells" in out
    with h5py.File(d / "frame0.data.h5") as f:
        truth = f["cell/frame0"][()]
        seen = f["cell/frame0_seen"][()].astype(bool)
    got = np.load(tmp_path / "v.npy")
    assert seen.sum() > 50 and np.isnan(truth[~seen]).all()
    np.testing.assert_array_equal(got, truth)  # NaN where unseen, in the same places
    # drawn: the white background, the grey of unseen faces and many colours of the map
    c = colours(tmp_path / "v.png")
    assert [255, 255, 255] in c.tolist() and len(c) > 50


def test_paraview_plays_the_unsteady_runs_frames(outputs, tmp_path):
    """ParaView's "Xdmf Reader" (VTK's ``vtkXdmfReader``) on ``run.xdmf``: the frames' time
    steps are ``/frames/time`` and frame 5's dCp is row 5 of ``/dcp``. (Its "Xdmf3 Reader"
    reads the grid and the time steps but not the frames' values, which the file takes
    from ``/dcp`` by XDMF's HyperSlab: docs/known_issues.md.)"""
    d = outputs
    out = paraview(str(d / "run.xdmf"), "--array", "dCp", "--reader", "Xdmf Reader",
                   "--step", "5", "--npy", str(tmp_path / "v.npy"), "--png",
                   str(tmp_path / "v.png"), "--size", "400,300")
    with h5py.File(d / "run.h5") as f:
        dcp = f["dcp"][()]
        times = f["frames/time"][()]
    m = re.search(r"(\d+) time steps, step 5 at t = (\S+), (\d+) values of dCp on the points",
                  out)
    assert m, out
    assert int(m.group(1)) == len(times) == 16 and int(m.group(3)) == dcp.shape[1]
    assert float(m.group(2)) == pytest.approx(times[5], abs=1e-9)
    got = np.load(tmp_path / "v.npy")
    assert np.isfinite(dcp[5]).sum() > 50
    np.testing.assert_array_equal(got, dcp[5])
    c = colours(tmp_path / "v.png")
    assert [255, 255, 255] in c.tolist() and len(c) > 50
