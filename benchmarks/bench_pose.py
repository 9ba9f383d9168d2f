"""The Point of View against OpenCV's solvePnP (``bench/bench_pose.py``)."""

from __future__ import annotations

import numpy as np

from ._peers import ratio_of_best


class PoseVsSolvePnP:
    """40 random cameras (radial + tangential distortion, 0.1 px noise, 6-15 markers in a
    0.6 m cube): ``resection.solve_pose`` (no guess: its own starts, the acceptance rule)
    against ``cv2.solvePnP`` (iterative) on the same cases."""

    timeout = 300

    def setup(self):
        import cv2
        from bench_pose import _case

        from resection import solve_pose

        rng = np.random.default_rng(0)
        self.cases = [_case(rng, int(rng.integers(6, 16)), False) for _ in range(40)]
        self.solve_pose = solve_pose
        self.cv2 = cv2
        self._ours()

    def _ours(self):
        from resection import SolveError

        for cam, X, uv in self.cases:
            try:
                self.solve_pose(cam, X, uv)
            except SolveError:  # an ambiguous or refused case costs its time too
                pass

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
