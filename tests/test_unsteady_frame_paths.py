"""The fast way's per-frame shortcuts, each against the plain computation it replaces.

* pixels warped in from beyond the frame's edge (NaN) leave their faces: the sparse
  products rescale only the faces they touch (:meth:`FrameOperator._camera_faces`), checked
  against the dense weighted mean over each face's remaining pixels, with and without
  uPSP's polynomial patch (a spot whose ring lost a pixel leaves as a whole);
* faces lost in a frame leave their nodes: :func:`phase1._fast_nodes` rescales only the
  nodes around them, checked against :func:`phase1._to_nodes` (the area-weighted mean of
  the finite faces around each node, the full way's);
* a picture drawn into a :func:`resection.surface.plots.prepare_view` made apart equals
  the one drawn from scratch.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from selfillum.unsteady.fastmap import FrameOperator
from selfillum.unsteady.phase1 import _face_to_vertex, _fast_nodes, _to_nodes


def _operator(A, patch=None, seen=None) -> FrameOperator:
    op = object.__new__(FrameOperator)  # the products alone, without a cast
    op.A, op.patch, op._shares, op._nodes = [sp.csr_matrix(A)], [patch], {}, None
    op.seen = np.ones(A.shape[0], bool) if seen is None else seen
    return op


def _dense_faces(A, x, bad, A2=None, Cu=None, Aw=None, nP=1):
    """Each face's value from its pixels left (and its spots whose rings are whole),
    scaled to the face's whole weight; NaN for a face left with none."""
    A = np.asarray(A)
    good = ~bad
    share = A.sum(axis=1)
    num = A[:, good] @ x[good]
    kept = A[:, good].sum(axis=1)
    if A2 is not None:
        Cu, A2, Aw = np.asarray(Cu), np.asarray(A2), np.asarray(Aw)
        share = share + Aw.sum(axis=1)
        m = Aw.shape[1]
        ring_ok = ~np.array([(Cu[s * nP:(s + 1) * nP][:, bad] != 0).any() for s in range(m)])
        coef = (Cu[:, good] @ x[good]).reshape(m, nP)
        num = num + A2 @ (coef * ring_ok[:, None]).ravel()
        kept = kept + Aw[:, ring_ok].sum(axis=1)
    out = np.zeros(A.shape[0])
    has = share > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        out[has] = np.where(kept[has] > 0, num[has] * share[has] / kept[has], np.nan)
    return out


@pytest.mark.parametrize("with_patch", [False, True])
def test_pixels_off_the_frame_leave_only_their_faces(with_patch):
    rng = np.random.default_rng(3)
    nf, npx, m, nP = 60, 400, 4, 3
    face = rng.integers(0, nf - 5, npx)  # the last 5 faces have no pixel
    A = sp.csr_matrix((rng.uniform(0.1, 1.0, npx), (face, np.arange(npx))), shape=(nf, npx))
    patch, dense = None, {}
    if with_patch:
        ring = [rng.choice(npx, 6, replace=False) for _ in range(m)]
        Cu = np.zeros((m * nP, npx))
        for s, r in enumerate(ring):
            Cu[s * nP:(s + 1) * nP, r] = rng.normal(size=(nP, r.size))
        A2 = sp.random(nf, m * nP, density=0.2, random_state=4).toarray()
        Aw = np.abs(sp.random(nf, m, density=0.3, random_state=5).toarray())
        patch = (sp.csr_matrix(A2), sp.csr_matrix(Cu), None, sp.csr_matrix(Aw))
        dense = dict(A2=A2, Cu=Cu, Aw=Aw, nP=nP)
    op = _operator(A, patch)
    x = rng.uniform(100.0, 4000.0, npx)
    for n_bad in (0, 1, 25):
        bad = np.zeros(npx, bool)
        bad[rng.choice(npx, n_bad, replace=False)] = True
        # every pixel of face 0 off the frame: that face is not seen
        if n_bad == 25:
            bad[face == 0] = True
        got = op._camera_faces(0, np.where(bad, np.nan, x), bad)
        want = _dense_faces(A.toarray(), x, bad, **dense)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got[~np.isnan(want)], want[~np.isnan(want)], rtol=1e-12)
        if n_bad == 25 and not with_patch:  # (a patched spot may still light it)
            assert np.isnan(got[0])


class _Grid:
    def __init__(self, n_vertices, order):
        self.node_vertex = order

    def to_nodes(self, v):
        return np.asarray(v)[..., self.node_vertex]


