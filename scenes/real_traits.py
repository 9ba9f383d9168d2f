"""A synthetic wind-tunnel scene with the traits of real PSP frames (issue 12).

A painted flat plate carrying a black, unpainted block, filmed by two cameras:

* **grid**: a multi-block Plot3D surface grid (written with
  :func:`resection.io.meshes.write_plot3d`): the plate ``z = 0``, ``|x| <= 0.35``,
  ``|y| <= 0.25`` (metres) split into 3 x 2 blocks whose interfaces (``x = +-0.1``,
  ``y = 0``) cross flat paint, plus the block ``|x| <= 0.04``, ``|y| <= 0.03``,
  ``0 <= z <= 0.04`` as five blocks (top and four sides, normals outwards; no bottom);
* **paint**: the plate is painted (a smooth luminescence field :func:`luminescence`, around 1),
  the block is not (a black level of ``BLACK`` times the paint level);
* **targets**: dark dots of diameter 6 mm: a jittered grid on the plate, one on the block's
  top (low contrast on black), one placed so that camera 0 sees it at ``u ~ 1`` (cut by the
  image edge). Their *surveyed* positions (:attr:`RealTraits.surveyed`, the marker file) are
  the true ones moved along the surface by 0.5 to 1.5 px equivalent (at camera 0's
  distance), as real survey errors are;
* **pressure taps**: smaller dark dots (1.5 mm, not in the marker file): distractors;
* **frames**: 8-bit (``uint8``), camera 1 with a different gain from camera 0, vignetting
  (12 % at the corners), Gaussian read noise, and a glare spot (additive, saturated at its
  core) in camera 0.

Rendering: every pixel's line of sight (distortion included) is cast on the grid by
:class:`resection.SurfaceMap`; the pixel gets the luminescence at its hit point (or the black
level on the block), times a dot attenuation: each dot is a disk rendered by
:func:`scenes.marker_images.render_markers` (pixel-integrated, blurred) at its projected true
centre with its projected diameter (the dots are small: their ellipticity is neglected). Dots
hidden from a camera (behind the block or facing away) are not drawn.

Size: ``scale=1`` gives 320 x 240 frames (seconds to build, for tests); ``scale=4`` gives
1280 x 960 for benchmarks (the grid is refined with it).

Conventions: docs/design.md (pixel centres at integer ``(u, v)``, ``img[v, u]``, metres).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.camera.model import Camera
from resection.errors import InputError
from resection.io.cameras import write_camera
from resection.io.images import write_image
from resection.io.markers import write_markers
from resection.io.meshes import plot3d_to_mesh, write_plot3d
from resection.surface.surface_map import SurfaceMap
from resection.surface.visibility import RayCaster

from .marker_images import render_markers

__all__ = ["RealTraits", "real_traits", "luminescence", "plate_blocks", "write_scene",
           "HALF_X", "HALF_Y", "BOX", "BLACK"]

HALF_X, HALF_Y = 0.35, 0.25  #: plate half sizes, metres
BOX = (0.04, 0.03, 0.04)  #: block half length (x), half width (y), height (z), metres
BLACK = 0.12  #: block level relative to the paint (unpainted black)
TARGET_D = 0.006  #: target diameter, metres
TAP_D = 0.0015  #: pressure tap diameter, metres
_DOT_DEPTH = 0.75  #: fraction of the light a dot absorbs


@dataclass(frozen=True)
class RealTraits:
    """The scene and its truth.

    Attributes
    ----------
    blocks : list of (ni, nj, 1, 3) arrays
        The Plot3D surface blocks (plate blocks first, then the block's top and sides).
    mesh : trimesh.Trimesh
        The triangulated grid (``face_attributes["block"]`` gives each face's block).
    painted : (F,) bool
        Faces of the plate (painted); the block's faces are False.
    truth : (F,) float64
        True radiance per face in camera 0's counts (luminescence at the face centroid times
        ``gain[0]``, or the black level): the reference of a merge.
    cameras : list of Camera
        The two cameras (true poses).
    images : list of (H, W) uint8 arrays
        The frames.
    gains : (2,) float64
        Counts per unit luminescence of each camera.
    glare : list of (H, W) float64
        The additive glare of each frame (counts, before clipping).
    marker_ids : tuple of str
        Target ids (``T01``...; ``TB`` on the block, ``TE`` at camera 0's edge).
    markers : (M, 3) float64
        True target centres.
    surveyed : (M, 3) float64
        Surveyed target centres (what the marker file holds).
    survey_error_px : (M,) float64
        Size of each survey error in pixels at camera 0's distance (0.5 to 1.5).
    taps : (P, 3) float64
        Pressure tap centres (distractors).
    uv : list of (M, 2) float64
        True image positions of the targets in each camera (NaN where hidden or behind).
    """

    blocks: list
    mesh: trimesh.Trimesh
    painted: np.ndarray
    truth: np.ndarray
    cameras: list
    images: list
    gains: np.ndarray
    glare: list
    marker_ids: tuple
    markers: np.ndarray
    surveyed: np.ndarray
    survey_error_px: np.ndarray
    taps: np.ndarray
    uv: list


def luminescence(points) -> np.ndarray:
    """Paint luminescence at model points (wind-on like: a suction peak ahead of the block,
    a gentle gradient), between about 0.75 and 1.1."""
    p = np.asarray(points, dtype=np.float64)
    x, y = p[..., 0], p[..., 1]
    return (1.0 - 0.2 * np.exp(-((x + 0.09) ** 2 + y**2) / 0.05**2)
            + 0.15 * x + 0.05 * np.cos(np.pi * y / HALF_Y))


def _grid(x0, x1, y0, y1, nx, ny):
    """A flat block of the plate, (nx+1, ny+1, 1, 3), normal +z (d/di = +x, d/dj = +y)."""
    X, Y = np.meshgrid(np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1), indexing="ij")
    return np.stack([X, Y, np.zeros_like(X)], axis=-1)[:, :, None, :]


def plate_blocks(cell: float = 0.015) -> list:
    """The Plot3D blocks: 3 x 2 plate blocks (interfaces across the flat plate), then the
    block's top, -y, +x, +y and -x sides, every normal pointing out of the model."""
    xs, ys = (-HALF_X, -0.1, 0.1, HALF_X), (-HALF_Y, 0.0, HALF_Y)
    blocks = []
    for i in range(3):
        for j in range(2):
            nx = max(2, int(round((xs[i + 1] - xs[i]) / cell)))
            ny = max(2, int(round((ys[j + 1] - ys[j]) / cell)))
            blocks.append(_grid(xs[i], xs[i + 1], ys[j], ys[j + 1], nx, ny))
    a, b, h = BOX
    c = min(cell, 0.01)
    na, nb, nh = (max(2, int(round(2 * a / c))), max(2, int(round(2 * b / c))),
                  max(2, int(round(h / c))))
    top = _grid(-a, a, -b, b, na, nb)
    top[..., 2] = h
    blocks.append(top)
    s = np.linspace(0.0, 1.0, nh + 1)

    def side(p0, p1, n):
        """Side from bottom edge p0 -> p1 (seen from outside, counter-clockwise), up to h:
        d/di along the edge, d/dj up, so the normal d/di x d/dj points outwards."""
        t = np.linspace(0.0, 1.0, n + 1)
        P = np.asarray(p0)[None, :] + t[:, None] * (np.asarray(p1) - np.asarray(p0))[None, :]
        out = np.empty((n + 1, nh + 1, 1, 3))
        out[:, :, 0, :2] = P[:, None, :]
        out[:, :, 0, 2] = h * s[None, :]
        return out

    blocks.append(side((-a, -b), (a, -b), na))  # -y face: along +x, normal -y
    blocks.append(side((a, -b), (a, b), nb))  # +x face
    blocks.append(side((a, b), (-a, b), na))  # +y face
    blocks.append(side((-a, b), (-a, -b), nb))  # -x face
    return blocks


def _cameras(scale: float) -> list:
    w, h = int(round(320 * scale)), int(round(240 * scale))
    f = 470.0 * scale
    K = [[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]]
    up = [0.0, 1.0, 0.0]
    return [
        Camera.look_at([-0.17, -0.27, 0.50], [-0.07, 0.0, 0.0], up, K=K, width=w, height=h,
                       dist=[-0.05, 0.0, 0.0, 0.0, 0.0], name="cam0"),
        Camera.look_at([0.15, -0.24, 0.54], [0.07, 0.01, 0.0], up, K=K, width=w, height=h,
                       dist=[-0.03, 0.0, 0.0, 0.0, 0.0], name="cam1"),
    ]


def _dots(smap: SurfaceMap, caster: RayCaster, centres, normals, diameter):
    """Projected centres and diameters (pixels) of the dots a camera sees (others dropped)."""
    cam = smap.camera
    uv = cam.project(centres)
    xc = cam.to_camera_frame(centres)
    to_cam = cam.center[None, :] - centres
    dist = np.linalg.norm(to_cam, axis=1)
    facing = np.einsum("ij,ij->i", normals, to_cam) > 0
    ok = np.all(np.isfinite(uv), axis=1) & (xc[:, 2] > 0) & facing
    # hidden: a ray from the camera hits the model clearly before the dot
    dirs = -to_cam / dist[:, None]
    _, hit, _ = caster.first_hit(cam.center, dirs)
    ok &= np.isfinite(hit) & (hit > dist - 1e-3)
    d_px = diameter * cam.K[0, 0] / np.maximum(xc[:, 2], 1e-9)
    inside = ok & (uv[:, 0] > -d_px) & (uv[:, 0] < cam.width - 1 + d_px) \
        & (uv[:, 1] > -d_px) & (uv[:, 1] < cam.height - 1 + d_px)
    return np.where(ok[:, None], uv, np.nan), d_px, inside


def real_traits(*, scale: float = 1.0, seed: int = 0, gain_ratio: float = 1.25,
                noise: float = 1.2, glare: float = 140.0, vignetting: float = 0.12
                ) -> RealTraits:
    """Build the scene (see the module docstring).

    Parameters
    ----------
    scale : float
        Image size factor: 320 x 240 frames at 1 (tests), 1280 x 960 at 4 (benchmarks);
        the grid cell shrinks with it (1.5 cm at 1).
    seed : int
        Random seed (target jitter, survey errors, taps, noise).
    gain_ratio : float
        Gain of camera 1 over camera 0.
    noise : float
        Read-noise standard deviation, counts.
    glare : float
        Peak of camera 0's glare spot, counts (its core saturates the 8-bit frame).
    vignetting : float
        Relative fall-off of the light at the image corners (``1 - vignetting r^2``, ``r``
        the distance to the image centre over the half diagonal).
    """
    if not (0.25 <= scale <= 8):
        raise InputError(f"real_traits: scale must be in [0.25, 8], got {scale}")
    rng = np.random.default_rng(seed)
    blocks = plate_blocks(0.015 / np.sqrt(scale))
    mesh = plot3d_to_mesh(blocks, source="real_traits")
    nplate = 6
    painted = np.asarray(mesh.face_attributes["block"]) <= nplate  # blocks count from 1
    cameras = _cameras(scale)
    gains = np.array([150.0, 150.0 * gain_ratio])

    # targets: a jittered 5 x 4 grid on the plate away from the block, one on the block top,
    # one at camera 0's left edge (u ~ 1)
    gx, gy = np.meshgrid(np.linspace(-0.22, 0.22, 5), np.linspace(-0.14, 0.14, 4),
                         indexing="ij")
    pts = np.column_stack([gx.ravel(), gy.ravel()]) + rng.uniform(-0.012, 0.012, (20, 2))
    a, b, h = BOX
    away = (np.abs(pts[:, 0]) > a + 0.02) | (np.abs(pts[:, 1]) > b + 0.02)
    pts = pts[away]
    plate_t = np.column_stack([pts, np.zeros(len(pts))])
    top_t = np.array([[0.012, -0.008, h]])
    cam0 = cameras[0]
    o, d = cam0.rays(np.array([[1.0, 0.55 * (cam0.height - 1)]]))
    s = -o[0, 2] / d[0, 2]
    edge_t = (o[0] + s * d[0])[None, :]
    centres = np.vstack([plate_t, top_t, edge_t])
    ids = tuple([f"T{k + 1:02d}" for k in range(len(plate_t))] + ["TB", "TE"])
    normals = np.tile([0.0, 0.0, 1.0], (len(centres), 1))
    # survey error: along the surface, 0.5..1.5 px at camera 0's distance
    px = np.linalg.norm(centres - cam0.center, axis=1) / cam0.K[0, 0]
    mag = rng.uniform(0.5, 1.5, len(centres))
    ang = rng.uniform(0, 2 * np.pi, len(centres))
    surveyed = centres + np.column_stack([np.cos(ang), np.sin(ang), np.zeros(len(ang))]) \
        * (mag * px)[:, None]

    # pressure taps: two rows of small dots on the plate, upstream and beside the block
    tx = np.concatenate([np.linspace(-0.2, -0.06, 8), np.full(6, 0.0)])
    ty = np.concatenate([np.full(8, 0.005), np.linspace(0.05, 0.15, 6)])
    taps = np.column_stack([tx, ty, np.zeros(len(tx))])

    caster = RayCaster(mesh)
    images, glares, uvs = [], [], []
    blur = 0.6
    for c, cam in enumerate(cameras):
        smap = SurfaceMap(mesh, cam, caster=caster)
        P = smap.points
        f_idx = smap.face_index
        on_paint = (f_idx >= 0) & painted[np.maximum(f_idx, 0)]
        lum = np.where(on_paint, luminescence(np.nan_to_num(P)), BLACK)
        signal = np.where(f_idx >= 0, gains[c] * lum, 4.0)  # tunnel wall: dark
        uv_t, d_t, in_t = _dots(smap, caster, centres, normals, TARGET_D)
        uv_p, d_p, in_p = _dots(smap, caster, taps, np.tile([0.0, 0.0, 1.0], (len(taps), 1)),
                                TAP_D)
        att = np.zeros(cam.height * cam.width).reshape(cam.height, cam.width)
        for uv_, d_, in_ in ((uv_t, d_t, in_t), (uv_p, d_p, in_p)):  # targets, then taps
            if in_.any():
                att += render_markers((cam.height, cam.width), uv_[in_], d_[in_],
                                      contrast=1.0, background=0.0, polarity="bright",
                                      blur=blur, dtype=np.float64)
        signal = signal * (1.0 - _DOT_DEPTH * np.clip(att, 0.0, 1.0))
        vv, uu = np.mgrid[0:cam.height, 0:cam.width]
        r2 = ((uu - (cam.width - 1) / 2) ** 2 + (vv - (cam.height - 1) / 2) ** 2) \
            / (((cam.width - 1) / 2) ** 2 + ((cam.height - 1) / 2) ** 2)
        signal = signal * (1.0 - vignetting * r2)
        g = np.zeros((cam.height, cam.width))
        if c == 0 and glare > 0:
            gu, gv, gs = 0.3 * cam.width, 0.3 * cam.height, 0.05 * cam.width
            g = glare * np.exp(-((uu - gu) ** 2 + (vv - gv) ** 2) / (2 * gs**2))
        img = signal + g + noise * rng.standard_normal(signal.shape)
        images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
        glares.append(g)
        uvs.append(uv_t)
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    truth = gains[0] * np.where(painted, luminescence(tri.mean(axis=1)), BLACK)
    return RealTraits(blocks, mesh, painted, truth, cameras, images, gains, glares, ids,
                      centres, surveyed, mag, taps, uvs)


def write_scene(scene: RealTraits, folder: str | os.PathLike) -> dict:
    """Write the scene as a user would bring it: ``grid.xyz`` (binary multi-block Plot3D),
    ``cam0.json``/``cam1.json`` (true poses), ``cam0.png``/``cam1.png`` (8-bit frames),
    ``markers.csv`` (surveyed targets with their diameter) and ``taps.csv`` (id,x,y,z).

    Returns a dict of the paths written.
    """
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    paths = {"grid": os.path.join(folder, "grid.xyz"),
             "markers": os.path.join(folder, "markers.csv"),
             "taps": os.path.join(folder, "taps.csv")}
    write_plot3d(paths["grid"], scene.blocks)
    write_markers(paths["markers"], scene.marker_ids, scene.surveyed,
                  np.full(len(scene.marker_ids), TARGET_D))
    write_markers(paths["taps"], [f"P{k + 1:02d}" for k in range(len(scene.taps))],
                  scene.taps)
    for c, (cam, img) in enumerate(zip(scene.cameras, scene.images, strict=True)):
        paths[f"camera{c}"] = os.path.join(folder, f"cam{c}.json")
        paths[f"image{c}"] = os.path.join(folder, f"cam{c}.png")
        write_camera(paths[f"camera{c}"], cam)
        write_image(paths[f"image{c}"], img)
    return paths
