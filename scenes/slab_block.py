"""A painted slab carrying an unpainted block: the geometry of issue 14, at any size.

Geometry (model units, metres by default): a slab ``|x| <= a``, ``|y| <= b``,
``-t <= z <= 0`` (top, underside and four rims, every normal pointing out of the slab),
and on its top a box ``|x| <= c``, ``|y| <= d``, ``0 <= z <= h`` (top and four sides,
normals outwards, no bottom). Every part is one Plot3D-like structured block (a grid of
``ni x nj`` points, normal ``d/di x d/dj``), in this order (block numbers counted from 1,
as in a Plot3D file written by :func:`write_slab_block`):

1 slab top, 2 slab underside, 3-6 slab rims (-y, +x, +y, -x),
7 box top, 8-11 box sides (-y, +x, +y, -x).

The slab top is painted with a smooth field (:func:`paint`), the box is black and
unpainted: it emits nothing and reflects little. Most faces (the underside) cannot send
light to the top, the situation where only the faces coupled to the seen ones matter.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.camera.model import Camera
from resection.errors import InputError

__all__ = ["SlabBlock", "slab_block", "paint", "write_slab_block", "slab_camera",
           "BOX_BLOCKS"]

#: Block numbers (from 1) of the box: what ``--unpainted`` takes.
BOX_BLOCKS = "7-11"


@dataclass(frozen=True)
class SlabBlock:
    """The scene.

    Attributes
    ----------
    blocks : list of (ni, nj, 1, 3) float64 arrays
        The structured blocks (see the module notes for the order).
    mesh : trimesh.Trimesh
        Triangles of every block (two a cell), ``face_attributes["block"]`` counted from 1.
    part : (N,) int64
        Block of each face, counted from 0 (``face_attributes["block"] - 1``).
    painted : (N,) bool
        Faces of the slab (the box is unpainted).
    emission : (N,) float64
        True emission: :func:`paint` at the centroid on the slab, 0 on the box.
    reflectance : (N,) float64
        ``rho_paint`` on the slab, ``rho_box`` on the box.
    """

    blocks: list
    mesh: trimesh.Trimesh
    part: np.ndarray
    painted: np.ndarray
    emission: np.ndarray
    reflectance: np.ndarray


def paint(points) -> np.ndarray:
    """Smooth luminescence of the paint at model points (about 0.8 to 1.2)."""
    p = np.asarray(points, dtype=np.float64)
    return 1.0 + 0.15 * np.sin(3.0 * p[..., 0]) + 0.1 * np.cos(4.0 * p[..., 1])


def _patch(p0, e1, e2, s, u) -> np.ndarray:
    """Grid ``p0 + s_i e1 + u_j e2`` (``s``, ``u`` increasing from 0 to 1), normal
    ``e1 x e2``."""
    g = (np.asarray(p0, float) + np.asarray(s, float)[:, None, None] * np.asarray(e1, float)
         + np.asarray(u, float)[None, :, None] * np.asarray(e2, float))
    return g[:, :, None, :]


def _line(n: int) -> np.ndarray:
    return np.linspace(0.0, 1.0, n + 1)


def _split_line(half: float, inner: float, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """``[-half, half]`` in steps of about ``cell`` with grid lines on ``+-inner``: as
    fractions of the whole side, and the fractions of the inner part alone."""
    n_out = max(1, int(round((half - inner) / cell)))
    n_in = max(2, int(round(2 * inner / cell)))
    x = np.concatenate([np.linspace(-half, -inner, n_out + 1),
                        np.linspace(-inner, inner, n_in + 1)[1:],
                        np.linspace(inner, half, n_out + 1)[1:]])
    return (x + half) / (2 * half), _line(n_in)


def _blocks(a, b, t, c, d, h, cell) -> list:
    """The 11 blocks; the slab top has grid lines on the box's outline, so the box's sides
    share their bottom edges with it (the grid is connected there, as real grids are)."""
    sx, sc = _split_line(a, c, cell)
    sy, sd = _split_line(b, d, cell)
    st = _line(max(1, int(round(t / cell))))
    sh = _line(max(2, int(round(h / cell))))
    X, Y, Z = np.eye(3)
    return [
        _patch([-a, -b, 0], 2 * a * X, 2 * b * Y, sx, sy),  # top, +z
        _patch([-a, -b, -t], 2 * b * Y, 2 * a * X, sy, sx),  # underside, -z
        _patch([-a, -b, -t], 2 * a * X, t * Z, sx, st),  # rim -y
        _patch([a, -b, -t], 2 * b * Y, t * Z, sy, st),  # rim +x
        _patch([a, b, -t], -2 * a * X, t * Z, sx, st),  # rim +y
        _patch([-a, b, -t], -2 * b * Y, t * Z, sy, st),  # rim -x
        _patch([-c, -d, h], 2 * c * X, 2 * d * Y, sc, sd),  # box top
        _patch([-c, -d, 0], 2 * c * X, h * Z, sc, sh),  # box -y
        _patch([c, -d, 0], 2 * d * Y, h * Z, sd, sh),  # box +x
        _patch([c, d, 0], -2 * c * X, h * Z, sc, sh),  # box +y
        _patch([-c, d, 0], -2 * d * Y, h * Z, sd, sh),  # box -x
    ]


def slab_block(
    faces: int = 20_000,
    *,
    half=(0.35, 0.25),
    thickness: float = 0.02,
    box=(0.04, 0.03, 0.04),
    rho_paint: float = 0.6,
    rho_box: float = 0.05,
) -> SlabBlock:
    """Build the scene with about ``faces`` triangles (square cells of one size).

    Parameters
    ----------
    faces : int
        Wanted number of triangles (the result is within a few percent).
    half : (a, b)
        Slab half sizes along x and y.
    thickness : float
        Slab thickness ``t``.
    box : (c, d, h)
        Box half sizes along x and y, and height.
    rho_paint, rho_box : float
        Reflectances of the painted slab and of the black box, in ``[0, 1)``.
    """
    from resection.io.meshes import plot3d_to_mesh

    a, b = (float(v) for v in half)
    c, d, h = (float(v) for v in box)
    t = float(thickness)
    if not (faces >= 100 and min(a, b, c, d, h, t) > 0 and c < a and d < b):
        raise InputError("slab_block: need faces >= 100, positive sizes and a box inside "
                         "the slab")
    area = 2 * (4 * a * b) + 2 * t * (4 * a + 4 * b) + 4 * c * d + 2 * h * (4 * c + 4 * d)
    cell = np.sqrt(2.0 * area / faces)
    blocks = _blocks(a, b, t, c, d, h, cell)
    mesh = plot3d_to_mesh(blocks, source="slab_block")
    part = np.asarray(mesh.face_attributes["block"], dtype=np.int64) - 1
    painted = part < 6
    centres = np.asarray(mesh.triangles_center)
    emission = np.where(painted, paint(centres), 0.0)
    rho = np.where(painted, rho_paint, rho_box)
    return SlabBlock(blocks, mesh, part, painted, emission, rho)


def slab_camera(width: int = 640, height: int = 480, *, zoom: float = 1.6) -> Camera:
    """A camera above the slab looking down at the box at 15 degrees from the vertical,
    seeing about half of the slab top (more with a smaller ``zoom``). It sees the box's
    -y side at about 75 degrees from its normal: beyond the usual cut-off of 70."""
    f = 0.9 * width * zoom
    K = [[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]]
    eye = [0.0, -0.5 * np.tan(np.radians(15.0)), 0.5]
    return Camera.look_at(eye, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], K=K, width=width,
                          height=height)


def write_slab_block(scene: SlabBlock, path: str | os.PathLike) -> None:
    """Write the blocks as a binary multi-block Plot3D grid."""
    from resection.io.meshes import write_plot3d

    write_plot3d(path, scene.blocks)
