"""Direct Linear Transformation: the 11 collinearity parameters, and the planar homography.

The DLT writes the pinhole projection of a model point ``X = (X, Y, Z)`` as

``u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)``
``v = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)``

i.e. a 3x4 projection matrix ``P = K [R | t]`` up to scale. It is linear in the 11
parameters, so six or more *non-coplanar* markers give it by linear least squares
(with Hartley's normalisation of both point sets for conditioning). ``P`` decomposes into
``K`` (with a possible skew), ``R`` and ``t`` by an RQ factorisation.

Markers on a plane (a PIV/DGV calibration card) do not determine ``P``; a homography
``H`` (plane coordinates -> pixels) does, from four or more markers, and :func:`dewarp`
resamples an image onto the plane's coordinates with it.

Pixel conventions are those of docs/design.md: the centre of the top-left pixel is ``(0, 0)``,
``u`` to the right, ``v`` down; images are indexed ``img[v, u]``. The DLT and the
homography are pinhole models: for a lens with distortion, fit them to undistorted
pixel coordinates (:meth:`Camera.undistort`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy import ndimage

from resection._checks import as_matrix, as_points
from resection.errors import DegenerateError, InputError, SolveError

__all__ = [
    "fit_dlt",
    "dlt_project",
    "dlt_coefficients",
    "decompose_projection",
    "camera_from_dlt",
    "fit_homography",
    "apply_homography",
    "dewarp",
    "coplanarity",
]

#: Relative thickness (smallest / largest singular value of the centred marker cloud)
#: below which markers are treated as coplanar.
COPLANAR_RTOL = 1e-3
#: Same ratio for the second singular value: below it the markers are collinear.
COLLINEAR_RTOL = 1e-6


def coplanarity(points3d) -> tuple[float, float]:
    """Flatness of a point cloud: ``(s2 / s1, s3 / s1)``, ratios of the singular values
    of the centred coordinates. ``s3 / s1`` near 0 means coplanar, ``s2 / s1`` near 0
    collinear."""
    X = as_points(points3d, 3, "points3d")
    if len(X) < 2:
        return 0.0, 0.0
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if s[0] == 0:
        return 0.0, 0.0
    s = np.concatenate([s, np.zeros(3 - s.size)])
    return float(s[1] / s[0]), float(s[2] / s[0])


def _normalizer(pts: np.ndarray) -> np.ndarray:
    """Hartley's similarity: centroid to the origin, mean distance ``sqrt(dim)``."""
    dim = pts.shape[1]
    c = pts.mean(axis=0)
    d = np.linalg.norm(pts - c, axis=1).mean()
    if d == 0:
        raise DegenerateError("all points coincide")
    s = np.sqrt(dim) / d
    T = np.eye(dim + 1)
    T[:dim, :dim] *= s
    T[:dim, dim] = -s * c
    return T


def _pairs(points3d, points2d, dim3: int, name3: str, minimum: int):
    X = as_points(points3d, dim3, name3)
    uv = as_points(points2d, 2, "points2d")
    if len(X) != len(uv):
        raise InputError(f"{name3} and points2d differ in length: {len(X)} != {len(uv)}")
    if len(X) < minimum:
        raise InputError(f"at least {minimum} point pairs are needed, got {len(X)}")
    return X, uv


def fit_dlt(points3d, points2d) -> np.ndarray:
    """The 3x4 projection matrix from six or more non-coplanar markers (linear DLT).

    Parameters
    ----------
    points3d : (N, 3) array_like
        Marker coordinates, model units, N >= 6, not coplanar.
    points2d : (N, 2) array_like
        Their (undistorted) pixel coordinates.

    Returns
    -------
    P : (3, 4) ndarray
        Projection matrix ``~ K [R | t]``, scaled so that ``||P[2, :3]|| = 1`` and the
        depths ``P[2] @ [X, 1]`` of the markers are positive (then ``P[2] @ [X, 1]`` is
        the depth along the optical axis in model units).

    Raises
    ------
    InputError
        Fewer than 6 markers, NaN, mismatched lengths.
    DegenerateError
        Coplanar or collinear markers (use :func:`fit_homography` for a plane).
    """
    X, uv = _pairs(points3d, points2d, 3, "points3d", 6)
    s2, s3 = coplanarity(X)
    if s2 < COLLINEAR_RTOL:
        raise DegenerateError("DLT: the markers are collinear")
    if s3 < COPLANAR_RTOL:
        raise DegenerateError(
            f"DLT: the markers are coplanar (thickness ratio {s3:.2e}); the 11-parameter DLT "
            "needs non-coplanar markers: use fit_homography for a plane"
        )
    T3 = _normalizer(X)
    T2 = _normalizer(uv)
    Xn = X @ T3[:3, :3].T + T3[:3, 3]
    un = uv @ T2[:2, :2].T + T2[:2, 2]
    n = len(X)
    Xh = np.column_stack([Xn, np.ones(n)])
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xh
    A[0::2, 8:12] = -un[:, :1] * Xh
    A[1::2, 4:8] = Xh
    A[1::2, 8:12] = -un[:, 1:] * Xh
    _, s, vt = np.linalg.svd(A, full_matrices=False)
    if s[-2] < 1e-12 * s[0]:
        raise DegenerateError("DLT: the linear system is singular (degenerate marker layout)")
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.solve(T2, Pn @ T3)
    P /= np.linalg.norm(P[2, :3])
    depth = np.column_stack([X, np.ones(n)]) @ P[2]
    if np.median(depth) < 0:
        P = -P
    return P


