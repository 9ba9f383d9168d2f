"""The unsteady run with the options uPSP's decks set (``target_patcher = polynomial``,
``registration = pixel``, ``overlap = average_view``, a Gaussian filter), and its
self-illumination of the faces no camera sees.

* uPSP's polynomial patch as a linear operator (:func:`selfillum.unsteady.spots.
  patch_operator`) against a least-squares fit by NumPy, spot by spot, and against an image
  that is a cubic polynomial (the patch recovers it);
* the fast Phase 1 (sparse products) against the full per-frame map, for every deck option
  (the same answer for a fixed map; the fast way's tolerance for a moving model), with
  the full casts counted: after the references, no frame takes the full way;
* the hidden faces' emission continued within their part (not across the concave crease
  where a block stands on a plate).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest

from selfillum.unsteady.spots import patch_operator, patch_spots


def _lstsq_patch(img, centre, radius, ring_px=3.0, order=3):
    """One spot patched by NumPy's least squares on its ring (the reference)."""
    H, W = img.shape
    R = int(np.ceil(radius + ring_px))
    cu, cv = int(np.rint(centre[0])), int(np.rint(centre[1]))
    v, u = np.mgrid[cv - R:cv + R + 1, cu - R:cu + R + 1]
    inb = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    d = np.hypot(u - centre[0], v - centre[1])
    ring = inb & (d > radius) & (d <= radius + ring_px)
    ring[ring] = np.isfinite(img[v[ring], u[ring]])  # a value that is not finite: left out
    inside = inb & (d <= radius)
    x, y = (u - centre[0]) / R, (v - centre[1]) / R
    terms = [x**i * y**j for i in range(order + 1) for j in range(order + 1 - i)]
    A = np.stack([t[ring] for t in terms], axis=1)
    coef, *_ = np.linalg.lstsq(A, img[v[ring], u[ring]], rcond=None)
    out = img.astype(float).copy()
    out[v[inside], u[inside]] = np.stack([t[inside] for t in terms], axis=1) @ coef
    return out


def test_patch_operator_is_numpys_least_squares_and_recovers_a_cubic():
    rng = np.random.default_rng(3)
    img = rng.uniform(100, 4000, (90, 120))
    centres = np.array([[30.3, 40.6], [90.2, 20.9], [60.0, 70.4]])  # apart
    radii = np.array([6.2, 4.1, 8.0])
    got = patch_spots(img, centres, radii)
    want = img.copy()
    for c, r in zip(centres, radii, strict=True):
        want = np.where(_lstsq_patch(img, c, r) != img, _lstsq_patch(img, c, r), want)
    np.testing.assert_allclose(got, want, rtol=1e-7)  # normal equations against lstsq
    # the operator's parts: C (coefficients from the rings) and the terms, applied
    P = patch_operator(img.shape, centres, radii)
    np.testing.assert_allclose(P.apply(img), want, rtol=1e-7)
    assert P.C.shape == (3 * 10, img.size)  # 10 terms of a cubic a spot
    # an image that is a cubic polynomial: the patch gives it back inside the spots
    v, u = np.mgrid[0:90, 0:120] / 100.0
    cubic = 1000 + 300 * u - 200 * v + 50 * u * v + 80 * u**3 - 40 * v**2 * u
    spotted = np.where(P.apply(np.zeros_like(img)) != 0, 0.0, cubic)  # darken nothing
    spotted[np.hypot(np.arange(120)[None] - 30.3, np.arange(90)[:, None] - 40.6) < 6] = 5.0
    np.testing.assert_allclose(patch_spots(spotted, centres, radii), cubic, rtol=1e-7)
    # values that are not finite: NaN off the spots (inf too), left out of the rings
    holed = img.copy()
    holed[5, 7], holed[80, 100] = np.nan, np.inf
    ring = (np.hypot(np.arange(120)[None] - 30.3, np.arange(90)[:, None] - 40.6) > 7.0) \
        & (np.hypot(np.arange(120)[None] - 30.3, np.arange(90)[:, None] - 40.6) < 8.0)
    holed[np.argwhere(ring)[0][0], np.argwhere(ring)[0][1]] = np.nan
    Pf = patch_operator(img.shape, centres, radii, finite=np.isfinite(holed))
    want = _lstsq_patch(holed, centres[0], radii[0])
    got = Pf.apply(holed)
    assert np.isnan(got[5, 7]) and np.isnan(got[80, 100]) and np.isinf(holed[80, 100])
    inside = np.hypot(np.arange(120)[None] - 30.3, np.arange(90)[:, None] - 40.6) <= 6.2
    np.testing.assert_allclose(got[inside], want[inside], rtol=1e-7)
    same = holed.copy()
    assert Pf.apply(same, in_place=True) is same  # patched itself, as asked
    np.testing.assert_array_equal(same, got)


