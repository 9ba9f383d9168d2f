"""Model deformation from markers: wind-on minus wind-off displacements.

Two set-ups are covered:

* **One camera**, its pose fixed from the wind-off frame. The image displacement of every
  marker (wind-on minus wind-off, pixels) is always available. One camera cannot see motion
  along its lines of sight, so a displacement in model units needs one known component: the
  marker is assumed to move in a plane through its wind-off position with a given normal
  (by default the camera's optical axis, i.e. the motion across the line of sight at the
  marker's depth; for a wing whose spanwise stations are known, the spanwise axis). Both the
  wind-off and the wind-on lines of sight are intersected with that plane, so that the
  wind-off resection residual cancels in the difference. Alternatively the lines of sight
  are intersected with the model surface (a mesh, Embree): the displacement along the
  surface.
* **Two or more calibrated cameras**: every marker is triangulated in 3-D (linear DLT on
  undistorted normalised coordinates, then a Levenberg-Marquardt refinement of the
  reprojection error in pixels, distortion included), vectorised across markers, and the
  3-D displacements are the differences of the triangulated positions.

Units: pixels for image quantities, model units (those of the cameras' ``t``) for 3-D ones.
Conventions as in docs/design.md (OpenCV camera frame, ``x_cam = R @ X + t``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from resection._checks import as_points
from resection.camera.model import Camera
from resection.errors import DegenerateError, InputError

__all__ = [
    "Triangulation",
    "triangulate",
    "ImageDisplacements",
    "pair_by_id",
    "stack_views",
    "marker_displacements",
    "Displacements3D",
    "displacements_3d",
]


# --------------------------------------------------------------------------- helpers
def _check_cameras(cameras: Sequence[Camera]) -> list[Camera]:
    cams = list(cameras)
    if len(cams) < 2:
        raise InputError(f"triangulation needs at least 2 cameras, got {len(cams)}")
    for i, c in enumerate(cams):
        if not isinstance(c, Camera):
            raise InputError(f"cameras[{i}]: expected a resection.Camera, got {type(c).__name__}")
    centres = np.array([c.center for c in cams])
    base = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=2)
    scale = max(np.abs(centres).max(), 1e-300)
    if base.max() <= 1e-12 * scale:
        raise DegenerateError("triangulation: all cameras share the same perspective centre")
    return cams


def _check_views(uv, n_cams: int) -> np.ndarray:
    try:
        arr = np.asarray(uv, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"uv: not a numeric array ({exc})") from None
    if arr.ndim == 2 and arr.shape[1] == 2 and n_cams == 1:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[0] != n_cams or arr.shape[2] != 2:
        raise InputError(
            f"uv: expected shape ({n_cams} cameras, N markers, 2), got {arr.shape}"
        )
    if np.any(np.isinf(arr)):
        raise InputError("uv: contains infinite values (use NaN for a marker not seen)")
    return arr


def _project_many(cams: list[Camera], X: np.ndarray) -> np.ndarray:
    """Project (N, 3) points into every camera -> (M, N, 2); NaN where not projectable."""
    out = np.full((len(cams), len(X), 2), np.nan)
    ok = np.all(np.isfinite(X), axis=1)
    if ok.any():
        for m, c in enumerate(cams):  # loop over cameras (2-4), vectorised over markers
            out[m, ok] = c.project(X[ok])
    return out


# --------------------------------------------------------------------------- triangulation
@dataclass(frozen=True)
class Triangulation:
    """Markers triangulated from several calibrated cameras.

    Attributes
    ----------
    points : (N, 3) ndarray
        Model coordinates; NaN for markers seen in fewer than 2 cameras.
    residuals : (M, N, 2) ndarray
        Reprojection residuals (projected minus measured), pixels, per camera; NaN where the
        marker was not measured.
    rms : (N,) ndarray
        Root-mean-square reprojection error of each marker over its views, pixels.
    n_views : (N,) ndarray of int
        Number of cameras that measured each marker.
    angle : (N,) ndarray
        Largest angle between the marker's lines of sight, degrees (small angles mean a
        poorly conditioned depth).
    linear : (N, 3) ndarray
        The linear (DLT) solution before refinement.
    """

    points: np.ndarray
    residuals: np.ndarray
    rms: np.ndarray
    n_views: np.ndarray
    angle: np.ndarray
    linear: np.ndarray


def _linear_triangulation(cams: list[Camera], xn: np.ndarray) -> np.ndarray:
    """Batched homogeneous DLT on undistorted normalised coordinates ``xn`` (M, N, 2).

    For each view the rows ``x P3 - P1`` and ``y P3 - P2`` of ``P = [R | t / s]`` are
    stacked (zero rows for missing views) and the right singular vector of the smallest
    singular value is the homogeneous point ``(X, s)``.
    """
    M, N, _ = xn.shape
    scale = max(float(np.mean([np.linalg.norm(c.t) for c in cams])), 1e-12)
    A = np.zeros((N, 2 * M, 4))
    for m, c in enumerate(cams):
        P = np.column_stack([c.R, c.t / scale])
        x, y = xn[m, :, 0:1], xn[m, :, 1:2]
        seen = np.isfinite(x) & np.isfinite(y)
        r1 = np.where(seen, x * P[2] - P[0], 0.0)
        r2 = np.where(seen, y * P[2] - P[1], 0.0)
        A[:, 2 * m] = r1
        A[:, 2 * m + 1] = r2
    # normalise rows so that each view weighs alike
    norms = np.linalg.norm(A, axis=2, keepdims=True)
    A = np.divide(A, norms, out=np.zeros_like(A), where=norms > 0)
    _, _, vt = np.linalg.svd(A)
    h = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        X = scale * h[:, :3] / h[:, 3:4]
    return X


def _refine(cams: list[Camera], uv: np.ndarray, X0: np.ndarray, *, iterations: int = 30,
            tol: float = 1e-12) -> np.ndarray:
    """Levenberg-Marquardt on the pixel reprojection error, independently per marker but
    vectorised across markers (3x3 normal equations solved in one batched call).

    The Jacobian is taken by central differences (6 batched projections per camera and
    iteration), which keeps the distortion model in one place (``Camera.project``).
    """
    X = X0.copy()
    N = len(X)
    seen = np.all(np.isfinite(uv), axis=2)  # (M, N)
    active = np.all(np.isfinite(X), axis=1)
    lam = np.full(N, 1e-3)

    def residual(P):
        r = _project_many(cams, P) - uv
        r[~seen] = 0.0
        return r  # (M, N, 2), NaN where the point cannot be projected

    def cost(r):
        c = np.einsum("mnk,mnk->n", r, r)
        return np.where(np.isfinite(c), c, np.inf)

    r = residual(X)
    c = cost(r)
    eye = np.eye(3)
    for _ in range(iterations):
        if not active.any():
            break
        scale = np.maximum(1.0, np.linalg.norm(np.where(np.isfinite(X), X, 0.0), axis=1))
        h = 1e-6 * scale
        J = np.empty((len(cams), N, 2, 3))
        for k in range(3):
            d = np.zeros((N, 3))
            d[:, k] = h
            J[..., k] = (residual(X + d) - residual(X - d)) / (2.0 * h)[None, :, None]
        J = np.where(np.isfinite(J), J, 0.0)
        rr = np.where(np.isfinite(r), r, 0.0)
        JtJ = np.einsum("mnki,mnkj->nij", J, J)
        Jtr = np.einsum("mnki,mnk->ni", J, rr)
        diag = np.einsum("nii->ni", JtJ)
        A = JtJ + lam[:, None, None] * (diag[:, :, None] * eye + 1e-12 * eye)
        good = active & np.all(np.isfinite(A), axis=(1, 2))
        step = np.zeros((N, 3))
        if good.any():
            try:
                step[good] = np.linalg.solve(A[good], -Jtr[good][..., None])[..., 0]
            except np.linalg.LinAlgError:  # singular for some marker: solve one by one
                for i in np.flatnonzero(good):
                    try:
                        step[i] = np.linalg.solve(A[i], -Jtr[i])
                    except np.linalg.LinAlgError:
                        good[i] = False
        Xn = np.where(good[:, None], X + step, X)
        rn = residual(Xn)
        cn = cost(rn)
        better = good & (cn <= c)
        X = np.where(better[:, None], Xn, X)
        r = np.where(better[None, :, None], rn, r)
        small = np.linalg.norm(step, axis=1) <= tol * scale
        c = np.where(better, cn, c)
        lam = np.where(better, lam * 0.3, lam * 10.0)
        active &= ~(better & small) & (lam < 1e12)
    return X


def triangulate(cameras: Sequence[Camera], uv, *, refine: bool = True) -> Triangulation:
    """Triangulate markers seen by two or more calibrated cameras.

    Parameters
    ----------
    cameras : sequence of M >= 2 :class:`~resection.Camera`
        Calibrated cameras (intrinsics, distortion and pose) in the same model frame.
    uv : (M, N, 2) array_like
        Measured (distorted) pixel coordinates of N markers in each camera; NaN rows for a
        marker a camera did not see.
    refine : bool
        Refine the linear solution by minimising the reprojection error in pixels (the
        maximum-likelihood estimate under isotropic Gaussian image noise).

    Returns
    -------
    Triangulation

    Raises
    ------
    InputError
        Fewer than 2 cameras, or ``uv`` of the wrong shape.
    DegenerateError
        All cameras at the same perspective centre.
    """
    cams = _check_cameras(cameras)
    uvm = _check_views(uv, len(cams))
    M, N, _ = uvm.shape
    xn = np.empty_like(uvm)
    for m, c in enumerate(cams):
        ideal = c.undistort(uvm[m])
        xn[m] = c.pixels_to_normalized(ideal)
    seen = np.all(np.isfinite(xn), axis=2)
    n_views = seen.sum(axis=0)
    X_lin = _linear_triangulation(cams, xn)
    X_lin[n_views < 2] = np.nan
    X = _refine(cams, uvm, X_lin) if refine else X_lin.copy()
    res = _project_many(cams, X) - uvm
    res[~seen] = np.nan
    with np.errstate(invalid="ignore"):
        sq = np.nansum(res**2, axis=(0, 2))
        rms = np.where(n_views > 0, np.sqrt(sq / np.maximum(n_views, 1)), np.nan)
    rms[~np.all(np.isfinite(X), axis=1)] = np.nan
    # largest angle between lines of sight
    dirs = np.full((M, N, 3), np.nan)
    for m, c in enumerate(cams):
        d_cam = np.column_stack([xn[m], np.ones(N)])
        d = d_cam @ c.R
        dirs[m] = d / np.linalg.norm(d, axis=1, keepdims=True)
    cosang = np.einsum("anx,bnx->nab", dirs, dirs).reshape(N, -1)
    finite = np.isfinite(cosang)
    smallest = np.min(np.where(finite, cosang, np.inf), axis=1)  # no all-NaN warning
    smallest[~finite.any(axis=1)] = np.nan
    with np.errstate(invalid="ignore"):
        ang = np.degrees(np.arccos(np.clip(smallest, -1, 1)))
    ang[n_views < 2] = np.nan
    return Triangulation(points=X, residuals=res, rms=rms, n_views=n_views, angle=ang,
                         linear=X_lin)


# --------------------------------------------------------------------------- one camera
def pair_by_id(ids_a, values_a, ids_b, values_b) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair two tables by marker id.

    Parameters
    ----------
    ids_a, ids_b : (Na,), (Nb,) array_like of str
        Marker ids (converted to str); duplicates are an error.
    values_a, values_b : (Na, k), (Nb, k) array_like
        Values per marker.

    Returns
    -------
    ids : (N,) ndarray of str
        The ids present in both tables, in the order of ``ids_a``.
    a, b : (N, k) ndarrays
        The paired rows.
    """
    ia = np.asarray(ids_a).astype(str).ravel()
    ib = np.asarray(ids_b).astype(str).ravel()
    va = np.asarray(values_a, dtype=np.float64)
    vb = np.asarray(values_b, dtype=np.float64)
    if len(va) != len(ia) or len(vb) != len(ib):
        raise InputError(
            f"pair_by_id: {len(ia)} ids for {len(va)} rows, {len(ib)} ids for {len(vb)} rows"
        )
    for name, ids in (("first", ia), ("second", ib)):
        u, cnt = np.unique(ids, return_counts=True)
        if np.any(cnt > 1):
            dup = str(u[cnt > 1][0])
            raise InputError(f"pair_by_id: duplicate marker id {dup!r} in {name} table")
    common, pa, pb = np.intersect1d(ia, ib, assume_unique=True, return_indices=True)
    order = np.argsort(pa)
    return common[order], va[pa[order]], vb[pb[order]]


