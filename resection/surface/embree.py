"""Embree 4 through its C API: a triangle scene on shared buffers, traced from numba.

The Embree library is the one the ``embreex`` wheel ships (``embreex.libs/libembree4*``),
loaded with :mod:`ctypes` without importing ``embreex`` itself. Compared with
``embreex``'s ``TriangleMesh`` / ``EmbreeScene.run``:

* the scene reads the caller's float32 vertex and uint32 index arrays in place
  (``rtcSetSharedGeometryBuffer``): no element-by-element copy with the GIL held (0.21 s
  for 610k faces in ``embreex``), and the BVH is built (``rtcCommitScene``, on Embree's
  own threads) while Python's GIL is released;
* rays are traced one ``rtcIntersect1`` call at a time from compiled numba kernels, which
  take the C function as an argument (a first-class function: the kernels stay cached on
  disk, the library's address is read when the kernel is called). A kernel that makes its
  rays, traces them and uses the hits in one pass needs no ``(M, 3)`` ray arrays.

Ray layout (Embree 4 ``RTCRayHit``, 32-bit words): origin 0-2, ``tnear`` 3, direction
4-6, time 7, ``tfar`` 8, mask 9, id 10, flags 11; geometric normal 12-14, ``u`` 15,
``v`` 16, ``primID`` 17, ``geomID`` 18, ``instID`` 19, ``instPrimID`` 20. A hit reports the
face index (``primID``); a miss leaves ``geomID`` at ``0xFFFFFFFF`` and is returned as -1.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import glob
import importlib.util
import os
import weakref

import numba
import numpy as np

from resection._threads import numba_threads
from resection.errors import InputError

__all__ = ["Scene", "library", "trace", "first_hit", "ray_buffer"]

#: ``enum RTCError`` of Embree 4.
_ERRORS = {1: "unknown error", 2: "invalid argument", 3: "invalid operation",
           4: "out of memory", 5: "unsupported CPU", 6: "cancelled"}
_GEOMETRY_TRIANGLE = 0
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
#: ``RTC_SCENE_FLAG_ROBUST``: watertight triangle tests (a ray through an edge or a vertex
#: shared by two faces hits one of them; without it, rays through a regular grid's edges
#: were seen to pass between the faces). ``embreex`` sets it too.
_SCENE_ROBUST = 1 << 2
#: Rays per block of the parallel trace (one scratch ray a block).
_BLOCK = 4096


@functools.cache
def library() -> ctypes.CDLL:
    """Embree 4's shared library (the one ``embreex`` ships), loaded once, with the
    signatures of the functions used here. Raises ``ImportError`` when there is none."""
    spec = importlib.util.find_spec("embreex")
    found = []
    if spec is not None and spec.origin:
        pkg = os.path.dirname(spec.origin)
        for pattern in ("../embreex.libs/libembree4*", ".dylibs/libembree4*", "*embree4*.dll",
                        "../embreex.libs/*embree4*.dll", "libembree4*"):
            found += sorted(glob.glob(os.path.join(pkg, pattern)))
    if not found:
        name = ctypes.util.find_library("embree4")
        found = [name] if name else []
    if not found:
        raise ImportError("Embree 4: no libembree4 found (it comes with the embreex package)")
    lib = ctypes.CDLL(found[0])
    p, c_int, c_uint = ctypes.c_size_t, ctypes.c_int, ctypes.c_uint
    signatures = {
        "rtcNewDevice": (p, [ctypes.c_char_p]),
        "rtcReleaseDevice": (None, [p]),
        "rtcGetDeviceError": (c_int, [p]),
        "rtcNewScene": (p, [p]),
        "rtcReleaseScene": (None, [p]),
        "rtcCommitScene": (None, [p]),
        "rtcSetSceneFlags": (None, [p, c_int]),
        "rtcNewGeometry": (p, [p, c_int]),
        "rtcSetSharedGeometryBuffer": (None, [p, c_int, c_uint, c_int, p, p, p, p]),
        "rtcCommitGeometry": (None, [p]),
        "rtcAttachGeometry": (c_uint, [p, p]),
        "rtcReleaseGeometry": (None, [p]),
        "rtcIntersect1": (None, [p, p, p]),
    }
    for name, (res, args) in signatures.items():
        fn = getattr(lib, name)
        fn.restype, fn.argtypes = res, args
    return lib


def _release(lib, scene: int, device: int, buffers) -> None:
    """Free a scene and its device (``buffers`` are kept alive until then)."""
    if scene:
        lib.rtcReleaseScene(scene)
    if device:
        lib.rtcReleaseDevice(device)


class Scene:
    """A committed Embree scene of one triangle mesh, on buffers shared with Embree.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex coordinates in the scene's frame, stored as float32 (keep them within a
        few hundred units of the origin for float32 precision).
    faces : (F, 3) array_like of int
        Triangles (indices into ``vertices``); a hit reports the row index.
    name : str
        What the mesh is called in error messages (e.g. its file name).

    Attributes
    ----------
    handle : int
        The ``RTCScene`` pointer, for the trace kernels.
    intersect : ctypes function
        ``rtcIntersect1(scene, rayhit, args)``, the kernels' first argument.

    Raises
    ------
    InputError
        No faces, vertices not finite in float32, face indices out of range, or Embree
        reports an error while building the scene.
    """

    def __init__(self, vertices, faces, *, name: str = "mesh"):
        v = np.asarray(vertices)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise InputError(f"{name}: vertices {v.shape} and faces {f.shape} must be (n, 3)")
        if len(f) == 0 or len(v) == 0:
            raise InputError(f"{name}: no faces to build an Embree scene of")
        if not np.issubdtype(f.dtype, np.integer):
            raise InputError(f"{name}: face indices must be integers, got {f.dtype}")
        # Embree may read 16 bytes from the last vertex: one row of padding
        vbuf = np.zeros((len(v) + 1, 3), dtype=np.float32)
        with np.errstate(over="ignore", invalid="ignore"):  # checked next
            vbuf[:-1] = v
        if not np.isfinite(vbuf).all():
            raise InputError(f"{name}: vertices contain NaN or infinite values (in float32)")
        lo, hi = int(f.min()), int(f.max())
        if lo < 0 or hi >= len(v):
            raise InputError(f"{name}: face indices {lo}..{hi} out of range for {len(v)} "
                             "vertices")
        ibuf = np.ascontiguousarray(f, dtype=np.uint32)
        lib = library()
        device = lib.rtcNewDevice(None)
        if not device:
            raise InputError(f"{name}: Embree could not start a device")
        scene = 0
        try:
            scene = lib.rtcNewScene(device)
            lib.rtcSetSceneFlags(scene, _SCENE_ROBUST)
            geom = lib.rtcNewGeometry(device, _GEOMETRY_TRIANGLE)
            lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3,
                                           vbuf.ctypes.data, 0, 12, len(v))
            lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_INDEX, 0, _FORMAT_UINT3,
                                           ibuf.ctypes.data, 0, 12, len(ibuf))
            lib.rtcCommitGeometry(geom)
            lib.rtcAttachGeometry(scene, geom)
            lib.rtcReleaseGeometry(geom)
            lib.rtcCommitScene(scene)  # the BVH, on Embree's threads (ctypes drops the GIL)
            err = lib.rtcGetDeviceError(device)
            if err:
                raise InputError(f"{name}: Embree could not build the scene of {len(f)} faces "
                                 f"({_ERRORS.get(err, f'error {err}')})")
        except BaseException:
            _release(lib, scene, device, None)
            raise
        self.handle = scene
        self.intersect = lib.rtcIntersect1
        self.n_faces = len(ibuf)
        # freed with the owner (not at the interpreter's exit: the OS takes it back faster)
        self._free = weakref.finalize(self, _release, lib, scene, device, (vbuf, ibuf))
        self._free.atexit = False

    def close(self) -> None:
        """Free the scene now (it is freed with the object otherwise)."""
        self.handle = 0
        self._free()

    def run(self, origins, directions, *, workers: int | None = None) -> np.ndarray:
        """First face hit by each ray, ``(M,)`` int32, -1 for a miss (``embreex``'s
        ``EmbreeScene.run``).

        Parameters
        ----------
        origins, directions : (M, 3) array_like
            Rays in the scene's frame (cast to float32); directions need not be unit.
        workers : int, optional
            numba threads tracing blocks of rays (default: numba's thread count).
        """
        if not self.handle:
            raise InputError("Embree scene: already closed")
        o = np.ascontiguousarray(origins, dtype=np.float32).reshape(-1, 3)
        d = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
        if o.shape != d.shape and len(o) != 1:
            raise InputError(f"rays: origins {o.shape} and directions {d.shape} differ")
        out = np.empty(len(d), dtype=np.int32)
        with numba_threads(workers):
            _trace_parallel(self.intersect, self.handle, o, d, out)
        return out


@numba.njit(cache=True, nogil=True)
def ray_buffer():  # pragma: no cover - compiled
    """A scratch ``RTCRayHit`` (32 float32 words, 16-byte aligned as Embree requires) and
    its uint32 view."""
    raw = np.empty(36, dtype=np.float32)
    start = ((16 - raw.ctypes.data % 16) % 16) // 4
    buf = raw[start:start + 32]
    return buf, buf.view(np.uint32)


@numba.njit(cache=True, nogil=True, inline="always")
def first_hit(fn, scene, buf, ib, ox, oy, oz, dx, dy, dz):  # pragma: no cover - compiled
    """Trace one ray (float32 origin and direction in the scene's frame) with
    ``fn = rtcIntersect1`` through the scratch ``buf`` / ``ib`` of :func:`ray_buffer`:
    the face hit first, -1 for a miss."""
    buf[0], buf[1], buf[2], buf[3] = ox, oy, oz, np.float32(0.0)
    buf[4], buf[5], buf[6], buf[7] = dx, dy, dz, np.float32(0.0)
    buf[8] = np.inf
    ib[9], ib[10], ib[11] = np.uint32(0xFFFFFFFF), np.uint32(0), np.uint32(0)
    ib[18], ib[19] = np.uint32(0xFFFFFFFF), np.uint32(0xFFFFFFFF)
    fn(scene, buf.ctypes.data, 0)
    if ib[18] == np.uint32(0xFFFFFFFF):
        return -1
    return np.int64(ib[17])


@numba.njit(cache=True, nogil=True)
def trace(fn, scene, o, d, out, start=0, stop=-1):  # pragma: no cover - compiled
    """First hits of the rays ``start <= r < stop`` (default all) ``(o[r] or o[0], d[r])``
    (float32, the scene's frame) into ``out[r]`` (int, -1 for a miss), on the calling
    thread (no GIL held)."""
    buf, ib = ray_buffer()
    one = o.shape[0] == 1
    end = d.shape[0] if stop < 0 else stop
    for r in range(start, end):
        q = 0 if one else r
        out[r] = first_hit(fn, scene, buf, ib, o[q, 0], o[q, 1], o[q, 2],
                           d[r, 0], d[r, 1], d[r, 2])


@numba.njit(cache=True, nogil=True, parallel=True)
def _trace_parallel(fn, scene, o, d, out):  # pragma: no cover - compiled
    """:func:`trace` over blocks of rays on numba's threads."""
    n = d.shape[0]
    nb = (n + _BLOCK - 1) // _BLOCK
    for b in numba.prange(nb):
        trace(fn, scene, o, d, out, b * _BLOCK, min(n, (b + 1) * _BLOCK))
