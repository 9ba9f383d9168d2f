"""No silent wrong camera: what a camera was solved on, and whether it fits an image.

A camera file given with another camera's image, or in other units than the grid, makes
``map``, the merge and ``selfillum correct`` write wrong results with exit 0. Three checks
catch it, from cheap to thorough:

* **the record** (:func:`solved_on_record`): ``resection pose`` writes into the camera file
  (key ``"solved_on"``) the image it was solved on (file name, size, a fingerprint) and its
  marker file (name and the targets' coordinates, which carry the file's units);
* **the image** (:func:`other_image`): a camera used with an image other than the one it was
  solved on gets a warning (fine for another frame of the same camera; wrong for another
  camera's image);
* **the units** (:func:`require_same_units`): the record's targets against the grid, with
  :func:`resection.camera.units.spread_hint` as ``pose --mesh`` does: a mismatch is refused;
* **the markers** (:func:`marker_fit`, :func:`require_fit`, with ``--markers``): each target
  the camera should see is projected into the image and a window around it is checked for a
  dark spot (the target) against the ring around it; a camera under which fewer than half of
  them land on one is refused.

The fingerprint is cheap: a SHA-1 of about 4,096 pixels on a regular grid (float32, NaN as a
fixed value), so the same pixels give the same fingerprint whatever the file format.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import numpy as np

from resection.camera.units import spread_hint
from resection.errors import InputError

__all__ = ["image_fingerprint", "solved_on_record", "other_image", "require_same_units",
           "MarkerFit", "marker_fit", "require_fit", "check_camera", "FIT_SHARE"]

#: a camera is refused when fewer than this share of the targets it should see land on a
#: dark spot of the image
FIT_SHARE = 0.5
_SAMPLES = 64  # fingerprint grid per side


def image_fingerprint(image) -> str:
    """``"sha1:<16 hex>"`` of a 64 x 64 grid of the image's pixels (float32, NaN as -1e30)."""
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        raise InputError(f"image_fingerprint: expected a 2-D image, got shape {img.shape}")
    rows = np.linspace(0, img.shape[0] - 1, min(_SAMPLES, img.shape[0])).round().astype(int)
    cols = np.linspace(0, img.shape[1] - 1, min(_SAMPLES, img.shape[1])).round().astype(int)
    s = np.asarray(img[np.ix_(rows, cols)], dtype=np.float32)
    s = np.where(np.isfinite(s), s, np.float32(-1e30))
    h = hashlib.sha1(np.ascontiguousarray(s).tobytes() + str(img.shape).encode())
    return f"sha1:{h.hexdigest()[:16]}"


def solved_on_record(image_path=None, image=None, markers_path=None, markers=None) -> dict:
    """The ``"solved_on"`` record ``pose`` writes into a camera file.

    ``{"image": {"name", "width", "height", "fingerprint"}, "markers": {"name", "count",
    "xyz"}}`` (either part when given): the image's file name (not its folder), size in
    pixels and :func:`image_fingerprint`; the marker file's name and its targets'
    coordinates in the file's own units (rounded to 9 significant digits).
    """
    rec: dict = {}
    if image is not None:
        img = np.asarray(image)
        rec["image"] = {"name": os.path.basename(os.fspath(image_path or "")),
                        "width": int(img.shape[1]), "height": int(img.shape[0]),
                        "fingerprint": image_fingerprint(img)}
    if markers is not None:
        xyz = np.asarray(markers.xyz, dtype=np.float64)
        rec["markers"] = {"name": os.path.basename(os.fspath(markers_path or "")),
                          "count": int(len(xyz)),
                          "xyz": [[float(f"{v:.9g}") for v in row] for row in xyz]}
    return rec


def other_image(solved_on: dict | None, image_path, image, camera_path) -> str | None:
    """A one-line warning when the camera was solved on another image than ``image``
    (different fingerprint or size), else None (also when the camera has no record)."""
    rec = (solved_on or {}).get("image")
    if not isinstance(rec, dict) or "fingerprint" not in rec:
        return None
    img = np.asarray(image)
    same_size = (rec.get("width"), rec.get("height")) == (img.shape[1], img.shape[0])
    if same_size and rec["fingerprint"] == image_fingerprint(img):
        return None
    name = os.path.basename(os.fspath(image_path))
    return (f"{camera_path}: solved on {rec.get('name') or 'another image'} "
            f"({rec.get('width')}x{rec.get('height')}, {rec['fingerprint']}), used with "
            f"{name} ({img.shape[1]}x{img.shape[0]}, {image_fingerprint(img)}): right for "
            "another frame of the same camera, wrong for another camera's image (check with "
            "--markers)")


