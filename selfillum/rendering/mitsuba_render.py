"""Synthetic images of a painted model rendered with Mitsuba 3 (the independent reference).

A triangle mesh whose faces carry their own emitted exitance ``E`` and diffuse reflectance
``rho`` is rendered by Mitsuba's ``path`` integrator through a :class:`resection.Camera`.
``bounces=1`` gives the emission only (no self-illumination), ``bounces=-1`` all the
interreflections. The image is radiance: a Lambertian face of radiosity ``B`` (all the
exitance leaving it) shows ``B / pi``.

How the scene is built (see docs/design.md, "the Mitsuba trap"):

* every face gets its own three vertices and its own texel of two ``bitmap`` textures
  (``raw``, ``nearest`` filtering); all three texture coordinates of a face sit on its
  texel's centre, so the ``area`` emitter radiance ``E / pi`` and the ``diffuse``
  reflectance are exactly per-face whichever way Mitsuba samples the face (a
  ``mesh_attribute`` ``face_color`` emitter is looked up wrongly when the emitter is
  sampled directly);
* faces are one-sided as in :mod:`selfillum.mesh`: they emit and reflect on the side their
  normal points to (right-hand rule on the vertex order), their back is black, unless
  ``two_sided`` (a reversed copy of each face, set back 1e-5 of the mesh size behind it);
* the ``perspective`` sensor reproduces the camera's pinhole exactly: horizontal field of
  view from ``fx`` and the width, principal point through ``principal_point_offset_x/y``
  (fractions of the film width and height), pose from ``R, t`` (OpenCV's x right, y down,
  z forward is Mitsuba's camera frame turned by 180 degrees about z). Mitsuba's film puts
  pixel centres at ``+0.5``; ours are at integers: ``u = x_film - 0.5``;
* a box reconstruction filter, so a pixel is the mean radiance over its square, and the
  stratified ``multijitter`` sampler (pixel coverage converges much faster than with
  independent samples);
* lens distortion, unequal ``fx, fy`` or skew are applied after rendering as a warp: an
  ideal pinhole image with square pixels is rendered on a canvas covering the undistorted
  field (``oversample`` times finer), and every output pixel is the mean of
  ``oversample**2`` bilinear samples of it at the undistorted positions of points spread
  over the pixel.

The Mitsuba variant is chosen from what the machine has (:func:`choose_variant`):
``cuda_ad_rgb`` with a working GPU, ``llvm_ad_rgb`` when a libLLVM loads, else
``scalar_rgb``; the one used is reported in :class:`RenderResult`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.camera.model import Camera, undistort_normalized
from resection.errors import InputError
from selfillum.mesh import check_mesh
from selfillum.mitsuba_variants import available_variants, choose_variant, import_mitsuba

__all__ = ["RenderResult", "render", "choose_variant", "available_variants", "mitsuba_scene"]

_MAX_LANES = 1 << 24  # samples traced at once by the vectorised variants (memory bound)
_MAX_CANVAS = 16  # a distortion canvas may have at most this many times the output pixels


@dataclass(frozen=True)
class RenderResult:
    """A rendered image and how it was made.

    Attributes
    ----------
    image : (H, W) float32 ndarray
        Radiance, ``img[v, u]``, pixel centres at integer ``(u, v)``; a Lambertian face of
        radiosity ``B`` shows ``B / pi``. Background and pixels the lens model cannot map
        (beyond the monotonic range of the distortion) are 0.
    variant : str
        Mitsuba variant used (``cuda_ad_rgb``, ``llvm_ad_rgb`` or ``scalar_rgb``).
    spp : int
        Samples per output pixel actually used (``spp`` rounded up to a count Mitsuba's
        ``multijitter`` sampler stratifies exactly).
    bounces : int
        Path length limit given to the ``path`` integrator (``max_depth``; -1: no limit).
    seed : int
        Seed of the first pass (pass ``i`` uses ``seed + i``).
    """

    image: np.ndarray
    variant: str
    spp: int
    bounces: int
    seed: int


# --------------------------------------------------------------------------- inputs
def _per_face(value, n: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    arr = arr.ravel() if arr.ndim == 2 and 1 in arr.shape else arr
    if arr.shape != (n,):
        raise InputError(f"render: {name} must be a number or have one value per face ({n}), "
                         f"got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr))
        raise InputError(f"render: {name} is NaN or infinite on {bad.size} face(s), "
                         f"first face {bad[0]}")
    return arr


def _check_inputs(mesh, emission, reflectance):
    check_mesh(mesh)
    n = len(mesh.faces)
    e = _per_face(emission, n, "emission")
    if e.min() < 0:
        raise InputError(f"render: emission must be >= 0, got {e.min()} "
                         f"on face {int(np.argmin(e))}")
    r = _per_face(reflectance, n, "reflectance")
    if r.min() < 0 or r.max() >= 1:
        i = int(np.argmin(r)) if r.min() < 0 else int(np.argmax(r))
        raise InputError(f"render: reflectance must be in [0, 1), got {r[i]} on face {i}")
    return e, r


def _check_camera(camera) -> Camera:
    if not isinstance(camera, Camera):
        raise InputError(f"render: camera must be a resection.Camera, got {type(camera).__name__}")
    return camera


# --------------------------------------------------------------------------- the scene
def _texel_layout(n: int) -> tuple[int, int, np.ndarray]:
    """Texture of ``tw x th`` texels, face ``k`` on texel ``(k % tw, k // tw)``; returns
    ``tw, th`` and the ``(n, 2)`` texel-centre UVs."""
    tw = max(1, math.ceil(math.sqrt(n)))
    th = max(1, math.ceil(n / tw))
    k = np.arange(n)
    uv = np.column_stack([(k % tw + 0.5) / tw, (k // tw + 0.5) / th])
    return tw, th, uv


def _bitmap(mi, values: np.ndarray, tw: int, th: int) -> dict:
    tex = np.zeros(tw * th, dtype=np.float32)
    tex[: values.size] = values
    rgb = np.repeat(tex.reshape(th, tw, 1), 3, axis=2)
    return {
        "type": "bitmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(rgb)),
        "raw": True,
        "filter_type": "nearest",
        "wrap_mode": "clamp",
    }


def _mitsuba_mesh(mi, mesh: trimesh.Trimesh, emission: np.ndarray, reflectance: np.ndarray,
                  paint=None, two_sided: bool = False):
    """``mi.Mesh`` with unshared vertices, one texel per face for emitter and BSDF.

    ``two_sided``: every face also gets a reversed copy (same texel) set back behind it by
    ``1e-5`` of the mesh size, so that its back emits and reflects like its front (Mitsuba's
    area emitters are one-sided)."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    tw, th, uv = _texel_layout(len(faces))
    tri = np.asarray(mesh.vertices, dtype=np.float64)[faces]
    if two_sided:
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        setback = 1e-5 * float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
        back = tri[:, ::-1] - setback * normal[:, None, :]
        tri = np.concatenate([tri, back])
        uv = np.concatenate([uv, uv])
    n = len(tri)
    positions = tri.reshape(-1, 3)
    props = mi.Properties()
    texture = _bitmap(mi, reflectance, tw, th)
    bsdf = {"type": "diffuse", "reflectance": texture} if paint is None else \
        paint.mitsuba_bsdf(texture)
    props["bsdf"] = mi.load_dict(bsdf)
    if np.any(emission > 0):
        props["emitter"] = mi.load_dict(
            {"type": "area", "radiance": _bitmap(mi, emission / math.pi, tw, th)}
        )
    m = mi.Mesh("model", 3 * n, n, props=props, has_vertex_texcoords=True)
    params = mi.traverse(m)
    params["vertex_positions"] = type(params["vertex_positions"])(
        positions.astype(np.float32).ravel()
    )
    params["faces"] = type(params["faces"])(np.arange(3 * n, dtype=np.uint32))
    params["vertex_texcoords"] = type(params["vertex_texcoords"])(
        np.repeat(uv, 3, axis=0).astype(np.float32).ravel()
    )
    params.update()
    return m


def _sensor(mi, camera: Camera, mesh: trimesh.Trimesh, spp: int) -> dict:
    """``perspective`` sensor for a pinhole camera with square pixels and no skew."""
    K = camera.K
    W, H = camera.width, camera.height
    fx, cx, cy = float(K[0, 0]), float(K[0, 2]), float(K[1, 2])
    to_world = np.eye(4)
    # Mitsuba's camera frame is OpenCV's turned by 180 degrees about z (x left, y up).
    to_world[:3, :3] = camera.R.T @ np.diag([-1.0, -1.0, 1.0])
    to_world[:3, 3] = camera.center
    depth = (np.asarray(mesh.vertices, dtype=np.float64) @ camera.R.T + camera.t)[:, 2]
    far = max(float(depth.max()), 0.0) * 2.0 + 1e-9
    near = max(far * 1e-6, 1e-12)
    return {
        "type": "perspective",
        "fov": math.degrees(2.0 * math.atan(W / (2.0 * fx))),
        "fov_axis": "x",
        # offsets in fractions of the film size; positive moves the image content left/up
        "principal_point_offset_x": ((W - 1) / 2.0 - cx) / W,
        "principal_point_offset_y": ((H - 1) / 2.0 - cy) / H,
        "near_clip": near,
        "far_clip": far,
        "to_world": mi.ScalarTransform4f(to_world.tolist()),
        "film": {
            "type": "hdrfilm",
            "width": W,
            "height": H,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
            "sample_border": False,
        },
        "sampler": {"type": "multijitter", "sample_count": spp},
    }


def mitsuba_scene(mesh, emission, reflectance, camera, *, bounces: int = -1, spp: int = 16,
                  variant: str | None = None, paint=None, two_sided: bool = False):
    """The Mitsuba scene :func:`render` renders (for inspection or custom rendering).

    The camera must be a pinhole with square pixels and no skew or distortion (the warp
    for the others is done by :func:`render`). Sets the Mitsuba variant (``variant``,
    default: :func:`choose_variant`) and returns ``mi.Scene``.
    """
    mi, _ = import_mitsuba()
    mi.set_variant(choose_variant(variant))
    e, r = _check_inputs(mesh, emission, reflectance)
    camera = _check_camera(camera)
    return _load_scene(mi, mesh, e, r, camera, _check_bounces(bounces), int(spp),
                       _check_paint(paint), bool(two_sided))


def _check_paint(paint):
    from selfillum.solve.brdf import GlossyPaint

    if paint is not None and not isinstance(paint, GlossyPaint):
        raise InputError(f"render: paint must be a selfillum.solve.brdf.GlossyPaint or None, got "
                         f"{type(paint).__name__}")
    return paint


def _load_scene(mi, mesh, e, r, camera, bounces, spp, paint=None, two_sided=False):
    K = camera.K
    if K[0, 1] != 0 or K[0, 0] != K[1, 1] or np.any(camera.dist):
        raise InputError("mitsuba_scene: the camera must have fx == fy, no skew and no "
                         "distortion (render() warps the others)")
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "path", "max_depth": bounces, "hide_emitters": False},
        "sensor": _sensor(mi, camera, mesh, spp),
        "model": _mitsuba_mesh(mi, mesh, e, r, paint, two_sided),
    })


