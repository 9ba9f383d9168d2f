"""``--surface FILE`` on ``selfillum psp`` (with and without ``--uncertainty``): the
uncertainty fields in VTU, XDMF and Plot3D function files, read back by independent
readers (meshio for VTU; ``tests/field_readers.py``: the XDMF's XML parsed with the
standard library and its HDF5 data read with h5py, Plot3D function files read with plain
NumPy following the format) and compared with the command's CSV files. ``selfillum
unsteady --surface``: ``tests/test_uncertainty_unsteady.py``."""

from __future__ import annotations

import numpy as np
import pytest
from field_readers import read_function_file, read_xdmf_attribute


@pytest.fixture(scope="module")
def corner_case():
    from scenes.psp_uncertainty import psp_uncertainty_case

    return psp_uncertainty_case(exact_rays=1024)


def test_psp_surface_files_with_uncertainty(corner_case, tmp_path, capsys):
    """``psp --uncertainty --surface a.vtu --surface a.xdmf``: cp, cp_u and each source's
    part per face (cells) and per node (points), equal to pressure_faces.csv and
    pressure_nodes.csv."""
    import meshio

    from scenes.psp_uncertainty import write_psp_files
    from selfillum.cli.main import main

    args = write_psp_files(corner_case, tmp_path, 3)
    vtu, xdmf = tmp_path / "a.vtu", tmp_path / "a.xdmf"
    rc = main(args + ["--uncertainty", "--out", str(tmp_path / "o"), "--no-plots",
                      "--markers", str(tmp_path / "model.tgts"), "--u", "marker=0.05px",
                      "--surface", str(vtu), "--surface", str(xdmf)])
    assert rc == 0, capsys.readouterr().err
    faces = np.genfromtxt(tmp_path / "o" / "pressure_faces.csv", delimiter=",", names=True)
    nodes = np.genfromtxt(tmp_path / "o" / "pressure_nodes.csv", delimiter=",", names=True)
    m = meshio.read(vtu)
    assert len(m.points) == len(corner_case.mesh.vertices)
    names = [n for n in faces.dtype.names if n.startswith("cp_u") or n in ("cp", "p_u")]
    assert "cp_u_noise" in names and "cp_u_registration" in names
    for n in names:
        np.testing.assert_allclose(m.cell_data[n][0], faces[n], rtol=1e-7, equal_nan=True)
        np.testing.assert_allclose(m.point_data[n], nodes[n], rtol=1e-7, equal_nan=True)
        np.testing.assert_allclose(read_xdmf_attribute(xdmf, n, "Cell"), faces[n], rtol=1e-7,
                                   equal_nan=True)
        np.testing.assert_allclose(read_xdmf_attribute(xdmf, n, "Node"), nodes[n], rtol=1e-7,
                                   equal_nan=True)
    assert np.all(faces["cp_u"][np.isfinite(faces["cp"])] > 0)


def test_psp_surface_bad_paths(corner_case, tmp_path, capsys):
    """An unknown format, an input's name, a .f on a non-Plot3D mesh: one-line errors, exit
    2, nothing written."""
    from scenes.psp_uncertainty import write_psp_files
    from selfillum.cli.main import main

    args = write_psp_files(corner_case, tmp_path, 1)
    for bad, msg in ((tmp_path / "a.stl", "unknown format"),
                     (tmp_path / "corner.ply", "is an input"),
                     (tmp_path / "a.f", "needs a Plot3D grid")):
        rc = main(args + ["--uncertainty", "--out", str(tmp_path / "o"), "--surface",
                          str(bad)])
        err = capsys.readouterr().err
        assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "o").exists()


def test_psp_surface_file_without_uncertainty(corner_case, tmp_path, capsys):
    """Plain ``psp --surface a.vtu``: pressure and ratio per face (cells) equal to
    pressure_faces.csv, and their node values (points) finite where a face has one."""
    import meshio

    from scenes.psp_uncertainty import write_psp_files
    from selfillum.cli.main import main

    args = write_psp_files(corner_case, tmp_path, 1)
    rc = main(args + ["--out", str(tmp_path / "o"), "--surface", str(tmp_path / "a.vtu")])
    assert rc == 0, capsys.readouterr().err
    faces = np.genfromtxt(tmp_path / "o" / "pressure_faces.csv", delimiter=",", names=True)
    m = meshio.read(tmp_path / "a.vtu")
    for n in ("pressure", "ratio"):
        np.testing.assert_allclose(m.cell_data[n][0], faces[n], rtol=1e-7, equal_nan=True)
        assert np.isfinite(m.point_data[n]).mean() > 0.9


def test_function_file_of_mesh_fields(tmp_path):
    """A Plot3D grid of two blocks: node fields to a ``.f`` land on the grid's own nodes
    (a linear function of the position comes back at every node, seam copies included),
    the ``.nam`` names the variables in order; face fields go to VTU cells."""
    import meshio

    from resection.io.meshes import load_mesh
    from resection.io.plot3d import write_plot3d
    from selfillum.surface_fields import write_mesh_fields

    u = np.linspace(0.0, 1.0, 7)
    v = np.linspace(0.0, 0.5, 5)
    U, V = np.meshgrid(u, v, indexing="ij")
    b1 = np.stack([U, V, np.zeros_like(U)], axis=-1)
    b2 = np.stack([U + 1.0, V, 0.1 * U], axis=-1)  # shares the seam x = 1
    write_plot3d(tmp_path / "g.xyz", [b1, b2])
    mesh = load_mesh(tmp_path / "g.xyz")
    X = np.asarray(mesh.vertices)
    nodes = {"cp_u": 0.01 + 0.002 * X[:, 0] + 0.003 * X[:, 1], "cp": X[:, 2] - 0.5}
    cfaces = np.asarray(mesh.triangles_center)
    faces = {"cp_u": 0.01 + 0.002 * cfaces[:, 0]}
    write_mesh_fields(tmp_path / "u.f", mesh, faces, nodes)
    blocks = read_function_file(tmp_path / "u.f")
    assert (tmp_path / "u.nam").read_text().split() == ["cp_u", "cp"]
    for blk, pts in zip(blocks, (b1, b2), strict=True):
        assert blk.shape == pts.shape[:2] + (1, 2)
        np.testing.assert_allclose(blk[:, :, 0, 0], 0.01 + 0.002 * pts[..., 0]
                                   + 0.003 * pts[..., 1], rtol=1e-12)
        np.testing.assert_allclose(blk[:, :, 0, 1], pts[..., 2] - 0.5, atol=1e-12)
    write_mesh_fields(tmp_path / "u.vtu", mesh, faces, nodes)
    m = meshio.read(tmp_path / "u.vtu")
    np.testing.assert_allclose(m.cell_data["cp_u"][0], faces["cp_u"], rtol=1e-12)
