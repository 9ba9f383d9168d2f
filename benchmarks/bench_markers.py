"""Marker detection, matching and refinding against their peers (OpenCV, trackpy, a bare
solve), with the accuracy against each scene's truth tracked beside the ratio."""

from __future__ import annotations

import math

import numpy as np

from ._peers import ratio_of_best


class DetectVsOpenCV:
    """A 1024 x 1024 16-bit frame, 400 dark markers of 6 px, SNR 20, an illumination
    gradient; ours (sub-pixel fit included) against ``cv2.SimpleBlobDetector`` (defaults,
    the frame scaled to 8 bits in its time, one thread). Accuracy: RMS error per
    coordinate of the markers found within 1.5 px of the truth (pixels)."""

    timeout = 300

    def setup(self):
        from resection.markers.detect import detect_markers

        from ._scenes import make_frame, opencv_default_detector

        self.frame, self.truth = make_frame((1024, 1024), 400, 6.0, 20.0, 0)
        self.opencv = opencv_default_detector()
        self.detect = detect_markers
        self.detect(np.ascontiguousarray(self.frame[:256, :256]), 6.0)  # kernels loaded first

    def time_detect_markers(self):
        self.detect(self.frame, 6.0)

    def time_opencv_blob_detector(self):
        self.opencv(self.frame)

    def track_ratio_to_opencv(self):
        return ratio_of_best(lambda: self.detect(self.frame, 6.0),
                             lambda: self.opencv(self.frame))

    track_ratio_to_opencv.unit = "ours / OpenCV"

    def track_rms_error(self):
        from ._scenes import accuracy

        return accuracy(self.detect(self.frame, 6.0).uv, self.truth)[0]

    track_rms_error.unit = "px"

    def track_opencv_rms_error(self):
        from ._scenes import accuracy

        return accuracy(self.opencv(self.frame), self.truth)[0]

    track_opencv_rms_error.unit = "px"


class DetectVsTrackpy:
    """``scenes.marker_images.make_scene``: 1024 x 1024, 200 markers of 6 px, SNR 20, blur
    0.7 px; ours against ``trackpy.locate`` (inverted, the feature size of the markers)."""

    timeout = 300

    def setup(self):
        import trackpy

        from resection.markers.detect import detect_markers
        from scenes.marker_images import make_scene

        trackpy.quiet()
        self.sc = make_scene((1024, 1024), 200, 6.0, snr=20.0, blur=0.7, rng=0)
        self.detect = detect_markers
        self.size = int(2 * np.ceil(6.0 / 2 + 1.5) + 1)
        self.trackpy = trackpy
        self.detect(self.sc.image, 6.0)

    def _trackpy(self):
        return self.trackpy.locate(self.sc.image, self.size, invert=True, minmass=0)

    def time_detect_markers(self):
        self.detect(self.sc.image, 6.0)

    def time_trackpy_locate(self):
        self._trackpy()

    def track_ratio_to_trackpy(self):
        return ratio_of_best(lambda: self.detect(self.sc.image, 6.0), self._trackpy)

    track_ratio_to_trackpy.unit = "ours / trackpy"

    def track_trackpy_rms_error(self):
        from ._scenes import accuracy

        uv = self._trackpy().nlargest(200, "mass")[["x", "y"]].to_numpy()
        return accuracy(uv, self.sc.uv)[0]

    track_trackpy_rms_error.unit = "px"


class DetectPaintVsOpenCV:
    """Real-looking paint (``scenes.revolution.paint_frame``, seed 100, not one the detector
    was developed on): 1280 x 800 8-bit, speckle, grain, glare, targets of 4-6 px, taps of
    2-3 px; ours against ``cv2.SimpleBlobDetector`` with its area filter set for the targets
    and thresholds 10-250 by 10. Accuracy: the share of the targets found within 1.5 px."""

    timeout = 300

    def setup(self):
        from resection.markers.detect import detect_markers
        from scenes.revolution import paint_frame

        from ._scenes import opencv_target_detector

        self.img, self.truth, self.d, _ = paint_frame(100, snr=20.0)
        self.opencv = opencv_target_detector(self.d)
        self.detect = detect_markers
        self.detect(self.img, self.d)

    def time_detect_markers(self):
        self.detect(self.img, self.d)

    def time_opencv_blob_detector(self):
        self.opencv(self.img)

    def track_ratio_to_opencv(self):
        return ratio_of_best(lambda: self.detect(self.img, self.d),
                             lambda: self.opencv(self.img))

    track_ratio_to_opencv.unit = "ours / OpenCV"

    def _found(self, uv):
        from scipy.spatial import cKDTree

        return float((cKDTree(uv).query(self.truth)[0] < 1.5).mean()) if len(uv) else 0.0

    def track_found_share(self):
        return self._found(self.detect(self.img, self.d).uv)

    track_found_share.unit = "share of targets"

    def track_opencv_found_share(self):
        return self._found(self.opencv(self.img))

    track_opencv_found_share.unit = "share of targets"


