"""Mitsuba renders (:mod:`selfillum.rendering`) against independent references.

* pixel convention and camera mapping: the centroid of a small emitting square lands on
  ``Camera.project`` of its centre (the lead's camera model), and its flux equals
  ``E/pi`` times its projected area (shoelace formula);
* per-face emission and reflectance: an emission-only render shows exactly ``E_k/pi`` on
  every pixel that lies inside face ``k`` (faces located analytically from the pixel's
  rays);
* one reflection on a uniform corner: radiance ``(E + rho E F(x -> other plate)) / pi``
  with ``F`` from Lambert's closed-form contour integral for a point and a polygon.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from resection import Camera, InputError
from resection.io.cameras import write_camera
from selfillum.rendering.mitsuba_render import available_variants, choose_variant, render

# ----------------------------------------------------------------------------- helpers


def corner_mesh(n: int = 8) -> trimesh.Trimesh:
    """Floor z=0 (normal +z) and wall x=0 (normal +x), unit squares, ``n x n`` cells of two
    triangles each; face order: floor lower triangles, floor upper, wall lower, wall upper
    (see :func:`corner_face_at`)."""
    g = np.linspace(0.0, 1.0, n + 1)
    a, b = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    tri = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    floor = np.column_stack([a, b, np.zeros_like(a)])
    wall = np.column_stack([np.zeros_like(a), b, a])
    faces = np.vstack([tri, tri[:, ::-1] + len(floor)])
    return trimesh.Trimesh(np.vstack([floor, wall]), faces, process=False)


def corner_face_at(plate: np.ndarray, p: np.ndarray, n: int) -> np.ndarray:
    """Face index of :func:`corner_mesh` at points ``p`` on ``plate`` (0 floor, 1 wall)."""
    a = np.where(plate == 0, p[:, 0], p[:, 2]) * n
    b = p[:, 1] * n
    i = np.clip(np.floor(a), 0, n - 1)
    j = np.clip(np.floor(b), 0, n - 1)
    upper = (b - j) > (a - i)
    return (plate * 2 * n * n + upper * n * n + i * n + j).astype(int)


def corner_hits(camera: Camera, uv: np.ndarray):
    """Plate (0 floor, 1 wall, -1 none) and model point seen along each pixel's ray."""
    o, d = camera.rays(uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        tz = -o[:, 2] / d[:, 2]
        tx = -o[:, 0] / d[:, 0]
    pz = o + tz[:, None] * d
    px = o + tx[:, None] * d
    inside = lambda p, k: np.all((p[:, k] >= 0) & (p[:, k] <= 1), axis=1)  # noqa: E731
    tz = np.where((tz > 0) & inside(pz, [0, 1]), tz, np.inf)
    tx = np.where((tx > 0) & inside(px, [1, 2]), tx, np.inf)
    plate = np.where(np.isinf(tz) & np.isinf(tx), -1, np.where(tz <= tx, 0, 1))
    return plate, np.where((plate == 0)[:, None], pz, px)


def pixel_grid(camera: Camera) -> np.ndarray:
    vv, uu = np.mgrid[0 : camera.height, 0 : camera.width]
    return np.column_stack([uu.ravel(), vv.ravel()]).astype(float)


def footprint_faces(camera: Camera, n: int, reach: float = 0.5):
    """Face at each pixel centre, whether the pixel's square (grown to ``reach`` px from
    the centre) lies on that single face, and whether it misses the model entirely."""
    uv = pixel_grid(camera)
    plate, p = corner_hits(camera, uv)
    face = np.where(plate >= 0, corner_face_at(plate, p, n), -1)
    same = face >= 0
    empty = face < 0
    for du in (-reach, 0.0, reach):
        for dv in (-reach, 0.0, reach):
            pl2, p2 = corner_hits(camera, uv + [du, dv])
            same &= (pl2 >= 0) & (corner_face_at(pl2, p2, n) == face)
            empty &= pl2 < 0
    return face, same, empty


def lambert_form_factor(x: np.ndarray, normal: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Form factor from differential areas at ``x`` (M, 3) with unit ``normal`` (M, 3) to a
    planar polygon (K, 3) entirely on their front side: Lambert's contour formula
    ``F = |sum_k gamma_k n . (R_k x R_k+1) / |R_k x R_k+1|| / (2 pi)``."""
    R = polygon[None] - x[:, None]
    R1 = np.roll(R, -1, axis=1)
    c = np.cross(R, R1)
    cn = np.linalg.norm(c, axis=2)
    cosg = np.einsum("mkj,mkj->mk", R, R1) / (
        np.linalg.norm(R, axis=2) * np.linalg.norm(R1, axis=2)
    )
    gamma = np.arccos(np.clip(cosg, -1.0, 1.0))
    proj = np.einsum("mkj,mj->mk", c, normal) / np.where(cn > 0, cn, 1.0)
    return np.abs((gamma * proj).sum(axis=1)) / (2.0 * np.pi)


def corner_camera(dist=None) -> Camera:
    K = [[80.0, 0.0, 47.2], [0.0, 80.0, 35.9], [0.0, 0.0, 1.0]]
    return Camera.look_at([1.4, 0.5, 1.2], [0.3, 0.5, 0.3], [0.0, 1.0, 0.0], K=K,
                          width=96, height=72, dist=dist)


def square(center, half, normal_axis_toward=+1):
    """Two triangles of a square in the plane z = center[2], normal +z."""
    c = np.asarray(center, float)
    V = c + np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]])
    F = [[0, 1, 2], [0, 2, 3]] if normal_axis_toward > 0 else [[0, 2, 1], [0, 3, 2]]
    return trimesh.Trimesh(V, F, process=False)


VARIANTS = available_variants()


# ----------------------------------------------------------------------------- variants
def test_variant_choice_is_reported():
    assert "scalar_rgb" in VARIANTS
    assert choose_variant() == VARIANTS[0]
    assert choose_variant("scalar") == "scalar_rgb"
    cam = Camera.look_at([0, 0, 1.0], [0, 0, 0], [0, 1, 0],
                         K=[[20, 0, 7.5], [0, 20, 7.5], [0, 0, 1]], width=16, height=16)
    res = render(square([0, 0, 0], 0.1), 1.0, 0.0, cam, bounces=1, spp=4)
    assert res.variant == VARIANTS[0]
    assert res.spp == 4 and res.bounces == 1
    assert render(square([0, 0, 0], 0.1), 1.0, 0.0, cam, bounces=1, spp=5).spp == 6
    with pytest.raises(InputError, match="unknown Mitsuba variant"):
        choose_variant("opengl")
    for short, name in (("cuda", "cuda_ad_rgb"), ("llvm", "llvm_ad_rgb")):
        if name in VARIANTS:
            assert choose_variant(short) == name
        else:
            with pytest.raises(InputError, match="not available on this machine"):
                choose_variant(short)


def test_llvm_variant_available_when_libllvm_installed():
    from selfillum.mitsuba_variants import _find_libllvm

    if _find_libllvm() is not None:  # libLLVM >= 16 on this machine (tools/setup.sh)
        assert "llvm_ad_rgb" in VARIANTS
    assert VARIANTS[-1] == "scalar_rgb"  # fastest first, scalar the fallback


def test_libllvm_lookup_picks_newest_supported(monkeypatch, tmp_path):
    import subprocess

    import selfillum.mitsuba_variants as render_mod

    libs = {name: tmp_path / name for name in
            ("libLLVM-14.so.1", "libLLVM-15.so", "libLLVM.so.19.1", "libLLVM-17.so.1")}
    for path in libs.values():
        path.write_bytes(b"")
    listing = "\n".join(f"\t{n} (libc6,x86-64) => {p}" for n, p in libs.items())
    listing += "\n\tlibLLVM-21.so.1 (libc6,x86-64) => /nonexistent/libLLVM-21.so.1"

    def fake_run(*args, **kwargs):
        return subprocess.CompletedProcess(args, 0, stdout=listing, stderr="")

    monkeypatch.setattr(render_mod.subprocess, "run", fake_run)
    assert render_mod._find_libllvm() == str(libs["libLLVM.so.19.1"])
    listing = "\n".join(f"\t{n} (libc6,x86-64) => {p}" for n, p in libs.items()
                        if "19" not in n and "17" not in n)
    assert render_mod._find_libllvm() is None  # only LLVM < 16: Mitsuba cannot use it


# ----------------------------------------------------------------------------- pixels
CAMERAS = {
    # name: (K, dist, eye, up)
    "pinhole": ([[60, 0, 31.5], [0, 60, 23.5], [0, 0, 1]], None, [0, 0, 1.0], [0, 1, 0]),
    "offset_rolled": ([[55, 0, 27.3], [0, 55, 26.8], [0, 0, 1]], None, [0.1, -0.05, 1.2],
                      [0.6, 0.8, 0]),
    "fx_ne_fy": ([[60, 0, 30.3], [0, 66, 20.7], [0, 0, 1]], None, [0, 0, 1.0], [0, 1, 0]),
    "distorted": ([[60, 0, 30.3], [0, 60, 20.7], [0, 0, 1]], [-0.2, 0.05, 0.001, -0.002, 0],
                  [0, 0, 1.0], [0, 1, 0]),
}


def projected_square(camera: Camera, center, half: float, m: int = 120):
    """Image area (px^2) and area centroid of the square seen by ``camera``: the square is
    cut into ``m x m`` cells whose projected corners give each cell's image area."""
    g = np.linspace(-half, half, m + 1)
    a, b = np.meshgrid(g, g, indexing="ij")
    pts = np.column_stack([a.ravel(), b.ravel(), np.zeros(a.size)]) + np.asarray(center)
    q = camera.project(pts).reshape(m + 1, m + 1, 2)
    c = [q[:-1, :-1], q[1:, :-1], q[1:, 1:], q[:-1, 1:]]
    area = 0.5 * np.abs(sum(c[k][..., 0] * c[(k + 1) % 4][..., 1]
                            - c[(k + 1) % 4][..., 0] * c[k][..., 1] for k in range(4)))
    mid = sum(c) / 4.0
    total = area.sum()
    return total, (mid * area[..., None]).sum(axis=(0, 1)) / total


@pytest.mark.parametrize("name", sorted(CAMERAS))
@pytest.mark.parametrize("center", [[0.05, 0.02, 0.0], [-0.22, 0.1, 0.1]])
def test_pixel_convention_centroid(name, center):
    """Centroid within 0.05 px of where the camera model puts the square, flux within 1 %
    of E/pi times its image area: checks the half-pixel shift, principal point, focal
    length, pose and the distortion warp."""
    K, dist, eye, up = CAMERAS[name]
    cam = Camera.look_at(eye, [0, 0, 0], up, K=K, width=64, height=48, dist=dist)
    half = 0.05
    res = render(square(center, half), np.pi, 0.0, cam, bounces=1, spp=256, variant="scalar")
    img = res.image.astype(np.float64)
    vv, uu = np.mgrid[0:48, 0:64]
    s = img.sum()
    centroid = np.array([(img * uu).sum() / s, (img * vv).sum() / s])
    area, expected = projected_square(cam, center, half)
    assert np.all(np.abs(centroid - expected) < 0.05), (centroid, expected)
    assert np.hypot(*(expected - cam.project(np.asarray(center, float)[None])[0])) < 0.5
    assert s == pytest.approx(area, rel=0.01)  # radiance E/pi = 1
    assert img.max() == pytest.approx(1.0, abs=1e-5)


def test_back_side_is_black():
    cam = Camera.look_at([0, 0, 1.0], [0, 0, 0], [0, 1, 0],
                         K=[[20, 0, 7.5], [0, 20, 7.5], [0, 0, 1]], width=16, height=16)
    front = render(square([0, 0, 0], 0.1), 1.0, 0.0, cam, bounces=1, spp=4, variant="scalar")
    back = render(square([0, 0, 0], 0.1, -1), 1.0, 0.0, cam, bounces=1, spp=4,
                  variant="scalar")
    assert front.image.max() == pytest.approx(1 / np.pi, rel=1e-5)
    assert back.image.max() == 0.0


def test_two_sided_faces():
    """Both sides emit; seen from outside, a corner's plates receive nothing from each
    other (their painted insides face away), so every pixel inside a face shows exactly
    E/pi even with all bounces: the back copies neither leak nor shadow wrongly."""
    n = 8
    mesh = corner_mesh(n)
    E = np.random.default_rng(4).uniform(0.5, 3.0, len(mesh.faces))
    K = [[80.0, 0.0, 47.5], [0.0, 80.0, 35.5], [0.0, 0.0, 1.0]]
    cam = Camera.look_at([-0.9, 0.5, -0.8], [0.35, 0.5, 0.35], [0, 1, 0], K=K, width=96,
                         height=72)
    one = render(mesh, E, 0.6, cam, bounces=-1, spp=16, variant="scalar")
    two = render(mesh, E, 0.6, cam, bounces=-1, spp=16, variant="scalar", two_sided=True)
    face, inside, _ = footprint_faces(cam, n)
    assert inside.sum() > 1000
    assert np.all(one.image.ravel()[inside] == 0.0)
    np.testing.assert_allclose(two.image.ravel()[inside], E[face[inside]] / np.pi, rtol=2e-6)
    # and inside the corner two-sided faces look the same as one-sided ones
    cin = corner_camera()
    a = render(mesh, E, 0.0, cin, bounces=1, spp=4, variant="scalar").image
    b = render(mesh, E, 0.0, cin, bounces=1, spp=4, variant="scalar", two_sided=True).image
    face, inside, _ = footprint_faces(cin, n)
    np.testing.assert_allclose(b.ravel()[inside], a.ravel()[inside], rtol=2e-6)


# ----------------------------------------------------------------------------- per face
@pytest.mark.parametrize("variant", VARIANTS)
def test_emission_only_is_exact_per_face(variant):
    n = 8
    mesh = corner_mesh(n)
    rng = np.random.default_rng(1)
    E = rng.uniform(0.5, 3.0, len(mesh.faces))
    cam = corner_camera()
    res = render(mesh, E, 0.4, cam, bounces=1, spp=16, variant=variant)
    assert res.variant == variant
    face, inside, empty = footprint_faces(cam, n)
    img = res.image.ravel().astype(np.float64)
    assert inside.sum() > 2000
    assert len(np.unique(face[inside])) == len(mesh.faces)  # every face checked
    np.testing.assert_allclose(img[inside], E[face[inside]] / np.pi, rtol=2e-6)
    assert empty.sum() > 1000 and np.all(img[empty] == 0.0)


def test_emission_only_with_distortion_warp():
    n = 8
    mesh = corner_mesh(n)
    E = np.random.default_rng(2).uniform(0.5, 3.0, len(mesh.faces))
    cam = corner_camera(dist=[-0.15, 0.03, 0.002, -0.001, 0.0])
    res = render(mesh, E, 0.4, cam, bounces=1, spp=16, variant="scalar")
    # pixels whose square, grown by 1.5 canvas pixels of bilinear reach, stays on one face
    face, inside, _ = footprint_faces(cam, n, reach=1.0)
    img = res.image.ravel().astype(np.float64)
    assert inside.sum() > 500 and len(np.unique(face[inside])) > 150
    np.testing.assert_allclose(img[inside], E[face[inside]] / np.pi, rtol=1e-5)


# ----------------------------------------------------------------------------- transport
def test_one_reflection_corner_matches_view_factor_model():
    """bounces=2 (emission + one reflection), E = 1 everywhere: a point x of one plate
    shows (1 + rho F(x -> other plate)) / pi."""
    n, rho = 8, 0.5
    mesh = corner_mesh(n)
    cam = corner_camera()
    res = render(mesh, 1.0, rho, cam, bounces=2, spp=64, seed=3, variant=choose_variant())
    uv = pixel_grid(cam)
    plate, p = corner_hits(cam, uv)
    ok = plate >= 0
    for du in (-0.5, 0.5):
        for dv in (-0.5, 0.5):
            ok &= corner_hits(cam, uv + [du, dv])[0] == plate
    floor_poly = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    wall_poly = np.array([[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 0, 1]], float)
    on_floor = (plate == 0)[:, None]
    normal = np.where(on_floor, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    F = np.where(plate == 0, lambert_form_factor(p, normal, wall_poly),
                 lambert_form_factor(p, normal, floor_poly))
    expected = (1.0 + rho * F) / np.pi
    img = res.image.ravel().astype(np.float64)
    assert ok.sum() > 800 and F[ok].max() > 0.4 and F[ok].min() < 0.1
    # means over bands of equal F (Monte-Carlo noise averages out): within 0.5 %
    edges = np.quantile(F[ok], np.linspace(0, 1, 6))
    band = np.clip(np.digitize(F[ok], edges) - 1, 0, 4)
    for k in range(5):
        sel = band == k
        assert img[ok][sel].mean() == pytest.approx(expected[ok][sel].mean(), rel=0.005)
    # the self-illumination part alone, over all pixels: within 2 %
    si_render = img[ok].mean() - 1 / np.pi
    si_model = expected[ok].mean() - 1 / np.pi
    assert si_render == pytest.approx(si_model, rel=0.02)


def test_bounces_add_reflection_orders():
    mesh = corner_mesh(4)
    cam = corner_camera()
    imgs = [render(mesh, 1.0, 0.9, cam, bounces=b, spp=36, variant="scalar").image
            for b in (1, 2, 3, -1)]
    seen = imgs[0] > 0
    means = [im[seen].mean() for im in imgs]
    assert means[1] > means[0] * 1.1  # one reflection adds rho F E
    assert means[2] > means[1] * 1.02  # the second reflection adds rho F rho F E
    assert means[3] > means[2] * 1.005


def test_same_seed_same_image():
    mesh = corner_mesh(2)
    cam = corner_camera()
    a = render(mesh, 1.0, 0.5, cam, bounces=-1, spp=4, seed=7, variant="scalar").image
    b = render(mesh, 1.0, 0.5, cam, bounces=-1, spp=4, seed=7, variant="scalar").image
    c = render(mesh, 1.0, 0.5, cam, bounces=-1, spp=4, seed=8, variant="scalar").image
    assert a.dtype == np.float32 and a.shape == (72, 96)
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"reflectance": 1.0}, "reflectance must be in"),
        ({"reflectance": -0.1}, "reflectance must be in"),
        ({"emission": -1.0}, "emission must be >= 0"),
        ({"emission": np.ones(3)}, "one value per face"),
        ({"emission": np.nan}, "NaN or infinite"),
        ({"bounces": 0}, "bounces must be"),
        ({"spp": 0}, "spp must be"),
        ({"variant": "vulkan"}, "unknown Mitsuba variant"),
        ({"camera": "cam.json"}, "must be a resection.Camera"),
        ({"mesh": trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]],
                                  process=False)}, "degenerate"),
    ],
)
def test_bad_input(kwargs, match):
    args = {"mesh": corner_mesh(2), "emission": 1.0, "reflectance": 0.5,
            "camera": corner_camera()}
    args.update(kwargs)
    extra = {k: args.pop(k) for k in ("bounces", "spp", "variant") if k in args}
    with pytest.raises(InputError, match=match):
        render(args["mesh"], args["emission"], args["reflectance"], args["camera"], **extra)


