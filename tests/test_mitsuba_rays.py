"""Mitsuba / Dr.Jit first hits (the tracer used on a GPU, here its CPU LLVM variant)
against closed-form plane crossings and against Embree on the same rays."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from resection import InputError
from selfillum.mitsuba_variants import import_mitsuba
from selfillum.transport.mitsuba_rays import MitsubaRayScene, tracing_variant
from selfillum.transport.viewfactors import RayScene


def plate() -> trimesh.Trimesh:
    """The square [-1, 1]^2 at z = 0 as two triangles split along (-1, -1) -> (1, 1)."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def test_hits_on_a_plate_against_the_closed_form():
    """Rays from above towards random points of the plane z = 0: the face containing the
    crossing point (the diagonal splits the plate), a miss outside the plate and for rays
    pointing up."""
    rng = np.random.default_rng(2)
    n = 20_000
    target = np.column_stack([rng.uniform(-1.5, 1.5, (n, 2)), np.zeros(n)])
    o = target + rng.uniform(0.5, 2.0, (n, 1)) * rng.normal([0, 0, 1], 0.3, (n, 3))
    o[:, 2] = np.abs(o[:, 2]) + 0.1
    d = target - o
    d[::10] *= -1.0  # pointing away: misses
    scene = MitsubaRayScene(plate().vertices, plate().faces)
    face = scene.first_hit(o, d)
    x, y = target[:, 0], target[:, 1]
    inside = (np.abs(x) < 1) & (np.abs(y) < 1)
    inside[::10] = False
    expect = np.where(inside, np.where(x > y, 0, 1), -1)
    # away from the edges and the diagonal (the tracer works in float32)
    clear = (np.minimum(np.abs(np.abs(x) - 1), np.abs(np.abs(y) - 1)) > 1e-4) \
        & (np.abs(x - y) > 1e-4)
    np.testing.assert_array_equal(face[clear], expect[clear])
    assert face.dtype == np.int64


def test_same_first_hits_as_embree_inside_a_sphere():
    """The same 200,000 rays from inside an icosphere: Mitsuba and Embree report the same
    face for all but a few rays that graze an edge between two faces (float32 either
    way): at least 99.99 % of them."""
    mesh = trimesh.creation.icosphere(subdivisions=4)
    rng = np.random.default_rng(3)
    o = rng.normal(size=(200_000, 3)) * 0.2
    d = rng.normal(size=(200_000, 3))
    a = MitsubaRayScene(mesh.vertices, mesh.faces).first_hit(o, d)
    b = RayScene(mesh.vertices, mesh.faces).first_hit(o, d)
    # a closed surface: every ray hits, but for a few that slip through an edge in float32
    assert np.mean(a >= 0) >= 0.9999 and np.mean(b >= 0) >= 0.9999
    assert np.mean(a == b) >= 0.9999


def test_variant_is_restored_and_bad_variants_refused():
    mi, _ = import_mitsuba()
    mi.set_variant("scalar_rgb")
    scene = MitsubaRayScene(plate().vertices, plate().faces)
    scene.first_hit(np.array([[0.2, -0.5, 1.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert mi.variant() == "scalar_rgb"
    assert scene.variant in ("cuda_ad_rgb", "llvm_ad_rgb")
    with pytest.raises(InputError, match="unknown variant"):
        tracing_variant("scalar")
    with pytest.raises(InputError, match="unknown variant"):
        tracing_variant("opengl")
    with pytest.raises(InputError, match="faces"):
        MitsubaRayScene(np.zeros((3, 3)), np.zeros((0, 3), int))


def test_view_factors_traced_by_mitsuba_match_the_closed_form_and_embree():
    """Perpendicular unit squares sharing an edge (Howell C-14: F = 0.20004378): the plate
    total of F traced by Mitsuba is within the RQMC noise of the closed form (tolerance
    4e-3, twice the rms error over seeds measured at K = 256 in the former
    bench_viewfactors.py [5], docs/benchmark_history.md),
    and F equals Embree's on the same rays but for the few rays that graze an edge:
    the plate totals within 1e-4."""
    from selfillum import view_factors
    from selfillum.mesh import face_areas

    n = 10
    g = np.linspace(0.0, 1.0, n + 1)
    xx, yy = np.meshgrid(g, g)
    floor = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    wall = np.column_stack([xx.ravel(), np.zeros(xx.size), yy.ravel()])
    quads = [[r * (n + 1) + c, r * (n + 1) + c + 1, (r + 1) * (n + 1) + c + 1,
              (r + 1) * (n + 1) + c] for r in range(n) for c in range(n)]
    tri = np.array([[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads])
    m = len(floor)
    mesh = trimesh.Trimesh(np.vstack([floor, wall]),
                           np.vstack([tri, tri[:, ::-1] + m]), process=False)
    on_floor = np.arange(len(mesh.faces)) < len(tri)
    assert np.all(mesh.face_normals[on_floor, 2] > 0.99)
    assert np.all(mesh.face_normals[~on_floor, 1] > 0.99)
    area = face_areas(mesh)
    totals = {}
    for tracer in ("mitsuba", "embree"):
        F = view_factors(mesh, 256, seed=1, tracer=tracer)
        to_wall = np.asarray(F[:, ~on_floor].sum(axis=1)).ravel()
        totals[tracer] = float(np.sum(area[on_floor] * to_wall[on_floor]) / area[on_floor].sum())
    assert abs(totals["mitsuba"] - 0.20004378) < 4e-3
    assert abs(totals["mitsuba"] - totals["embree"]) < 1e-4
    with pytest.raises(InputError, match="tracer"):
        view_factors(mesh, 16, tracer="optix")
