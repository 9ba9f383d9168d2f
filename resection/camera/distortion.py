"""Brown-Conrady lens distortion on normalised coordinates (OpenCV order).

``dist = [k1, k2, p1, p2, k3]`` acts on ``(x, y) = (X/Z, Y/Z)`` in the camera frame (x right,
y down): :func:`distort_normalized` applies it, :func:`undistort_normalized` inverts it inside
the radius where the radial factor is monotonic (:func:`max_monotonic_radius`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["distort_normalized", "undistort_normalized", "max_monotonic_radius"]

def distort_normalized(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Apply Brown-Conrady distortion to normalised coordinates.

    Parameters
    ----------
    xy : (N, 2) array
        Ideal normalised coordinates ``(x/z, y/z)``.
    dist : (5,) array
        ``[k1, k2, p1, p2, k3]``.

    Returns
    -------
    (N, 2) array of distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = dist
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.column_stack([xd, yd])


def max_monotonic_radius(dist: np.ndarray) -> float:
    """Largest normalised radius up to which the radial distortion is monotonic.

    The distorted radius ``r_d = r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` increases with ``r``
    while ``1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 > 0``. Beyond the first root the polynomial
    folds back and a projected point can land on the image at a wrong place; such points are
    flagged by :meth:`Camera.project`.

    Returns
    -------
    float
        The radius (normalised units, i.e. ``tan`` of the off-axis angle), ``inf`` when the
        polynomial is monotonic everywhere.
    """
    k1, k2, _, _, k3 = (float(d) for d in dist)
    coeffs = [7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0]  # in s = r^2, highest power first
    while coeffs and coeffs[0] == 0.0:
        coeffs.pop(0)
    if len(coeffs) <= 1:
        return math.inf
    roots = np.roots(coeffs)
    real = roots[np.abs(roots.imag) < 1e-12 * np.maximum(1.0, np.abs(roots))].real
    real = real[real > 0]
    return float(np.sqrt(real.min())) if real.size else math.inf


def undistort_normalized(
    xy_d: np.ndarray, dist: np.ndarray, *, iterations: int = 50, tol: float = 1e-15
) -> np.ndarray:
    """Invert :func:`distort_normalized` by vectorised Newton iterations.

    Each point iterates until its Newton step falls below ``tol`` (relative); the others
    stop early. Points whose inverse does not converge, or lies beyond
    :func:`max_monotonic_radius`, are returned as NaN.
    """
    xy_d = np.asarray(xy_d, dtype=np.float64)
    k1, k2, p1, p2, k3 = dist
    if not np.any(dist):
        return xy_d.copy()
    xd_all = np.ascontiguousarray(xy_d[:, 0])
    yd_all = np.ascontiguousarray(xy_d[:, 1])
    xs, ys = xd_all.copy(), yd_all.copy()
    active = np.flatnonzero(np.isfinite(xd_all) & np.isfinite(yd_all))  # still iterating
    for it in range(iterations):
        if active.size == 0:
            break
        full = it == 0 and active.size == xs.size  # avoid gathers while all points move
        x, y = (xs, ys) if full else (xs[active], ys[active])
        xd, yd = (xd_all, yd_all) if full else (xd_all[active], yd_all[active])
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d(radial)/d(r2)
        rx = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        ry = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        j11 = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
        j12 = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y
        j22 = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x
        det = j11 * j22 - j12 * j12  # the Jacobian is symmetric
        with np.errstate(divide="ignore", invalid="ignore"):
            dx = (j22 * rx - j12 * ry) / det
            dy = (j11 * ry - j12 * rx) / det
        x = x - dx
        y = y - dy
        xs[active] = x
        ys[active] = y
        step = np.maximum(np.abs(dx), np.abs(dy))
        active = active[~(step <= tol * (1.0 + np.maximum(np.abs(x), np.abs(y))))]
    xy = np.column_stack([xs, ys])
    res = np.abs(distort_normalized(xy, dist) - xy_d).max(axis=1)
    r = np.hypot(xy[:, 0], xy[:, 1])
    bad = ~(res < 1e-9) | (r > max_monotonic_radius(dist))
    xy[bad] = np.nan
    return xy
