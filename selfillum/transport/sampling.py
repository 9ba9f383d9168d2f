"""Ray samples for view factors: uniform points of faces and cosine-distributed
directions, from randomised quasi-Monte Carlo points (Sobol, Owen-scrambled per face) or
from a random stream (stratified).

The RQMC points of a face are keyed on its index and a seed (counter-based), so a face's
rays are the same whatever else is computed with it: chunks, row subsets and worker
threads give the same rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["sample_rays", "rqmc_points", "digital_shifts"]

#: Random permutations of the strata drawn per block of faces (random-stream sampling).
_POOL = 64


def _stratified_2d(rng: np.random.Generator, n: int, k: int) -> np.ndarray:
    """``(n, k, 2)`` float32 points of the unit square, stratified per row.

    Each row takes ``k`` distinct cells of an ``m x m`` grid (``m = ceil(sqrt(k))``; all
    of them, the jittered grid, when ``k = m^2``) in a random order and jitters each point
    within its cell. The orders are drawn from a pool of random permutations (each row
    picks one at random), which keeps every point uniformly distributed, the positions and
    directions of a face decorrelated, and the cost linear in ``n k`` (no sort per row).
    Used by the random-stream interface of :func:`sample_rays` (``rng`` given).
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


#: Sobol direction numbers of dimensions 2-5 (Joe and Kuo 2008, ``new-joe-kuo-6.21201``,
#: the table SciPy's ``qmc.Sobol`` uses): ``(degree s, coefficients a, m_1..m_s)``.
_JOE_KUO = ((1, 0, (1,)), (2, 1, (1, 3)), (3, 1, (1, 3, 1)), (3, 2, (1, 1, 1)))


def _sobol_base(k: int, dims: int) -> np.ndarray:
    """The first ``k`` points of the (unscrambled) Sobol sequence in ``dims <= 5``
    dimensions, in Gray-code order, as ``(k, dims)`` uint32 integers (point = integer /
    2**32): the points of ``scipy.stats.qmc.Sobol(dims, scramble=False)`` (checked in
    tests/test_viewfactors.py), made here without importing ``scipy.stats`` (0.25 s of
    imports and 0.1 s of its set-up, on one thread, in every ``selfillum correct``)."""
    if not 1 <= dims <= len(_JOE_KUO) + 1:
        raise ValueError(f"_sobol_base: dims must be in [1, {len(_JOE_KUO) + 1}], got {dims}")
    bits = max(1, int(np.ceil(np.log2(k))) if k > 1 else 1)
    v = np.zeros((dims, bits), dtype=np.uint64)  # direction numbers, 32-bit
    v[0] = [1 << (31 - j) for j in range(bits)]  # van der Corput
    for d in range(1, dims):  # the recurrence of each dimension's primitive polynomial
        s, a, m = _JOE_KUO[d - 1][0], _JOE_KUO[d - 1][1], list(_JOE_KUO[d - 1][2])
        for j in range(s, bits):
            x = m[j - s] ^ (m[j - s] << s)
            for t in range(1, s):
                if (a >> (s - 1 - t)) & 1:
                    x ^= m[j - t] << t
            m.append(x)
        v[d] = [m[j] << (31 - j) for j in range(bits)]
    i = np.arange(k, dtype=np.uint64)
    gray = i ^ (i >> np.uint64(1))
    out = np.zeros((k, dims), dtype=np.uint64)
    for j in range(bits):  # loop over the 32 bits at most, vectorised over the points
        out[((gray >> np.uint64(j)) & np.uint64(1)).astype(bool)] ^= v[:, j]
    return out.astype(np.uint32)


#: The per-face scramble key before hashing, ``seed * SEED + face * FACE + dim * DIM``
#: (wrapping uint64), and SplitMix64's finaliser, ``x ^= x >> 30; x *= MIX1;
#: x ^= x >> 27; x *= MIX2; x ^= x >> 31``: the constants of :func:`digital_shifts`, of
#: its compiled twin :func:`_shift` and of its Dr.Jit twin in
#: :mod:`selfillum.transport.mitsuba_factors`.
_KEY_SEED, _KEY_FACE, _KEY_DIM = (np.uint64(0x9E3779B97F4A7C15), np.uint64(0xD1B54A32D192ED03),
                                  np.uint64(0x8CB92BA72F3D8DD7))
