"""Several cameras merged onto one grid, without seams.

Each camera maps its image onto the faces it sees (:class:`~resection.surface.SurfaceMap`).
Where two cameras overlap, a plain mean shows a step at every image's edge: the cameras'
gains differ (exposure, lens, sensor), pixels near an edge or an occlusion boundary mix
in whatever lies beyond it, and faces seen obliquely are blurred. :func:`merge_views`
therefore

1. weights every pixel by its distance to the image's edge and to the nearest *boundary
   pixel* (the model's outline, a depth jump where one part hides another, or a crease
   between faces of very different orientation), ramping from 0 to 1 over ``feather_px``
   pixels (default 4 % of the image's smaller side); pixels on a boundary (within
   ``edge_margin``) are dropped;
2. averages each camera's pixels onto the faces with those weights; a camera's weight for
   a face is the sum of its pixel weights (proportional to the face's projected area)
   times a view-angle taper, 1 for a face seen square-on and 0 at the obliqueness cut-off
   ``max_obliqueness`` (default 70 degrees between the line of sight and the face
   normal, as uPSP); faces beyond it count as unseen by that camera;
3. matches a gain per camera on the overlaps: for every pair of cameras the median of
   ``log(v_b / v_a)`` over the faces both see, then one least-squares solve for all the
   log-gains with the reference camera's fixed at 1; each camera's values are divided by
   its gain (the merge is in the reference camera's counts);
4. takes the weighted mean of the gain-matched values (or the value of the camera of
   largest weight), and reports per pair of cameras the overlap statistics
   (:class:`Overlap`) before and after the gain matching.

Inputs are raw counts (dark level removed); NaN pixels (e.g. saturated ones, see
``resection.io.images.read_image(mask_saturated=True)``) are ignored.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from resection.errors import InputError

__all__ = ["MergedViews", "Overlap", "merge_views", "pixel_weights", "angle_weights",
           "boundary_pixels", "match_gains", "default_feather"]


@dataclass(frozen=True)
class Overlap:
    """Statistics of the faces two cameras both see.

    ``before`` and ``after`` are for the ratio ``v_b / v_a`` of their face values before
    and after the gain matching: median minus 1, and robust spread (1.4826 x median
    absolute deviation) of the ratio.
    """

    cameras: tuple  #: (a, b) camera indices
    n_faces: int  #: faces both see (values > 0)
    gain_ratio: float  #: matched gain of b over a (NaN: pair not used)
    median_before: float
    spread_before: float
    median_after: float
    spread_after: float

    def line(self) -> str:
        a, b = self.cameras
        return (f"cameras {a}-{b}: {self.n_faces} faces in common, gain ratio "
                f"{self.gain_ratio:.4f}; difference before {100 * self.median_before:+.2f} % "
                f"(spread {100 * self.spread_before:.2f} %), after "
                f"{100 * self.median_after:+.2f} % (spread {100 * self.spread_after:.2f} %)")


@dataclass(frozen=True)
class MergedViews:
    """Per-face values merged over cameras.

    Attributes
    ----------
    values : (F,) float64
        Merged value in the reference camera's units (NaN where no camera sees the face).
    seen : (F,) bool
        Faces seen by at least one camera.
    weight : (F,) float64
        Sum of the weights used (0 where unseen).
    best : (F,) int64
        Camera of largest weight for each face (-1 where unseen).
    n_cameras : (F,) int64
        How many cameras see each face (weight > 0).
    gains : (C,) float64
        Gain of each camera relative to the reference camera (1 for it).
    camera_values : (C, F) float64
        Each camera's own face values before gain matching (NaN where it does not count).
    camera_weights : (C, F) float64
        Each camera's weight per face (0 where it does not count).
    overlaps : tuple of Overlap
        One per pair of cameras with faces in common.
    """

    values: np.ndarray
    seen: np.ndarray
    weight: np.ndarray
    best: np.ndarray
    n_cameras: np.ndarray
    gains: np.ndarray
    camera_values: np.ndarray
    camera_weights: np.ndarray
    overlaps: tuple

    def report(self) -> str:
        """Lines for people: gains and overlap statistics."""
        lines = [f"camera {c}: gain {g:.4f}" for c, g in enumerate(self.gains)]
        lines += [o.line() for o in self.overlaps]
        return "\n".join(lines)


def _face_normals_centres(mesh) -> tuple[np.ndarray, np.ndarray]:
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    return n, tri.mean(axis=1)


def angle_weights(smap, max_obliqueness: float | None = None) -> np.ndarray:
    """View-angle taper per face: ``(cos t - cos t_max) / (1 - cos t_max)`` clipped to
    [0, 1], ``t`` the angle between the face normal and the direction from the face centre
    to the camera (as :func:`resection.surface.surface_map.oblique_faces`), ``t_max`` the cut-off
    (degrees; None: the map's own ``max_obliqueness``, 90 if it has none); 0 beyond the
    cut-off and for faces seen from behind."""
    if max_obliqueness is None:
        max_obliqueness = getattr(smap, "max_obliqueness", None) or 90.0
    try:
        lim = float(max_obliqueness)
    except (TypeError, ValueError):
        lim = np.nan
    if not 0.0 < lim <= 90.0:
        raise InputError(f"max_obliqueness must be in (0, 90] degrees, got {max_obliqueness}")
    n, cen = _face_normals_centres(smap.mesh)
    to_cam = smap.camera.center[None, :] - cen
    cos = np.einsum("ij,ij->i", n, to_cam) / np.linalg.norm(to_cam, axis=1)
    c0 = np.cos(np.radians(lim))
    return np.clip((cos - c0) / (1.0 - c0), 0.0, 1.0)


def boundary_pixels(smap, *, depth_jump: float = 0.02, crease_deg: float = 45.0) -> np.ndarray:
    """(H, W) bool: model pixels next to (8-neighbourhood) the background, a depth jump
    larger than ``depth_jump`` times the depth (one part hiding another), or a pixel seeing
    a face whose normal differs by more than ``crease_deg`` degrees (a crease: pixels there
    mix both sides). Image edges are not boundaries (see :func:`pixel_weights`)."""
    face = smap.face_index
    mask = face >= 0
    H, W = mask.shape
    depth = np.where(mask, smap.depth, np.inf)
    n, _ = _face_normals_centres(smap.mesh)
    cos_lim = np.cos(np.radians(crease_deg))
    bnd = np.zeros((H, W), dtype=bool)
    for dv, du in ((0, 1), (1, 0), (1, 1), (1, -1)):  # the 4 neighbour directions
        a = (slice(0, H - dv), slice(max(0, -du), W - max(0, du)))
        b = (slice(dv, H), slice(max(0, du), W - max(0, -du)))
        ma, mb = mask[a], mask[b]
        fa, fb = face[a], face[b]
        da, db = depth[a], depth[b]
        with np.errstate(invalid="ignore"):
            jump = np.abs(da - db) > depth_jump * np.minimum(da, db)
        edge = (ma != mb) | (ma & mb & jump)
        other = np.flatnonzero((ma & mb & (fa != fb)).ravel())  # pixels on two faces
        if other.size:
            f1, f2 = fa.ravel()[other], fb.ravel()[other]
            crease = np.einsum("ij,ij->i", n[f1], n[f2]) < cos_lim
            edge.ravel()[other[crease]] = True
        bnd[a] |= edge
        bnd[b] |= edge
    return bnd & mask


def default_feather(shape) -> float:
    """Default feathering width: 4 % of the image's smaller side, at least 4 pixels
    (vignetting and similar camera-to-camera differences vary on the image's scale)."""
    return max(4.0, 0.04 * min(shape))


def pixel_weights(smap, *, feather_px: float | None = None, edge_margin: int = 1,
                  depth_jump: float = 0.02, crease_deg: float = 45.0) -> np.ndarray:
    """(H, W) feathering weights in [0, 1] (0 off the model).

    With ``d_b`` the distance (pixels) to the nearest boundary pixel
    (:func:`boundary_pixels`, 0 on it) and ``d_e`` the distance to the outside of the image
    (1 for the first row or column), the weight is
    ``min(ramp(d_b - edge_margin + 1), ramp(d_e))`` with ``ramp(d) = clip(d / (feather_px
    + 1), 0, 1)``; pixels with ``d_b < edge_margin`` get 0. ``feather_px = 0`` gives 1
    everywhere else (no feathering); None: :func:`default_feather`.
    """
    if feather_px is None:
        feather_px = default_feather(smap.shape)
    if not feather_px >= 0:
        raise InputError(f"feather_px must be >= 0, got {feather_px}")
    try:
        margin = int(edge_margin)
    except (TypeError, ValueError):
        margin = -1
    if margin < 0:
        raise InputError(f"edge_margin must be an integer >= 0, got {edge_margin!r}")
    mask = smap.mask
    H, W = mask.shape
    bnd = boundary_pixels(smap, depth_jump=depth_jump, crease_deg=crease_deg)
    d_b = distance_transform_edt(~bnd) if bnd.any() else np.full((H, W), np.inf)
    vv, uu = np.mgrid[0:H, 0:W]
    d_e = np.minimum(np.minimum(uu + 1, W - uu), np.minimum(vv + 1, H - vv)).astype(float)
    f = float(feather_px) + 1.0
    w = np.minimum(np.clip((d_b - margin + 1) / f, 0.0, 1.0), np.clip(d_e / f, 0.0, 1.0))
    w[d_b < margin] = 0.0
    return np.where(mask, w, 0.0)


def _robust(x: np.ndarray) -> tuple[float, float]:
    if x.size == 0:
        return np.nan, np.nan
    med = float(np.median(x))
    return med, float(1.4826 * np.median(np.abs(x - med)))


def match_gains(values: np.ndarray, weights: np.ndarray, *, reference: int = 0,
                min_overlap: int = 10) -> tuple[np.ndarray, tuple]:
    """Gains of C cameras from their face values on the overlaps.

    Parameters
    ----------
    values, weights : (C, F) arrays
        Each camera's face values and weights (weight 0: not seen by that camera).
    reference : int
        Camera whose gain is 1.
    min_overlap : int
        Pairs with fewer common faces (positive values) are not used.

    Returns
    -------
    gains : (C,) float64
        ``v_c ~ gains[c] * v_reference``; 1 for cameras not linked to the reference.
    overlaps : tuple of Overlap
    """
    C = values.shape[0]
    if not 0 <= reference < C:
        raise InputError(f"reference camera {reference} out of range (0..{C - 1})")
    ok = (weights > 0) & np.isfinite(values) & (values > 0)
    logv = np.log(np.where(ok, values, 1.0))
    pairs = []
    for a in range(C):  # loop over pairs of cameras (a handful)
        for b in range(a + 1, C):
            both = ok[a] & ok[b]
            if both.any():
                r = logv[b, both] - logv[a, both]
                pairs.append((a, b, int(both.sum()), float(np.median(r)), both))
    used = [p for p in pairs if p[2] >= min_overlap]
    logg = np.zeros(C)
    if used:
        A = np.zeros((len(used) + 1, C))
        y = np.zeros(len(used) + 1)
        for k, (a, b, n, m, _) in enumerate(used):
            s = np.sqrt(n)
            A[k, a], A[k, b], y[k] = -s, s, s * m
        A[-1, reference] = 1e3  # log gain of the reference fixed at 0
        # cameras not linked to the reference keep gain 1: find them by connectivity
        linked = {reference}
        changed = True
        while changed:
            changed = False
            for a, b, *_ in used:
                if (a in linked) != (b in linked):
                    linked |= {a, b}
                    changed = True
        sol, *_ = np.linalg.lstsq(A, y, rcond=None)
        logg = np.where(np.isin(np.arange(C), sorted(linked)), sol, 0.0)
    gains = np.exp(logg)
    overlaps = []
    for a, b, n, _, both in pairs:
        ratio = np.exp(logv[b, both] - logv[a, both])
        mb, sb = _robust(ratio - 1.0)
        ma, sa = _robust(ratio * gains[a] / gains[b] - 1.0)
        g = gains[b] / gains[a] if n >= min_overlap else np.nan
        overlaps.append(Overlap((a, b), n, float(g), mb, sb, ma, sa))
    return gains, tuple(overlaps)


def _restate(o: Overlap, vals, wts, gains) -> Overlap:
    a, b = o.cameras
    both = (wts[a] > 0) & (wts[b] > 0) & (vals[a] > 0) & (vals[b] > 0)
    ma, sa = _robust(vals[b, both] / vals[a, both] * gains[a] / gains[b] - 1.0)
    return Overlap(o.cameras, o.n_faces, float(gains[b] / gains[a]), o.median_before,
                   o.spread_before, ma, sa)


def merge_views(maps: Sequence, images: Sequence, *, method: str = "weighted",
                min_pixels: int = 1, edge_margin: int = 1, feather_px: float | None = None,
                max_obliqueness: float | None = None, match_gain: bool = True,
                reference: int = 0, min_overlap: int = 10, depth_jump: float = 0.02,
                crease_deg: float = 45.0, gains=None,
                pixel_weights_=None) -> MergedViews:
    """Merge what several cameras see of the same surface onto its faces.

    Parameters
    ----------
    maps : sequence of resection.surface.surface_map.SurfaceMap
        One per camera, all of the same mesh (same face order).
    images : sequence of (H_c, W_c) arrays
        The images (raw counts, dark level removed; NaN pixels ignored).
    method : {"weighted", "best"}
        Weighted mean of the gain-matched values, or the value of the camera of largest
        weight.
    min_pixels : int
        A camera counts for a face only if at least this many of its finite, non-zero-weight
        pixels see it.
    edge_margin : int
        Pixels closer than this to a boundary pixel are dropped (1: the boundary pixels
        themselves, whose square straddles the outline or an occlusion edge).
    feather_px : float, optional
        Width of the weight ramp from image edges and boundaries, pixels (0: none; default
        4 % of each image's smaller side, :func:`default_feather`).
    max_obliqueness : float, optional
        Obliqueness cut-off, degrees: faces seen more obliquely count as unseen by that
        camera; the weight tapers to 0 there. Default: each map's own cut-off
        (:class:`~resection.surface.surface_map.SurfaceMap`'s ``max_obliqueness``, 70 by default).
    match_gain : bool
        Match a gain per camera on the overlaps (else every gain is 1).
    reference : int
        Camera whose units the merge is in.
    min_overlap : int
        Fewest common faces for a pair of cameras to enter the gain matching.
    depth_jump, crease_deg
        Boundary detection, see :func:`boundary_pixels`.
    gains : (C,) array_like, optional
        Gains to use instead of matching them (e.g. those of the wind-off merge for the
        wind-on images of the same cameras, so that a ratio of the two has no seam).
    pixel_weights_ : sequence of (H_c, W_c) arrays, optional
        Each camera's :func:`pixel_weights` with these options, when the caller has them
        (several merges of the same maps: computed once).

    Returns
    -------
    MergedViews

    Raises
    ------
    InputError
        Different numbers of maps and images, maps of different meshes, bad options, image
        shapes that do not match their camera.
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
    C = len(maps)
    vals = np.full((C, nf), np.nan)
    wts = np.zeros((C, nf))
    for c, (m, img) in enumerate(zip(maps, images, strict=True)):  # loop over cameras
        arr = np.asarray(img, dtype=np.float64)
        if arr.shape != m.shape:
            raise InputError(f"merge_views: image {c} has shape {arr.shape}, its camera "
                             f"{m.shape}")
        try:
            pw = pixel_weights(m, feather_px=feather_px, edge_margin=edge_margin,
                               depth_jump=depth_jump, crease_deg=crease_deg) \
                if pixel_weights_ is None else np.asarray(pixel_weights_[c], np.float64)
        except InputError as e:
            raise InputError(f"merge_views: {e}") from None
        finite = np.isfinite(arr)
        pw = np.where(finite, pw, 0.0).ravel()
        planes = np.stack([pw * np.where(finite, arr, 0.0).ravel(), pw,
                           (pw > 0).astype(np.float64)]).reshape(3, *m.shape)
        vsum, wsum, npx = m.to_surface(planes).values * m.pixel_counts[None, :]
        vsum, wsum, npx = (np.nan_to_num(x) for x in (vsum, wsum, npx))
        ang = angle_weights(m, max_obliqueness)
        ok = (npx >= mp - 0.5) & (wsum > 0) & (ang > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            vals[c] = np.where(ok, vsum / np.where(ok, wsum, 1.0), np.nan)
        wts[c] = np.where(ok, wsum * ang, 0.0)
    fitted, overlaps = match_gains(vals, wts, reference=reference,
                                   min_overlap=min_overlap if match_gain else nf + 1)
    if gains is not None:
        g = np.asarray(gains, dtype=np.float64).ravel()
        if g.shape != (C,) or not np.all(np.isfinite(g) & (g > 0)):
            raise InputError(f"merge_views: gains must be {C} positive numbers, got {gains!r}")
        gains = g
    else:
        gains = fitted if match_gain else np.ones(C)
    if gains is not fitted:  # statistics after the gains actually used
        overlaps = tuple(_restate(o, vals, wts, gains) for o in overlaps)
    matched = vals / gains[:, None]
    total = wts.sum(axis=0)
    seen = total > 0
    best = np.where(seen, np.argmax(wts, axis=0), -1)
    if method == "best":
        values = np.where(seen, matched[np.maximum(best, 0), np.arange(nf)], np.nan)
        weight = np.where(seen, wts.max(axis=0), 0.0)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            values = np.where(seen, np.nansum(wts * np.nan_to_num(matched), axis=0) / total,
                              np.nan)
        weight = total
    return MergedViews(values, seen, weight, best.astype(np.int64),
                       (wts > 0).sum(axis=0).astype(np.int64), gains, vals, wts, overlaps)
