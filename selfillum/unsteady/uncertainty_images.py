"""Per-node quantities of ``selfillum unsteady --uncertainty`` taken through Phase 1's own
mapping: images made from frame 0 (its intensity times a pixel's surface coordinates, or
times its displacement under a pose perturbation) are mapped onto the nodes by
:func:`selfillum.unsteady.phase1.map_run` with the run's options (dark spots masked or
patched, the cameras' merge weights and gains, the filter), so that a node's weights of
its pixels are exactly those its intensity gets in the run.

* :func:`support_moments`: the first and second moments, about each node, of the surface
  points of the pixels its value averages, weighted by their share of the node's intensity
  (:mod:`selfillum.uncertainty.mapping`);
* :func:`pose_sensitivity`: per camera, the relative change of each node's intensity per
  unit pose perturbation ``theta = (w, dt)`` (:mod:`selfillum.uncertainty.registration`):
  a frame sampled where the surface points project with a perturbed pose reads the image
  ``du = J theta`` pixels away, ``dI = grad I . du``.

Phase 1 is linear in the pixels without the self-illumination removal (``si=None`` here):
the weights are those of the node intensity before it (the reflected light's share of a
pixel counts as paint, a small difference away from concave corners).
"""

from __future__ import annotations

import numpy as np

__all__ = ["support_moments", "pose_sensitivity", "mapped"]


def mapped(grid, runs, images, chain: dict, cfg) -> np.ndarray:
    """(K, N) node values of ``images`` (per camera a list of K (H, W) images, the first
    of each being frame 0's, whose merge gains the others keep) mapped as the run's frame
    0 (its pose: ``registration="none"``), without the self-illumination removal."""
    from selfillum.unsteady.phase1 import CameraRun, map_run

    K = len(images[0])
    cams = [CameraRun(r.number, r.camera, imgs, None)
            for r, imgs in zip(runs, images, strict=True)]
    out = np.full((K, grid.n_nodes), np.nan)
    for fn in map_run(grid, cams, list(range(K)), spots=chain.get("spots"),
                      registration="none", patcher=cfg.target_patcher, overlap=cfg.overlap,
                      filter=cfg.filter, filter_size=cfg.filter_size,
                      max_obliqueness=cfg.oblique_angle, si=None,
                      unpainted=chain.get("unpainted"), fast=True):
        out[int(fn.index)] = np.asarray(fn.values, np.float64)
    return out


def _filled_points(smap) -> np.ndarray:
    """(H, W, 3) each pixel's surface point; a pixel off the model takes its nearest
    model pixel's (a dark spot's ring on the silhouette samples the background: it stays
    close to the node)."""
    from scipy import ndimage

    X = np.asarray(smap.points, np.float64).reshape(smap.shape + (3,))
    bad = ~np.isfinite(X[..., 0])
    if bad.all():
        return np.zeros_like(X)
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return X[idx[0], idx[1]]


def support_moments(grid, runs, maps, frame0, chain: dict, cfg, extra=None):
    """``(delta, Q, extra_nodes)``: (N, 3) first and (N, 3, 3) second moments about each
    node of its pixels' surface points (frame 0's maps ``maps``), each pixel weighted by
    its share of the node's intensity in ``frame0`` (one image a camera), in one
    :func:`mapped` pass; NaN where no pixel counts. ``extra``: per camera a list of more
    images mapped in the same pass (their node values, divided by the node's intensity,
    come back as ``extra_nodes`` (E, N))."""
    c0 = np.asarray(grid.points, np.float64).mean(axis=0)  # centred: float32 products
    iu = np.triu_indices(3)
    images = []
    for c, (m, img) in enumerate(zip(maps, frame0, strict=True)):
        I0 = np.nan_to_num(np.asarray(img, np.float64))
        X = _filled_points(m) - c0
        imgs = [I0] + [I0 * X[..., a] for a in range(3)] \
            + [I0 * X[..., a] * X[..., b] for a, b in zip(*iu, strict=True)]
        if extra is not None:
            imgs += list(extra[c])
        images.append([np.asarray(i, np.float32) for i in imgs])
    V = mapped(grid, runs, images, chain, cfg)
    with np.errstate(invalid="ignore", divide="ignore"):
        R = V[1:] / V[0]
    x = np.asarray(grid.points, np.float64) - c0
    m1 = R[:3].T
    Q = np.empty((len(x), 3, 3))
    Q[:, iu[0], iu[1]] = R[3:9].T
    Q[:, iu[1], iu[0]] = R[3:9].T
    # about the node: E[(X - x)(X - x)^T] = E[X X^T] - x mu^T - mu x^T + x x^T
    Q = Q - x[:, :, None] * m1[:, None, :] - m1[:, :, None] * x[:, None, :] \
        + x[:, :, None] * x[:, None, :]
    return m1 - x, Q, R[9:]


def pose_images(smap, frame0) -> list:
    """Six (H, W) images ``grad I . d u / d theta_k`` of one camera: frame 0's central
    differences times each pixel's displacement per unit pose perturbation
    (:func:`selfillum.uncertainty.registration.pixel_jacobian`; 0 off the model)."""
    from selfillum.uncertainty.registration import pixel_jacobian

    I0 = np.nan_to_num(np.asarray(frame0, np.float64))
    gy, gx = np.gradient(I0)
    J = np.nan_to_num(pixel_jacobian(smap))  # (6, H, W, 2): du, dv
    return [gx * J[k, ..., 0] + gy * J[k, ..., 1] for k in range(6)]


def pose_sensitivity(sens, covariances) -> np.ndarray:
    """(N,) standard deviation of the node's relative intensity from the cameras' pose
    covariances: ``sens`` (C, 6, N) the mapped :func:`pose_images` over the node's
    intensity, ``covariances`` (C,) (6, 6) (None: that camera's pose held). The cameras'
    poses are independent."""
    var = 0.0
    for g, C in zip(sens, covariances, strict=True):
        if C is None:
            continue
        g = np.nan_to_num(np.asarray(g, np.float64))
        var = var + np.einsum("kn,kl,ln->n", g, np.asarray(C, np.float64), g)
    return np.sqrt(var)