_MIX1, _MIX2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _mix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser: a bijective 64-bit hash, element-wise on uint64."""
    x = x ^ (x >> np.uint64(30))
    x = x * _MIX1
    x = x ^ (x >> np.uint64(27))
    x = x * _MIX2
    return x ^ (x >> np.uint64(31))


def digital_shifts(seed: int, face_ids: np.ndarray, dims: int) -> np.ndarray:
    """Random digital shifts (32-bit XOR masks), ``(n, dims)`` uint32, one per face and
    dimension, a hash of ``(seed, face, dimension)`` (counter-based: the same for a face
    whatever else is computed with it)."""
    f = np.asarray(face_ids, dtype=np.uint64)[:, None]
    d = np.arange(dims, dtype=np.uint64)[None, :]
    with np.errstate(over="ignore"):
        key = np.uint64(seed) * _KEY_SEED + f * _KEY_FACE + d * _KEY_DIM
        return (_mix64(_mix64(key)) >> np.uint64(32)).astype(np.uint32)


_U = np.uint64  # numba: keep every operand uint64 (uint64 with int64 gives float64)
_M1, _M2, _M4, _M8 = _U(0x55555555), _U(0x33333333), _U(0x0F0F0F0F), _U(0x00FF00FF)
_M32 = _U(0xFFFFFFFF)
_LK = (_U(0x6C50B47C), _U(0xB82F1E52), _U(0xC7AFE638), _U(0x8D22F6E6))
_S1, _S2, _S4, _S8, _S16 = _U(1), _U(2), _U(4), _U(8), _U(16)


@njit(cache=True)
def _rev32(x):  # pragma: no cover - compiled
    """Bit reversal of a 32-bit value held in a uint64."""
    x = ((x >> _S1) & _M1) | ((x & _M1) << _S1)
    x = ((x >> _S2) & _M2) | ((x & _M2) << _S2)
    x = ((x >> _S4) & _M4) | ((x & _M4) << _S4)
    x = ((x >> _S8) & _M8) | ((x & _M8) << _S8)
    return ((x >> _S16) | (x << _S16)) & _M32


@njit(cache=True, inline="always")
def _owen(xr, key):  # pragma: no cover - compiled
    """One Owen-scrambled coordinate from a bit-reversed Sobol integer ``xr`` (uint64
    holding 32 bits) and a face's key: a float32 strictly inside (0, 1) (the top 24 bits,
    centred in their cell)."""
    x = (xr + key) & _M32
    x ^= (x * _LK[0]) & _M32
    x ^= (x * _LK[1]) & _M32
    x ^= (x * _LK[2]) & _M32
    x ^= (x * _LK[3]) & _M32
    x = _rev32(x)
    return (np.float32(x >> _S8) + np.float32(0.5)) * np.float32(2.0**-24)


@njit(cache=True, nogil=True)
def _reversed_base(base):  # pragma: no cover - compiled
    """Bit-reversed Sobol integers, ``(k, dims)`` uint64 (the scramble works on them)."""
    out = np.empty(base.shape, dtype=np.uint64)
    for i in range(base.shape[0]):
        for d in range(base.shape[1]):
            out[i, d] = _rev32(_U(base[i, d]))
    return out


@njit(cache=True, nogil=True)
def _owen_points(rbase, keys, out):  # pragma: no cover - compiled
    """``out[f, i, d]``: Sobol point ``i`` (bit-reversed integers ``rbase[i, d]``)
    Owen-scrambled with ``keys[f, d]`` (see :func:`_owen`)."""
    for f in range(keys.shape[0]):
        for d in range(keys.shape[1]):
            key = _U(keys[f, d])
            for i in range(rbase.shape[0]):
                out[f, i, d] = _owen(rbase[i, d], key)


def rqmc_points(k: int, face_ids: np.ndarray, seed: int, dims: int = 4) -> np.ndarray:
    """Randomised quasi-Monte Carlo points of the unit cube, ``(n, k, dims)`` float32.

    Each face gets the first ``k`` points of the Sobol sequence, Owen-scrambled with its
    own seeds (the seeds are :func:`digital_shifts`; each bit of a coordinate is flipped
    by a hash of the bits above it, the Laine-Karras permutation applied to the
    bit-reversed value, as in Burley, "Practical Hash-based Owen Scrambling", JCGT 2020).
    A scrambled net stays a net and every point is uniformly distributed on
    ``[0, 1)^dims`` (to 2**-24; ``dims`` at most 5), so every estimate built on these points
    is unbiased,
    while the error of one face's points falls faster than ``1/sqrt(k)`` (measured
    against Howell's closed forms in the former ``bench/bench_viewfactors.py``).
    """
    rbase = _reversed_base(_sobol_base(k, dims))
    keys = digital_shifts(seed, face_ids, dims)
    out = np.empty((len(keys), k, dims), dtype=np.float32)
    _owen_points(rbase, keys, out)
    return out


@njit(cache=True, nogil=True, inline="always")
def _frame(n0, n1, n2):  # pragma: no cover - compiled
    """Two unit vectors ``(t1, t2)`` completing the unit normal ``n`` (float64) to a
    right-handed frame: ``t1 = n x h / |n x h|`` with ``h`` the x axis (the y axis when
    ``|n_x| >= 0.9``), ``t2 = n x t1``; as six float64 values."""
    h0, h1 = (1.0, 0.0) if abs(n0) < 0.9 else (0.0, 1.0)
    a0 = n1 * 0.0 - n2 * h1
    a1 = n2 * h0 - n0 * 0.0
    a2 = n0 * h1 - n1 * h0
    s = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    a0, a1, a2 = a0 / s, a1 / s, a2 / s
    return a0, a1, a2, n1 * a2 - n2 * a1, n2 * a0 - n0 * a2, n0 * a1 - n1 * a0


@njit(cache=True, nogil=True)
def _frames(normals, t1, t2):  # pragma: no cover - compiled
    """:func:`_frame` of every row of ``normals`` into ``t1``, ``t2`` (float32)."""
    for f in range(normals.shape[0]):
        a0, a1, a2, b0, b1, b2 = _frame(normals[f, 0], normals[f, 1], normals[f, 2])
        t1[f, 0], t1[f, 1], t1[f, 2] = a0, a1, a2
        t2[f, 0], t2[f, 1], t2[f, 2] = b0, b1, b2


def _tangent_frames(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(t1, t2)`` completing each unit normal to a right-handed frame,
    float32 (:func:`_frame`, the values the fused row kernel uses)."""
    n = np.ascontiguousarray(normals, dtype=np.float64)
    t1 = np.empty((len(n), 3), dtype=np.float32)
    t2 = np.empty((len(n), 3), dtype=np.float32)
    _frames(n, t1, t2)
    return t1, t2