def _check_bounces(bounces) -> int:
    try:
        b = int(bounces)
    except (TypeError, ValueError):
        raise InputError(f"render: bounces must be an integer, got {bounces!r}") from None
    if b != bounces or not (b >= 1 or b == -1):
        raise InputError(f"render: bounces must be >= 1 or -1 (all), got {bounces!r}")
    return b


# --------------------------------------------------------------------------- rendering
def _multijitter_count(spp: int) -> int:
    """Smallest sample count >= ``spp`` that Mitsuba's ``multijitter`` sampler takes as is
    (``w x h`` strata with ``w = floor(sqrt(spp))``)."""
    w = max(1, math.isqrt(spp))
    return w * math.ceil(spp / w)


def _render_pinhole(mi, mesh, e, r, camera, bounces, spp, seed, paint=None, two_sided=False):
    """Render with a square-pixel pinhole camera; several passes when ``W H spp`` is too
    many samples to trace at once. Returns float64 ``(H, W)`` radiance and the spp used."""
    lanes = camera.width * camera.height
    # the vectorised variants trace all samples of a pass at once; scalar works in blocks
    limit = spp if mi.variant().startswith("scalar") else _MAX_LANES // max(lanes, 1)
    per_pass = max(1, min(spp, limit))
    passes = math.ceil(spp / per_pass)
    per_pass = _multijitter_count(math.ceil(spp / passes))
    scene = _load_scene(mi, mesh, e, r, camera, bounces, per_pass, paint, two_sided)
    acc = np.zeros((camera.height, camera.width))
    for i in range(passes):
        img = np.asarray(mi.render(scene, spp=per_pass, seed=seed + i), dtype=np.float64)
        acc += img[..., :3].mean(axis=2)
    return acc / passes, per_pass * passes


