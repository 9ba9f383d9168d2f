"""Marker detection against OpenCV's SimpleBlobDetector (``bench/bench_detect.py``)."""

from __future__ import annotations

import numpy as np

from ._peers import ratio_of_best


class DetectVsOpenCV:
    """A 1024 x 1024 16-bit frame, 400 dark markers of 6 px, SNR 20, an illumination
    gradient; ours (sub-pixel fit included) against ``cv2.SimpleBlobDetector``."""

    timeout = 300

    def setup(self):
        from bench_detect import make_frame, opencv_detector

        from resection.markers.detect import detect_markers

        self.frame, _ = make_frame((1024, 1024), 400, 6.0, 20.0, 0)
        self.opencv = opencv_detector()
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
