"""A wind-tunnel model carrying markers, moving with a known motion in front of a fixed camera.

The model is a small aircraft-like set of markers: a grid on the wing (plane ``z = 0``) and a
row on the fuselage top (``z > 0``), so that the markers are not coplanar. Over a sequence it
pitches sinusoidally about a pivot (the balance centre) and heaves slightly, as a model does on
a sting during a run (the paper's 500 frames at 50 fps). Frames are rendered with
:func:`scenes.marker_images.render_markers` (pixel-integrated, blurred, noisy disks) at the
exact projections of the markers, so that the true image positions and the true motion of
every frame are known.

Motion convention (the one :mod:`resection.sequence` reports): the laboratory frame is the
model frame at frame 0; at frame ``k`` a model point ``X`` is at ``Y = M_k X + d_k`` with
``M_k = Rz(yaw) Ry(pitch) Rx(roll)`` (right-handed rotations about the model axes, radians
in code, degrees in files) and ``d_k`` the displacement of the model origin. The fixed
camera sees ``x_cam = Rc Y + tc``, i.e. the per-frame pose ``R_k = Rc M_k``,
``t_k = Rc d_k + tc``.
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.io.cameras import write_camera
from scenes.marker_images import render_markers

__all__ = ["MovingModel", "pitch_oscillation", "write_sequence", "rotation_zyx"]


def rotation_zyx(roll, pitch, yaw) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` for arrays of angles (radians) -> (F, 3, 3),
    written out element by element (independent of scipy's Euler conventions)."""
    r, p, y = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    M = np.empty((len(r), 3, 3))
    M[:, 0, 0] = cy * cp
    M[:, 0, 1] = cy * sp * sr - sy * cr
    M[:, 0, 2] = cy * sp * cr + sy * sr
    M[:, 1, 0] = sy * cp
    M[:, 1, 1] = sy * sp * sr + cy * cr
    M[:, 1, 2] = sy * sp * cr - cy * sr
    M[:, 2, 0] = -sp
    M[:, 2, 1] = cp * sr
    M[:, 2, 2] = cp * cr
    return M