def test_faces_lost_in_a_frame_leave_only_their_nodes():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    nf, nv = len(mesh.faces), len(mesh.vertices)
    rng = np.random.default_rng(7)
    W = _face_to_vertex(mesh)
    grid = _Grid(nv, rng.permutation(nv))  # grid nodes in another order than vertices
    seen_ref = rng.random(nf) < 0.7
    op = _operator(sp.csr_matrix((nf, 1)), seen=seen_ref)
    B = rng.uniform(1.0, 2.0, nf)
    E = B - rng.uniform(0.0, 0.1, nf)
    for lost in (0, 1, 40):
        seen = seen_ref.copy()
        seen[rng.choice(np.flatnonzero(seen_ref), lost, replace=False)] = False
        Ei, Bi = np.where(seen, E, np.nan), np.where(seen, B, np.nan)
        got = _fast_nodes(op, W, grid, Ei, Bi, seen)
        want = _to_nodes(W, np.vstack([Ei, Bi]), grid)
        np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
        np.testing.assert_allclose(got[~np.isnan(want)], want[~np.isnan(want)], rtol=1e-6)


def test_a_prepared_view_draws_the_same_picture():
    from resection.surface.plots import plot_surface, prepare_view

    mesh = trimesh.creation.box(extents=(1.0, 2.0, 0.5)).subdivide().subdivide()
    fv = np.linspace(0.0, 1.0, len(mesh.faces))
    view = prepare_view(mesh, outline=True)
    assert view.outline_uv is not None and len(view.outline_uv) > 0

    def pixels(fig):
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        return np.asarray(canvas.buffer_rgba()).copy()

    a = pixels(plot_surface(mesh, fv, outline=True))
    b = pixels(plot_surface(mesh, fv, outline=True, view=view))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(Exception, match="faces"):
        plot_surface(trimesh.creation.icosphere(), np.zeros(80), view=view)


@pytest.mark.parametrize("A", [[[1.001, 0.0002, 0.3], [0.0001, 0.999, -0.2]],
                               [[1.0, 0.0, 2.0], [0.0, 1.0, -3.0]]],
                         ids=["affine", "whole-pixel shift"])
