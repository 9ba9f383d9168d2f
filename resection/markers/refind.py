"""Every target that should be seen is found, or the reason is given.

After a first pose (from the matcher), :func:`refind_targets` predicts every target of the
marker file with it and sorts them:

* **off the image**: behind the camera or its centre outside the sensor;
* **facing away**: its surface normal (``nx, ny, nz`` of the marker file) points away from
  the camera;
* **occluded**: with a mesh, the line of sight from the camera meets the model before
  the target (Embree ray cast);
* otherwise it *should be seen*, and unless the first pose used it, it is **looked for
  again**: a window at its predicted position, enhanced locally
  (:mod:`resection.markers.enhancement`) and searched with the same detector and sub-pixel disk fit
  (:func:`resection.markers.detect.detect_markers`). A target cut by the image border is fitted
  with its visible part (the pixels beyond the border are masked, not reflected);
* a candidate is taken only when it lies within the acceptance rule's outlier gate of the
  prediction (:func:`resection.pose.acceptance.outlier_gate`); none in the window: **not
  detected** (or **cut by the image border** when the disk crosses it); one farther:
  **rejected as outlier**;
* the pose is solved again from every target used, under the acceptance rule
  (:func:`resection.pose.solve.solve_pose`): the targets it drops are **rejected as outlier**
  too.

Pressure taps (``MarkerSet.taps``) are never looked for: they are distractors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.pose.acceptance import (
    DEFAULT_MARKER_ACCURACY,
    DEFAULT_MAX_RMS,
    check_accuracy,
    outlier_gate,
)
from resection.pose.solve import PoseResult, solve_pose

__all__ = ["RefindResult", "REASONS", "refind_targets", "occluded_targets"]

#: Why a target of the marker file is not used, in the order they are decided.
REASONS = ("off the image", "facing away", "occluded", "cut by the image border",
           "not detected", "rejected as outlier")


@dataclass(frozen=True)
class RefindResult:
    """Result of :func:`refind_targets`.

    Attributes
    ----------
    pose : PoseResult
        The pose solved from the targets ``ids`` under the acceptance rule (``pose.used``
        False: dropped as gross outliers).
    ids : tuple of str
        Targets given to the final solve, in the order of ``points3d`` / ``points2d``.
    points3d : (M, 3) ndarray
        Their model coordinates.
    points2d : (M, 2) ndarray
        Their measured pixel positions.
    refound : tuple of str
        Targets the first pose did not use, found again in their window and used.
    not_used : dict {id: reason}
        Every target of the marker file (taps excluded) not used, with why (one of
        :data:`REASONS`, with details after a colon).
    n_expected : int
        Targets predicted inside the image, facing the camera and not hidden.
    gate : float
        Largest distance from the prediction at which a candidate was accepted, px.
    """

    pose: PoseResult
    ids: tuple
    points3d: np.ndarray
    points2d: np.ndarray
    refound: tuple
    not_used: dict = field(default_factory=dict)
    n_expected: int = 0
    gate: float = math.nan

    def report(self) -> list[str]:
        """Lines for people: the count, then each target not used and why."""
        used = int(np.sum(self.pose.used))
        out = [f"targets: {used} used ({len(self.refound)} found again) of "
               f"{self.n_expected} expected in view; {len(self.not_used)} not used"]
        out += [f"  {k}: {why}" for k, why in self.not_used.items()]
        return out


def occluded_targets(mesh, camera: Camera, X: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Targets whose line of sight meets ``mesh`` before them (by more than their size)."""
    from resection.surface.visibility import RayCaster

    C = camera.center
    d = X - C
    dist = np.linalg.norm(d, axis=1)
    _, hit, _ = RayCaster(mesh).first_hit(C, d)
    tol = np.maximum(sizes, 1e-3 * dist)
    with np.errstate(invalid="ignore"):
        return np.isfinite(hit) & (hit < dist - tol)


