"""From an image to a camera pose: detect the markers, link or match them, solve the PoV.

:func:`image_points` returns the linked markers of one image (ids, model and pixel
coordinates), either from a hand-made linking file (``id,candidate``, see
:mod:`resection.link`) or by automatic matching against an approximate camera or an earlier
matched frame (:func:`resection.match.match_markers`). :func:`pose_from_image` adds the
Point-of-View solve (:func:`resection.pose.solve_pose`). :func:`detect_in_image` reads an
image file (saturated pixels of 8/16-bit files masked), enhances it over the whole image or
inside windows, and detects its markers.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .acceptance import DEFAULT_MARKER_ACCURACY, DEFAULT_MAX_RMS
from .camera import Camera
from .errors import InputError
from .markers import Candidates, detect_markers, read_candidates

__all__ = ["ImagePoints", "image_points", "pose_from_image", "expected_diameter",
           "detect_in_image"]


@dataclass(frozen=True)
class ImagePoints:
    """Linked markers of one image."""

    ids: tuple  #: marker ids
    points3d: np.ndarray  #: (M, 3) model coordinates
    points2d: np.ndarray  #: (M, 2) pixel coordinates
    candidates: Candidates  #: all candidates of the image
    candidate_index: np.ndarray  #: (M,) candidate numbers of the linked markers
    match: object = None  #: MatchResult when matched automatically
    refind: object = None  #: RefindResult when the targets were looked for again


def expected_diameter(camera: Camera, markers) -> float:
    """Median diameter (px) of the markers as imaged by ``camera``: ``f D / z`` from the
    marker file's ``diameter`` column (model units). Raises if no diameter is known."""
    d = np.asarray(getattr(markers, "diameter", np.full(len(markers.ids), np.nan)), float)
    z = camera.to_camera_frame(markers.xyz)[:, 2]
    ok = np.isfinite(d) & (z > 0)
    if not ok.any():
        raise InputError("marker diameter unknown: give the diameter in pixels, or a "
                         "'diameter' column in the marker file")
    f = 0.5 * (camera.K[0, 0] + camera.K[1, 1])
    return float(np.median(f * d[ok] / z[ok]))


def detect_in_image(
    image,
    diameter: float,
    polarity: str = "dark",
    template: str = "tophat",
    roi=None,
    threshold: float | None = None,
    *,
    enhance: str | None = None,
    enhance_windows=None,
    **detect_options,
):
    """Read (if a path), optionally enhance, and detect the markers of one image.

    Parameters
    ----------
    image : (H, W) array or path
        A path is read with :func:`resection.io.images.read_image` with ``mask_saturated``:
        the saturated pixels of 8/16-bit files become NaN, so they stay masked (and counted
        in ``Candidates.n_masked``) also after enhancement.
    diameter, polarity, template, roi, threshold
        As in :func:`resection.markers.detect_markers`.
    enhance : {"background", "normalize", "clahe"}, optional
        Enhancement before detection (:func:`resection.enhance.enhance`; background and
        normalisation scale ``max(4 diameter, 15)`` px).
    enhance_windows : sequence of (u_min, v_min, u_max, v_max), optional
        Enhance only inside these boxes (inclusive pixels), each on its own, and search
        only there: each box is searched as a ``roi`` (markers cut by its edge are
        rejected), with the pixels outside every box masked, so that the step between
        enhanced and raw pixels is not taken for markers. ``n_masked`` and ``n_rejected``
        are summed over the boxes. Needs ``enhance``; excludes ``roi``.
    **detect_options
        Further keyword arguments of :func:`resection.markers.detect_markers`.

    Returns
    -------
    Candidates
    """
    from .markers import _check_diameter

    if isinstance(image, str | os.PathLike):
        from .io.images import read_image

        image = read_image(image, mask_saturated=True)
    d = _check_diameter(diameter)
    if enhance_windows is not None and enhance is None:
        raise InputError("enhance_windows: give an enhancement method too")
    img = image
    if enhance is not None:
        from .enhance import enhance as _enhance

        opts = {} if enhance == "clahe" else {"size": max(4.0 * d, 15.0)}
        img = _enhance(np.asarray(image, float), enhance, windows=enhance_windows, **opts)
    if enhance_windows is None:
        return detect_markers(img, d, polarity, template, roi, threshold, **detect_options)
    if roi is not None:
        raise InputError("roi and enhance_windows: give one or the other (the windows are "
                         "the searched regions)")
    # each window is searched as a roi (markers cut by its edge are rejected), the pixels
    # outside every window masked (the step between enhanced and raw pixels is not seen)
    boxes = np.rint(np.asarray(enhance_windows, dtype=float).reshape(-1, 4)).astype(int)
    outside = ~_window_mask(np.shape(img), boxes)
    user = detect_options.pop("mask", None)
    if user is not None:
        user = np.asarray(user, bool)
        if user.shape != outside.shape:
            raise InputError(f"mask: shape {user.shape} differs from the image's "
                             f"{outside.shape}")
        outside |= user
    parts = [detect_markers(img, d, polarity, template, tuple(b), threshold, mask=outside,
                            **detect_options) for b in boxes.tolist()]  # a few windows
    return _merge(parts, d, detect_options.get("min_separation"))


