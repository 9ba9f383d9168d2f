"""From an image to a camera pose: detect the markers, link or match them, solve the PoV.

:func:`image_points` returns the linked markers of one image (ids, model and pixel
coordinates), either from a hand-made linking file (``id,candidate``, see
:mod:`resection.link`) or by automatic matching against an approximate camera or an earlier
matched frame (:func:`resection.match.match_markers`). :func:`pose_from_image` adds the
Point-of-View solve (:func:`resection.pose.solve_pose`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .errors import InputError
from .markers import Candidates, detect_markers, read_candidates

__all__ = ["ImagePoints", "image_points", "pose_from_image", "expected_diameter"]


@dataclass(frozen=True)
class ImagePoints:
    """Linked markers of one image."""

    ids: tuple  #: marker ids
    points3d: np.ndarray  #: (M, 3) model coordinates
    points2d: np.ndarray  #: (M, 2) pixel coordinates
    candidates: Candidates  #: all candidates of the image
    candidate_index: np.ndarray  #: (M,) candidate numbers of the linked markers
    match: object = None  #: MatchResult when matched automatically


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


def _load(image, markers, camera):
    from .images import read_image
    from .markerio import read_markers

    if isinstance(image, str | os.PathLike):
        image = read_image(image)
    if isinstance(markers, str | os.PathLike):
        markers = read_markers(markers)
    if isinstance(camera, str | os.PathLike):
        camera = Camera.read(camera)
    if camera is not None and not isinstance(camera, Camera):
        raise InputError("camera: expected a resection.Camera or a camera JSON path")
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
    links=None,
    candidates=None,
    reference=None,
    detect_options: dict | None = None,
    match_options: dict | None = None,
) -> ImagePoints:
    """Detect the markers of an image and link them to the model's markers.

    Parameters
    ----------
    image : (H, W) array or path
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
    links : path, optional
        Linking CSV ``id,candidate``: the markers are linked by hand instead of matched.
    candidates : Candidates or path, optional
        Candidates to use instead of detecting (e.g. the CSV the linking file numbers).
    reference : MatchResult or (ids, uv), optional
        An earlier matched frame as the matching reference.
    detect_options, match_options : dict, optional
        Further keyword arguments of ``detect_markers`` and ``match_markers``.
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
        img = image
        if enhance is not None:
            from .enhance import enhance as _enhance

            opts = {} if enhance == "clahe" else {"size": max(4.0 * diameter, 15.0)}
            img = _enhance(np.asarray(image, float), enhance, **opts)
        candidates = detect_markers(img, diameter, polarity, template, roi, threshold,
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
    m = match_markers(candidates, markers, ref, camera=camera, **(match_options or {}))
    return ImagePoints(tuple(m.marker_ids), markers.select(m.marker_ids), m.uv, candidates,
                       m.candidate_index, m)


def pose_from_image(image, markers, camera, *, robust=None, max_rms=None,
                    refine_intrinsics=False, **kwargs):
    """Detect, link or match, and solve the camera's Point of View.

    ``kwargs`` are those of :func:`image_points`. Returns ``(PoseResult, ImagePoints)``.
    """
    from .pose import solve_pose

    image, markers, camera = _load(image, markers, camera)
    if camera is None:
        raise InputError("pose_from_image: a camera (intrinsics) is needed")
    pts = image_points(image, markers, camera, **kwargs)
    res = solve_pose(camera, pts.points3d, pts.points2d, robust=robust, max_rms=max_rms,
                     refine_intrinsics=refine_intrinsics)
    return res, pts
