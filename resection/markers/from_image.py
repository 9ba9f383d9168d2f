"""From an image to a camera pose: detect the markers, link or match them, solve the PoV.

:func:`image_points` returns the linked markers of one image (ids, model and pixel
coordinates), either from a hand-made linking file (``id,candidate``, see
:mod:`resection.markers.link`) or by automatic matching against an approximate camera or
an earlier matched frame (:func:`resection.markers.match.match_markers`).
:func:`pose_from_image` adds the Point-of-View solve (:func:`resection.pose.solve.solve_pose`).
The image itself is read and its markers detected by :mod:`resection.markers.in_image`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.markers.detect import Candidates, read_candidates
from resection.markers.in_image import (  # re-exported
    detect_in_image,
    expected_diameter,
)
from resection.pose.acceptance import DEFAULT_MARKER_ACCURACY, DEFAULT_MAX_RMS

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


def _check_size(image, camera):
    if camera is None or image is None:
        return
    shape = np.shape(image)
    if len(shape) == 2 and shape != (camera.height, camera.width):
        raise InputError(f"image: {shape[1]}x{shape[0]} pixels, but the camera is "
                         f"{camera.width}x{camera.height} (wrong image or camera file?)")


def _load(image, markers, camera):
    from resection.io.images import read_image
    from resection.io.markers import read_markers

    if isinstance(image, str | os.PathLike):
        image = read_image(image, mask_saturated=True)
    markers_path = None
    if isinstance(markers, str | os.PathLike):
        markers_path = os.fspath(markers)
        markers = read_markers(markers)
    meta = {"has_pose": True, "source": None}
    if isinstance(camera, str | os.PathLike):
        camera, meta = _read_posed(camera, np.shape(image)[::-1][-2:])
    meta["markers"] = markers_path
    if camera is not None and not isinstance(camera, Camera):
        raise InputError("camera: expected a resection.Camera or a camera JSON path")
    _check_size(image, camera)
    return image, markers, camera, meta


def _read_posed(path, image_size=None) -> tuple[Camera, dict]:
    """A camera file's camera, and what the file says of its pose (an intrinsics-only
    file has none) and its name, for the messages of :func:`image_points`; ``image_size``
    ``(width, height)`` for a uPSP file that gives none."""
    from resection.io.cameras import read_camera_file

    cf = read_camera_file(path, image_size=image_size)
    return cf.camera, {"has_pose": bool(cf.has_pose), "source": os.fspath(path)}


def _pose_check(image, markers, camera, meta, has_pose, need_diameter: bool):
    """A camera without a pose is named as such (:mod:`resection.pose.pose_needed`), before the
    matcher or the diameter estimate would blame the markers or the camera's direction."""
    from resection.pose.pose_needed import has_usable_pose, no_pose_message, require_pose

    if has_pose is None:
        has_pose = meta["has_pose"]
    names = dict(camera_path=meta["source"], markers_path=meta["markers"],
                 image_path=os.fspath(image) if isinstance(image, str | os.PathLike) else None)
    if not need_diameter:
        require_pose(camera, markers, has_pose=has_pose, **names)
    elif not has_usable_pose(camera, getattr(markers, "targets", markers).xyz, has_pose):
        raise InputError(no_pose_message(
            "intrinsics only" if not has_pose else "the identity pose",
            camera=names["camera_path"], image=names["image_path"],
            markers=names["markers_path"], way_forward=False,
            what="the size of the markers in the image is unknown: give the marker diameter "
            "in pixels (--diameter PX, the value resection link --serve printed) or the "
            "candidates (--candidates)"))


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
    has_pose: bool | None = None,
    markers_source: str | None = None,
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
        Passed to :func:`resection.markers.detect.detect_markers`.
    enhance : {"background", "normalize", "clahe"}, optional
        Enhancement applied before detection (:func:`resection.markers.enhancement.enhance`).
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
        The acceptance rule's options (px, :mod:`resection.pose.acceptance`), passed to the
        matcher and its pose solves.
    has_pose : bool, optional
        False when ``camera`` holds intrinsics only (default: what its file says when
        ``camera`` is a path, else True). A camera without a pose (or with the identity
        pose and fewer than three targets in view) cannot be matched from: the error says
        so and names ``resection link --serve`` (:mod:`resection.pose.pose_needed`).
    markers_source : str, optional
        The marker file's name for messages, when ``markers`` is given already read.
    """
    image_arg = image
    image, markers, camera, meta = _load(image, markers, camera)
    meta["markers"] = meta["markers"] or markers_source
    if links is None and reference is None and camera is not None:
        _pose_check(image_arg, markers, camera, meta, has_pose, need_diameter=False)
    if candidates is None:
        if image is None:
            raise InputError("image_points: give an image or candidates")
        if diameter is None:
            if camera is None:
                raise InputError("image_points: give the marker diameter in pixels (or a "
                                 "camera and marker diameters)")
            _pose_check(image_arg, markers, camera, meta, has_pose, need_diameter=True)
            diameter = expected_diameter(camera, markers)
        candidates = detect_in_image(image, diameter, polarity, template, roi, threshold,
                                     enhance=enhance, enhance_windows=enhance_windows,
                                     **(detect_options or {}))
    elif isinstance(candidates, str | os.PathLike):
        candidates = read_candidates(candidates)[0]
    elif not isinstance(candidates, Candidates):
        candidates = Candidates.from_uv(candidates)
    if links is not None:
        from resection.markers.link import read_links

        ids, uv, index = read_links(links, candidates, markers)
        return ImagePoints(ids, markers.select(ids), uv, candidates, index)
    from resection.markers.match import match_markers

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
    (:mod:`resection.pose.acceptance`); they go to the matcher too. With ``refind`` (what
    ``resection pose --image`` does by default), every target the first pose predicts in
    view, facing the camera and not hidden by ``mesh`` is looked for again
    (:func:`resection.markers.refind.refind_targets`), the pose is solved from all those found, and
    ``ImagePoints.refind`` lists the targets not used with why. ``kwargs`` are those of
    :func:`image_points`. Returns ``(PoseResult, ImagePoints)``.
    """
    from resection.pose.solve import solve_pose

    image, markers, camera, meta = _load(image, markers, camera)
    if camera is None:
        raise InputError("pose_from_image: a camera (intrinsics) is needed")
    kwargs.setdefault("has_pose", meta["has_pose"])
    pts = image_points(image, markers, camera, marker_accuracy=marker_accuracy,
                       max_rms=max_rms, **kwargs)
    res = solve_pose(camera, pts.points3d, pts.points2d, robust=robust, max_rms=max_rms,
                     marker_accuracy=marker_accuracy, refine_intrinsics=refine_intrinsics,
                     ids=pts.ids)
    if not refind:  # after hand links too: every other target in view is looked for
        return res, pts
    from dataclasses import replace

    from resection.markers.refind import refind_targets

    found = refind_targets(image, markers, res.camera, np.asarray(pts.ids)[res.used],
                           pts.points2d[res.used], diameter=kwargs.get("diameter"),
                           polarity=kwargs.get("polarity", "dark"), mesh=mesh,
                           marker_accuracy=marker_accuracy, max_rms=max_rms,
                           pose_kw={"robust": robust, "refine_intrinsics": refine_intrinsics})
    cand = dict(zip(pts.ids, pts.candidate_index, strict=True))
    return found.pose, replace(pts, ids=found.ids, points3d=found.points3d,
                               points2d=found.points2d, refind=found,
                               candidate_index=np.array([cand.get(k, -1) for k in found.ids]))