@pytest.fixture(scope="module")
def scene():
    """A vibrating run (1 degree: points move about 2 px), 24 frames, its true poses, the
    view factors."""
    from resection.io.cameras import read_camera
    from resection.io.markers import read_markers
    from resection.io.video import open_frames
    from scenes.unsteady_run import make_unsteady_run
    from selfillum.transport.viewfactors import view_factors
    from selfillum.unsteady.grid import load_run_grid
    from selfillum.unsteady.spots import DarkSpots

    T = 24
    with tempfile.TemporaryDirectory() as d:
        run = make_unsteady_run(Path(d), frames=T, vibration_deg=1.0, faces=1500,
                                width=160, height=120)
        grid = load_run_grid(run.grid)
        cam = read_camera(run.calibration)
        src = open_frames(run.video)
        frames = [np.asarray(src[k]) for k in range(T)]
        src.close()
        spots = DarkSpots.from_markers(read_markers(run.targets, include_taps=True),
                                       str(run.targets))
    poses = [cam.with_pose(R=run.poses[0, k, :3], t=run.poses[0, k, 3]) for k in range(T)]
    F = view_factors(grid.mesh, rays_per_face=64, seed=0, progress=False)
    return dict(T=T, grid=grid, cam=cam, frames=frames, spots=spots, poses=poses, F=F)


def _values(sc, monkeypatch, fast, **opts):
    """Node values of every frame, and the number of SurfaceMap casts it took."""
    import resection.surface.surface_map as smod
    from selfillum.unsteady.phase1 import CameraRun, SelfIllumination, map_run

    casts = []
    real = smod.SurfaceMap.__init__

    def counted(self, *a, **k):
        casts.append(1)
        real(self, *a, **k)

    monkeypatch.setattr(smod.SurfaceMap, "__init__", counted)
    si = SelfIllumination(sc["grid"].mesh, sc["F"], 0.6)
    res = map_run(sc["grid"], [CameraRun(1, sc["cam"], sc["frames"], sc["poses"])],
                  range(sc["T"]), spots=sc["spots"], si=si, fast=fast, **opts)
    out = np.array([r.values for r in res], dtype=np.float64)
    monkeypatch.undo()
    return out, len(casts)


@pytest.mark.parametrize("opts", [
    dict(registration="none", patcher="polynomial", overlap="average_view"),
    dict(registration="first-frame", patcher="polynomial", overlap="average_view"),
    dict(registration="none", patcher="polynomial", overlap="best_view",
         filter="gaussian", filter_size=5),
    dict(registration="first-frame", patcher="none", overlap="merge"),
], ids=["none-poly", "pixel-poly", "none-poly-gauss-best", "pixel-mask-merge"])
def test_fixed_map_deck_options_fast_equals_full(scene, monkeypatch, opts):
    """A fixed map (frame 0's) with each deck option: the sparse products give the full
    way's node values (1e-6), with one cast of frame 0 instead of one a frame.

    With the affine registration (``pixel``), pixels warped in from beyond the frame's
    edge are NaN: the sparse products leave them out of their faces (and a patched spot
    whose ring lost one, as a whole), the full way's merge drops the faces' edge pixels
    around them and fits a spot's patch on the rest of its ring. The nodes at the frame's
    edge differ (under 0.5 % of the values); the others agree to 2e-5 (the registration's
    rounding)."""
    full, n_full = _values(scene, monkeypatch, False, **opts)
    fast, n_fast = _values(scene, monkeypatch, True, **opts)
    assert n_full >= 1 and n_fast == 1
    assert np.isfinite(full).mean() > 0.2
    edge = opts["registration"] == "first-frame"
    if not edge:
        np.testing.assert_array_equal(np.isfinite(full), np.isfinite(fast))
        ok = np.isfinite(full)
        np.testing.assert_allclose(fast[ok], full[ok], rtol=1e-6)
        return
    both = np.isfinite(full) & np.isfinite(fast)
    assert (np.isfinite(full) != np.isfinite(fast)).mean() < 0.005
    rel = np.abs(fast[both] - full[both]) / np.abs(full[both])
    # measured: median 0, 95th percentile 3e-6, 99th 0.4 %, largest 2.7 %
    assert np.median(rel) < 1e-6 and np.percentile(rel, 95) < 1e-5
    assert np.percentile(rel, 99) < 0.01


