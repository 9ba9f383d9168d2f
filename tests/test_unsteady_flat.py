"""``unsteady --upsp-flat``: the flat files uPSP's own scripts read (issue 34 item 12).

uPSP's ``scripts/upsp-kulite-comparison`` reads a node's dCp history with
``_read_pressure_transpose``: the node count from the byte size of the ``X`` file beside
``pressure_transpose`` (4 bytes a node), the frame count from ``pressure_transpose``'s
size, then ``count = frames`` float32 at ``offset = node * frames * 4``.
:func:`upsp_read_pressure_transpose` below does the same steps (written here, not copied);
``psp_process`` writes every per-node file as ``N`` raw float32 (``pwrite_full`` of a
``std::vector<float>``), read back here with :func:`numpy.fromfile`. The values are checked
against the run's file and against the intensities decoded here from Phase 1's codes; the
coverage against OpenCV's projection of the nodes."""

from __future__ import annotations

import json
import os
import types

import cv2
import h5py
import numpy as np
import trimesh

from resection import Camera
from selfillum.unsteady.output import (
    FLAT_FILES,
    camera_coverage,
    write_flat,
    write_node_files,
)


def upsp_read_pressure_transpose(folder, node_index: int) -> np.ndarray:
    """One node's time history as uPSP's ``_read_pressure_transpose``
    (scripts/upsp-kulite-comparison) reads it."""
    x_bytes = os.path.getsize(os.path.join(folder, "X"))
    p_path = os.path.join(folder, "pressure_transpose")
    p_bytes = os.path.getsize(p_path)
    n_nodes = x_bytes // 4
    n_frames = (p_bytes // 4) // n_nodes
    assert n_frames * n_nodes * 4 == p_bytes  # as uPSP asserts
    return np.fromfile(p_path, dtype=np.float32, count=n_frames,
                       offset=node_index * n_frames * 4)


def _run_files(tmp_path, T=37, N=53):
    """A run's output file and Phase 1's work file with known content."""
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(N, 3)) * [10.0, 2.0, 1.0]
    dcp = rng.normal(scale=0.02, size=(T, N)).astype(np.float32)
    dcp[:, 5] = np.nan  # a node never seen
    cp = rng.uniform(-1.0, 1.0, N)
    cp[7] = 9.9  # no steady data: NaN in steady_state, as psp_process writes it
    gain = rng.uniform(0.5, 2.0, N)
    out = tmp_path / "run.h5"
    with h5py.File(out, "w") as f:
        f.create_dataset("grid/points", data=pts)
        f.create_dataset("dcp", data=dcp, chunks=(8, 16))
        f.create_dataset("steady/cp", data=cp)
        f.create_dataset("steady/gain", data=gain)
        f.create_dataset("stats/dcp_mean", data=np.mean(dcp, axis=0))
        f.create_dataset("stats/dcp_rms", data=np.sqrt(np.mean(dcp.astype(float) ** 2,
                                                               axis=0)))
        f.attrs["conditions"] = json.dumps({"surface_temperature": 81.5})
    codes = rng.integers(1, 65535, size=(T, N)).astype(np.uint16)
    codes[:, 5] = 0  # unseen: code 0
    codes[3, 9] = 0  # one frame without a value
    scale = rng.uniform(10.0, 20.0, T)
    work = tmp_path / "phase1.h5"
    with h5py.File(work, "w") as w:
        w.create_dataset("values", data=codes, chunks=(8, 16))
        w.create_dataset("values_scale", data=scale)
    return out, work, dcp, pts, cp, gain, codes, scale