class MatchingVsSolvePnP:
    """Matching 30 markers (30 % hidden, as many spurious candidates as real ones, a camera
    a few mm and a few mrad off) against one bare ``cv2.solvePnP`` on the known pairs,
    20 frames; the frames matched exactly are tracked."""

    timeout = 300

    def setup(self):
        import cv2
        from scipy.spatial.transform import Rotation

        from resection.camera.model import Camera
        from resection.markers.match import match_markers

        rng = np.random.default_rng(1)
        K = [[1500.0, 0, 512], [0, 1500.0, 384], [0, 0, 1]]
        self.base = Camera.look_at([0.2, -0.3, 1.6], [0, 0, 0], [0, 1, 0], K=K, width=1024,
                                   height=768)
        n = 30
        X = np.column_stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.25, 0.25, n),
                             np.zeros(n)])
        X[:, 2] = 0.08 * np.exp(-((X[:, 1] / 0.08) ** 2))
        self.ids, self.X = tuple(f"M{k}" for k in range(n)), X
        self.data = []
        for _ in range(20):
            dR = Rotation.from_rotvec(rng.normal(0, 0.004, 3)).as_matrix()
            cam = self.base.with_pose(R=dR @ self.base.R, t=self.base.t + rng.normal(0, 0.004, 3))
            uv = cam.project(X)
            vis = cam.in_image(uv, margin=8) & (rng.random(n) > 0.3)
            real = uv[vis] + rng.normal(0, 0.05, (vis.sum(), 2))
            spur = np.column_stack([rng.uniform(5, 1019, vis.sum()),
                                    rng.uniform(5, 763, vis.sum())])
            Q = np.vstack([real, spur])
            perm = rng.permutation(len(Q))
            truth = np.array([self.ids[i] for i in np.flatnonzero(vis)] + [None] * vis.sum(),
                             dtype=object)
            self.data.append((Q[perm], truth[perm], X[vis], real))
        self.K = np.array(K)
        self.match, self.cv2 = match_markers, cv2
        self._ours()

    def _ours(self):
        return [self.match(Q, (self.ids, self.X), self.base) for Q, _, _, _ in self.data]

    def _opencv(self):
        for _, _, Xv, real in self.data:
            self.cv2.solvePnP(Xv, real, self.K, None, flags=self.cv2.SOLVEPNP_ITERATIVE)

    def time_match_markers(self):
        self._ours()

    def time_opencv_solvepnp(self):
        self._opencv()

    def track_ratio_to_solvepnp(self):
        return ratio_of_best(self._ours, self._opencv)

    track_ratio_to_solvepnp.unit = "ours / solvePnP"

    def track_frames_matched(self):
        return sum(np.array_equal(np.array(r.ids, dtype=object), d[1])
                   for r, d in zip(self._ours(), self.data, strict=True))

    track_frames_matched.unit = "of 20 frames"


def _refind_scene(scale: float = 2.0):
    """Camera 0 of ``scenes.real_traits`` (8-bit, a black block, a target cut by the
    edge, taps, survey errors of 0.5-1.5 px), a start 0.4 degree and 2 % off."""
    from scipy.spatial.transform import Rotation

    from resection.io.markers import MarkerSet
    from scenes.real_traits import real_traits

    sc = real_traits(scale=scale)
    truth = sc.cameras[0]
    d = np.linalg.norm(truth.center)
    R0 = Rotation.from_rotvec(np.radians(0.4) * np.array([0.6, 0.0, 0.8])).as_matrix() @ truth.R
    start = truth.replace(R=R0, t=-R0 @ (truth.center + 0.02 * d * np.array([0.6, -0.64, 0.48])))
    ms = MarkerSet(sc.marker_ids, sc.surveyed, np.full(len(sc.marker_ids), 0.006))
    mo = {"match_options": {"search_radius": 25.0 * scale, "tolerance": 3.0 * scale}}
    return sc, truth, start, ms, sc.images[0].astype(float), mo


class RefindVsFirstPose:
    """``refind_targets`` after the first pose (windows, local enhancement, fit, pose
    again) against the first pose itself (``pose_from_image``: detection over the whole
    image, matching, pose), on ``scenes.real_traits`` camera 0 at 640 x 480. Accuracy: the
    rotation error of the refound pose against the truth (degrees)."""

    timeout = 300

    def setup(self):
        from resection.markers.from_image import pose_from_image
        from resection.markers.refind import refind_targets

        self.sc, self.truth, self.start, self.ms, self.img, self.mo = _refind_scene()
        self.pose_from_image, self.refind = pose_from_image, refind_targets
        self.first, self.pts = self._first()

    def _first(self):
        return self.pose_from_image(self.img, self.ms, self.start, **self.mo)

    def _refind(self):
        return self.refind(self.img, self.ms, self.first.camera, self.pts.ids,
                           self.pts.points2d, mesh=self.sc.mesh)

    def time_first_pose(self):
        self._first()

    def time_refind_targets(self):
        self._refind()

    def track_ratio_to_first_pose(self):
        return ratio_of_best(self._refind, self._first)

    track_ratio_to_first_pose.unit = "refind / first pose"

    def track_rotation_error(self):
        from scipy.spatial.transform import Rotation

        cam = self._refind().pose.camera
        return math.degrees(Rotation.from_matrix(cam.R @ self.truth.R.T).magnitude())

    track_rotation_error.unit = "deg"