@njit(cache=True, nogil=True)
def _build_rays(tri, nrm, t1, t2, pts, side, offset, origins,
                directions):  # pragma: no cover - compiled
    """Rays from unit-square samples (float32 throughout, one ray a loop iteration).

    ``pts[f, i, 0:2]`` place the ray, ``pts[f, i, 2:4]`` aim it. Position: the
    area-preserving map of the square onto the triangle (``sqrt(u0)``), lifted by
    ``offset`` on the side the ray leaves and moved as much towards the face's centre (a
    point on an edge shared with a perpendicular face would otherwise lie in that face's
    plane). Direction: cosine-weighted about the signed normal (Malley's method: a
    uniform disk lifted to the hemisphere).
    """
    n, k = pts.shape[0], pts.shape[1]
    two_pi = np.float32(2.0 * np.pi)
    for f in range(n):
        cx = (tri[f, 0, 0] + tri[f, 1, 0] + tri[f, 2, 0]) / np.float32(3.0)
        cy = (tri[f, 0, 1] + tri[f, 1, 1] + tri[f, 2, 1]) / np.float32(3.0)
        cz = (tri[f, 0, 2] + tri[f, 1, 2] + tri[f, 2, 2]) / np.float32(3.0)
        for i in range(k):
            r = f * k + i
            sa = np.sqrt(pts[f, i, 0])
            w2 = sa * pts[f, i, 1]
            w1 = sa - w2
            sd = np.float32(side[f, i])
            for c in range(3):
                origins[r, c] = (tri[f, 0, c] + w1 * (tri[f, 1, c] - tri[f, 0, c])
                                 + w2 * (tri[f, 2, c] - tri[f, 0, c]))
            if offset > 0:
                ix, iy, iz = cx - origins[r, 0], cy - origins[r, 1], cz - origins[r, 2]
                d = np.sqrt(ix * ix + iy * iy + iz * iz)
                g = offset / max(d, offset)
                origins[r, 0] += ix * g + sd * offset * nrm[f, 0]
                origins[r, 1] += iy * g + sd * offset * nrm[f, 1]
                origins[r, 2] += iz * g + sd * offset * nrm[f, 2]
            rr = np.sqrt(pts[f, i, 2])
            phi = two_pi * pts[f, i, 3]
            lx = rr * np.cos(phi)
            ly = rr * np.sin(phi)
            lz = np.sqrt(max(np.float32(0.0), np.float32(1.0) - pts[f, i, 2])) * sd
            for c in range(3):
                directions[r, c] = lx * t1[f, c] + ly * t2[f, c] + lz * nrm[f, c]