def stack_views(ids_per_camera, uv_per_camera, ids=None) -> tuple[np.ndarray, np.ndarray]:
    """Gather per-camera marker tables into the ``(M, N, 2)`` array :func:`triangulate`
    takes.

    Parameters
    ----------
    ids_per_camera : sequence of M (n_m,) array_like of str
        Marker ids measured by each camera (e.g. one frame of each camera's ``markers.csv``
        from ``resection track``).
    uv_per_camera : sequence of M (n_m, 2) array_like
        Their pixel positions.
    ids : (N,) array_like of str, optional
        Markers wanted, in this order. Default: those seen by at least two cameras, sorted.

    Returns
    -------
    ids : (N,) ndarray of str
    uv : (M, N, 2) ndarray
        NaN where a camera did not measure a marker.
    """
    if len(ids_per_camera) != len(uv_per_camera):
        raise InputError(f"stack_views: {len(ids_per_camera)} id lists for "
                         f"{len(uv_per_camera)} position arrays")
    tables = []
    for m, (i, uv) in enumerate(zip(ids_per_camera, uv_per_camera, strict=True)):
        i = np.asarray(i).astype(str).ravel()
        uv = as_points(uv, 2, f"uv of camera {m}", allow_nan=True)
        if len(i) != len(uv):
            raise InputError(f"stack_views: camera {m} has {len(i)} ids for {len(uv)} positions")
        u, c = np.unique(i, return_counts=True)
        if np.any(c > 1):
            raise InputError(f"stack_views: duplicate marker id {str(u[c > 1][0])!r} in camera {m}")
        tables.append(dict(zip(i.tolist(), uv, strict=True)))
    if ids is None:
        count: dict[str, int] = {}
        for t in tables:
            for k in t:
                count[k] = count.get(k, 0) + 1
        out_ids = np.array(sorted(k for k, c in count.items() if c >= 2), dtype=str)
    else:
        out_ids = np.asarray(ids).astype(str).ravel()
    out = np.full((len(tables), len(out_ids), 2), np.nan)
    for m, t in enumerate(tables):
        for j, k in enumerate(out_ids):  # loop over marker ids (tens), not pixels
            if k in t:
                out[m, j] = t[k]
    return out_ids, out