def _merge(parts, diameter, min_separation) -> Candidates:
    """Candidates of several windows as one list (decreasing merit, doubles of
    overlapping windows removed); counts summed over the windows, noise their median."""
    from scipy.spatial import cKDTree

    from .markers import _FIELDS

    cols = {f: np.concatenate([getattr(c, f) for c in parts]) for f in _FIELDS}
    order = np.argsort(-cols["merit"], kind="stable")
    cols = {f: v[order] for f, v in cols.items()}
    keep = np.ones(order.size, bool)
    sep = min_separation if min_separation is not None else max(0.75 * diameter, 1.5)
    if order.size > 1:
        pairs = cKDTree(np.column_stack([cols["u"], cols["v"]])).query_pairs(
            sep, output_type="ndarray")
        pairs = np.sort(pairs.reshape(-1, 2), axis=1)  # (stronger, weaker)
        pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
        for i, j in pairs.tolist():  # the few close pairs only
            if keep[i]:
                keep[j] = False
    rejected = {k: sum(c.n_rejected.get(k, 0) for c in parts) for k in parts[0].n_rejected}
    rejected["double"] += int((~keep).sum())
    return Candidates(**{f: v[keep] for f, v in cols.items()},
                      n_masked=sum(c.n_masked for c in parts),
                      noise=float(np.median([c.noise for c in parts])),
                      threshold=float(np.median([c.threshold for c in parts])),
                      polarity=parts[0].polarity, n_rejected=rejected)


def _window_mask(shape, windows) -> np.ndarray:
    """True inside the boxes (u_min, v_min, u_max, v_max), inclusive, clipped to the image."""
    H, W = shape
    arr = np.asarray(windows, dtype=float).reshape(-1, 4)
    inside = np.zeros((H, W), bool)
    for u0, v0, u1, v1 in np.rint(arr).astype(int):  # a loop over the few boxes
        inside[max(v0, 0):min(v1, H - 1) + 1, max(u0, 0):min(u1, W - 1) + 1] = True
    return inside


def _check_size(image, camera):
    if camera is None or image is None:
        return
    shape = np.shape(image)
    if len(shape) == 2 and shape != (camera.height, camera.width):
        raise InputError(f"image: {shape[1]}x{shape[0]} pixels, but the camera is "
                         f"{camera.width}x{camera.height} (wrong image or camera file?)")


def _load(image, markers, camera):
    from .io.images import read_image
    from .io.markers import read_markers

    if isinstance(image, str | os.PathLike):
        image = read_image(image, mask_saturated=True)
    if isinstance(markers, str | os.PathLike):
        markers = read_markers(markers)
    if isinstance(camera, str | os.PathLike):
        camera = Camera.read(camera)
    if camera is not None and not isinstance(camera, Camera):
        raise InputError("camera: expected a resection.Camera or a camera JSON path")
    _check_size(image, camera)
    return image, markers, camera