def dlt_coefficients(P) -> np.ndarray:
    """The 11 DLT parameters ``L1..L11`` of a projection matrix (``P`` scaled so that
    ``P[2, 3] = 1``; requires the model origin off the camera's principal plane)."""
    P = as_matrix(P, (3, 4), "P")
    if abs(P[2, 3]) < 1e-12 * np.abs(P).max():
        raise InputError("dlt_coefficients: the model origin lies in the camera's principal "
                         "plane (P[2,3] = 0); the 11-parameter form is undefined")
    return (P / P[2, 3]).ravel()[:11]


def dlt_project(P, points3d) -> np.ndarray:
    """Project model points with a 3x4 matrix (or the 11 DLT coefficients).

    Returns (N, 2) pixel coordinates; points on the principal plane come back as NaN.
    """
    P = np.asarray(P, dtype=np.float64)
    if P.shape == (11,):
        P = np.append(P, 1.0).reshape(3, 4)
    P = as_matrix(P, (3, 4), "P")
    X = as_points(points3d, 3, "points3d")
    x = X @ P[:, :3].T + P[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = x[:, :2] / x[:, 2:3]
    uv[~np.isfinite(uv).all(axis=1)] = np.nan
    return uv


def decompose_projection(P) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split ``P ~ K [R | t]`` into intrinsics, rotation and translation (RQ factorisation).

    Returns
    -------
    K : (3, 3) ndarray
        Upper triangular, positive diagonal, ``K[2, 2] = 1`` (``K[0, 1]`` is the skew).
    R : (3, 3) ndarray
        Proper rotation (model -> camera).
    t : (3,) ndarray
        Translation, so that ``x_cam = R X + t``.
    """
    P = as_matrix(P, (3, 4), "P")
    M = P[:, :3]
    det = np.linalg.det(M)
    if abs(det) < 1e-300 or np.linalg.cond(M) > 1e12:
        raise DegenerateError("decompose_projection: the left 3x3 block of P is singular")
    if det < 0:
        P = -P
        M = P[:, :3]
    K, R = scipy.linalg.rq(M)
    D = np.diag(np.sign(np.diag(K)))
    K = K @ D
    R = D @ R
    lam = K[2, 2]
    t = np.linalg.solve(K, P[:, 3])
    K = K / lam
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    K[2, 2] = 1.0
    # make R exactly orthonormal (it is up to rounding)
    u, _, vt = np.linalg.svd(R)
    R = u @ vt
    return K, R, t


def camera_from_dlt(points3d, points2d, width: int, height: int, **kwargs):
    """A :class:`~resection.Camera` (intrinsics and pose, no distortion) from one image of
    six or more non-coplanar markers, through the DLT and its decomposition.

    ``kwargs`` go to the Camera (``name``, ``oof``). The skew found by the DLT is kept in
    ``K[0, 1]``.

    Raises
    ------
    SolveError
        When the decomposition puts the markers behind the camera.
    """
    from resection.camera.model import Camera

    P = fit_dlt(points3d, points2d)
    K, R, t = decompose_projection(P)
    X = as_points(points3d, 3, "points3d")
    z = (X @ R.T + t)[:, 2]
    if np.any(z <= 0):
        raise SolveError("DLT: the decomposed camera sees markers behind it (inconsistent "
                         "marker/point pairs?)")
    return Camera(width, height, K, np.zeros(5), R, t, **kwargs)


# --------------------------------------------------------------------------- homography
def fit_homography(plane_points, points2d) -> np.ndarray:
    """Homography ``H`` mapping plane coordinates ``(x, y)`` to pixels, from >= 4 markers.

    Linear least squares with Hartley normalisation (the DLT of a plane).

    Parameters
    ----------
    plane_points : (N, 2) array_like
        Marker coordinates in the plane, model units.
    points2d : (N, 2) array_like
        Their pixel coordinates (undistorted for a lens with distortion).

    Returns
    -------
    H : (3, 3) ndarray with ``H[2, 2] = 1`` (or unit norm when that entry is 0), so that
        ``[u, v, 1] ~ H @ [x, y, 1]``.

    Raises
    ------
    InputError, DegenerateError
        Fewer than 4 pairs, NaN, or three-quarters of the layout collinear.
    """
    xy, uv = _pairs(plane_points, points2d, 2, "plane_points", 4)
    for name, pts in (("plane_points", xy), ("points2d", uv)):
        c = pts - pts.mean(axis=0)
        s = np.linalg.svd(c, compute_uv=False)
        if s[0] == 0 or s[1] < COLLINEAR_RTOL * s[0]:
            raise DegenerateError(f"fit_homography: the {name} are collinear")
    Ta = _normalizer(xy)
    Tb = _normalizer(uv)
    a = xy @ Ta[:2, :2].T + Ta[:2, 2]
    b = uv @ Tb[:2, :2].T + Tb[:2, 2]
    n = len(a)
    ah = np.column_stack([a, np.ones(n)])
    A = np.zeros((2 * n, 9))
    A[0::2, 0:3] = ah
    A[0::2, 6:9] = -b[:, :1] * ah
    A[1::2, 3:6] = ah
    A[1::2, 6:9] = -b[:, 1:] * ah
    _, s, vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])
    if s[-2] < 1e-10 * s[0]:
        raise DegenerateError("fit_homography: singular system (three or more of four "
                              "points collinear?)")
    H = np.linalg.solve(Tb, vt[-1].reshape(3, 3) @ Ta)
    if abs(H[2, 2]) > 1e-12 * np.abs(H).max():
        H /= H[2, 2]
    else:
        H /= np.linalg.norm(H)
    return H


def apply_homography(H, points) -> np.ndarray:
    """Map (N, 2) points through a 3x3 homography (NaN where the mapping is at infinity)."""
    H = as_matrix(H, (3, 3), "H")
    p = as_points(points, 2, "points", allow_nan=True)
    q = p @ H[:, :2].T + H[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = q[:, :2] / q[:, 2:3]
    out[~np.isfinite(out).all(axis=1)] = np.nan
    return out


def dewarp(
    image,
    H,
    extent: tuple[float, float, float, float],
    resolution: float,
    *,
    camera=None,
    order: int = 1,
    cval: float = np.nan,
) -> np.ndarray:
    """Resample an image onto a regular grid of the plane's coordinates.

    Parameters
    ----------
    image : (H, W) array_like
        The camera image, indexed ``img[v, u]``.
    H : (3, 3) array_like
        Homography plane ``(x, y)`` -> pixel ``(u, v)`` (:func:`fit_homography`). When
        ``camera`` is given, ``H`` maps to *undistorted* pixels and the camera's distortion
        is applied before sampling.
    extent : (xmin, xmax, ymin, ymax)
        Plane region to resample, model units. Output pixel ``[i, j]`` is the plane point
        ``(xmin + j * resolution, ymin + i * resolution)``: rows follow ``y`` increasing,
        columns ``x`` increasing.
    resolution : float
        Plane distance between output pixels, model units.
    camera : Camera, optional
        Lens distortion to apply (only ``K`` and ``dist`` are used).
    order : int
        Spline order of the interpolation (0 nearest, 1 bilinear, 3 cubic).
    cval : float
        Value outside the image.

    Returns
    -------
    (ny, nx) float ndarray (float32 for float32 or integer input, float64 for float64).
    """
    img = np.asarray(image)
    if img.ndim != 2:
        raise InputError(f"dewarp: expected a 2-D image, got shape {img.shape}")
    if not np.issubdtype(img.dtype, np.number):
        raise InputError(f"dewarp: image is not numeric ({img.dtype})")
    H = as_matrix(H, (3, 3), "H")
    ext = as_matrix(np.asarray(extent, dtype=float).ravel(), (4,), "extent")
    res = float(resolution)
    if not np.isfinite(res) or res <= 0:
        raise InputError(f"dewarp: resolution must be positive, got {resolution}")
    xmin, xmax, ymin, ymax = ext
    if xmax <= xmin or ymax <= ymin:
        raise InputError(f"dewarp: empty extent {tuple(ext)}")
    nx = int(np.floor((xmax - xmin) / res + 1e-9)) + 1
    ny = int(np.floor((ymax - ymin) / res + 1e-9)) + 1
    if nx * ny > 400_000_000:
        raise InputError(f"dewarp: output of {ny}x{nx} pixels is too large")
    xs = xmin + res * np.arange(nx)
    ys = ymin + res * np.arange(ny)
    gx, gy = np.meshgrid(xs, ys)
    uv = apply_homography(H, np.column_stack([gx.ravel(), gy.ravel()]))
    if camera is not None:
        uv = camera.distort(uv)
    out_dtype = np.float64 if img.dtype == np.float64 else np.float32
    h, w = img.shape
    with np.errstate(invalid="ignore"):
        inside = ((uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
                  & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5))
    uv[~inside] = 0.0
    vals = ndimage.map_coordinates(
        img.astype(out_dtype, copy=False), [uv[:, 1], uv[:, 0]], order=order,
        mode="nearest", prefilter=order > 1,
    )
    vals[~inside] = cval
    return vals.reshape(ny, nx).astype(out_dtype, copy=False)
