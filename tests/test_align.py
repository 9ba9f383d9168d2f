"""Alignment through the model surface: sampling positions against OpenCV's projection of
closed-form surface points, warped images against direct closed-form renders, and the PSP
ratio noise of the paper's Figure 21 (aligned = perfectly registered, not a 1-px shift)."""

import cv2
import numpy as np
import pytest
import trimesh

from resection import Camera, InputError, SurfaceMap
from resection.surface.align import ViewWarp, warp_image
from scenes.psp_pair import panel_mesh, plane_hits, pressure_factor, psp_pair, render


@pytest.fixture(scope="module")
def pair():
    pp = psp_pair(seed=3)
    return pp, ViewWarp(pp.mesh, pp.camera_off, pp.camera_on)


def inner_mask(warp, cam_a, margin=2):
    u, v = warp.uv[..., 0], warp.uv[..., 1]
    with np.errstate(invalid="ignore"):
        return (warp.valid & (u > margin) & (u < cam_a.width - 1 - margin) & (v > margin)
                & (v < cam_a.height - 1 - margin))


def test_sampling_positions_match_opencv(pair):
    pp, warp = pair
    P, on = plane_hits(pp.camera_on)
    K, dist, rvec, tvec = pp.camera_off.to_opencv()
    uv, _ = cv2.projectPoints(P[on], rvec, tvec, K, dist)
    uv = uv.reshape(-1, 2)
    ins = pp.camera_off.in_image(uv)
    assert ins.mean() > 0.95
    np.testing.assert_allclose(warp.uv[on][ins], uv[ins], atol=1e-6)
    assert np.all(np.isnan(warp.uv[on][~ins]))
    # the model moved by about 2 pixels between the images
    vv, uu = np.nonzero(on)
    shift = np.hypot(uv[:, 0] - uu, uv[:, 1] - vv)
    assert 1.0 < np.median(shift) < 4.0


@pytest.mark.parametrize("order,max_err,rms_err", [(1, 0.03, 0.005), (3, 0.005, 5e-4)])
def test_warped_matches_direct_render(pair, order, max_err, rms_err):
    pp, warp = pair
    direct = render(pp.camera_on)
    warped = warp(render(pp.camera_off), order=order)
    m = inner_mask(warp, pp.camera_off)
    assert m.mean() > 0.8
    rel = warped[m] / direct[m] - 1
    assert np.abs(rel).max() < max_err
    assert np.sqrt(np.mean(rel**2)) < rms_err
    # without alignment the images differ by the texture contrast
    raw = render(pp.camera_off)[m] / direct[m] - 1
    assert np.sqrt(np.nanmean(raw**2)) > 10 * rms_err


def test_ratio_noise_aligned_vs_one_pixel_shift(pair):
    pp, warp = pair
    P, on = plane_hits(pp.camera_on)
    truth = pressure_factor(P)
    m = inner_mask(warp, pp.camera_off, margin=3) & on
    m[:3], m[-3:], m[:, :3], m[:, -3:] = False, False, False, False

    def noise(ratio):
        return np.std(ratio[m] / truth[m] - 1)

    ideal = noise(pp.wind_on / pp.wind_off_in_on_view)  # perfectly registered
    assert ideal == pytest.approx(np.sqrt(2) * 0.005, rel=0.1)  # two independent 0.5 % noises
    aligned = noise(pp.wind_on / warp(pp.wind_off))
    shifted = noise(pp.wind_on / np.roll(pp.wind_off_in_on_view, 1, axis=1))
    unaligned = noise(pp.wind_on / pp.wind_off)
    assert abs(aligned / ideal - 1) < 0.1
    assert shifted > 3 * ideal
    assert unaligned > shifted


def test_occluded_points_left_out():
    """A blocker above the panel hides part of it from camera A only: those pixels of B get
    nothing (closed-form shadow of the blocker seen from A's centre)."""
    panel = panel_mesh(24)
    z0 = 0.03
    bv = np.array([[-0.02, -0.15, z0], [0.02, -0.15, z0], [0.02, 0.15, z0], [-0.02, 0.15, z0]])
    blocker = trimesh.Trimesh(bv, [[0, 1, 2], [0, 2, 3]], process=False)
    mesh = trimesh.util.concatenate([panel, blocker])
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    K = [[300.0, 0, 79.5], [0, 300.0, 59.5], [0, 0, 1]]
    cam_b = Camera.look_at([0.0, 0.0, 0.5], [0, 0, 0], [0, 1, 0], K=K, width=160, height=120)
    cam_a = Camera.look_at([0.25, 0.0, 0.45], [0, 0, 0], [0, 1, 0], K=K, width=160, height=120)
    warp = ViewWarp(mesh, cam_a, cam_b)
    P, on = plane_hits(cam_b)
    Ca = cam_a.center
    s = (z0 - Ca[2]) / (P[..., 2] - Ca[2])
    Q = Ca + s[..., None] * (P - Ca)
    shadow = on & (np.abs(Q[..., 0]) < 0.02) & (np.abs(Q[..., 1]) < 0.15)
    # pixels of B that see the panel (not the blocker)
    sees_panel = on & (warp.surface_map.face_index < len(panel.faces))
    edge = np.abs(np.abs(Q[..., 0]) - 0.02) < 0.002
    sel = sees_panel & ~edge
    assert (shadow & sel).sum() > 100
    K, dist, rvec, tvec = cam_a.to_opencv()
    uv, _ = cv2.projectPoints(P.reshape(-1, 3), rvec, tvec, K, dist)
    uv = uv.reshape(P.shape[:2] + (2,))
    outside = ~((uv[..., 0] >= -0.5) & (uv[..., 0] <= 159.5) & (uv[..., 1] >= -0.5)
                & (uv[..., 1] <= 119.5))
    # a point within 1e-6 px of A's image border is inside or out by rounding: not judged
    sel &= np.all(np.abs(uv - [-0.5, -0.5]) > 1e-6, axis=-1) \
        & np.all(np.abs(uv - [159.5, 119.5]) > 1e-6, axis=-1)
    np.testing.assert_array_equal(~warp.valid[sel], (shadow | outside)[sel])
    no_occ = ViewWarp(mesh, cam_a, cam_b, occlusion=False)
    assert no_occ.valid[shadow & sel].all()


def test_stack_and_errors(pair):
    pp, warp = pair
    stack = np.stack([pp.wind_off, 2 * pp.wind_off])
    out = warp(stack)
    assert out.shape == (2, pp.camera_on.height, pp.camera_on.width)
    np.testing.assert_allclose(out[1], 2 * out[0], rtol=1e-12)
    one = warp_image(pp.wind_off, pp.mesh, pp.camera_off, pp.camera_on)
    np.testing.assert_array_equal(one, out[0])
    with pytest.raises(InputError, match=r"\(10, 10\).*\(240, 320\)"):
        warp(np.zeros((10, 10)))
    with pytest.raises(InputError, match="target"):
        ViewWarp(pp.mesh, pp.camera_off, "camera")
    with pytest.raises(InputError, match="image: expected real numbers"):
        warp(np.full((240, 320), "a"))
    other = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    with pytest.raises(InputError, match="SurfaceMap of a mesh of 1 faces"):
        ViewWarp(pp.mesh, pp.camera_off, SurfaceMap(other, pp.camera_on))