# ------------------------------------------------- the Lambertian model against Mitsuba
@pytest.fixture(scope="module")
def corner_case():
    """The shared corner scene (smooth emission, rho 0.6), its view factors, forward
    radiosity, a surface map and the all-bounce and emission-only Mitsuba renders."""
    from scipy.ndimage import maximum_filter, minimum_filter

    from resection.surface.surface_map import SurfaceMap
    from scenes.corner import corner
    from selfillum.solve.radiosity import forward
    from selfillum.transport.viewfactors import view_factors

    sc = corner(resolution=10, reflectance=0.6, pattern="smooth")
    F = view_factors(sc.mesh, rays_per_face=2048, seed=1)
    B = forward(F, sc.emission, sc.reflectance)
    cam = Camera.look_at([1.4, 0.5, 1.2], [0.3, 0.5, 0.3], [0, 1, 0],
                         K=[[260, 0, 159.5], [0, 260, 119.5], [0, 0, 1]], width=320, height=240)
    smap = SurfaceMap(sc.mesh, cam)
    full = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=256, seed=1)
    emitted = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=1, spp=16, seed=2)
    fi = smap.face_index
    plate = np.where(fi >= 0, sc.plate[np.maximum(fi, 0)], -1)
    # model pixels at least 2 px from the silhouette and from the corner line
    away = (plate >= 0) & (minimum_filter(plate, 5) == maximum_filter(plate, 5))
    return sc, F, B, smap, full.image, emitted.image, away


