"""Per-face / per-node field files (meshio: VTK, VTU, XDMF; plyfile: PLY; CSV; NPY; Plot3D
.f): round trips, independent readers (XML parse of XDMF, trimesh for PLY, the VTK test
parser in test_io_meshes), and the commands reading what ``map`` writes."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh

from resection import InputError
from resection.cli.main import main
from resection.io.cameras import write_camera
from resection.io.fields import read_fields, write_fields
from resection.io.meshes import write_plot3d
from resection.io.plot3d import read_plot3d_function


def _mesh_and_fields():
    m = trimesh.creation.icosphere(subdivisions=1)
    m = trimesh.Trimesh(m.vertices, m.faces, process=False)
    nf = len(m.faces)
    rng = np.random.default_rng(3)
    cp = rng.normal(size=nf)
    cp[[2, 7]] = np.nan
    return m, {"Cp": cp, "seen": rng.random(nf) > 0.3, "count": rng.integers(0, 50, nf),
               "grad": rng.normal(size=(nf, 2))}


@pytest.mark.parametrize("ext", [".vtk", ".vtu", ".xdmf", ".ply", ".csv"])
def test_face_fields_round_trip(tmp_path, ext):
    m, f = _mesh_and_fields()
    p = tmp_path / f"surf{ext}"
    write_fields(p, m, f)
    got = read_fields(p, len(m.faces))
    np.testing.assert_array_equal(got["Cp"], f["Cp"])  # NaN kept, values exact
    np.testing.assert_array_equal(got["seen"], f["seen"].astype(float))
    np.testing.assert_array_equal(got["count"], f["count"])
    np.testing.assert_array_equal(got["grad_1"], f["grad"][:, 1])
    assert not list(tmp_path.glob(".*tmp*"))  # no temporary file left behind


@pytest.mark.parametrize("ext", [".vtu", ".xdmf", ".ply"])
def test_node_fields_round_trip(tmp_path, ext):
    m, _ = _mesh_and_fields()
    z = np.asarray(m.vertices)[:, 2].copy()
    p = tmp_path / f"nodes{ext}"
    write_fields(p, m, node_fields={"height": z}, include_attributes=False)
    got = read_fields(p, len(m.vertices), location="node")
    np.testing.assert_array_equal(got["height"], z)


def test_xdmf_light_data_in_xml_heavy_data_in_hdf5(tmp_path):
    """Issue 34 item 8: the XDMF file held every value inline (100 MB for two cameras on a
    real grid). The XML holds the structure; an XML parser finds the HDF5 paths of the
    triangles and the per-face values (Center="Cell"), read here with h5py, and VTK's own
    XDMF reader (ParaView's) reads the fields."""
    import h5py
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    m, f = _mesh_and_fields()
    p = tmp_path / "surf.xdmf"
    write_fields(p, m, {"Cp": f["Cp"], "count": f["count"]}, include_attributes=False)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["surf.data.h5", "surf.xdmf"]
    root = ET.parse(p).getroot()
    topo = root.find(".//Topology")
    assert topo.get("TopologyType") == "Triangle"

    def heavy(item):
        assert item.get("Format") == "HDF"
        name, key = item.text.strip().split(":", 1)
        with h5py.File(tmp_path / name) as h:
            return h[key][()]

    np.testing.assert_array_equal(heavy(topo.find("DataItem")), m.faces)
    att = [a for a in root.iter("Attribute") if a.get("Name") == "Cp"][0]
    assert att.get("Center") == "Cell"
    np.testing.assert_array_equal(heavy(att.find("DataItem")), f["Cp"])
    reader = vtk.vtkXdmfReader()
    reader.SetFileName(str(p))
    reader.Update()
    grid = reader.GetOutputDataObject(0)
    assert grid.GetNumberOfCells() == len(m.faces)
    np.testing.assert_array_equal(vtk_to_numpy(grid.GetCellData().GetArray("Cp")), f["Cp"])
    np.testing.assert_array_equal(vtk_to_numpy(grid.GetCellData().GetArray("count")),
                                  f["count"])


def test_xdmf_of_the_real_grid_is_small_and_its_hdf5_is_never_the_users(upsp_samples,
                                                                        tmp_path):
    from resection.io.meshes import load_mesh

    mesh = load_mesh(upsp_samples / "fml_tc3_volume.grid")
    nf = len(mesh.faces)
    rng = np.random.default_rng(0)
    fields = {f"cam{k}": rng.normal(size=nf) for k in range(4)}
    p = tmp_path / "two.xdmf"
    write_fields(p, mesh, fields)
    assert p.stat().st_size < 10_000  # the structure only: 609,120 faces x 6 fields in HDF5
    got = read_fields(p, nf)
    np.testing.assert_array_equal(got["cam3"], fields["cam3"])
    write_fields(p, mesh, fields)  # its own data file is replaced
    other = tmp_path / "user.xdmf"
    (tmp_path / "user.data.h5").write_bytes(b"the user's")
    with pytest.raises(InputError, match=r"user\.data\.h5: exists and is not the data of "
                                         r"user\.xdmf"):
        write_fields(other, mesh, fields)
    assert (tmp_path / "user.data.h5").read_bytes() == b"the user's"


def test_ply_read_by_trimesh(tmp_path):
    m, f = _mesh_and_fields()
    p = tmp_path / "surf.ply"
    write_fields(p, m, f)
    raw = trimesh.load(p, process=False)
    np.testing.assert_array_equal(raw.vertices, m.vertices)  # doubles: exact
    data = raw.metadata["_ply_raw"]["face"]["data"]
    np.testing.assert_array_equal(data["Cp"], f["Cp"])
    np.testing.assert_array_equal(data["count"], f["count"])


def test_npy_and_errors(tmp_path):
    m, f = _mesh_and_fields()
    write_fields(tmp_path / "cp.npy", m, {"Cp": f["Cp"]})
    np.testing.assert_array_equal(read_fields(tmp_path / "cp.npy")["values"], f["Cp"])
    with pytest.raises(InputError, match="holds one field"):
        write_fields(tmp_path / "two.npy", m, {"a": f["Cp"], "b": f["Cp"]})
    with pytest.raises(InputError, match="unknown field file format '.txt'"):
        write_fields(tmp_path / "x.txt", m, f)
    with pytest.raises(InputError, match="does not match"):
        write_fields(tmp_path / "x.vtu", m, {"a": np.zeros(3)})
    bad = tmp_path / "bad.vtu"
    bad.write_text("<VTKFile><Unstructured")
    with pytest.raises(InputError, match=r"bad.vtu: cannot be read as VTU"):
        read_fields(bad)
    with pytest.raises(InputError, match="has 20 faces|values but the mesh"):
        read_fields(tmp_path / "cp.npy", 7)


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    from scenes.psp_pair import HALF_X, HALF_Y, plane_hits, psp_pair

    d = tmp_path_factory.mktemp("fields_cli")
    pp = psp_pair(width=160, height=120, noise=0.0)
    X, Y = np.meshgrid(np.linspace(-HALF_X, HALF_X, 25), np.linspace(-HALF_Y, HALF_Y, 17),
                       indexing="ij")
    write_plot3d(d / "panel.grid", [np.stack([X, Y, np.zeros_like(X)], -1)])  # by content
    write_camera(d / "off.json", pp.camera_off)
    P, on = plane_hits(pp.camera_off)
    np.save(d / "xcoord.npy", np.where(on, P[..., 0], np.nan))
    return d, X


@pytest.mark.parametrize("ext", [".vtk", ".vtu", ".xdmf", ".ply"])
def test_view_and_backproject_read_what_map_writes(plate, ext, capsys):
    d, _ = plate
    out = d / f"surf{ext}"
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(out)]) == 0
    fields = read_fields(out)
    seen = fields["xcoord_seen"] > 0
    assert seen.sum() > 50
    assert main(["backproject", "--mesh", str(d / "panel.grid"), "--camera",
                 str(d / "off.json"), "--values", str(out), "--field", "xcoord",
                 "--out", str(d / f"back{ext}.npy")]) == 0
    assert main(["view", "--mesh", str(d / "panel.grid"), "--values", str(out), "--field",
                 "xcoord", "--size", "120x90", "--out", str(d / f"view{ext}.png")]) == 0
    assert (d / f"view{ext}.png").stat().st_size > 0
    capsys.readouterr()


