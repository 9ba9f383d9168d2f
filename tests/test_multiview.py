"""Several cameras merged before the self-illumination inverse (selfillum.images.multiview),
checked on Mitsuba renders of the corner against the true emission."""

from __future__ import annotations

import numpy as np
import pytest

from resection import Camera, InputError
from selfillum.images.multiview import merge_views
from selfillum.rendering.mitsuba_render import render


@pytest.fixture(scope="module")
def two_cameras():
    from resection.surface.surface_map import SurfaceMap
    from scenes.corner import corner
    from selfillum.transport.viewfactors import view_factors

    sc = corner(resolution=10, reflectance=0.6, pattern="smooth")
    F = view_factors(sc.mesh, rays_per_face=2048, seed=1)
    K = [[200, 0, 79.5], [0, 200, 59.5], [0, 0, 1]]
    # A frames the floor, B the wall: each sees one plate whole and the other's near half
    cams = [Camera.look_at([1.3, 0.5, 1.6], [0.45, 0.5, 0.0], [0, 1, 0], K=K, width=160,
                           height=120),
            Camera.look_at([1.6, 0.5, 1.3], [0.0, 0.5, 0.45], [0, 1, 0], K=K, width=160,
                           height=120)]
    maps = [SurfaceMap(sc.mesh, c) for c in cams]
    images = [render(sc.mesh, sc.emission, sc.reflectance, c, bounces=-1, spp=256,
                     seed=s).image for s, c in enumerate(cams)]
    return sc, F, maps, images


def _corrected(sc, F, mv):
    from selfillum.solve.radiosity import correct

    B = np.where(mv.seen, mv.values * np.pi, np.nan)
    return correct(F, B, sc.reflectance, mv.seen, mesh=sc.mesh)


@pytest.mark.parametrize("method", ["weighted", "best"])
def test_merged_cameras_recover_emission(two_cameras, method):
    sc, F, maps, images = two_cameras
    n = len(sc.mesh.faces)
    singles = [merge_views([m], [im]) for m, im in zip(maps, images, strict=True)]
    assert all(s.seen.sum() < 0.8 * n for s in singles)
    mv = merge_views(maps, images, method=method)
    assert mv.seen.all()
    assert mv.n_cameras.max() == 2 and (mv.n_cameras == 2).sum() > 0.3 * n
    rel = _corrected(sc, F, mv) / sc.emission - 1.0
    assert abs(np.median(rel)) < 0.005
    assert np.percentile(np.abs(rel), 95) < 0.02
    assert np.abs(rel).max() < 0.05
    # one camera alone must guess the faces it does not see: far worse there
    for s in singles:
        rel1 = _corrected(sc, F, s) / sc.emission - 1.0
        assert np.percentile(np.abs(rel1[~s.seen]), 95) > 0.2
        # and the wrong guess spoils the seen faces too (their SI comes from hidden ones)
        assert np.percentile(np.abs(rel1[s.seen]), 95) > np.percentile(np.abs(rel), 95)


def test_cameras_agree_on_common_faces(two_cameras):
    """Lambertian paint: both cameras see the same radiance on the faces they share."""
    sc, F, maps, images = two_cameras
    a, b = (merge_views([m], [im]) for m, im in zip(maps, images, strict=True))
    both = a.seen & b.seen
    assert both.sum() > 100
    rel = a.values[both] / b.values[both] - 1.0
    assert abs(np.median(rel)) < 0.005 and np.percentile(np.abs(rel), 95) < 0.03
    # the weighted mean lies between the two, camera 1 brought to camera 0's gain (which
    # the overlap finds equal to 1 within the render noise: same radiance, same film)
    mv = merge_views(maps, images)
    assert mv.gains[0] == 1.0 and abs(mv.gains[1] - 1.0) < 0.005
    bb = b.values[both] / mv.gains[1]
    lo = np.minimum(a.values[both], bb)
    hi = np.maximum(a.values[both], bb)
    assert np.all((mv.values[both] >= lo - 1e-12) & (mv.values[both] <= hi + 1e-12))
    assert np.all(mv.best[both] >= 0) and np.all(mv.best[~mv.seen] == -1)


def test_silhouette_pixels_are_dropped(two_cameras):
    """Pixels straddling the outline mix in the background: keeping them biases the
    faces along the plates' free edges low."""
    from selfillum.solve.radiosity import forward

    sc, F, maps, images = two_cameras
    B = forward(F, sc.emission, sc.reflectance) / np.pi
    # no feathering: the margin alone (feathering would mostly hide the mixed pixels too)
    keep = merge_views(maps, images, silhouette_margin=0, feather_px=0)
    drop = merge_views(maps, images, feather_px=0)
    err_keep = np.abs(keep.values / B - 1.0)
    err_drop = np.abs(drop.values / B - 1.0)
    assert np.percentile(err_drop, 95) < 0.02
    assert err_keep.max() > 2 * err_drop.max()


def test_bad_input(two_cameras):
    sc, F, maps, images = two_cameras
    with pytest.raises(InputError, match="2 surface maps but 1 images"):
        merge_views(maps, images[:1])
    with pytest.raises(InputError, match="method"):
        merge_views(maps, images, method="median")
    with pytest.raises(InputError, match="shape"):
        merge_views(maps, [images[0], images[1][:-1]])
    with pytest.raises(InputError, match="no camera"):
        merge_views([], [])
    with pytest.raises(InputError, match="silhouette_margin"):
        merge_views(maps, images, silhouette_margin=-1)
    from resection.surface.surface_map import SurfaceMap
    from scenes.corner import corner

    other = SurfaceMap(corner(resolution=3).mesh, maps[0].camera)
    with pytest.raises(InputError, match="another mesh"):
        merge_views([maps[0], other], [images[0], images[0]])
