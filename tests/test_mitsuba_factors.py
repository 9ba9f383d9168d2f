"""View factors sampled, traced and summed in Dr.Jit (``tracer="mitsuba"``,
:mod:`selfillum.transport.mitsuba_factors`) on the variant this machine runs (``llvm`` on a
CPU, ``cuda`` on a GPU): its rays against the NumPy sampler's, its F against Howell's closed
forms, exact properties, and Embree's F on the same rays."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from test_viewfactors import (
    EX,
    EY,
    group_factor,
    howell_parallel,
    howell_perpendicular,
    join,
    perpendicular_mesh,
    plate,
)

from scenes.corner import corner
from selfillum import view_factors
from selfillum.mesh import face_areas, face_normals
from selfillum.transport.mitsuba_factors import MitsubaFactorTracer
from selfillum.transport.sampling import sample_rays


@pytest.mark.parametrize("two_sided", [False, True])
def test_rays_are_those_of_the_numpy_sampler(two_sided):
    """The Dr.Jit rays of a set of faces are the rays of ``sample_rays`` (the same Sobol
    points, Owen scramble and seeds): origins within float32 rounding of the scene's size,
    directions within a few float32 ulps (sin/cos and the tangent frame are computed in
    float32 on the device, in float64 or by libm in NumPy)."""
    mesh = corner(resolution=10).mesh
    v, f, nrm = np.asarray(mesh.vertices), np.asarray(mesh.faces), face_normals(mesh)
    size = float(np.ptp(v, axis=0).max())
    k, seed, offset = 32, 5, 1e-6 * size
    tr = MitsubaFactorTracer(v, f, nrm, k, seed, offset=offset, two_sided=two_sided)
    rows = np.array([0, 3, 17, 150, len(f) - 1])
    o, d = tr.rays(rows)
    o_ref, d_ref, side = sample_rays(v[f[rows]] - tr.scene.origin, nrm[rows], k,
                                     two_sided=two_sided, offset=offset, face_ids=rows,
                                     seed=seed)
    assert o.shape == o_ref.shape == (rows.size * k, 3)
    np.testing.assert_allclose(o, o_ref, rtol=0, atol=4e-7 * size)
    np.testing.assert_allclose(d, d_ref, rtol=0, atol=4e-7)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-6)
    # each ray leaves the side the NumPy sampler says (both sides when two-sided)
    cos = np.einsum("ij,ij->i", d, np.repeat(nrm[rows], k, axis=0))
    np.testing.assert_array_equal(np.sign(cos), side)
    assert (side < 0).any() == two_sided


def test_howell_perpendicular_and_parallel_plates():
    """Howell C-14 (perpendicular unit squares sharing an edge) and C-11 (opposed unit
    squares at distance 1): the plate totals within 0.5 % (the tolerance of the Embree
    tests at K = 1024)."""
    mesh, g = perpendicular_mesh()
    F = view_factors(mesh, rays_per_face=1024, seed=1, tracer="mitsuba")
    assert abs(group_factor(F, mesh, g, 0, 1) / howell_perpendicular(1, 1, 1) - 1) < 0.005
    lower = plate(10, [0, 0, 0], EX, EY)  # normal +z
    upper = plate(10, [0, 0, 1], EY, EX)  # normal -z
    mesh, g = join(lower, upper)
    F = view_factors(mesh, rays_per_face=1024, seed=2, tracer="mitsuba")
    exact = howell_parallel(1, 1, 1)
    assert abs(group_factor(F, mesh, g, 0, 1) / exact - 1) < 0.005
    assert abs(group_factor(F, mesh, g, 1, 0) / exact - 1) < 0.005


def test_sphere_interior_and_closed_box():
    """Inside a sphere every face sees every face (F_ij = A_j / A); a closed box's rows
    sum to 1 exactly, its flat faces do not see themselves, and each row's column indices
    are unique (the pairs were summed on the device)."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    sphere.invert()
    a = face_areas(sphere)
    F = view_factors(sphere, rays_per_face=4096, seed=0, tracer="mitsuba")
    got = np.asarray(F.sum(axis=0)).ravel() / len(a)
    assert np.abs(got / (a / a.sum()) - 1).max() < 0.05
    np.testing.assert_allclose(np.asarray(F.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert np.diff(F.indptr).max() <= 4096
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5)).subdivide().subdivide()
    box.invert()
    F = view_factors(box, rays_per_face=256, seed=4, tracer="mitsuba")
    np.testing.assert_allclose(np.asarray(F.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert F.diagonal().max() == 0.0
    nnz = F.nnz
    F.sum_duplicates()
    assert F.nnz == nnz
    assert np.all(F.data > 0) and np.all(np.round(F.data * 256) == F.data * 256)


def test_two_sided_and_occlusion():
    """A plate turned away from its partner exchanges nothing one-sided (hits on a back
    are absorbed) and half of C-11 two-sided; a blocker hides two plates from each other."""
    lower = plate(10, [0, 0, 0], EY, EX)  # normal -z: faces away from the upper plate
    upper = plate(10, [0, 0, 1], EY, EX)  # normal -z: faces the lower plate
    mesh, g = join(lower, upper)
    one = view_factors(mesh, rays_per_face=64, seed=7, tracer="mitsuba")
    assert group_factor(one, mesh, g, 0, 1) == 0.0 and group_factor(one, mesh, g, 1, 0) == 0.0
    two = view_factors(mesh, rays_per_face=1024, seed=7, two_sided=True, tracer="mitsuba")
    exact = howell_parallel(1, 1, 1)
    assert group_factor(two, mesh, g, 0, 1) == pytest.approx(exact / 2, rel=0.01)
    assert group_factor(two, mesh, g, 1, 0) == pytest.approx(exact / 2, rel=0.01)
    blocker = plate(2, [-2, -2, 0.5], 5 * EY, 5 * EX)  # painted side down
    mesh, g = join(plate(4, [0, 0, 0], EX, EY), plate(4, [0, 0, 1], EY, EX), blocker)
    F = view_factors(mesh, rays_per_face=256, seed=8, tracer="mitsuba")
    assert group_factor(F, mesh, g, 0, 1) == 0.0
    assert group_factor(F, mesh, g, 0, 2) > 0.9


@pytest.mark.parametrize("two_sided", [False, True])
def test_same_f_as_embree_on_the_same_rays(two_sided):
    """The corner (1600 faces, K = 64): Mitsuba's F is Embree's but for rays that graze an
    edge in float32 (a ray's weight 1/K moves between two neighbouring entries): no entry
    differs by more than two rays' weight, at most 0.1 % of the entries differ, and no row
    sum by more than 2/K."""
    mesh = corner(resolution=20).mesh
    k = 64
    E = view_factors(mesh, k, seed=3, two_sided=two_sided)
    M = view_factors(mesh, k, seed=3, two_sided=two_sided, tracer="mitsuba")
    assert M.shape == E.shape and E.nnz > 5000
    diff = abs(M - E)
    assert diff.max() <= 2.0 / k + 1e-12
    assert (diff > 1e-12).nnz <= 1e-3 * E.nnz
    rows = np.abs(np.asarray(M.sum(axis=1)) - np.asarray(E.sum(axis=1)))
    assert rows.max() <= 2.0 / k + 1e-12


def test_launches_rows_and_progress_give_the_full_rows():
    """A row depends on its face only: F is the same whatever the launch size (the counts
    are integers, so the order of the atomic additions cannot change them), a subset of
    rows gives those rows of the full F, and progress is reported launch by launch; the
    Mitsuba variant set before the call is set again after it."""
    from selfillum.mitsuba_variants import import_mitsuba

    mi, _ = import_mitsuba()
    mi.set_variant("scalar_rgb")
    mesh, _ = perpendicular_mesh(n=20)  # 1600 faces
    k = 32
    full = view_factors(mesh, k, seed=11, tracer="mitsuba")
    assert mi.variant() == "scalar_rgb"  # the process's variant restored
    calls = []
    small = view_factors(mesh, k, seed=11, tracer="mitsuba", chunk_size=300,
                         progress=lambda d, t: calls.append((d, t)))
    assert (full != small).nnz == 0
    done = [d for d, _ in calls]
    assert all(t == 1600 for _, t in calls) and done[-1] == 1600 and len(calls) == 6
    assert all(0 < b - a <= 300 for a, b in zip([0, *done], done, strict=False))
    assert (view_factors(mesh, k, seed=12, tracer="mitsuba") != full).nnz > 0
    rows = np.array([3, 70, 71, 200, 1599])
    part = view_factors(mesh, k, seed=11, rows=rows, tracer="mitsuba")
    others = np.setdiff1d(np.arange(1600), rows)
    assert part[others].nnz == 0
    assert (part[rows] != full[rows]).nnz == 0
    rec = view_factors(mesh, k, seed=11, tracer="mitsuba", reciprocity=True)
    a = face_areas(mesh)
    AF = rec.multiply(a[:, None]).tocsr()
    assert abs(AF - AF.T).max() < 1e-12 * a.max()


@pytest.mark.parametrize("k", [1, 7, 24])
def test_rays_per_face_not_a_multiple_of_16(k):
    """A lane of the trace kernel casts gcd(K, 16) rays of one face: any K gives Embree's
    F on the same rays (up to rays grazing an edge), every row a multiple of 1/K."""
    mesh = corner(resolution=20).mesh
    E = view_factors(mesh, k, seed=9)
    M = view_factors(mesh, k, seed=9, tracer="mitsuba")
    assert abs(M - E).max() <= 2.0 / k + 1e-12
    assert (abs(M - E) > 1e-12).nnz <= max(2, 1e-3 * E.nnz)
    np.testing.assert_allclose(M.data * k, np.round(M.data * k), atol=1e-9)
    assert np.asarray(M.sum(axis=1)).max() <= 1.0 + 1e-12


@pytest.mark.parametrize("seed", [0, 7, 2**64 - 1])
def test_scramble_keys_made_on_the_device_are_numpys(seed):
    """The per-face scramble keys hashed on the device (64-bit wrapping arithmetic in
    Dr.Jit) equal :func:`selfillum.transport.sampling.digital_shifts` (NumPy uint64), for
    large seeds and the five dimensions of the two-sided rays."""
    from selfillum.mitsuba_variants import import_mitsuba
    from selfillum.transport.mitsuba_factors import _digital_shifts
    from selfillum.transport.mitsuba_rays import tracing_variant
    from selfillum.transport.sampling import digital_shifts

    mi, dr = import_mitsuba()
    previous = mi.variant()
    mi.set_variant(tracing_variant(None))
    try:
        n, dims = 1000, 5
        got = np.asarray(_digital_shifts(mi, dr, seed, n, dims)).reshape(n, dims)
    finally:
        if previous is not None:
            mi.set_variant(previous)
    np.testing.assert_array_equal(got, digital_shifts(seed, np.arange(n), dims))