def test_map_xdmf_names_its_data_file_by_the_final_name(plate, tmp_path, capsys):
    """``map --out m.xdmf`` leaves ``m.xdmf`` and ``m.data.h5`` only, the XML naming
    ``m.data.h5`` (the command once wrote through a temporary name, so the XML named a
    temporary data file that was never renamed), and its values are the data file's."""
    import h5py

    d, _ = plate
    out = tmp_path / "m.xdmf"
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(out)]) == 0
    capsys.readouterr()
    assert sorted(x.name for x in tmp_path.iterdir()) == ["m.data.h5", "m.xdmf"]
    items = ET.parse(out).getroot().findall(".//DataItem")
    assert items and {i.text.split(":")[0] for i in items} == {"m.data.h5"}
    with h5py.File(tmp_path / "m.data.h5") as f:
        seen = f["cell/xcoord_seen"][()]
        assert seen.sum() > 50
        np.testing.assert_array_equal(read_fields(out)["xcoord_seen"], seen)


def test_map_writes_plot3d_function_file(plate):
    """``--out P.f`` on a Plot3D grid: per-node values on the original grid with a ``.nam``
    sidecar naming them, and one definition of a node value: the .f holds, for the same
    image, exactly the node values of the .h5 time history (``--per node``). The image holds
    the x coordinate of the plate under each pixel, so a node's value is its own x to a
    fraction of the grid spacing (closed form)."""
    from resection.io.history import read_history
    from resection.io.meshes import load_mesh

    d, X = plate
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(d / "P.f")]) == 0
    (vals,) = read_plot3d_function(d / "P.f")
    assert vals.shape == (25, 17, 1, 3)
    assert (d / "P.nam").read_text() == "xcoord\nxcoord_count\nxcoord_seen\n"
    v = vals[..., 0, 0]
    fin = np.isfinite(v)
    inner = np.zeros_like(fin)  # nodes whose eight neighbours have values: seen all round
    inner[1:-1, 1:-1] = np.all([fin[1 + di:fin.shape[0] - 1 + di, 1 + dj:fin.shape[1] - 1 + dj]
                                for di in (-1, 0, 1) for dj in (-1, 0, 1)], axis=0)
    assert inner.sum() > 40
    dx = X[1, 0] - X[0, 0]
    assert np.max(np.abs(v[inner] - X[inner])) < 0.1 * dx
    # the same image to a time history, per node: the same values
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(d / "P.h5"),
                 "--per", "node"]) == 0
    h = read_history(d / "P.h5")
    mesh = load_mesh(d / "panel.grid")
    node_vertex = mesh.metadata["plot3d_node_vertex"].reshape(25, 17)
    np.testing.assert_array_equal(np.asarray(h.points), mesh.vertices)
    hv = h.values[0][node_vertex]
    assert hv.dtype == np.float32  # the history stores float32: the .f's values, rounded
    np.testing.assert_array_equal(v.astype(np.float32), hv)


