"""Which faces of a model surface a camera sees, with Embree ray casting.

A face is *visible* from a camera when

1. it faces the camera (its normal points towards the perspective centre),
2. the angle between its normal and the line of sight is at most an obliqueness limit
   (paint seen too obliquely is not measured reliably),
3. its sample points project inside the image, and
4. the ray from the perspective centre to its sample points hits that face first (no other
   part of the model in between).

Ray casting goes through Embree (``embreex``, the binding trimesh uses for
``trimesh.ray.ray_pyembree``). Embree works in float32; hit distances and barycentric
coordinates are recomputed here in float64 from the face Embree reports, so that they are
exact to double precision for the face that was hit.

Face winding gives the normal: counter-clockwise seen from outside, as trimesh.
"""

from __future__ import annotations

import numba
import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from ._checks import as_points
from .camera import Camera
from .errors import InputError

__all__ = ["RayCaster", "visible_faces", "face_sample_points"]


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
        if not isinstance(mesh, trimesh.Trimesh):
            raise InputError(f"mesh: expected a trimesh.Trimesh, got {type(mesh).__name__}")
        if len(mesh.faces) == 0:
            raise InputError("mesh: has no faces")
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        if not np.all(np.isfinite(vertices)):
            raise InputError("mesh: vertices contain NaN or infinite values")
        self._vertices = vertices
        self._faces = np.asarray(mesh.faces, dtype=np.int64)
        self._origin = vertices.min(axis=0)
        extent = float(np.linalg.norm(vertices.max(axis=0) - self._origin))
        self._scale = 100.0 / extent if extent > 0 else 1.0
        scaled = ((vertices - self._origin) * self._scale).astype(np.float32)
        self._dual = None  # per-face data of _plane_hits, built on first use
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(scene=self._scene, vertices=scaled,
                     indices=self._faces.astype(np.int32))

    @property
    def n_faces(self) -> int:
        return len(self._faces)

    def first_hit(self, origins, directions, *, unit: bool = False):
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
        d = as_points(directions, 3, "ray directions", allow_nan=True)
        o_in = np.asarray(origins, dtype=np.float64)
        single = o_in.shape == (3,)  # one origin for every ray (a camera centre)
        o = o_in[None, :] if single else as_points(o_in, 3, "ray origins", allow_nan=True)
        if not single and o.shape != d.shape:
            raise InputError(f"rays: origins {o.shape} and directions {d.shape} differ")
        n = len(d)
        face = np.full(n, -1, dtype=np.int64)
        dist = np.full(n, np.nan)
        bary = np.full((n, 3), np.nan)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            norm = np.sqrt(np.einsum("ij,ij->i", d, d))
            ok = np.isfinite(norm) & (norm > 0)
            if single:
                ok &= bool(np.all(np.isfinite(o)))
            else:
                ok &= np.all(np.isfinite(o), axis=1)
        if not np.any(ok):
            return face, dist, bary
        all_ok = bool(ok.all())
        idx = None if all_ok else np.flatnonzero(ok)
        if unit:
            du = d if all_ok else d[idx]
        else:
            du = d / norm[:, None] if all_ok else d[idx] / norm[idx, None]
        oo = o if single else (o if all_ok else o[idx])
        so = ((oo - self._origin) * self._scale).astype(np.float32)
        if single:
            so = np.broadcast_to(so, du.shape)
        hit = np.asarray(self._scene.run(np.ascontiguousarray(so),
                                         du.astype(np.float32)), dtype=np.int64)
        sel = np.flatnonzero(hit >= 0)
        rows = sel if all_ok else idx[sel]
        face[rows] = hit[sel]
        self._plane_hits(oo, du, sel, hit, rows, dist, bary)
        return face, dist, bary

    def _plane_hits(self, o, d, sel, hit, rows, dist, bary) -> None:
        """Float64 distance and barycentrics of rays ``sel`` of ``(o, d)`` on the planes of
        their faces ``hit[sel]``, written to ``dist[rows]`` and ``bary[rows]``; per-face
        data computed once, one compiled pass over the rays (no per-ray temporaries)."""
        if self._dual is None:
            tri = self._vertices[self._faces]
            v0 = tri[:, 0]
            e1, e2 = tri[:, 1] - v0, tri[:, 2] - v0
            nrm = np.cross(e1, e2)
            nn = np.einsum("ij,ij->i", nrm, nrm)
            with np.errstate(divide="ignore", invalid="ignore"):
                a1 = np.cross(e2, nrm) / nn[:, None]  # w1 = (p - v0) . a1
                a2 = np.cross(nrm, e1) / nn[:, None]  # w2 = (p - v0) . a2
            self._dual = np.ascontiguousarray(np.hstack([v0, nrm, a1, a2]))  # (F, 12)
        o2 = np.ascontiguousarray(np.atleast_2d(o), dtype=np.float64)
        _plane_hit_kernel(o2, np.ascontiguousarray(d, dtype=np.float64), sel, hit, rows,
                          self._dual, dist, bary)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plane_hit_kernel(o, d, sel, hit, rows, dual, dist, bary):  # pragma: no cover (compiled)
    """For k in sel: ray (o[k] or o[0], d[k]) on the plane of face hit[k] (dual row:
    v0, normal, a1, a2); distance t and barycentrics (1 - w1 - w2, w1, w2) to row rows[j]."""
    one = o.shape[0] == 1
    for j in range(sel.shape[0]):
        k = sel[j]
        f = hit[k]
        r = rows[j]
        ko = 0 if one else k
        q0 = dual[f, 0] - o[ko, 0]
        q1 = dual[f, 1] - o[ko, 1]
        q2 = dual[f, 2] - o[ko, 2]
        nd = dual[f, 3] * d[k, 0] + dual[f, 4] * d[k, 1] + dual[f, 5] * d[k, 2]
        t = (dual[f, 3] * q0 + dual[f, 4] * q1 + dual[f, 5] * q2) / nd
        p0 = t * d[k, 0] - q0
        p1 = t * d[k, 1] - q1
        p2 = t * d[k, 2] - q2
        w1 = p0 * dual[f, 6] + p1 * dual[f, 7] + p2 * dual[f, 8]
        w2 = p0 * dual[f, 9] + p1 * dual[f, 10] + p2 * dual[f, 11]
        dist[r] = t
        bary[r, 0] = 1.0 - w1 - w2
        bary[r, 1] = w1
        bary[r, 2] = w2


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