def test_forward_model_matches_all_bounce_render(corner_case):
    """(I - rho F) B = E solved with Embree view factors, backprojected, against
    Mitsuba's all-bounce path tracing: median within 1 % over model pixels."""
    sc, F, B, smap, full, emitted, away = corner_case
    assert away.sum() > 40000
    predicted = smap.to_image(B / np.pi, interpolation="nearest")
    rel = full[away] / predicted[away] - 1.0
    assert abs(np.median(rel)) < 0.01
    # per face (pixel means): median within 1 %, 95 % of the faces within 2 %
    meas = smap.to_surface(np.where(away, full, np.nan))
    ok = meas.counts > 20
    frel = meas.values[ok] / (B[ok] / np.pi) - 1.0
    assert ok.sum() > 300
    assert abs(np.median(frel)) < 0.01 and np.percentile(np.abs(frel), 95) < 0.02
    # and the self-illumination is large enough for this to mean something
    si = (B - sc.emission) / B
    assert si.max() > 0.2


def test_correction_of_all_bounce_render_gives_emission_only_render(corner_case):
    """correct() applied to the faces' radiosity measured on the all-bounce render,
    backprojected, against the emission-only render: median within 1 %, 95th
    percentile within 3 % (uncorrected: about 10 % and 27 %)."""
    from selfillum.solve.radiosity import correct

    sc, F, B, smap, full, emitted, away = corner_case
    meas = smap.to_surface(full * np.pi)
    seen = ~meas.unseen
    E = correct(F, np.where(seen, meas.values, np.nan), sc.reflectance, seen, mesh=sc.mesh)
    corrected = smap.to_image(E / np.pi, interpolation="nearest")
    rel = corrected[away] / emitted[away] - 1.0
    assert abs(np.median(rel)) < 0.01
    assert np.percentile(np.abs(rel), 95) < 0.03
    before = full[away] / emitted[away] - 1.0
    assert np.median(before) > 0.05  # there was something to correct


