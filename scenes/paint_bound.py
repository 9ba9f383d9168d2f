"""Cramér-Rao bound of each target's centre in a frame of :mod:`scenes.revolution`.

The bound is taken from the frame as the generator renders it (noise-free,
:meth:`RevolutionModel.render`): the derivatives of the rendered pixels with respect to the
target's centre and to the nuisance parameters are central differences of whole renders in
which every target is moved (or resized, tilted, deepened) at once. Targets lie farther
apart than their windows, so each window sees only its own target's change. Under white
Gaussian noise of standard deviation ``s`` (the generator's, with the 8-bit rounding's
``1/12`` count² added), the Fisher matrix of a window is ``J^T J / s^2`` and the bound on
the centre's covariance is the ``(u, v)`` block of its inverse.

Parameters of a target, in the columns of ``J`` (:data:`PARAMETERS`):

* ``u, v``: the centre's image (pixels): the painted dot moved in its tangent plane by the
  displacement whose projection is one pixel along ``u`` or ``v``;
* ``depth``: the dot's relative depth (the render is linear in it);
* ``size``: the dot's diameter;
* ``tilt1, tilt2``: the dot's normal turned about its two tangent axes (the ellipse's
  shape and orientation);
* ``b0, bu, bv``: an additive background plane (the disk fit's own background model);
* ``mu, mv``: the paint's shading across the window as a multiplicative plane (the frame
  less the glare, times ``u`` or ``v`` from the window's centre): the dot's depth follows
  the shading, which a uniform-disk fit on an additive plane does not model.

Nested sets of unknowns (:data:`SETS`): ``known`` (the centre only), ``fit`` (the disk
fit's unknowns: centre, depth, size, additive plane; the shape known), ``shape`` (plus the
two tilts: an estimator that does not know the ellipse), ``shading`` (plus the depth's
gradient).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["PARAMETERS", "SETS", "fisher_bounds", "target_bounds", "median_at_bound"]

PARAMETERS = ("u", "v", "depth", "size", "tilt1", "tilt2", "b0", "bu", "bv", "mu", "mv")
SETS = {
    "known": ("u", "v"),
    "fit": ("u", "v", "depth", "size", "b0", "bu", "bv"),
    "shape": ("u", "v", "depth", "size", "tilt1", "tilt2", "b0", "bu", "bv"),
    "shading": PARAMETERS,
}


def fisher_bounds(J: np.ndarray, weights: np.ndarray, sigma: float, columns) -> np.ndarray:
    """Bound on the centre's covariance from a batch of window Jacobians.

    Parameters
    ----------
    J : (n, P, K) array
        Derivatives of the ``P`` pixels of ``n`` windows with respect to ``K`` parameters,
        the first two the centre's ``u`` and ``v`` (counts per unit).
    weights : (n, P) array
        1 for the pixels that count, 0 for the others.
    sigma : float
        Noise standard deviation, counts.
    columns : sequence of int
        The parameters estimated (must include 0 and 1, first).

    Returns
    -------
    (n, 2, 2) array
        Covariance bound of ``(u, v)``, pixels².
    """
    Jc = J[:, :, list(columns)] * weights[:, :, None]
    F = np.swapaxes(Jc, 1, 2) @ Jc / sigma**2
    return np.linalg.inv(F)[:, :2, :2]


def _tangent_basis(N):
    """Two unit vectors perpendicular to each normal of ``N`` (n, 3)."""
    a = np.where(np.abs(N[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(N, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(N, e1)


def target_bounds(model, k: int = 0, targets=None, *, step_px: float = 0.1,
                  size_step: float = 0.02, tilt_step: float = 0.02,
                  supersample: int = 32) -> dict:
    """Per-target bound of the centre in frame ``k`` of ``model`` (a ``RevolutionModel``).

    Parameters
    ----------
    model : scenes.revolution.RevolutionModel
    k : int
        Frame.
    targets : (N,) bool array, optional
        The targets to bound (default: those drawn, ``model.visible(k)``).
    step_px, size_step, tilt_step : float
        Half-steps of the central differences: the centre (pixels), the diameter
        (relative), the normal's tilt (radians).
    supersample : int
        Sub-samples along a pixel's side of the renders (the frame's own, 16 in
        ``paint_frame``, makes the differences of a 0.1 px move step-wise).

    Returns
    -------
    dict
        ``uv`` (N, 2) true centres; ``cov`` dict set name -> (N, 2, 2) bound (px²);
        ``drawn`` (N,) the targets' depth as drawn (counts, ``drawn_depth``); ``peak`` (N,)
        their depth in the noise-free frame (the largest difference from the same frame
        without the targets within the window: blur and pixel integration included);
        ``sigma`` the noise (counts, rounding included); ``saturated`` (N,) bool, a window
        with a pixel at or above 254.5 counts; ``half`` the windows' half-size (pixels).
    """
    vis = model.visible(k)
    sel = vis if targets is None else np.asarray(targets, bool) & vis
    m = dataclasses.replace(model, supersample=int(supersample))
    cam = m.camera_at(k)
    P, N = m.points3d.copy(), m.normals.copy()
    e1, e2 = _tangent_basis(N)
    # the tangent displacement per pixel of image motion: the inverse of the projection's
    # 2 x 2 Jacobian in the tangent plane (numerical, 1e-6 m)
    eps = 1e-6
    Ju = (cam.project(P + eps * e1) - cam.project(P - eps * e1)) / (2 * eps)
    Jv = (cam.project(P + eps * e2) - cam.project(P - eps * e2)) / (2 * eps)
    Jt = np.stack([Ju, Jv], axis=-1)  # (n, 2 image, 2 tangent)
    Jinv = np.linalg.inv(Jt)
    T = np.stack([e1, e2], axis=-1)  # (n, 3, 2)
    move = T @ Jinv  # (n, 3, 2): metres per pixel of u and v

    def render(**kw):
        return dataclasses.replace(m, **kw).render(k).astype(np.float64)

    base = render()
    cols = {}
    for j, name in enumerate(("u", "v")):
        dP = step_px * move[:, :, j]
        cols[name] = (render(points3d=P + dP) - render(points3d=P - dP)) / (2 * step_px)
    flat = render(target_depth=0.0)
    cols["depth"] = (base - flat) / m.target_depth
    d0 = m.marker_diameter
    cols["size"] = (render(marker_diameter=d0 * (1 + size_step))
                    - render(marker_diameter=d0 * (1 - size_step))) / (2 * size_step)
    for name, e in (("tilt1", e1), ("tilt2", e2)):
        Np = N + tilt_step * e
        Nm = N - tilt_step * e
        Np /= np.linalg.norm(Np, axis=1, keepdims=True)
        Nm /= np.linalg.norm(Nm, axis=1, keepdims=True)
        cols[name] = (render(normals=Np) - render(normals=Nm)) / (2 * tilt_step)
    glare = m._static()[2].astype(np.float64)
    shaded = base - glare

    uv = cam.project(P[sel])
    R = 0.5 * d0 * m.px_per_m
    half = int(np.ceil(R + 4.0 * m.blur + 3.0))
    off = np.arange(-half, half + 1)
    dv, du = np.meshgrid(off, off, indexing="ij")
    inside = (np.hypot(du, dv) <= half + 0.5).ravel()
    c0 = np.rint(uv).astype(int)
    H, W = base.shape
    vv = np.clip(c0[:, 1, None, None] + dv[None], 0, H - 1)
    uu = np.clip(c0[:, 0, None, None] + du[None], 0, W - 1)
    n = len(uv)

    def win(a):
        return a[vv, uu].reshape(n, -1)

    ones = np.ones((n, inside.size))
    du_, dv_ = (np.broadcast_to(x.ravel(), (n, inside.size)) for x in (du, dv))
    J = np.stack([win(cols["u"]), win(cols["v"]), win(cols["depth"]), win(cols["size"]),
                  win(cols["tilt1"]), win(cols["tilt2"]), ones, du_, dv_,
                  win(shaded) * du_, win(shaded) * dv_], axis=-1)
    weights = np.broadcast_to(inside, (n, inside.size)).astype(float)
    sigma = float(np.sqrt(m.noise_sigma**2 + 1.0 / 12.0))
    cov = {name: fisher_bounds(J, weights, sigma, [PARAMETERS.index(p) for p in cols_])
           for name, cols_ in SETS.items()}
    peak = np.max((win(flat) - win(base)) * inside, axis=1)
    saturated = np.any((win(base) >= 254.5) & inside, axis=1)
    return {"uv": uv, "cov": cov, "drawn": m.drawn_depth(k)[sel], "peak": peak,
            "sigma": sigma, "saturated": saturated, "half": half}


def median_at_bound(cov: np.ndarray, draws: int = 4000, seed: int = 0) -> float:
    """Median of ``|e|`` pooled over targets, each ``e`` drawn from ``N(0, cov[i])``: the
    median error of an unbiased estimator on the bound (pixels)."""
    rng = np.random.default_rng(seed)
    L = np.linalg.cholesky(cov)  # (n, 2, 2)
    z = rng.standard_normal((len(cov), 2, draws))
    e = L @ z
    return float(np.median(np.hypot(e[:, 0], e[:, 1])))
