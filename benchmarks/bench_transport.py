"""View factors, the self-illumination correction, its solve and the renders against bare
Embree, bare SciPy products and Mitsuba."""

from __future__ import annotations

import time

import numpy as np

from ._peers import best_times, ratio_of_best


class ViewFactorsVsEmbree:
    """The open corner of ``scenes.corner`` (resolution 30: 3,600 faces), 128 rays a face:
    ``selfillum.view_factors`` (sampling, tracing, sparse assembly) against one bare
    ``embreex`` run of the very same rays (tracing only: the ceiling)."""

    timeout = 300

    def setup(self):
        from scenes.corner import corner
        from selfillum import view_factors

        from ._scenes import same_rays

        self.mesh = corner(resolution=30).mesh
        self.scene, self.o, self.d = same_rays(self.mesh, 128, 0)
        self.view_factors = view_factors
        self.view_factors(self.mesh, 8, seed=0)  # compiled kernels loaded before timing

    def time_view_factors(self):
        self.view_factors(self.mesh, 128, seed=0)

    def time_bare_embree(self):
        self.scene.run(self.o, self.d)

    def track_ratio_to_bare_embree(self):
        return ratio_of_best(lambda: self.view_factors(self.mesh, 128, seed=0),
                             lambda: self.scene.run(self.o, self.d))

    track_ratio_to_bare_embree.unit = "ours / bare Embree"


class CorrectImageVsBareEmbree:
    """``correct_image`` in this process (surface map, view factors of the seen and coupled
    faces, the unseen faces' solve, the per-pixel correction; 256 rays a face) on the slab
    and block of ``scenes.slab_block`` (100,000 faces, one 1280 x 1024 camera) against a
    bare one-thread Embree pass of 256 cosine rays from every face (scene build and
    ``run``; ``time_bare_embree`` also counts making the rays, the ratio does not)."""

    timeout = 900

    def setup(self):
        from resection.surface.surface_map import SurfaceMap
        from scenes.slab_block import slab_block, slab_camera
        from selfillum.images.image_correction import correct_image

        from ._scenes import FACE_FACTOR, bare_embree

        self.sc = slab_block(int(100_000 * FACE_FACTOR))
        self.cam = slab_camera(1280, 1024, zoom=1.25)
        smap = SurfaceMap(self.sc.mesh, self.cam)
        img = np.where(smap.mask, self.sc.emission[np.maximum(smap.face_index, 0)], 0.0)
        self.img = (img * 100.0).astype(np.float32)
        self.correct_image, self.bare = correct_image, bare_embree

    def _ours(self):
        return self.correct_image(self.img, self.sc.mesh, self.cam, self.sc.reflectance,
                                  unpainted=~self.sc.painted)

    def time_correct_image(self):
        self._ours()

    def time_bare_embree(self):
        self.bare(self.sc.mesh)

    def track_ratio_to_bare_embree(self):
        ours, peer = float("inf"), float("inf")
        for _ in range(2):
            t0 = time.perf_counter()
            self._ours()
            ours = min(ours, time.perf_counter() - t0)
            peer = min(peer, self.bare(self.sc.mesh))
        return ours / peer

    track_ratio_to_bare_embree.unit = "ours / bare Embree"


class CorrectSolveVsProducts:
    """The solve of ``selfillum correct`` alone (``selfillum.solve.radiosity.correct``, the
    unseen faces' continuation inside) on the slab and block (20,000 faces, the camera's
    seen faces, the unpainted box) against the bare SciPy CSR products ``F @ x`` its
    iterations need (as many as it reported): what the solve costs beyond its products."""

    timeout = 600

    def setup(self):
        import scipy.sparse as sp

        from resection.surface.surface_map import SurfaceMap
        from scenes.slab_block import slab_block, slab_camera
        from selfillum.solve.radiosity import correct, forward
        from selfillum.transport.viewfactors import view_factors

        from ._scenes import FACE_FACTOR

        sc = slab_block(int(20_000 * FACE_FACTOR))
        smap = SurfaceMap(sc.mesh, slab_camera(1280, 1024, zoom=1.25))
        self.seen = (smap.pixel_counts > 0) & ~smap.oblique
        self.F = sp.csr_matrix(view_factors(sc.mesh, rays_per_face=128, seed=0))
        self.B = forward(self.F, sc.emission, sc.reflectance)
        self.rho, self.mesh, self.unpainted = sc.reflectance, sc.mesh, ~sc.painted
        self.correct = correct
        _, info = self._ours()
        self.iterations = max(1, int(info.iterations))
        self.x = np.ones(self.F.shape[0])

    def _ours(self):
        return self.correct(self.F, self.B, self.rho, self.seen, mesh=self.mesh,
                            unpainted=self.unpainted, unseen="continue", return_info=True)

    def _products(self):
        for _ in range(self.iterations):
            self.F @ self.x

    def time_correct(self):
        self._ours()

    def time_csr_products(self):
        self._products()

    def track_ratio_to_csr_products(self):
        return ratio_of_best(self._ours, self._products)

    track_ratio_to_csr_products.unit = "solve / its products"


