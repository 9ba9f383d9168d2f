"""Form factors between the faces of a triangle mesh, by Embree ray casting.

``F[i, j]`` is the fraction of the (Lambertian) light leaving face ``i`` that reaches face
``j`` directly, occlusion included. It is estimated by casting ``K`` cosine-distributed
rays from ``K`` stratified points of every face and counting ``1/K`` for each ray whose
first hit is the painted side of face ``j``:

``F_ij = (1 / A_i) integral_{A_i} integral_{A_j} cos(t_i) cos(t_j) V / (pi r^2) dA_j dA_i``

The estimator is unbiased; its standard error falls as ``1/sqrt(K)`` (faster, thanks to
the stratification, for smooth configurations). ``F`` is a ``scipy.sparse`` CSR matrix with
at most ``K`` non-zeros a row, so memory grows as ``N K``, not ``N^2``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from resection.errors import InputError

from .mesh import check_mesh, face_areas, face_normals

__all__ = ["view_factors", "enforce_reciprocity", "RayScene", "sample_rays"]

#: Faces sharing one random stream; results do not depend on ``chunk_size``.
_BLOCK = 512
#: Ray origins are lifted off their face by this fraction of the mesh size.
_OFFSET = 1e-6
#: Random permutations of the strata drawn per block of faces.
_POOL = 64
#: Default number of rays in flight per chunk.
_RAYS_PER_CHUNK = 1 << 20


class RayScene:
    """An Embree scene of a mesh, in float32 coordinates centred on the mesh's box.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex coordinates (model units).
    faces : (N, 3) array_like of int
        Triangles.
    """

    def __init__(self, vertices, faces):
        v = np.asarray(vertices, dtype=np.float64)
        self.origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
        self.scene = rtcore_scene.EmbreeScene()
        # keep references: Embree reads these buffers
        self._v = np.ascontiguousarray(v - self.origin, dtype=np.float32)
        self._f = np.ascontiguousarray(faces, dtype=np.int32)
        TriangleMesh(scene=self.scene, vertices=self._v, indices=self._f)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Index of the first face hit by each ray (``-1`` for a miss), ``(M,)`` int64."""
        o = np.ascontiguousarray(origins - self.origin, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        return np.asarray(self.scene.run(o, d), dtype=np.int64)


def _stratified_2d(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """``(n, k, 2)`` float32 points of the unit square, stratified per row.

    Each row takes ``k`` distinct cells of an ``m x m`` grid (``m = ceil(sqrt(k))``; all
    of them, the jittered grid, when ``k = m^2``) in a random order and jitters each point
    within its cell. The orders are drawn from a pool of random permutations (each row
    picks one at random), which keeps every point uniformly distributed, the positions and
    directions of a face decorrelated, and the cost linear in ``n k`` (no sort per row).
    """
    m = int(np.ceil(np.sqrt(k)))
    pool = min(n, _POOL)
    perms = np.argsort(rng.random((pool, m * m), dtype=np.float32), axis=1)[:, :k]
    cx = (perms % m).astype(np.float32)
    cy = (perms // m).astype(np.float32)
    pick = rng.integers(0, pool, size=n)
    out = rng.random((n, k, 2), dtype=np.float32)
    out[..., 0] += cx[pick]
    out[..., 1] += cy[pick]
    out *= np.float32(1.0 / m)
    return np.minimum(out, np.float32(1.0 - 2**-24), out=out)


def _tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(t1, t2)`` completing each unit normal to a right-handed frame."""
    helper = np.where(
        (np.abs(normals[:, 0]) < 0.9)[:, None], np.array([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0]
    )
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return t1, t2


def sample_rays(
    triangles: np.ndarray,
    normals: np.ndarray,
    k: int,
    rng: np.random.Generator,
    *,
    two_sided: bool = False,
    offset: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosine-distributed rays leaving stratified points of faces (float32, for Embree).

    Parameters
    ----------
    triangles : (n, 3, 3) ndarray
        Vertices of the faces, in the frame the rays are wanted in (keep it centred on
        the scene for float32 precision).
    normals : (n, 3) ndarray
        Unit normals (painted side).
    k : int
        Rays per face.
    rng : numpy.random.Generator
        Random stream.
    two_sided : bool
        Send half of the rays (at random) out of the back side.
    offset : float
        Lift the start points off the face by this distance, on the side the ray leaves
        (model units), so that a ray does not hit its own face.

    Returns
    -------
    origins : (n * k, 3) float32 ndarray
        Ray start points: uniform, stratified points of the faces (lifted by ``offset``).
    directions : (n * k, 3) float32 ndarray
        Unit directions, cosine-distributed about the (signed) normal.
    side : (n * k,) int8 ndarray
        ``+1`` for rays leaving the painted side, ``-1`` for the back side.
    """
    n = triangles.shape[0]
    f32 = np.float32
    pos = _stratified_2d(rng, n, k)
    dirs = _stratified_2d(rng, n, k)
    tri = triangles.astype(f32)
    nrm = normals.astype(f32)
    if two_sided:
        flip = rng.integers(0, 2, size=(n, 1))
        side = np.where((np.arange(k)[None, :] + flip) % 2 == 0, 1, -1).astype(np.int8)
    else:
        side = np.ones((n, k), dtype=np.int8)
    # uniform point of a triangle from the unit square (area-preserving map), as the
    # weights of [v0, v1 - v0, v2 - v0, offset * normal]: one batched 4x3 product a face
    sa = np.sqrt(pos[..., 0])
    w = np.empty((n, k, 4), dtype=f32)
    w[..., 0] = 1.0
    w[..., 2] = sa * pos[..., 1]
    w[..., 1] = sa - w[..., 2]
    w[..., 3] = side
    basis = np.empty((n, 4, 3), dtype=f32)
    basis[:, 0] = tri[:, 0]
    basis[:, 1] = tri[:, 1] - tri[:, 0]
    basis[:, 2] = tri[:, 2] - tri[:, 0]
    basis[:, 3] = f32(offset) * nrm
    origins = np.matmul(w, basis)
    # cosine-weighted hemisphere (Malley's method: uniform disk lifted to the hemisphere),
    # local (x, y, z) times the face frame [t1, t2, n]
    local = np.empty((n, k, 3), dtype=f32)
    r = np.sqrt(dirs[..., 0])
    phi = f32(2.0 * np.pi) * dirs[..., 1]
    local[..., 0] = r * np.cos(phi)
    local[..., 1] = r * np.sin(phi)
    local[..., 2] = np.sqrt(np.maximum(f32(0.0), f32(1.0) - dirs[..., 0])) * side
    t1, t2 = _tangent_frames(normals)
    frame = np.stack([t1, t2, normals], axis=1).astype(f32)
    directions = np.matmul(local, frame)
    return origins.reshape(-1, 3), directions.reshape(-1, 3), side.reshape(-1)


def _chunk_matrix(
    scene: RayScene,
    triangles: np.ndarray,
    normals: np.ndarray,
    start: int,
    stop: int,
    k: int,
    seed: int,
    offset: float,
    two_sided: bool,
    n_faces: int,
) -> sp.csr_matrix:
    """Rows ``start:stop`` of ``F`` (shape ``(stop - start, n_faces)``); ``triangles`` in
    the scene's centred frame."""
    m = (stop - start) * k
    origins = np.empty((m, 3), dtype=np.float32)
    directions = np.empty((m, 3), dtype=np.float32)
    for b0 in range(start, stop, _BLOCK):
        b1 = min(b0 + _BLOCK, stop)
        rng = np.random.default_rng([seed, b0 // _BLOCK])
        o, d, _ = sample_rays(
            triangles[b0:b1], normals[b0:b1], k, rng, two_sided=two_sided, offset=offset
        )
        sl = slice((b0 - start) * k, (b1 - start) * k)
        origins[sl] = o
        directions[sl] = d
    hit = np.asarray(scene.scene.run(origins, directions))
    src = np.repeat(np.arange(start, stop, dtype=hit.dtype), k)
    ok = (hit >= 0) & (hit != src)
    idx = np.flatnonzero(ok)
    hit = hit[idx]
    if not two_sided:
        # a ray arriving on the back (unpainted) side of a face is absorbed there
        front = np.einsum("ij,ij->i", directions[idx], normals[hit].astype(np.float32)) < 0
        idx, hit = idx[front], hit[front]
    rows = idx // k
    data = np.full(rows.size, 1.0 / k)
    mat = sp.csr_matrix((data, (rows, hit)), shape=(stop - start, n_faces))
    mat.sum_duplicates()
    return mat


def view_factors(
    mesh: trimesh.Trimesh,
    rays_per_face: int = 256,
    seed: int = 0,
    *,
    reciprocity: bool = False,
    chunk_size: int | None = None,
    two_sided: bool = False,
    progress: bool | Callable | None = False,
) -> sp.csr_matrix:
    """Form factors between the faces of a mesh, with occlusion, by Embree ray casting.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh; faces are the radiosity elements. Its painted side is the side
        its normals point to (right-hand rule on the vertex order).
    rays_per_face : int
        ``K``, rays cast from each face; each hit adds ``1/K``.
    seed : int
        Seed of the random streams. The result depends only on ``mesh``,
        ``rays_per_face``, ``seed`` and ``two_sided`` (not on ``chunk_size``).
    reciprocity : bool
        Enforce ``A_i F_ij = A_j F_ji`` by area-weighted symmetrisation and symmetric
        balancing to the raw row sums (see :func:`enforce_reciprocity`); the sparsity
        pattern then is the union of those of ``F`` and ``F.T`` (up to ``2 K`` non-zeros
        a row).
    chunk_size : int, optional
        Faces traced at once, rounded down to a multiple of 512 and at least 512 (one
        random block); memory in flight is about ``chunk_size * K * 150`` bytes. Default:
        about ``2**20 / K`` faces (about 1 million rays a chunk, more when ``K > 2048``).
    two_sided : bool
        Faces painted on both sides with the same radiosity (thin sheets): half the
        rays of a face leave from its back, and hits on either side count. With the
        default ``False`` rays leave the painted side only and a ray that reaches the
        back of a face is absorbed there (it counts nowhere).
    progress : bool or callable
        ``True`` shows a ``tqdm`` bar over chunks; a callable is called with
        ``(faces_done, faces_total)`` after each chunk.

    Returns
    -------
    scipy.sparse.csr_matrix
        ``F``, ``(N, N)`` float64, ``F[i, j]`` from face ``i`` to face ``j``. Row sums are
        ``<= 1`` (``1`` minus what escapes the scene or hits unpainted sides).

    Raises
    ------
    InputError
        Invalid mesh (see :func:`selfillum.mesh.check_mesh`) or parameters.
    """
    check_mesh(mesh)
    k = _positive_int(rays_per_face, "rays_per_face")
    if chunk_size is None:
        chunk = max(1, _RAYS_PER_CHUNK // k)
    else:
        chunk = _positive_int(chunk_size, "chunk_size")
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise InputError(f"seed: expected an integer, got {seed!r}") from None
    if seed < 0:
        raise InputError(f"seed: expected a non-negative integer, got {seed}")
    chunk = max(_BLOCK, (chunk // _BLOCK) * _BLOCK)  # whole random blocks per chunk
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = face_normals(mesh)
    n = len(faces)
    scene = RayScene(vertices, faces)
    triangles = (vertices - scene.origin)[faces]  # the scene's centred frame
    size = float(np.ptp(vertices, axis=0).max())
    offset = _OFFSET * size

    starts = range(0, n, chunk)
    bar = None
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=n, desc="view factors", unit="face", leave=False)
    blocks = []
    for s0 in starts:
        s1 = min(s0 + chunk, n)
        blocks.append(
            _chunk_matrix(scene, triangles, normals, s0, s1, k, seed, offset, two_sided, n)
        )
        if bar is not None:
            bar.update(s1 - s0)
        elif callable(progress):
            progress(s1, n)
    if bar is not None:
        bar.close()
    F = sp.vstack(blocks, format="csr")
    if reciprocity:
        F = enforce_reciprocity(F, face_areas(mesh))
    return F


def enforce_reciprocity(F, areas, *, tol: float = 1e-10, maxiter: int = 500) -> sp.csr_matrix:
    """Make ``A_i F_ij = A_j F_ji`` hold exactly, keeping each row's sum.

    1. Area-weighted symmetrisation: ``G = (A F + (A F)^T) / 2`` (``A = diag(areas)``),
       the reciprocal matrix closest to ``A F`` in the Frobenius norm.
    2. Symmetric balancing (symmetric Sinkhorn-Knopp): ``G' = X G X`` with ``X`` diagonal
       positive, so that the row sums of ``F' = A^-1 G'`` equal those of ``F`` (the
       fraction of rays of each face that hit something, an accurate estimate: exactly
       1 in a closed enclosure). ``G'`` stays symmetric: reciprocity holds exactly.
    3. Any row still summing above 1 (rounding, or balancing not converged) has its
       pairs ``(i, j)`` scaled by ``min(1, 1/s_i, 1/s_j)``: rows ``<= 1``, still reciprocal.

    Parameters
    ----------
    F : (N, N) sparse matrix
        Form factors.
    areas : (N,) array_like
        Face areas (model units squared), positive.
    tol : float
        Relative tolerance on the row sums of the balancing.
    maxiter : int
        Balancing iterations at most (each is one sparse product).

    Returns
    -------
    scipy.sparse.csr_matrix
        Reciprocal form factors; the sparsity pattern is the union of those of ``F`` and
        ``F.T``.
    """
    F = sp.csr_matrix(F, dtype=np.float64)
    a = np.asarray(areas, dtype=np.float64)
    if F.shape[0] != F.shape[1] or a.shape != (F.shape[0],):
        raise InputError(f"F {F.shape} and areas {a.shape} do not match")
    if not np.all(a > 0):
        raise InputError("areas: must be positive")
    AF = (sp.diags(a) @ F).tocsr()
    target = np.asarray(AF.sum(axis=1)).ravel()
    G = ((AF + AF.T) * 0.5).tocsr()
    G.sum_duplicates()
    x = np.ones(len(a))
    active = target > 0
    for _ in range(int(maxiter)):
        gx = G @ x
        got = x * gx
        ok = active & (got > 0)
        if np.all(np.abs(got[ok] - target[ok]) <= tol * target[ok]):
            break
        x = np.where(ok, np.sqrt(x * target / np.where(ok, gx, 1.0)), x)
    G = G.tocoo()
    G.data *= x[G.row] * x[G.col]
    s = np.bincount(G.row, weights=G.data, minlength=len(a)) / a
    if np.any(s > 1.0):
        c = np.minimum(1.0, 1.0 / np.maximum(s, 1e-300))
        G.data *= np.minimum(c[G.row], c[G.col])
    Fr = sp.csr_matrix((G.data / a[G.row], (G.row, G.col)), shape=F.shape)
    Fr.sum_duplicates()
    return Fr


def _positive_int(value, name: str) -> int:
    try:
        iv = int(value)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected a positive integer, got {value!r}") from None
    if iv != value or iv < 1:
        raise InputError(f"{name}: expected a positive integer, got {value!r}")
    return iv