def _windows_detect(image, uv, half, diameter, polarity, enhance, detect_options):
    """Candidates in square windows of half-size ``half`` around ``uv`` (one detection per
    window, all windows in one pass); the image padded with masked pixels so that a disk
    cut by the image border is fitted with its visible part. Returns the candidates' uv
    (image coordinates) and the window each came from (-1: from none)."""
    from resection.markers.in_image import detect_in_image

    H, W = image.shape
    pad = int(half) + 2
    padded = np.pad(np.asarray(image, float), pad, constant_values=np.nan)
    c = np.rint(uv).astype(int) + pad
    boxes = np.column_stack([c[:, 0] - half, c[:, 1] - half, c[:, 0] + half,
                             c[:, 1] + half])
    opts = {"max_masked": 0.6, **(detect_options or {})}
    if enhance is not None:
        cand = detect_in_image(padded, diameter, polarity, enhance=enhance,
                               enhance_windows=boxes, **opts)
    else:  # the raw pixels, each window searched as a roi (as detect_in_image does)
        from resection.markers.detect import detect_markers
        from resection.markers.in_image import merge_candidates, window_mask

        outside = ~window_mask(padded.shape, boxes)
        parts = [detect_markers(padded, diameter, polarity, roi=tuple(b), mask=outside,
                                **opts) for b in boxes.tolist()]  # a few tens of windows
        cand = merge_candidates(parts, diameter, opts.get("min_separation"))
    q = cand.uv - pad
    inside = ((q[:, 0] >= -0.5) & (q[:, 0] <= W - 0.5) & (q[:, 1] >= -0.5)
              & (q[:, 1] <= H - 0.5))
    return q[inside]