@njit(cache=True, inline="always")
def _shift(seed, face, dim):  # pragma: no cover - compiled
    """:func:`digital_shifts` of one face and dimension (uint64 holding 32 bits)."""
    key = _U(seed) * _KEY_SEED + _U(face) * _KEY_FACE + _U(dim) * _KEY_DIM
    for _ in range(2):  # SplitMix64's finaliser, twice
        key = key ^ (key >> _U(30))
        key = key * _MIX1
        key = key ^ (key >> _U(27))
        key = key * _MIX2
        key = key ^ (key >> _U(31))
    return key >> _U(32)


@njit(cache=True, nogil=True)
def _shifts(seed, face_ids, dims):  # pragma: no cover - compiled
    """:func:`_shift` of every face and dimension, ``(n, dims)`` uint32."""
    out = np.empty((face_ids.shape[0], dims), dtype=np.uint32)
    for f in range(face_ids.shape[0]):
        for d in range(dims):
            out[f, d] = _shift(seed, face_ids[f], d)
    return out


@njit(cache=True, nogil=True, inline="always")
def _rqmc_ray(rbase, i, keys, two_sided, tri, c, nrm, t1, t2, offset, o,
              d):  # pragma: no cover - compiled
    """Ray ``i`` of a face from its RQMC point (Sobol point ``rbase[i]`` scrambled with
    the face's ``keys``, uint64): its origin into ``o[0:3]`` and its unit direction into
    ``d[0:3]`` (float32), as :func:`_build_rays` places them; ``tri`` the face's (3, 3)
    float32 vertices, ``c`` its centroid, ``nrm``, ``t1``, ``t2`` its float32 frame.
    Returns the side, +1 or -1."""
    p0 = _owen(rbase[i, 0], keys[0])
    p1 = _owen(rbase[i, 1], keys[1])
    p2 = _owen(rbase[i, 2], keys[2])
    p3 = _owen(rbase[i, 3], keys[3])
    sd = np.float32(1.0)
    if two_sided and _owen(rbase[i, 4], keys[4]) >= np.float32(0.5):
        sd = np.float32(-1.0)
    sa = np.sqrt(p0)
    w2 = sa * p1
    w1 = sa - w2
    for a in range(3):
        o[a] = tri[0, a] + w1 * (tri[1, a] - tri[0, a]) + w2 * (tri[2, a] - tri[0, a])
    if offset > 0:
        ix, iy, iz = c[0] - o[0], c[1] - o[1], c[2] - o[2]
        dd = np.sqrt(ix * ix + iy * iy + iz * iz)
        g = offset / max(dd, offset)
        o[0] += ix * g + sd * offset * nrm[0]
        o[1] += iy * g + sd * offset * nrm[1]
        o[2] += iz * g + sd * offset * nrm[2]
    rr = np.sqrt(p2)
    phi = np.float32(2.0 * np.pi) * p3
    lx = rr * np.cos(phi)
    ly = rr * np.sin(phi)
    lz = np.sqrt(max(np.float32(0.0), np.float32(1.0) - p2)) * sd
    for a in range(3):
        d[a] = lx * t1[a] + ly * t2[a] + lz * nrm[a]
    return sd


