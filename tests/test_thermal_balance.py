"""The radiometric balance (selfillum.thermal.balance, selfillum.thermal.phase2): a model
whose parts see each other, its radiosity solved densely by NumPy (the exchange with the
walls and between the parts to all orders), the camera's signal made from it, and the
temperatures found back from the signal with and without the view factors."""

from __future__ import annotations

import numpy as np
import pytest

from selfillum.thermal.phase2 import ir_temperature
from selfillum.thermal.radiometry import Emissivity, Planck, Radiometry

PL = Planck(620420.0, 1374.5, 1.35, 6646.0)


def _scene(eps: Emissivity, theta):
    """Four parts: view factors (rows sum under 1, the rest sees the walls)."""
    F = np.array([[0.0, 0.30, 0.10, 0.05],
                  [0.25, 0.0, 0.20, 0.0],
                  [0.10, 0.15, 0.0, 0.30],
                  [0.05, 0.0, 0.35, 0.0]])
    T = np.array([310.0, 350.0, 400.0, 330.0])
    Tw = 295.0
    U, Uw = PL.radiance(T), PL.radiance(Tw)
    wall = 1.0 - F.sum(axis=1)
    eh = eps.hemispherical()
    # J = eh U + (1 - eh) (F J + wall Uw), solved densely
    J = np.linalg.solve(np.eye(4) - (1 - eh) * F, eh * U + (1 - eh) * wall * Uw)
    H = F @ J + wall * Uw
    ed = eps(theta)
    M = ed * U + (1 - ed) * H  # what the camera sees
    return F, T, Tw, M, wall, eh


def test_constant_emissivity_exact():
    eps = Emissivity("constant", 0.7)
    theta = np.radians([10.0, 30.0, 50.0, 65.0])
    F, T, Tw, M, wall, eh = _scene(eps, theta)
    rad = Radiometry(PL, eps, Tw)
    rho = 1 - eh
    values = M - rho * (F @ M)  # Phase 1's node values with rho F M removed
    got, bad = ir_temperature(rad, M[None], values[None], rho, np.cos(theta)[None], wall)
    np.testing.assert_allclose(got[0], T, atol=1e-9)
    assert bad == 0
    # without the parts' light: every part hotter than it is
    naive, _ = ir_temperature(rad, M[None], None, rho, np.cos(theta)[None],
                              np.ones(4))
    assert np.all(naive[0] > T + 1.0)


def test_directional_emissivity_small_error():
    eps = Emissivity("fresnel", 0.9, n=1.9)
    theta = np.radians([10.0, 30.0, 50.0, 65.0])
    F, T, Tw, M, wall, eh = _scene(eps, theta)
    rad = Radiometry(PL, eps, Tw)
    values = M - (1 - eh) * (F @ M)
    got, _ = ir_temperature(rad, M[None], values[None], 1 - eh, np.cos(theta)[None], wall)
    # the parts' radiance toward each other taken as the camera sees it: a small error
    assert np.max(np.abs(got[0] - T)) < 0.5
    # the grazing fall of the emissivity ignored (its normal value taken): far worse
    flat = Radiometry(PL, Emissivity("constant", float(eps(0.0))), Tw)
    got0, _ = ir_temperature(flat, M[None], values[None], 1 - eh, np.cos(theta)[None],
                             wall)
    assert np.max(np.abs(got0[0] - T)) > 3 * np.max(np.abs(got[0] - T))


def test_out_of_range_counted():
    eps = Emissivity("constant", 1.0)
    rad = Radiometry(Planck(PL.R, PL.B, PL.F, PL.O, t_range=(280.0, 360.0)), eps, 295.0)
    U = PL.radiance(np.array([[300.0, 390.0]]))
    got, bad = ir_temperature(rad, U, None, 0.0, np.ones((1, 2)), np.ones(2))
    assert bad == 1 and np.isnan(got[0, 1]) and got[0, 0] == pytest.approx(300.0)


