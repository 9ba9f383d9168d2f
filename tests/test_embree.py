"""The Embree binding (resection.surface.embree) and the view factors' fused row kernel,
against embreex's own scene (the same Embree library, built and traced by embreex's copy
and its ``EmbreeScene.run``)."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from resection._threads import numba_threads
from resection.errors import InputError
from resection.surface import embree
from selfillum.transport.sampling import _shifts, _tangent_frames, digital_shifts, sample_rays
from selfillum.transport.viewfactors import RowTracer, view_factors

#: Rays whose first hit may differ between two float32 traversals of the same scene
#: (rays grazing an edge or a vertex): at most this fraction (measured: none of 400,000
#: in robust mode, 1-2 in 500,000 without it).
GRAZING = 1e-4


def _embreex_hits(vertices, faces, o, d):
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=scene, vertices=np.asarray(vertices, np.float32),
                 indices=np.asarray(faces, np.int32))
    return np.asarray(scene.run(np.ascontiguousarray(o, np.float32),
                                np.ascontiguousarray(d, np.float32)))


def _closed():
    return trimesh.creation.icosphere(subdivisions=4)  # 5120 faces, closed


def _open():
    m = trimesh.creation.annulus(r_min=0.3, r_max=1.0, height=0.5, sections=48)
    keep = np.abs(m.face_normals[:, 2]) < 0.5  # the two cylinders, no caps: open
    return trimesh.Trimesh(m.vertices, m.faces[keep])


@pytest.mark.parametrize("make", [_closed, _open])
def test_first_hits_equal_embreex(make):
    mesh = make()
    rng = np.random.default_rng(7)
    n = 200_000
    o = (rng.normal(size=(n, 3)) * 0.6).astype(np.float32)
    d = rng.normal(size=(n, 3)).astype(np.float32)
    ref = _embreex_hits(mesh.vertices, mesh.faces, o, d)
    scene = embree.Scene(mesh.vertices, mesh.faces)
    got = scene.run(o, d)
    assert got.dtype == np.int32 and got.shape == (n,)
    assert np.mean(got != ref) <= GRAZING
    assert 0.05 < np.mean(ref < 0) < 0.95  # misses and hits both tested
    assert np.array_equal(np.unique(got[got < 0]), [-1])  # a miss is -1
    assert np.mean((got < 0) != (ref < 0)) <= GRAZING
    # one thread, and one shared origin, give the same hits
    assert np.array_equal(scene.run(o, d, workers=1), got)
    one = np.empty(n, np.int64)
    embree.trace(scene.intersect, scene.handle, o[:1], d, one)
    ref_one = _embreex_hits(mesh.vertices, mesh.faces, np.repeat(o[:1], n, axis=0), d)
    assert np.mean(one != ref_one) <= GRAZING


def test_bad_scenes_raise_one_line_input_errors():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2]])
    for vertices, faces, what in [
        (np.where(np.eye(3, dtype=bool), np.nan, v), f, "NaN"),
        (v * 1e39, f, "NaN or infinite"),  # finite in float64, not in float32
        (v, np.zeros((0, 3), int), "no faces"),
        (v, np.array([[0, 1, 3]]), "out of range"),
        (v, np.array([[0.0, 1.0, 2.0]]), "integers"),
        (v[:, :2], f, "(n, 3)"),
    ]:
        with pytest.raises(InputError, match="grid.ply") as e:
            embree.Scene(vertices, faces, name="grid.ply")
        assert what in str(e.value) and "\n" not in str(e.value)
    scene = embree.Scene(v, f)
    scene.close()
    with pytest.raises(InputError, match="closed"):
        scene.run(np.zeros((1, 3)), np.ones((1, 3)))


def test_numba_threads_restored():
    before = numba.get_num_threads()
    with numba_threads(1):
        assert numba.get_num_threads() == 1
    assert numba.get_num_threads() == before
    with numba_threads(10_000):  # capped at numba's pool
        assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    assert numba.get_num_threads() == before


def test_compiled_shifts_and_frames():
    ids = np.array([0, 1, 5, 123456, 2**40 + 3], dtype=np.int64)
    for seed in (0, 1, 2**31 + 7):
        assert np.array_equal(_shifts(np.uint64(seed), ids, 5), digital_shifts(seed, ids, 5))
    rng = np.random.default_rng(3)
    n = rng.normal(size=(1000, 3))
    n[:3] = [[1, 0, 0], [0, 0, -1], [0.9, np.sqrt(0.19), 0]]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t1, t2 = _tangent_frames(n)
    assert np.allclose(np.linalg.norm(t1, axis=1), 1, atol=1e-6)
    assert np.allclose(np.einsum("ij,ij->i", t1, n), 0, atol=1e-6)
    assert np.allclose(t2, np.cross(n, t1), atol=1e-6)  # right-handed (n, t1, t2)


def _rows_by_embreex(mesh, k, seed, two_sided):
    """F from ``sample_rays``' rays (the same frame as the row kernel), traced by
    embreex, filtered in NumPy: an independent path to the same estimator."""
    v = np.asarray(mesh.vertices, float)
    f = np.asarray(mesh.faces)
    with RowTracer(mesh, k, seed, two_sided=two_sided) as rt:
        rt.hits(np.arange(1))
        origin, scale, offset = rt._scene.origin, rt._scene.scale, rt.job.offset
        normals = rt.job.normals
    tri = (v[f] - origin) * scale
    o, d, _ = sample_rays(tri, normals, k, two_sided=two_sided, offset=offset * scale,
                          face_ids=np.arange(len(f)), seed=seed)
    hit = _embreex_hits((v - origin) * scale, f, o, d)
    row = np.repeat(np.arange(len(f)), k)
    keep = (hit >= 0) & (hit != row)
    if not two_sided:
        keep &= np.einsum("ij,ij->i", d, normals.astype(np.float32)[np.maximum(hit, 0)]) < 0
    F = sp.csr_matrix((np.full(keep.sum(), 1.0 / k), (row[keep], hit[keep])),
                      shape=(len(f), len(f)))
    F.sum_duplicates()
    return F


@pytest.mark.parametrize("two_sided", [False, True])
def test_row_kernel_equals_sample_rays_traced_by_embreex(two_sided):
    inside = trimesh.creation.icosphere(subdivisions=3)
    inside = trimesh.Trimesh(inside.vertices, inside.faces[:, ::-1])  # normals inward
    box = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    box = box.subdivide().subdivide()
    plate = trimesh.Trimesh([[-0.5, -0.5, 0.5], [0.5, -0.5, 0.5], [0.5, 0.5, 0.5],
                             [-0.5, 0.5, 0.5]], [[0, 1, 2], [0, 2, 3]]).subdivide()
    # occlusion by the inner box; rays reaching the back of the one-sided plate
    mesh = trimesh.util.concatenate([inside, box, plate])
    k, seed = 64, 11
    ref = _rows_by_embreex(mesh, k, seed, two_sided)
    for workers in (1, 2):
        F = view_factors(mesh, k, seed, two_sided=two_sided, workers=workers, chunk_size=300)
        diff = abs(F - ref)
        assert ref.nnz > 10 * len(mesh.faces)
        assert diff.max() <= 2.0 / k + 1e-12  # a grazing ray moves one weight at most
        assert (diff > 1e-12).nnz <= GRAZING * len(mesh.faces) * k


def test_rays_through_edges_and_vertices_of_a_grid_hit_it():
    """A ray aimed at a vertex, an edge or a cell diagonal of a flat grid hits one of the
    faces sharing it (watertight tests): closed form, every aimed point is on the grid."""
    n, m = 24, 16
    xs, ys = np.linspace(-1, 1, n + 1), np.linspace(-0.7, 0.7, m + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    v = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(len(v)).reshape(n + 1, m + 1)
    a, b, c, d = (idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(),
                  idx[:-1, 1:].ravel())
    f = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    # the vertices, the edges' midpoints and points along the cell diagonals, inside
    cells = np.stack([X[:-1, :-1], Y[:-1, :-1]], -1).reshape(-1, 2)
    dx, dy = xs[1] - xs[0], ys[1] - ys[0]
    aims = [v[:, :2]] + [cells + [t * dx, t * dy] for t in (0.25, 0.5, 0.75)] \
        + [cells + [0.5 * dx, 0], cells + [0, 0.5 * dy]]
    p = np.concatenate(aims)
    p = p[(np.abs(p[:, 0]) < 1 - 1e-9) & (np.abs(p[:, 1]) < 0.7 - 1e-9)]
    target = np.column_stack([p, np.zeros(len(p))]) * 40.0  # a box of about 100
    scene = embree.Scene(v * 40.0, f)
    for eye in ([0.0, 0.0, 20.0], [3.0, -2.0, 25.0]):  # a camera above, head-on and not
        d = target - np.array(eye)
        hit = scene.run(np.broadcast_to(np.float32(eye), d.shape), d)
        assert np.all(hit >= 0)
        straight = scene.run(target + [0, 0, 10.0], np.broadcast_to([0, 0, -1.0], d.shape))
        assert np.all(straight >= 0)
