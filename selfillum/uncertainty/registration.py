"""Registration: the error of a camera's pose, carried to each face as a pixel displacement
times the local image gradient.

Model. The pose is a least-squares fit to the markers' image positions, each coordinate
with the stated standard uncertainty ``sigma_m`` (``--u marker=0.04px``, Liu and Sullivan's
order of magnitude). Its covariance is ``sigma_m^2 (J^T J)^-1`` with ``J`` (2M, 6) the
derivatives of the M markers' projections with respect to the pose perturbation
``theta = (w, dt)``: ``R' = exp([w]x) R``, ``t' = t + dt`` (:func:`pose_covariance`,
central differences of :meth:`resection.Camera.project`). A perturbed pose moves the image
point of a surface point by ``du = (du/dtheta) theta`` pixels; the face value then reads
the images ``du`` away, so its error is the merge-weighted mean over its pixels of
``grad I . du``. Wind-off and wind-on share the camera's pose, so the ratio's relative
error is ``du . grad ln(I_off / I_on)``: only the gradient of the pressure's signature,
not of the paint texture, matters (:func:`ratio_sensitivity`). The six components are
shared by every face of the camera (correlated), and independent between cameras.

Left out: the intrinsics' uncertainty (taken as known), the markers' 3-D positions'
uncertainty, and second-order terms (the displacement is small against the image's
curvature scale).
"""

from __future__ import annotations

import numpy as np

from resection.errors import InputError

__all__ = ["perturbed", "pose_covariance", "pixel_jacobian", "ratio_sensitivity"]

_STEP = (1e-6, 1e-6, 1e-6, 1e-6, 1e-6, 1e-6)


def perturbed(camera, theta):
    """The camera with its pose perturbed by ``theta = (w, dt)`` (rad, model units)."""
    from resection.camera.rotation import rotvec_to_matrix

    th = np.asarray(theta, dtype=np.float64)
    return camera.with_pose(R=rotvec_to_matrix(th[:3]) @ camera.R, t=camera.t + th[3:])


def _jacobian(camera, points) -> np.ndarray:
    """(P, 2, 6) derivatives of the projections of ``points`` w.r.t. ``theta``."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    J = np.empty((len(P), 2, 6))
    for k in range(6):  # six central differences, each a batch projection
        e = np.zeros(6)
        e[k] = _STEP[k] * max(1.0, float(np.abs(camera.t).max()) if k >= 3 else 1.0)
        J[:, :, k] = (perturbed(camera, e).project(P)
                      - perturbed(camera, -e).project(P)) / (2 * e[k])
    return J


def pose_covariance(camera, markers, sigma_px: float, name: str = "markers") -> np.ndarray:
    """(6, 6) covariance of ``theta`` from the markers the camera sees.

    Parameters
    ----------
    camera : resection.Camera
    markers : (M, 3) array_like
        Marker positions (model units); those that project outside the image are left out.
    sigma_px : float
        Standard uncertainty of a marker's image position, per coordinate (pixels).
    """
    X = np.asarray(markers, dtype=np.float64).reshape(-1, 3)
    uv = camera.project(X)
    ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] > -0.5) & (uv[:, 1] > -0.5) \
        & (uv[:, 0] < camera.width - 0.5) & (uv[:, 1] < camera.height - 0.5)
    if ok.sum() < 3:
        raise InputError(f"{name}: {int(ok.sum())} markers in the camera's image; the pose's "
                         "covariance needs at least 3")
    J = _jacobian(camera, X[ok]).reshape(-1, 6)
    N = J.T @ J
    if np.linalg.cond(N) > 1e14:
        raise InputError(f"{name}: the markers the camera sees do not determine its pose "
                         "(collinear or too few)")
    return float(sigma_px) ** 2 * np.linalg.inv(N)


def pixel_jacobian(smap) -> np.ndarray:
    """(6, H, W, 2) pixel displacement of each pixel's surface point per unit ``theta``
    (NaN off the model)."""
    H, W = smap.shape
    pts = smap.points.reshape(-1, 3)
    hit = np.all(np.isfinite(pts), axis=1)
    J = np.full((H * W, 2, 6), np.nan)
    J[hit] = _jacobian(smap.camera, pts[hit])
    return np.moveaxis(J, 2, 0).reshape(6, H, W, 2)


def ratio_sensitivity(weights, off_images, on_images, covariances) -> np.ndarray:
    """Shared sensitivity vectors of the ratio: (6 C, F) relative errors ``dR / R`` of the
    faces for one standard deviation of each camera's pose components (its covariance's
    Cholesky factor's columns).

    Parameters
    ----------
    weights : selfillum.uncertainty.faces.MergeWeights
    off_images, on_images : sequence of (H, W)
    covariances : sequence of (6, 6)
        Each camera's pose covariance.
    """
    rows = []
    C = len(weights.maps)
    for c, (m, off, on, S) in enumerate(zip(weights.maps, off_images, on_images,
                                            covariances, strict=True)):
        with np.errstate(invalid="ignore", divide="ignore"):
            lr = np.log(np.asarray(off, np.float64) / np.asarray(on, np.float64))
        gy, gx = np.gradient(lr)  # d/dv, d/du, pixels
        Jp = pixel_jacobian(m)  # (6, H, W, 2)
        s = Jp[..., 0] * gx[None] + Jp[..., 1] * gy[None]  # (6, H, W): d ln R / d theta
        L = np.linalg.cholesky(S + 1e-30 * np.eye(6))
        planes = np.einsum("khw,kj->jhw", np.nan_to_num(s), L)  # one std of each component
        per_cam = [np.zeros((6,) + mm.shape) for mm in weights.maps]
        per_cam[c] = planes
        rows.append(weights.mean(per_cam, relative=True))
    return np.concatenate(rows) if C else np.zeros((0, weights.camera.shape[1]))
