"""The pose stage: from linked markers to a camera.

Takes in model points (N, 3) and their pixels (N, 2), with intrinsics; gives out the Point
of View (:class:`PoseResult`: rotation, translation, residuals, covariance), the DLT, the
calibrated intrinsics, and the one acceptance rule that judges them all.

- :mod:`~resection.pose.solve`: :func:`solve_pose` (no guess needed; refuses ambiguous poses);
- :mod:`~resection.pose.starts`, :mod:`~resection.pose.three_point`: the starts (P3P, DLT,
  homography);
- :mod:`~resection.pose.dlt`: 11-parameter DLT, decomposition, homographies, ``dewarp``;
- :mod:`~resection.pose.calibration`: intrinsics and distortion from one or several views;
- :mod:`~resection.pose.acceptance`: the acceptance rule (marker accuracy, outliers, threshold);
- :mod:`~resection.pose.reprojection`: residuals and their Jacobians;
- :mod:`~resection.pose.figure20`: the residual overlay (the paper's Figure 20);
- :mod:`~resection.pose.pose_needed`: a camera without a pose named as such, with the way
  forward (link a few targets by hand).
"""

from __future__ import annotations

from resection._lazy import attach

_EXPORTS: dict[str, str] = {
    "Acceptance": ".acceptance",
    "CALIBRATION_PARAMETERS": ".calibration",
    "CONFIDENCE": ".acceptance",
    "CalibrationResult": ".calibration",
    "DEFAULT_MARKER_ACCURACY": ".acceptance",
    "DEFAULT_MAX_RMS": ".acceptance",
    "INTRINSIC_NAMES": ".solve",
    "OUTLIER_RISK": ".acceptance",
    "PoseResult": ".solve",
    "apply_homography": ".dlt",
    "calibrate": ".calibration",
    "camera_from_dlt": ".dlt",
    "check_accuracy": ".acceptance",
    "coplanarity": ".dlt",
    "decompose_projection": ".dlt",
    "dewarp": ".dlt",
    "dlt_coefficients": ".dlt",
    "dlt_project": ".dlt",
    "drop_outliers": ".acceptance",
    "fit_dlt": ".dlt",
    "fit_homography": ".dlt",
    "grade": ".acceptance",
    "has_usable_pose": ".pose_needed",
    "judge": ".acceptance",
    "outlier_gate": ".acceptance",
    "outlier_limit": ".acceptance",
    "p3p": ".three_point",
    "plot_pose": ".figure20",
    "require": ".acceptance",
    "require_pose": ".pose_needed",
    "rms_threshold": ".acceptance",
    "solve_pose": ".solve",
    "write_pose_plot": ".figure20",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = attach(__name__, _EXPORTS)