def test_flat_files_read_by_upsps_logic(tmp_path):
    out, work, dcp, pts, cp, gain, codes, scale = _run_files(tmp_path)
    T, N = dcp.shape
    folder = tmp_path / "flat"
    folder.mkdir()
    paths = {name: folder / name for name in FLAT_FILES}
    cover = np.arange(N) % 3
    with h5py.File(out) as f, h5py.File(work) as w:
        write_flat(f, paths["pressure"], paths["pressure_transpose"], node_block=10)
        write_node_files(f, {k: paths[k] for k in FLAT_FILES[2:]}, work=w, coverage=cover,
                         node_block=10)
    assert sorted(os.listdir(folder)) == sorted(FLAT_FILES)
    # uPSP's script: the node count from X, each node's history from pressure_transpose
    for node in (0, 5, 17, N - 1):
        np.testing.assert_array_equal(upsp_read_pressure_transpose(folder, node),
                                      dcp[:, node])
    np.testing.assert_array_equal(np.fromfile(folder / "pressure", "<f4").reshape(T, N), dcp)

    def node_file(name):
        assert os.path.getsize(folder / name) == 4 * N, name
        return np.fromfile(folder / name, "<f4")

    for k, axis in enumerate("XYZ"):
        np.testing.assert_array_equal(node_file(axis), pts[:, k].astype(np.float32))
    np.testing.assert_allclose(node_file("avg"), dcp.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(node_file("rms"), np.sqrt((dcp.astype(float) ** 2).mean(0)),
                               rtol=1e-6)
    np.testing.assert_array_equal(node_file("gain"), gain.astype(np.float32))
    ss = node_file("steady_state")
    assert np.isnan(ss[7]) and np.isnan(ss).sum() == 1
    np.testing.assert_array_equal(np.delete(ss, 7), np.delete(cp, 7).astype(np.float32))
    assert np.all(node_file("model_temp") == np.float32(81.5))
    np.testing.assert_array_equal(node_file("coverage"), cover.astype(np.float32))
    # intensities: the codes decoded here (code / the frame's scale; 0: no value)
    inten = np.where(codes > 0, codes / scale[:, None], np.nan)
    seen = np.ones(N, bool)
    seen[5] = False
    avg = np.array([inten[np.isfinite(inten[:, j]), j].mean() if seen[j] else np.nan
                    for j in range(N)])
    rms = np.array([np.sqrt((inten[np.isfinite(inten[:, j]), j] ** 2).mean())
                    if seen[j] else np.nan for j in range(N)])
    np.testing.assert_allclose(node_file("intensity_avg"), avg, rtol=1e-6)
    np.testing.assert_allclose(node_file("intensity_rms"), rms, rtol=1e-6)
    np.testing.assert_allclose(node_file("intensity_ratio_0"), avg / inten[0] - 1.0,
                               rtol=1e-5, atol=1e-7)


def test_coverage_counts_the_cameras_that_see_each_node():
    """Two cameras over a plate, one seeing all of it, one a corner: the count of cameras
    whose image holds the node (OpenCV's projection), away from the image edges."""
    n = 30
    xs = np.linspace(-1.0, 1.0, n + 1)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), \
        idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    mesh = trimesh.Trimesh(V, F, process=False)
    grid = types.SimpleNamespace(mesh=mesh, to_nodes=lambda v: np.asarray(v))
    K = [[300.0, 0, 159.5], [0, 300.0, 119.5], [0, 0, 1]]
    cams = [Camera.look_at([0.1, -0.2, 4.0], [0, 0, 0], [0, 1, 0], K=K, width=320,
                           height=240),
            Camera.look_at([0.8, 0.7, 1.5], [0.7, 0.6, 0], [0, 1, 0], K=K, width=320,
                           height=240)]
    cover = camera_coverage(grid, cams, 70.0)
    ref = np.zeros(len(V))
    clear = np.ones(len(V), bool)
    for cam in cams:
        K_, dist, rvec, tvec = cam.to_opencv()
        uv, _ = cv2.projectPoints(V, rvec, tvec, K_, dist)
        u, v = uv.reshape(-1, 2).T
        inside = (u > -0.5) & (u < 319.5) & (v > -0.5) & (v < 239.5)
        ref += inside
        edge = np.minimum.reduce([u + 0.5, 319.5 - u, v + 0.5, 239.5 - v])
        clear &= np.abs(edge) > 20.0  # within a face (13 px) of the edge: either
    assert clear.sum() > 400 and set(np.unique(ref[clear])) == {1.0, 2.0}
    np.testing.assert_array_equal(cover[clear], ref[clear])