@dataclass(frozen=True)
class ImageDisplacements:
    """Marker displacements seen by one camera whose pose is fixed from wind-off.

    Attributes
    ----------
    ids : (N,) ndarray of str
    uv_ref, uv : (N, 2) ndarray
        Wind-off and wind-on image positions, pixels.
    duv : (N, 2) ndarray
        ``uv - uv_ref``, pixels.
    X_ref : (N, 3) ndarray
        Wind-off positions: the wind-off line of sight intersected with the constraint
        plane, model units.
    dX : (N, 3) ndarray
        Displacements within the constraint plane, model units; NaN where the line of
        sight is (nearly) parallel to the plane.
    normal : (N, 3) ndarray
        Unit normal of each marker's constraint plane.
    """

    ids: np.ndarray
    uv_ref: np.ndarray
    uv: np.ndarray
    duv: np.ndarray
    X_ref: np.ndarray
    dX: np.ndarray
    normal: np.ndarray


def _ray_plane(camera: Camera, uv: np.ndarray, P0: np.ndarray, n: np.ndarray,
               min_cos: float) -> np.ndarray:
    o, d = camera.rays(uv)
    denom = np.einsum("ij,ij->i", d, n)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.einsum("ij,ij->i", P0 - o, n) / denom
    X = o + s[:, None] * d
    X[~(np.abs(denom) >= min_cos) | ~(s > 0)] = np.nan
    return X