def _canvas_for(camera: Camera, oversample: int):
    """Pinhole canvas covering the undistorted field of ``camera`` and the canvas
    coordinates of ``oversample**2`` points per output pixel.

    Returns ``(canvas_camera, coords)`` with ``coords`` of shape ``(2, S, H, W)`` (canvas
    row, column; NaN where the lens model has no inverse)."""
    W, H = camera.width, camera.height
    s = oversample
    offs = (np.arange(s) + 0.5) / s - 0.5
    dv, du = np.meshgrid(offs, offs, indexing="ij")
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float64)
    u = uu[None] + du.reshape(-1, 1, 1)
    v = vv[None] + dv.reshape(-1, 1, 1)
    uv = np.column_stack([u.ravel(), v.ravel()])
    xy = undistort_normalized(camera.pixels_to_normalized(uv), camera.dist)
    finite = np.all(np.isfinite(xy), axis=1)
    if not finite.any():
        raise InputError("render: no pixel of the camera can be undistorted")
    f = s * float(max(camera.K[0, 0], camera.K[1, 1]))
    lo = xy[finite].min(axis=0)
    hi = xy[finite].max(axis=0)
    margin = 2.0
    cw = int(math.ceil(f * (hi[0] - lo[0]) + 2 * margin)) + 1
    ch = int(math.ceil(f * (hi[1] - lo[1]) + 2 * margin)) + 1
    if cw * ch > _MAX_CANVAS * s * s * W * H:
        raise InputError(
            f"render: the lens distortion spreads the field over {cw}x{ch} canvas pixels; "
            "too strong to render as a warp"
        )
    cx = margin - f * lo[0]
    cy = margin - f * lo[1]
    canvas = Camera(cw, ch, [[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]], np.zeros(5),
                    camera.R, camera.t)
    cu = f * xy[:, 0] + cx
    cv = f * xy[:, 1] + cy
    coords = np.stack([cv.reshape(s * s, H, W), cu.reshape(s * s, H, W)])
    return canvas, coords


