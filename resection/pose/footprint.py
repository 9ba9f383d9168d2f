"""Does the model's footprint match the frame? The check of a camera when no markers are
given.

A camera file in other units than the grid (the camera in mm, the grid in inches) maps
without an error: the model lands as a dot of a few thousand pixels, or blown up around
the camera, and every number written is wrong. The frame itself tells: a painted model is
the lit part of a PSP/TSP frame (or the dark part, seen against a bright background). So,
when the frame has a lit and a dark part (:func:`lit_mask`), the model's footprint (the
pixels whose line of sight meets it) is compared with the frame's lit part (Otsu's
threshold) on a coarse grid of cells (:data:`CELL` pixels a side):

* the overlap (intersection over union) of the footprint with the lit part, or with the
  dark part when that is larger (:func:`footprint_overlap`);
* the same for the model scaled by each unit factor and its inverse
  (:data:`resection.camera.units.UNIT_FACTORS`): the model scaled by ``s`` seen by the camera
  ``(R, t)`` is the model seen by ``(R, t / s)``, so one Embree scene serves every scale.

:func:`check_footprint` refuses (InputError naming the units) a camera whose footprint
overlaps the frame by less than :data:`POOR` when a unit factor makes it overlap by
:data:`GOOD` or more, and warns when the overlap is poor and no factor helps (another
camera's file, a pose far off). A model that fills the frame under both the right camera
and another one cannot be told apart by its footprint: ``--markers`` can
(:mod:`resection.pose.camera_fit`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.camera.model import Camera
from resection.camera.units import UNIT_FACTORS, _units
from resection.errors import InputError

__all__ = ["CELL", "GOOD", "MAX_DARK_RATIO", "MIN_PART", "POOR", "FootprintFit",
           "check_footprint", "footprint_fit", "footprint_overlap", "lit_mask"]

#: Side of a cell of the coarse grid the footprints are compared on, pixels.
CELL = 8
#: Overlap under which a footprint does not match the frame.
POOR = 0.25
#: Overlap from which a scaled footprint matches it.
GOOD = 0.5


#: The lit and the dark part must each hold this share of the frame's finite pixels ...
MIN_PART = 0.05
#: ... and the dark part's mean be at most this share of the lit part's (light falls on
#: the painted model, little on the tunnel): else the frame is no lit model on a dark
#: ground or the reverse (a uniform frame, a ramp, a field that is not light) and
#: nothing is checked.
MAX_DARK_RATIO = 0.5


def lit_mask(image) -> np.ndarray | None:
    """(H, W) bool: pixels above Otsu's threshold of the frame's finite pixels (256 bins;
    NaN pixels are not lit); None when the frame has no lit part to tell from a dark one
    (:data:`MIN_PART`, :data:`MAX_DARK_RATIO`)."""
    img = np.asarray(image, dtype=np.float64)
    fin = np.isfinite(img)
    x = img[fin]
    if x.size == 0 or not np.ptp(x) > 0:
        return None
    h, edges = np.histogram(x, 256)
    c = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(h, dtype=np.float64)
    s0 = np.cumsum(h * c)
    w1, s1 = w0[-1] - w0, s0[-1] - s0
    with np.errstate(invalid="ignore", divide="ignore"):
        between = w0 * w1 * (s0 / w0 - s1 / w1) ** 2
    k = int(np.nanargmax(between))
    n = w0[-1]
    m0, m1 = s0[k] / w0[k], s1[k] / w1[k]
    if min(w0[k], w1[k]) < MIN_PART * n or not m1 > 0 or \
            not -0.1 * m1 <= m0 <= MAX_DARK_RATIO * m1:
        return None
    out = np.zeros(img.shape, bool)
    out[fin] = img[fin] > c[k]
    return out


def _coarse(mask: np.ndarray, cell: int) -> np.ndarray:
    """Cells (``cell`` x ``cell`` pixels, the image cropped to whole cells) more than half
    covered by ``mask``."""
    H, W = mask.shape
    h, w = H // cell, W // cell
    m = mask[:h * cell, :w * cell].reshape(h, cell, w, cell)
    return m.mean(axis=(1, 3)) > 0.5


def _coarse_camera(camera: Camera, cell: int) -> Camera:
    """The camera of the coarse grid: one pixel a cell, the cell's centre on the fine
    pixel grid (distortion acts on normalised coordinates: unchanged)."""
    K = np.array(camera.K, dtype=np.float64)
    K[:2, :] /= cell
    K[0, 2] -= (cell - 1) / (2.0 * cell)
    K[1, 2] -= (cell - 1) / (2.0 * cell)
    return camera.replace(K=K, width=camera.width // cell, height=camera.height // cell)


def footprint_overlap(footprint: np.ndarray, lit: np.ndarray) -> float:
    """Intersection over union of ``footprint`` with ``lit`` or with its complement,
    whichever is larger (a bright model, or a dark one on a bright background)."""
    def iou(a, b):
        u = (a | b).sum()
        return float((a & b).sum() / u) if u else 0.0

    return max(iou(footprint, lit), iou(footprint, ~lit))


@dataclass(frozen=True)
class FootprintFit:
    """Result of :func:`check_footprint`.

    Attributes
    ----------
    overlap : float
        Overlap of the footprint with the frame as given (0..1).
    footprint_share, lit_share : float
        Shares of the frame the footprint and the lit part cover.
    scale, scaled_overlap : float or None
        The unit factor by which the model would fit best, and its overlap (None when no
        factor beats the camera as given).
    scales : tuple of float
        Every factor whose overlap is within 0.02 of the best, nearest to 1 first (a model
        that fills the frame fills it at several scales).
    """

    overlap: float
    footprint_share: float
    lit_share: float
    scale: float | None
    scaled_overlap: float | None
    scales: tuple = ()


def footprint_fit(camera: Camera, image, caster, *, bounds=None,
                  cell: int = CELL) -> FootprintFit:
    """Overlaps of the model's footprint with the frame, as given and for every unit
    factor (see the module docstring). ``caster``: a
    :class:`resection.surface.visibility.RayCaster` of the model; ``bounds``: the model's
    ``(lo, hi)`` corners, a scale that puts the camera inside them is no view."""
    coarse = _coarse_camera(camera, cell)
    if coarse.width < 4 or coarse.height < 4:
        return FootprintFit(1.0, float("nan"), float("nan"), None, None)
    lit = lit_mask(image)
    if lit is None:  # nothing to compare with: not checked
        return FootprintFit(1.0, float("nan"), float("nan"), None, None)
    lit = _coarse(lit, cell)
    if lit.shape != (coarse.height, coarse.width):  # another size: told by the mapping
        return FootprintFit(1.0, float("nan"), float("nan"), None, None)
    _, dirs = coarse.rays()

    def footprint(s: float) -> np.ndarray:
        cam = coarse.with_pose(R=coarse.R, t=np.asarray(coarse.t) / s)
        face, _, _ = caster.first_hit(cam.center, dirs, unit=True)
        return (face >= 0).reshape(coarse.height, coarse.width)

    fp = footprint(1.0)
    base = footprint_overlap(fp, lit)
    tried = {}
    for f in UNIT_FACTORS:
        for s in (f, 1.0 / f):
            if bounds is not None:
                c = camera.center / s
                if np.all((c > bounds[0]) & (c < bounds[1])):
                    continue  # the camera inside the model: no view
            tried[s] = footprint_overlap(footprint(s), lit)
    best = max(tried.values(), default=0.0)
    if best <= base:
        return FootprintFit(base, float(fp.mean()), float(lit.mean()), None, None)
    near = sorted((s for s, o in tried.items() if o >= best - 0.02),
                  key=lambda s: abs(np.log(s)))
    return FootprintFit(base, float(fp.mean()), float(lit.mean()), near[0], best,
                        tuple(near))


def check_footprint(camera: Camera, image, caster, camera_path, image_path, mesh_path, *,
                    bounds=None) -> str | None:
    """Refuse a camera whose model footprint does not match the frame while a unit factor
    makes it match (InputError naming the likely units); return a warning line when the
    footprint matches poorly and no factor helps; None when it matches."""
    fit = footprint_fit(camera, image, caster, bounds=bounds)
    if fit.overlap >= POOR:
        return None
    where = (f"{camera_path} on {image_path}: the model's footprint covers "
             f"{100 * fit.footprint_share:.1f}% of the frame and overlaps the frame's lit "
             f"part ({100 * fit.lit_share:.0f}% of the frame) by {100 * fit.overlap:.0f}%")
    if fit.scale is not None and fit.scaled_overlap >= GOOD and \
            fit.scaled_overlap >= 2.0 * fit.overlap:
        readings = []
        for sc in fit.scales:
            mine, theirs = _units(sc)
            readings.append(f"{sc:.6g} (the grid in {mine} and the camera in {theirs}?)")
        raise InputError(f"{where}; with {mesh_path} scaled by {' or '.join(readings)} it "
                         f"would overlap by {100 * fit.scaled_overlap:.0f}%: convert them to "
                         "one unit")
    return (f"{where}: the wrong camera file, or a pose far off? (--markers checks the "
            "targets)")