def require_same_units(solved_on: dict | None, mesh_vertices, camera_path, mesh_path) -> None:
    """Refuse a camera whose record's targets and the grid differ in units, as ``pose``
    refuses its markers against the mesh (:func:`resection.camera.units.spread_hint`)."""
    rec = (solved_on or {}).get("markers")
    if not isinstance(rec, dict) or not rec.get("xyz"):
        return
    try:
        xyz = np.asarray(rec["xyz"], dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise InputError(f"{camera_path}: solved_on.markers.xyz is not a list of "
                         "coordinates") from None
    what = f"the targets {camera_path} was solved on ({rec.get('name') or 'markers'})"
    hint = spread_hint(xyz, mesh_vertices, what, f"the grid {mesh_path}")
    if hint:
        raise InputError(f"{camera_path}: {hint}")


@dataclass(frozen=True)
class MarkerFit:
    """Which targets the camera should see land on a dark spot of the image.

    Attributes
    ----------
    expected : tuple of str
        Targets in the image, facing and not hidden (when a surface map is given).
    on_spot : tuple of str
        Those whose window holds a spot of the polarity asked for.
    """

    expected: tuple[str, ...]
    on_spot: tuple[str, ...]

    @property
    def share(self) -> float:
        return len(self.on_spot) / len(self.expected) if self.expected else float("nan")

    def line(self) -> str:
        return (f"markers: {len(self.on_spot)} of {len(self.expected)} expected in the image "
                "land on a spot")


def marker_fit(camera, image, markers, *, surface_map=None, polarity: str = "dark",
               default_diameter_px: float = 5.0) -> MarkerFit:
    """Window check per target: does the camera put each target on a spot of the image?

    A target is expected when it projects inside the image (a window's margin in), faces
    the camera (when it has a normal) and, with ``surface_map``, is not hidden (the surface
    the pixel sees is no nearer than the target by more than 2 % of its distance plus its
    diameter). Its window: a disk of the target's projected diameter ``d`` (``fx d / z``,
    clipped to 2..20 px; ``default_diameter_px`` without a diameter) and the ring from ``d``
    to ``d + max(2, d / 2)`` around it. The target lands on a spot when the disk's mean is
    darker (``polarity="dark"``) or brighter than the ring's median by more than 3 robust
    standard deviations of the ring (and 2 % of the ring's level). NaN pixels are left out.
    """
    if polarity not in ("dark", "bright"):
        raise InputError(f"polarity must be 'dark' or 'bright', got {polarity!r}")
    img = np.asarray(image, dtype=np.float64)
    H, W = img.shape
    X = np.asarray(markers.xyz, dtype=np.float64)
    if len(X) == 0:
        return MarkerFit((), ())
    uv, valid = camera.project(X, return_valid=True)
    xc = X @ np.asarray(camera.R).T + np.asarray(camera.t)
    z = xc[:, 2]
    diam = np.asarray(markers.diameter, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        dpx = np.where(np.isfinite(diam) & (z > 0), camera.K[0, 0] * diam / z,
                       default_diameter_px)
    dpx = np.clip(np.nan_to_num(dpx, nan=default_diameter_px), 2.0, 20.0)
    r_in, r1 = dpx / 2.0, dpx
    r2 = r1 + np.maximum(2.0, dpx / 2.0)
    h = int(np.ceil(r2.max()))
    ok = valid & camera.in_image(uv, margin=float(h)) & markers.facing(camera.center)
    if surface_map is not None and ok.any():
        iu = np.clip(np.rint(uv[:, 0]).astype(int), 0, W - 1)
        iv = np.clip(np.rint(uv[:, 1]).astype(int), 0, H - 1)
        seen_depth = np.asarray(surface_map.depth)[iv, iu]
        dist = np.linalg.norm(X - camera.center, axis=1)
        tol = 0.02 * dist + np.where(np.isfinite(diam), diam, 0.0)
        ok &= ~(seen_depth < dist - tol)  # NaN depth (background): not hidden
    idx = np.flatnonzero(ok)
    ids = tuple(markers.ids[i] for i in idx)
    if idx.size == 0:
        return MarkerFit((), ())
    dv, du = np.mgrid[-h:h + 1, -h:h + 1]
    du, dv = du.ravel().astype(np.float64), dv.ravel().astype(np.float64)
    cu, cv = uv[idx, 0:1], uv[idx, 1:2]
    pu = np.rint(cu) + du  # (n, m) pixel columns and rows of each window
    pv = np.rint(cv) + dv
    r = np.hypot(pu - cu, pv - cv)
    vals = img[np.clip(pv, 0, H - 1).astype(int), np.clip(pu, 0, W - 1).astype(int)]
    fin = np.isfinite(vals)
    inner = (r <= r_in[idx, None]) & fin
    ring = (r >= r1[idx, None]) & (r <= r2[idx, None]) & fin
    with np.errstate(invalid="ignore"):
        inner_mean = np.nanmean(np.where(inner, vals, np.nan), axis=1)
        ring_vals = np.where(ring, vals, np.nan)
        ring_med = np.nanmedian(ring_vals, axis=1)
        mad = np.nanmedian(np.abs(ring_vals - ring_med[:, None]), axis=1)
    noise = np.maximum(1.4826 * mad, 0.02 * np.abs(ring_med))
    contrast = (ring_med - inner_mean) if polarity == "dark" else (inner_mean - ring_med)
    hit = np.isfinite(contrast) & (contrast > 3.0 * noise) & (contrast > 0)
    return MarkerFit(ids, tuple(k for k, good in zip(ids, hit, strict=True) if good))


def require_fit(fit: MarkerFit, camera_path, image_path, *, min_expected: int = 3) -> None:
    """Refuse a camera under which fewer than :data:`FIT_SHARE` of the expected targets land
    on a spot; fewer than ``min_expected`` expected targets cannot be judged (no refusal)."""
    if len(fit.expected) < min_expected:
        return
    if fit.share < FIT_SHARE:
        missed = [k for k in fit.expected if k not in set(fit.on_spot)]
        raise InputError(
            f"{camera_path} does not fit {image_path}: {len(fit.on_spot)} of "
            f"{len(fit.expected)} targets it should see land on a spot of the image (window "
            f"check; missed: {', '.join(missed[:8])}{' ...' if len(missed) > 8 else ''}): "
            "another camera's file or image, or a pose for another run?")


def check_camera(camera_path, camera_file, image_path, image, mesh_vertices, mesh_path, *,
                 markers=None, surface_map=None, polarity: str = "dark",
                 caster=None) -> str | None:
    """Every check of this module for one (camera, image) pair of a command.

    Warns (:class:`UserWarning`) when the camera was solved on another image; raises
    :class:`~resection.errors.InputError` on a units mismatch and, with ``markers``, when
    the camera does not fit the image. Without ``markers``, given the model's ``caster``,
    the model's footprint is compared with the frame
    (:func:`resection.pose.footprint.check_footprint`: a unit mismatch is refused, a poor
    match warned). Returns the marker check's line for the report (None without
    ``markers``).

    Parameters
    ----------
    camera_file : resection.io.cameras.CameraFile
        The camera as read (its ``solved_on`` record, if any).
    caster : resection.surface.visibility.RayCaster, optional
        The model's Embree scene, for the footprint check.
    """
    import warnings

    msg = other_image(camera_file.solved_on, image_path, image, camera_path)
    if msg:
        warnings.warn(msg, UserWarning, stacklevel=2)
    require_same_units(camera_file.solved_on, mesh_vertices, camera_path, mesh_path)
    if markers is None:
        if caster is not None:
            from resection.pose.footprint import check_footprint

            X = np.asarray(mesh_vertices, dtype=np.float64)
            line = check_footprint(camera_file.camera, image, caster, camera_path,
                                   image_path, mesh_path,
                                   bounds=(X.min(axis=0), X.max(axis=0)))
            if line:
                warnings.warn(line, UserWarning, stacklevel=2)
        return None
    fit = marker_fit(camera_file.camera, image, markers, surface_map=surface_map,
                     polarity=polarity)
    require_fit(fit, camera_path, image_path)
    return f"{camera_path}: {fit.line()}"
