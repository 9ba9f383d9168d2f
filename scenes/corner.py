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
from numba import njit
from threadpoolctl import threadpool_limits

from resection.errors import InputError

__all__ = [
    "CornerScene",
    "corner",
    "corner_profile_line",
    "corner_form_factors",
    "exact_radiosity",
    "symmetric_factors",
    "DEFAULT_REFLECTANCE",
]

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


def corner_form_factors(scene: CornerScene, order: int = 6, *, far_order: int = 2,
                        near: int = 6, dtype=np.float64) -> np.ndarray:
    """Converged form factors from the floor's faces to the wall's, without rays.

    Every floor face sees the whole wall (nothing lies between two plates at 90
    degrees), so ``F_ij`` is the exact point-to-triangle factor (Lambert's contour
    integral, :func:`selfillum.transport.kernel.pair_factors`) integrated over the floor face by a
    collapsed Gauss rule: ``order**2`` points for pairs near the fold (columns ``ix``
    and ``jz`` and offset ``d`` along it with ``ix + jz + |d| <= near``, where the
    integrand varies fastest), ``far_order**2`` points for the others. The corner is
    invariant along the fold (``y``): a pair's factor depends on the two faces' columns
    and on their offset in ``y`` only, and the mirror image in the plane ``x = z`` with
    reciprocity maps each such class onto another one, so about ``2 res^2 (2 res - 1)``
    pairs are integrated instead of ``(2 res^2)^2``. The floor-to-wall total matches
    Howell's C-14 to about 1e-5 relative (tested); at resolution 40 the radiosity from
    the defaults is within 1.4e-5 of that from 100 points near / 16 far (measured).

    ``dtype`` is that of the returned matrix (the factors are computed in float64).

    Returns
    -------
    (M, M) ndarray
        ``F[i, j]``, floor face ``i`` (0..M-1) to wall face ``M + j``, ``M = 2 res^2``.
        Wall to floor is its transpose (all triangles have the same area).
    """
    from selfillum.mesh import face_normals
    from selfillum.transport.kernel import pair_factors

    res = scene.resolution
    m = 2 * res * res
    mesh = scene.mesh
    t, ix, tw, jz, d = np.meshgrid(np.arange(2), np.arange(res), np.arange(2),
                                   np.arange(res), np.arange(-(res - 1), res), indexing="ij")
    iy = np.where(d < 0, res - 1, 0)  # a source row from which the offset d is on the wall
    src = t * res * res + ix * res + iy  # faces: triangle t, then square (u, v) of _plate
    dst = m + tw * res * res + (iy + d) * res + jz  # wall: u = y, v = z
    # the mirror x <-> z maps class (t, ix, tw, jz, d) onto (1 - tw, jz, 1 - t, ix, -d)
    # (with reciprocity): integrate one class of each pair and copy it to the other
    code, mirror = _class_codes(t, ix, tw, jz, d)
    own = code <= mirror
    close = ix + jz + np.abs(d) <= near
    g = np.empty(t.shape)
    nrm = face_normals(mesh)
    for sel, q in ((own & close, order), (own & ~close, far_order)):
        g[sel] = pair_factors(mesh.vertices, mesh.faces, nrm, src[sel], dst[sel], order=q)
    g.ravel()[code[~own]] = g.ravel()[mirror[~own]]
    return _expand(g.astype(dtype, copy=False))


def _class_codes(t, ix, tw, jz, d):
    """Flat index of the floor-to-wall class ``(t, ix, tw, jz, d)`` in an array of shape
    ``(2, res, 2, res, 2 res - 1)``, and that of its mirror image in the plane ``x = z``,
    ``(1 - tw, jz, 1 - t, ix, -d)`` (the same factor)."""
    res = ix.shape[1] if np.ndim(ix) == 5 else int(np.max(ix)) + 1
    nd = 2 * res - 1
    code = (((t * res + ix) * 2 + tw) * res + jz) * nd + d + res - 1
    mirror = ((((1 - tw) * res + jz) * 2 + 1 - t) * res + ix) * nd - d + res - 1
    return code, mirror


def exact_radiosity(scene: CornerScene, tol: float = 1e-6) -> np.ndarray:
    """Radiosity ``B = E + rho F B`` of the corner from its converged form factors
    (:func:`corner_form_factors`, default rule: within 1.4e-5 of a 100/16-point rule at
    resolution 40), solved by block Jacobi iteration to ``tol`` (relative): an
    independent reference for ray-cast view factors and for the correction. The
    products run in float32 (rounding about 1e-7 relative), so ``tol`` below about 1e-6
    is not reached and the iteration stops after 200 sweeps.
    """
    F = corner_form_factors(scene, dtype=np.float32)
    m = F.shape[0]
    rho = scene.reflectance
    e_floor, e_wall = scene.emission[:m], scene.emission[m:]
    f32 = np.float32
    b_floor = e_floor.copy()
    # one BLAS thread: the products are memory-bound, and OpenBLAS's idle threads spin
    # on the cores for a while after each call (slowing whatever runs next)
    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(200):  # converges as (rho^2 |F|^2)^n, about 0.1 a sweep
            b_wall = e_wall + rho * (F.T @ b_floor.astype(f32))
            new = e_floor + rho * (F @ b_wall.astype(f32))
            done = np.max(np.abs(new - b_floor)) <= tol * np.max(np.abs(new))
            b_floor = new
            if done:
                break
        return np.concatenate([b_floor, e_wall + rho * (F.T @ b_floor.astype(f32))])


