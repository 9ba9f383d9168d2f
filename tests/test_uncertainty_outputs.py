"""``--surface FILE`` on ``selfillum psp`` (with and without ``--uncertainty``) and
``selfillum unsteady``: the uncertainty fields in VTU, XDMF and Plot3D function files,
read back by independent readers (meshio for VTU; the XDMF's XML parsed with the standard
library and its HDF5 data read with h5py; Plot3D function files read with plain NumPy
following the format: Fortran records of ``nblocks``, ``ni nj nk nvar`` per block, then
each block's variables, ``i`` fastest) and compared with the command's CSV / HDF5."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest


def read_function_file(path) -> list:
    """A multi-block Plot3D function file by hand: (ni, nj, nk, nvar) per block."""
    raw = open(path, "rb").read()  # noqa: SIM115
    recs, pos = [], 0
    while pos < len(raw):
        n = int(np.frombuffer(raw, "<i4", 1, pos)[0])
        recs.append(raw[pos + 4:pos + 4 + n])
        assert np.frombuffer(raw, "<i4", 1, pos + 4 + n)[0] == n
        pos += n + 8
    nb = int(np.frombuffer(recs[0], "<i4")[0])
    dims = np.frombuffer(recs[1], "<i4").reshape(nb, 4)
    out = []
    for r, (ni, nj, nk, nv) in zip(recs[2:], dims, strict=True):
        v = np.frombuffer(r, "<f8").reshape(nv, nk, nj, ni)
        out.append(np.transpose(v, (3, 2, 1, 0)))
    return out


def read_xdmf_attribute(path, name: str, center: str) -> np.ndarray:
    """The named attribute of an XDMF file: its DataItem's ``file:/dataset`` read with
    h5py (the file beside the XDMF)."""
    root = ET.parse(path).getroot()
    for att in root.iter("Attribute"):
        if att.get("Name") == name and att.get("Center") == center:
            fname, ds = att.find("DataItem").text.strip().split(":")
            with h5py.File(path.parent / fname) as f:
                return f[ds][()]
    raise KeyError(name)


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


def test_unsteady_surface_files(tmp_path, capsys):
    """``unsteady --uncertainty --surface a.f --surface a.vtu``: the per-node fields (steady
    cp, dcp_rms, dcp_u, dcp_u_gain, the RMS without the noise, the noise floor) in the
    Plot3D function file (grid file order: blocks one after the other, ``i`` fastest),
    the VTU's points and the run's own XDMF, equal to the HDF5's datasets."""
    import meshio

    from scenes.unsteady_run import make_unsteady_run
    from selfillum.cli import main

    run = make_unsteady_run(tmp_path, faces=800, frames=40, width=120, height=90,
                            noise=0.01, vibration_deg=0.0, heave_m=0.0, amplitude=0.1)
    out, f_file, vtu = tmp_path / "u.h5", tmp_path / "a.f", tmp_path / "a.vtu"
    rc = main(["unsteady", str(run.deck), "--paint-calibration", str(run.paint), "--steady",
               str(run.steady), "--fps", str(run.fps), "--out", str(out), "--quiet",
               "--no-plots", "--uncertainty", "--u", "gain_a=0.01", "--surface", str(f_file),
               "--surface", str(vtu)])
    assert rc == 0, capsys.readouterr().err
    want = {"cp": "steady/cp", "dcp_rms": "stats/dcp_rms", "dcp_u": "dcp_u",
            "dcp_u_gain": "dcp_u_gain", "dcp_rms_signal": "stats/dcp_rms_signal",
            "dcp_rms_signal_u": "stats/dcp_rms_signal_u", "noise_floor": "psd/noise_floor"}
    with h5py.File(out) as f:
        ref = {k: f[d][()].astype(np.float64) for k, d in want.items()}
    names = (tmp_path / "a.nam").read_text().split()
    assert set(want) <= set(names)
    blocks = read_function_file(f_file)
    flat = np.concatenate([b.reshape(-1, b.shape[3], order="F") for b in blocks])
    m = meshio.read(vtu)
    for k, v in ref.items():
        assert np.isfinite(v).sum() > 100, k
        np.testing.assert_allclose(flat[:, names.index(k)], v, rtol=1e-6, equal_nan=True)
        np.testing.assert_allclose(m.point_data[k], v, rtol=1e-6, equal_nan=True)
        if k != "cp":
            np.testing.assert_allclose(read_xdmf_attribute(out.with_suffix(".xdmf"), k,
                                                           "Node"), v, rtol=1e-6,
                                       equal_nan=True)
    with h5py.File(out) as f:
        np.testing.assert_allclose(m.points, f["grid/points"][()])
    # bad --surface paths: one line, exit 2, before any work, nothing written
    base = ["unsteady", str(run.deck), "--paint-calibration", str(run.paint), "--steady",
            str(run.steady), "--fps", str(run.fps), "--quiet", "--no-plots"]
    for bad, msg in ((vtu, "exists"), (tmp_path / "b.npy", "unknown format"),
                     (run.steady, "is an input")):
        rc = main(base + ["--out", str(tmp_path / "v.h5"), "--surface", str(bad)])
        err = capsys.readouterr().err
        assert rc == 2 and msg in err and len(err.strip().splitlines()) == 1, err
        assert not (tmp_path / "v.h5").exists()