def refind_targets(
    image,
    markers,
    camera: Camera,
    used_ids=(),
    used_uv=None,
    *,
    diameter: float | None = None,
    polarity: str = "dark",
    mesh=None,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    max_rms: float | None = DEFAULT_MAX_RMS,
    enhance: str | None = "normalize",
    window: float | None = None,
    detect_options: dict | None = None,
    pose_kw: dict | None = None,
) -> RefindResult:
    """Look again for every target that the first pose says should be seen.

    Parameters
    ----------
    image : (H, W) array
        The camera image (the camera's size; NaN pixels are masked).
    markers : MarkerSet
        The marker file (normals used when given; taps ignored).
    camera : Camera
        The first pose (e.g. from :func:`resection.markers.match.match_markers`).
    used_ids, used_uv : sequence of str, (M, 2) array
        Targets the first pose used and their pixel positions (kept as measured).
    diameter : float, optional
        Marker diameter, px (default: from the marker file's diameters and the camera).
    polarity : {"dark", "bright"}
    mesh : trimesh.Trimesh, optional
        Model surface: targets hidden by it are reported as occluded, not looked for.
    marker_accuracy, max_rms : float
        The acceptance rule's options, px (:mod:`resection.pose.acceptance`): the gate around
        each prediction and the final pose's test.
    enhance : {"normalize", "background", "clahe"} or None
        Local enhancement of each window before detection (default ``"normalize"``:
        local contrast normalisation, which lifts a target on a dark unpainted part).
    window : float, optional
        Half-size of the searched windows, px (default ``max(3 d, gate + 2 d)``).
    detect_options : dict, optional
        Further keyword arguments of :func:`resection.markers.detect.detect_markers`.
    pose_kw : dict, optional
        Further keyword arguments of :func:`resection.pose.solve.solve_pose` for the final pose.

    Returns
    -------
    RefindResult

    Raises
    ------
    InputError
        Bad image, markers or options.
    SolveError
        The final pose fails the acceptance rule.
    """
    from resection.markers.in_image import expected_diameter

    a = check_accuracy(marker_accuracy, "refind_targets")
    if not isinstance(camera, Camera):
        raise InputError("refind_targets: camera must be a resection.Camera")
    img = np.asarray(image, float)
    if img.shape != (camera.height, camera.width):
        raise InputError(f"refind_targets: image is {img.shape[1]}x{img.shape[0]} px, the "
                         f"camera {camera.width}x{camera.height}")
    tg = markers.targets if hasattr(markers, "targets") else markers
    ids = [str(k) for k in tg.ids]
    X = np.asarray(tg.xyz, float)
    n = len(ids)
    used_ids = [str(k) for k in used_ids]
    pos = {k: i for i, k in enumerate(ids)}
    unknown = [k for k in used_ids if k not in pos]
    if unknown:
        raise InputError(f"refind_targets: used id(s) {unknown[:5]} not in the marker file")
    used_uv = np.zeros((0, 2)) if used_uv is None else np.asarray(used_uv, float).reshape(-1, 2)
    if len(used_uv) != len(used_ids):
        raise InputError(f"refind_targets: {len(used_ids)} used ids but {len(used_uv)} "
                         "positions")
    d = float(diameter) if diameter is not None else expected_diameter(camera, tg)
    if not (math.isfinite(d) and d > 0):
        raise InputError(f"refind_targets: diameter must be positive, got {diameter}")

    # ---- sort the targets by what the first pose predicts
    uv, valid = camera.project(X, return_valid=True)
    reason = np.full(n, "", dtype=object)
    inside = valid & camera.in_image(np.where(valid[:, None], uv, 0.0))
    reason[~inside] = "off the image"
    facing = tg.facing(camera.center) if hasattr(tg, "facing") else np.ones(n, bool)
    reason[(reason == "") & ~facing] = "facing away"
    if mesh is not None:
        z = np.maximum(camera.to_camera_frame(X)[:, 2], 1e-12)
        size = d * z / camera.K[0, 0]  # model units a marker spans
        hidden = occluded_targets(mesh, camera, X, size)
        reason[(reason == "") & hidden] = "occluded"
    expected = reason == ""
    n_exp = int(expected.sum())
    gate = outlier_gate(max(n_exp, 1), a)
    half = int(math.ceil(window if window is not None else max(3.0 * d, gate + 2.0 * d)))

    # ---- look again for the expected targets the first pose did not use
    found = np.full((n, 2), np.nan)
    found[[pos[k] for k in used_ids]] = used_uv
    look = np.flatnonzero(expected & ~np.isfinite(found[:, 0]))
    refound = []
    if look.size:
        q = _windows_detect(img, uv[look], half, d, polarity, enhance, detect_options)
        if len(q):
            from scipy.spatial import cKDTree

            from resection.markers.match import assign_nearest

            j, dist = assign_nearest(uv[look], cKDTree(q), np.inf)
            ok = (j >= 0) & (np.abs(q[np.maximum(j, 0)] - uv[look]).max(axis=1) <= half)
            take = ok & (dist <= gate)
            found[look[take]] = q[j[take]]
            refound = [ids[i] for i in look[take]]
            far = ok & ~take
            reason[look[far]] = [f"rejected as outlier: found {dd:.2g} px from its "
                                 f"prediction (gate {gate:.2g} px)" for dd in dist[far]]
        # the ones left: nothing in the window (a disk cut by the border may be too little)
        cut = ~camera.in_image(uv, margin=d / 2.0 + 0.5)
        left = look[(reason[look] == "") & ~np.isfinite(found[look, 0])]
        reason[left] = np.where(cut[left], "cut by the image border", "not detected")
    reason[np.isfinite(found[:, 0])] = ""  # measured by the first pose: kept

    # ---- the pose from every target used, under the acceptance rule
    sel = np.flatnonzero(np.isfinite(found[:, 0]))
    sel_ids = [ids[i] for i in sel]
    pose = solve_pose(camera, X[sel], found[sel], ids=sel_ids, marker_accuracy=a,
                      max_rms=max_rms, **(pose_kw or {}))
    for k in np.flatnonzero(~pose.used):
        reason[sel[k]] = f"rejected as outlier: {pose.errors[k]:.2g} px from the pose"
    kept = {ids[i] for i in sel[pose.used]}
    not_used = {ids[i]: str(reason[i]) for i in range(n) if ids[i] not in kept}
    return RefindResult(pose=pose, ids=tuple(sel_ids), points3d=X[sel], points2d=found[sel],
                        refound=tuple(k for k in refound if k in kept), not_used=not_used,
                        n_expected=n_exp, gate=gate)
