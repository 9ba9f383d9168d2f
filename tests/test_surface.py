"""SurfaceMap: face-index image against closed-form ray/plane geometry (rays from OpenCV's
undistortPoints, not from Camera.rays), to_surface / to_image round trips, errors."""

import cv2
import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from resection import Camera, InputError, SurfaceMap
from resection.surface.visibility import RayCaster

N = 16  # grid cells per side
H, W = 120, 160


def grid_plane(n=N, half=1.0):
    """Plane z = 0 over [-half, half]^2: cell (i, j) of size h, split along a -> c."""
    xs = np.linspace(-half, half, n + 1)
    X, Y = np.meshgrid(xs, xs)
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return trimesh.Trimesh(V, F, process=False)


def camera(dist=(-0.12, 0.03, 0.001, -0.0005, 0.0)):
    K = [[150.0, 0.0, 79.5], [0.0, 152.0, 59.5], [0.0, 0.0, 1.0]]
    return Camera.look_at([0.25, -0.3, 2.2], [0.05, 0.0, 0.0], [0, 1, 0], K=K, width=W,
                          height=H, dist=list(dist))


def reference_hits(cam, n=N, half=1.0):
    """Closed-form plane hits of every pixel, rays through OpenCV's undistortPoints."""
    vv, uu = np.mgrid[0:H, 0:W]
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)
    K, dist, _, _ = cam.to_opencv()
    xy = cv2.undistortPoints(uv[:, None, :], K, dist,
                             criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200,
                                       1e-15)).reshape(-1, 2)
    d = np.column_stack([xy, np.ones(len(xy))]) @ np.asarray(cam.R)  # R^T d_cam
    C = cam.center
    s = -C[2] / d[:, 2]
    P = C + s[:, None] * d
    h = 2.0 * half / n
    gx, gy = (P[:, 0] + half) / h, (P[:, 1] + half) / h
    inside = (s > 0) & (gx > 0) & (gx < n) & (gy > 0) & (gy < n)
    i, j = np.floor(gy).astype(int), np.floor(gx).astype(int)
    fx, fy = gx - j, gy - i
    lower = fx > fy  # triangle (a, b, c) holds the points below the diagonal a -> c
    face = np.where(lower, i * n + j, n * n + i * n + j)
    face[~inside] = -1
    # distance to the nearest cell edge or diagonal, in cells
    edge = np.minimum.reduce([fx, 1 - fx, fy, 1 - fy, np.abs(fx - fy) / np.sqrt(2)])
    return face.reshape(H, W), P.reshape(H, W, 3), edge.reshape(H, W)


@pytest.fixture(scope="module")
def plane_map():
    mesh = grid_plane()
    cam = camera()
    return mesh, cam, SurfaceMap(mesh, cam), reference_hits(cam)


def test_face_index_matches_closed_form(plane_map):
    mesh, cam, sm, (face, P, edge) = plane_map
    clear = edge > 1e-4  # float32 Embree may pick either face exactly on an edge
    assert (face >= 0).sum() > 0.3 * H * W and (face < 0).sum() > 0.1 * H * W
    np.testing.assert_array_equal(sm.face_index[clear], face[clear])
    assert np.mean(sm.face_index == face) > 0.999
    # hit points from the barycentrics agree with the closed-form plane hits
    on = face >= 0
    np.testing.assert_allclose(sm.points[on], P[on], atol=1e-9)
    np.testing.assert_allclose(sm.barycentric[on].sum(axis=1), 1.0, atol=1e-12)
    assert np.all(sm.barycentric[on] > -1e-6)
    np.testing.assert_allclose(sm.depth[on], np.linalg.norm(P[on] - cam.center, axis=1),
                               rtol=1e-12)
    assert np.all(np.isnan(sm.barycentric[~sm.mask]))
    # sparse matrix: one entry per model pixel
    assert sm.matrix.shape == (len(mesh.faces), H * W)
    assert sm.matrix.nnz == sm.mask.sum()
    np.testing.assert_array_equal(sm.pixel_counts, np.bincount(sm.face_index[sm.mask],
                                                               minlength=len(mesh.faces)))


