"""Plot3D grids and function files, checked against the independent ``plot3d`` package
(NASA's reader/writer on PyPI) and SciPy's Fortran record reader."""

from __future__ import annotations

import numpy as np
import plot3d
import pytest
from scipy.io import FortranFile

from resection import InputError
from resection.io.meshes import load_mesh
from resection.io.plot3d import (
    faces_to_grid_nodes,
    read_plot3d,
    read_plot3d_function,
    write_plot3d,
    write_plot3d_function,
)


def _blocks():
    """Two surface blocks of a wavy plate (nk = 1), different sizes."""
    out = []
    for k, (ni, nj) in enumerate([(7, 5), (4, 9)]):
        x, y = np.meshgrid(np.linspace(0, 1, ni) + 1.5 * k, np.linspace(0, 2, nj),
                           indexing="ij")
        z = 0.05 * np.sin(3 * x) * np.cos(2 * y)
        out.append(np.stack([x, y, z], -1)[:, :, None, :])
    return out


def _as_p3d_blocks(blocks):
    return [plot3d.Block(b[..., 0].copy(), b[..., 1].copy(), b[..., 2].copy()) for b in blocks]


@pytest.mark.parametrize("kw", [
    dict(binary=True, fortran=True, big_endian=False),
    dict(binary=True, fortran=True, big_endian=True),
    dict(binary=True, fortran=False, big_endian=True),
    dict(binary=True, fortran=False, big_endian=False, double_precision=False),
    dict(binary=False),
])
def test_read_files_written_by_plot3d_package(tmp_path, kw):
    blocks = _blocks()
    p = tmp_path / "model.grid"  # an extension trimesh does not know: found by content
    plot3d.write_plot3D(str(p), _as_p3d_blocks(blocks), **kw)
    got = read_plot3d(p)
    tol = 1e-6 if kw.get("double_precision") is False or not kw.get("binary") else 0
    for (xyz, _), ref in zip(got, blocks, strict=True):
        np.testing.assert_allclose(xyz, ref, rtol=0, atol=tol)
    mesh = load_mesh(p)
    assert mesh.metadata["format"] == "plot3d"
    assert len(mesh.faces) == 2 * (6 * 4 + 3 * 8)


@pytest.mark.parametrize("kw", [
    dict(binary=True, endian="<"), dict(binary=True, endian=">"),
    dict(binary=True, records=False), dict(binary=False),
    dict(binary=True, precision="single", endian=">"),
])
def test_files_we_write_read_by_plot3d_package(tmp_path, kw):
    blocks = _blocks()
    p = tmp_path / "out.xyz"
    write_plot3d(p, blocks, **kw)
    ref = plot3d.read_plot3D(str(p))
    tol = 1e-6 if kw.get("precision") == "single" else 1e-15
    for b, r in zip(blocks, ref, strict=True):
        np.testing.assert_allclose(np.stack([r.X, r.Y, r.Z], -1), b, rtol=0, atol=tol)


def test_format_option_and_unknown_content(tmp_path):
    p = tmp_path / "grid.dat"
    write_plot3d(p, _blocks())
    assert load_mesh(p, format="plot3d").metadata["format"] == "plot3d"
    assert load_mesh(p).metadata["format"] == "plot3d"
    junk = tmp_path / "model.bin"
    junk.write_bytes(np.random.default_rng(0).bytes(1000))
    with pytest.raises(InputError, match=r"model.bin: unknown mesh format.*--format"):
        load_mesh(junk)
    junk = junk.rename(tmp_path / "model.grid")  # a Plot3D extension: the Plot3D reason
    with pytest.raises(InputError, match=r"model.grid: not a readable Plot3D file"):
        load_mesh(junk)
    with pytest.raises(InputError, match="unknown mesh format 'vrml'"):
        load_mesh(p, format="vrml")


def test_function_file_read_by_scipy_fortranfile(tmp_path):
    rng = np.random.default_rng(1)
    vals = [rng.normal(size=(7, 5, 1, 2)), rng.normal(size=(4, 9, 1, 2))]
    vals[0][2, 3, 0, 1] = np.nan
    p = tmp_path / "p.f"
    write_plot3d_function(p, vals)
    with FortranFile(p, "r", header_dtype="<u4") as f:
        assert f.read_ints("<i4").tolist() == [2]
        assert f.read_ints("<i4").tolist() == [7, 5, 1, 2, 4, 9, 1, 2]
        for v in vals:
            raw = f.read_reals("<f8")
            np.testing.assert_array_equal(raw, v.transpose(3, 2, 1, 0).ravel())
    back = read_plot3d_function(p)
    for a, b in zip(back, vals, strict=True):
        np.testing.assert_array_equal(a, b)


def test_faces_to_grid_nodes_linear_field(tmp_path):
    """A field linear in x, y sampled at face centroids comes back exactly at the interior
    nodes of a uniform grid (the four cells around a node average to the node)."""
    p = tmp_path / "plate.x"
    ni, nj = 6, 5
    x, y = np.meshgrid(np.linspace(0, 1, ni), np.linspace(0, 0.8, nj), indexing="ij")
    write_plot3d(p, [np.stack([x, y, np.zeros_like(x)], -1)])
    mesh = load_mesh(p)
    c = mesh.triangles_center
    f = 2.0 * c[:, 0] - 3.0 * c[:, 1] + 0.5
    nodes = faces_to_grid_nodes(mesh, f)
    assert nodes[0].shape == (ni, nj, 1, 1)
    ref = 2.0 * x - 3.0 * y + 0.5
    np.testing.assert_allclose(nodes[0][1:-1, 1:-1, 0, 0], ref[1:-1, 1:-1], atol=1e-12)
    # a corner node has one cell: the value at that cell's centre
    np.testing.assert_allclose(nodes[0][0, 0, 0, 0], 2.0 * 0.1 - 3.0 * 0.1 + 0.5, atol=1e-12)


def test_truncated_plot3d(tmp_path):
    p = tmp_path / "g.x"
    write_plot3d(p, _blocks())
    data = p.read_bytes()
    p.write_bytes(data[:-37])
    with pytest.raises(InputError, match="g.x"):
        load_mesh(p)