class AcceptanceRuleVsBareSolve:
    """``solve_pose`` (the acceptance rule and outlier loop included) against one bare solve
    of the same markers (``resection.pose.solve._solve_once``), the refound markers of
    ``scenes.real_traits`` camera 0: what the rule costs."""

    timeout = 300

    def setup(self):
        from resection.markers.from_image import pose_from_image
        from resection.markers.refind import refind_targets
        from resection.pose.solve import _solve_once, solve_pose

        sc, self.truth, start, ms, img, mo = _refind_scene()
        first, pts = pose_from_image(img, ms, start, **mo)
        found = refind_targets(img, ms, first.camera, pts.ids, pts.points2d, mesh=sc.mesh)
        self.X, self.uv = found.points3d, found.points2d
        self.rule, self.bare = solve_pose, _solve_once

    def _rule(self):
        self.rule(self.truth, self.X, self.uv)

    def _bare(self):
        self.bare(self.truth, self.X, self.uv)

    def time_solve_pose(self):
        self._rule()

    def time_bare_solve(self):
        self._bare()

    def track_ratio_to_bare_solve(self):
        return ratio_of_best(self._rule, self._bare, repeat=10)

    track_ratio_to_bare_solve.unit = "solve_pose / bare solve"



def _oblique_frame(n: int = 40, a: float = 15.0, b: float = 8.25, phi: float = 0.5,
                   blur: float = 0.6, snr: float = 100.0, seed: int = 0):
    """``n`` round markers of 30 px seen at an aspect of 0.55, rotated by ``phi`` (rad):
    ellipses of semi-axes ``a, b`` rendered 16 x 16 times a pixel, blurred by SciPy's
    Gaussian filter and averaged over each pixel (contrast 100 on 1000, noise 100 / snr);
    returns the frame, the true centres and starts 0.5 px off."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    S, W = 16, 64
    c, s = np.cos(phi), np.sin(phi)
    Rm = np.array([[c, -s], [s, c]])
    Q = Rm @ np.diag([1 / a**2, 1 / b**2]) @ Rm.T
    truth = np.column_stack([32 + 64 * np.arange(n) + rng.uniform(-0.5, 0.5, n),
                             32 + rng.uniform(-0.5, 0.5, n)])
    g = (np.arange(W * S) + 0.5) / S - 0.5
    img = np.zeros((W, W * n))
    for i, (u, v) in enumerate(truth):  # the markers, a few dozen
        U, V = np.meshgrid(g - (u - 64 * i), g - v)
        inside = (Q[0, 0] * U * U + 2 * Q[0, 1] * U * V + Q[1, 1] * V * V <= 1).astype(float)
        img[:, 64 * i:64 * (i + 1)] = gaussian_filter(inside, blur * S, mode="constant",
                                                      truncate=6).reshape(W, S, W, S).mean(
                                                          axis=(1, 3))
    img = 1000 + 100 * img + rng.normal(0, 100 / snr, img.shape)
    return img, truth, truth + rng.normal(0, 0.5, truth.shape)


class ObliqueMarkersEllipseVsDisk:
    """40 round markers of 30 px seen at an aspect of 0.55 (``_oblique_frame``: rendered by
    supersampling, SNR 100), each fitted in its window from a start 0.5 px off:
    ``refine_markers(shape="ellipse")`` (the tracker's model for markers of 12 px or more)
    against the disk model (``shape="disk"``, the tracker's before). Tracked beside: each
    one's RMS centre error against the truth (pixels)."""

    timeout = 300

    def setup(self):
        from resection.markers.refine import refine_markers

        self.img, self.truth, self.start = _oblique_frame()
        self.fit = refine_markers
        self._ellipse()  # kernels loaded first
        self._disk()

    def _ellipse(self):
        return self.fit(self.img, self.start, 30.0, shape="ellipse")

    def _disk(self):
        return self.fit(self.img, self.start, 30.0, shape="disk")

    def _rms(self, f):
        d = np.column_stack([f["u"], f["v"]]) - self.truth
        return float(np.sqrt(np.mean(d**2)))

    def time_ellipse(self):
        self._ellipse()

    def time_disk(self):
        self._disk()

    def track_ratio_to_disk(self):
        return ratio_of_best(self._ellipse, self._disk)

    track_ratio_to_disk.unit = "ellipse / disk"

    def track_rms_error(self):
        return self._rms(self._ellipse())

    track_rms_error.unit = "px"

    def track_disk_rms_error(self):
        return self._rms(self._disk())

    track_disk_rms_error.unit = "px"
