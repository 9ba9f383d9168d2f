"""Image <-> surface mapping, the per-frame map of a moving model, the multi-camera merge and
the checks of ``map``, each against a bare-library peer or the work it sits in."""

from __future__ import annotations

import numpy as np

from ._peers import ROOT, ratio_of_best

UPSP = ROOT / "tests" / "data" / "upsp"


class SurfaceMapVsEmbree:
    """``SurfaceMap`` of a 1024 x 1024 camera with distortion on an icosphere of 20,480
    faces (pixel rays, Embree first hits, barycentrics, the sparse matrix; the camera's
    undistortion map already made) against one bare ``embreex`` call on the same float32
    rays (scene build + ``run``)."""

    timeout = 300

    def setup(self):
        import trimesh
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        from resection import Camera, SurfaceMap

        n = 1024
        m = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
        self.mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
        K = [[1.2 * n, 0, (n - 1) / 2], [0, 1.2 * n, (n - 1) / 2], [0, 0, 1]]
        self.cam = Camera.look_at([0.3, -0.4, 1.6], [0, 0, 0], [0, 0, 1], K=K, width=n,
                                  height=n, dist=[-0.1, 0.02, 0, 0, 0])
        self.SurfaceMap = SurfaceMap
        SurfaceMap(self.mesh, self.cam)
        o, d = self.cam.rays()
        self.o32 = np.ascontiguousarray(o, dtype=np.float32)
        self.d32 = d.astype(np.float32)
        self.v32 = np.asarray(self.mesh.vertices, np.float32)
        self.f32 = np.asarray(self.mesh.faces, np.int32)
        self.scene_type, self.tri_type = rtcore_scene.EmbreeScene, TriangleMesh

    def _bare(self):
        sc = self.scene_type()
        self.tri_type(scene=sc, vertices=self.v32, indices=self.f32)
        return sc.run(self.o32, self.d32)

    def _ours(self):
        return self.SurfaceMap(self.mesh, self.cam)

    def time_surface_map(self):
        self._ours()

    def time_bare_embree(self):
        self._bare()

    def track_ratio_to_bare_embree(self):
        return ratio_of_best(self._ours, self._bare)

    track_ratio_to_bare_embree.unit = "ours / bare Embree"

    def track_same_face(self):
        every = self.SurfaceMap(self.mesh, self.cam, max_obliqueness=None)
        return float(np.mean(self._bare() == every.face_index.ravel()))

    track_same_face.unit = "share of pixels"


def _frames(self, n: int = 512, frames: int = 10) -> None:
    """An icosphere of 20,480 faces seen at ``n`` x ``n``, its ``SurfaceMap`` (the
    reconstruction matrix built), ``frames`` images and ``frames`` per-face fields."""
    import trimesh

    from resection import Camera, SurfaceMap

    m = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
    K = [[1.2 * n, 0, (n - 1) / 2], [0, 1.2 * n, (n - 1) / 2], [0, 0, 1]]
    cam = Camera.look_at([0.3, -0.4, 1.6], [0, 0, 0], [0, 0, 1], K=K, width=n, height=n)
    self.smap = SurfaceMap(mesh, cam)
    rng = np.random.default_rng(0)
    self.stack = rng.normal(100.0, 5.0, size=(frames, n, n)).astype(np.float32)
    self.stack[:, :10, :10] = np.nan
    self.nf = len(mesh.faces)
    self.values = rng.normal(size=(frames, self.nf))
    self.smap.to_image(self.values[0])


class ToSurfaceVsBincount:
    """``SurfaceMap.to_surface`` of 10 frames of 512 x 512 (one sparse product, NaN-aware)
    against the per-frame ``numpy.bincount`` over the face-index image."""

    timeout = 300
    setup = _frames

    def _bincount(self):
        fi = self.smap.face_index.ravel()
        on = fi >= 0
        out = np.empty((len(self.stack), self.nf))
        for k, frame in enumerate(self.stack):  # the per-frame peer
            x = frame.ravel()[on]
            ok = np.isfinite(x)
            s = np.bincount(fi[on][ok], weights=x[ok], minlength=self.nf)
            c = np.bincount(fi[on][ok], minlength=self.nf)
            with np.errstate(invalid="ignore", divide="ignore"):
                out[k] = s / c
        return out

    def time_to_surface(self):
        self.smap.to_surface(self.stack)

    def time_numpy_bincount(self):
        self._bincount()

    def track_ratio_to_bincount(self):
        return ratio_of_best(lambda: self.smap.to_surface(self.stack), self._bincount)

    track_ratio_to_bincount.unit = "ours / bincount"


