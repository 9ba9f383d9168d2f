"""A synthetic PSP image pair: a textured flat panel seen wind-off and wind-on.

The model is the flat panel ``z = 0``, ``|x| <= 0.15``, ``|y| <= 0.10`` (metres) with a
painted texture (paint thickness / luminophore inhomogeneity, band-limited, wavelengths of
8 to 22 mm, i.e. 10 to 30 pixels) that a PSP ratio must divide out. Wind-on, the luminescence
is multiplied by a smooth pressure-dependent factor and the model has moved (pitched and
shifted slightly, as under load), so the wind-on image is misregistered by a few pixels.

Images are rendered in closed form, independently of :class:`resection.SurfaceMap`: every
pixel's line of sight (:meth:`Camera.rays`, distortion included) is intersected with the
plane ``z = 0`` analytically and the texture is evaluated at the hit point. Noise is
Gaussian, relative to the signal (shot-noise-like), independent between images.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from resection.camera.model import Camera

__all__ = ["PSPPair", "panel_mesh", "paint", "pressure_factor", "render", "psp_pair",
           "HALF_X", "HALF_Y"]

HALF_X, HALF_Y = 0.15, 0.10

# wave vectors (cycles per metre) and phases of the paint texture
_WAVES = np.array([
    [1.0 / 0.012, 0.0], [0.0, 1.0 / 0.010], [1.0 / 0.014, 1.0 / 0.016],
    [-1.0 / 0.009, 1.0 / 0.018], [1.0 / 0.022, -1.0 / 0.013],
])
_AMPS = np.array([0.12, 0.10, 0.08, 0.07, 0.06])
_PHASES = np.array([0.3, 1.7, 2.9, 4.1, 5.3])


def panel_mesh(n: int = 48) -> trimesh.Trimesh:
    """The panel as a triangulated grid (``n`` x ``2n/3`` cells), normal +z."""
    m = max(2, int(round(n * HALF_Y / HALF_X)))
    xs = np.linspace(-HALF_X, HALF_X, n + 1)
    ys = np.linspace(-HALF_Y, HALF_Y, m + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(V.shape[0]).reshape(n + 1, m + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return trimesh.Trimesh(V, F, process=False)


def paint(points: np.ndarray) -> np.ndarray:
    """Wind-off luminescence of the paint at model points (x, y used), around 1."""
    xy = np.asarray(points)[..., :2]
    phase = 2 * np.pi * (xy @ _WAVES.T) + _PHASES
    return 1.0 + (_AMPS * np.cos(phase)).sum(axis=-1)


def pressure_factor(points: np.ndarray) -> np.ndarray:
    """Wind-on / wind-off luminescence ratio (smooth: a suction peak and a gradient)."""
    x, y = np.asarray(points)[..., 0], np.asarray(points)[..., 1]
    return 1.0 - 0.25 * np.exp(-((x - 0.02) ** 2 + (y + 0.01) ** 2) / 0.04**2) + 0.4 * x


def plane_hits(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form hit points of every pixel's ray on ``z = 0`` and the on-panel mask."""
    H, W = camera.height, camera.width
    vv, uu = np.mgrid[0:H, 0:W]
    o, d = camera.rays(np.column_stack([uu.ravel(), vv.ravel()]).astype(float))
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[:, 2] / d[:, 2]
    P = o + s[:, None] * d
    on = (s > 0) & (np.abs(P[:, 0]) <= HALF_X) & (np.abs(P[:, 1]) <= HALF_Y)
    return P.reshape(H, W, 3), on.reshape(H, W)


def render(camera: Camera, wind_on: bool = False, *, noise: float = 0.0,
           rng: np.random.Generator | None = None, level: float = 1000.0) -> np.ndarray:
    """Image of the panel (counts): ``level * paint [* pressure_factor]`` with relative
    Gaussian noise of standard deviation ``noise``; NaN off the panel."""
    P, on = plane_hits(camera)
    signal = level * paint(P)
    if wind_on:
        signal = signal * pressure_factor(P)
    if noise > 0:
        rng = np.random.default_rng() if rng is None else rng
        signal = signal * (1.0 + noise * rng.standard_normal(signal.shape))
    return np.where(on, signal, np.nan)


@dataclass
class PSPPair:
    """Cameras and images of a synthetic PSP pair (see :func:`psp_pair`)."""

    mesh: trimesh.Trimesh
    camera_off: Camera
    camera_on: Camera
    wind_off: np.ndarray
    wind_on: np.ndarray
    wind_off_in_on_view: np.ndarray  # wind-off rendered directly in the wind-on pose


def psp_pair(*, width: int = 320, height: int = 240, noise: float = 0.005,
             pitch_deg: float = 0.6, shift=(0.0015, -0.001, 0.002), seed: int = 0) -> PSPPair:
    """Wind-off and wind-on images of the panel from a fixed camera, the model having
    pitched by ``pitch_deg`` about the y axis and moved by ``shift`` (metres) wind-on.

    The motion is expressed as the camera pose of each image (``R_on = Rc M``,
    ``t_on = Rc d + tc``), as a resection of each image would give it.
    """
    rng = np.random.default_rng(seed)
    K = [[600.0, 0.0, (width - 1) / 2], [0.0, 600.0, (height - 1) / 2], [0.0, 0.0, 1.0]]
    cam_off = Camera.look_at([0.03, -0.06, 0.45], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], K=K,
                             width=width, height=height, dist=[-0.08, 0.01, 0.0, 0.0, 0.0])
    a = np.radians(pitch_deg)
    M = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    d = np.asarray(shift, dtype=float)
    cam_on = cam_off.with_pose(R=cam_off.R @ M, t=cam_off.R @ d + cam_off.t)
    return PSPPair(
        mesh=panel_mesh(),
        camera_off=cam_off,
        camera_on=cam_on,
        wind_off=render(cam_off, False, noise=noise, rng=rng),
        wind_on=render(cam_on, True, noise=noise, rng=rng),
        wind_off_in_on_view=render(cam_on, False, noise=noise, rng=rng),
    )
