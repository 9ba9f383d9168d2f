"""Several cameras: merge what each sees of the surface before the self-illumination inverse.

Each camera maps its image onto the faces it sees (:class:`resection.surface.SurfaceMap`);
faces hidden from one camera are often seen by another. :func:`merge_views` combines the
per-face radiance of all cameras into one field with a larger ``seen`` set, so that
:func:`selfillum.radiosity.correct` has to guess (by smooth continuation) only the faces no
camera sees.

For Lambertian paint every camera sees the same radiance ``B / pi`` on a face, up to noise
and to the blur of pixels straddling face edges, both worse when a face is seen obliquely
or by few pixels. Each camera's face value is therefore weighted by

``w = n_pixels * cos(theta)``

(``theta`` the angle between the face normal and the direction to the camera), the number
of pixels being itself proportional to the face's projected area. ``method="best"`` keeps
only the camera of largest weight for every face; ``"weighted"`` (default) averages with
those weights.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_erosion

from resection.errors import InputError

__all__ = ["MergedViews", "merge_views", "view_weights"]


@dataclass(frozen=True)
class MergedViews:
    """Per-face values merged over cameras.

    Attributes
    ----------
    values : (F,) float64
        Merged value (NaN where no camera sees the face).
    seen : (F,) bool
        Faces seen by at least one camera.
    weight : (F,) float64
        Sum of the weights used (0 where unseen).
    best : (F,) int64
        Index of the camera with the largest weight for each face (-1 where unseen).
    n_cameras : (F,) int64
        How many cameras see each face.
    """

    values: np.ndarray
    seen: np.ndarray
    weight: np.ndarray
    best: np.ndarray
    n_cameras: np.ndarray


def view_weights(smap, counts: np.ndarray) -> np.ndarray:
    """``counts * cos(theta)`` per face for one camera (0 for faces seen from behind or not
    at all)."""
    mesh = smap.mesh
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    to_cam = smap.camera.center - tri.mean(axis=1)
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", n, to_cam)
    return np.where(cos > 0, counts * cos, 0.0)


def merge_views(maps: Sequence, images: Sequence, *, method: str = "weighted",
                min_pixels: int = 1, silhouette_margin: int = 1) -> MergedViews:
    """Merge the per-face values that several cameras see of the same surface.

    Parameters
    ----------
    maps : sequence of resection.surface.SurfaceMap
        One per camera, all of the same mesh (same face order).
    images : sequence of (H_c, W_c) arrays
        The images of the cameras (radiance, or anything proportional to it with the same
        gain for every camera). NaN pixels are ignored.
    method : {"weighted", "best"}
        Weighted mean over the cameras, or the value of the best-placed camera.
    min_pixels : int
        A camera counts for a face only if at least this many of its finite pixels see it.
    silhouette_margin : int
        Pixels within this many pixels (8-connected) of the background are ignored: their
        square straddles the model's outline and mixes in the background. 0 keeps them.

    Returns
    -------
    MergedViews

    Raises
    ------
    InputError
        Different numbers of maps and images, maps of different meshes, unknown method,
        image shapes that do not match their camera.
    """
    maps, images = list(maps), list(images)
    if not maps:
        raise InputError("merge_views: no camera given")
    if len(maps) != len(images):
        raise InputError(f"merge_views: {len(maps)} surface maps but {len(images)} images")
    if method not in ("weighted", "best"):
        raise InputError(f"merge_views: method must be 'weighted' or 'best', got {method!r}")
    try:
        mp = int(min_pixels)
    except (TypeError, ValueError):
        raise InputError(f"merge_views: min_pixels must be an integer, got {min_pixels!r}") \
            from None
    if mp < 1:
        raise InputError(f"merge_views: min_pixels must be >= 1, got {min_pixels!r}")
    nf = maps[0].n_faces
    faces0 = np.asarray(maps[0].mesh.faces)
    for c, m in enumerate(maps[1:], start=1):
        if m.n_faces != nf or not (m.mesh is maps[0].mesh or np.array_equal(
                np.asarray(m.mesh.faces), faces0)):
            raise InputError(f"merge_views: camera {c} maps another mesh than camera 0")
    try:
        margin = int(silhouette_margin)
    except (TypeError, ValueError):
        margin = -1
    if margin < 0:
        raise InputError(f"merge_views: silhouette_margin must be an integer >= 0, got "
                         f"{silhouette_margin!r}")
    vals = np.empty((len(maps), nf))
    wts = np.empty((len(maps), nf))
    for c, (m, img) in enumerate(zip(maps, images, strict=True)):
        arr = np.asarray(img, dtype=np.float64)
        if arr.shape != m.shape:
            raise InputError(f"merge_views: image {c} has shape {arr.shape}, its camera "
                             f"{m.shape}")
        if margin:
            inner = binary_erosion(m.mask, np.ones((3, 3), bool), iterations=margin,
                                   border_value=1)
            arr = np.where(inner, arr, np.nan)
        sample = m.to_surface(arr)
        ok = sample.counts >= mp
        vals[c] = np.where(ok, sample.values, 0.0)
        wts[c] = np.where(ok, view_weights(m, sample.counts), 0.0)
    total = wts.sum(axis=0)
    seen = total > 0
    best = np.where(seen, np.argmax(wts, axis=0), -1)
    if method == "best":
        values = np.where(seen, vals[np.maximum(best, 0), np.arange(nf)], np.nan)
        weight = np.where(seen, wts.max(axis=0), 0.0)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            values = np.where(seen, (wts * vals).sum(axis=0) / total, np.nan)
        weight = total
    return MergedViews(values, seen, weight, best.astype(np.int64),
                       (wts > 0).sum(axis=0).astype(np.int64))