@pytest.mark.parametrize("opts", [
    dict(patcher="polynomial", overlap="average_view"),
    dict(patcher="polynomial", overlap="average_view", filter="gaussian", filter_size=5),
    dict(patcher="none", overlap="best_view", filter="gaussian", filter_size=3),
], ids=["poly", "poly-gauss", "mask-gauss-best"])
def test_moving_model_deck_options_take_the_fast_way(scene, monkeypatch, opts):
    """A moving model (each frame's own pose), uPSP's patch and the Gaussian filter: every
    frame after the references takes the sparse products (a handful of casts, not one a
    frame: before, the patch and the filter sent every frame the full way), within the
    fast way's stated tolerance of the full per-frame map (median 0.1 %, 99th percentile
    3 %, under 0.5 % of the values seen by one way and not the other)."""
    full, n_full = _values(scene, monkeypatch, False, registration="track", **opts)
    fast, n_fast = _values(scene, monkeypatch, True, registration="track", **opts)
    assert n_full == scene["T"]
    assert n_fast <= 4
    both = np.isfinite(full) & np.isfinite(fast)
    assert both.sum() > 0.2 * full.size
    assert (np.isfinite(full) != np.isfinite(fast)).mean() < 0.005
    rel = np.abs(fast[both] - full[both]) / np.abs(full[both])
    assert np.median(rel) < 1e-3 and np.percentile(rel, 99) < 0.03


