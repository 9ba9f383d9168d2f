"""Visibility against closed-form geometry: a sphere half hidden behind a plate, back
faces, the obliqueness limit, partial occlusion and the field of view."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from resection import Camera, InputError, visible_faces

C = np.array([0.0, 0.0, 5.0])
K = [[400.0, 0.0, 199.5], [0.0, 400.0, 199.5], [0.0, 0.0, 1.0]]


def cam(eye=C, target=(0, 0, 0), up=(0, 1, 0), w=400, h=400, k=K):
    return Camera.look_at(eye, target, up, K=k, width=w, height=h)


def plate(x0, x1, y0, y1, z, up=True):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    return trimesh.Trimesh(v, f if up else f[:, ::-1], process=False)


def sphere():
    s = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    return trimesh.Trimesh(s.vertices, s.faces, process=False)


@pytest.mark.parametrize("plate_faces_camera", [True, False])
def test_sphere_behind_plate(plate_faces_camera):
    sph = sphere()
    pl = plate(-2.0, 0.0, -2.0, 2.0, 2.0, up=plate_faces_camera)
    mesh = trimesh.util.concatenate([sph, pl])
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    vis = visible_faces(mesh, cam(), max_obliqueness_deg=89.0, samples_per_face=1)
    ns = len(sph.faces)
    P = sph.triangles_center
    # closed form: facing (true sphere normal) and the segment C -> P crossing the plate
    to_c = C - P
    cosang = np.einsum("ij,ij->i", P / np.linalg.norm(P, axis=1, keepdims=True), to_c) \
        / np.linalg.norm(to_c, axis=1)
    s = (2.0 - C[2]) / (P[:, 2] - C[2])
    Q = C + s[:, None] * (P - C)
    hidden = (Q[:, 0] > -2) & (Q[:, 0] < 0) & (np.abs(Q[:, 1]) < 2)
    expected = (cosang > 0) & ~hidden
    # skip faces on the limb (face normal vs sphere normal) or at the plate's edge
    face_cos = np.einsum("ij,ij->i", sph.face_normals, to_c) / np.linalg.norm(to_c, axis=1)
    clear = (np.abs(cosang) > 0.05) & (np.abs(face_cos) > 0.05) & (np.abs(Q[:, 0]) > 0.02)
    assert clear.sum() > 0.9 * ns
    np.testing.assert_array_equal(vis[:ns][clear], expected[clear])
    assert expected[clear].sum() > 0.15 * ns  # seen faces
    assert (~expected[clear] & (cosang[clear] > 0)).sum() > 50  # facing but hidden
    # the plate is seen only if it faces the camera
    assert vis[ns:].tolist() == [plate_faces_camera] * 2


def test_obliqueness_limit():
    angles = np.array([10.0, 30.0, 50.0, 59.0, 61.0, 75.0, 88.0])
    parts = []
    for k, a in enumerate(angles):
        centre = np.array([(k - 3) * 0.6, 0.0, 0.0])
        d = (C - centre) / np.linalg.norm(C - centre)
        axis = np.cross(d, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        n = Rotation.from_rotvec(np.radians(a) * axis).apply(d)
        e1 = np.cross(n, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        r = 0.1
        v = centre + r * np.array([e1, -0.5 * e1 + 0.866 * e2, -0.5 * e1 - 0.866 * e2])
        # centroid of the triangle is the centre; order so the normal is +n
        f = [0, 1, 2] if np.dot(np.cross(v[1] - v[0], v[2] - v[0]), n) > 0 else [0, 2, 1]
        parts.append(trimesh.Trimesh(v, [f], process=False))
    mesh = trimesh.util.concatenate(parts)
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    vis = visible_faces(mesh, cam(), max_obliqueness_deg=60.0)
    np.testing.assert_array_equal(vis, angles <= 60.0)
    vis = visible_faces(mesh, cam(), max_obliqueness_deg=89.5)
    assert vis.all()


def test_partial_occlusion_any_all_and_field_of_view():
    big = plate(-1.0, 1.0, -1.0, 1.0, 0.0)
    blocker = plate(-0.6, 0.0, -2.0, 2.0, 1.0)  # hides part of both triangles
    far = plate(20.0, 21.0, 0.0, 1.0, 0.0)  # outside the field of view
    mesh = trimesh.util.concatenate([big, blocker, far])
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    any_ = visible_faces(mesh, cam(), samples_per_face=7, require="any")
    all_ = visible_faces(mesh, cam(), samples_per_face=7, require="all")
    assert any_[:2].all() and not all_[:2].any()
    assert any_[2:4].all() and all_[2:4].all()
    assert not any_[4:].any()
    assert visible_faces(mesh, cam(), in_image=False)[4:].all()


def test_errors():
    mesh = sphere()
    with pytest.raises(InputError, match="max_obliqueness_deg"):
        visible_faces(mesh, cam(), max_obliqueness_deg=120)
    with pytest.raises(InputError, match="samples_per_face"):
        visible_faces(mesh, cam(), samples_per_face=9)
    with pytest.raises(InputError, match="camera"):
        visible_faces(mesh, None)


def test_first_hit_per_ray_origins_against_closed_form():
    """Rays with their own origins (and NaN rows) on the plate z = 0: distance and
    barycentrics in float64 against the closed-form plane crossing."""
    from resection.surface.visibility import RayCaster

    pl = plate(-1.0, 1.0, -1.0, 1.0, 0.0)
    rng = np.random.default_rng(5)
    target = np.column_stack([rng.uniform(-0.9, 0.9, (500, 2)), np.zeros(500)])
    o = target + rng.uniform(0.5, 3.0, (500, 1)) * rng.normal([0, 0, 1], 0.3, (500, 3))
    d = target - o
    d[::50] = np.nan
    face, dist, bary = RayCaster(pl).first_hit(o, d)
    ok = np.isfinite(d).all(axis=1)
    assert np.all(face[~ok] == -1) and np.all(np.isnan(dist[~ok]))
    np.testing.assert_allclose(dist[ok], np.linalg.norm(d[ok], axis=1), rtol=1e-12)
    tri = pl.vertices[pl.faces[face[ok]]]
    np.testing.assert_allclose(np.einsum("nk,nkj->nj", bary[ok], tri), target[ok], atol=1e-12)
    # which triangle: the plate splits along the diagonal (-1, -1) -> (1, 1)
    lower = target[ok, 0] > target[ok, 1]
    np.testing.assert_array_equal(face[ok], np.where(lower, 0, 1))


def test_first_hit_threads_over_blocks_of_rays_against_closed_form():
    """120,000 rays (NaN rows among them), split over 2 threads in several blocks, with
    their own origins and with one shared origin: every ray's face, distance and hit point
    against the closed-form plane crossing, and the same answer with one thread."""
    from resection.surface.visibility import RayCaster

    pl = plate(-1.0, 1.0, -1.0, 1.0, 0.0)
    caster = RayCaster(pl)
    rng = np.random.default_rng(8)
    n = 120_000
    target = np.column_stack([rng.uniform(-0.95, 0.95, (n, 2)), np.zeros(n)])
    shared = np.array([0.2, -0.1, 2.5])
    for o in (target + rng.uniform(0.5, 3.0, (n, 1)) * rng.normal([0, 0, 1], 0.3, (n, 3)),
              shared):
        d = target - o
        d[7::997] = np.nan
        face, dist, bary = caster.first_hit(o, d, workers=2)
        ok = np.isfinite(d).all(axis=1)
        assert np.all(face[~ok] == -1) and np.all(np.isnan(bary[~ok]))
        np.testing.assert_allclose(dist[ok], np.linalg.norm(d[ok], axis=1), rtol=1e-12)
        tri = pl.vertices[pl.faces[face[ok]]]
        np.testing.assert_allclose(np.einsum("nk,nkj->nj", bary[ok], tri), target[ok],
                                   atol=1e-12)
        # which triangle, away from the diagonal they share (Embree works in float32)
        gap = target[ok, 0] - target[ok, 1]
        clear = np.abs(gap) > 1e-4
        np.testing.assert_array_equal(face[ok][clear], np.where(gap[clear] > 0, 0, 1))
        one = caster.first_hit(o, d, workers=1)
        np.testing.assert_array_equal(one[0], face)
        np.testing.assert_allclose(one[1], dist, rtol=1e-12, equal_nan=True)


def test_caster_frame_and_normals_against_closed_form():
    """The frame a caster's scene is in (shared with the view factors) and its normals:
    a right triangle and its mirror, normals by the right-hand rule, and a ray aimed in
    the scene's frame by hand hits the face it should."""
    from resection.surface.visibility import RayCaster

    v = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [5, 5, 1]], float)
    mesh = trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)
    c = RayCaster(mesh)
    n2 = np.cross(v[2] - v[0], v[3] - v[0])
    np.testing.assert_allclose(c.normals, [[0, 0, 1], n2 / np.linalg.norm(n2)], atol=1e-15)
    np.testing.assert_allclose(c.origin, [0, 0, 0])
    assert c.scale == pytest.approx(100 / np.linalg.norm([5, 5, 1]))
    o = ((np.array([[1.5, 0.2, 1.0]]) - c.origin) * c.scale).astype(np.float32)
    assert list(c.scene.run(o, np.array([[0, 0, -1]], np.float32))) == [0]
    np.testing.assert_allclose(c.centroids, [[2 / 3, 2 / 3, 0], (v[0] + v[2] + v[3]) / 3],
                               atol=1e-15)
    np.testing.assert_allclose(c.areas, [2.0, np.linalg.norm(n2) / 2], rtol=1e-15)


def test_compiled_bounds_and_normals_against_numpy():
    from resection.surface.visibility import bounds, unit_normals

    rng = np.random.default_rng(5)
    v = rng.normal(size=(500, 3)) * [1.0, 10.0, 0.1]
    f = rng.integers(0, 500, size=(900, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    lo, hi = bounds(v)
    assert np.array_equal(lo, v.min(axis=0)) and np.array_equal(hi, v.max(axis=0))
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    ref = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    assert np.allclose(unit_normals(v, f), ref, rtol=0, atol=1e-12)
    w = v.copy()
    w[7, 1] = np.inf
    assert not np.all(np.isfinite(np.concatenate(bounds(w))))
    w[9, 2] = np.nan
    assert np.all(np.isnan(np.concatenate(bounds(w))))