def test_affine_sampling_is_scipys_bilinear_with_nan_neighbours_of_zero_weight_left_out(A):
    """The registration's sampler against ``scipy.ndimage.map_coordinates(order=1)``:
    equal values; NaN exactly where a neighbour of non-zero weight is NaN or the point
    falls outside the frame (a whole-pixel shift reads no NaN it gives no weight)."""
    from scipy import ndimage

    from selfillum.unsteady.registration import AffineRegistration

    rng = np.random.default_rng(0)
    img = rng.integers(0, 4000, (80, 128)).astype(np.float64)
    img[rng.random(img.shape) < 0.02] = np.nan
    mask = np.zeros(img.shape, bool)
    mask[5:75, 4:124] = True
    A = np.asarray(A)
    reg = AffineRegistration(np.nan_to_num(img), mask)
    pix = np.flatnonzero(np.ones(img.shape, bool))
    got = reg.sample(img, A, pix, 1)
    v, u = np.divmod(pix, img.shape[1])
    at = [A[1, 0] * u + A[1, 1] * v + A[1, 2], A[0, 0] * u + A[0, 1] * v + A[0, 2]]
    want = ndimage.map_coordinates(np.nan_to_num(img), at, order=1)
    bad = ndimage.map_coordinates(np.isnan(img).astype(float), at, order=1) > 0
    bad |= ~((at[0] >= 0) & (at[0] <= img.shape[0] - 1) & (at[1] >= 0)
             & (at[1] <= img.shape[1] - 1))
    np.testing.assert_array_equal(np.isnan(got), bad)
    np.testing.assert_allclose(got[~bad], want[~bad], rtol=1e-12, atol=1e-9)
    for workers in (1, 3):  # the whole frame's warp, stepped along rows, in blocks
        whole = reg.warp_all(img, A, workers).ravel()
        np.testing.assert_array_equal(np.isnan(whole), bad)
        np.testing.assert_allclose(whole[~bad], want[~bad], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("filter_", ["none", "gaussian"])
def test_cameras_prepared_side_by_side_equal_one_by_one(filter_):
    """Several cameras' frames (the affine fit and warp onto frame 0, the filter) made one
    thread a camera give the same images as made one after another: each is its camera's
    own work. Checked against a direct registration of each camera's frame."""
    from selfillum.unsteady.frames import fixed_images as _fixed_images
    from selfillum.unsteady.phase1 import CameraRun
    from selfillum.unsteady.registration import AffineRegistration

    rng = np.random.default_rng(3)
    H, W = 60, 90
    yy, xx = np.mgrid[:H, :W]
    cams, regs, read = [], [], []
    for c in range(3):  # cameras
        base = 2000 + 600 * np.sin(xx / (5.0 + c)) * np.cos(yy / 7.0)
        shifted = 2000 + 600 * np.sin((xx - 0.3 * (c + 1)) / (5.0 + c)) * np.cos(yy / 7.0)
        frames = np.stack([base, shifted]) + rng.normal(0, 2, (2, H, W))
        mask = np.zeros((H, W), bool)
        mask[8:52, 10:80] = True
        cams.append(CameraRun(c + 1, None, frames))
        regs.append(AffineRegistration(frames[0], mask))
        read.append(np.flatnonzero(mask))
    kw = dict(spot_px=[None] * 3, filter=filter_, filter_size=5, pres=None, read=read)
    one = _fixed_images(cams, 1, regs, workers=1, **kw)
    for r in regs:
        r._M = np.eye(3)  # the fits start again from the identity
    side = _fixed_images(cams, 1, regs, workers=None, **kw)
    for a, b in zip(one, side, strict=True):
        np.testing.assert_array_equal(np.asarray(getattr(a, "values", a)),
                                      np.asarray(getattr(b, "values", b)))
    for c, r in enumerate(regs):  # each camera's own registration of its frame
        r._M = np.eye(3)
        A = r.fit(cams[c].frames[1])
        np.testing.assert_allclose(A[0, 2], 0.3 * (c + 1), atol=0.05)


def test_moving_samples_are_the_cameras_projection_and_scipys_bilinear():
    """A moving model's frame read at its reference's points (``_sample_moved``, the
    compiled projection and sampling) against :meth:`resection.Camera.project` with its
    distortion and SciPy's bilinear ``map_coordinates``: the statuses (off the sensor,
    behind the camera, moved too far) and the values."""
    from scipy.ndimage import map_coordinates

    from resection import Camera
    from selfillum.unsteady.fastmap import _sample_moved

    rng = np.random.default_rng(5)
    H, W, n = 60, 90, 3000
    cam = Camera(width=W, height=H, K=np.array([[80.0, 0.3, 44.0], [0, 78.0, 29.0],
                                                [0, 0, 1]]),
                 dist=np.array([-0.08, 0.02, 0.001, -0.002, 0.0]),
                 R=np.eye(3), t=np.array([0.01, -0.02, 0.0]))
    X = np.column_stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-0.5, 0.5, n),
                         rng.uniform(0.9, 1.1, n)])
    X[:20, 2] = -1.0  # behind the camera
    X[20:40] = np.nan  # background pixels: read where they are
    uv = np.full((n, 2), np.nan)
    uv[40:] = cam.project(X[40:])
    uv0 = np.where(np.isfinite(uv), uv, rng.uniform(0, 50, (n, 2)))
    uv0[40:80] += 3.0  # moved by 3 px: beyond a refresh of 2 x 1 px
    img = rng.integers(0, 4096, (H, W)).astype(np.uint16)
    x, status = _sample_moved(X, uv0, img, cam, 1.0, workers=1)
    assert status is None  # a point moved more than twice refresh_px
    keep = np.r_[0:40, 80:n]
    x, status = _sample_moved(X[keep], uv0[keep], img, cam, 1.0, workers=1)
    uv, uv0 = uv[keep], uv0[keep]
    inside = np.isfinite(uv).all(axis=1) & (uv[:, 0] >= -0.5) & (uv[:, 1] >= -0.5) & \
        (uv[:, 0] <= W - 0.5) & (uv[:, 1] <= H - 0.5)
    back = np.arange(len(keep)) < 40
    back_nan = np.arange(len(keep)) >= 20
    np.testing.assert_array_equal(status[~back], np.where(inside[~back], 0, 2))
    np.testing.assert_array_equal(status[:20], 2)
    np.testing.assert_array_equal(status[20:40], 0)
    ok = (status == 0) & ~back
    ref = map_coordinates(img.astype(np.float64), [np.clip(uv[ok, 1], 0, H - 1),
                                                   np.clip(uv[ok, 0], 0, W - 1)],
                          order=1, mode="nearest")
    np.testing.assert_allclose(x[ok], ref, rtol=0, atol=1e-6)
    at = np.rint(uv0[back & back_nan]).astype(int)  # a NaN point: its own pixel
    np.testing.assert_array_equal(x[back & back_nan], img[at[:, 1], at[:, 0]])
    assert ok.sum() > 1200 and (status[~back] == 2).sum() > 50
    x2, status2 = _sample_moved(X[keep], uv0, img, cam, 1.0, workers=2)  # in blocks
    np.testing.assert_array_equal(status2, status)
    np.testing.assert_array_equal(x2[status == 0], x[status == 0])