class SparseProductThreadsVsScipy:
    """A CSR product of the continuation's size (185,846 rows, 1 M entries in a band like
    the form factors of nearby faces) on numba's threads (``prange`` over the rows, through
    ``resection._threads.numba_threads``) against SciPy's one-thread ``csr_matvec``, 20
    products each: why the solve's products stay serial on a shared 2-core machine."""

    timeout = 300

    def setup(self):
        import numba
        import scipy.sparse as sp

        from resection._threads import numba_threads

        @numba.njit(nogil=True, parallel=True)
        def parallel(indptr, indices, data, x, out):  # pragma: no cover - compiled
            for i in numba.prange(out.size):
                s = 0.0
                for k in range(indptr[i], indptr[i + 1]):
                    s += data[k] * x[indices[k]]
                out[i] = s

        rng = np.random.default_rng(0)
        rows, nnz = 185_846, 1_000_000
        r = rng.integers(0, rows, nnz)
        c = np.clip(r + rng.integers(-2000, 2000, nnz), 0, rows - 1)
        self.A = sp.csr_matrix((rng.random(nnz), (r, c)), shape=(rows, rows))
        self.x, self.out = rng.random(rows), np.empty(rows)
        self.kernel, self.threads = parallel, numba_threads
        self._numba()

    def _numba(self):
        with self.threads(None):
            for _ in range(20):
                self.kernel(self.A.indptr, self.A.indices, self.A.data, self.x, self.out)

    def _scipy(self):
        for _ in range(20):
            self.A @ self.x

    def time_numba_threads(self):
        self._numba()

    def time_scipy_csr_matvec(self):
        self._scipy()

    def track_ratio_to_scipy(self):
        return ratio_of_best(self._numba, self._scipy, repeat=5)

    track_ratio_to_scipy.unit = "numba threads / SciPy"


class MitsubaRaysVsEmbree:
    """The same float32 rays (the open corner, 3,600 faces, 64 rays a face) through
    Mitsuba / Dr.Jit (``MitsubaRayScene``: OptiX on a GPU, LLVM on the CPU) against one
    bare ``embreex`` call. Tracked beside: the share of rays with the same first hit."""

    timeout = 600

    def setup(self):
        from scenes.corner import corner
        from selfillum.transport.mitsuba_rays import MitsubaRayScene

        from ._scenes import same_rays

        mesh = corner(resolution=30).mesh
        self.scene, self.o, self.d = same_rays(mesh, 64, 0)
        self.ms = MitsubaRayScene(np.asarray(mesh.vertices, np.float64), mesh.faces)
        self.ms.run(self.o, self.d)  # scene commit, kernel compilation

    def time_mitsuba_rays(self):
        self.ms.run(self.o, self.d)

    def time_bare_embree(self):
        self.scene.run(self.o, self.d)

    def track_ratio_to_bare_embree(self):
        return ratio_of_best(lambda: self.ms.run(self.o, self.d),
                             lambda: self.scene.run(self.o, self.d))

    track_ratio_to_bare_embree.unit = "Mitsuba / bare Embree"

    def track_same_first_hit(self):
        return float(np.mean(np.asarray(self.scene.run(self.o, self.d))
                             == np.asarray(self.ms.run(self.o, self.d))))

    track_same_first_hit.unit = "share of rays"


class RenderVsModel:
    """An all-bounce Mitsuba render of the corner (resolution 20, reflectance 0.6, 320 x 240,
    64 samples a pixel, the fastest variant here) against the Lambertian model of the same
    image (view factors of 256 rays a face, the radiosity solve, the backprojection).
    Accuracy: the median and 95th percentile of render / model - 1 away from the plates'
    edges."""

    timeout = 900

    def setup(self):
        from scipy.ndimage import maximum_filter, minimum_filter

        from resection import Camera
        from resection.surface.surface_map import SurfaceMap
        from scenes.corner import corner
        from selfillum.rendering.mitsuba_render import available_variants, render
        from selfillum.solve.radiosity import forward
        from selfillum.transport.viewfactors import view_factors

        self.sc = corner(resolution=20, reflectance=0.6, pattern="smooth")
        W, H = 320, 240
        f = 0.8125 * W
        self.cam = Camera.look_at([1.4, 0.5, 1.2], [0.3, 0.5, 0.3], [0, 1, 0],
                                  K=[[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]],
                                  width=W, height=H)
        self.variant = available_variants()[0]
        self.render, self.forward, self.vf, self.SurfaceMap = (render, forward, view_factors,
                                                               SurfaceMap)
        self.model_image = self._model()
        fi = self.smap.face_index
        plate = np.where(fi >= 0, self.sc.plate[np.maximum(fi, 0)], -1)
        self.away = (plate >= 0) & (minimum_filter(plate, 5) == maximum_filter(plate, 5))
        self._render(1)  # JIT compilation of the vectorised variants

    def _model(self):
        F = self.vf(self.sc.mesh, rays_per_face=256, seed=1)
        B = self.forward(F, self.sc.emission, self.sc.reflectance)
        self.smap = self.SurfaceMap(self.sc.mesh, self.cam)
        return self.smap.to_image(B / np.pi, interpolation="nearest")

    def _render(self, spp=64):
        return self.render(self.sc.mesh, self.sc.emission, self.sc.reflectance, self.cam,
                           bounces=-1, spp=spp, seed=1, variant=self.variant)

    def time_mitsuba_render(self):
        self._render()

    def time_lambertian_model(self):
        self._model()

    def track_ratio_to_model(self):
        a, b = best_times(self._render, self._model, repeat=2)
        return a / b

    track_ratio_to_model.unit = "render / model"

    def _rel(self):
        return self._render().image[self.away] / self.model_image[self.away] - 1.0

    def track_median_difference(self):
        return float(np.median(self._rel()))

    track_median_difference.unit = "share"

    def track_p95_difference(self):
        return float(np.percentile(np.abs(self._rel()), 95))

    track_p95_difference.unit = "share"
