"""Brown-Conrady lens distortion on normalised coordinates (OpenCV order).

``dist = [k1, k2, p1, p2, k3]`` acts on ``(x, y) = (X/Z, Y/Z)`` in the camera frame (x right,
y down): :func:`distort_normalized` applies it, :func:`undistort_normalized` inverts it inside
the radius where the radial factor is monotonic (:func:`max_monotonic_radius`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["distort_normalized", "undistort_normalized", "max_monotonic_radius",
           "lens_problem"]

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


def lens_problem(dist, K, width: int, height: int) -> str | None:
    """What makes ``dist`` no lens for an image of ``width`` x ``height`` through ``K``, or
    None.

    A lens maps every pixel of its image to one line of sight, and a real one bends the
    lines of sight of the image's corners by less than a factor of ten:

    * the radial polynomial ``g(r) = r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` must not fold back
      (:func:`max_monotonic_radius`) before it reaches the image's farthest corner, at
      distorted normalised radius ``R``;
    * the corner's line of sight ``r`` (``g(r) = R``) must lie within ``R / 10`` and
      ``10 R``: ``g(R / 10) <= R <= g(min(10 R, fold))``;
    * the tangential terms must not move the corner by more than half its radius (real
      lenses: a few thousandths).

    Coefficients such as 1e300 (a wrong unit, an order other than OpenCV's) fail one.

    Parameters
    ----------
    dist : (5,) array_like
        ``[k1, k2, p1, p2, k3]``.
    K : (3, 3) array_like
        Intrinsics (pixels).
    width, height : int
        Image size (pixels).

    Returns
    -------
    str or None
        A sentence naming the problem (no file name), or None for a plausible lens.
    """
    d = np.asarray(dist, dtype=np.float64).ravel()
    K = np.asarray(K, dtype=np.float64)
    u = np.array([-0.5, width - 0.5, width - 0.5, -0.5])
    v = np.array([-0.5, -0.5, height - 0.5, height - 0.5])
    y = (v - K[1, 2]) / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * y) / K[0, 0]
    reach = float(np.hypot(x, y).max())  # the farthest corner, distorted normalised radius
    k1, k2, p1, p2, k3 = d
    rmax = max_monotonic_radius(d)
    unit = " not a lens (coefficients in another unit or order?)"

    def g(r):
        s = r * r
        return r * (1.0 + s * (k1 + s * (k2 + s * k3)))

    with np.errstate(over="ignore", invalid="ignore"):
        top = g(min(10.0 * reach, rmax))  # the largest radius it reaches, up to 10 R
        if not (np.isfinite(top) and top >= reach):
            where = (f"folds back at normalised radius {rmax:.3g}" if rmax < 10.0 * reach
                     else f"reaches radius {top:.3g} at 10 times the corner's")
            return (f"distortion {d.tolist()} {where}, inside the {width}x{height} image "
                    f"(its corners at {reach:.3g}):{unit}")
        low = g(min(reach / 10.0, rmax))
        if not (np.isfinite(low) and low <= reach):
            return (f"distortion {d.tolist()} bends a tenth of the corner's line of sight "
                    f"({reach / 10:.3g}) out to {low:.3g}, beyond the {width}x{height} "
                    f"image's corners ({reach:.3g}):{unit}")
        shift = 3.0 * (abs(p1) + abs(p2)) * reach * reach  # tangential, at the corner
        if not (np.isfinite(shift) and shift <= 0.5 * reach):
            return (f"distortion {d.tolist()}: the tangential terms p1, p2 move the image's "
                    f"corners by {shift / max(reach, 1e-300):.3g} of their radius:{unit}")
    return None
