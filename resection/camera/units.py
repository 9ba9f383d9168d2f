"""Unit mismatches and views that see nothing: diagnosis for the messages.

A camera solved with markers in metres and a mesh in millimetres (or markers in inches)
does not fail loudly: it sees nothing, or sees the model from inside. These functions say
why, so that the refusal names the likely cause:

* :func:`camera_scale_hint`: the points (markers, mesh vertices) would be seen as a model
  is seen - in front of the camera, inside the image, filling a fair part of it, the
  camera outside them - once scaled by a unit factor (1000: mm vs m, 25.4: mm vs inch,
  39.37: inch vs m), and are not as given;
* :func:`spread_hint`: two point sets that should share units (markers and the mesh they
  sit on) whose spreads differ by such a factor, or that lie far apart;
* :func:`nothing_seen_causes`: the likely causes of a view that sees none of the points
  (all behind the camera, all outside the image, a unit mismatch);
* :func:`require_seen`: refuse a run that sees nothing, with those causes.
"""

from __future__ import annotations

import numpy as np

from resection._checks import as_points
from resection.camera.model import Camera
from resection.errors import InputError

__all__ = [
    "UNIT_FACTORS",
    "camera_scale_hint",
    "nothing_seen_causes",
    "require_seen",
    "spread_hint",
]

#: Length-unit factors that are mixed up in practice, with their usual reading.
UNIT_FACTORS = {1000.0: ("mm", "m"), 25.4: ("mm", "inch"), 39.37: ("inch", "m")}
#: A spread ratio within this relative distance of a unit factor reads as that factor.
FACTOR_RTOL = 0.15
#: At most this many points are tried (a deterministic stride through larger sets).
_MAX_POINTS = 4000