def _expand(g: np.ndarray) -> np.ndarray:
    """The floor-to-wall block ``F[(t, ix, iy), (tw, jy, jz)] = g[t, ix, tw, jz, jy - iy +
    res - 1]`` (faces numbered as in :func:`_plate`), ``(M, M)`` from ``g`` of shape
    ``(2, res, 2, res, 2 res - 1)``: each ``(iy, jy)`` block is a Toeplitz matrix, read as
    a sliding window over ``g``'s last axis (one copy, no index arrays)."""
    res = g.shape[1]
    w = np.lib.stride_tricks.sliding_window_view(g, res, axis=4)[..., ::-1, :]
    # w[..., iy, jy] = g[..., res - 1 - iy + jy]
    return np.ascontiguousarray(w.transpose(0, 1, 4, 2, 5, 3)).reshape(2 * res * res, -1)


@njit(cache=True)
def _pool_pairs(indptr, indices, data, res, sums):  # pragma: no cover - compiled
    """Add every floor-wall entry of a CSR ``F`` to its symmetry class in ``sums``.

    A class is ``(t, ix, tw, jz, d)``: floor face ``(t, ix, iy)`` to wall face
    ``(tw, iy + d, jz)``. A wall-to-floor entry counts for the floor-to-wall pair
    (reciprocity, equal areas), and a class is merged with its mirror image in the plane
    ``x = z`` (``(1 - tw, jz, 1 - t, ix, -d)``): the smaller code names both."""
    m = 2 * res * res
    rr = res * res
    nd = 2 * res - 1
    for i in range(indptr.shape[0] - 1):
        pi = i >= m
        ri = i - m if pi else i
        ti, ai, bi = ri // rr, (ri % rr) // res, ri % res
        for e in range(indptr[i], indptr[i + 1]):
            j = indices[e]
            pj = j >= m
            if pj == pi:
                continue
            rj = j - m if pj else j
            tj, aj, bj = rj // rr, (rj % rr) // res, rj % res
            if pi:  # wall (ti, jy=ai, jz=bi) to floor (tj, ix=aj, iy=bj)
                t, ix, iy, tw, jy, jz = tj, aj, bj, ti, ai, bi
            else:
                t, ix, iy, tw, jy, jz = ti, ai, bi, tj, aj, bj
            d = jy - iy
            c1 = (((t * res + ix) * 2 + tw) * res + jz) * nd + d + res - 1
            c2 = ((((1 - tw) * res + jz) * 2 + 1 - t) * res + ix) * nd - d + res - 1
            sums[min(c1, c2)] += data[e]


def symmetric_factors(scene: CornerScene, F, dtype=np.float64) -> np.ndarray:
    """The floor-to-wall block of ray-cast form factors, averaged over the corner's
    symmetries.

    A pair's factor depends only on the two faces' relative position, and nothing lies
    between the plates, so every floor-to-wall pair with the same columns and the same
    offset ``d`` along the fold has the same factor (translation), a wall-to-floor
    entry estimates its transpose (reciprocity: all faces have the same area), and the
    mirror image in the plane ``x = z`` maps the floor onto the wall. Each class of
    pairs is estimated by the mean of all its ``F`` entries (zeros included: the
    divisor is the number of directed pairs in the class, hit or not), so the average
    of unbiased estimates stays unbiased. The variance drops by up to ``4 (res - |d|)``
    in class ``d``.

    Parameters
    ----------
    scene : CornerScene
    F : (N, N) sparse matrix
        Form factors of ``scene.mesh`` (every row), e.g. from
        :func:`selfillum.view_factors`.
    dtype : numpy dtype
        Of the returned matrix (the averages are computed in float64).

    Returns
    -------
    (M, M) ndarray
        ``F[i, j]``, floor face ``i`` to wall face ``M + j`` (as
        :func:`corner_form_factors`); wall to floor is its transpose.
    """
    import scipy.sparse as sp

    res = scene.resolution
    m = 2 * res * res
    F = sp.csr_matrix(F)
    if F.shape != (2 * m, 2 * m):
        raise InputError(f"symmetric_factors: F is {F.shape}, the corner has {2 * m} faces")
    t, ix, tw, jz, d = np.meshgrid(np.arange(2), np.arange(res), np.arange(2),
                                   np.arange(res), np.arange(-(res - 1), res), indexing="ij")
    code = np.minimum(*_class_codes(t, ix, tw, jz, d))
    # directed pairs of a class: res - |d| floor-to-wall ones and as many wall-to-floor
    count = np.bincount(code.ravel(), weights=2.0 * (res - np.abs(d)).ravel(),
                        minlength=code.size)
    sums = np.zeros(code.size)
    _pool_pairs(F.indptr, F.indices, F.data.astype(np.float64, copy=False), res, sums)
    return _expand((sums / np.maximum(count, 1.0))[code].astype(dtype, copy=False))
