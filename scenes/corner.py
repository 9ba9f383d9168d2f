"""The self-illumination corner: two square painted plates meeting at 90 degrees.

Geometry (model units): the *floor* ``z = 0``, ``0 <= x, y <= size``, painted side ``+z``;
the *wall* ``x = 0``, ``0 <= y, z <= size``, painted side ``+x``. They share the edge
``x = z = 0``. Each plate is a ``resolution x resolution`` grid of squares, each split
into two triangles, so the mesh has ``4 * resolution**2`` faces; floor faces come first.

Near the corner each plate sees the other over about half of its hemisphere, so with a
reflectance of 0.6 about 30% of the light leaving a face next to the corner is
self-illumination (the paper's order of magnitude).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from resection.errors import InputError

__all__ = ["CornerScene", "corner", "corner_profile_line", "DEFAULT_REFLECTANCE"]

#: Reflectance giving about 30% self-illumination next to the corner.
DEFAULT_REFLECTANCE = 0.6


@dataclass(frozen=True)
class CornerScene:
    """The corner case.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Both plates, ``4 * resolution**2`` faces, floor faces first.
    emission : (N,) ndarray
        True emitted exitance per face (arbitrary units).
    reflectance : float
        Diffuse reflectance of the paint.
    plate : (N,) ndarray of int
        0 for floor faces, 1 for wall faces.
    size : float
        Side of each plate (model units).
    resolution : int
        Squares along each side of a plate.
    """

    mesh: trimesh.Trimesh
    emission: np.ndarray
    reflectance: float
    plate: np.ndarray
    size: float
    resolution: int


def _plate(n: int, size: float, e1: np.ndarray, e2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid of ``n x n`` squares spanned by ``size * e1``, ``size * e2`` from the origin,
    normal ``e1 x e2``."""
    s = np.linspace(0.0, size, n + 1)
    uu, vv = np.meshgrid(s, s, indexing="ij")
    vertices = uu.reshape(-1, 1) * e1 + vv.reshape(-1, 1) * e2
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)])
    return vertices, faces


def corner(
    size: float = 1.0,
    resolution: int = 40,
    reflectance: float = DEFAULT_REFLECTANCE,
    pattern: str = "smooth",
) -> CornerScene:
    """Build the corner scene.

    Parameters
    ----------
    size : float
        Side of each square plate (model units, > 0).
    resolution : int
        Squares along a side (>= 1); the mesh has ``4 * resolution**2`` triangles.
    reflectance : float
        Diffuse reflectance in ``[0, 1)``.
    pattern : {"smooth", "uniform"}
        True emission: ``"uniform"`` is 1 everywhere; ``"smooth"`` is
        ``1 + 0.3 cos(pi s / size) + 0.15 sin(2 pi y / size)`` with ``s`` the signed
        distance from the corner along the surface (``-x`` on the floor, ``+z`` on the
        wall), like a pressure field varying across the corner.

    Returns
    -------
    CornerScene
    """
    try:
        size = float(size)
        res = int(resolution)
    except (TypeError, ValueError):
        raise InputError("corner: size must be a number and resolution an integer") from None
    if not (np.isfinite(size) and size > 0):
        raise InputError(f"corner: size must be a positive number, got {size}")
    if res != resolution or res < 1:
        raise InputError(f"corner: resolution must be a positive integer, got {resolution!r}")
    if not (0.0 <= float(reflectance) < 1.0):
        raise InputError(f"corner: reflectance must lie in [0, 1), got {reflectance}")
    ex, ey, ez = np.eye(3)
    v_floor, f_floor = _plate(res, size, ex, ey)  # normal ex x ey = +z
    v_wall, f_wall = _plate(res, size, ey, ez)  # normal ey x ez = +x
    mesh = trimesh.Trimesh(
        np.vstack([v_floor, v_wall]),
        np.vstack([f_floor, f_wall + len(v_floor)]),
        process=False,
    )
    # merge the shared edge so that the two plates are one connected surface
    mesh.merge_vertices()
    plate = np.repeat([0, 1], len(f_floor))
    c = np.asarray(mesh.triangles_center)
    s = np.where(plate == 0, -c[:, 0], c[:, 2])
    if pattern == "smooth":
        e = 1.0 + 0.3 * np.cos(np.pi * s / size) + 0.15 * np.sin(2.0 * np.pi * c[:, 1] / size)
    elif pattern == "uniform":
        e = np.ones(len(c))
    else:
        raise InputError(f"corner: unknown pattern {pattern!r} (use 'smooth' or 'uniform')")
    return CornerScene(mesh, e, float(reflectance), plate, size, res)


def corner_profile_line(
    scene: CornerScene, y: float | None = None, n: int = 401
) -> tuple[np.ndarray, np.ndarray]:
    """Points along the line across the corner, at height ``y``.

    The default ``y`` is the middle of the row of grid squares at mid-plate, so that
    the line never runs along a mesh edge.

    The line runs from the far edge of the floor ``(size, y, 0)`` to the corner
    ``(0, y, 0)`` and up the wall to ``(0, y, size)``.

    Returns
    -------
    s : (n,) ndarray
        Signed distance from the corner along the surface: ``-x`` on the floor,
        ``+z`` on the wall (model units).
    points : (n, 3) ndarray
        The points, lifted by nothing: they lie on the plates.
    """
    L = scene.size
    if y is None:
        y = (scene.resolution // 2 + 0.5) * L / scene.resolution
    y = float(y)
    if not 0.0 <= y <= L:
        raise InputError(f"corner profile: y must lie in [0, {L}], got {y}")
    # avoid the exact corner and the plate edges, where a point belongs to two faces
    s = np.linspace(-L, L, int(n))
    s = np.clip(s, -L * (1 - 1e-9), L * (1 - 1e-9))
    s = np.where(s == 0.0, 1e-9 * L, s)
    pts = np.zeros((s.size, 3))
    pts[:, 1] = y
    pts[:, 0] = np.where(s < 0, -s, 0.0)
    pts[:, 2] = np.where(s > 0, s, 0.0)
    return s, pts