def _ray_surface(camera: Camera, uv: np.ndarray, surface) -> np.ndarray:
    from resection.surface.visibility import RayCaster

    caster = surface if isinstance(surface, RayCaster) else RayCaster(surface)
    o, d = camera.rays(uv)
    face, dist, _ = caster.first_hit(camera.center, d)
    X = camera.center + dist[:, None] * d
    X[face < 0] = np.nan
    return X


def marker_displacements(
    camera: Camera,
    ids3d,
    points3d,
    ids_ref,
    uv_ref,
    ids,
    uv,
    *,
    normal=None,
    surface=None,
    min_cos: float = 0.1,
) -> ImageDisplacements:
    """Marker displacements wind-on minus wind-off with one camera fixed from wind-off.

    Parameters
    ----------
    camera : Camera
        The camera with its pose solved on the wind-off frame.
    ids3d, points3d : (K,), (K, 3) array_like
        The markers' ids and nominal model coordinates (they place the constraint planes).
    ids_ref, uv_ref : (Na,), (Na, 2) array_like
        Marker ids and measured pixel positions in the wind-off frame.
    ids, uv : (Nb,), (Nb, 2) array_like
        The same in the wind-on frame. Markers present in all three tables are reported.
    normal : (3,) or (K, 3) array_like, optional
        Normal (model frame) of the plane through each marker within which it is assumed to
        move. Default: the camera's optical axis (motion across the line of sight, at the
        marker's depth).
    surface : trimesh.Trimesh or resection.surface.visibility.RayCaster, optional
        Instead of planes: the model surface (wind-off shape). The wind-off and wind-on
        lines of sight are intersected with it (first hit, Embree), so ``dX`` is the
        displacement *along the surface* that the image motion implies: exact for markers
        that slide within the surface, and what an image <-> surface mapping of the wind-on
        frame would use. ``X_ref`` and the wind-on point are NaN for rays that miss.
    min_cos : float
        Lines of sight more oblique to the plane than this cosine give NaN (plane mode).

    Returns
    -------
    ImageDisplacements
    """
    if not isinstance(camera, Camera):
        raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
    P = as_points(points3d, 3, "points3d")
    ids3 = np.asarray(ids3d).astype(str).ravel()
    if len(ids3) != len(P):
        raise InputError(f"marker_displacements: {len(ids3)} ids for {len(P)} 3-D markers")
    if not (0.0 <= float(min_cos) < 1.0):
        raise InputError(f"min_cos: must be in [0, 1), got {min_cos}")
    if normal is not None and surface is not None:
        raise InputError("marker_displacements: give a plane normal or a surface, not both")
    if normal is None:
        nrm = np.broadcast_to(camera.R[2], P.shape).copy()
    else:
        nrm = np.asarray(normal, dtype=np.float64)
        if nrm.shape == (3,):
            nrm = np.broadcast_to(nrm, P.shape).copy()
        nrm = as_points(nrm, 3, "normal")
        if len(nrm) != len(P):
            raise InputError(f"normal: expected (3,) or ({len(P)}, 3), got {nrm.shape}")
    lens = np.linalg.norm(nrm, axis=1)
    if np.any(lens <= 0):
        raise InputError("normal: zero-length normal")
    nrm = nrm / lens[:, None]
    uv_a = as_points(uv_ref, 2, "uv_ref", allow_nan=True)
    uv_b = as_points(uv, 2, "uv", allow_nan=True)
    ids_ab, a, b = pair_by_id(ids_ref, uv_a, ids, uv_b)
    ids_c, ab, pn = pair_by_id(ids_ab, np.hstack([a, b]), ids3, np.hstack([P, nrm]))
    if len(ids_c) == 0:
        raise InputError("marker_displacements: no marker id common to the 3-D, wind-off and "
                         "wind-on tables")
    a, b = ab[:, :2], ab[:, 2:]
    P0, n = pn[:, :3], pn[:, 3:]
    if surface is None:
        X_ref = _ray_plane(camera, a, P0, n, min_cos)
        X_def = _ray_plane(camera, b, P0, n, min_cos)
    else:
        X_ref = _ray_surface(camera, a, surface)
        X_def = _ray_surface(camera, b, surface)
    return ImageDisplacements(ids=ids_c, uv_ref=a, uv=b, duv=b - a, X_ref=X_ref,
                              dX=X_def - X_ref, normal=n)


# --------------------------------------------------------------------------- two cameras
@dataclass(frozen=True)
class Displacements3D:
    """3-D marker displacements from two or more cameras.

    Attributes
    ----------
    ref, deformed : Triangulation
        Wind-off and wind-on triangulations.
    displacement : (N, 3) ndarray
        ``deformed.points - ref.points``, model units.
    """

    ref: Triangulation
    deformed: Triangulation
    displacement: np.ndarray


def displacements_3d(cameras: Sequence[Camera], uv_ref, uv) -> Displacements3D:
    """Triangulate markers wind-off and wind-on and return their 3-D displacements.

    Parameters
    ----------
    cameras : sequence of M >= 2 Camera
    uv_ref, uv : (M, N, 2) array_like
        Wind-off and wind-on pixel positions of the same N markers (same order) in every
        camera; NaN for a marker not seen.
    """
    a = triangulate(cameras, uv_ref)
    b = triangulate(cameras, uv)
    if a.points.shape != b.points.shape:
        raise InputError(
            f"displacements_3d: {len(a.points)} wind-off markers vs {len(b.points)} wind-on"
        )
    return Displacements3D(ref=a, deformed=b, displacement=b.points - a.points)