@dataclass(frozen=True)
class MovingModel:
    """A marker model, a fixed camera and a known motion over a sequence.

    Attributes
    ----------
    camera : Camera
        The fixed camera, posed on the model at rest (frame-0 model axes = laboratory).
    ids : (K,) ndarray of str
    points3d : (K, 3) ndarray
        Marker positions in model coordinates, metres.
    marker_diameter : float
        Marker diameter, metres.
    fps : float
        Frame rate, frames per second.
    angles : (F, 3) ndarray
        True ``(roll, pitch, yaw)`` of every frame relative to frame 0, radians.
    translation : (F, 3) ndarray
        True displacement ``d_k`` of the model origin, metres (laboratory axes).
    contrast, background, blur, snr, polarity :
        Rendering settings (see :func:`scenes.marker_images.render_markers`).
    seed : int
        Noise seed; frame ``k`` uses ``(seed, k)``.
    """

    camera: Camera
    ids: np.ndarray
    points3d: np.ndarray
    marker_diameter: float
    fps: float
    angles: np.ndarray
    translation: np.ndarray
    contrast: float = 400.0
    background: float = 1000.0
    blur: float = 0.7
    snr: float | None = 150.0
    polarity: str = "dark"
    seed: int = 0
    shape: tuple[int, int] = field(default=(256, 256))

    @property
    def n_frames(self) -> int:
        return len(self.angles)

    @property
    def times(self) -> np.ndarray:
        """Frame times, seconds."""
        return np.arange(self.n_frames) / self.fps

    def motion(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """``(M_k, d_k)`` of frame ``k``."""
        a = self.angles[k]
        return rotation_zyx(a[0], a[1], a[2])[0], self.translation[k].copy()

    def camera_at(self, k: int) -> Camera:
        """The camera's pose relative to the model in frame ``k``."""
        M, d = self.motion(k)
        Rc, tc = self.camera.R, self.camera.t
        return self.camera.with_pose(R=Rc @ M, t=Rc @ d + tc)

    def uv(self, k: int) -> np.ndarray:
        """True image positions of the markers in frame ``k``, pixels, (K, 2)."""
        return self.camera_at(k).project(self.points3d)

    def diameters_px(self, k: int) -> np.ndarray:
        """Apparent marker diameters in frame ``k`` (focal length x diameter / depth)."""
        cam = self.camera_at(k)
        z = cam.to_camera_frame(self.points3d)[:, 2]
        return float(cam.K[0, 0]) * self.marker_diameter / z

    def image(self, k: int) -> np.ndarray:
        """Render frame ``k`` (float32)."""
        rng = np.random.default_rng([self.seed, k])
        return render_markers(
            self.shape, self.uv(k), self.diameters_px(k), contrast=self.contrast,
            background=self.background, polarity=self.polarity, blur=self.blur,
            snr=self.snr, rng=rng,
        )


def _model_markers() -> tuple[np.ndarray, np.ndarray]:
    """Wing grid (z = 0) plus fuselage-top row (z > 0), metres; ids 'W..' and 'F..'."""
    xs = np.array([-0.09, -0.045, 0.0, 0.045, 0.09])
    ys = np.array([-0.15, -0.09, -0.03, 0.03, 0.09, 0.15])
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    # an irregular layout, as painted by hand: a regular lattice would let a shift by one
    # lattice step explain most markers (an ambiguous match); fixed jitter, same every call
    jit = np.random.default_rng(143).uniform(-0.014, 0.014, (gx.size, 2))
    wing = np.column_stack([gx.ravel() + jit[:, 0], gy.ravel() + jit[:, 1], np.zeros(gx.size)])
    fx = np.array([-0.18, -0.13, 0.15, 0.20])
    fus = np.column_stack([fx, np.zeros(fx.size), 0.035 + 0.1 * np.abs(fx) ** 2])
    pts = np.vstack([wing, fus])
    ids = np.array([f"W{i:02d}" for i in range(len(wing))] + [f"F{i}" for i in range(len(fus))])
    return ids, pts


def pitch_oscillation(
    n_frames: int = 500,
    *,
    fps: float = 50.0,
    amplitude_deg: float = 2.0,
    frequency_hz: float = 1.0,
    heave: float = 0.002,
    roll_deg: float = 0.3,
    pivot=(0.04, 0.0, 0.0),
    shape: tuple[int, int] = (256, 256),
    focal_px: float | None = None,
    marker_diameter: float = 0.010,
    snr: float | None = 150.0,
    seed: int = 0,
) -> MovingModel:
    """A model pitching sinusoidally about a pivot, with a small heave and roll.

    ``pitch(t) = A sin(2 pi f t)``, ``roll(t) = r sin(2 pi 0.5 f t)``,
    ``heave(t) = h (1 - cos(2 pi f t))`` along ``z``; frame 0 is the rest position. The
    camera looks down on the wing obliquely from about 0.95 m, its focal length chosen so
    that the model fills most of the ``shape`` image.

    Returns
    -------
    MovingModel
    """
    n = int(n_frames)
    if n < 1:
        raise InputError(f"n_frames: must be >= 1, got {n_frames}")
    H, W = int(shape[0]), int(shape[1])
    f = float(focal_px) if focal_px is not None else 2.0 * max(H, W)
    K = np.array([[f, 0.0, (W - 1) / 2.0], [0.0, f, (H - 1) / 2.0], [0.0, 0.0, 1.0]])
    eye = np.array([0.44, -0.44, 0.66])
    cam = Camera.look_at(eye, [0.0, 0.0, 0.02], [1.0, 0.0, 0.0], K=K, width=W, height=H,
                         dist=[-0.05, 0.0, 0.0, 0.0, 0.0], name="fixed tunnel camera")
    ids, pts = _model_markers()
    t = np.arange(n) / float(fps)
    w = 2.0 * np.pi * float(frequency_hz)
    pitch = np.radians(amplitude_deg) * np.sin(w * t)
    roll = np.radians(roll_deg) * np.sin(0.5 * w * t)
    yaw = np.zeros(n)
    angles = np.column_stack([roll, pitch, yaw])
    Ms = rotation_zyx(roll, pitch, yaw)
    p = np.asarray(pivot, dtype=float)
    hv = np.zeros((n, 3))
    hv[:, 2] = heave * (1.0 - np.cos(w * t))
    d = p[None, :] - Ms @ p + hv  # rotation about the pivot, then heave
    model = MovingModel(cam, ids, pts, float(marker_diameter), float(fps), angles, d,
                        snr=snr, seed=int(seed), shape=(H, W))
    uv0 = model.uv(0)
    if not np.all(cam.in_image(uv0, margin=8)):
        raise InputError("pitch_oscillation: markers fall outside the image; change shape/focal_px")
    return model


def write_sequence(
    model: MovingModel,
    out_dir: str | os.PathLike,
    *,
    frames=None,
    fmt: str = "npy",
    approximate_camera: bool = True,
) -> dict:
    """Write the frames, the marker file, the camera file and the truth to ``out_dir``.

    Parameters
    ----------
    model : MovingModel
    out_dir : path-like
        Created if missing.
    frames : iterable of int, optional
        Which frames to write (default all).
    fmt : {"npy", "tif", "png"}
        Frame file format (PNG rounds to 16-bit integers).
    approximate_camera : bool
        Write a camera whose pose is perturbed (about 0.5 degree, 1 cm) from the frame-0 truth,
        as a user's approximate camera would be; otherwise the exact frame-0 camera.

    Returns
    -------
    dict
        ``frames`` (list of paths), ``camera`` (path), ``markers`` (path), ``truth`` (path
        of a CSV with frame, time, roll/pitch/yaw in degrees and dx, dy, dz in metres).
    """
    from resection.io.images import write_image
    from resection.io.markers import write_markers

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ks = range(model.n_frames) if frames is None else list(frames)
    paths = []
    for k in ks:  # one frame at a time (each frame's rendering is vectorised)
        p = out / f"frame_{k:05d}.{fmt}"
        img = model.image(k)
        if fmt == "png":
            write_image(p, np.clip(img, 0, 65535), dtype=np.uint16)
        else:
            write_image(p, img)
        paths.append(str(p))
    cam = model.camera
    if approximate_camera:
        from scipy.spatial.transform import Rotation

        dR = Rotation.from_rotvec(np.radians([0.3, -0.4, 0.25])).as_matrix()
        cam = cam.with_pose(R=dR @ cam.R, t=cam.t + np.array([0.005, -0.004, 0.006]))
    cam_path = out / "camera.json"
    write_camera(cam_path, cam)
    m_path = out / "markers.csv"
    write_markers(m_path, model.ids, model.points3d,
                  np.full(len(model.ids), model.marker_diameter))
    t_path = out / "truth.csv"
    with open(t_path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["frame", "time", "roll_deg", "pitch_deg", "yaw_deg", "dx", "dy", "dz"])
        for k in range(model.n_frames):
            a = np.degrees(model.angles[k])
            w.writerow([k, f"{model.times[k]:.6f}", *(f"{v:.12g}" for v in a),
                        *(f"{v:.12g}" for v in model.translation[k])])
    return {"frames": paths, "camera": str(cam_path), "markers": str(m_path),
            "truth": str(t_path)}