@pytest.mark.parametrize("patcher", ["polynomial", "none"])
def test_moving_filtered_frame_is_the_patch_then_scipys_filter(scene, patcher):
    """A moving model's filtered frame read at its reference's own pose by the fast way
    (the frame filtered in its own pixels, read at the reference's points, the pixels the
    spots reach corrected: :mod:`selfillum.unsteady.spot_filter`) against uPSP's order
    done plainly: each spot patched by NumPy's least squares on its ring (or left out),
    then SciPy's Gaussian of the finite pixels over its weights, read at the operator's
    pixels. Without the correction the pixels beside the spots are off by 1e-3 to 1e-1."""
    from scipy import ndimage

    from resection.surface.surface_map import SurfaceMap
    from selfillum.unsteady.fastmap import FrameOperator
    from selfillum.unsteady.spots import mask_spots, project_spots

    cam = scene["poses"][0]
    smap = SurfaceMap(scene["grid"].mesh, cam, max_obliqueness=70.0)
    cen, rad = project_spots(scene["spots"], smap, margin_px=1.0)
    assert len(rad) >= 5
    img = np.asarray(scene["frames"][0], dtype=np.float64)
    if patcher == "polynomial":
        spots = patch_operator(smap.shape, cen, rad)
        assert not spots.unfit.any()  # every ring is whole: each spot its own fit
        prepared = img.copy()
        for c, r in zip(cen, rad, strict=True):
            one = _lstsq_patch(img, c, r)
            prepared = np.where(one != img, one, prepared)
        finite = np.ones(smap.shape, bool)
    else:
        spots = (cen, rad)
        prepared = mask_spots(img, cen, rad).astype(np.float64)
        finite = np.isfinite(prepared)
    mk = dict(method="weighted", feather_px=0, edge_margin=1, match_gain=False)
    op = FrameOperator([smap], [finite], mk, [1.0], None, sample_points=True,
                       filter_size=5, spots=[spots])
    x, bad = op.samples([scene["frames"][0]], [cam], 3.0, workers=1)[0]
    # OpenCV's sigma for a 5-pixel kernel, 0.3 ((5 - 1) / 2 - 1) + 0.8
    g1 = np.exp(-0.5 * (np.arange(-2, 3) / 1.1) ** 2)
    k2 = np.outer(g1, g1) / g1.sum() ** 2
    ok = np.isfinite(prepared)
    num = ndimage.correlate(np.where(ok, prepared, 0.0), k2, mode="reflect")
    den = ndimage.correlate(ok.astype(np.float64), k2, mode="reflect")
    want = num.ravel()[op.cols[0]] / den.ravel()[op.cols[0]]  # pixels read: den > 0
    assert not bad.any()
    np.testing.assert_allclose(x, want, rtol=1e-9)
    plain = ndimage.correlate(img, k2, mode="reflect").ravel()[op.cols[0]]
    off = np.abs(plain - want) / np.abs(want)  # what the correction changes
    assert (off > 1e-3).sum() > 100 and off.max() > 0.05
    # a spot's pixel not read (off the sensor): the pixels its value reaches are left out,
    # exactly those whose corrected value changes with it
    sf = op.spot_filters[0][0]
    g = img.ravel()[sf.pixels]  # the frame at its reference's pose
    for j in (0, len(g) // 2, len(g) - 1):
        x0, x1, b = plain.copy(), plain.copy(), np.zeros(plain.size, bool)
        sf.correct(x0, b.copy(), g, np.zeros(g.size, bool))
        g2 = g.copy()
        g2[j] += 1000.0
        sf.correct(x1, b.copy(), g2, np.zeros(g.size, bool))
        lost = np.zeros(g.size, bool)
        lost[j] = True
        sf.correct(plain.copy(), b, g, lost)
        np.testing.assert_array_equal(b, x0 != x1)
        assert b.any()


def test_hidden_faces_continue_within_their_part():
    """A block standing on a plate: the graph crosses the block's own (convex) edges and
    the plate's smooth ones, not the concave crease at the block's foot; a hidden side of
    the block takes its time history from the block's seen faces, and a hidden face
    follows its source's ratio to frame 0."""
    from scenes.slab_block import slab_block
    from selfillum.unsteady.hidden import HiddenContinuation, part_graph

    sc = slab_block(3000, half=(0.35, 0.25), box=(0.04, 0.03, 0.04), rho_paint=0.6,
                    rho_box=0.6)
    mesh = sc.mesh
    n = len(mesh.faces)
    c = np.asarray(mesh.triangles_center)
    nz = np.asarray(mesh.face_normals)
    on_block = (np.abs(c[:, 0]) <= 0.0401) & (np.abs(c[:, 1]) <= 0.0301) & (c[:, 2] > 1e-6)
    top = on_block & (nz[:, 2] > 0.9)
    side_px = on_block & (nz[:, 0] > 0.9)  # the block's +x side
    plate_top = ~on_block & (nz[:, 2] > 0.9)
    assert top.sum() > 4 and side_px.sum() > 4 and plate_top.sum() > 100
    g = part_graph(mesh)
    # no edge joins the block's side to the plate (the foot is a concave crease)
    i, j = g.nonzero()
    assert not np.any(side_px[i] & plate_top[j])
    assert np.any(side_px[i] & top[j])  # but the side and the top are joined
    seen = plate_top | top | (on_block & (nz[:, 0] < -0.9))  # the +x side is hidden
    B0 = np.full(n, 100.0)
    E0 = np.full(n, 90.0)
    hc = HiddenContinuation(g, B0, E0, needed=np.ones(n, bool))
    hid, src, _ = hc.assignment(seen)
    assert set(np.flatnonzero(side_px)) <= set(hid)
    assert on_block[src[np.isin(hid, np.flatnonzero(side_px))]].all()
    # the block's seen faces at 110 % of frame 0, the plate at 100 %: the side follows
    B = np.where(on_block, 110.0, 100.0)
    x = hc.radiosity(B, seen)
    np.testing.assert_allclose(x[side_px], 100.0 + 90.0 * 0.1)
    np.testing.assert_allclose(x[seen], B[seen])
    # a frame that lost a few faces (under 1 %) reuses the search: the lost faces hold
    # frame 0's radiosity, the faces they sourced their own
    lost = np.flatnonzero(top)[:2]
    seen2 = seen.copy()
    seen2[lost] = False
    assert hc.assignment(seen2)[2] is hc.assignment(seen)[2]
    x2 = hc.radiosity(B, seen2)
    np.testing.assert_allclose(x2[lost], 100.0)
    from_lost = hid[np.isin(src, lost)]
    np.testing.assert_allclose(x2[from_lost], 100.0)


@pytest.mark.parametrize("extra", [(), ("--registration", "track"),
                                   ("--registration", "track", "--filter", "gaussian",
                                    "--filter-size", "5")],
                         ids=["deck-pixel-poly", "track-poly", "track-poly-gauss"])
def test_whole_command_with_the_deck_maps_frames_by_sparse_products(tmp_path, capsys,
                                                                    extra):
    """The whole command on a run whose deck is uPSP's (``target_patcher = polynomial``,
    ``registration = pixel``, ``overlap = average_view``), its ``.wtd`` in NASA's layout:
    one frame is mapped the full way (frame 0), every other by the sparse products (before
    issue 33, every frame of this deck was a ray cast)."""
    from scenes.unsteady_run import make_unsteady_run
    from selfillum.cli import main

    run = make_unsteady_run(tmp_path / "run", frames=16, faces=1500, width=160, height=120)
    assert "target_patcher = polynomial" in run.deck.read_text()
    assert run.wtd.read_text().startswith("RUN ")
    rc = main(["unsteady", str(run.deck), "--paint-calibration", str(run.paint), "--steady",
               str(run.steady), "--fps", str(run.fps), "--out", str(tmp_path / "o.h5"),
               "--quiet", "--no-plots", *extra])
    out = capsys.readouterr()
    assert rc == 0, out.err
    assert "phase 1: 15 frames by sparse products, 1 mapped the full way" in out.out
