"""The pose, the calibration and the camera checks against OpenCV and the work they guard."""

from __future__ import annotations

import numpy as np

from ._peers import ratio_of_best


class PoseVsSolvePnP:
    """40 random cameras (radial + tangential distortion, 0.1 px noise, 6-15 markers in a
    0.6 m cube): ``resection.solve_pose`` (no guess: its own starts, the acceptance rule)
    against ``cv2.solvePnP`` (iterative) on the same cases. Tracked beside: the cases
    returned more than 1 degree or 2 % of the distance off (gross errors; refused cases
    are not counted)."""

    timeout = 300

    def setup(self):
        import cv2

        from resection import solve_pose

        from ._scenes import pose_case

        rng = np.random.default_rng(0)
        self.cases = [pose_case(rng, int(rng.integers(6, 16)), False) for _ in range(40)]
        self.solve_pose = solve_pose
        self.cv2 = cv2
        self._ours()

    def _ours(self):
        from resection import SolveError

        out = []
        for cam, X, uv in self.cases:
            try:
                out.append(self.solve_pose(cam, X, uv))
            except SolveError:  # an ambiguous or refused case costs its time too
                out.append(None)
        return out

    def _opencv(self):
        for cam, X, uv in self.cases:
            self.cv2.solvePnP(X, uv, np.asarray(cam.K), np.asarray(cam.dist),
                              flags=self.cv2.SOLVEPNP_ITERATIVE)

    def time_solve_pose(self):
        self._ours()

    def time_opencv_solvepnp(self):
        self._opencv()

    def track_ratio_to_solvepnp(self):
        return ratio_of_best(self._ours, self._opencv)

    track_ratio_to_solvepnp.unit = "ours / solvePnP"

    def track_gross_errors(self):
        gross = 0
        for res, (cam, _, _) in zip(self._ours(), self.cases, strict=True):
            if res is None:
                continue
            got = res.camera
            c = (np.trace(got.R.T @ cam.R) - 1) / 2
            rot = np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
            far = np.linalg.norm(got.center - cam.center) / np.linalg.norm(cam.center)
            gross += bool(rot > 1.0 or far > 0.02)
        return gross

    track_gross_errors.unit = "of 40 cases"


class CalibrateVsOpenCV:
    """10 views of an 11 x 8 planar board, 0.1 px noise, distortion ``k1, k2, p1, p2`` (k3
    fixed): ``resection.calibrate`` against ``cv2.calibrateCamera(flags=CALIB_FIX_K3)``.
    Accuracy: the largest error of fx, fy, cx, cy against the truth (pixels)."""

    timeout = 300

    def setup(self):
        import cv2

        from resection import Camera, calibrate

        from ._scenes import H, W

        rng = np.random.default_rng(3)
        self.K = np.array([[1150.0, 0, 650.5], [0, 1158.0, 470.2], [0, 0, 1.0]])
        dist = np.array([-0.22, 0.09, 0.0012, -0.0009, 0.0])
        gx, gy = np.meshgrid(np.arange(11) * 0.03, np.arange(8) * 0.03)
        board = np.column_stack([gx.ravel() - 0.15, gy.ravel() - 0.105, np.zeros(88)])
        self.views = []
        while len(self.views) < 10:
            d = rng.normal(size=3)
            d[2] = -abs(d[2]) - 1.0
            cam = Camera.look_at(d / np.linalg.norm(d) * rng.uniform(0.45, 0.7),
                                 rng.normal(scale=0.03, size=3), [0, -1, 0.3], K=self.K,
                                 width=W, height=H, dist=dist)
            uv, ok = cam.project(board, return_valid=True)
            if ok.all() and cam.in_image(uv, margin=3).all():
                self.views.append((board, uv + rng.normal(scale=0.1, size=uv.shape)))
        self.op = [v[0].astype(np.float32) for v in self.views]
        self.ip = [v[1].astype(np.float32) for v in self.views]
        self.size, self.calibrate, self.cv2 = (W, H), calibrate, cv2

    def _ours(self):
        return self.calibrate(self.views, self.size, fix=("k3",))

    def _opencv(self):
        return self.cv2.calibrateCamera(self.op, self.ip, self.size, None, None,
                                        flags=self.cv2.CALIB_FIX_K3)

    def time_calibrate(self):
        self._ours()

    def time_opencv_calibrate_camera(self):
        self._opencv()

    def track_ratio_to_calibrate_camera(self):
        return ratio_of_best(self._ours, self._opencv)

    track_ratio_to_calibrate_camera.unit = "ours / OpenCV"

    def track_intrinsic_error(self):
        sel = [0, 1, 0, 1], [0, 1, 2, 2]
        return float(np.abs(self._ours().camera.K[sel] - self.K[sel]).max())

    track_intrinsic_error.unit = "px"


def _real_traits_camera():
    from resection.io.marker_set import MarkerSet
    from resection.surface.surface_map import SurfaceMap
    from scenes.real_traits import real_traits

    sc = real_traits(scale=4)  # 1280 x 960, two cameras, 22 targets
    ms = MarkerSet(sc.marker_ids, sc.surveyed, np.full(len(sc.marker_ids), 0.006))
    cam, img = sc.cameras[0], sc.images[0].astype(np.float32)
    return sc, ms, cam, img, SurfaceMap(sc.mesh, cam)


class MarkerFitVsSurfaceMap:
    """The camera check of ``--markers`` (``marker_fit``: a window per target) against
    building the ``SurfaceMap`` of the same camera that ``map`` builds anyway
    (``scenes.real_traits`` at 1280 x 960)."""

    timeout = 300

    def setup(self):
        from resection.pose.camera_fit import marker_fit
        from resection.surface.surface_map import SurfaceMap

        self.sc, self.ms, self.cam, self.img, self.smap = _real_traits_camera()
        self.fit, self.SurfaceMap = marker_fit, SurfaceMap
        self._fit()

    def _fit(self):
        self.fit(self.cam, self.img, self.ms, surface_map=self.smap)

    def _map(self):
        self.SurfaceMap(self.sc.mesh, self.cam)

    def time_marker_fit(self):
        self._fit()

    def time_surface_map(self):
        self._map()

    def track_ratio_to_surface_map(self):
        return ratio_of_best(self._fit, self._map)

    track_ratio_to_surface_map.unit = "marker_fit / SurfaceMap"


class FingerprintVsToSurface:
    """The image record ``pose`` writes and ``map`` and ``correct`` compare
    (``image_fingerprint``) against mapping the same image (``SurfaceMap.to_surface``)."""

    timeout = 300

    def setup(self):
        from resection.pose.camera_fit import image_fingerprint

        _, _, _, self.img, self.smap = _real_traits_camera()
        self.fingerprint = image_fingerprint

    def time_image_fingerprint(self):
        self.fingerprint(self.img)

    def time_to_surface(self):
        self.smap.to_surface(self.img)

    def track_ratio_to_to_surface(self):
        return ratio_of_best(lambda: self.fingerprint(self.img),
                             lambda: self.smap.to_surface(self.img), repeat=5)

    track_ratio_to_to_surface.unit = "fingerprint / to_surface"