def test_view_cosines_closed_form():
    """A node's view cosine from the camera centres of each frame, against the angle
    between its normal and the line to the camera written out (two cameras: the squarer
    one's; a normal pointing away: the absolute cosine)."""
    from selfillum.thermal.balance import camera_centres, view_cosines

    pts = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, -1.0]])
    nrm = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    # camera 1 over the first node, then at 45 deg; camera 2 always at 60 deg of node 1
    c1 = np.array([[0.0, 0.0, 2.0], [3.0, 0.0, 3.0]])
    c2 = np.array([[np.sqrt(3.0), 0.0, 1.0], [np.sqrt(3.0), 0.0, 1.0]])
    R = np.broadcast_to(np.eye(3), (2, 2, 3, 3))
    t = -np.stack([c1, c2])  # x_cam = X - C: centre C
    C = camera_centres(R, t)
    np.testing.assert_allclose(C, np.stack([c1, c2]))
    cos = view_cosines(C, pts, nrm)
    np.testing.assert_allclose(cos[:, 0], [1.0, np.sqrt(0.5)], atol=1e-12)
    for k in range(2):  # node 2 (normal -z, pointing away from both): |cos|, best camera
        d = np.stack([c1[k], c2[k]]) - pts[1]
        ref = np.max(np.abs(d[:, 2]) / np.linalg.norm(d, axis=1))
        assert cos[k, 1] == pytest.approx(ref, abs=1e-12)


def _roof(alpha_deg: float, n: int = 9):
    """A roof of two flat plates tilted by +-alpha about the y axis, meeting at the ridge
    x = 0, on a regular grid of n x n nodes with every square split the same way (each
    node inside touches six triangles of equal area: a ridge node three on each plate)."""
    import trimesh

    x = np.linspace(-1.0, 1.0, n)
    X, Y = np.meshgrid(x, x, indexing="ij")
    Z = -np.abs(X) * np.tan(np.radians(alpha_deg))
    v = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            f += [[a, b, c], [a, c, d]]
    mesh = trimesh.Trimesh(v, np.array(f), process=False)
    idx = np.arange(len(v))
    grid = type("Grid", (), {"mesh": mesh, "points": v, "node_vertex": idx,
                             "to_nodes": staticmethod(lambda a: np.asarray(a)[..., idx])})()
    return grid, X.ravel(), Y.ravel()


@pytest.mark.parametrize("beta", [20.0, 45.0])
def test_pixel_emissivity_on_a_roof(beta):
    """The emissivity at each pixel's view angle on a roof of two flat plates tilted by
    +-30 deg, a camera far off at beta from the vertical toward +x: every pixel of a plate
    sees it at the same angle, 30 + beta and 30 - beta deg (closed form), so a plate's
    nodes take eps of their plate's angle, and a ridge node, whose value is the mean of the
    faces around it (three of equal area on each plate), the mean of the two; with beta
    45 deg one plate is seen at 75 deg, beyond the 70 deg cut-off, and the ridge takes the
    other's. The node's own normal (the mean of the two plates') gives another value."""
    from selfillum.thermal.balance import NodeGeometry, pixel_emissivity, view_cosines

    eps = Emissivity("fresnel", 0.95, n=1.5)
    grid, X, Y = _roof(30.0)
    geom = NodeGeometry.from_grid(grid)
    assert (np.asarray(grid.mesh.face_normals)[:, 2] > 0).all()  # the painted side up
    b = np.radians(beta)
    centres = 1e7 * np.array([[[np.sin(b), 0.0, np.cos(b)]] * 2])  # (1 camera, 2 frames)
    inner = np.abs(Y) < 0.99  # not on the roof's ends (fewer faces there)
    nodes = np.flatnonzero(inner)
    cos = view_cosines(centres, geom.points[nodes], geom.normals[nodes])
    got = pixel_emissivity(eps, centres, geom, nodes, cos, 70.0)
    x = X[nodes]
    tA, tB = np.radians(30.0 + beta), np.radians(abs(30.0 - beta))  # x < 0, x > 0
    eA, eB = float(eps(tA)), float(eps(tB))
    want = np.where(x < 0, eA, eB)
    ridge = np.abs(x) < 1e-12
    want[ridge] = 0.5 * (eA + eB) if 30.0 + beta < 70.0 else eB
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-6)
    own = eps.of_cosine(cos[:, ridge])  # the node's own normal: the vertical
    assert np.abs(own - want[ridge]).min() > 1e-3
