"""A body of revolution with markers all around it, filmed as a real PSP run (issue 21).

The model (metres, model frame: ``x`` along the body's axis, nose towards ``+x``):

* a cylinder of radius ``R0 = 0.05`` from the tail ``x = -0.28`` to ``x = 0.15``, a cone from
  there to the nose ``x = 0.30``, a flat base at the tail, and four thin fins at the tail
  (roll angles 45, 135, 225 and 315 degrees, ``x`` from -0.28 to -0.20, span up to 0.05);
* **36 targets** all around the body: four rings (10, 8, 7 and 7) on the cylinder and four
  on the cone, staggered and jittered as painted by hand; about half of them face a given camera;
* **pressure taps** (smaller dark dots, not in the marker file): rows along the body.

The paint is speckled: a fixed texture on the surface (grain of ``grain`` px on the image,
relative contrast ``speckle``), shaded by the cosine of the view angle, with a static
glare spot (additive, saturating at its core), vignetting and Gaussian noise; the frames
are 8-bit (``uint8``), 1280 x 800 by default. Every frame is ray cast exactly (closed-form
intersections of the lines of sight with the cylinder, cone, base and fins), so the paint
moves with the model; the dots are ellipses, the exact perspective images of the painted
circles (4 x 4 sub-samples a pixel, each intersected with the dot's tangent plane), blurred
with the lens' PSF (``blur``). A dot is drawn where it faces the camera and no part of the
body hides its centre.

Motion (periodic over ``period`` frames, so that a run longer than one period can list the
same files again): a slow roll sweep about the body's axis (``roll_deg`` amplitude, which
carries markers in and out of view) plus vibration: pitch, yaw and translation at 5, 7.5
and 12.5 Hz (fractions of a pixel to about 2 px). The convention is that of
:mod:`scenes.moving_model`: ``Y = M_k X + d_k``, the fixed camera sees ``R_k = Rc M_k``,
``t_k = Rc d_k + tc``.

:func:`paint_frame` draws one frame with its parameters (target size 4-6 px, grain 1-3 px,
speckle contrast 5-15 %, glare position, roll) from a seed, for detection benchmarks.
"""

from __future__ import annotations

import csv
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage

from resection.camera import Camera
from scenes.moving_model import rotation_zyx

__all__ = ["RevolutionModel", "revolution_model", "paint_frame", "write_sequence",
           "R0", "X_TAIL", "X_CONE", "X_NOSE"]

R0, X_TAIL, X_CONE, X_NOSE = 0.05, -0.28, 0.15, 0.30  #: body radius and stations, metres
FIN_X1, FIN_SPAN = -0.20, 0.05  #: fins from the tail to FIN_X1, span at the tail, metres
FIN_ROLL = np.radians([45.0, 135.0, 225.0, 315.0])
_TEXEL = 2.5e-4  #: speckle texture sampling on the surface, metres
_TEX_SHAPE = (2600, 2600)  #: texels along x (from x = -0.33) and along the arc


def _shading(cosine):
    """The paint's brightness relative to face-on at the cosine of the view angle."""
    return 0.3 + 0.7 * cosine


