"""Exact unoccluded form factors (selfillum.transport.kernel) against closed forms, and the
corner's converged reference built on them."""

import numpy as np
import pytest
from test_viewfactors import howell_perpendicular, perpendicular_mesh

from scenes.corner import corner, corner_form_factors, exact_radiosity
from selfillum import forward, view_factors
from selfillum.mesh import face_normals
from selfillum.transport.kernel import pair_factors, point_polygon_factor, triangle_rule


def dA_to_rectangle_corner(a: float, b: float, c: float) -> float:
    """Howell B-3: differential area to a parallel rectangle a x b at distance c, the
    normal of the element passing through one corner of the rectangle."""
    A, B = a / c, b / c
    return float((A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
                  + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))) / (2 * np.pi))


def test_point_to_square_closed_form():
    # unit square at height 1 centred over the point: four B-3 rectangles 0.5 x 0.5
    sq = np.array([[[-.5, -.5, 1], [.5, .5, 1], [.5, -.5, 1]],
                   [[-.5, -.5, 1], [-.5, .5, 1], [.5, .5, 1]]])
    f = point_polygon_factor(np.zeros((2, 3)), np.tile([0.0, 0, 1], (2, 1)), sq)
    assert f.sum() == pytest.approx(4 * dA_to_rectangle_corner(0.5, 0.5, 1.0), rel=1e-12)
    # the same square seen from behind (its painted side is -z: vertex order) gives 0
    g = point_polygon_factor(np.zeros((2, 3)), np.tile([0.0, 0, 1], (2, 1)), sq[:, ::-1])
    assert np.all(g == 0)


def test_point_to_triangle_clipped_by_horizon():
    # a vertical square x = 1, |y| <= 0.5, -1 <= z <= 1, facing -x: half of it lies below
    # the horizon of a point at the origin facing +z; the upper half is a B-3 pair
    # rotated: differential area to a perpendicular rectangle (Howell B-2 by superposition)
    quad = np.array([[1, -.5, -1], [1, .5, -1], [1, .5, 1], [1, -.5, 1]], float)
    tris = np.array([quad[[0, 2, 1]], quad[[0, 3, 2]]])
    full = point_polygon_factor(np.zeros((2, 3)), np.tile([0.0, 0, 1], (2, 1)), tris).sum()
    upper = np.array([[1, -.5, 0], [1, .5, 0], [1, .5, 1], [1, -.5, 1]], float)
    tu = np.array([upper[[0, 2, 1]], upper[[0, 3, 2]]])
    half = point_polygon_factor(np.zeros((2, 3)), np.tile([0.0, 0, 1], (2, 1)), tu).sum()
    assert full == pytest.approx(half, rel=1e-12)
    # B-2 (Howell): element at the base of a perpendicular rectangle, for each half in y:
    # F = (1/2pi) (atan(1/Y) - Y/sqrt(X^2+Y^2)... written with X = b/a, Y = c/a
    def b2(a, b, c):  # rectangle a (along the normal) x b, element at distance c from
        X, Y = a / b, c / b  # the rectangle's base edge, opposite one end of it
        return (np.arctan(1 / Y) - Y / np.sqrt(X * X + Y * Y)
                * np.arctan(1 / np.sqrt(X * X + Y * Y))) / (2 * np.pi)
    assert half == pytest.approx(2 * b2(1.0, 0.5, 1.0), rel=1e-10)


def test_quadrature_weights_and_c14():
    bary, w = triangle_rule(5)
    assert w.sum() == pytest.approx(1.0) and np.all(bary >= 0)
    # integrates a quadratic exactly on the triangle: mean of l1^2 is 1/6
    assert w @ bary[:, 1] ** 2 == pytest.approx(1 / 6, rel=1e-12)
    mesh, g = perpendicular_mesh(n=4)
    i, j = np.meshgrid(np.flatnonzero(g == 0), np.flatnonzero(g == 1), indexing="ij")
    F = pair_factors(mesh.vertices, mesh.faces, face_normals(mesh), i.ravel(), j.ravel())
    a = mesh.area_faces[g == 0]
    total = a @ F.reshape(i.shape).sum(axis=1) / a.sum()
    assert total == pytest.approx(howell_perpendicular(1, 1, 1), rel=2e-5)


def test_corner_reference_matches_howell_and_rays():
    scene = corner(resolution=6)
    F = corner_form_factors(scene)
    assert F.sum() / F.shape[0] == pytest.approx(howell_perpendicular(1, 1, 1), rel=2e-5)
    B = exact_radiosity(scene)
    # the ray-cast factors converge to the same radiosity (independent estimator)
    Fr = view_factors(scene.mesh, 1024, seed=3)
    Br = forward(Fr, scene.emission, scene.reflectance)
    assert np.max(np.abs(Br / B - 1)) < 0.01
    assert np.mean(np.abs(Br / B - 1)) < 0.002