def render(
    mesh: trimesh.Trimesh,
    emission,
    reflectance,
    camera: Camera,
    *,
    bounces: int = -1,
    spp: int = 64,
    seed: int = 0,
    variant: str | None = None,
    oversample: int = 2,
    paint=None,
    two_sided: bool = False,
) -> RenderResult:
    """Render the radiance image of a painted mesh seen by a camera, with Mitsuba 3.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Model surface (model units); faces are one-sided, painted on the side of their
        normal (right-hand rule on the vertex order).
    emission : float or (N,) array_like
        Emitted exitance ``E`` per face (any radiometric unit, e.g. W m^-2), ``>= 0``.
    reflectance : float or (N,) array_like
        Diffuse (Lambertian) reflectance ``rho`` per face, in ``[0, 1)``.
    camera : resection.Camera
        Intrinsics, distortion and pose (``x_cam = R X + t``).
    bounces : int
        ``max_depth`` of Mitsuba's ``path`` integrator: 1 = emission only (no
        self-illumination), 2 = emission + one reflection, ..., -1 = all orders.
    spp : int
        Samples per output pixel (the variance of a pixel falls as ``1/spp``); rounded up
        to ``w * ceil(spp / w)``, ``w = floor(sqrt(spp))``, the counts Mitsuba's
        ``multijitter`` sampler stratifies exactly (squares are kept).
    seed : int
        Seed of the sampler; equal inputs and seed give equal images.
    variant : str, optional
        Mitsuba variant (see :func:`choose_variant`); default: the fastest available.
    oversample : int
        Canvas refinement used only when the camera has distortion, skew or
        ``fx != fy`` (see the module notes).
    paint : selfillum.solve.brdf.GlossyPaint, optional
        Glossy paint (diffuse base of reflectance ``reflectance`` plus a GGX lobe,
        Mitsuba's ``blendbsdf`` of ``diffuse`` and ``roughconductor``); default Lambertian.
        The emission stays Lambertian.
    two_sided : bool
        Faces painted on both sides with the same emission and reflectance (thin sheets,
        as ``two_sided`` in :func:`selfillum.view_factors`); default: one-sided,
        the back is black.

    Returns
    -------
    RenderResult
        ``image`` ``(H, W)`` float32 radiance (``B / pi`` on a Lambertian face of
        radiosity ``B``), with the variant, spp, bounces and seed used.

    Raises
    ------
    InputError
        Invalid mesh (see :func:`selfillum.mesh.check_mesh`), emission < 0 or not finite,
        reflectance outside ``[0, 1)``, wrong per-face lengths, bad ``bounces``/``spp``,
        not a Camera, unavailable variant.
    """
    e, r = _check_inputs(mesh, emission, reflectance)
    camera = _check_camera(camera)
    b = _check_bounces(bounces)
    paint = _check_paint(paint)
    try:
        spp_i, seed_i, over = int(spp), int(seed), int(oversample)
    except (TypeError, ValueError):
        raise InputError("render: spp, seed and oversample must be integers") from None
    if spp_i != spp or spp_i < 1:
        raise InputError(f"render: spp must be a positive integer, got {spp!r}")
    if seed_i < 0:
        raise InputError(f"render: seed must be >= 0, got {seed!r}")
    if over < 1 or over > 8:
        raise InputError(f"render: oversample must be in 1..8, got {oversample!r}")
    mi, _ = import_mitsuba()
    name = choose_variant(variant)
    previous = mi.variant()
    mi.set_variant(name)
    try:
        K = camera.K
        if K[0, 1] == 0 and K[0, 0] == K[1, 1] and not np.any(camera.dist):
            img, used = _render_pinhole(mi, mesh, e, r, camera, b, spp_i, seed_i, paint,
                                        bool(two_sided))
        else:
            img, used = _render_warped(mi, mesh, e, r, camera, b, spp_i, seed_i, over, paint,
                                       bool(two_sided))
    finally:
        if previous is not None and previous != name:
            mi.set_variant(previous)
    return RenderResult(img.astype(np.float32), name, int(used), b, seed_i)


def _render_warped(mi, mesh, e, r, camera, bounces, spp, seed, over, paint=None,
                   two_sided=False):
    from scipy.ndimage import map_coordinates

    canvas, coords = _canvas_for(camera, over)
    # each output pixel averages over*over canvas samples: keep its sample count ~ spp
    spp_canvas = max(1, math.ceil(spp / (over * over)))
    pin, used = _render_pinhole(mi, mesh, e, r, canvas, bounces, spp_canvas, seed, paint,
                                two_sided)
    valid = np.all(np.isfinite(coords), axis=0)
    c = np.where(valid, coords, -10.0)
    samples = map_coordinates(pin, c.reshape(2, -1), order=1, mode="constant", cval=0.0)
    samples = np.where(valid.ravel(), samples, 0.0).reshape(over * over, *valid.shape[1:])
    return samples.mean(axis=0), used * over * over
