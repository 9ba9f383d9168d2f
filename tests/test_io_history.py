"""Time histories (resection.io.history) read back by h5py directly and by meshio's XDMF
time-series reader (independent readers of the file and of its sidecar)."""

import h5py
import meshio
import numpy as np
import pytest
import trimesh

from resection import Camera, InputError
from resection.io.history import HistoryWriter, read_history, write_xdmf, xdmf_path


@pytest.fixture
def mesh():
    m = trimesh.creation.icosphere(subdivisions=1)
    return trimesh.Trimesh(m.vertices, m.faces, process=False)


def _camera(k):
    K = [[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]
    return Camera.look_at([0.1 * k, -3.0, 1.0], [0, 0, 0], [0, 0, 1], K=K, width=640,
                          height=480, dist=[-0.1, 0.01, 0.0, 0.0, 0.0])


def _values(k, n):
    v = np.sin(0.1 * np.arange(n) + k).astype(np.float32)
    v[k % n] = np.nan  # unseen
    return v


@pytest.mark.parametrize("per", ["node", "face"])
def test_round_trip_h5py_and_meshio(tmp_path, mesh, per):
    path = tmp_path / "p.h5"
    n = len(mesh.vertices) if per == "node" else len(mesh.faces)
    times = 0.02 * np.arange(7) + 1.0
    with HistoryWriter(path, mesh, per=per, xdmf_every=3) as w:
        for k in range(7):
            w.append(_values(k, n), time=times[k], camera=_camera(k), index=10 + k)
    # h5py directly, by the documented layout
    with h5py.File(path, "r") as f:
        assert f.attrs["n_frames"] == 7 and f.attrs["per"] == per
        np.testing.assert_array_equal(f["grid/points"][()], mesh.vertices)
        np.testing.assert_array_equal(f["grid/triangles"][()], mesh.faces)
        np.testing.assert_array_equal(f["frames/time"][()], times)
        np.testing.assert_array_equal(f["frames/index"][()], 10 + np.arange(7))
        for k in range(7):
            np.testing.assert_array_equal(f[f"values/{k:06d}"][()], _values(k, n))
            np.testing.assert_array_equal(f["frames/camera/R"][k], _camera(k).R)
            np.testing.assert_array_equal(f["frames/camera/t"][k], _camera(k).t)
        assert f["values/000003"].dtype == np.float32
    # the package's reader
    h = read_history(path)
    assert h.per == per and h.n_frames == 7 and h.values.shape == (7, n)
    np.testing.assert_array_equal(h.values[4], _values(4, n))
    assert h.cameras[5] == _camera(5)
    sub = read_history(path, frames=slice(2, 4))
    np.testing.assert_array_equal(sub.times, times[2:4])
    pts = read_history(path, items=[7, 3, 7])  # time history of points, any order
    np.testing.assert_array_equal(pts.values, np.array([_values(k, n) for k in range(7)])
                                  [:, [7, 3, 7]])
    with pytest.raises(InputError, match="items"):
        read_history(path, items=[n])
    # meshio's XDMF time-series reader on the sidecar
    with meshio.xdmf.TimeSeriesReader(xdmf_path(path)) as r:
        points, cells = r.read_points_cells()
        np.testing.assert_allclose(points, mesh.vertices)
        np.testing.assert_array_equal(cells[0].data, mesh.faces)
        assert r.num_steps == 7
        for k in (0, 6):
            t, point_data, cell_data = r.read_data(k)
            assert t == pytest.approx(times[k], rel=1e-15)
            got = point_data["value"] if per == "node" else cell_data["value"][0]
            np.testing.assert_array_equal(got, _values(k, n))


def test_interrupted_run_keeps_its_frames_and_resumes(tmp_path, mesh):
    path = tmp_path / "run.h5"
    n = len(mesh.vertices)

    def frames():
        for k in range(10):
            if k == 6:
                raise KeyboardInterrupt  # the run is stopped during frame 6
            yield k

    w = HistoryWriter(path, mesh)
    with pytest.raises(KeyboardInterrupt):
        for k in frames():
            w.append(_values(k, n), time=0.1 * k, camera=_camera(k), index=k)
    # a frame begun but not committed: its values are there, n_frames does not count it
    w._f["values"].create_dataset("000006", data=np.zeros(n, np.float32))
    w._f.flush()
    w._f.close()
    w._jf.close()  # the process ends: the lock on the file goes with it
    with h5py.File(path, "r") as f:  # what an interrupted run leaves
        assert f.attrs["n_frames"] == 6
    h = read_history(path)
    assert h.n_frames == 6
    np.testing.assert_array_equal(h.values[5], _values(5, n))
    assert write_xdmf(path) == xdmf_path(path)
    with meshio.xdmf.TimeSeriesReader(xdmf_path(path)) as r:
        r.read_points_cells()
        assert r.num_steps == 6
    with pytest.raises(InputError, match="exists"):
        HistoryWriter(path, mesh)
    with HistoryWriter(path, mesh, resume=True) as w:
        assert w.n_frames == 6 and list(w.done) == list(range(6))
        for k in range(6, 10):
            w.append(_values(k, n), time=0.1 * k, camera=_camera(k), index=k)
    h = read_history(path)
    assert h.n_frames == 10 and list(h.index) == list(range(10))
    for k in (5, 6, 9):
        np.testing.assert_array_equal(h.values[k], _values(k, n))
    np.testing.assert_allclose(h.times, 0.1 * np.arange(10), rtol=1e-15)


def test_history_errors(tmp_path, mesh):
    path = tmp_path / "p.h5"
    with HistoryWriter(path, mesh) as w:
        with pytest.raises(InputError, match=r"expected \(42,\) per node"):
            w.append(np.zeros(5), time=0.0)
    other = trimesh.creation.icosphere(subdivisions=2)
    with pytest.raises(InputError, match="another grid"):
        HistoryWriter(path, other, resume=True)
    with pytest.raises(InputError, match="per node, not per face"):
        HistoryWriter(path, mesh, per="face", resume=True)
    with pytest.raises(InputError, match="HDF5"):
        HistoryWriter(tmp_path / "p.csv", mesh)
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(InputError, match="junk.h5: not a readable HDF5 file"):
        read_history(tmp_path / "junk.h5")
    with pytest.raises(InputError, match="not found"):
        read_history(tmp_path / "none.h5")
