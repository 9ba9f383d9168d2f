"""Which faces of a model surface a camera sees, with Embree ray casting.

A face is *visible* from a camera when

1. it faces the camera (its normal points towards the perspective centre),
2. the angle between its normal and the line of sight is at most an obliqueness limit
   (paint seen too obliquely is not measured reliably),
3. its sample points project inside the image, and
4. the ray from the perspective centre to its sample points hits that face first (no other
   part of the model in between).

Ray casting goes through Embree 4 (the library the ``embreex`` wheel ships, called through
:mod:`resection.surface.embree`: the scene shares this module's float32 vertex and index
arrays, and rays are traced from compiled kernels without the GIL). Embree works in
float32; hit distances and barycentric coordinates are recomputed here in float64 from the
face Embree reports, so that they are exact to double precision for the face that was hit.

Face winding gives the normal: counter-clockwise seen from outside, as trimesh.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba
import numpy as np

from resection._checks import as_points
from resection._mesh_graph import edge_cross
from resection._threads import run_blocks, split_range
from resection.camera.model import Camera
from resection.errors import InputError
from resection.surface import embree
from resection.trisurface import is_mesh

if TYPE_CHECKING:
    import trimesh

__all__ = ["RayCaster", "visible_faces", "face_sample_points", "face_geometry",
           "bounds", "unit_normals"]


class RayCaster:
    """First-hit ray casting on a triangle mesh with Embree.

    The scene is built once (float32, shifted and scaled to a box of about 100 units to use
    the float32 range well, as trimesh does) and can be queried many times.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The surface; its face order defines the face indices returned.
    """

    def __init__(self, mesh: trimesh.Trimesh):
        if not is_mesh(mesh):
            raise InputError(f"mesh: expected a trimesh.Trimesh or TriSurface, got "
                             f"{type(mesh).__name__}")
        if len(mesh.faces) == 0:
            raise InputError("mesh: has no faces")
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        lo, hi = bounds(vertices)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise InputError("mesh: vertices contain NaN or infinite values")
        self._vertices = vertices
        self._faces = np.asarray(mesh.faces, dtype=np.int64)
        self._origin = lo
        extent = float(np.linalg.norm(hi - lo))
        self._scale = 100.0 / extent if extent > 0 else 1.0
        self._dual = None  # per-face data of _plane_hits, built on first use
        self._normals = None  # (normals, centroids, areas), built on first use
        # committed (BVH built) here, on Embree's threads; Embree reads the arrays in place
        self._scene = embree.Scene((vertices - self._origin) * self._scale, self._faces)

    @property
    def n_faces(self) -> int:
        return len(self._faces)

    @property
    def scene(self):
        """The committed Embree scene (:class:`resection.surface.embree.Scene`), in the
        frame of :attr:`origin` and :attr:`scale`: a model point ``x`` is at
        ``(x - origin) * scale`` (float32) in it. Other ray casts of the same mesh may
        query it (from several threads) instead of building their own:
        :class:`selfillum.transport.viewfactors.RowTracer` does."""
        return self._scene

    @property
    def origin(self) -> np.ndarray:
        """Model point at the scene's origin (the mesh's lowest corner), ``(3,)``."""
        return self._origin.copy()

    @property
    def scale(self) -> float:
        """Scene units per model unit (the mesh's box diagonal is 100 in the scene)."""
        return self._scale

    @property
    def normals(self) -> np.ndarray:
        """Unit face normals ``(F, 3)`` float64, right-hand rule on the vertex order
        (``(v1 - v0) x (v2 - v0)`` normalised), computed once from the float64 vertices."""
        return self._geometry()[0]

    @property
    def centroids(self) -> np.ndarray:
        """Face centroids ``(F, 3)`` float64 (model units), computed once."""
        return self._geometry()[1]

    @property
    def areas(self) -> np.ndarray:
        """Face areas ``(F,)`` float64 (model units squared), computed once."""
        return self._geometry()[2]

    def _geometry(self):
        """``(normals, centroids, areas)`` of the faces, in one compiled pass."""
        if self._normals is None:
            self._normals = _geometry_of(self._face_duals(), self._vertices, self._faces)
        return self._normals

    def first_hit(self, origins, directions, *, unit: bool = False,
                  workers: int | None = None):
        """Cast rays and return the first face each one hits.

        Parameters
        ----------
        origins : (N, 3) or (3,) array_like
            Ray origins in model coordinates, or one origin shared by every ray.
        directions : (N, 3) array_like
            Directions (need not be unit); rows with NaN are not cast and come back as
            misses.
        unit : bool
            The directions are already unit vectors (skips normalising them).
        workers : int, optional
            Threads over blocks of rays (Embree's queries and the compiled passes release
            the GIL). Default: the cores this process may use.

        Returns
        -------
        face : (N,) int64
            Index of the face hit first, -1 for a miss.
        distance : (N,) float64
            Distance along the unit direction to the hit point (model units), NaN for a
            miss; recomputed in float64 on the hit face's plane.
        bary : (N, 3) float64
            Barycentric coordinates of the hit point on the face's vertices ``(w0, w1, w2)``
            (sum 1), NaN for a miss.
        """
        d = np.ascontiguousarray(as_points(directions, 3, "ray directions", allow_nan=True),
                                 dtype=np.float64)
        o_in = np.asarray(origins, dtype=np.float64)
        single = o_in.shape == (3,)  # one origin for every ray (a camera centre)
        o = o_in[None, :] if single else as_points(o_in, 3, "ray origins", allow_nan=True)
        if not single and o.shape != d.shape:
            raise InputError(f"rays: origins {o.shape} and directions {d.shape} differ")
        o = np.ascontiguousarray(o, dtype=np.float64)
        n = len(d)
        face = np.empty(n, dtype=np.int64)
        dist = np.empty(n)
        bary = np.empty((n, 3))
        dual = self._face_duals()
        shift = np.ascontiguousarray(self._origin, dtype=np.float64)
        scene = self._scene

        def block(b: tuple[int, int]) -> None:
            start, stop = b
            o32 = np.empty((1 if single else stop - start, 3), np.float32)
            d32 = np.empty((stop - start, 3), np.float32)
            keep = np.empty(stop - start, np.int64)
            k = _prepare_rays(o, d, start, stop, unit, shift, self._scale, o32, d32, keep,
                              face, dist, bary)
            if k == 0:
                return
            hit = np.empty(k, np.int64)
            embree.trace(scene.intersect, scene.handle, o32 if single else o32[:k], d32[:k],
                         hit)
            _plane_hits(o, d, keep[:k], hit, unit, dual, face, dist, bary)

        run_blocks(block, split_range(n, workers, min_size=16384), workers)
        return face, dist, bary

    def _face_duals(self) -> np.ndarray:
        """Per-face data of the float64 plane hits (v0, normal, a1, a2), built once
        (:func:`_duals`: one compiled pass, 10 ns a face)."""
        if self._dual is None:
            dual = np.empty((len(self._faces), 12))
            _duals(self._vertices, self._faces, 0, len(self._faces), dual)
            self._dual = dual
        return self._dual


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _duals(vertices, faces, start, stop, dual):  # pragma: no cover - compiled
    """Rows ``start <= f < stop`` of the duals: ``v0``, the normal ``n = e1 x e2``
    (``e1 = v1 - v0``, ``e2 = v2 - v0``, not normalised), ``a1 = (e2 x n) / |n|^2`` and
    ``a2 = (n x e1) / |n|^2``, so that a point ``p`` of the plane has barycentrics
    ``w1 = (p - v0) . a1``, ``w2 = (p - v0) . a2`` (NaN or infinite for a degenerate
    face)."""
    for f in range(start, stop):
        i0 = faces[f, 0]
        e1x, e1y, e1z, e2x, e2y, e2z, nx, ny, nz = edge_cross(vertices, i0, faces[f, 1],
                                                              faces[f, 2])
        nn = nx * nx + ny * ny + nz * nz
        for c in range(3):
            dual[f, c] = vertices[i0, c]
        dual[f, 3], dual[f, 4], dual[f, 5] = nx, ny, nz
        dual[f, 6] = (e2y * nz - e2z * ny) / nn
        dual[f, 7] = (e2z * nx - e2x * nz) / nn
        dual[f, 8] = (e2x * ny - e2y * nx) / nn
        dual[f, 9] = (ny * e1z - nz * e1y) / nn
        dual[f, 10] = (nz * e1x - nx * e1z) / nn
        dual[f, 11] = (nx * e1y - ny * e1x) / nn


def face_geometry(vertices, faces) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit normals ``(F, 3)`` (right-hand rule on the vertex order), centroids ``(F, 3)``
    and areas ``(F,)`` of triangles, float64, in two compiled passes (about 25 ns a
    face): the values :attr:`RayCaster.normals`, :attr:`RayCaster.centroids` and
    :attr:`RayCaster.areas` give for the same mesh."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    dual = np.empty((len(f), 12))
    _duals(v, f, 0, len(f), dual)
    return _geometry_of(dual, v, f)


def bounds(vertices) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest coordinates ``(3,)`` of ``(V, 3)`` vertices (float64), in one
    compiled pass (NumPy's ``min(axis=0)`` on this shape is 10 times slower); NaN in
    both when a coordinate is NaN or the array is empty."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    lo, hi = np.empty(3), np.empty(3)
    _bounds(v, lo, hi)
    return lo, hi


@numba.njit(cache=True, nogil=True)
def _bounds(v, lo, hi):  # pragma: no cover - compiled
    lo[:] = np.inf
    hi[:] = -np.inf
    bad = v.shape[0] == 0
    for i in range(v.shape[0]):
        for c in range(3):
            x = v[i, c]
            if x != x:
                bad = True
            if x < lo[c]:
                lo[c] = x
            if x > hi[c]:
                hi[c] = x
    if bad:
        lo[:] = np.nan
        hi[:] = np.nan


def unit_normals(vertices, faces) -> np.ndarray:
    """Unit face normals ``(F, 3)`` float64 (right-hand rule on the vertex order), in one
    compiled pass: the values of :func:`face_geometry` (the same arithmetic), without its
    centroids, areas and per-face plane data."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    out = np.empty((len(f), 3))
    _normals_only(v, f, out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _normals_only(vertices, faces, out):  # pragma: no cover - compiled
    for f in range(faces.shape[0]):
        nx, ny, nz = edge_cross(vertices, faces[f, 0], faces[f, 1], faces[f, 2])[6:]
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        out[f, 0] = nx / length
        out[f, 1] = ny / length
        out[f, 2] = nz / length


def _geometry_of(dual, vertices, faces):
    nf = len(faces)
    out = (np.empty((nf, 3)), np.empty((nf, 3)), np.empty(nf))
    _unit_normals(dual, vertices, faces, *out)
    return out


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _unit_normals(dual, vertices, faces, normals, centroids, areas):  # pragma: no cover
    """Unit normals (the duals' ``n`` over its length), centroids and areas
    (``|n| / 2``) of every face."""
    third = 1.0 / 3.0
    for f in range(dual.shape[0]):
        nx, ny, nz = dual[f, 3], dual[f, 4], dual[f, 5]
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        normals[f, 0] = nx / length
        normals[f, 1] = ny / length
        normals[f, 2] = nz / length
        areas[f] = length / 2.0
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        for c in range(3):
            centroids[f, c] = (vertices[i0, c] + vertices[i1, c] + vertices[i2, c]) * third


@numba.njit(cache=True, nogil=True, inline="always")
def _miss(k, face, dist, bary):  # pragma: no cover - compiled
    """Ray ``k`` hits nothing: face -1, distance and barycentrics NaN."""
    face[k] = -1
    dist[k] = np.nan
    bary[k, 0] = np.nan
    bary[k, 1] = np.nan
    bary[k, 2] = np.nan


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _prepare_rays(o, d, start, stop, unit, shift, scale, o32, d32, keep, face, dist,
                  bary):  # pragma: no cover (compiled)
    """Rays ``start <= k < stop`` with a finite origin and a finite non-zero direction:
    their scaled float32 origins and unit float32 directions packed into ``o32``/``d32``
    (one shared origin when ``o`` has one row), their indices into ``keep``; the others
    written as misses. Returns how many were packed."""
    one = o.shape[0] == 1
    if one:
        o_ok = np.isfinite(o[0, 0]) and np.isfinite(o[0, 1]) and np.isfinite(o[0, 2])
        for c in range(3):
            o32[0, c] = (o[0, c] - shift[c]) * scale
    m = 0
    for k in range(start, stop):
        dx, dy, dz = d[k, 0], d[k, 1], d[k, 2]
        nn = dx * dx + dy * dy + dz * dz
        ok = np.isfinite(nn) and nn > 0.0
        if not one:
            ok = ok and np.isfinite(o[k, 0]) and np.isfinite(o[k, 1]) and np.isfinite(o[k, 2])
        elif not o_ok:
            ok = False
        if not ok:
            _miss(k, face, dist, bary)
            continue
        s = 1.0 if unit else 1.0 / np.sqrt(nn)
        d32[m, 0] = dx * s
        d32[m, 1] = dy * s
        d32[m, 2] = dz * s
        if not one:
            for c in range(3):
                o32[m, c] = (o[k, c] - shift[c]) * scale
        keep[m] = k
        m += 1
    return m


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plane_hits(o, d, keep, hit, unit, dual, face, dist, bary):  # pragma: no cover
    """For ray ``keep[j]`` that Embree reports on face ``hit[j]`` (-1: a miss): the face,
    and the float64 distance and barycentrics ``(1 - w1 - w2, w1, w2)`` of the ray
    ``(o[k] or o[0], d[k] / |d[k]|)`` on that face's plane (dual row: v0, normal, a1, a2)."""
    one = o.shape[0] == 1
    for j in range(keep.shape[0]):
        k = keep[j]
        f = hit[j]
        if f < 0:
            _miss(k, face, dist, bary)
            continue
        ko = 0 if one else k
        s = 1.0 if unit else 1.0 / np.sqrt(d[k, 0] ** 2 + d[k, 1] ** 2 + d[k, 2] ** 2)
        d0, d1, d2 = d[k, 0] * s, d[k, 1] * s, d[k, 2] * s
        q0 = dual[f, 0] - o[ko, 0]
        q1 = dual[f, 1] - o[ko, 1]
        q2 = dual[f, 2] - o[ko, 2]
        nd = dual[f, 3] * d0 + dual[f, 4] * d1 + dual[f, 5] * d2
        t = (dual[f, 3] * q0 + dual[f, 4] * q1 + dual[f, 5] * q2) / nd
        p0 = t * d0 - q0
        p1 = t * d1 - q1
        p2 = t * d2 - q2
        w1 = p0 * dual[f, 6] + p1 * dual[f, 7] + p2 * dual[f, 8]
        w2 = p0 * dual[f, 9] + p1 * dual[f, 10] + p2 * dual[f, 11]
        face[k] = f
        dist[k] = t
        bary[k, 0] = 1.0 - w1 - w2
        bary[k, 1] = w1
        bary[k, 2] = w2


def face_sample_points(mesh: trimesh.Trimesh, samples_per_face: int = 1) -> np.ndarray:
    """Sample points inside every face at fixed barycentric positions.

    Sample 0 is the centroid; samples 1-3 lean towards each vertex (barycentric weight 0.6
    on it, 0.2 on the others) and samples 4-6 towards each edge (0.4, 0.4 on its ends, 0.2
    on the opposite vertex), so that every sample is strictly inside the face.

    Parameters
    ----------
    samples_per_face : int
        1 to 7.

    Returns
    -------
    (F, S, 3) array of model points.
    """
    s = int(samples_per_face)
    if s < 1 or s > 7:
        raise InputError(f"samples_per_face must be in 1..7, got {samples_per_face}")
    third = 1.0 / 3.0
    weights = [[third, third, third]]
    for k in range(3):  # towards each vertex: 0.6 on it, 0.2 on the others
        w = [0.2, 0.2, 0.2]
        w[k] = 0.6
        weights.append(w)
    for k in range(3):  # towards each edge midpoint: 0.4, 0.4 on its ends, 0.2 on the other
        w = [0.4, 0.4, 0.4]
        w[k] = 0.2
        weights.append(w)
    W = np.asarray(weights[:s])  # (S, 3)
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]  # (F, 3, 3)
    return np.einsum("sk,fkj->fsj", W, tri)


def visible_faces(
    mesh: trimesh.Trimesh,
    camera: Camera,
    max_obliqueness_deg: float = 80.0,
    samples_per_face: int = 1,
    *,
    require: str = "any",
    in_image: bool = True,
    caster: RayCaster | None = None,
) -> np.ndarray:
    """Faces of ``mesh`` that ``camera`` sees.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Model surface, model units; normals from the face winding.
    camera : Camera
        Camera with its pose.
    max_obliqueness_deg : float
        Largest angle, in degrees, between a face normal and the direction from the face
        centroid to the perspective centre (0 = seen head-on, 90 = edge-on).
    samples_per_face : int
        Number of sample points per face (1..7, see :func:`face_sample_points`) tested for
        occlusion and for falling inside the image.
    require : {"any", "all"}
        A face is visible when any (partially seen) or all (fully seen) of its samples are
        unoccluded and inside the image.
    in_image : bool
        Also require the samples to project inside the image (with distortion).
    caster : RayCaster, optional
        A prebuilt ray caster for ``mesh`` (saves rebuilding the Embree scene).

    Returns
    -------
    (F,) bool ndarray
    """
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    lim = float(max_obliqueness_deg)
    if not (0.0 < lim <= 90.0):
        raise InputError(f"max_obliqueness_deg must be in (0, 90], got {max_obliqueness_deg}")
    if require not in ("any", "all"):
        raise InputError(f"require must be 'any' or 'all', got {require!r}")
    caster = RayCaster(mesh) if caster is None else caster
    if caster.n_faces != len(mesh.faces):
        raise InputError(f"caster: built for {caster.n_faces} faces, the mesh has "
                         f"{len(mesh.faces)}")
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nlen = np.linalg.norm(normal, axis=1)
    C = camera.center
    to_cam = C - tri.mean(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cosang = np.einsum("ij,ij->i", normal, to_cam) / (nlen * np.linalg.norm(to_cam, axis=1))
    facing = cosang >= np.cos(np.radians(lim)) - 1e-12
    facing &= cosang > 0
    cand = np.flatnonzero(facing)
    vis = np.zeros(len(tri), dtype=bool)
    if cand.size == 0:
        return vis
    pts = face_sample_points(mesh, samples_per_face)[cand]  # (M, S, 3)
    m, s = pts.shape[:2]
    flat = pts.reshape(-1, 3)
    d = flat - C
    target = np.linalg.norm(d, axis=1)
    face_hit, dist, _ = caster.first_hit(C, d)
    own = np.repeat(cand, s)
    # the ray reaches the sample on its own face, or on a face at the same distance
    # (coplanar duplicate / edge): nothing lies in front of it
    tol = 1e-6 * target
    ok = (face_hit == own) | ((face_hit >= 0) & (dist >= target - tol))
    if in_image:
        uv = camera.project(flat)
        ok &= camera.in_image(uv)
    ok = ok.reshape(m, s)
    vis[cand] = ok.any(axis=1) if require == "any" else ok.all(axis=1)
    return vis