def test_cli_correct_on_all_bounce_render_gives_emission_only_render(corner_case, tmp_path,
                                                                     capsys):
    """``selfillum correct`` (image level: per-pixel correction interpolated over the
    surface) on the all-bounce render, against the emission-only render: median within
    1 %, 95th percentile within 3 % over model pixels away from edges."""
    from selfillum.cli.main import main

    sc, F, B, smap, full, emitted, away = corner_case
    sc.mesh.export(tmp_path / "corner.ply")
    write_camera(tmp_path / "cam.json", smap.camera)
    np.save(tmp_path / "full.npy", full)
    rc = main(["correct", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--image", str(tmp_path / "full.npy"),
               "--reflectance", str(sc.reflectance), "--rays", "2048", "--quiet",
               "--out", str(tmp_path / "corrected.npy")])
    assert rc == 0, capsys.readouterr().err
    corrected = np.load(tmp_path / "corrected.npy")
    assert corrected.dtype == full.dtype and corrected.shape == full.shape
    rel = corrected[away] / emitted[away] - 1.0
    assert abs(np.median(rel)) < 0.01
    assert np.percentile(np.abs(rel), 95) < 0.03
    before = full[away] / emitted[away] - 1.0
    assert np.median(before) > 0.05 and np.percentile(np.abs(before), 95) > 0.2
    np.testing.assert_array_equal(corrected[~smap.mask], full[~smap.mask])


