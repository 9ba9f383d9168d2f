"""The trimesh-free surface (:class:`resection.trisurface.TriSurface`) and its readers
(:func:`resection.io.meshes.read_surface`), against trimesh as the independent reference:
the face geometry trimesh computes, the triangles trimesh reads from the same files, its
vertex merge, and the ``selfillum correct`` result with a trimesh mesh."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest
import trimesh

from resection import Camera
from resection.errors import InputError
from resection.io.cameras import write_camera
from resection.io.meshes import (
    load_mesh,
    merged,
    plot3d_to_surface,
    read_surface,
    write_cart3d_tri,
    write_plot3d,
    write_surface,
)
from resection.surface.surface_map import SurfaceMap
from resection.surface.visibility import RayCaster
from resection.trisurface import MERGE_DIGITS, ZERO_NORM, TriSurface, is_mesh
from scenes.corner import corner
from selfillum.mesh import check_mesh

TIGHT = {"rtol": 1e-12, "atol": 1e-15}  # the same arithmetic: equal but for rounding


def _sphere() -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=2)
    m.vertices = m.vertices * [1.0, 2.5, 0.4] + [3.0, -1.0, 7.0]  # not a unit sphere
    return m


def _camera() -> Camera:
    K = [[160.0, 0.0, 95.5], [0.0, 160.0, 71.5], [0.0, 0.0, 1.0]]
    return Camera.look_at([1.6, 0.5, 1.3], [0.3, 0.5, 0.3], [0.0, 1.0, 0.0], K=K,
                          width=192, height=144)


def test_constants_are_trimesh_s():
    assert MERGE_DIGITS == trimesh.util.decimal_to_digits(trimesh.tol.merge)
    assert ZERO_NORM == trimesh.util.TOL_ZERO


@pytest.mark.parametrize("which", ["sphere", "corner", "degenerate"])
def test_face_geometry_is_trimesh_s(which):
    if which == "sphere":
        ref = _sphere()
    elif which == "corner":
        ref = corner(resolution=6).mesh
    else:  # a zero-area face (repeated vertex) among good ones: trimesh gives a zero normal
        v = np.random.default_rng(3).normal(size=(30, 3))
        f = np.random.default_rng(4).integers(0, 30, size=(40, 3))
        f[7] = [5, 5, 9]
        ref = trimesh.Trimesh(v, f, process=False)
    s = TriSurface(ref.vertices, ref.faces)
    np.testing.assert_array_equal(s.triangles, ref.triangles)
    np.testing.assert_allclose(s.face_normals, ref.face_normals, **TIGHT)
    np.testing.assert_allclose(s.area_faces, ref.area_faces, **TIGHT)
    np.testing.assert_allclose(s.triangles_center, ref.triangles_center, **TIGHT)
    np.testing.assert_allclose(s.bounds, ref.bounds, **TIGHT)
    if which == "degenerate":
        assert not s.face_normals[7].any() and s.area_faces[7] == 0.0


def test_container_is_read_only_and_round_trips_through_trimesh():
    ref = _sphere()
    ref.face_attributes["component"] = np.arange(len(ref.faces)) % 3
    s = TriSurface.from_trimesh(ref)
    s.metadata["source"] = "x.ply"
    with pytest.raises(ValueError, match="read-only"):
        s.vertices[0, 0] = 1.0
    assert ref.vertices.flags.writeable  # the caller's array keeps its flags
    back = s.to_trimesh()
    assert isinstance(back, trimesh.Trimesh) and back.metadata["source"] == "x.ply"
    np.testing.assert_array_equal(back.faces, ref.faces)
    np.testing.assert_array_equal(back.vertices, ref.vertices)
    np.testing.assert_array_equal(back.face_attributes["component"],
                                  ref.face_attributes["component"])
    assert is_mesh(s) and is_mesh(ref) and not is_mesh(ref.vertices)


def test_consumers_accept_the_container_and_refuse_other_objects():
    sc = corner(resolution=6)
    s = TriSurface.from_trimesh(sc.mesh)
    a, b = SurfaceMap(s, _camera()), SurfaceMap(sc.mesh, _camera())
    np.testing.assert_array_equal(a.face_index, b.face_index)
    assert check_mesh(s) is s
    from resection.sequence.inputs import _mesh_normals  # trimesh's nearest-point query

    pts = sc.mesh.triangles_center[::7] + 0.01
    np.testing.assert_array_equal(_mesh_normals(s, pts, None),
                                  _mesh_normals(sc.mesh, pts, None))
    for call in (lambda: SurfaceMap("m.ply", _camera()), lambda: RayCaster([1, 2]),
                 lambda: check_mesh({"faces": []})):
        with pytest.raises(InputError, match="expected a trimesh.Trimesh or TriSurface"):
            call()


def test_merge_is_trimesh_s_on_a_soup():
    """Vertices repeated with offsets below and above trimesh's merge precision, and
    unused vertices: the same kept vertices, order and faces as ``merge_vertices``."""
    rng = np.random.default_rng(7)
    base = rng.uniform(-2, 2, size=(60, 3))
    jitter = rng.choice([0.0, 2e-9, 3e-8], size=(60, 1)) * rng.choice([-1, 1], size=(60, 3))
    v = np.vstack([base, base + jitter, rng.uniform(-2, 2, size=(5, 3))])  # 5 unused
    f = rng.integers(0, 120, size=(150, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    ref = trimesh.Trimesh(v, f, process=False)
    ref.merge_vertices(merge_tex=True, merge_norm=True)
    ours = merged(TriSurface(v, f, {"k": np.arange(len(f))}))
    np.testing.assert_array_equal(ours.vertices, ref.vertices)
    np.testing.assert_array_equal(ours.faces, ref.faces)
    np.testing.assert_array_equal(ours.face_attributes["k"], np.arange(len(f)))
    s = TriSurface(ref.vertices, ref.faces)
    assert merged(s) is s  # nothing to merge


def _files(tmp_path):
    """One file per format read without trimesh; ``(path, kwargs of the reference)``."""
    sph, sc = _sphere(), corner(resolution=6).mesh
    out = {}
    sph.export(tmp_path / "s.stl")
    out["stl binary"] = tmp_path / "s.stl"
    sc.export(tmp_path / "a.stl", file_type="stl_ascii")
    out["stl ascii"] = tmp_path / "a.stl"
    sph.export(tmp_path / "s.ply")
    out["ply binary"] = tmp_path / "s.ply"
    sc.export(tmp_path / "a.ply", encoding="ascii")
    out["ply ascii"] = tmp_path / "a.ply"
    fields = {"Cp": np.linspace(0, 1, len(sph.faces)), "seen": np.arange(len(sph.faces)) % 2}
    write_surface(tmp_path / "f.ply", sph, fields)
    out["ply fields"] = tmp_path / "f.ply"
    grid = corner(resolution=6).mesh  # trimesh writes its int64 face attributes
    grid.face_attributes["block"] = np.arange(len(grid.faces), dtype=np.int64) - 5
    grid.face_attributes["cell_i"] = np.arange(len(grid.faces), dtype=np.uint64) * 2**40
    grid.export(tmp_path / "g.ply")
    out["ply int64"] = tmp_path / "g.ply"
    ply = plyfile.PlyData.read(str(tmp_path / "f.ply"))
    ply.byte_order = ">"
    ply.write(str(tmp_path / "big.ply"))
    out["ply big-endian"] = tmp_path / "big.ply"
    return out


@pytest.mark.parametrize("kind", ["stl binary", "stl ascii", "ply binary", "ply ascii",
                                  "ply fields", "ply int64", "ply big-endian"])
@pytest.mark.parametrize("merge", [True, False])
def test_read_surface_reads_what_trimesh_reads(tmp_path, kind, merge):
    path = _files(tmp_path)[kind]
    ref = load_mesh(path, merge_vertices=merge)  # trimesh's reader and merge
    s = read_surface(path, merge_vertices=merge)
    assert isinstance(s, TriSurface)
    np.testing.assert_array_equal(s.vertices, ref.vertices)
    np.testing.assert_array_equal(s.faces, ref.faces)
    assert set(s.face_attributes) == set(ref.face_attributes)
    for k, v in ref.face_attributes.items():
        np.testing.assert_array_equal(s.face_attributes[k], v)
    assert s.metadata["source"] == ref.metadata["source"] == str(path)
    assert s.metadata["format"] == ref.metadata["format"]
    np.testing.assert_allclose(s.triangles, ref.triangles, **TIGHT)
    # trimesh may keep an STL's own float32 normals, computed before the corners were
    # rounded to float32 (edges of 0.3 at coordinates up to 7: 1e-6 relative)
    np.testing.assert_allclose(s.face_normals, ref.face_normals, rtol=0, atol=1e-5)


def test_plot3d_and_cart3d_merge_as_trimesh_does(tmp_path):
    """Plot3D blocks sharing a seam, a blanked point and a collapsed line; the Cart3D file
    of the merged grid. Reference: trimesh's ``merge_vertices`` of the unmerged triangles."""
    th = np.linspace(0, np.pi, 9)
    z = np.linspace(0, 2, 5)
    T, Z = np.meshgrid(th, z, indexing="ij")
    R = np.where(Z > 0, 1.0, 0.0)[..., None] * np.ones_like(T)[..., None]  # row z=0 collapses
    blk = np.concatenate([R * np.cos(T)[..., None], R * np.sin(T)[..., None], Z[..., None]],
                         axis=-1)
    halves = [blk[:5], blk[4:] + [0.0, 0.0, 1e-9]]  # seam repeated, below the merge precision
    ib = [np.ones((5, 5, 1), int), np.ones((5, 5, 1), int)]
    ib[1][2, 3, 0] = 0
    p = tmp_path / "g.xyz"
    write_plot3d(p, halves, iblank=ib, binary=True)
    s = read_surface(p)
    raw = plot3d_to_surface([(h[:, :, None, :], i) for h, i in zip(halves, ib, strict=True)],
                         merge_vertices=False)
    ref = trimesh.Trimesh(raw.vertices, raw.faces, process=False)
    ref.merge_vertices(merge_tex=True, merge_norm=True)
    np.testing.assert_array_equal(s.vertices, ref.vertices)
    np.testing.assert_array_equal(s.faces, ref.faces)
    assert isinstance(s, TriSurface) and s.metadata["format"] == "plot3d"
    assert len(s.vertices) < len(raw.vertices)  # the seam merged
    nv = s.metadata["plot3d_node_vertex"]
    used = nv >= 0
    np.testing.assert_allclose(s.vertices[nv[used]], raw.vertices[used], atol=1e-8)
    as_trimesh = load_mesh(p)
    np.testing.assert_array_equal(as_trimesh.faces, s.faces)
    np.testing.assert_array_equal(as_trimesh.face_attributes["block"],
                                  s.face_attributes["block"])
    q = tmp_path / "g.tri"
    write_cart3d_tri(q, ref)
    c = read_surface(q)
    np.testing.assert_allclose(c.vertices, ref.vertices, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(c.faces, ref.faces)
    assert c.metadata["format"] == "cart3d"


def test_other_files_still_go_through_trimesh(tmp_path):
    """A PLY of quads and an ASCII STL of two solids: trimesh's result, unchanged."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], float)
    text = ("ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
            "property float z\nelement face 2\nproperty list uchar int vertex_indices\n"
            "end_header\n" + "\n".join(" ".join(str(c) for c in r) for r in v)
            + "\n4 0 1 2 3\n4 1 4 5 2\n")
    (tmp_path / "q.ply").write_text(text)
    got = read_surface(tmp_path / "q.ply")
    assert isinstance(got, trimesh.Trimesh) and len(got.faces) == 4
    ply = plyfile.PlyData.read(str(tmp_path / "q.ply"))
    ply.text = False
    ply.write(str(tmp_path / "qb.ply"))
    got = read_surface(tmp_path / "qb.ply")
    assert isinstance(got, trimesh.Trimesh) and len(got.faces) == 4
    solid = trimesh.creation.box().export(file_type="stl_ascii")
    (tmp_path / "two.stl").write_text(solid + "\n" + solid.replace("solid", "solid b"))
    two = read_surface(tmp_path / "two.stl", merge_vertices=False)
    assert isinstance(two, trimesh.Trimesh)
    np.testing.assert_array_equal(np.bincount(two.face_attributes["component"]), [12, 12])
    with pytest.raises(InputError, match="bad.ply: cannot be read as a mesh"):
        (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex x\n")
        read_surface(tmp_path / "bad.ply")


@pytest.fixture(scope="module")
def corner_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("corner")
    sc = corner(resolution=8)
    cam = _camera()
    sc.mesh.export(d / "corner.ply")
    sc.mesh.export(d / "corner.stl")
    write_camera(d / "cam.json", cam)
    smap = SurfaceMap(sc.mesh, cam)
    img = np.where(smap.mask, 1.0 + 0.5 * smap.to_image(sc.mesh.triangles_center[:, 0]),
                   np.nan).astype(np.float32)
    np.save(d / "img.npy", img)
    return d


@pytest.mark.parametrize("mesh", ["corner.ply", "corner.stl"])
def test_correct_command_gives_the_trimesh_result(corner_files, mesh):
    """``selfillum correct`` (which reads the file into a TriSurface) gives the corrected
    image of ``correct_image`` with trimesh's mesh of the same file. That it runs without
    importing trimesh is tests/test_package.py's."""
    from selfillum.cli.main import main
    from selfillum.images.image_correction import correct_image

    d = corner_files
    out = d / f"out_{mesh}.npy"
    assert main(["correct", "--mesh", str(d / mesh), "--camera", str(d / "cam.json"),
                 "--image", str(d / "img.npy"), "--reflectance", "0.6", "--rays", "64",
                 "--out", str(out), "--quiet"]) == 0
    ref = correct_image(np.load(d / "img.npy"), load_mesh(d / mesh), _camera(), 0.6,
                        rays_per_face=64)
    got = np.load(out)
    ok = np.isfinite(ref.image)
    np.testing.assert_array_equal(np.isfinite(got), ok)
    assert ok.sum() > 1000
    # PLY: the same arithmetic; STL: trimesh's float32 file normals may move a ray
    np.testing.assert_allclose(got[ok], ref.image[ok], rtol=1e-5 if mesh.endswith("ply")
                               else 1e-3, atol=1e-6)
    assert not np.allclose(got[ok], np.load(d / "img.npy")[ok], rtol=1e-3)  # corrected