def test_face_index_against_projected_centroids():
    """Without distortion: each face centroid, projected with OpenCV, lands on a pixel that
    sees that face (faces several pixels across)."""
    mesh = grid_plane(n=8)
    cam = camera(dist=(0, 0, 0, 0, 0))
    sm = SurfaceMap(mesh, cam)
    K, dist, rvec, tvec = cam.to_opencv()
    uv, _ = cv2.projectPoints(mesh.triangles_center, rvec, tvec, K, dist)
    uv = uv.reshape(-1, 2)
    iu, iv = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
    ins = (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
    assert ins.sum() > 60
    np.testing.assert_array_equal(sm.face_index[iv[ins], iu[ins]], np.flatnonzero(ins))


def linear(P):
    return 2.0 * P[..., 0] - 3.0 * P[..., 1] + 0.5 * P[..., 2] + 10.0


def test_to_image_reproduces_linear_field(plane_map):
    mesh, cam, sm, (face, P, _) = plane_map
    fv = linear(mesh.triangles_center)
    img = sm.to_image(fv)
    ref = linear(P)
    # exact wherever the face's corners are inside the grid (each corner among the
    # centroids of its faces)
    edge_vertex = np.isclose(np.abs(mesh.vertices[:, :2]), 1.0).any(axis=1)
    inner = ~edge_vertex[mesh.faces].any(axis=1)
    sel = sm.mask & inner[np.maximum(sm.face_index, 0)]
    assert sel.sum() > 0.7 * sm.mask.sum()
    np.testing.assert_allclose(img[sel], ref[sel], rtol=1e-6)
    # on the grid's edge the extrapolation to the corner is limited to the values of the
    # faces around it: within the range of those faces, and within one cell's change of
    # the exact value (the field changes by 2*2 + 3*2 + 0.5*0 over the grid, N cells)
    ring = np.zeros((len(mesh.vertices), 2))
    ring[:, 0], ring[:, 1] = np.inf, -np.inf
    np.minimum.at(ring[:, 0], mesh.faces.ravel(), np.repeat(fv, 3))
    np.maximum.at(ring[:, 1], mesh.faces.ravel(), np.repeat(fv, 3))
    rim = sm.mask & ~inner[np.maximum(sm.face_index, 0)]
    corners = mesh.faces[sm.face_index[rim]]
    lo, hi = ring[corners, 0].min(axis=1), ring[corners, 1].max(axis=1)
    assert np.all((img[rim] >= lo - 1e-9) & (img[rim] <= hi + 1e-9))
    assert np.max(np.abs(img[rim] - ref[rim])) < (2 * 2 + 3 * 2) / N
    assert np.all(np.isnan(img[~sm.mask]))


def _ring2_range(mesh, fv):
    """Smallest and largest value of the faces around each vertex and around its
    neighbours (the faces a vertex value may be built from)."""
    nf = len(fv)
    inc = sp.csr_matrix((np.ones(mesh.faces.size),
                         (mesh.faces.ravel(), np.repeat(np.arange(nf), 3))))
    ring2 = ((inc @ inc.T) @ inc).tocsr()
    vals = fv[ring2.indices]
    return (np.minimum.reduceat(vals, ring2.indptr[:-1]),
            np.maximum.reduceat(vals, ring2.indptr[:-1]))


def test_to_image_linear_field_on_corner():
    """A 90-degree corner (two grids sharing an edge): the linear field is reproduced
    wherever a face's corners lie among the centroids of their faces; on the crease and
    the grid's edges (a vertex beyond its faces' centroids) the value is held within the
    values of the faces around it. Hit points from trimesh's own ray intersector."""
    a = grid_plane(n=8)
    b = grid_plane(n=8)
    v = b.vertices.copy()
    b = trimesh.Trimesh(np.column_stack([np.full(len(v), -1.0), v[:, 1], v[:, 0] + 1.0]),
                        b.faces[:, ::-1], process=False)
    mesh = trimesh.util.concatenate([a, b])
    mesh.merge_vertices()
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    cam = Camera.look_at([1.2, -0.4, 1.8], [-0.6, 0.0, 0.3], [0, 0, 1],
                         K=[[120.0, 0, 79.5], [0, 120.0, 59.5], [0, 0, 1]], width=W, height=H,
                         dist=[-0.05, 0, 0, 0, 0])
    sm = SurfaceMap(mesh, cam)
    assert np.any(sm.mask & (sm.face_index >= len(a.faces)))  # both planes seen
    img = sm.to_image(linear(mesh.triangles_center))
    # the two ends of the crease (3 faces whose centroids span only a plane) cannot carry
    # a 3-D gradient: skip their faces
    vx = mesh.vertices
    crease = np.isclose(vx[:, 0], -1) & np.isclose(vx[:, 2], 0)
    edges = np.sort(mesh.edges, axis=1)
    uniq, n_use = np.unique(edges, axis=0, return_counts=True)
    rim_vertex = np.zeros(len(vx), bool)
    rim_vertex[uniq[n_use == 1].ravel()] = True  # on the outer edge of the two grids
    good_face = ~(crease | rim_vertex)[mesh.faces].any(axis=1)
    sel = sm.mask & good_face[np.maximum(sm.face_index, 0)]
    assert sel.sum() > 0.5 * sm.mask.sum()
    iv, iu = np.nonzero(sm.mask)
    o, d = cam.rays(np.column_stack([iu, iv]))
    loc, iray, _ = mesh.ray.intersects_location(o, d, multiple_hits=False)
    assert len(iray) == len(o)
    ref = np.full(len(o), np.nan)
    ref[iray] = linear(loc)
    refimg = np.full(sm.shape, np.nan)
    refimg[iv, iu] = ref
    np.testing.assert_allclose(img[sel], refimg[sel], rtol=1e-6)
    # elsewhere: within the values of the faces around the face's corners (2-ring: a grid
    # corner's vertex is built from its neighbours' faces too), within a cell's change
    lo, hi = _ring2_range(mesh, linear(mesh.triangles_center))
    rest = sm.mask & ~sel
    corners = mesh.faces[sm.face_index[rest]]
    assert rest.sum() > 100
    assert np.all(img[rest] >= lo[corners].min(axis=1) - 1e-9)
    assert np.all(img[rest] <= hi[corners].max(axis=1) + 1e-9)
    assert np.max(np.abs(img[rest] - refimg[rest])) < (2 + 3 + 0.5) * 2 / 8


def test_to_surface_exact_for_per_face_constant_image(plane_map):
    mesh, cam, sm, (face, P, edge) = plane_map
    rng = np.random.default_rng(1)
    g = rng.normal(size=len(mesh.faces))
    img = np.where(face >= 0, g[np.maximum(face, 0)], 7.0)
    clear_faces = np.ones(len(mesh.faces), bool)
    # faces touched by an ambiguous edge pixel are excluded from the exact comparison
    amb = (face >= 0) & (edge <= 1e-4)
    clear_faces[face[amb]] = False
    img[amb] = np.nan
    res = sm.to_surface(img)
    ref_counts = np.bincount(face[(face >= 0) & ~amb], minlength=len(mesh.faces))
    cf = clear_faces & (ref_counts > 0)
    np.testing.assert_allclose(res.values[cf], g[cf], rtol=1e-12)
    np.testing.assert_array_equal(res.counts[cf], ref_counts[cf])
    np.testing.assert_array_equal(res.unseen, res.counts == 0)
    np.testing.assert_array_equal(res.unseen[clear_faces], ref_counts[clear_faces] == 0)
    assert np.all(np.isnan(res.values[res.unseen]))


def test_round_trip_linear_field(plane_map):
    """image of a linear field -> faces -> image: faces get the field at the mean hit point
    of their pixels (within the pixel footprint of the centroid value), and back."""
    mesh, cam, sm, (face, P, _) = plane_map
    img = np.where(face >= 0, linear(P), np.nan)
    res = sm.to_surface(img)
    seen = ~res.unseen
    mean_pt = np.stack([np.bincount(sm.face_index[sm.mask], weights=P[sm.mask][:, k],
                                    minlength=len(mesh.faces)) for k in range(3)], axis=1)
    mean_pt = mean_pt[seen] / res.counts[seen, None]
    np.testing.assert_allclose(res.values[seen], linear(mean_pt), rtol=1e-12)
    # faces seen by many pixels: the mean is close to the centroid value
    many = res.counts >= 30
    assert many.sum() > 30
    np.testing.assert_allclose(res.values[many], linear(mesh.triangles_center[many]),
                               atol=0.05)
    back = sm.to_image(res.values)
    err = np.abs(back - img)[sm.mask]
    assert np.median(err) < 0.01 and np.percentile(err, 99) < 0.1
    assert np.isnan(back[~sm.mask]).all()


def test_nan_pixels_ignored_and_counted(plane_map):
    mesh, cam, sm, _ = plane_map
    img = np.ones((H, W))
    f0 = np.argmax(sm.pixel_counts)
    pix = np.argwhere(sm.face_index == f0)
    img[pix[0, 0], pix[0, 1]] = np.nan
    img[pix[1, 0], pix[1, 1]] = 100.0
    res = sm.to_surface(img)
    n = sm.pixel_counts[f0]
    assert res.counts[f0] == n - 1 and res.nan_counts[f0] == 1
    assert res.nan_counts.sum() == 1
    assert res.values[f0] == pytest.approx((n - 2 + 100.0) / (n - 1))
    # all pixels NaN -> unseen
    img[sm.face_index == f0] = np.nan
    res = sm.to_surface(img)
    assert res.unseen[f0] and np.isnan(res.values[f0]) and res.counts[f0] == 0


def test_stack_is_frame_by_frame(plane_map):
    mesh, cam, sm, _ = plane_map
    rng = np.random.default_rng(2)
    stack = rng.normal(size=(4, H, W))
    stack[1, 10:20, 30:90] = np.nan
    res = sm.to_surface(stack)
    assert res.values.shape == (4, len(mesh.faces))
    for k in range(4):
        one = sm.to_surface(stack[k])
        np.testing.assert_allclose(res.values[k], one.values, rtol=1e-12)
        np.testing.assert_array_equal(res.counts[k], one.counts)
    imgs = sm.to_image(res.values)
    assert imgs.shape == (4, H, W)
    np.testing.assert_allclose(imgs[2], sm.to_image(res.values[2]), rtol=1e-12)


def test_background_preserved(plane_map):
    mesh, cam, sm, _ = plane_map
    rng = np.random.default_rng(3)
    bg = rng.normal(size=(H, W))
    fv = np.full(len(mesh.faces), 5.0)
    fv[:10] = np.nan
    out = sm.to_image(fv, background=bg)
    off = ~sm.mask
    np.testing.assert_array_equal(out[off], bg[off])
    nanface = sm.mask & (sm.face_index < 10)
    np.testing.assert_array_equal(out[nanface], bg[nanface])
    on = sm.mask & ~nanface
    np.testing.assert_allclose(out[on], 5.0, rtol=1e-12)
    out = sm.to_image(fv, background=-1.0)
    assert np.all(out[off] == -1.0)
    near = sm.to_image(np.arange(len(mesh.faces), dtype=float), interpolation="nearest")
    np.testing.assert_array_equal(near[sm.mask], sm.face_index[sm.mask])


def test_shape_errors(plane_map):
    mesh, cam, sm, _ = plane_map
    with pytest.raises(InputError, match=r"\(120, 161\).*\(120, 160\)|\(120, 160\).*\(120, 161\)"):
        sm.to_surface(np.zeros((120, 161)))
    with pytest.raises(InputError, match="background"):
        sm.to_image(np.zeros(len(mesh.faces)), background=np.zeros((10, 10)))
    with pytest.raises(InputError, match=str(len(mesh.faces))):
        sm.to_image(np.zeros(len(mesh.faces) + 1))
    with pytest.raises(InputError, match="camera"):
        SurfaceMap(mesh, "not a camera")
    nf = len(mesh.faces)
    with pytest.raises(InputError, match="background: 3 images for 2"):
        sm.to_image(np.zeros((2, nf)), background=np.zeros((3, 120, 160)))
    with pytest.raises(InputError, match="background: expected real numbers"):
        sm.to_image(np.zeros(nf), background="abc")
    with pytest.raises(InputError, match="face_values: expected real numbers"):
        sm.to_image(np.array(["a"] * nf))
    with pytest.raises(InputError, match="empty stack"):
        sm.to_surface(np.zeros((0, 120, 160)))
    with pytest.raises(InputError, match=f"expected \\({nf},\\)"):
        sm.vertex_values(np.zeros(3))
    with pytest.raises(InputError, match="caster: built for 2 faces"):
        SurfaceMap(mesh, cam, caster=RayCaster(trimesh.Trimesh(
            [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])))
    # one background image for every set of face values is fine
    out = sm.to_image(np.zeros((2, nf)), background=np.full((1, 120, 160), 7.0))
    assert out.shape == (2, 120, 160) and np.all(out[:, ~sm.mask] == 7.0)


def test_vertex_values_linear_exact_and_nan_faces():
    from resection import vertex_values

    mesh = grid_plane(n=6)
    f = linear(mesh.triangles_center)
    vv = vertex_values(mesh, f)
    inner = ~np.isclose(np.abs(mesh.vertices[:, :2]), 1.0).any(axis=1)
    np.testing.assert_allclose(vv[inner], linear(mesh.vertices[inner]), rtol=1e-12)
    # on the grid's edge: held within the values of the faces it is built from (its own,
    # and its neighbours' at a corner), and within a cell's change of the exact value
    lo, hi = _ring2_range(mesh, f)
    assert np.all((vv >= lo - 1e-12) & (vv <= hi + 1e-12))
    assert np.max(np.abs(vv - linear(mesh.vertices))) < (2 + 3) * 2 / 6
    assert np.any(np.abs(vv - linear(mesh.vertices)) > 1e-3)  # the limiter acted there
    # mean: exact only for a constant field
    np.testing.assert_allclose(vertex_values(mesh, np.full(len(f), 3.0), interpolation="mean"),
                               3.0, rtol=1e-12)
    # NaN faces are left out; a vertex with only NaN faces is NaN
    g = f.copy()
    corner = 0  # vertex 0 (grid corner) belongs to faces 0 and 36 only
    around = np.flatnonzero((mesh.faces == corner).any(axis=1))
    g[around] = np.nan
    vv = vertex_values(mesh, g)
    assert np.isnan(vv[corner])
    others = np.setdiff1d(np.arange(len(mesh.vertices)), [corner])
    assert np.all(np.isfinite(vv[others]))
    with pytest.raises(InputError, match="faces"):
        vertex_values(mesh, f[:-1])


def test_max_obliqueness_drops_faces_beyond_the_cut_off(plane_map):
    mesh, cam, sm, (face, P, edge) = plane_map
    # closed form: angle between the plane normal (+z) and the line from each face's
    # centroid to the perspective centre
    cen = mesh.vertices[mesh.faces].mean(axis=1)
    v = cam.center - cen
    ang = np.degrees(np.arccos(np.abs(v[:, 2]) / np.linalg.norm(v, axis=1)))
    hit = sm.pixel_counts > 0
    lim = float(np.median(ang[hit]))
    sm2 = SurfaceMap(mesh, cam, max_obliqueness=lim)
    clear = np.abs(ang - lim) > 1e-6
    np.testing.assert_array_equal(sm2.oblique[clear], ang[clear] > lim)
    kept = hit & clear & (ang < lim)
    np.testing.assert_array_equal(sm2.pixel_counts[kept], sm.pixel_counts[kept])
    assert np.all(sm2.pixel_counts[clear & (ang > lim)] == 0)
    # pixels on dropped faces are background
    gone = np.isin(face, np.flatnonzero(ang > lim)) & (edge > 1e-4)
    assert gone.sum() > 100 and not sm2.mask[gone].any()
    assert 0.3 < sm2.mask.sum() / sm.mask.sum() < 0.7
    for bad in (0, 91, "x"):
        with pytest.raises(InputError, match="max_obliqueness"):
            SurfaceMap(mesh, cam, max_obliqueness=bad)


def slab(half=(0.5, 0.3, 0.025), subdivisions=3):
    """Thin box centred on the origin, faces split to about 3 cm."""
    box = trimesh.creation.box(extents=2 * np.asarray(half))
    v, f = box.vertices, box.faces
    for _ in range(subdivisions):
        v, f = trimesh.remesh.subdivide(v, f)
    return trimesh.Trimesh(v, f, process=False)


def test_slab_edges_seen_edge_on_carry_no_value():
    half = np.array([0.5, 0.3, 0.025])
    mesh = slab(half)
    K = [[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]
    cam = Camera.look_at([0.1, -0.8, 2.0], [0.0, 0.0, 0.0], [0, 1, 0], K=K, width=320,
                         height=240)
    # closed-form normals of the box: the axis whose coordinate sits on the box's half size
    cen = mesh.vertices[mesh.faces].mean(axis=1)
    axis = np.argmax(np.abs(cen) / half - 1.0 > -1e-9, axis=1)
    normal = np.zeros_like(cen)
    normal[np.arange(len(cen)), axis] = np.sign(cen[np.arange(len(cen)), axis])
    view = cam.center - cen
    ang = np.degrees(np.arccos(np.abs(np.einsum("ij,ij->i", normal, view))
                               / np.linalg.norm(view, axis=1)))
    image = np.ones((240, 320))
    every = SurfaceMap(mesh, cam, max_obliqueness=None).to_surface(image)
    default = SurfaceMap(mesh, cam).to_surface(image)  # 70 degrees
    side = ~every.unseen & (ang > 70.5)  # the slab's -y edge, seen almost edge-on
    front = ~every.unseen & (ang < 69.5)
    assert side.sum() >= 8 and front.sum() > 100
    assert np.all(ang[side] > 75)  # really grazing, not borderline
    assert np.all(default.unseen[side]) and np.all(np.isnan(default.values[side]))
    np.testing.assert_array_equal(default.counts[front], every.counts[front])
    np.testing.assert_allclose(default.values[front], 1.0)


def test_to_nodes_linear_field_and_no_background(plane_map):
    """Node values from the pixels around each node: a field linear on the plane comes back
    at the node (closed-form hit points; the one-ring of an interior node of this regular
    grid is point-symmetric), and the background never leaks into a node."""
    mesh, cam, sm, (face, P, edge) = plane_map
    V = np.asarray(mesh.vertices)
    img = np.where(face >= 0, 0.3 + 2.0 * P[..., 0] - 0.5 * P[..., 1], 1e6)
    res = sm.to_nodes(img)
    truth = 0.3 + 2.0 * V[:, 0] - 0.5 * V[:, 1]
    # nodes whose faces all lie inside the image: the whole one-ring is sampled
    inside = cam.in_image(cam.project(V), margin=1.0)
    ring = np.ones(len(V), dtype=bool)
    for k in range(3):
        np.logical_and.at(ring, mesh.faces[:, k], inside[mesh.faces].all(axis=1))
    interior = ring & (np.abs(V[:, :2]) < 0.99).all(axis=1)
    assert interior.sum() > 100
    # pixel footprint on the plane ~ 2.2 m / 150 px = 0.015 m; bias from the perspective
    # change of the sampling density across a ring: a fraction of it (slope 2 -> 0.006)
    np.testing.assert_allclose(res.values[interior], truth[interior], atol=6e-3)
    # every node seen gets a value within the range of the model pixels: no background
    seen = ~res.unseen
    assert seen.sum() > interior.sum() and np.all(res.values[seen] < 10)
    assert np.all(res.counts[seen] > 0) and np.all(res.counts[~seen] == 0)
    # NaN pixels are left out and counted
    img2 = img.copy()
    img2[60, 80] = np.nan
    r2 = sm.to_nodes(np.stack([img, img2]))
    touched = r2.nan_counts[1] > 0
    assert 1 <= touched.sum() <= 3 and np.all(r2.nan_counts[0] == 0)
    np.testing.assert_allclose(r2.values[0], res.values, rtol=1e-12)


def test_vertex_values_next_to_missing_faces_stay_bounded():
    """A vertex far from the origin with one valued face around it: the gradient fit on its
    centroid spread (pure round-off) made values of 1e14 to 1e17 (issue 20 item 9). A
    linear field's vertex values stay within its range over the mesh, widened by the
    gradient times two face sizes (the fit's first-order error), whatever faces are
    missing."""
    from resection import vertex_values

    rng = np.random.default_rng(1)
    for _ in range(60):
        m = trimesh.creation.icosphere(subdivisions=2, radius=0.01)
        off = rng.uniform(-3000, 3000, 3)
        m = trimesh.Trimesh(m.vertices * rng.uniform(0.5, 2) + off, m.faces, process=False)
        r = np.abs(m.vertices[:, 0] - off[0]).max()
        f = 1000 + 3e4 * (m.triangles_center[:, 0] - off[0])
        f[rng.random(len(f)) < 0.8] = np.nan
        vv = vertex_values(m, f)
        ok = np.isfinite(vv)
        assert ok.any()
        assert np.abs(vv[ok] - 1000).max() <= 3e4 * (r + 2 * m.edges_unique_length.max())


def test_to_image_renormalises_over_valued_corners(plane_map):
    """Barycentric interpolation never mixes in a missing vertex value: the weights are
    renormalised over the corners that have one (closed form on a face), NaN where none."""
    mesh, cam, smap, _ = plane_map
    f = linear(mesh.triangles_center)
    vert = smap.vertex_values(f[:, None], "linear")
    face = int(np.bincount(smap.face_index[smap.face_index >= 0]).argmax())  # a well-seen face
    a, b, c = mesh.faces[face]
    holed = vert.copy()
    holed[a] = np.nan  # as if vertex a had no value

    class Patched(SurfaceMap):
        def vertex_values(self, fv, interpolation="linear"):
            return holed

    p = Patched.__new__(Patched)
    p.__dict__.update(smap.__dict__)
    img = p.to_image(f)
    pix = smap.face_index == face
    assert pix.sum() > 3
    bary = smap.barycentric[pix]  # weights of corners a, b, c
    ref = (bary[:, 1] * vert[b, 0] + bary[:, 2] * vert[c, 0]) / (bary[:, 1] + bary[:, 2])
    np.testing.assert_allclose(img[pix], ref, rtol=1e-12)
    holed[[b, c]] = np.nan  # no corner with a value: NaN
    assert np.isnan(p.to_image(f)[pix]).all()


def test_backproject_png_scaled_or_refused(tmp_path, capsys):
    """Float values to PNG: refused with the choices by default, or mapped linearly to
    1..65535 (NaN 0) as printed with --png-range."""
    from PIL import Image

    from resection.cli.main import main
    from resection.io.cameras import write_camera

    mesh = grid_plane()
    cam = camera()
    mesh.export(tmp_path / "plane.ply")
    write_camera(tmp_path / "cam.json", cam)
    vals = 681.0 + 695.0 * (mesh.triangles_center[:, 0] + 1) / 2  # 681..1376
    np.save(tmp_path / "v.npy", vals)
    base = ["backproject", "--mesh", str(tmp_path / "plane.ply"), "--camera",
            str(tmp_path / "cam.json"), "--values", str(tmp_path / "v.npy")]
    assert main([*base, "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "--png-range" in err and ".tif" in err and "x.png" in err
    assert not (tmp_path / "x.png").exists()
    assert main([*base, "--out", str(tmp_path / "x.npy")]) == 0
    ref = np.load(tmp_path / "x.npy")
    assert main([*base, "--out", str(tmp_path / "x.png"), "--png-range", "600,1400"]) == 0
    assert "600 -> 1, 1400 -> 65535" in capsys.readouterr().out
    got = np.asarray(Image.open(tmp_path / "x.png"))
    assert got.dtype == np.uint16
    fin = np.isfinite(ref)
    assert np.all(got[~fin] == 0) and np.all(got[fin] >= 1)
    back = 600 + (got[fin].astype(float) - 1) / 65534 * 800
    # half a count of the map, plus the float32 rounding of the .npy reference
    assert np.abs(back - ref[fin]).max() <= 0.5 * 800 / 65534 + 1376 * 2**-23


def test_vertex_values_are_the_weighted_least_squares_fit_of_each_vertex():
    """On a sphere with a third of its faces NaN (and an unused vertex), each vertex value
    is the area-weighted mean of its valued faces plus the least-squares gradient of
    their centroids (directions spreading less than 1e-2 of the largest dropped), held
    within the values of those faces, written here vertex by vertex with NumPy's
    pseudo-inverse."""
    from resection import vertex_values

    sphere = trimesh.creation.icosphere(3)
    mesh = trimesh.Trimesh(np.vstack([sphere.vertices, [[5.0, 5.0, 5.0]]]), sphere.faces,
                           process=False)
    c = mesh.triangles_center
    f = np.sin(2.0 * c[:, 0]) + c[:, 1] ** 2 - 0.5 * c[:, 2]
    f[np.random.default_rng(3).random(len(f)) < 0.33] = np.nan
    got = vertex_values(mesh, f)
    area = mesh.area_faces
    checked = 0
    for v in range(len(sphere.vertices)):
        around = np.flatnonzero((mesh.faces == v).any(axis=1) & np.isfinite(f))
        if around.size < 3:  # too few faces for a 2-D gradient: the 2-ring's rule
            continue
        w, cc = area[around], c[around]
        cbar = w @ cc / w.sum()
        d = cc - cbar
        C = (w[:, None] * d).T @ d
        if np.sum(np.linalg.eigvalsh(C) > 1e-2 * np.linalg.eigvalsh(C)[-1]) < 2:
            continue
        grad = np.linalg.pinv(C, rcond=1e-2, hermitian=True) @ ((w[:, None] * d).T @ f[around])
        ref = w @ f[around] / w.sum() + grad @ (mesh.vertices[v] - cbar)
        ref = min(max(ref, f[around].min()), f[around].max())
        np.testing.assert_allclose(got[v], ref, rtol=1e-9, atol=1e-12)
        checked += 1
    assert checked > 0.6 * len(sphere.vertices)
    assert np.isnan(got[-1])  # the unused vertex has no face


def test_prepared_vertex_fit_gives_the_same_image(plane_map, monkeypatch):
    """SurfaceMap.prepare builds the vertex matrix of a pattern of valued faces ahead:
    to_image then builds none and returns the same image as a map that was not
    prepared; another pattern is built as before."""
    from resection.surface import vertex_fit

    mesh, cam, smap, _ = plane_map
    c = mesh.triangles_center
    f = linear(c)
    f[::3] = np.nan
    ref = SurfaceMap(mesh, cam).to_image(f, background=0.0)
    smap.prepare(np.isfinite(f))
    built = []
    real = vertex_fit._vertex_matrix
    monkeypatch.setattr(vertex_fit, "_vertex_matrix",
                        lambda *a, **kw: built.append(1) or real(*a, **kw))
    np.testing.assert_array_equal(smap.to_image(f, background=0.0), ref)
    assert not built
    g = f.copy()
    g[1] = np.nan
    np.testing.assert_array_equal(smap.to_image(g, background=0.0),
                                  SurfaceMap(mesh, cam).to_image(g, background=0.0))
    assert built
    with pytest.raises(InputError, match="valued"):
        smap.prepare(np.ones(3, bool))