@pytest.mark.slow
def test_forward_model_matches_render_closely():
    """Finer corner, more rays and samples: per-face agreement of the Lambertian model and
    the all-bounce render within 0.3 % median and 1 % at the 95th percentile."""
    from resection.surface.surface_map import SurfaceMap
    from scenes.corner import corner
    from selfillum.images.multiview import merge_views
    from selfillum.solve.radiosity import forward
    from selfillum.transport.viewfactors import view_factors

    sc = corner(resolution=16, reflectance=0.6, pattern="smooth")
    F = view_factors(sc.mesh, rays_per_face=8192, seed=3)
    B = forward(F, sc.emission, sc.reflectance)
    cam = Camera.look_at([1.4, 0.5, 1.2], [0.3, 0.5, 0.3], [0, 1, 0],
                         K=[[520, 0, 319.5], [0, 520, 239.5], [0, 0, 1]], width=640, height=480)
    img = render(sc.mesh, sc.emission, sc.reflectance, cam, bounces=-1, spp=1024, seed=5).image
    mv = merge_views([SurfaceMap(sc.mesh, cam)], [img], min_pixels=50)
    rel = mv.values[mv.seen] * np.pi / B[mv.seen] - 1.0
    assert mv.seen.sum() > 0.9 * len(B)
    assert abs(np.median(rel)) < 0.003 and np.percentile(np.abs(rel), 95) < 0.01


