"""Markers detected in one image file: the diameter to expect, the image read (saturated
pixels of 8/16-bit files masked), enhanced over the whole image or inside windows, and its
candidates detected and merged.

Shared by :mod:`resection.markers.from_image` (one image to a pose) and
:mod:`resection.markers.refind` (every target in view looked for again).
"""

from __future__ import annotations

import os

import numpy as np

from resection.camera.model import Camera
from resection.errors import InputError
from resection.markers.detect import Candidates, detect_markers

__all__ = ["expected_diameter", "detect_in_image", "merge_candidates", "window_mask"]


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
        As in :func:`resection.markers.detect.detect_markers`.
    enhance : {"background", "normalize", "clahe"}, optional
        Enhancement before detection (:func:`resection.markers.enhancement.enhance`; background and
        normalisation scale ``max(4 diameter, 15)`` px).
    enhance_windows : sequence of (u_min, v_min, u_max, v_max), optional
        Enhance only inside these boxes (inclusive pixels), each on its own, and search
        only there: each box is searched as a ``roi`` (markers cut by its edge are
        rejected), with the pixels outside every box masked, so that the step between
        enhanced and raw pixels is not taken for markers. ``n_masked`` and ``n_rejected``
        are summed over the boxes. Needs ``enhance``; excludes ``roi``.
    **detect_options
        Further keyword arguments of :func:`resection.markers.detect.detect_markers`.

    Returns
    -------
    Candidates
    """
    from resection.markers.detect import check_diameter

    if isinstance(image, str | os.PathLike):
        from resection.io.images import read_image

        image = read_image(image, mask_saturated=True)
    d = check_diameter(diameter)
    if enhance_windows is not None and enhance is None:
        raise InputError("enhance_windows: give an enhancement method too")
    img = image
    if enhance is not None:
        from resection.markers.enhancement import enhance as _enhance

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
    outside = ~window_mask(np.shape(img), boxes)
    user = detect_options.pop("mask", None)
    if user is not None:
        user = np.asarray(user, bool)
        if user.shape != outside.shape:
            raise InputError(f"mask: shape {user.shape} differs from the image's "
                             f"{outside.shape}")
        outside |= user
    parts = [detect_markers(img, d, polarity, template, tuple(b), threshold, mask=outside,
                            **detect_options) for b in boxes.tolist()]  # a few windows
    return merge_candidates(parts, d, detect_options.get("min_separation"))


def merge_candidates(parts, diameter, min_separation) -> Candidates:
    """Candidates of several windows as one list (decreasing merit, doubles of
    overlapping windows removed); counts summed over the windows, noise their median."""
    from scipy.spatial import cKDTree

    from resection.markers.detect import CANDIDATE_FIELDS

    cols = {f: np.concatenate([getattr(c, f) for c in parts]) for f in CANDIDATE_FIELDS}
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
                      polarity=parts[0].polarity, n_rejected=rejected,
                      saturated=np.concatenate([c.saturated for c in parts]))


def window_mask(shape, windows) -> np.ndarray:
    """True inside the boxes (u_min, v_min, u_max, v_max), inclusive, clipped to the image."""
    H, W = shape
    arr = np.asarray(windows, dtype=float).reshape(-1, 4)
    inside = np.zeros((H, W), bool)
    for u0, v0, u1, v1 in np.rint(arr).astype(int):  # a loop over the few boxes
        inside[max(v0, 0):min(v1, H - 1) + 1, max(u0, 0):min(u1, W - 1) + 1] = True
    return inside