class ToImageVsGather:
    """``SurfaceMap.to_image`` (linear: vertex reconstruction + barycentric interpolation)
    of 10 fields on the same map against the per-frame gather ``values[face_index]``
    (nearest, the cheapest backprojection)."""

    timeout = 300
    setup = _frames

    def _gather(self):
        fi = self.smap.face_index.ravel()
        on = fi >= 0
        out = np.full((len(self.values), fi.size), np.nan)
        out[:, on] = self.values[:, fi[on]]
        return out

    def time_to_image(self):
        self.smap.to_image(self.values)

    def time_nearest_gather(self):
        self._gather()

    def track_ratio_to_gather(self):
        return ratio_of_best(lambda: self.smap.to_image(self.values), self._gather)

    track_ratio_to_gather.unit = "linear / nearest gather"


def _upsp_map():
    from resection.io.cameras import read_camera
    from resection.io.meshes import load_mesh
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster

    mesh = load_mesh(UPSP / "fml_tc3_volume.grid")
    cam = read_camera(UPSP / "camera-tunnel-calibration" / "camera01_35_6.json")
    caster = RayCaster(mesh)
    smap = SurfaceMap(mesh, cam, caster=caster)
    rng = np.random.default_rng(1)
    frame = np.where(smap.mask, 2400.0, 60.0) * rng.gamma(30.0, 1 / 30.0, smap.shape)
    frame[:, :3] = 2.0  # a dark border
    return mesh, cam, caster, smap, frame


class LimiterOnUpspGrid:
    """``SurfaceMap.to_image`` (linear) on NASA uPSP's grid (609,120 faces) and camera 1
    (1280 x 800) with the limiter that holds vertex values within their faces' values,
    against the same call with the limiter replaced by nothing."""

    timeout = 600

    def setup(self):
        from resection.surface import vertex_fit

        self.mesh, _, _, self.smap, _ = _upsp_map()
        self.fv = np.random.default_rng(0).integers(1, 166, len(self.mesh.faces)).astype(float)
        self.vertex_fit, self.real = vertex_fit, vertex_fit._clamp_to_support
        self.smap.to_image(self.fv)

    def teardown(self):
        self.vertex_fit._clamp_to_support = self.real

    def _with(self):
        self.vertex_fit._clamp_to_support = self.real
        self.smap.to_image(self.fv)

    def _without(self):
        self.vertex_fit._clamp_to_support = lambda *a: None
        try:
            self.smap.to_image(self.fv)
        finally:
            self.vertex_fit._clamp_to_support = self.real

    def time_to_image_limited(self):
        self._with()

    def time_to_image_unlimited(self):
        self._without()

    def track_ratio_to_unlimited(self):
        return ratio_of_best(self._with, self._without, repeat=5)

    track_ratio_to_unlimited.unit = "limited / unlimited"


class FootprintVsSurfaceMap:
    """The footprint check of ``map`` without ``--markers`` (``footprint_fit``: Otsu,
    8-pixel cells, 7 scales) against building the camera's ``SurfaceMap`` that ``map``
    builds anyway (the same Embree scene), on uPSP's grid and camera 1."""

    timeout = 600

    def setup(self):
        from resection.pose.footprint import footprint_fit
        from resection.surface.surface_map import SurfaceMap

        self.mesh, self.cam, self.caster, _, self.frame = _upsp_map()
        v = self.mesh.vertices
        self.bounds = (v.min(axis=0), v.max(axis=0))
        self.fit, self.SurfaceMap = footprint_fit, SurfaceMap
        self._fit()

    def _fit(self):
        self.fit(self.cam, self.frame, self.caster, bounds=self.bounds)

    def _map(self):
        self.SurfaceMap(self.mesh, self.cam, caster=self.caster)

    def time_footprint_fit(self):
        self._fit()

    def time_surface_map(self):
        self._map()

    def track_ratio_to_surface_map(self):
        return ratio_of_best(self._fit, self._map)

    track_ratio_to_surface_map.unit = "footprint / SurfaceMap"


class DarkBorderVsToSurface:
    """The dark-border search (``resection.border.mask_dark_border``) against
    ``SurfaceMap.to_surface`` of the same 1280 x 800 frame on uPSP's grid."""

    timeout = 600

    def setup(self):
        from resection.border import mask_dark_border

        _, _, _, self.smap, self.frame = _upsp_map()
        self.mask = mask_dark_border

    def time_mask_dark_border(self):
        self.mask(self.frame)

    def time_to_surface(self):
        self.smap.to_surface(self.frame)

    def track_ratio_to_to_surface(self):
        return ratio_of_best(lambda: self.mask(self.frame),
                             lambda: self.smap.to_surface(self.frame), repeat=5)

    track_ratio_to_to_surface.unit = "dark border / to_surface"