@njit(cache=True, nogil=True, inline="always")
def _centroid(tri, c):  # pragma: no cover - compiled
    """The float32 centroid of a face's (3, 3) float32 vertices into ``c``."""
    for a in range(3):
        c[a] = (tri[0, a] + tri[1, a] + tri[2, a]) / np.float32(3.0)


@njit(cache=True, nogil=True)
def _rqmc_rays(rbase, keys, tri, nrm, t1, t2, offset, origins, directions,
               side):  # pragma: no cover - compiled
    """The rays of :func:`_build_rays` from the RQMC points of :func:`rqmc_points`, made
    in one pass (no ``(n, k, dims)`` array of points in between): the same points, the
    same arithmetic (:func:`_rqmc_ray`). ``keys`` has 5 columns for two-sided faces (the
    5th coordinate picks the side) and 4 otherwise."""
    n, k = keys.shape[0], rbase.shape[0]
    two_sided = keys.shape[1] > 4
    key = np.zeros(5, dtype=np.uint64)
    c = np.empty(3, dtype=np.float32)
    for f in range(n):
        for a in range(keys.shape[1]):
            key[a] = _U(keys[f, a])
        _centroid(tri[f], c)
        for i in range(k):
            r = f * k + i
            side[r] = np.int8(_rqmc_ray(rbase, i, key, two_sided, tri[f], c, nrm[f], t1[f],
                                        t2[f], offset, origins[r], directions[r]))


def sample_rays(
    triangles: np.ndarray,
    normals: np.ndarray,
    k: int,
    rng: np.random.Generator | None = None,
    *,
    two_sided: bool = False,
    offset: float = 0.0,
    face_ids: np.ndarray | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosine-distributed rays leaving uniform points of faces (float32, for Embree).

    Parameters
    ----------
    triangles : (n, 3, 3) ndarray
        Vertices of the faces, in the frame the rays are wanted in (keep it centred on
        the scene for float32 precision).
    normals : (n, 3) ndarray
        Unit normals (painted side).
    k : int
        Rays per face.
    rng : numpy.random.Generator, optional
        Random stream: stratified random points (positions and directions each on a
        jittered grid). Without it, randomised quasi-Monte Carlo points
        (:func:`rqmc_points`) keyed on ``face_ids`` and ``seed``.
    two_sided : bool
        Send half of the rays out of the back side.
    offset : float
        Lift the start points off the face by this distance, on the side the ray leaves
        (model units), so that a ray does not hit its own face, and move them as much
        towards the face's centre, off its edges.
    face_ids : (n,) array_like of int, optional
        Global index of each face (RQMC points only; default ``0..n-1``).
    seed : int
        Seed of the RQMC shifts.

    Returns
    -------
    origins : (n * k, 3) float32 ndarray
        Ray start points: uniform points of the faces (lifted by ``offset``).
    directions : (n * k, 3) float32 ndarray
        Unit directions, cosine-distributed about the (signed) normal.
    side : (n * k,) int8 ndarray
        ``+1`` for rays leaving the painted side, ``-1`` for the back side.
    """
    n = triangles.shape[0]
    f32 = np.float32
    if rng is not None:
        pts = np.concatenate([_stratified_2d(rng, n, k), _stratified_2d(rng, n, k)], axis=2)
        if two_sided:
            flip = rng.integers(0, 2, size=(n, 1))
            side = np.where((np.arange(k)[None, :] + flip) % 2 == 0, 1, -1).astype(np.int8)
        else:
            side = np.ones((n, k), dtype=np.int8)
    t1, t2 = _tangent_frames(normals)
    frame = (np.ascontiguousarray(triangles, dtype=f32), np.ascontiguousarray(normals, f32),
             t1, t2)
    origins = np.empty((n * k, 3), dtype=f32)
    directions = np.empty((n * k, 3), dtype=f32)
    if rng is not None:
        _build_rays(*frame, pts, side, f32(offset), origins, directions)
        return origins, directions, side.reshape(-1)
    dims = 5 if two_sided else 4
    ids = np.arange(n) if face_ids is None else np.asarray(face_ids)
    side = np.empty(n * k, dtype=np.int8)
    _rqmc_rays(_reversed_base(_sobol_base(k, dims)), digital_shifts(seed, ids, dims), *frame,
               f32(offset), origins, directions, side)
    return origins, directions, side