def _vignetting(u, v, H: int, W: int):
    """The lens' vignetting at pixel ``(u, v)`` of an ``H x W`` frame (1 at the centre)."""
    r2 = ((u - W / 2) ** 2 + (v - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
    return 1.0 - 0.12 * r2


def _radial(theta):
    """Unit radial direction ``(0, cos, sin)`` at roll angle(s) ``theta``."""
    theta = np.asarray(theta, float)
    return np.stack([np.zeros_like(theta), np.cos(theta), np.sin(theta)], axis=-1)


def _cone_normal(theta):
    k = R0 / (X_NOSE - X_CONE)
    n = np.concatenate([np.full(np.shape(theta) + (1,), k), _radial(theta)[..., 1:]], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _body_point(x, theta):
    """Surface point and outward normal of the body at station ``x``, roll ``theta``."""
    x, theta = np.asarray(x, float), np.asarray(theta, float)
    r = np.where(x <= X_CONE, R0, R0 * (X_NOSE - x) / (X_NOSE - X_CONE))
    p = _radial(theta) * r[..., None]
    p[..., 0] = x
    n = np.where((x <= X_CONE)[..., None], _radial(theta), _cone_normal(theta))
    return p, n


def _layout(rng, counts=(10, 8, 7, 7)):
    """Targets (``sum(counts) + 4``: rings on the cylinder, four on the cone) and taps:
    positions, normals."""
    # rings of unequal counts, jittered: no roll of the body maps the layout onto itself
    # (a regular layout would make the statistical matcher's answer ambiguous)
    xs = [-0.17, -0.07, 0.03, 0.11]
    th, x = [], []
    for j, (xr, m) in enumerate(zip(xs, counts, strict=True)):
        th.extend(2 * np.pi * np.arange(m) / m + j * 0.6 + np.radians(rng.uniform(-9, 9, m)))
        x.extend(xr + rng.uniform(-0.014, 0.014, m))
    th.extend(2 * np.pi * np.arange(4) / 4 + np.pi / 8)
    x.extend([0.205] * 4)
    pts, nrm = _body_point(np.array(x), np.array(th))
    # taps: four rows along the body (two on the side facing the camera, one at the top,
    # one underneath), between the target rings
    tx = np.concatenate([np.linspace(-0.24, 0.14, 20), np.linspace(0.16, 0.25, 4)])
    tth = np.radians([150.0, 175.0, 95.0, 265.0])
    TX, TT = np.meshgrid(tx, tth)
    tpts, tnrm = _body_point(TX.ravel(), TT.ravel())
    return pts, nrm, tpts, tnrm


def _speckle(rng, grain_px: float, px_m: float) -> np.ndarray:
    """Surface texture (zero mean, unit standard deviation), float32."""
    sigma = max(0.5 * grain_px * px_m / _TEXEL, 0.6)  # grain in texels
    t = rng.standard_normal(_TEX_SHAPE).astype(np.float32)
    t = ndimage.gaussian_filter(t, sigma, mode="wrap")
    t /= t.std()
    return t


def _intersect(C, D):
    """First hit of rays ``C + t D`` (one origin, unit directions ``D`` (N, 3)) on the
    body: ``t`` (NaN for a miss), texture coordinates ``(x, arc)`` in metres and the
    cosine between the ray and the surface normal (absolute)."""
    n = len(D)
    best = np.full(n, np.inf)
    tx = np.full(n, np.nan)
    ta = np.full(n, np.nan)
    cs = np.full(n, np.nan)
    Cy, Cz = C[1], C[2]
    Dx, Dy, Dz = D[:, 0], D[:, 1], D[:, 2]

    def keep(t, x, arc, cosine):
        ok = np.isfinite(t) & (t > 1e-9) & (t < best)
        best[ok] = t[ok]
        tx[ok], ta[ok], cs[ok] = x[ok], arc[ok], cosine[ok]

    with np.errstate(invalid="ignore", divide="ignore"):
        # cylinder y^2 + z^2 = R0^2, near root
        a = Dy * Dy + Dz * Dz
        b = 2 * (Cy * Dy + Cz * Dz)
        c = Cy * Cy + Cz * Cz - R0 * R0
        t = (-b - np.sqrt(b * b - 4 * a * c)) / (2 * a)
        x = C[0] + t * Dx
        t = np.where((x >= X_TAIL) & (x <= X_CONE), t, np.nan)
        y, z = Cy + t * Dy, Cz + t * Dz
        th = np.arctan2(z, y)
        keep(t, x, np.mod(th, 2 * np.pi) * R0, np.abs(Dy * y + Dz * z) / R0)
        # cone y^2 + z^2 = k^2 (X_NOSE - x)^2, both roots
        k = R0 / (X_NOSE - X_CONE)
        w0 = X_NOSE - C[0]
        a = Dy * Dy + Dz * Dz - k * k * Dx * Dx
        b = 2 * (Cy * Dy + Cz * Dz + k * k * w0 * Dx)
        c = Cy * Cy + Cz * Cz - k * k * w0 * w0
        disc = np.sqrt(b * b - 4 * a * c)
        for sgn in (-1.0, 1.0):
            t = (-b + sgn * disc) / (2 * a)
            x = C[0] + t * Dx
            t = np.where((x >= X_CONE) & (x <= X_NOSE), t, np.nan)
            y, z = Cy + t * Dy, Cz + t * Dz
            th = np.arctan2(z, y)
            nrm = _cone_normal(th)
            cosine = np.abs(np.einsum("ij,ij->i", nrm, D))
            keep(t, x, np.mod(th, 2 * np.pi) * R0, cosine)
        # the base x = X_TAIL
        t = (X_TAIL - C[0]) / Dx
        y, z = Cy + t * Dy, Cz + t * Dz
        t = np.where(y * y + z * z <= R0 * R0, t, np.nan)
        keep(t, np.full(n, X_TAIL), 0.32 + np.hypot(y, z), np.abs(Dx))
        # fins: the half-planes at roll phi, R0 <= s <= R0 + span (x)
        for i, phi in enumerate(FIN_ROLL):
            e = np.array([0.0, np.cos(phi), np.sin(phi)])
            nf = np.array([0.0, -np.sin(phi), np.cos(phi)])
            t = -(C @ nf) / (D @ nf)
            P = C[None, :] + t[:, None] * D
            s = P @ e
            x = P[:, 0]
            span = FIN_SPAN * (FIN_X1 - x) / (FIN_X1 - X_TAIL)
            t = np.where((x >= X_TAIL) & (x <= FIN_X1) & (s >= R0) & (s <= R0 + span),
                         t, np.nan)
            keep(t, x, 0.34 + 0.07 * i + s, np.abs(D @ nf))
    best[~np.isfinite(best)] = np.nan
    return best, tx, ta, cs


@dataclass(frozen=True)
class RevolutionModel:
    """The body, its markers, the fixed camera, the motion and the rendering settings.

    Attributes
    ----------
    camera : Camera
        The fixed camera, posed on the model at rest.
    ids : (36,) str ndarray
    points3d, normals : (36, 3) ndarrays
        Target centres (metres) and outward unit normals.
    tap_points, tap_normals : (T, 3) ndarrays
    marker_diameter, tap_diameter : float
        Metres.
    fps : float
    angles : (F, 3) ndarray
        ``(roll, pitch, yaw)`` of every frame, radians.
    translation : (F, 3) ndarray
        Metres.
    paint, speckle, grain, snr, blur, glare :
        Paint level (counts of 255), relative speckle contrast, speckle grain (px), the
        SNR of a target seen face-on at the image's centre (its depth over the noise: the
        frame's other targets, shaded by the view angle and vignetted, have less), PSF
        sigma (px), glare centre ``(u, v)`` (px).
    seed : int
    target_depth, tap_depth : float
        Relative depth of the dots (their reflectance under the paint's is
        ``1 - depth``): a dot's depth in counts is ``depth`` times the paint as shaded there.
    supersample : int
        Sub-samples along each side of a pixel for the dots' coverage. The coverage of a
        ``n x n`` grid moves a 4-6 px dot's centroid off its true centre by about
        ``0.06 / n`` px (median; 0.015 px for 4, 0.004 px for 16), a bias of the image, not
        of a detector measured on it.
    """

    camera: Camera
    ids: np.ndarray
    points3d: np.ndarray
    normals: np.ndarray
    tap_points: np.ndarray
    tap_normals: np.ndarray
    marker_diameter: float
    tap_diameter: float
    fps: float
    angles: np.ndarray
    translation: np.ndarray
    paint: float = 150.0
    speckle: float = 0.10
    grain: float = 2.0
    snr: float = 20.0
    blur: float = 0.7
    glare: tuple = (520.0, 330.0)
    seed: int = 0
    supersample: int = 4
    target_depth: float = 0.7
    tap_depth: float = 0.6
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def n_frames(self) -> int:
        return len(self.angles)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.camera.height, self.camera.width)

    @property
    def px_per_m(self) -> float:
        """Image scale at the body's axis, pixels per metre."""
        return float(self.camera.K[0, 0] / np.linalg.norm(self.camera.center))

    def camera_at(self, k: int) -> Camera:
        a = self.angles[k]
        M = rotation_zyx(a[0], a[1], a[2])[0]
        Rc, tc = self.camera.R, self.camera.t
        return self.camera.with_pose(R=Rc @ M, t=Rc @ self.translation[k] + tc)

    def uv(self, k: int) -> np.ndarray:
        """True image positions of the targets in frame ``k`` (all 36), pixels."""
        return self.camera_at(k).project(self.points3d)

    def visible(self, k: int, points=None, normals=None, min_cos: float = 0.0) -> np.ndarray:
        """``(N,)`` bool: the dots (targets by default) whose normal faces the camera
        (cosine of the view angle above ``min_cos``) and whose centre no part of the body
        hides, in frame ``k``."""
        P = self.points3d if points is None else points
        N = self.normals if normals is None else normals
        C = self.camera_at(k).center
        v = C[None, :] - P
        dist = np.linalg.norm(v, axis=1)
        cosine = np.einsum("ij,ij->i", N, v) / dist
        t, *_ = _intersect(C, -v / dist[:, None])
        hidden = np.isfinite(t) & (t < dist - 1e-5)
        return (cosine > min_cos) & ~hidden

    def drawn_depth(self, k: int, points=None, normals=None) -> np.ndarray:
        """``(N,)`` depth of the dots (targets by default) as drawn in frame ``k``, counts:
        ``target_depth`` times the plain paint as shaded at the dot's centre (the cosine of
        the view angle, the vignetting), before the blur; the speckle (mean 1) left out."""
        P = self.points3d if points is None else points
        N = self.normals if normals is None else normals
        cam = self.camera_at(k)
        v = cam.center[None, :] - P
        cosine = np.einsum("ij,ij->i", N, v) / np.linalg.norm(v, axis=1)
        H, W = self.shape
        uv = cam.project(P)
        return self.target_depth * self.paint * _shading(cosine) * _vignetting(uv[:, 0],
                                                                             uv[:, 1], H, W)

    def _texture(self) -> np.ndarray:
        if "tex" not in self._cache:
            rng = np.random.default_rng([self.seed, 7])
            self._cache["tex"] = _speckle(rng, self.grain, 1.0 / self.px_per_m)
            self._cache["bg"] = ndimage.gaussian_filter(
                rng.standard_normal(self.shape).astype(np.float32), 1.5)
        return self._cache["tex"]

    def _static(self):
        """Background (tunnel wall), vignetting and glare layers (float32, (H, W))."""
        if "static" not in self._cache:
            H, W = self.shape
            self._texture()
            bg = self._cache["bg"]
            yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
            bg = 0.12 * self.paint * (1 + 0.1 * (xx / W)) * (1 + 1.0 * bg)
            vig = _vignetting(xx, yy, H, W)
            gu, gv = self.glare
            glare = 1.4 * self.paint * np.exp(-((xx - gu) ** 2 + (yy - gv) ** 2) / (2 * 22.0**2))
            self._cache["static"] = (bg.astype(np.float32), vig.astype(np.float32),
                                     glare.astype(np.float32))
        return self._cache["static"]

    def _dots(self, cam: Camera, P, N, diameter: float, out: np.ndarray, depth: float):
        """Multiply ``out`` by ``1 - depth x coverage`` of the dots (exact perspective
        ellipses, ``supersample`` x ``supersample`` sub-samples a pixel)."""
        if len(P) == 0:
            return
        H, W = out.shape
        att = np.zeros(out.shape, np.float32)
        ns = int(self.supersample)
        step = max(1, 4096 // (ns * ns))  # dots a batch: bounded memory for fine sampling
        for k in range(0, len(P), step):  # a loop over batches of dots
            self._coverage(cam, P[k:k + step], N[k:k + step], diameter, depth, att)
        out *= np.clip(1.0 - att, 0.0, 1.0)

    def _coverage(self, cam: Camera, P, N, diameter: float, depth: float, att):
        """Add ``depth x coverage`` of the dots ``P`` (normals ``N``) to ``att``."""
        uv = cam.project(P)
        C = cam.center
        H, W = att.shape
        h = int(np.ceil(0.5 * diameter * self.px_per_m)) + 2  # the major axis: diameter
        off = np.arange(-h, h + 1)
        ns = int(self.supersample)
        sub = (np.arange(ns) + 0.5) / ns - 0.5
        c0 = np.rint(uv).astype(int)
        pu = c0[:, 0, None, None, None, None] + off[None, None, :, None, None] \
            + sub[None, None, None, None, :]
        pv = c0[:, 1, None, None, None, None] + off[None, :, None, None, None] \
            + sub[None, None, None, :, None]
        pu, pv = np.broadcast_arrays(pu, pv)
        _, d = cam.rays(np.column_stack([pu.ravel(), pv.ravel()]))
        d = d.reshape(pu.shape + (3,))
        n = N[:, None, None, None, None, :]
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.einsum("k...j,k...j->k...", np.broadcast_to(n, d.shape),
                          (P - C)[:, None, None, None, None, :]) / \
                np.einsum("k...j,k...j->k...", np.broadcast_to(n, d.shape), d)
            Q = C + t[..., None] * d
            inside = np.linalg.norm(Q - P[:, None, None, None, None, :], axis=-1) \
                <= diameter / 2
        cover = inside.mean(axis=(3, 4))  # (K, 2h+1, 2h+1)
        vv = c0[:, 1, None, None] + off[None, :, None]
        uu = c0[:, 0, None, None] + off[None, None, :]
        vv, uu = np.broadcast_arrays(vv, uu)
        ok = (vv >= 0) & (vv < H) & (uu >= 0) & (uu < W) & (cover > 0)
        np.add.at(att, (vv[ok], uu[ok]), depth * cover[ok])

    @property
    def noise_sigma(self) -> float:
        """Standard deviation of the frames' white noise (counts, before the rounding to
        8 bits): the depth of a target seen face-on at the image's centre over ``snr``."""
        return float(self.target_depth * self.paint / self.snr)

    def image(self, k: int) -> np.ndarray:
        """Frame ``k``: (H, W) uint8, :meth:`render` plus white noise of
        :attr:`noise_sigma`, rounded and clipped to 0-255."""
        img = self.render(k)
        rng = np.random.default_rng([self.seed, 11, k])
        img += rng.standard_normal(img.shape, dtype=np.float32) * np.float32(self.noise_sigma)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    def render(self, k: int) -> np.ndarray:
        """Frame ``k`` without noise, before rounding: (H, W) float32 counts."""
        cam = self.camera_at(k)
        H, W = self.shape
        bg, vig, glare = self._static()
        tex = self._texture()
        # the lines of sight of the body's bounding box in the image only
        corners = np.array([[x, y, z] for x in (X_TAIL, X_NOSE)
                            for y in (-R0 - FIN_SPAN, R0 + FIN_SPAN)
                            for z in (-R0 - FIN_SPAN, R0 + FIN_SPAN)])
        cuv = cam.project(corners)
        u0, v0 = np.maximum(np.floor(np.nanmin(cuv, axis=0)).astype(int) - 3, 0)
        u1, v1 = np.minimum(np.ceil(np.nanmax(cuv, axis=0)).astype(int) + 4, (W, H))
        dirs = cam.undistortion_map().directions.reshape(H, W, 3)[v0:v1, u0:u1]
        d = dirs.reshape(-1, 3) @ cam.R  # model frame
        t, x, arc, cosine = _intersect(cam.center, d)
        hit = np.isfinite(t)
        img = bg.copy()
        box = img[v0:v1, u0:u1].reshape(-1)
        ix = (x[hit] + 0.33) / _TEXEL
        ia = arc[hit] / _TEXEL
        s = ndimage.map_coordinates(tex, [ix, ia], order=1, mode="grid-wrap")
        box[hit] = self.paint * _shading(cosine[hit]) * (1.0 + self.speckle * s)
        img[v0:v1, u0:u1] = box.reshape(v1 - v0, u1 - u0)
        vis = self.visible(k)
        self._dots(cam, self.points3d[vis], self.normals[vis], self.marker_diameter, img,
                   self.target_depth)
        tv = self.visible(k, self.tap_points, self.tap_normals)
        self._dots(cam, self.tap_points[tv], self.tap_normals[tv], self.tap_diameter, img,
                   self.tap_depth)
        return ndimage.gaussian_filter(img * vig + glare, self.blur)


def revolution_model(n_frames: int = 200, *, shape=(800, 1280), fps: float = 100.0,
                     period: int = 200, roll_deg: float = 25.0, vibration: float = 1.0,
                     marker_px: float = 5.0, tap_px: float = 2.5, speckle: float = 0.10,
                     grain: float = 2.0, snr: float = 20.0, roll0_deg: float = 0.0,
                     glare=None, rings=(10, 8, 7, 7), seed: int = 0,
                     supersample: int = 4) -> RevolutionModel:
    """The body of revolution pitching, yawing, heaving and rolling in front of a camera.

    Parameters
    ----------
    n_frames : int
    shape : (H, W)
    fps : float
        Frame rate; the vibration frequencies are 5, 7.5 and 12.5 Hz at 100 fps (scaled
        with ``fps / 100`` so that the motion stays periodic over ``period`` frames).
    period : int
        Frames per period of the motion (frame ``k`` and ``k + period`` are the same).
    roll_deg : float
        Amplitude of the roll sweep, degrees (one sweep a period).
    vibration : float
        Scale of the vibration (1: pitch 0.15 deg, yaw 0.10 deg, translation up to 0.4 mm,
        about 1-2 px at the nose).
    marker_px, tap_px : float
        Target and tap diameters on the image at the body's axis, pixels.
    speckle, grain, snr : float
        See :class:`RevolutionModel`.
    roll0_deg : float
        Roll offset of the whole run.
    rings : tuple of int
        Targets in each of the four rings on the cylinder (four more on the cone; the
        default makes 36).
    glare : (u, v), optional
        Glare centre; default on the body's upper side.
    seed : int
        Layout jitter, texture and noise seeds.
    supersample : int
        Sub-samples along a pixel's side for the dots (see :class:`RevolutionModel`).
    """
    H, W = int(shape[0]), int(shape[1])
    eye = np.array([0.0, -0.80, 0.25])
    f = 1517.0 * W / 1280.0
    K = np.array([[f, 0.0, (W - 1) / 2.0], [0.0, f, (H - 1) / 2.0], [0.0, 0.0, 1.0]])
    cam = Camera.look_at(eye, [0.01, 0.0, 0.0], [0.0, 0.0, 1.0], K=K, width=W, height=H,
                         dist=[-0.04, 0.0, 0.0, 0.0, 0.0], name="body of revolution camera")
    rng = np.random.default_rng([int(seed), 3])
    pts, nrm, tpts, tnrm = _layout(np.random.default_rng(2121), rings)
    ids = np.array([f"T{i:02d}" for i in range(len(pts))])
    px_m = f / np.linalg.norm(eye)
    n = int(n_frames)
    tt = np.arange(n) / float(fps)
    w0 = 2 * np.pi * float(fps) / period  # one period
    scale = float(fps) / 100.0
    a = float(vibration)
    ph = rng.uniform(0, 2 * np.pi, 6)
    roll = np.radians(roll0_deg + roll_deg * np.sin(w0 * tt))
    pitch = np.radians(a * (0.15 * np.sin(2 * np.pi * 5 * scale * tt + ph[0])
                            + 0.04 * np.sin(2 * np.pi * 12.5 * scale * tt + ph[1])))
    yaw = np.radians(a * 0.10 * np.sin(2 * np.pi * 7.5 * scale * tt + ph[2]))
    trans = a * np.column_stack([2e-4 * np.sin(2 * np.pi * 5 * scale * tt + ph[3]),
                                 1e-4 * np.sin(2 * np.pi * 7.5 * scale * tt + ph[4]),
                                 4e-4 * np.sin(2 * np.pi * 5 * scale * tt + ph[5])])
    if glare is None:
        glare = (W * (0.3 + 0.4 * rng.uniform()), H * 0.5 - 0.7 * R0 * px_m)
    return RevolutionModel(cam, ids, pts, nrm, tpts, tnrm, marker_px / px_m, tap_px / px_m,
                           float(fps), np.column_stack([roll, pitch, yaw]), trans,
                           speckle=float(speckle), grain=float(grain), snr=float(snr),
                           glare=tuple(float(g) for g in glare), seed=int(seed),
                           supersample=int(supersample))


def paint_frame(seed: int, *, snr: float = 20.0, shape=(800, 1280),
                speckle: float | None = None, snr_of: str = "targets"):
    """One real-looking frame for detection benchmarks, its parameters drawn from ``seed``:
    target size 4-6 px, tap size 2-3 px, speckle contrast (RMS) 5-15 %, grain 1-3 px,
    glare position and roll angle (``speckle``: a given RMS contrast instead, 0 for plain
    paint). The body carries 59 targets (rings of 18, 13, 12 and 12,
    four on the cone): 16 to 24 face the camera within 60 degrees. The dots are drawn with
    16 x 16 sub-samples a pixel (their centroids within about 0.005 px of the truth; the
    sequences' 4 x 4 leave about 0.015 px, as much as the noise's share at SNR 100).

    ``snr`` is the median, over the targets that face the camera within 60 degrees, of a
    target's depth as drawn (:meth:`RevolutionModel.drawn_depth`: shaded by the view angle
    and vignetted) over the noise's standard deviation (``snr_of="targets"``). The targets'
    own SNR then spreads about it (about 0.7 to 1.2 times). ``snr_of="face-on"``: the
    former definition, the depth of a target seen face-on at the image's centre, which
    none of the frame's targets is (their median drawn depth is 0.83 to 0.91 of it).

    Returns
    -------
    image : (H, W) uint8
    truth : (N, 2) ndarray
        True centres of the targets that face the camera within 60 degrees (pixels; beyond
        it a target is an ellipse of aspect under 1/2, counted neither found nor missed).
    diameter : float
        The targets' nominal diameter on the image, pixels.
    model : RevolutionModel
        Its ``snr`` is that of a target face-on at the image's centre (``snr`` divided by
        the median target's shading and vignetting with the default ``snr_of``).
    """
    rng = np.random.default_rng([int(seed), 99])
    d = rng.uniform(4.0, 6.0)
    model = revolution_model(1, shape=shape, marker_px=d, tap_px=rng.uniform(2.0, 3.0),
                             speckle=rng.uniform(0.05, 0.15) if speckle is None else speckle,
                             grain=rng.uniform(1.0, 3.0),
                             snr=snr, roll0_deg=rng.uniform(0, 360), roll_deg=0.0,
                             rings=(18, 13, 12, 12), seed=int(seed), supersample=16)
    keep = model.visible(0, min_cos=np.cos(np.radians(60.0)))
    if snr_of == "targets":
        face_on = model.target_depth * model.paint
        median = float(np.median(model.drawn_depth(0)[keep])) if keep.any() else face_on
        model = dataclasses.replace(model, snr=float(snr) * face_on / median)
    elif snr_of != "face-on":
        raise ValueError(f"snr_of: expected 'targets' or 'face-on', got {snr_of!r}")
    img = model.image(0)
    return img, model.uv(0)[keep], d, model


def write_sequence(model: RevolutionModel, out_dir, *, frames=None,
                   approximate_camera: bool = True, normals: bool = False) -> dict:
    """Write the frames (NPY files of uint8), the marker file (``normals``: with
    ``nx,ny,nz`` columns), the camera and the truth to ``out_dir``.

    Returns
    -------
    dict
        ``frames`` (paths), ``camera``, ``markers``, ``truth`` (paths).
    """
    from resection.io.cameras import write_camera
    from resection.io.markers import write_markers

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ks = range(model.n_frames) if frames is None else list(frames)
    paths = []
    for k in ks:
        p = out / f"frame_{k:05d}.npy"
        np.save(p, model.image(k))
        paths.append(str(p))
    cam = model.camera
    if approximate_camera:
        from scipy.spatial.transform import Rotation

        dR = Rotation.from_rotvec(np.radians([0.3, -0.3, 0.2])).as_matrix()
        cam = cam.with_pose(R=dR @ cam.R, t=cam.t + np.array([0.004, -0.003, 0.005]))
    cam_path = out / "camera.json"
    write_camera(cam_path, cam)
    m_path = out / "markers.csv"
    write_markers(m_path, model.ids, model.points3d,
                  np.full(len(model.ids), model.marker_diameter),
                  normals=model.normals if normals else None)
    t_path = out / "truth.csv"
    with open(t_path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "time", "roll_deg", "pitch_deg", "yaw_deg", "dx", "dy", "dz"])
        for k in range(model.n_frames):
            a = np.degrees(model.angles[k])
            w.writerow([k, f"{k / model.fps:.6f}", *(f"{v:.12g}" for v in a),
                        *(f"{v:.12g}" for v in model.translation[k])])
    return {"frames": paths, "camera": str(cam_path), "markers": str(m_path),
            "truth": str(t_path)}