def _subsample(points) -> np.ndarray:
    X = as_points(points, 3, "points")
    step = max(1, len(X) // _MAX_POINTS)
    return X[::step]


def _view_score(camera: Camera, X: np.ndarray) -> float:
    """Share of the points seen as a model is seen: in front of the camera and inside the
    image, with the camera outside their bounding box and the seen points spanning at
    least a tenth of the image (a cloud shrunk to a dot or blown up around the camera is
    not a view). 0 when one of these fails."""
    lo, hi = X.min(axis=0), X.max(axis=0)
    if np.all((camera.center > lo) & (camera.center < hi)):
        return 0.0
    uv, valid = camera.project(X, return_valid=True)
    seen = valid & camera.in_image(uv)
    if seen.sum() < 3:
        return 0.0
    span = np.ptp(uv[seen], axis=0).max()
    if span < 0.1 * min(camera.width, camera.height):
        return 0.0
    return float(seen.mean())


def _units(s: float) -> tuple[str, str]:
    """(points' unit, camera's unit) for a scale ``s`` that brings the points to the
    camera's units: ``s = 0.001`` reads as points in mm, camera in m."""
    f = 1.0 / s if s < 1 else s
    small, big = UNIT_FACTORS[min(UNIT_FACTORS, key=lambda k: abs(k - f))]
    return (small, big) if s < 1 else (big, small)


def camera_scale_hint(camera: Camera, points, what: str) -> str | None:
    """A sentence naming a unit mismatch between ``camera`` and ``points``, or None.

    The points are tried as given and scaled (about the origin) by each unit factor and
    its inverse; a hint is given when a scaled set is seen as a model is seen (see the
    module docstring) by at least half its points and clearly better than the set as
    given.

    Parameters
    ----------
    camera : Camera
        Camera with its pose (model units).
    points : (N, 3) array_like
        Marker coordinates or mesh vertices.
    what : str
        What the points are, for the sentence (e.g. ``"the markers"``).
    """
    X = _subsample(points)
    base = _view_score(camera, X)
    best, best_s = 0.0, None
    for f in UNIT_FACTORS:
        for s in (1.0 / f, f):
            score = _view_score(camera, X * s)
            if score > best:
                best, best_s = score, s
    if best_s is None or best < 0.5 or best < 2.0 * base:
        return None
    mine, theirs = _units(best_s)
    return (f"unit mismatch: {what} in {mine} and the camera in {theirs}? (scaled by "
            f"{best_s:.6g}, {100 * best:.0f}% of {what} fall in the image as a model's "
            "would); convert them to one unit")


def spread_hint(points, reference, what: str, reference_what: str) -> str | None:
    """A sentence naming a unit mismatch between two point sets that should share units
    (markers and the mesh they are painted on), or None.

    Given when ``points`` spread wider than ``reference`` by a unit factor (ratio of the
    RMS distances to the centroids within :data:`FACTOR_RTOL` of it); when they spread
    less by a unit factor and lie mostly outside the ``reference`` bounding box (markers
    may legitimately cover a small part of a model, but on it); or when they lie mostly
    farther than one ``reference`` size from its bounding box.
    """
    A, B = _subsample(points), _subsample(reference)
    lo, hi = B.min(axis=0), B.max(axis=0)
    size = float(np.linalg.norm(hi - lo))
    outside = np.linalg.norm(np.maximum(lo - A, 0) + np.maximum(A - hi, 0), axis=1)
    sa = float(np.sqrt(np.mean(np.sum((A - A.mean(axis=0)) ** 2, axis=1))))
    sb = float(np.sqrt(np.mean(np.sum((B - B.mean(axis=0)) ** 2, axis=1))))
    if sa > 0 and sb > 0:
        ratio = sa / sb
        off_reference = np.mean(outside > 0.01 * size) > 0.5
        for f, (small, big) in UNIT_FACTORS.items():
            if abs(ratio / f - 1.0) < FACTOR_RTOL:
                a_unit, b_unit = small, big
            elif abs(1.0 / (ratio * f) - 1.0) < FACTOR_RTOL and off_reference:
                a_unit, b_unit = big, small
            else:
                continue
            return (f"{what} spread {ratio:.4g} times as far as {reference_what}: "
                    f"{what} in {a_unit} and {reference_what} in {b_unit}? Convert "
                    "them to one unit")
    far = outside > size
    if size > 0 and far.mean() > 0.5:
        return (f"{int(far.sum())} of {len(A)} of {what} lie farther than the size of "
                f"{reference_what} ({size:.3g}) from its bounding box: different units or "
                "origins?")
    return None


def nothing_seen_causes(camera: Camera, points, what: str) -> str:
    """The likely causes of a view that sees none of ``points``, as one clause:
    all behind the camera (facing away), all outside the image (pose or intrinsics), a
    unit mismatch (:func:`camera_scale_hint`)."""
    X = _subsample(points)
    uv, valid = camera.project(X, return_valid=True)
    causes = []
    hint = camera_scale_hint(camera, X, what)
    if hint:
        causes.append(hint)
    z = camera.to_camera_frame(X)[:, 2]
    if np.all(z <= 0):
        causes.append(f"all of {what} are behind the camera (camera facing away?)")
    elif not np.any(valid & camera.in_image(uv)):
        causes.append(f"{what} project outside the {camera.width}x{camera.height} image "
                      "(wrong pose or intrinsics?)")
    lo, hi = X.min(axis=0), X.max(axis=0)
    if np.all((camera.center > lo) & (camera.center < hi)) and not hint:
        causes.append(f"the camera is inside the bounding box of {what} (unit mismatch?)")
    if not causes:
        causes.append("camera facing away, or a unit mismatch (mm vs m vs inch)")
    return "; ".join(causes)


def require_seen(n_seen: int, camera: Camera, points, what: str, context: str) -> None:
    """Raise :class:`InputError` when ``n_seen`` is 0: ``context`` (which run saw
    nothing) and the likely causes (:func:`nothing_seen_causes`)."""
    if int(n_seen) > 0:
        return
    raise InputError(f"{context}: likely causes: {nothing_seen_causes(camera, points, what)}")