# ----------------------------------------------------------------------------- CLI
def test_cli_render_writes_image_and_preview(tmp_path, capsys):
    from resection.io.images import read_image
    from selfillum.cli.main import main

    mesh = corner_mesh(4)
    mesh.export(tmp_path / "corner.ply")
    cam = corner_camera()
    write_camera(tmp_path / "cam.json", cam)
    E = np.linspace(1.0, 2.0, len(mesh.faces))
    np.save(tmp_path / "E.npy", E)
    out = tmp_path / "render.tif"
    rc = main(["render", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--emission", str(tmp_path / "E.npy"),
               "--reflectance", "0.3", "--bounces", "1", "--spp", "4", "--variant", "scalar",
               "--out", str(out)])
    assert rc == 0
    assert "variant   scalar_rgb" in capsys.readouterr().out
    img = read_image(out)
    assert img.dtype == np.float32 and img.shape == (72, 96)
    face, inside, _ = footprint_faces(cam, 4)
    np.testing.assert_allclose(img.ravel()[inside], E[face[inside]] / np.pi, rtol=2e-6)
    png = read_image(tmp_path / "render.preview.png")  # named from --out
    assert png.shape == (72, 96) and png.max() == 255 and png.min() == 0

    # glossy paint: brighter than Lambertian at the same diffuse reflectance
    rc = main(["render", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--emission", "1", "--reflectance", "0.3",
               "--specular-weight", "0.5", "--roughness", "0.4", "--bounces", "2",
               "--spp", "16", "--variant", "scalar", "--out", str(tmp_path / "g.npy")])
    assert rc == 0 and "GGX alpha 0.4" in capsys.readouterr().out
    rc = main(["render", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--emission", "1", "--reflectance", "0.3",
               "--bounces", "2", "--spp", "16", "--variant", "scalar",
               "--out", str(tmp_path / "d.npy")])
    assert rc == 0
    capsys.readouterr()
    glossy, diffuse = np.load(tmp_path / "g.npy"), np.load(tmp_path / "d.npy")
    seen = diffuse > 0
    assert glossy[seen].mean() > diffuse[seen].mean() * 1.01

    rc = main(["render", "--mesh", str(tmp_path / "corner.ply"), "--camera",
               str(tmp_path / "cam.json"), "--emission", "1", "--reflectance", "1.5",
               "--out", str(tmp_path / "bad.npy")])
    assert rc == 2
    assert "reflectance must be in [0, 1)" in capsys.readouterr().err
    assert not (tmp_path / "bad.npy").exists()