def test_merged_plot3d_function_file_named(plate):
    """A merge written to ``.f``: node values with a ``.nam`` naming every variable in file
    order; a camera's node values are those of ``map`` with that camera alone."""
    d, _ = plate
    img2 = d / "xcopy.npy"
    img2.write_bytes((d / "xcoord.npy").read_bytes())
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--camera", str(d / "off.json"),
                 "--image", str(img2), "--out", str(d / "M.f"), "--no-gain-match"]) == 0
    names = (d / "M.nam").read_text().splitlines()
    assert names == ["merged", "merged_weight", "merged_cameras", "merged_seen", "xcoord",
                     "xcoord_weight", "xcopy", "xcopy_weight"]
    (vals,) = read_plot3d_function(d / "M.f")
    assert vals.shape[-1] == len(names)
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(d / "S.f")]) == 0
    (single,) = read_plot3d_function(d / "S.f")
    np.testing.assert_array_equal(vals[..., names.index("xcoord")], single[..., 0])
    # two identical views: the merged value is the view's value wherever it has weight
    w = vals[..., names.index("merged_weight")] > 0
    np.testing.assert_allclose(vals[..., 0][w], single[..., 0][w], rtol=1e-12)


def _read_with_vtk(path):
    """Cell and point arrays of a legacy .vtk as VTK's own reader (ParaView's) gives them."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    r = vtk.vtkUnstructuredGridReader()
    r.SetFileName(str(path))
    r.ReadAllScalarsOn()
    r.ReadAllVectorsOn()
    r.ReadAllFieldsOn()
    r.Update()
    g = r.GetOutput()

    def arrays(data):
        return {data.GetArrayName(i): vtk_to_numpy(data.GetArray(i))
                for i in range(data.GetNumberOfArrays())}

    return g, arrays(g.GetCellData()), arrays(g.GetPointData())


def test_legacy_vtk_read_by_vtk_with_every_field(tmp_path):
    """VTK's legacy reader sees every field of our .vtk (booleans as uint8); on today's main
    it dropped them all ('Unsupported data type: vtktypeint32')."""
    m, f = _mesh_and_fields()
    m.face_attributes["block"] = np.arange(len(m.faces)) % 3 + 1
    nodes = {"h": np.linspace(0.0, 1.0, len(m.vertices)), "on": np.arange(len(m.vertices)) % 2 == 0}
    p = tmp_path / "surf.vtk"
    write_fields(p, m, f, nodes)
    g, cells, points = _read_with_vtk(p)
    assert g.GetNumberOfCells() == len(m.faces) and g.GetNumberOfPoints() == len(m.vertices)
    assert set(cells) == {"block", "Cp", "seen", "count", "grad_0", "grad_1"}
    assert set(points) == {"h", "on"}
    np.testing.assert_array_equal(cells["Cp"], f["Cp"])  # NaN kept
    assert cells["seen"].dtype == np.uint8 and points["on"].dtype == np.uint8
    np.testing.assert_array_equal(cells["seen"], f["seen"].astype(np.uint8))
    np.testing.assert_array_equal(cells["count"], f["count"])
    np.testing.assert_array_equal(cells["grad_1"], f["grad"][:, 1])
    np.testing.assert_array_equal(cells["block"], m.face_attributes["block"])
    np.testing.assert_array_equal(points["h"], nodes["h"])
    np.testing.assert_array_equal(points["on"], nodes["on"].astype(np.uint8))
    from vtk.util.numpy_support import vtk_to_numpy

    np.testing.assert_array_equal(vtk_to_numpy(g.GetPoints().GetData()), m.vertices)


def test_nam_sidecar_never_replaces_a_file_it_did_not_make(plate, capsys):
    """``P.nam`` next to no ``P.f`` is someone else's file: refused, nothing written."""
    d, _ = plate
    (d / "Q.nam").write_text("mine\n")
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(d / "Q.f")]) == 2
    assert "Q.nam" in capsys.readouterr().err
    assert (d / "Q.nam").read_text() == "mine\n" and not (d / "Q.f").exists()


def test_map_refuses_a_users_file_by_the_xdmf_data_name_before_mapping(plate, capsys,
                                                                       monkeypatch):
    from resection.surface import surface_map

    d, _ = plate
    (d / "mine.data.h5").write_bytes(b"kept")

    def no_map(*a, **kw):
        raise AssertionError("mapped before the outputs were checked")

    monkeypatch.setattr(surface_map.SurfaceMap, "__init__", no_map)
    assert main(["map", "--mesh", str(d / "panel.grid"), "--camera", str(d / "off.json"),
                 "--image", str(d / "xcoord.npy"), "--out", str(d / "mine.xdmf")]) == 2
    assert "mine.data.h5: exists and is not the data of mine.xdmf" in capsys.readouterr().err
    assert (d / "mine.data.h5").read_bytes() == b"kept"