class MergeVsSurfaceMaps:
    """The multi-camera merge (``merge_views``: gain matched, feathered) of the two
    1280 x 960 frames of ``scenes.real_traits`` against building the two cameras'
    ``SurfaceMap``s. Accuracy: the 90th percentile of the seam step against the truth
    (``tests/test_merge.py``'s measure, a share)."""

    timeout = 300

    def setup(self):
        from resection.surface.merge import merge_views
        from resection.surface.surface_map import SurfaceMap
        from scenes.real_traits import real_traits

        self.sc = real_traits(scale=4)
        self.maps = [SurfaceMap(self.sc.mesh, c) for c in self.sc.cameras]
        self.images = [np.where(i == 255, np.nan, i.astype(float)) for i in self.sc.images]
        self.merge, self.SurfaceMap = merge_views, SurfaceMap

    def _merge(self):
        return self.merge(self.maps, self.images)

    def _maps(self):
        return [self.SurfaceMap(self.sc.mesh, c) for c in self.sc.cameras]

    def time_merge_views(self):
        self._merge()

    def time_surface_maps(self):
        self._maps()

    def track_ratio_to_surface_maps(self):
        return ratio_of_best(self._merge, self._maps)

    track_ratio_to_surface_maps.unit = "merge / two SurfaceMaps"

    def track_seam_p90(self):
        import sys

        sys.path.insert(0, str(ROOT / "tests"))
        try:
            from test_merge import seam_level
        finally:
            sys.path.remove(str(ROOT / "tests"))
        return float(seam_level(self.sc, self.maps, self._merge())[0])

    track_seam_p90.unit = "share"


class SequenceMappingVsUpsp:
    """Per-frame maps of a pitching model (``map_frames``, a pose per frame), 60 frames of
    256 x 256, against uPSP's way: the frame-0 map and an affine ECC warp of every frame
    onto frame 0 (OpenCV). Accuracy: the 95th percentile of the error at the nodes near an
    edge against the paint field (counts; the field is 600-1,400), ours and uPSP's way."""

    timeout = 600

    def setup(self):
        from resection.sequence.mapping import map_frames
        from scenes.moving_model import pitch_oscillation
        from scenes.moving_surface import edge_nodes, model_surface, paint_field, render_surface

        from ._scenes import upsp_way

        model = pitch_oscillation(60, shape=(256, 256))
        self.mesh = model_surface(0.01)
        self.frames = [render_surface(model, k) for k in range(60)]
        self.cams = [model.camera_at(k) for k in range(60)]
        self.truth = paint_field(self.mesh.vertices)
        self.edge = edge_nodes(self.mesh)
        self.map_frames, self.upsp_way = map_frames, upsp_way

    def _ours(self):
        return np.array([r.values for r in self.map_frames(self.mesh, self.cams, self.frames,
                                                           per="node")])

    def _upsp(self):
        return np.array(list(self.upsp_way(self.mesh, self.cams[0], self.frames)))

    def time_per_frame_maps(self):
        self._ours()

    def time_upsp_way(self):
        self._upsp()

    def track_ratio_to_upsp_way(self):
        return ratio_of_best(self._ours, self._upsp, repeat=2)

    track_ratio_to_upsp_way.unit = "ours / uPSP's way"

    def _edge_p95(self, values):
        e = np.abs(values - self.truth)[:, self.edge]
        return float(np.percentile(e[np.isfinite(e)], 95))

    def track_edge_error_p95(self):
        return self._edge_p95(self._ours())

    track_edge_error_p95.unit = "counts"

    def track_upsp_edge_error_p95(self):
        return self._edge_p95(self._upsp())

    track_upsp_edge_error_p95.unit = "counts"


class ToImageRenormalisedVsPlainProduct:
    """``SurfaceMap.to_image`` with the renormalised interpolation (unseen faces' values
    NaN, the background filled) on a 320,000-face plate seen at 1280 x 960, against the
    plain interpolation core (one sparse product of NaN-zeroed vertex values)."""

    timeout = 300

    def setup(self):
        import trimesh

        from resection import Camera
        from resection.surface.surface_map import SurfaceMap

        n = 400
        xs = np.linspace(-1, 1, n + 1)
        X, Y = np.meshgrid(xs, xs)
        V = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
        idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
        a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
        c, d = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
        F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
        mesh = trimesh.Trimesh(V, F, process=False)
        cam = Camera.look_at([0.1, -0.2, 2.4], [0, 0, 0], [0, 1, 0],
                             K=[[900, 0, 639.5], [0, 900, 479.5], [0, 0, 1]], width=1280,
                             height=960)
        self.smap = SurfaceMap(mesh, cam)
        self.fv = 1000 + mesh.triangles_center[:, 0] * 300
        self.fv[mesh.triangles_center[:, 0] > 0.5] = np.nan
        self.smap.to_image(self.fv)

    def _plain(self):
        vert = self.smap.vertex_values(self.fv[:, None], "linear")
        return (self.smap._interpolation_matrix() @ np.nan_to_num(vert)).T

    def time_to_image(self):
        self.smap.to_image(self.fv)

    def time_plain_product(self):
        self._plain()

    def track_ratio_to_plain_product(self):
        return ratio_of_best(lambda: self.smap.to_image(self.fv), self._plain, repeat=5)

    track_ratio_to_plain_product.unit = "to_image / plain product"
