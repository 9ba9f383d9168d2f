"""Mesh input (Plot3D, Cart3D, trimesh formats) and per-face output (PLY, VTK, CSV).

Hand-written files (text typed here, binary packed with ``struct``) check the readers
independently of the writers; the writers are then checked by round trips and by parsing
their output here."""

import struct

import numpy as np
import pandas as pd
import pytest
import trimesh

from resection import InputError
from resection.io.meshes import (
    load_mesh,
    read_plot3d,
    write_cart3d_tri,
    write_plot3d,
    write_surface,
)

# Two blocks: a 3 x 2 grid in the plane z = 0 (x = i, y = j) and a 2 x 2 grid at z = 1
# (x = 5 + 2 i, y = j). Formatted Plot3D: nblocks, dims, then x, y, z of each block.
HAND_ASCII = """2
3 2 1
2 2 1
0 1 2 0 1 2
0 0 0 1 1 1
0 0 0 0 0 0
5.0 7.0 5.0 7.0
0.0D0 0.0D0 1.0D0 1.0D0
1 1 1 1
"""


def test_hand_written_ascii_multiblock(tmp_path):
    p = tmp_path / "wing.xyz"
    p.write_text(HAND_ASCII)
    m = load_mesh(p)
    assert len(m.faces) == 6  # 2 cells -> 4 triangles, 1 cell -> 2 triangles
    np.testing.assert_array_equal(m.face_attributes["block"], [1, 1, 1, 1, 2, 2])
    # blocks count from 1 everywhere: the block field and --unpainted agree
    from selfillum.solve.unseen import read_unpainted

    mask, _ = read_unpainted("2", m)
    np.testing.assert_array_equal(mask, m.face_attributes["block"] == 2)
    np.testing.assert_allclose(m.area_faces, [0.5, 0.5, 0.5, 0.5, 1.0, 1.0])
    # normals follow d/di x d/dj = +z
    np.testing.assert_allclose(m.face_normals, np.tile([0, 0, 1.0], (6, 1)), atol=1e-12)
    # first cell: corners (0,0), (1,0), (1,1), (0,1): triangles (p00,p10,p11), (p00,p11,p01)
    np.testing.assert_allclose(m.triangles[0], [[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    np.testing.assert_allclose(m.triangles[1], [[0, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_allclose(m.triangles_center[4], [(5 + 7 + 7) / 3, 1 / 3, 1.0])
    np.testing.assert_array_equal(m.face_attributes["cell_i"], [0, 0, 1, 1, 0, 0])


def test_ascii_fortran_repeat_counts(tmp_path):
    # list-directed output writes runs of equal values as n*value
    p = tmp_path / "rep.xyz"
    p.write_text("2\n3 2 1\n2 2 1\n0 1 2 0 1 2\n3*0 3*1\n6*0\n5.0 7.0 5.0 7.0\n"
                 "2*0.0D0 2*1.0D0\n4*1\n")
    ref = tmp_path / "ref.xyz"
    ref.write_text(HAND_ASCII)
    a, b = load_mesh(p), load_mesh(ref)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    p.write_text("1\n2 2 1\n0 1 0 1\n0 0 1 1\nx*0\n")
    with pytest.raises(InputError, match="bad repeat count"):
        load_mesh(p)


def _rec(fmt: str, *vals, endian=">") -> bytes:
    payload = struct.pack(endian + fmt, *vals)
    mark = struct.pack(endian + "i", len(payload))
    return mark + payload + mark


def test_hand_written_fortran_binary_single_precision_iblank(tmp_path):
    """Big-endian unformatted Fortran, float32, IBLANK; a 3 x 3 grid (x = i, y = j, z = i j)
    whose corner point (2, 2) is blanked: the cell (1, 1) is dropped."""
    ni, nj = 3, 3
    x = [i for j in range(nj) for i in range(ni)]
    y = [j for j in range(nj) for i in range(ni)]
    z = [i * j for j in range(nj) for i in range(ni)]
    ib = [1] * 8 + [0]
    data = _rec("i", 1) + _rec("3i", ni, nj, 1)
    data += _rec(f"{3 * ni * nj}f{ni * nj}i", *x, *y, *z, *ib)
    p = tmp_path / "grid.x"
    p.write_bytes(data)
    blocks = read_plot3d(p)
    assert len(blocks) == 1
    xyz, iblank = blocks[0]
    assert xyz.shape == (3, 3, 1, 3)
    np.testing.assert_allclose(xyz[2, 1, 0], [2, 1, 2])
    assert iblank[2, 2, 0] == 0 and iblank.sum() == 8
    m = load_mesh(p)
    assert len(m.faces) == 6
    cells = set(zip(m.face_attributes["cell_i"], m.face_attributes["cell_j"], strict=True))
    assert cells == {(0, 0), (1, 0), (0, 1)}


def test_hand_written_stream_binary_single_block(tmp_path):
    """Raw little-endian stream (no record markers), double precision, no IBLANK, no
    block count."""
    x = [0.0, 2.0, 0.0, 2.0]
    y = [0.0, 0.0, 3.0, 3.0]
    z = [1.0] * 4
    p = tmp_path / "plate.g"
    p.write_bytes(struct.pack("<3i", 2, 2, 1) + struct.pack("<12d", *x, *y, *z))
    m = load_mesh(p)
    assert len(m.faces) == 2 and m.area == pytest.approx(6.0)


def cylinder_blocks():
    """Two surface blocks of a cylinder of radius 1 (curved, non-trivial coordinates)."""
    out = []
    for b in range(2):
        th = np.linspace(b * np.pi / 2, (b + 1) * np.pi / 2, 7)
        zz = np.linspace(0.0, 2.0, 5)
        T, Z = np.meshgrid(th, zz, indexing="ij")
        out.append(np.stack([np.cos(T), np.sin(T), Z], axis=-1))  # (7, 5, 3): ni, nj
    return out


LAYOUTS = [(False, True, "<"), (True, True, "<"), (True, True, ">"), (True, False, "<"),
           (True, False, ">")]  # (binary, Fortran records, byte order); ASCII has no order


@pytest.mark.parametrize("binary,records,endian", LAYOUTS)
@pytest.mark.parametrize("precision", ["single", "double"])
@pytest.mark.parametrize("with_iblank", [False, True])
def test_plot3d_round_trip(tmp_path, binary, records, precision, with_iblank, endian):
    blocks = cylinder_blocks()
    ib = None
    if with_iblank:
        ib = [np.ones((7, 5, 1), int), np.ones((7, 5, 1), int)]
        ib[1][3, 2, 0] = 0  # blanks the 4 cells around point (3, 2) of block 2
    p = tmp_path / "cyl.xyz"
    write_plot3d(p, blocks, iblank=ib, binary=binary, precision=precision, endian=endian,
                 records=records)
    back = read_plot3d(p)
    tol = 1e-6 if precision == "single" else 1e-14
    for (xyz, bib), ref in zip(back, blocks, strict=True):
        np.testing.assert_allclose(xyz[:, :, 0], ref, atol=tol)
        assert (bib is None) == (not with_iblank)
    m = load_mesh(p)
    n_cells = 2 * 6 * 4 - (4 if with_iblank else 0)
    assert len(m.faces) == 2 * n_cells
    nb = np.bincount(m.face_attributes["block"]).tolist()
    assert nb == [0, 48, 48 - (8 if with_iblank else 0)]  # blocks 1 and 2
    # blocks share the seam at theta = pi/2: vertices merged
    assert len(m.vertices) == 2 * 35 - 5 - (1 if with_iblank else 0)  # blanked point unused
    # the triangles lie on the cylinder: vertices at radius 1, area below 2 pi / 4 * 2 * 2
    np.testing.assert_allclose(np.hypot(m.vertices[:, 0], m.vertices[:, 1]), 1.0, atol=tol)
    if not with_iblank:
        chord = 2 * np.sin(np.pi / 24)
        assert m.area == pytest.approx(12 * chord * 2.0, rel=1e-6)


def test_plot3d_collapsed_line_dropped(tmp_path):
    """A grid whose row i = 0 collapses to one point (a nose): the degenerate triangles are
    dropped, the others kept."""
    th = np.linspace(0, np.pi / 2, 5)
    r = np.linspace(0, 1, 4)
    R, T = np.meshgrid(r, th, indexing="ij")  # i along r: row i = 0 is the centre
    grid = np.stack([R * np.cos(T), R * np.sin(T), np.zeros_like(R)], axis=-1)
    p = tmp_path / "nose.xyz"
    write_plot3d(p, [grid], binary=False)
    m = load_mesh(p)
    assert len(m.faces) == 2 * 3 * 4 - 4
    assert m.area == pytest.approx(0.5 * 4 * np.sin(np.pi / 8), rel=1e-12)


def test_plot3d_errors(tmp_path):
    p = tmp_path / "vol.xyz"
    write_plot3d(p, [np.zeros((2, 2, 2, 3)) + np.arange(8).reshape(2, 2, 2, 1)])
    with pytest.raises(InputError, match="not a surface"):
        load_mesh(p)
    p2 = tmp_path / "bad.xyz"
    p2.write_text("1\n2 2 1\n0 1 0 1\n0 0 1 1\n0 0\n")  # z values missing
    with pytest.raises(InputError, match="does not fit a Plot3D grid"):
        load_mesh(p2)
    p3 = tmp_path / "nan.xyz"
    p3.write_text("2 2 1\n0 1 0 nan\n0 0 1 1\n0 0 0 0\n")
    with pytest.raises(InputError, match="NaN"):
        load_mesh(p3)
    with pytest.raises(InputError, match="not found"):
        load_mesh(tmp_path / "missing.xyz")
    (tmp_path / "empty.xyz").write_text("")
    with pytest.raises(InputError, match="empty"):
        load_mesh(tmp_path / "empty.xyz")
    # the writer refuses what the reader would refuse, and shapes that are not grids
    grid = np.zeros((3, 2, 3))
    grid[..., 0] = np.arange(3)[:, None]
    with pytest.raises(InputError, match=r"block 1 has shape \(3, 3\)"):
        write_plot3d(tmp_path / "w.xyz", [np.zeros((3, 3))])
    with pytest.raises(InputError, match="block 2 holds NaN"):
        write_plot3d(tmp_path / "w.xyz", [grid, np.full((2, 2, 3), np.nan)])
    with pytest.raises(InputError, match="IBLANK of block 1"):
        write_plot3d(tmp_path / "w.xyz", [grid], iblank=[np.ones((2, 2), int)])
    with pytest.raises(InputError, match="2 IBLANK arrays for 1 blocks"):
        write_plot3d(tmp_path / "w.xyz", [grid], iblank=[np.ones((3, 2), int)] * 2)
    assert not (tmp_path / "w.xyz").exists()


HAND_TRI = """5 3
0 0 0
1 0 0
1 1 0
0 1 0
0.5 0.5 1
1 2 3
1 3 4
1 2 5
7
7
12
"""


def test_cart3d_hand_written_and_round_trip(tmp_path):
    p = tmp_path / "model.tri"
    p.write_text(HAND_TRI)
    m = load_mesh(p)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    np.testing.assert_array_equal(m.face_attributes["component"], [7, 7, 12])
    np.testing.assert_allclose(m.area_faces[2], 0.5 * np.sqrt(1 + 0.25))
    q = tmp_path / "again.tri"
    write_cart3d_tri(q, m)
    m2 = load_mesh(q)
    np.testing.assert_array_equal(m2.faces, m.faces)
    np.testing.assert_array_equal(m2.vertices, m.vertices)
    np.testing.assert_array_equal(m2.face_attributes["component"], [7, 7, 12])
    # without component ids
    p.write_text("\n".join(HAND_TRI.splitlines()[:9]) + "\n")
    np.testing.assert_array_equal(load_mesh(p).face_attributes["component"], [1, 1, 1])
    p.write_text(HAND_TRI.replace("1 2 5", "1 2 6"))
    with pytest.raises(InputError, match="1-based"):
        load_mesh(p)
    p.write_text(HAND_TRI.replace("1 3 4", "1 3 3"))
    with pytest.raises(InputError, match="degenerate triangle.*face 1"):
        load_mesh(p)


@pytest.mark.parametrize("suffix", ["stl", "obj", "ply", "off", "glb"])
def test_trimesh_formats_keep_face_order(tmp_path, suffix):
    src = trimesh.creation.icosphere(subdivisions=1)
    p = tmp_path / f"s.{suffix}"
    src.export(p)
    m = load_mesh(p)
    assert len(m.faces) == len(src.faces)
    # process=False: same triangles in the same order
    np.testing.assert_allclose(m.triangles, src.triangles, atol=1e-6)
    # coincident vertices merged (STL stores 3 per triangle): faces share vertices
    assert len(m.vertices) == len(src.vertices)
    assert len(load_mesh(p, merge_vertices=False).vertices) >= len(src.vertices)


def test_glb_scene_components(tmp_path):
    a = trimesh.creation.box()
    b = trimesh.creation.icosphere(subdivisions=1)
    b.apply_translation([3, 0, 0])
    scene = trimesh.Scene([a, b])
    p = tmp_path / "two.glb"
    scene.export(p)
    m = load_mesh(p)
    assert len(m.faces) == len(a.faces) + len(b.faces)
    comp = m.face_attributes["component"]
    assert sorted(np.bincount(comp).tolist()) == sorted([len(a.faces), len(b.faces)])


def test_degenerate_nan_empty_refused(tmp_path):
    p = tmp_path / "deg.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 4\nf 1 2 3\n")
    with pytest.raises(InputError, match="degenerate"):
        load_mesh(p)
    p = tmp_path / "nan.obj"
    p.write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="NaN"):
        load_mesh(p)
    p = tmp_path / "empty.obj"
    p.write_text("# nothing\n")
    with pytest.raises(InputError, match="empty|no triangles"):
        load_mesh(p)


# --------------------------------------------------------------------------- writers
def _mesh_and_fields():
    m = trimesh.creation.icosphere(subdivisions=1)
    m = trimesh.Trimesh(m.vertices, m.faces, process=False)
    nf = len(m.faces)
    m.face_attributes["block"] = np.arange(nf) % 3
    f = {"Cp": np.linspace(-1, 1, nf), "seen": np.arange(nf) % 2 == 0,
         "grad": np.column_stack([np.arange(nf), -np.arange(nf)]) * 0.25}
    f["Cp"][5] = np.nan
    return m, f


def test_ply_round_trip(tmp_path):
    m, f = _mesh_and_fields()
    p = tmp_path / "out.ply"
    write_surface(p, m, f)
    raw = trimesh.load(p, process=False)  # trimesh's own reader
    np.testing.assert_array_equal(raw.faces, m.faces)
    np.testing.assert_allclose(raw.vertices, m.vertices, rtol=0, atol=0)
    data = raw.metadata["_ply_raw"]["face"]["data"]
    np.testing.assert_array_equal(data["Cp"], f["Cp"])  # NaN compares equal here
    np.testing.assert_array_equal(data["seen"], f["seen"])
    np.testing.assert_array_equal(data["grad_1"], f["grad"][:, 1])
    np.testing.assert_array_equal(data["block"], m.face_attributes["block"])
    back = load_mesh(p)
    np.testing.assert_array_equal(back.face_attributes["Cp"], f["Cp"])


def test_vtk_cell_data_read_by_vtk(tmp_path):
    """VTK's own legacy reader (the one ParaView uses) reads the mesh and every field."""
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    m, f = _mesh_and_fields()
    p = tmp_path / "out.vtk"
    write_surface(p, m, f)
    r = vtk.vtkUnstructuredGridReader()
    r.SetFileName(str(p))
    r.ReadAllScalarsOn()
    r.ReadAllFieldsOn()
    r.Update()
    g = r.GetOutput()
    np.testing.assert_array_equal(vtk_to_numpy(g.GetPoints().GetData()), m.vertices)
    assert g.GetNumberOfCells() == len(m.faces)
    assert {g.GetCellType(i) for i in range(g.GetNumberOfCells())} == {5}  # VTK_TRIANGLE
    conn = vtk_to_numpy(g.GetCells().GetConnectivityArray())
    np.testing.assert_array_equal(conn.reshape(-1, 3), m.faces)
    cd = g.GetCellData()
    fields = {cd.GetArrayName(i): vtk_to_numpy(cd.GetArray(i))
              for i in range(cd.GetNumberOfArrays())}
    np.testing.assert_array_equal(fields["Cp"], f["Cp"])
    np.testing.assert_array_equal(fields["seen"], f["seen"].astype(np.uint8))
    assert fields["seen"].dtype == np.uint8
    np.testing.assert_array_equal(fields["grad_0"], f["grad"][:, 0])
    np.testing.assert_array_equal(fields["block"], m.face_attributes["block"])


def test_csv_output(tmp_path):
    m, f = _mesh_and_fields()
    p = tmp_path / "out.csv"
    write_surface(p, m, f)
    df = pd.read_csv(p)
    assert list(df.columns[:4]) == ["face", "cx", "cy", "cz"]
    np.testing.assert_array_equal(df["face"], np.arange(len(m.faces)))
    np.testing.assert_allclose(df[["cx", "cy", "cz"]].to_numpy(), m.triangles_center,
                               rtol=1e-15)
    np.testing.assert_array_equal(df["Cp"].to_numpy(), f["Cp"])
    np.testing.assert_array_equal(df["grad_1"].to_numpy(), f["grad"][:, 1])


def test_writer_errors(tmp_path):
    m, _ = _mesh_and_fields()
    with pytest.raises(InputError, match="'p'.*faces"):
        write_surface(tmp_path / "x.vtk", m, {"p": np.zeros(3)})
    with pytest.raises(InputError, match="unknown field file format"):
        write_surface(tmp_path / "x.xyz", m, {})


def test_read_face_fields(tmp_path):
    from resection.io.meshes import read_face_fields

    m, f = _mesh_and_fields()
    nf = len(m.faces)
    for suffix in ("ply", "csv"):
        p = tmp_path / f"out.{suffix}"
        write_surface(p, m, f)
        got = read_face_fields(p, nf)
        np.testing.assert_array_equal(got["Cp"], f["Cp"])
        np.testing.assert_array_equal(got["grad_1"], f["grad"][:, 1])
        np.testing.assert_array_equal(got["block"], m.face_attributes["block"])
    np.save(tmp_path / "v.npy", np.arange(nf, dtype=float))
    np.testing.assert_array_equal(read_face_fields(tmp_path / "v.npy")["values"], np.arange(nf))
    with pytest.raises(InputError, match="has 80 values but the mesh has 81 faces"):
        read_face_fields(tmp_path / "v.npy", nf + 1)
    with pytest.raises(InputError, match="not found"):
        read_face_fields(tmp_path / "none.csv")


def test_hand_written_cart3d_fortran_binary(tmp_path):
    """Little-endian unformatted Cart3D: (nv, nt), float32 vertices, 1-based triangles,
    component ids."""
    verts = [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1]
    tris = [1, 2, 3, 1, 2, 4]
    data = (_rec("2i", 4, 2, endian="<") + _rec("12f", *verts, endian="<")
            + _rec("6i", *tris, endian="<") + _rec("2i", 3, 9, endian="<"))
    p = tmp_path / "bin.tri"
    p.write_bytes(data)
    m = load_mesh(p)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 1, 3]])
    np.testing.assert_array_equal(m.face_attributes["component"], [3, 9])
    assert m.area == pytest.approx(1.0)


def test_hand_written_plot3d_8_byte_record_markers(tmp_path):
    """gfortran -frecord-marker=8, little-endian, double precision, single block."""
    def rec8(fmt, *vals):
        payload = struct.pack("<" + fmt, *vals)
        mark = struct.pack("<q", len(payload))
        return mark + payload + mark

    x, y, z = [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 2.0, 2.0], [0.5] * 4
    p = tmp_path / "g8.x"
    p.write_bytes(rec8("3i", 2, 2, 1) + rec8("12d", *x, *y, *z))
    m = load_mesh(p)
    assert len(m.faces) == 2 and m.area == pytest.approx(2.0)
    np.testing.assert_allclose(m.vertices[:, 2], 0.5)
