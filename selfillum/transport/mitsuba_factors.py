"""Rows of the form factors ``F`` made where Mitsuba traces the rays: sampling, tracing and
accumulation in Dr.Jit arrays (OptiX on a CUDA GPU, Dr.Jit's LLVM backend on the CPU).

:func:`selfillum.view_factors` with ``tracer="mitsuba"`` uses :class:`MitsubaFactorTracer`.
A launch covers a block of faces (``2**24`` rays by default) in three Dr.Jit kernels:

1. **trace** (one lane for ``gcd(K, 16)`` rays of a face): make the rays of
   :func:`selfillum.transport.sampling.sample_rays` (the same Sobol points of Joe and
   Kuo's table, the same per-face Owen scramble keyed on the face index and the seed, the
   same float32 formulas: uniform points of the face lifted by the offset,
   cosine-distributed directions; Dr.Jit's ``sin``/``cos`` and the tangent frame rebuilt
   in float32 differ from NumPy's by an ulp or so), trace them
   (``Scene.ray_intersect_preliminary``), drop misses, hits on the ray's own face and
   (one-sided) hits on a face's back as the Embree path does, and list the kept rays
   (row, hit face) by stream compaction (``dr.scatter_inc``);
2. **sum per pair**: each kept ray adds one to the count of its (emitting face, hit face)
   pair in its row's hash table (``2**ceil(log2 2c)`` slots for a row of ``c`` kept rays:
   at most half full), by lock-free linear probing (``dr.scatter_cas``) and atomic adds;
   the ray that makes a pair lists it, with its rank in its row (``dr.scatter_inc``);
3. **CSR order**: each pair written at its row's offset (``dr.prefix_sum`` of the pairs
   per row) plus its rank.

Nothing goes back to NumPy per ray: only the per-pair sums (hit face, count, row by row)
and the pairs per row, from which the SciPy CSR matrix is built. Within a row the columns
are unique but in no set order (``F.has_sorted_indices`` is False; a device sort would cost
more than the rest on the CPU: Dr.Jit's radix sort there takes 25-100 ns a key). The
counts are integers, so ``F`` does not depend on the order of the atomic operations, on
the launch size, the thread count or the device. A launch holds at most about 52 bytes a
ray on the device (8 for the list of kept rays; for a kept ray up to 32 of hash table and
12 of pair lists): the default launch about 0.9 GB when every ray hits, much less when
most escape.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from resection.errors import InputError
from resection.memory import check_memory
from selfillum.transport.mitsuba_rays import MitsubaRayScene
from selfillum.transport.sampling import _KEY_DIM, _KEY_FACE, _KEY_SEED, _MIX1, _MIX2, _sobol_base

__all__ = ["MitsubaFactorTracer", "RAYS_PER_LAUNCH"]

#: Rays in one launch by default (at most :data:`_BYTES_PER_RAY` bytes each on the device).
RAYS_PER_LAUNCH = 1 << 24
#: Rays a lane of the trace kernel casts at most (all from one face).
_RAYS_PER_LANE = 16
#: Bytes a ray of a launch may take on the device: its listing (8) and, when it is kept,
#: its hash table slots (up to 4 of 8 bytes) and pair lists (12).
_BYTES_PER_RAY = 52
#: An empty slot of the hash table (slots hold the hit face + 1: a table is emptied by a
#: plain memset).
_EMPTY = 0
#: Knuth's multiplicative hash (2**32 / golden ratio), for the first slot of a hit face.
_GOLDEN = 0x9E3779B1
#: The Laine-Karras constants of the Owen scramble (as in ``sampling._owen``).
_LK = (0x6C50B47C, 0xB82F1E52, 0xC7AFE638, 0x8D22F6E6)


class MitsubaFactorTracer:
    """Rows of ``F`` sampled, traced and accumulated in Dr.Jit (see the module).

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex coordinates (model units).
    faces : (N, 3) array_like of int
        Triangles; their painted side by the right-hand rule.
    normals : (N, 3) array_like
        Unit face normals (painted side), float64.
    rays_per_face : int
        ``K``; each kept ray adds ``1/K``.
    seed : int
        Seed of the RQMC scramble (as :func:`selfillum.view_factors`).
    offset : float
        Lift of the ray origins off their face, model units.
    two_sided : bool
        As :func:`selfillum.view_factors`.
    variant : str, optional
        See :func:`selfillum.transport.mitsuba_rays.tracing_variant`.
    faces_per_launch : int, optional
        Faces traced in one launch; default about ``2**24 / K`` (see :data:`RAYS_PER_LAUNCH`).

    Attributes
    ----------
    scene : MitsubaRayScene
        The Mitsuba scene (its ``origin`` is the centre of the mesh's box; rays are traced
        relative to it, in float32).
    """

    def __init__(self, vertices, faces, normals, rays_per_face: int, seed: int = 0, *,
                 offset: float = 0.0, two_sided: bool = False, variant: str | None = None,
                 faces_per_launch: int | None = None):
        self.scene = MitsubaRayScene(vertices, faces, variant=variant)
        self.n = self.scene.n_faces
        self.k = int(rays_per_face)
        if self.k < 1:
            raise InputError(f"rays_per_face: expected a positive integer, got {rays_per_face}")
        self.launch = (max(1, RAYS_PER_LAUNCH // self.k) if faces_per_launch is None
                       else int(faces_per_launch))
        if self.launch < 1:
            raise InputError(f"faces_per_launch: expected a positive integer, got "
                             f"{faces_per_launch}")
        if self.launch * self.k >= 1 << 30:  # the tables: up to 4 slots a kept ray
            raise InputError(f"tracer mitsuba: {self.launch} faces of {self.k} rays are too "
                             "many for one launch (32-bit indices)")
        if self.n >= 0xFFFFFFFF:
            raise InputError(f"tracer mitsuba: {self.n} faces are too many (32-bit indices)")
        self.two_sided = bool(two_sided)
        self.dims = 5 if self.two_sided else 4
        self.offset = np.float32(offset)
        seed = int(seed)
        if not 0 <= seed < 1 << 64:
            raise InputError(f"seed: expected an integer in [0, 2**64), got {seed}")
        nrm = np.asarray(normals, dtype=np.float32)
        base = _sobol_base(self.k, self.dims)  # (k, dims) uint32
        # the scramble works on bit-reversed Sobol integers (``sampling._reversed_base``)
        rbase = _reverse_bits(base)
        mi, dr = self.scene._mi, self.scene._dr
        with self.scene._variant():
            # 12 floats a face, made on the device from the scene's float32 vertices (the
            # values NumPy gives for ``(v[faces] - origin).astype(float32)`` and its float32
            # edges); the centre and the tangent frame are rebuilt once a lane
            # (``_face_data``)
            corner = [dr.gather(mi.Vector3f, self.scene.positions,
                                dr.gather(mi.UInt32, self.scene.faces,
                                          dr.arange(mi.UInt32, self.n) * 3 + c))
                      for c in range(3)]
            self._face = {"v0": corner[0], "e1": corner[1] - corner[0],
                          "e2": corner[2] - corner[0], "n": _vector(mi, nrm)}
            self._rbase = mi.UInt32(np.ascontiguousarray(rbase).ravel())
            self._keys = _digital_shifts(mi, dr, seed, self.n, self.dims)
            dr.eval(self._face, self._rbase, self._keys)

    # ------------------------------------------------------------------ the rays
    def _face_data(self, face):
        """What the rays of ``face`` (UInt32, global indices) need: its vertex, edges,
        centre, normal and tangent frame (``Vector3f``) and its scramble keys (one ``UInt32``
        a dimension); in the trace kernel, once a lane."""
        mi, dr = self.scene._mi, self.scene._dr
        g = {name: dr.gather(mi.Vector3f, a, face) for name, a in self._face.items()}
        g["c"] = g["v0"] + (g["e1"] + g["e2"]) * (1.0 / 3.0)
        g["t1"], g["t2"] = _frame(mi, dr, g["n"])
        keys = [dr.gather(mi.UInt32, self._keys, face * self.dims + d) for d in range(self.dims)]
        return g, keys

    def _rays(self, g, keys, local):
        """Rays from the data of :meth:`_face_data` and ``local`` (UInt32, the sample index
        within the face). Returns the ray and the side (+1/-1 Float)."""
        mi, dr = self.scene._mi, self.scene._dr
        UInt32, Float = mi.UInt32, mi.Float

        def point(d):
            x = dr.gather(UInt32, self._rbase, local * self.dims + d) + keys[d]
            for c in _LK:
                x ^= x * c
            x = dr.brev(x)
            return (Float(x >> 8) + 0.5) * (2.0 ** -24)

        p0, p1, p2, p3 = (point(d) for d in range(4))
        sd = Float(1.0)
        if self.two_sided:
            sd = dr.select(point(4) >= 0.5, -1.0, 1.0)
        sa = dr.sqrt(p0)
        w2 = sa * p1
        w1 = sa - w2
        o = g["v0"] + w1 * g["e1"] + w2 * g["e2"]
        off = float(self.offset)
        if off > 0:
            to_c = g["c"] - o
            d = dr.sqrt(dr.squared_norm(to_c))
            lift = off / dr.maximum(d, off)
            o = o + (to_c * lift + (sd * off) * g["n"])
        rr = dr.sqrt(p2)
        s, c = dr.sincos(p3 * float(np.float32(2.0 * np.pi)))
        lz = dr.sqrt(dr.maximum(0.0, 1.0 - p2)) * sd
        direction = (rr * c) * g["t1"] + (rr * s) * g["t2"] + lz * g["n"]
        return mi.Ray3f(mi.Point3f(o), mi.Vector3f(direction)), sd

    def _chunk_indices(self, rows: np.ndarray):
        """Per ray of a chunk of faces: its global face and its sample index."""
        mi, dr = self.scene._mi, self.scene._dr
        ids = mi.UInt32(np.ascontiguousarray(rows, dtype=np.uint32))
        r = dr.arange(mi.UInt32, rows.size * self.k)
        row = r // self.k
        return row, dr.gather(mi.UInt32, ids, row), r - row * self.k

    def rays(self, rows) -> tuple[np.ndarray, np.ndarray]:
        """The rays of faces ``rows`` as NumPy ``(n K, 3)`` float32 origins and directions
        (relative to :attr:`scene` ``.origin``), for tests and benchmarks: the same rays
        :meth:`rows` traces."""
        rows = np.asarray(rows, dtype=np.int64)
        with self.scene._variant():
            _, face, local = self._chunk_indices(rows)
            ray, _ = self._rays(*self._face_data(face), local)
            return np.asarray(ray.o).T.copy(), np.asarray(ray.d).T.copy()

    def device_rays(self, rows):
        """The rays of faces ``rows`` as an evaluated Mitsuba ``Ray3f`` (on the device),
        for benchmarks that trace the same rays bare."""
        rows = np.asarray(rows, dtype=np.int64)
        with self.scene._variant():
            _, face, local = self._chunk_indices(rows)
            ray, _ = self._rays(*self._face_data(face), local)
            self.scene._dr.eval(ray)
            return ray

    # ------------------------------------------------------------------ one launch
    def _trace(self, rows: np.ndarray):
        """Kernel 1: one lane for ``S`` rays of a face (``S = gcd(K, 16)``: the face's data
        gathered once for them, while a launch keeps ``n K / S`` lanes to spread over a
        GPU), looping over them: sample, trace, filter, and list the kept rays (stream
        compaction). Returns, evaluated, the kept rays' rows (in the launch) and hit faces
        + 1 (the first ``n_kept`` entries), ``n_kept`` and the kept rays of each row."""
        mi, dr = self.scene._mi, self.scene._dr
        UInt32 = mi.UInt32
        per_lane = math.gcd(self.k, _RAYS_PER_LANE)
        lanes = self.k // per_lane  # lanes a face
        ids = UInt32(np.ascontiguousarray(rows, dtype=np.uint32))
        j = dr.arange(UInt32, rows.size * lanes)
        row = j // lanes
        face = dr.gather(UInt32, ids, row)
        first = (j - row * lanes) * per_lane
        g, keys = self._face_data(face)
        kept_row = dr.empty(UInt32, rows.size * self.k)
        kept_hit = dr.empty(UInt32, rows.size * self.k)
        n_kept = dr.zeros(UInt32, 1)

        def more(i, kept):
            return i < per_lane

        def one_ray(i, kept):
            ray, _ = self._rays(g, keys, first + i)
            pi = self.scene._scene.ray_intersect_preliminary(ray, coherent=False)
            hit = UInt32(pi.prim_index)
            keep = pi.is_valid() & (hit != face)
            if not self.two_sided:  # a ray arriving on the unpainted side is absorbed there
                n_hit = dr.gather(mi.Vector3f, self._face["n"], hit, keep)
                keep &= dr.dot(ray.d, n_hit) < 0
            at = dr.scatter_inc(n_kept, UInt32(0), active=keep)
            dr.scatter(kept_row, row, at, active=keep)
            dr.scatter(kept_hit, hit + 1, at, active=keep)
            return i + 1, dr.select(keep, kept + 1, kept)

        zero = dr.zeros(UInt32, rows.size * lanes)
        _, kept = dr.while_loop((zero, UInt32(zero)), more, one_ray, labels=("i", "kept"))
        dr.eval(kept_row, kept_hit, n_kept, kept)
        if lanes > 1:
            kept = dr.block_sum(kept, lanes, mode="evaluated")
        return kept_row, kept_hit, int(n_kept[0]), kept

    def _insert(self, kept_row, kept_hit, n_kept: int, kept, n_rows: int):
        """Kernel 2: each kept ray adds one to the count of its (row, hit face) pair in its
        row's hash table (``2**ceil(log2(2 c))`` slots for a row of ``c`` kept rays: at most
        half full), by linear probing; the ray that makes a pair lists its slot, its row and
        its rank in the row. Returns, evaluated: the tables and counts, the pairs' slots,
        rows and ranks (first ``n_pairs``), the pairs per row and ``n_pairs``."""
        mi, dr = self.scene._mi, self.scene._dr
        UInt32 = mi.UInt32
        bits = dr.select(kept > 0, 32 - dr.lzcnt(2 * kept - 1), 0)  # log2 of the row's slots
        size = dr.select(kept > 0, UInt32(1) << bits, 0)
        start = dr.prefix_sum(size)
        dr.eval(bits, start)
        total = int(dr.gather(UInt32, start, UInt32(n_rows - 1))[0]) + int(
            dr.gather(UInt32, size, UInt32(n_rows - 1))[0])
        table = dr.zeros(UInt32, total)  # slots hold the hit face + 1 (0: empty)
        counts = dr.zeros(UInt32, total)
        pair_slot, pair_row, pair_rank = (dr.empty(UInt32, n_kept) for _ in range(3))
        m = dr.arange(UInt32, n_kept)
        row = dr.gather(UInt32, kept_row, m)
        hit = dr.gather(UInt32, kept_hit, m)
        b = dr.gather(UInt32, bits, row)
        base = dr.gather(UInt32, start, row)
        mask = (UInt32(1) << b) - 1
        slot = (hit * _GOLDEN) >> (32 - b)

        def probing(slot, done, new):
            return ~done

        def probe(slot, done, new):  # claim an empty slot, or find the pair's
            old, ok = dr.scatter_cas(table, UInt32(_EMPTY), hit, base + slot, active=~done)
            done = done | ok | (old == hit)
            return dr.select(done, slot, (slot + 1) & mask), done, new | ok

        slot, _, new = dr.while_loop((slot, dr.zeros(mi.Bool, n_kept),
                                      dr.zeros(mi.Bool, n_kept)),
                                     probing, probe, labels=("slot", "done", "new"))
        slot = base + slot
        # plain atomics (the LLVM backend's default would copy the counts once a thread)
        dr.scatter_reduce(dr.ReduceOp.Add, counts, UInt32(1), slot, mode=dr.ReduceMode.Direct)
        n_pairs = dr.zeros(UInt32, 1)
        per_row = dr.zeros(UInt32, n_rows)
        at = dr.scatter_inc(n_pairs, UInt32(0), active=new)
        dr.scatter(pair_slot, slot, at, active=new)
        dr.scatter(pair_row, row, at, active=new)
        dr.scatter(pair_rank, dr.scatter_inc(per_row, row, active=new), at, active=new)
        dr.eval(table, counts, pair_slot, pair_row, pair_rank, per_row, n_pairs)
        return table, counts, pair_slot, pair_row, pair_rank, per_row, int(n_pairs[0])

    def _launch(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-pair sums of the faces ``rows``: ``(nnz per row, hit faces, counts)``, the
        pairs grouped by row in the order of ``rows`` (within a row, in no set order)."""
        mi, dr = self.scene._mi, self.scene._dr
        UInt32 = mi.UInt32
        kept_row, kept_hit, n_kept, kept = self._trace(rows)
        if n_kept == 0:  # nothing hit: empty rows
            return np.zeros(rows.size, np.int64), np.zeros(0, np.int32), np.zeros(0, np.uint32)
        table, counts, pair_slot, pair_row, pair_rank, per_row, n_pairs = self._insert(
            kept_row, kept_hit, n_kept, kept, rows.size)
        del kept_row, kept_hit
        # kernel 3: the pairs in CSR order, row by row
        pairs = dr.arange(UInt32, n_pairs)
        where = dr.gather(UInt32, pair_slot, pairs)
        dest = (dr.gather(UInt32, dr.prefix_sum(per_row), dr.gather(UInt32, pair_row, pairs))
                + dr.gather(UInt32, pair_rank, pairs))
        cols = dr.zeros(UInt32, n_pairs)
        cnt = dr.zeros(UInt32, n_pairs)
        dr.scatter(cols, dr.gather(UInt32, table, where) - 1, dest)
        dr.scatter(cnt, dr.gather(UInt32, counts, where), dest)
        dr.eval(cols, cnt)
        return (np.asarray(per_row, dtype=np.int64), np.asarray(cols, dtype=np.int32),
                np.asarray(cnt))

    def rows(self, rows, progress: bool | Callable | None = None) -> sp.csr_matrix:
        """``F`` with only ``rows`` (sorted unique face indices) filled, ``(N, N)`` CSR (each
        row's columns unique, not sorted); ``progress`` as in :func:`selfillum.view_factors`."""
        todo = np.asarray(rows, dtype=np.int64)
        check_memory(min(self.launch, max(todo.size, 1)) * float(self.k * _BYTES_PER_RAY),
                     f"view factors with {self.k} rays per face (tracer mitsuba)")
        bar = None
        if progress is True:
            from tqdm.auto import tqdm

            bar = tqdm(total=todo.size, desc="view factors", unit="face", leave=False)
        nnz = np.zeros(self.n, dtype=np.int64)
        cols, cnts = [], []
        with self.scene._variant():
            # launches of equal size
            step = max(1, -(-todo.size // max(1, -(-todo.size // self.launch))))
            for a in range(0, todo.size, step):
                part = todo[a:a + step]
                per_row, c, w = self._launch(part)
                nnz[part] = per_row
                cols.append(c)
                cnts.append(w)
                done = a + part.size
                if bar is not None:
                    bar.update(part.size)
                elif callable(progress):
                    progress(done, todo.size)
        if bar is not None:
            bar.close()
        indptr = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(nnz, out=indptr[1:])
        indices = np.concatenate(cols) if cols else np.zeros(0, np.int32)
        data = (np.concatenate(cnts).astype(np.float64) if cnts else np.zeros(0)) / self.k
        F = sp.csr_matrix((data, indices, indptr), shape=(self.n, self.n))
        F.has_sorted_indices = False  # each row's columns are unique, in hash order
        return F


def _digital_shifts(mi, dr, seed: int, n: int, dims: int):
    """:func:`selfillum.transport.sampling.digital_shifts` of faces ``0 .. n - 1`` made on
    the device: ``(n dims,)`` UInt32, face ``f``'s key of dimension ``d`` at ``f dims + d``
    (the same 64-bit SplitMix hash, wrapping unsigned arithmetic)."""
    u64 = mi.UInt64
    mix1, mix2 = u64(int(_MIX1)), u64(int(_MIX2))

    def mix(x):
        x = x ^ (x >> 30)
        x = x * mix1
        x = x ^ (x >> 27)
        x = x * mix2
        return x ^ (x >> 31)

    i = dr.arange(mi.UInt32, n * dims)
    face = i // dims
    key = (u64(seed) * u64(int(_KEY_SEED)) + u64(face) * u64(int(_KEY_FACE))
           + u64(i - face * dims) * u64(int(_KEY_DIM)))
    return mi.UInt32(mix(mix(key)) >> 32)


def _frame(mi, dr, n):
    """The tangent frame of :func:`selfillum.transport.sampling._tangent_frames`, per
    ray in float32: ``t1 = n x h / |n x h|`` (``h = x``, or ``y`` when ``|n_x| >= 0.9``),
    ``t2 = n x t1``."""
    x_axis = dr.abs(n.x) < 0.9
    h = mi.Vector3f(dr.select(x_axis, 1.0, 0.0), dr.select(x_axis, 0.0, 1.0), 0.0)
    t1 = dr.normalize(dr.cross(n, h))
    return t1, dr.cross(n, t1)


def _vector(mi, a: np.ndarray):
    """A Dr.Jit ``Vector3f`` of the rows of an ``(n, 3)`` float32 array."""
    a = np.asarray(a, dtype=np.float32)
    return mi.Vector3f(*(mi.Float(np.ascontiguousarray(a[:, c])) for c in range(3)))


def _reverse_bits(x: np.ndarray) -> np.ndarray:
    """The 32 bits of each uint32 reversed (vectorised)."""
    x = np.asarray(x, dtype=np.uint32).copy()
    for shift, mask in ((1, 0x55555555), (2, 0x33333333), (4, 0x0F0F0F0F), (8, 0x00FF00FF)):
        m = np.uint32(mask)
        s = np.uint32(shift)
        x = ((x >> s) & m) | ((x & m) << s)
    return (x >> np.uint32(16)) | (x << np.uint32(16))
