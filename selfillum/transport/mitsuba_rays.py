"""First hits of rays with Mitsuba 3 / Dr.Jit: OptiX on a CUDA GPU, or Dr.Jit's LLVM backend
on the CPU.

The view factors' default tracer is Embree through ``embreex`` (:class:`RayScene` in
:mod:`~selfillum.transport.viewfactors`). :class:`MitsubaRayScene` answers the same question
(which face each ray hits first) through Mitsuba's ``Scene.ray_intersect_preliminary``: with the
``cuda_ad_rgb`` variant the rays are traced by OptiX on the GPU, with ``llvm_ad_rgb`` by
Mitsuba's own Embree on every CPU core. It takes the same float32 rays in the same centred
frame, so the two tracers can be compared ray for ray (the former
``bench/bench_viewfactors.py``,
section [7]) and :func:`selfillum.view_factors` can use either (``tracer="mitsuba"``).

Mitsuba's variant is process-wide state: each call sets the scene's variant and restores the
one that was set before.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from resection.errors import InputError
from selfillum.mitsuba_variants import available_variants, import_mitsuba

__all__ = ["MitsubaRayScene", "tracing_variant"]

#: Rays handed to Dr.Jit at once (each ray costs about 60 bytes on the device).
_RAYS_PER_LAUNCH = 1 << 22


def tracing_variant(variant: str | None = None) -> str:
    """The Mitsuba variant to trace with.

    Parameters
    ----------
    variant : {None, "auto", "cuda", "llvm"} or a full variant name
        ``None``/``"auto"``: ``cuda_ad_rgb`` when a CUDA device works, else ``llvm_ad_rgb``.

    Raises
    ------
    InputError
        An unknown variant, ``scalar`` (one ray at a time: no use for millions of rays),
        or one this machine cannot run.
    """
    names = {"cuda": "cuda_ad_rgb", "llvm": "llvm_ad_rgb"}
    avail = [v for v in available_variants() if v in names.values()]
    if variant is None or variant == "auto":
        if not avail:
            raise InputError("tracer mitsuba: neither the cuda nor the llvm variant can run "
                             "here (the llvm variant needs libLLVM >= 16)")
        return avail[0]
    name = names.get(variant, variant)
    if name not in names.values():
        raise InputError(f"tracer mitsuba: unknown variant {variant!r} (expected auto, cuda "
                         "or llvm)")
    if name not in avail:
        raise InputError(f"tracer mitsuba: variant {name} is not available on this machine "
                         f"(available: {', '.join(avail) or 'none'})")
    return name


class MitsubaRayScene:
    """A triangle mesh in a Mitsuba scene, for first-hit queries.

    Parameters
    ----------
    vertices : (V, 3) array_like
        Vertex coordinates (model units).
    faces : (N, 3) array_like of int
        Triangles; the face indices returned are rows of this array.
    variant : str, optional
        See :func:`tracing_variant`.

    Attributes
    ----------
    origin : (3,) float64
        The centre of the mesh's box: rays are given relative to it (as for
        :class:`selfillum.transport.viewfactors.RayScene`), in float32.
    variant : str
        The Mitsuba variant used.
    """

    def __init__(self, vertices, faces, variant: str | None = None):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces)
        if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise InputError(f"tracer mitsuba: expected (V, 3) vertices and (N, 3) faces, got "
                             f"{v.shape} and {f.shape}")
        self.variant = tracing_variant(variant)
        self.origin = 0.5 * (v.min(axis=0) + v.max(axis=0))
        self.n_faces = len(f)
        mi, self._dr = import_mitsuba()
        self._mi = mi
        with self._variant():
            mesh = mi.Mesh("model", len(v), len(f))
            params = mi.traverse(mesh)
            #: the float32 vertices (relative to ``origin``) and the faces, flat, on the
            #: device: :class:`~selfillum.transport.mitsuba_factors.MitsubaFactorTracer`
            #: gathers its per-face data there
            self.positions = mi.Float(
                np.ascontiguousarray(v - self.origin, dtype=np.float32).ravel())
            self.faces = mi.UInt32(np.ascontiguousarray(f, dtype=np.uint32).ravel())
            params["vertex_positions"] = self.positions
            params["faces"] = self.faces
            params.update()
            self._scene = mi.load_dict({"type": "scene", "model": mesh})

    @contextmanager
    def _variant(self):
        """Set this scene's variant for the block, then restore the previous one."""
        previous = self._mi.variant()
        if previous != self.variant:
            self._mi.set_variant(self.variant)
        try:
            yield
        finally:
            if previous is not None and previous != self.variant:
                self._mi.set_variant(previous)

    def run(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """First face hit by each ray, ``-1`` for a miss.

        Parameters
        ----------
        origins, directions : (M, 3) float32
            Rays relative to :attr:`origin` (directions need not be unit).

        Returns
        -------
        (M,) int32
        """
        o = np.asarray(origins, dtype=np.float32)
        d = np.asarray(directions, dtype=np.float32)
        out = np.empty(len(d), dtype=np.int32)
        mi, dr = self._mi, self._dr
        with self._variant():
            for a in range(0, len(d), _RAYS_PER_LAUNCH):
                b = min(a + _RAYS_PER_LAUNCH, len(d))
                oo, dd = o[a:b], d[a:b]
                ray = mi.Ray3f(mi.Point3f(oo[:, 0], oo[:, 1], oo[:, 2]),
                               mi.Vector3f(dd[:, 0], dd[:, 1], dd[:, 2]))
                pi = self._scene.ray_intersect_preliminary(ray, coherent=False)
                face = dr.select(pi.is_valid(), mi.Int32(pi.prim_index), -1)
                out[a:b] = np.asarray(face)
        return out

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """As :meth:`selfillum.transport.viewfactors.RayScene.first_hit`: model-frame float64 rays,
        ``(M,)`` int64 face indices (``-1`` for a miss)."""
        o = np.ascontiguousarray(np.asarray(origins) - self.origin, dtype=np.float32)
        return self.run(o, np.asarray(directions, dtype=np.float32)).astype(np.int64)