def image_points(
    image,
    markers,
    camera: Camera | None = None,
    *,
    diameter: float | None = None,
    polarity: str = "dark",
    template: str = "tophat",
    roi=None,
    threshold: float | None = None,
    enhance: str | None = None,
    enhance_windows=None,
    links=None,
    candidates=None,
    reference=None,
    detect_options: dict | None = None,
    match_options: dict | None = None,
    marker_accuracy: float = DEFAULT_MARKER_ACCURACY,
    max_rms: float | None = DEFAULT_MAX_RMS,
) -> ImagePoints:
    """Detect the markers of an image and link them to the model's markers.

    Parameters
    ----------
    image : (H, W) array or path
        Its size must be the camera's, when a camera is given. Saturated pixels of 8/16-bit
        files are masked (see :func:`detect_in_image`).
    markers : MarkerSet or path of a marker CSV
    camera : Camera or path, optional
        Approximate camera (intrinsics, and the pose used as the matching reference when
        no other ``reference`` is given).
    diameter : float, optional
        Marker diameter in pixels (default: from the marker file's diameters and the camera,
        :func:`expected_diameter`).
    polarity, template, roi, threshold
        Passed to :func:`resection.markers.detect_markers`.
    enhance : {"background", "normalize", "clahe"}, optional
        Enhancement applied before detection (:func:`resection.enhance.enhance`).
    enhance_windows : sequence of (u_min, v_min, u_max, v_max), optional
        Enhance only inside these boxes (see :func:`detect_in_image`).
    links : path, optional
        Linking CSV ``id,candidate``: the markers are linked by hand instead of matched.
    candidates : Candidates or path, optional
        Candidates to use instead of detecting (e.g. the CSV the linking file numbers).
    reference : MatchResult or (ids, uv), optional
        An earlier matched frame as the matching reference.
    detect_options, match_options : dict, optional
        Further keyword arguments of ``detect_markers`` and ``match_markers``.
    marker_accuracy, max_rms : float
        The acceptance rule's options (px, :mod:`resection.acceptance`), passed to the
        matcher and its pose solves.
    """
    image, markers, camera = _load(image, markers, camera)
    if candidates is None:
        if image is None:
            raise InputError("image_points: give an image or candidates")
        if diameter is None:
            if camera is None:
                raise InputError("image_points: give the marker diameter in pixels (or a "
                                 "camera and marker diameters)")
            diameter = expected_diameter(camera, markers)
        candidates = detect_in_image(image, diameter, polarity, template, roi, threshold,
                                     enhance=enhance, enhance_windows=enhance_windows,
                                     **(detect_options or {}))
    elif isinstance(candidates, str | os.PathLike):
        candidates = read_candidates(candidates)[0]
    elif not isinstance(candidates, Candidates):
        candidates = Candidates.from_uv(candidates)
    if links is not None:
        from .link import read_links

        ids, uv, index = read_links(links, candidates, markers)
        return ImagePoints(ids, markers.select(ids), uv, candidates, index)
    from .match import match_markers

    ref = reference if reference is not None else camera
    if ref is None:
        raise InputError("image_points: automatic matching needs an approximate camera or "
                         "a reference frame (or give a linking file)")
    opts = {"marker_accuracy": marker_accuracy, "max_rms": max_rms, **(match_options or {})}
    m = match_markers(candidates, markers, ref, camera=camera, **opts)
    return ImagePoints(tuple(m.marker_ids), markers.select(m.marker_ids), m.uv, candidates,
                       m.candidate_index, m)


def pose_from_image(image, markers, camera, *, robust=None, max_rms=DEFAULT_MAX_RMS,
                    marker_accuracy=DEFAULT_MARKER_ACCURACY, refine_intrinsics=False,
                    refind=False, mesh=None, **kwargs):
    """Detect, link or match, and solve the camera's Point of View.

    ``marker_accuracy`` and ``max_rms`` (px) are the acceptance rule's options
    (:mod:`resection.acceptance`); they go to the matcher too. With ``refind`` (what
    ``resection pose --image`` does by default), every target the first pose predicts in
    view, facing the camera and not hidden by ``mesh`` is looked for again
    (:func:`resection.refind.refind_targets`), the pose is solved from all those found, and
    ``ImagePoints.refind`` lists the targets not used with why. ``kwargs`` are those of
    :func:`image_points`. Returns ``(PoseResult, ImagePoints)``.
    """
    from .pose import solve_pose

    image, markers, camera = _load(image, markers, camera)
    if camera is None:
        raise InputError("pose_from_image: a camera (intrinsics) is needed")
    pts = image_points(image, markers, camera, marker_accuracy=marker_accuracy,
                       max_rms=max_rms, **kwargs)
    res = solve_pose(camera, pts.points3d, pts.points2d, robust=robust, max_rms=max_rms,
                     marker_accuracy=marker_accuracy, refine_intrinsics=refine_intrinsics,
                     ids=pts.ids)
    if not refind or kwargs.get("links") is not None:
        return res, pts
    from dataclasses import replace

    from .refind import refind_targets

    found = refind_targets(image, markers, res.camera, np.asarray(pts.ids)[res.used],
                           pts.points2d[res.used], diameter=kwargs.get("diameter"),
                           polarity=kwargs.get("polarity", "dark"), mesh=mesh,
                           marker_accuracy=marker_accuracy, max_rms=max_rms,
                           pose_kw={"robust": robust, "refine_intrinsics": refine_intrinsics})
    cand = dict(zip(pts.ids, pts.candidate_index, strict=True))
    return found.pose, replace(pts, ids=found.ids, points3d=found.points3d,
                               points2d=found.points2d, refind=found,
                               candidate_index=np.array([cand.get(k, -1) for k in found.ids]))
