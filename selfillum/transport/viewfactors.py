"""Form factors between the faces of a triangle mesh, by Embree ray casting.

``F[i, j]`` is the fraction of the (Lambertian) light leaving face ``i`` that reaches face
``j`` directly, occlusion included. It is estimated by casting ``K`` cosine-distributed
rays from ``K`` stratified points of every face and counting ``1/K`` for each ray whose
first hit is the painted side of face ``j``:

``F_ij = (1 / A_i) integral_{A_i} integral_{A_j} cos(t_i) cos(t_j) V / (pi r^2) dA_j dA_i``

The points and directions are randomised quasi-Monte Carlo (a Sobol net with a random
digital shift per face): the estimator is unbiased, and its error falls faster than the
``1/sqrt(K)`` of independent rays (about ``K^-3/4``, measured against Howell's closed forms
in the former ``bench/bench_viewfactors.py``). ``F`` is a ``scipy.sparse`` CSR matrix with
at most ``K`` non-zeros a row, so memory grows as ``N K``, not ``N^2``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from resection._threads import available_cores, numba_threads
from resection.errors import InputError
from resection.memory import check_memory
from resection.surface.embree import Scene
from resection.surface.visibility import bounds, unit_normals
from selfillum.mesh import check_mesh, face_areas
from selfillum.transport.rowtrace import assemble_rows, trace_rows
from selfillum.transport.sampling import (
    _reversed_base,
    _sobol_base,
    digital_shifts,
    rqmc_points,
    sample_rays,
)

if TYPE_CHECKING:
    import scipy.sparse as sp
    import trimesh

__all__ = ["view_factors", "RowTracer", "enforce_reciprocity", "RayScene", "sample_rays",
           "rqmc_points", "digital_shifts"]

#: Ray origins are lifted off their face by this fraction of the mesh size.
_OFFSET = 1e-6
#: Default number of rays a chunk (4 bytes each in flight: their hits).
_RAYS_PER_CHUNK = 1 << 22
#: Bytes a ray of a chunk costs (its hit, before the misses are dropped), for the memory
#: check before a chunk is allocated.
_RAY_BYTES_MIN = 8


class RayScene:
    """An Embree scene of a mesh (:class:`resection.surface.embree.Scene`), in float32
    coordinates centred on the mesh's box.

    A model point ``x`` is at ``(x - origin) * scale`` in the scene (``scale`` is 1 for a
    scene built here; :meth:`from_caster` shares the scene of a
    :class:`resection.surface.visibility.RayCaster`, in that caster's frame).

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex coordinates (model units).
    faces : (N, 3) array_like of int
        Triangles.
    """

    #: Scene units per model unit.
    scale = 1.0

    def __init__(self, vertices, faces):
        v = np.asarray(vertices, dtype=np.float64)
        self.origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
        self.scene = Scene(v - self.origin, faces)

    @classmethod
    def from_caster(cls, caster) -> RayScene:
        """The scene of a :class:`~resection.surface.visibility.RayCaster`, not built
        again: its frame (``origin``, ``scale``) and its committed Embree scene."""
        self = cls.__new__(cls)
        self.origin, self.scale, self.scene = caster.origin, caster.scale, caster.scene
        self._caster = caster  # keeps the scene alive
        return self

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Index of the first face hit by each ray (``-1`` for a miss), ``(M,)`` int64."""
        o = np.ascontiguousarray((origins - self.origin) * self.scale, dtype=np.float32)
        d = np.ascontiguousarray(directions, dtype=np.float32)
        return self.scene.run(o, d).astype(np.int64)

    def run(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """First face hit by rays already in the scene's frame, float32 ``(M, 3)`` arrays
        (``-1`` for a miss), ``(M,)`` int32, traced on numba's threads."""
        return self.scene.run(origins, directions)


#: The ray tracers :func:`view_factors` can use.
TRACERS = ("embree", "mitsuba")




@dataclass(frozen=True)
class _Job:
    """What every chunk of :func:`view_factors` needs (sent once to each worker)."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    normals32: np.ndarray
    k: int
    seed: int
    offset: float
    two_sided: bool
    rbase: np.ndarray  # bit-reversed Sobol base points (K, 4 or 5), uint64


def _scene(tracer: str, job: _Job, launch: int | None, mesh: trimesh.Trimesh, caster=None):
    """The scene of ``tracer``: Embree's in the frame of a
    :class:`~resection.surface.visibility.RayCaster` (``caster``'s, shared, or one built
    here: the same frame either way, so the same rays and hits), or Mitsuba's (OptiX on a
    GPU, else LLVM), which also samples the rays and sums them into ``F`` in Dr.Jit
    (``launch`` faces at once)."""
    if tracer == "mitsuba":
        from selfillum.transport.mitsuba_factors import MitsubaFactorTracer

        return MitsubaFactorTracer(job.vertices, job.faces, job.normals, job.k, job.seed,
                                   offset=job.offset, two_sided=job.two_sided,
                                   faces_per_launch=launch)
    if caster is None:
        from resection.surface.visibility import RayCaster

        caster = RayCaster(mesh)
    return RayScene.from_caster(caster)


def _trace_rows(job: _Job, scene: RayScene, rows: np.ndarray):
    """Hits of the rays of faces ``rows``: ``(counts per row, hit faces)``, both int32,
    the hits grouped by row in the order of ``rows`` (duplicates kept); made, traced and
    filtered in one compiled pass on numba's threads
    (:func:`selfillum.transport.rowtrace.trace_rows`)."""
    return trace_rows(scene, rows, job.vertices, job.faces, job.normals, job.normals32,
                      job.rbase, job.seed, job.two_sided, job.offset)


def view_factors(
    mesh: trimesh.Trimesh,
    rays_per_face: int = 256,
    seed: int = 0,
    *,
    reciprocity: bool = False,
    chunk_size: int | None = None,
    two_sided: bool = False,
    rows=None,
    workers: int | None = None,
    progress: bool | Callable | None = False,
    tracer: str = "embree",
    caster=None,
) -> sp.csr_matrix:
    """Form factors between the faces of a mesh, with occlusion, by Embree ray casting.

    Each face casts ``K`` cosine-distributed rays from uniform points of itself; each ray
    whose first hit is the painted side of face ``j`` adds ``1/K`` to ``F[i, j]``. The
    points are randomised quasi-Monte Carlo (Sobol, a random digital shift per face, see
    :func:`rqmc_points`): the estimate is unbiased and its error falls faster than the
    ``1/sqrt(K)`` of independent rays.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh; faces are the radiosity elements. Its painted side is the side
        its normals point to (right-hand rule on the vertex order).
    rays_per_face : int
        ``K``, rays cast from each face; each hit adds ``1/K``. Powers of 2 make the
        best use of the Sobol points.
    seed : int
        Seed of the random shifts. A row depends only on ``mesh``, ``rays_per_face``,
        ``seed``, ``two_sided`` and its face index (not on ``chunk_size``, ``rows`` or
        ``workers``).
    reciprocity : bool
        Enforce ``A_i F_ij = A_j F_ji`` by area-weighted symmetrisation and symmetric
        balancing to the raw row sums (see :func:`enforce_reciprocity`); the sparsity
        pattern then is the union of those of ``F`` and ``F.T`` (up to ``2 K`` non-zeros
        a row). Needs every row (``rows`` not given).
    chunk_size : int, optional
        Faces traced at once (split over the threads); memory in flight is about
        ``chunk_size * K * 4`` bytes (the hits, before the misses are dropped). Default:
        about ``2**22 / K`` faces (about 4 million rays a chunk).
    two_sided : bool
        Faces painted on both sides with the same radiosity (thin sheets): half the
        rays of a face leave from its back, and hits on either side count. With the
        default ``False`` rays leave the painted side only and a ray that reaches the
        back of a face is absorbed there (it counts nowhere).
    rows : array_like of int or bool, optional
        Only these faces cast rays (indices, or a boolean mask of length ``N``); the
        other rows of ``F`` are empty. Each computed row is the one the full
        computation gives.
    workers : int, optional
        numba threads over the faces of each chunk, tracing in one Embree scene (the rays
        are made, traced and filtered in one compiled pass that releases Python's GIL;
        numba's thread count is set for the call and restored after; at most numba's
        ``NUMBA_NUM_THREADS``). Default: the CPUs this process may use; ``1`` traces in the
        calling thread.
    progress : bool or callable
        ``True`` shows a ``tqdm`` bar over chunks; a callable is called with
        ``(faces_done, faces_total)`` after each chunk.
    tracer : {"embree", "mitsuba"}
        Who traces the rays: Embree (the default, CPU: the Embree 4 library of the
        ``embreex`` wheel, called through :mod:`resection.surface.embree` on shared buffers;
        each face's rays are made, traced and filtered in one compiled pass on numba's
        threads, :mod:`selfillum.transport.rowtrace`), or Mitsuba /
        Dr.Jit (OptiX on a CUDA GPU when one works, else Dr.Jit's LLVM backend on every CPU
        core, in this process). With ``"mitsuba"`` the rays are also made and summed per
        face pair in Dr.Jit where they are traced
        (:mod:`selfillum.transport.mitsuba_factors`): only the per-pair sums come back, and
        each row's column indices are unique but not sorted. The rays are the same; the two
        F differ only for rays that graze an edge in float32 (a ray's weight in a few
        entries). The Embree path, making the rays included, runs at 0.64-0.81x the speed
        of one bare ``embreex`` call on the same prepared rays on one thread and at
        1.20-1.66x on two (main before the native binding: 0.60-0.81x and 1.08-1.47x in the
        same run, 2 cores, load 5-6; bench/README.md, issue 21 items 4-5, fourth pass).
        The Mitsuba figures that follow were measured against that previous Embree path
        (``embreex`` from a Python thread pool), which took up to 1.13x the time of
        today's. On the CPU (``llvm`` variant, 2 cores, load 3-5) whole
        ``view_factors`` with ``"mitsuba"`` ran at 0.9-1.0x the speed of threaded Embree
        where every ray hits and 1.7-3.3x where most rays escape, and at 0.26-0.60x the
        speed of its bare rays (``ray_intersect_preliminary`` on the same rays): making a
        ray costs about as much as tracing one that escapes, and the scene build and the
        mesh checks are not in the bare figure. On a GPU (one H100 without RT cores, 16 CPU
        cores, Mitsuba 3.9.1 ``cuda``, measured 2026-11-27, bench/README.md "Issue 21 item 6
        on an H100"), whole ``view_factors`` with ``"mitsuba"`` ran at 4.3-13.4x the speed
        of ``"embree"`` over the 16 threads on a 609k-face grid (0.08 s against 0.35-1.10 s
        at K = 64 and 256: 485-1,903 M rays/s) and 4.4-5.4x inside a sphere where every ray
        hits (78-99 M rays/s, against 69 M rays/s for bare OptiX rays made and read back in
        NumPy), with the same F but for a ray's weight in 20-134 entries; its scene build
        takes 0.03-0.04 s, its launches 2.6-4.8 times the bare traversal of the same rays
        already on the device. So on a CUDA GPU ``"mitsuba"`` is the faster choice;
        ``"embree"`` stays the default (every machine, the tests' reference path).
    caster : resection.surface.visibility.RayCaster, optional
        An Embree scene of ``mesh`` already built, traced in instead of building one (see
        :class:`RowTracer`): a command that also maps images onto ``mesh`` builds one scene.

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
    n = len(mesh.faces)
    todo = _as_rows(rows, n)
    if reciprocity and todo.size != n:
        raise InputError("view_factors: reciprocity needs every row (rows not given)")
    with RowTracer(mesh, rays_per_face, seed, two_sided=two_sided, chunk_size=chunk_size,
                   workers=workers, n_rows=todo.size, tracer=tracer, checked=True,
                   caster=caster) as rt:
        F = rt.rows(todo, progress=progress)
    if reciprocity:
        F = enforce_reciprocity(F, face_areas(mesh))
    return F


class RowTracer:
    """Rows of ``F`` traced on demand, with one Embree scene kept for every call.

    :func:`view_factors` is one call of this; callers that need rows in rounds (the
    faces coupled to the seen ones, :mod:`selfillum.transport.coupling`) keep one tracer, so that
    the scene is built once. Each row is the one the full
    computation gives (the RQMC points of a face are keyed on its index).

    Parameters
    ----------
    mesh, rays_per_face, seed, two_sided, chunk_size, workers, tracer
        As in :func:`view_factors` (with ``tracer="mitsuba"`` the rays are made, traced and
        summed per face pair in this process, by Dr.Jit on its device:
        :class:`~selfillum.transport.mitsuba_factors.MitsubaFactorTracer`; ``chunk_size``
        is then the faces of a launch, default about ``2**24 / K``).
    n_rows : int, optional
        Rows expected in all (decides whether threads pay off; default all faces).
    caster : resection.surface.visibility.RayCaster, optional
        An Embree scene of ``mesh`` already built (e.g. the one a
        :class:`~resection.surface.SurfaceMap` of the same mesh was cast with): its scene
        and face normals are used, not built again. Without it the tracer builds one, in
        the same frame, so a row is the same either way.
    checked : bool
        ``mesh`` has passed :func:`selfillum.mesh.check_mesh` already (the caller checked
        it): not checked again.

    Use it as a context manager, or call :meth:`close` (nothing is left running either
    way: the threads are numba's, set for each call).
    """

    def __init__(self, mesh: trimesh.Trimesh, rays_per_face: int = 256, seed: int = 0, *,
                 two_sided: bool = False, chunk_size: int | None = None,
                 workers: int | None = None, n_rows: int | None = None,
                 tracer: str = "embree", caster=None, checked: bool = False):
        if not checked:
            check_mesh(mesh)
        if tracer not in TRACERS:
            raise InputError(f"tracer: expected one of {', '.join(TRACERS)}, got {tracer!r}")
        if caster is not None and caster.n_faces != len(mesh.faces):
            raise InputError(f"caster: built for {caster.n_faces} faces, the mesh has "
                             f"{len(mesh.faces)}")
        self.tracer = tracer
        self.mesh = mesh
        self._caster = caster if tracer == "embree" else None
        k = _positive_int(rays_per_face, "rays_per_face")
        self.chunk = (max(1, _RAYS_PER_CHUNK // k) if chunk_size is None
                      else _positive_int(chunk_size, "chunk_size"))
        # the rays of one chunk are allocated at once: refuse what cannot be, before
        check_memory(min(self.chunk, n_rows or len(mesh.faces)) * float(k) * _RAY_BYTES_MIN,
                     f"view factors with {k} rays per face")
        try:
            seed = int(seed)
        except (TypeError, ValueError):
            raise InputError(f"seed: expected an integer, got {seed!r}") from None
        if seed < 0:
            raise InputError(f"seed: expected a non-negative integer, got {seed}")
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
        self.n, self.k = len(faces), k
        lo, hi = bounds(vertices)
        size = float((hi - lo).max())
        # unit normals, compiled (the caster's when given): face_normals' values
        normals = (unit_normals(vertices, faces) if self._caster is None
                   else self._caster.normals)
        rbase = _reversed_base(_sobol_base(k, 5 if two_sided else 4))
        self.job = _Job(vertices, faces, normals, normals.astype(np.float32), k, seed,
                        _OFFSET * size, bool(two_sided), rbase)
        self.nproc = 1 if tracer == "mitsuba" else _workers(workers)
        self._launch = None if chunk_size is None else self.chunk  # faces a Dr.Jit launch
        self._scene = None

    def __enter__(self) -> RowTracer:
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False

    def close(self) -> None:
        """Drop the scene (a caster's scene stays with its caster)."""
        self._scene = None

    def _start(self) -> None:
        self._scene = _scene(self.tracer, self.job, self._launch, self.mesh, self._caster)
        if self.tracer == "mitsuba":
            return
        # compile (or load from numba's cache) the kernels once, on one face
        with numba_threads(1):
            _trace_rows(self.job, self._scene, np.arange(1))

    def rows(self, rows, progress: bool | Callable | None = None) -> sp.csr_matrix:
        """``F`` with only ``rows`` filled (indices or a boolean mask), ``(N, N)`` CSR.

        ``progress`` as in :func:`view_factors`.
        """
        if self.tracer == "mitsuba":  # sampled, traced and summed in Dr.Jit
            if self._scene is None:
                self._start()
            return self._scene.rows(_as_rows(rows, self.n), progress=progress)
        counts, hits = self.hits(rows, progress)
        with numba_threads(self.nproc):
            return _assemble(self.n, self.k, counts, hits)

    def hits(self, rows, progress: bool | Callable | None = None) -> tuple[np.ndarray, list]:
        """The rays' hits of ``rows`` before they are assembled into ``F``: ``(counts,
        parts)``, ``counts`` the kept hits of every face (``(N,)`` int64, 0 outside
        ``rows``) and ``parts`` a list of ``(faces, hit faces)`` arrays, the hits grouped
        by face in the order of ``faces``. :meth:`assemble` makes ``F`` of one or more
        such results of disjoint rows (one sparse assembly for several rounds). Embree
        only (Mitsuba sums the rays into ``F`` itself: :meth:`rows`)."""
        if self.tracer != "embree":
            raise InputError("RowTracer.hits: the embree tracer only (use rows)")
        todo = _as_rows(rows, self.n)
        if self._scene is None:
            self._start()
        # as many chunks of at most ``chunk`` faces as it takes, of equal size; each is
        # split over the threads
        n_chunks = -(-todo.size // self.chunk)
        step = max(1, -(-todo.size // max(1, n_chunks)))
        chunks = [todo[i:i + step] for i in range(0, todo.size, step)]
        bar = None
        if progress is True:
            from tqdm.auto import tqdm

            bar = tqdm(total=todo.size, desc="view factors", unit="face", leave=False)
        done = 0
        counts = np.zeros(self.n, dtype=np.int64)
        hits = []
        for part in chunks:
            with numba_threads(self.nproc):
                c, h = _trace_rows(self.job, self._scene, part)
            counts[part] = c
            hits.append((part, h))
            done += part.size
            if bar is not None:
                bar.update(part.size)
            elif callable(progress):
                progress(done, todo.size)
        if bar is not None:
            bar.close()
        return counts, hits

    def assemble(self, counts: np.ndarray, hits: list) -> sp.csr_matrix:
        """``F`` (``(N, N)`` CSR) from what :meth:`hits` returned (counts summed and parts
        joined over calls of disjoint rows)."""
        with numba_threads(self.nproc):
            return _assemble(self.n, self.k, counts, hits)


def _assemble(n: int, k: int, counts: np.ndarray, hits: list) -> sp.csr_matrix:
    """CSR ``F`` from the per-row hit counts and the hit lists of each chunk
    (:func:`selfillum.transport.rowtrace.assemble_rows`, on numba's threads)."""
    return assemble_rows(n, k, counts, hits)


def _as_rows(rows, n: int) -> np.ndarray:
    """Sorted unique face indices from ``rows`` (indices or a boolean mask)."""
    if rows is None:
        return np.arange(n)
    r = np.asarray(rows)
    if r.dtype == bool:
        if r.shape != (n,):
            raise InputError(f"rows: boolean mask of shape {r.shape} for {n} faces")
        return np.flatnonzero(r)
    if r.size and not np.issubdtype(r.dtype, np.integer):
        raise InputError(f"rows: expected face indices or a boolean mask, got {r.dtype}")
    r = r.astype(np.int64).ravel()
    if r.size > 1 and not np.all(r[1:] > r[:-1]):  # already sorted and unique: kept
        r = np.unique(r)
    if r.size and (r[0] < 0 or r[-1] >= n):
        raise InputError(f"rows: face indices must be in [0, {n}), got {r[0]}..{r[-1]}")
    return r


def _workers(workers) -> int:
    """Number of tracing threads: ``workers`` if given, else the usable CPUs."""
    if workers is not None:
        return _positive_int(workers, "workers")
    return available_cores()


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
    import scipy.sparse as sp
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
