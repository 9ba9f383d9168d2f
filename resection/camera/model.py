"""The camera model: pinhole + Brown-Conrady distortion + out-of-focus, and its pose.

Conventions (see docs/design.md):

* Camera frame as in OpenCV: x right, y down, z forward; ``x_cam = R @ X + t``.
* Pixel coordinates ``(u, v)``: u = column to the right, v = row down, the *centre* of the
  top-left pixel is ``(0, 0)``; image arrays are indexed ``img[v, u]``.
* ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` (skew ``s`` is normally 0), distortion
  ``dist = [k1, k2, p1, p2, k3]`` (OpenCV order) applied to the normalised coordinates
  ``x/z, y/z``.
* Model units are those of the mesh and markers (metres by default).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from resection._checks import as_matrix, as_points, json_array, json_number
from resection.camera.distortion import (  # re-exported: the camera model's functions
    distort_normalized,
    max_monotonic_radius,
    undistort_normalized,
)
from resection.camera.rotation import matrix_to_rotvec, rotvec_to_matrix
from resection.errors import InputError

__all__ = [
    "Camera",
    "project_with_poses",
    "distort_normalized",
    "undistort_normalized",
    "max_monotonic_radius",
    "effective_focal_length",
]

#: Largest focal length accepted, in multiples of the image's larger side (a field of view of
#: about a microradian; a real lens stays under 100).
MAX_FOCAL_PER_PIXEL = 1e6

_REQUIRED_KEYS = ("width", "height", "K", "dist", "R", "t")
_OPTIONAL_KEYS = ("oof", "name")




def effective_focal_length(
    lens_focal_length: float, focus_distance: float, stop_distance: float
) -> float:
    """Effective focal length of a lens focused at a finite distance (out-of-focus model).

    A thin lens of focal length ``f`` focused at object distance ``s`` forms its image at
    ``v = f s / (s - f)``. With the aperture stop at distance ``d`` from the optical centre,
    the projection centre is the entrance pupil and the effective focal length
    (pupil-to-sensor distance seen through the lens) is

    ``M = v + d (1 - v / f) = f (s - d) / (s - f)``.

    ``d = 0`` gives the classical ``M = v``; ``d = f`` (stop at the front focal point, an
    image-space telecentric lens) gives ``M = f`` at every focus.

    Parameters
    ----------
    lens_focal_length, focus_distance, stop_distance : float
        ``f``, ``s`` and ``d``, all in the same length unit; ``s > f``.
    """
    f, s, d = float(lens_focal_length), float(focus_distance), float(stop_distance)
    if not (np.isfinite(f) and np.isfinite(s) and np.isfinite(d)) or f <= 0:
        raise InputError("effective_focal_length: f, s, d must be finite and f > 0")
    if s <= f:
        raise InputError(
            f"effective_focal_length: focus distance {s} must exceed the focal length {f}"
        )
    return f * (s - d) / (s - f)


# --------------------------------------------------------------------------- the camera
@dataclass(frozen=True)
class Camera:
    """A calibrated camera and its Point of View.

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    K : (3, 3) ndarray
        Intrinsic matrix, pixels.
    dist : (5,) ndarray
        ``[k1, k2, p1, p2, k3]`` on normalised coordinates.
    R : (3, 3) ndarray
        Rotation model -> camera (``x_cam = R @ X + t``).
    t : (3,) ndarray
        Translation, model units.
    oof : float or None
        Out-of-focus parameter: distance ``d`` of the aperture stop from the lens' optical
        centre, model units (see :func:`effective_focal_length` and :meth:`refocus`).
    name : str or None
        Free label.
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    oof: float | None = None
    name: str | None = None

    def __post_init__(self):
        try:
            if any(isinstance(v, (bool, str, bytes)) for v in (self.width, self.height)):
                raise TypeError
            w, h = int(self.width), int(self.height)
        except (TypeError, ValueError, OverflowError):
            raise InputError(
                f"camera: width/height must be integers, got {self.width!r}, {self.height!r}"
            ) from None
        if w != self.width or h != self.height or w <= 0 or h <= 0:
            raise InputError(
                f"camera: width/height must be positive integers, got {self.width}, {self.height}"
            )
        K = as_matrix(self.K, (3, 3), "camera K")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"camera K: focal lengths must be positive, got {K[0, 0]}, {K[1, 1]}")
        if max(K[0, 0], K[1, 1]) > MAX_FOCAL_PER_PIXEL * max(w, h):
            raise InputError(f"camera K: focal lengths {K[0, 0]:g}, {K[1, 1]:g} px are beyond "
                             f"{MAX_FOCAL_PER_PIXEL:g} times the image size (a field of view "
                             "under a microradian: wrong units?)")
        if K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise InputError("camera K: must be upper triangular with K[2,2] = 1")
        try:
            dist = np.asarray(self.dist, dtype=np.float64).ravel()
        except (TypeError, ValueError) as exc:
            raise InputError(f"camera dist: not a numeric array ({exc})") from None
        if dist.shape != (5,):
            raise InputError(f"camera dist: expected 5 values [k1,k2,p1,p2,k3], got {dist.size}")
        if not np.all(np.isfinite(dist)):
            raise InputError("camera dist: contains NaN or infinite values")
        R = as_matrix(self.R, (3, 3), "camera R")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise InputError("camera R: not a rotation matrix (R R^T != I or det(R) < 0)")
        t = as_matrix(self.t, np.shape(self.t), "camera t").ravel()
        if t.shape != (3,):
            raise InputError(f"camera t: expected 3 values, got shape {np.shape(self.t)}")
        oof = self.oof
        if oof is not None:
            try:
                if isinstance(oof, (str, bytes, bool)):
                    raise TypeError
                oof = float(oof)
            except (TypeError, ValueError):
                raise InputError(f"camera oof: must be a number, got {self.oof!r}") from None
            if not np.isfinite(oof):
                raise InputError("camera oof: must be finite")
        if self.name is not None and not isinstance(self.name, str):
            raise InputError(f"camera name: must be a string, got {self.name!r}")
        for attr, val in (("width", w), ("height", h), ("K", K), ("dist", dist), ("R", R),
                          ("t", t), ("oof", oof)):
            if isinstance(val, np.ndarray):
                val = val.copy()  # never freeze (or alias) the caller's array
                val.setflags(write=False)
            object.__setattr__(self, attr, val)

    # ------------------------------------------------------------------ derived quantities
    @property
    def center(self) -> np.ndarray:
        """Perspective centre in model coordinates, ``C = -R^T t``."""
        return -self.R.T @ self.t

    @property
    def rvec(self) -> np.ndarray:
        """Rotation vector (axis * angle, radians) of ``R``, as OpenCV's Rodrigues."""
        return matrix_to_rotvec(self.R)

    @property
    def P(self) -> np.ndarray:
        """The 3x4 projection matrix ``K [R | t]`` (no distortion)."""
        return self.K @ np.column_stack([self.R, self.t])

    @property
    def image_size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return self.width, self.height

    @property
    def max_radius(self) -> float:
        """See :func:`max_monotonic_radius`."""
        return max_monotonic_radius(self.dist)

    def replace(self, **changes) -> Camera:
        """A copy with some attributes changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def with_pose(self, R=None, t=None, *, rvec=None) -> Camera:
        """A copy with another pose, given as ``R`` or ``rvec``, and ``t``."""
        if rvec is not None:
            rv = as_matrix(np.asarray(rvec, dtype=float).ravel(), (3,), "rvec")
            R = rotvec_to_matrix(rv)
        new = self.replace(R=self.R if R is None else R, t=self.t if t is None else t)
        # same intrinsics, same lines of sight: the copy shares this camera's cache
        object.__setattr__(new, "_icache", self._intrinsics_cache())
        return new

    def _intrinsics_cache(self) -> dict:
        """Per-instance store of what depends on the intrinsics only (shared with the
        :meth:`with_pose` copies)."""
        cache = self.__dict__.get("_icache")
        if cache is None:
            cache = {}
            object.__setattr__(self, "_icache", cache)
        return cache

    def undistortion_map(self):
        """Lines of sight of every pixel centre, camera frame
        (:class:`resection.camera.undistortion.UndistortionMap`), computed on first use and kept
        on this instance (and shared with the copies :meth:`with_pose` makes)."""
        cache = self._intrinsics_cache()
        if "undistortion" not in cache:
            from resection.camera.undistortion import undistortion_map

            cache["undistortion"] = undistortion_map(self)
        return cache["undistortion"]

    def __getstate__(self):  # pickles (Dask) carry the camera, not the cached map
        state = dict(self.__dict__)
        state.pop("_icache", None)
        return state

    # ------------------------------------------------------------------ projection
    def to_camera_frame(self, points: np.ndarray) -> np.ndarray:
        """Model points ``(N, 3)`` to the camera frame ``R X + t``."""
        X = as_points(points, 3, "points")
        return X @ self.R.T + self.t

    def project(self, points, *, return_valid: bool = False):
        """Project model points to pixel coordinates, with distortion.

        Parameters
        ----------
        points : (N, 3) array_like
            Model coordinates.
        return_valid : bool
            Also return the validity mask.

        Returns
        -------
        uv : (N, 2) ndarray
            Pixel coordinates (pixel centres at integers). Rows of points that cannot be
            projected are NaN: points on or behind the camera plane (``z <= 0``), and points
            beyond the radius where the distortion polynomial stops being monotonic
            (:attr:`max_radius`), which a real lens would not image there.
        valid : (N,) bool ndarray, only if ``return_valid``
            False for the NaN rows.
        """
        Xc = self.to_camera_frame(points)
        z = Xc[:, 2]
        valid = z > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = Xc[:, :2] / np.where(valid, z, np.nan)[:, None]
        r = np.hypot(xy[:, 0], xy[:, 1])
        valid &= r <= self.max_radius
        uv = self.normalized_to_pixels(distort_normalized(xy, self.dist))
        uv[~valid] = np.nan
        return (uv, valid) if return_valid else uv

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Normalised (already distorted) coordinates to pixels through ``K``."""
        K = self.K
        u = K[0, 0] * xy[:, 0] + K[0, 1] * xy[:, 1] + K[0, 2]
        v = K[1, 1] * xy[:, 1] + K[1, 2]
        return np.column_stack([u, v])

    def pixels_to_normalized(self, uv: np.ndarray) -> np.ndarray:
        """Pixels to normalised coordinates through ``K^-1`` (no undistortion)."""
        K = self.K
        y = (uv[:, 1] - K[1, 2]) / K[1, 1]
        x = (uv[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
        return np.column_stack([x, y])

    def distort(self, uv) -> np.ndarray:
        """Ideal (pinhole) pixel coordinates -> distorted pixel coordinates (as imaged)."""
        uv = as_points(uv, 2, "uv", allow_nan=True)
        return self.normalized_to_pixels(
            distort_normalized(self.pixels_to_normalized(uv), self.dist)
        )

    def undistort(self, uv) -> np.ndarray:
        """Distorted (imaged) pixel coordinates -> ideal pinhole pixel coordinates.

        Points outside the monotonic range of the distortion come back as NaN.
        """
        uv = as_points(uv, 2, "uv", allow_nan=True)
        return self.normalized_to_pixels(
            undistort_normalized(self.pixels_to_normalized(uv), self.dist)
        )

    def rays(self, uv=None) -> tuple[np.ndarray, np.ndarray]:
        """Lines of sight through image points.

        Parameters
        ----------
        uv : (N, 2) array_like, optional
            Pixel coordinates as imaged (distorted). None: every pixel centre of the image,
            row-major (``v * W + u``), from the :meth:`undistortion_map` computed once.

        Returns
        -------
        origins : (N, 3) ndarray
            The perspective centre, repeated (model frame); a read-only broadcast view when
            ``uv`` is None.
        directions : (N, 3) ndarray
            Unit directions in the model frame (NaN where the pixel cannot be undistorted).
        """
        if uv is None:
            d = self.undistortion_map().rays(self.R)
            return np.broadcast_to(self.center, d.shape), d
        uv = as_points(uv, 2, "uv", allow_nan=True)
        xy = undistort_normalized(self.pixels_to_normalized(uv), self.dist)
        d_cam = np.column_stack([xy, np.ones(len(xy))])
        d = d_cam @ self.R  # R^T d_cam for every row
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.center, d.shape).copy(), d

    def in_image(self, uv, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixel coordinates that fall on the sensor (pixel edges at
        ``-0.5`` and ``W - 0.5``), at least ``margin`` pixels inside."""
        uv = as_points(uv, 2, "uv", allow_nan=True)
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + margin)
                & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin)
                & (uv[:, 1] <= self.height - 0.5 - margin)
            )

    # ------------------------------------------------------------------ focus
    def refocus(
        self, focus_distance: float, *, calibrated_focus: float, lens_focal_length: float
    ) -> Camera:
        """The same camera refocused from ``calibrated_focus`` to ``focus_distance``.

        The focal lengths ``fx, fy`` scale by ``M(s_new) / M(s_cal)`` with ``M`` from
        :func:`effective_focal_length` and ``d = self.oof``. The principal point,
        distortion and pose are kept (the projection centre is the entrance pupil, which
        does not move relative to the lens mount in this model).

        Parameters
        ----------
        focus_distance, calibrated_focus : float
            Object distances the lens is focused at, model units.
        lens_focal_length : float
            Nominal focal length ``f`` of the lens, model units.
        """
        if self.oof is None:
            raise InputError("refocus: the camera has no out-of-focus parameter 'oof'")
        ratio = effective_focal_length(
            lens_focal_length, focus_distance, self.oof
        ) / effective_focal_length(lens_focal_length, calibrated_focus, self.oof)
        K = np.array(self.K)
        K[0, :2] *= ratio
        K[1, 1] *= ratio
        return self.replace(K=K)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_fov(
        cls,
        hfov: float,
        vfov: float,
        width: int,
        height: int,
        *,
        R=None,
        t=None,
        dist=None,
        **kwargs,
    ) -> Camera:
        """Camera from the field-of-view form ``(hF, vF, W, H)``.

        ``hfov`` and ``vfov`` are the full horizontal and vertical fields of view in
        **degrees**, measured between the outer edges of the sensor. The principal point is
        the image centre ``((W - 1) / 2, (H - 1) / 2)``.
        """
        for nm, val in (("hfov", hfov), ("vfov", vfov)):
            if not (np.isfinite(val) and 0 < val < 180):
                raise InputError(f"from_fov: {nm} must be in (0, 180) degrees, got {val}")
        fx = (width / 2.0) / math.tan(math.radians(hfov) / 2.0)
        fy = (height / 2.0) / math.tan(math.radians(vfov) / 2.0)
        K = [[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]]
        return cls(
            width, height, K,
            np.zeros(5) if dist is None else dist,
            np.eye(3) if R is None else R,
            np.zeros(3) if t is None else t,
            **kwargs,
        )

    def fov(self) -> tuple[float, float]:
        """Full horizontal and vertical fields of view, degrees (pinhole, no distortion)."""
        return (
            math.degrees(2.0 * math.atan(self.width / 2.0 / self.K[0, 0])),
            math.degrees(2.0 * math.atan(self.height / 2.0 / self.K[1, 1])),
        )

    @classmethod
    def look_at(
        cls, eye, target, up, *, K, width: int, height: int, dist=None, **kwargs
    ) -> Camera:
        """Camera at ``eye`` looking at ``target`` with ``up`` pointing up in the image
        (model coordinates)."""
        eye = as_matrix(np.asarray(eye, float).ravel(), (3,), "eye")
        target = as_matrix(np.asarray(target, float).ravel(), (3,), "target")
        up = as_matrix(np.asarray(up, float).ravel(), (3,), "up")
        z = target - eye
        # coincident up to rounding (relative 1e-12): no viewing direction
        if np.linalg.norm(z) <= 1e-12 * max(np.linalg.norm(eye), np.linalg.norm(target)):
            raise InputError("look_at: eye and target coincide")
        z /= np.linalg.norm(z)
        y = -(up - np.dot(up, z) * z)
        if np.linalg.norm(y) < 1e-12:
            raise InputError("look_at: up is parallel to the viewing direction")
        y /= np.linalg.norm(y)
        x = np.cross(y, z)
        R = np.vstack([x, y, z])
        return cls(width, height, K, np.zeros(5) if dist is None else dist, R, -R @ eye,
                   **kwargs)

    # ------------------------------------------------------------------ OpenCV
    @classmethod
    def from_opencv(
        cls, camera_matrix, dist_coeffs, rvec, tvec, width: int, height: int, **kwargs
    ) -> Camera:
        """From OpenCV's ``cameraMatrix, distCoeffs, rvec, tvec``.

        ``distCoeffs`` may have 4, 5 or more entries; beyond 5 they must be zero (the
        rational and thin-prism models are not part of this camera model).
        """
        d = np.asarray(dist_coeffs, dtype=np.float64).ravel()
        if d.size in (1, 2, 3):
            raise InputError(f"from_opencv: expected 4, 5 or more distortion coefficients "
                             f"(OpenCV order k1, k2, p1, p2[, k3, ...]), got {d.size}")
        if d.size not in (0, 4, 5) and not (d.size > 5 and np.all(d[5:] == 0)):
            raise InputError(
                f"from_opencv: {d.size} distortion coefficients with non-zero terms beyond k3 "
                "are not supported"
            )
        dist = np.zeros(5)
        dist[: min(5, d.size)] = d[:5]
        rv = as_matrix(np.asarray(rvec, dtype=float).ravel(), (3,), "rvec")
        tv = as_matrix(np.asarray(tvec, dtype=float).ravel(), (3,), "tvec")
        return cls(width, height, camera_matrix, dist, rotvec_to_matrix(rv), tv,
                   **kwargs)

    def to_opencv(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(cameraMatrix, distCoeffs, rvec, tvec)`` as OpenCV expects them."""
        return (np.array(self.K), np.array(self.dist), self.rvec.reshape(3, 1),
                np.array(self.t).reshape(3, 1))

    # ------------------------------------------------------------------ files
    def to_dict(self) -> dict:
        """The DESIGN camera-file dictionary (JSON-serialisable)."""
        d = {
            "width": self.width,
            "height": self.height,
            "K": np.asarray(self.K).tolist(),
            "dist": np.asarray(self.dist).tolist(),
            "R": np.asarray(self.R).tolist(),
            "t": np.asarray(self.t).tolist(),
        }
        if self.oof is not None:
            d["oof"] = self.oof
        if self.name is not None:
            d["name"] = self.name
        return d

    @classmethod
    def from_dict(cls, d: dict, *, source: str = "camera") -> Camera:
        """From the DESIGN camera-file dictionary. Unknown or missing keys are errors."""
        if not isinstance(d, dict):
            raise InputError(f"{source}: expected a JSON object, got {type(d).__name__}")
        unknown = sorted(set(d) - set(_REQUIRED_KEYS) - set(_OPTIONAL_KEYS))
        if unknown:
            raise InputError(
                f"{source}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: "
                f"{', '.join(_REQUIRED_KEYS + _OPTIONAL_KEYS)}"
            )
        missing = [k for k in _REQUIRED_KEYS if k not in d]
        if missing:
            raise InputError(f"{source}: missing key(s) {', '.join(map(repr, missing))}")
        try:
            for k in ("width", "height"):
                v = d[k]
                if isinstance(v, bool) or not isinstance(v, int):
                    raise InputError(f"camera width/height: {k} must be an integer, got {v!r}")
            # types first (a string or a boolean is never read as a number), then the
            # constructor checks the shapes and values
            K, dist, R, t = (json_array(d[k], None, f"camera {k}") for k in ("K", "dist", "R", "t"))
            for k, arr in (("dist", dist), ("t", t)):
                if arr.ndim != 1:
                    raise InputError(f"camera {k}: expected a flat list, got shape "
                                     f"{'x'.join(map(str, arr.shape))}")
            oof = d.get("oof")
            if oof is not None:
                oof = json_number(oof, "camera oof")
            return cls(d["width"], d["height"], K, dist, R, t, oof=oof, name=d.get("name"))
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def __eq__(self, other) -> bool:  # arrays make the dataclass default useless
        if not isinstance(other, Camera):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # type: ignore[assignment]


def project_with_poses(camera: Camera, R, t, points3d, *,
                       max_radius: float | None = None) -> np.ndarray:
    """Pixel positions ``(P, N, 2)`` of ``N`` model points under ``P`` poses at once (the
    rotations ``R`` (P, 3, 3) and translations ``t`` (P, 3)), with ``camera``'s intrinsics
    and distortion, as :meth:`Camera.project`: NaN behind the camera or beyond the
    distortion's monotonic radius (``camera.max_radius`` unless given: it costs a
    polynomial root finding, worth passing when projecting often)."""
    R = np.asarray(R, float).reshape(-1, 3, 3)
    t = np.asarray(t, float).reshape(-1, 3)
    X = np.asarray(points3d, float).reshape(-1, 3)
    Xc = np.einsum("pij,nj->pni", R, X) + t[:, None, :]
    z = Xc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = Xc[..., :2] / np.where(z > 0, z, np.nan)[..., None]
    rmax = camera.max_radius if max_radius is None else max_radius
    bad = np.hypot(xy[..., 0], xy[..., 1]) > rmax
    xy = distort_normalized(xy.reshape(-1, 2), camera.dist).reshape(xy.shape)
    K = camera.K
    u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
    v = K[1, 1] * xy[..., 1] + K[1, 2]
    uv = np.stack([u, v], axis=-1)
    uv[bad] = np.nan
    return uv
