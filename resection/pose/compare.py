"""Two cameras of the same view compared: a new pose against an older calibration.

:func:`compare_cameras` projects the same model points (the targets, the grid's nodes)
through both cameras and measures how far apart they land, in pixels, and how far apart the
cameras are: the distance between their perspective centres (model units) and the angle of
the rotation that takes one camera's axes to the other's (degrees), with the intrinsics'
differences.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError

__all__ = ["CameraComparison", "PointSpread", "compare_cameras", "rotation_angle_deg"]


@dataclass(frozen=True)
class PointSpread:
    """Pixel distances of one set of points projected through both cameras.

    Attributes
    ----------
    name : str
    n : int
        Points that land in the image of either camera (in front of both).
    mean, largest : float
        Mean and largest distance between the two projections, pixels (NaN when n = 0).
    worst : str or int
        The point of the largest distance (an id, or a node number).
    """

    name: str
    n: int
    mean: float
    largest: float
    worst: str | int | None

    def line(self) -> str:
        if self.n == 0:
            return f"{self.name}: none in view of either camera"
        return (f"{self.name}: {self.n} in view, {self.mean:.3f} px apart on average, "
                f"{self.largest:.3f} px at most ({self.worst})")


@dataclass(frozen=True)
class CameraComparison:
    """Result of :func:`compare_cameras`.

    Attributes
    ----------
    centre_a, centre_b : (3,) float64
        Perspective centres, model units.
    centre_distance : float
        ``|centre_b - centre_a|``, model units.
    rotation_deg : float
        Angle of ``R_b R_a^T``, degrees (0: the same orientation).
    focal_change : (2,) float64
        ``fx, fy`` of b less those of a, pixels.
    principal_change : (2,) float64
        ``cx, cy`` of b less those of a, pixels.
    spreads : tuple of PointSpread
        One per point set.
    """

    centre_a: np.ndarray
    centre_b: np.ndarray
    centre_distance: float
    rotation_deg: float
    focal_change: np.ndarray
    principal_change: np.ndarray
    spreads: tuple

    def report(self, names=("A", "B")) -> str:
        a, b = names
        c_a = ", ".join(f"{x:.4g}" for x in self.centre_a)
        c_b = ", ".join(f"{x:.4g}" for x in self.centre_b)
        lines = [
            f"centres: {a} ({c_a}), {b} ({c_b}): {self.centre_distance:.4g} apart "
            "(model units)",
            f"rotation apart: {self.rotation_deg:.4f} deg",
            f"focal length change fx, fy: {self.focal_change[0]:+.3f}, "
            f"{self.focal_change[1]:+.3f} px; principal point change cx, cy: "
            f"{self.principal_change[0]:+.3f}, {self.principal_change[1]:+.3f} px",
        ]
        return "\n".join(lines + [s.line() for s in self.spreads])


def rotation_angle_deg(Ra, Rb) -> float:
    """Angle of the rotation ``Rb Ra^T``, degrees (stable near 0 and 180)."""
    D = np.asarray(Rb, float) @ np.asarray(Ra, float).T
    s = np.linalg.norm([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]]) / 2.0
    c = (np.trace(D) - 1.0) / 2.0
    return float(np.degrees(np.arctan2(s, c)))


def _spread(name, a: Camera, b: Camera, points, labels) -> PointSpread:
    uv_a, ok_a = a.project(points, return_valid=True)
    uv_b, ok_b = b.project(points, return_valid=True)
    both = ok_a & ok_b
    seen = both & (a.in_image(uv_a) | b.in_image(uv_b))
    if not seen.any():
        return PointSpread(name, 0, float("nan"), float("nan"), None)
    d = np.linalg.norm(uv_b[seen] - uv_a[seen], axis=1)
    k = int(np.argmax(d))
    worst = labels[np.flatnonzero(seen)[k]]
    return PointSpread(name, int(seen.sum()), float(d.mean()), float(d[k]),
                       worst.item() if isinstance(worst, np.generic) else worst)


def compare_cameras(a: Camera, b: Camera, point_sets=()) -> CameraComparison:
    """Compare camera ``b`` with camera ``a``.

    Parameters
    ----------
    a, b : Camera
        The same image size.
    point_sets : sequence of (name, (N, 3) points, (N,) labels)
        Model points to project through both (e.g. the targets with their ids, the
        grid's nodes with their numbers); a point counts when it is in front of both
        cameras and lands in the image of either.

    Returns
    -------
    CameraComparison

    Raises
    ------
    InputError
        Cameras of different image sizes.
    """
    if (a.width, a.height) != (b.width, b.height):
        raise InputError(f"the cameras' images differ: {a.width}x{a.height} and "
                         f"{b.width}x{b.height}")
    spreads = tuple(_spread(name, a, b, np.asarray(p, float), np.asarray(lab))
                    for name, p, lab in point_sets)
    ca, cb = np.asarray(a.center, float), np.asarray(b.center, float)
    return CameraComparison(
        centre_a=ca, centre_b=cb, centre_distance=float(np.linalg.norm(cb - ca)),
        rotation_deg=rotation_angle_deg(a.R, b.R),
        focal_change=np.array([b.K[0, 0] - a.K[0, 0], b.K[1, 1] - a.K[1, 1]]),
        principal_change=np.array([b.K[0, 2] - a.K[0, 2], b.K[1, 2] - a.K[1, 2]]),
        spreads=spreads)
