"""Perspective-3-point: every pose that puts three model points on three lines of sight.

Grunert's formulation: the three distances along the rays are eliminated down to a quartic,
solved as a companion-matrix eigenproblem for many triplets at once, then the model triangle
is aligned with the camera-frame triangle (Kabsch). Used by :func:`resection.pose.solve.solve_pose`
for its starts.
"""

from __future__ import annotations

import numpy as np

from resection._checks import as_points
from resection.errors import DegenerateError, InputError

__all__ = ["p3p"]


def _pmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Products of polynomials, row by row (ascending coefficients on the last axis)."""
    out = np.zeros(a.shape[:-1] + (a.shape[-1] + b.shape[-1] - 1,))
    for i in range(a.shape[-1]):
        out[..., i:i + b.shape[-1]] += a[..., i:i + 1] * b
    return out


def _pval(c: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Values of polynomials ``c (T, k)`` at ``x (T, m)`` (Horner)."""
    out = np.zeros(x.shape, dtype=np.result_type(c, x))
    for i in range(c.shape[-1] - 1, -1, -1):
        out = out * x + c[..., i:i + 1]
    return out


def p3p_batch(X: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P3P for T triplets at once: ``X (T, 3, 3)`` model points, ``b (T, 3, 3)`` unit
    bearings. Returns ``R (M, 3, 3)``, ``t (M, 3)`` and the triplet index ``(M,)`` of the
    solutions that put their three points in front of the camera."""
    T = len(X)
    ca = np.einsum("ti,ti->t", b[:, 1], b[:, 2])
    cb = np.einsum("ti,ti->t", b[:, 0], b[:, 2])
    cg = np.einsum("ti,ti->t", b[:, 0], b[:, 1])
    a = np.linalg.norm(X[:, 1] - X[:, 2], axis=1)
    bb = np.linalg.norm(X[:, 0] - X[:, 2], axis=1)
    c = np.linalg.norm(X[:, 0] - X[:, 1], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        a2, c2 = (a / bb) ** 2, (c / bb) ** 2
    one = np.ones(T)
    # Grunert: s2 = u s1, s3 = v s1; eliminating s1 and u leaves a quartic in v
    W = np.stack([one, -2.0 * cb, one], axis=1)
    Q = np.stack([-one, 0 * one, one], axis=1) + (c2 - a2)[:, None] * W
    D = np.stack([2.0 * cg, -2.0 * ca], axis=1)
    quartic = (_pmul(Q, Q) + np.pad(2.0 * cg[:, None] * _pmul(Q, D), ((0, 0), (0, 1)))
               + _pmul(np.stack([1 - c2, 2 * c2 * cb, -c2], axis=1), _pmul(D, D)))
    lead = quartic[:, 4]
    ok = (np.isfinite(quartic).all(axis=1) & (np.abs(lead) > 1e-12 * np.abs(quartic).max(1))
          & (a > 0) & (bb > 0) & (c > 0))
    roots = np.full((T, 4), np.nan + 0j)
    if ok.any():
        comp = np.zeros((int(ok.sum()), 4, 4))
        comp[:, 1:, :3] = np.eye(3)
        comp[:, :, 3] = -quartic[ok, :4] / lead[ok, None]
        roots[ok] = np.linalg.eigvals(comp)
    real = np.abs(roots.imag) <= 1e-3 * (1.0 + np.abs(roots))
    v = roots.real
    with np.errstate(divide="ignore", invalid="ignore"):
        d = _pval(D, v)
        u = -_pval(Q, v) / d
        den = 1.0 + u * u - 2.0 * u * cg[:, None]
        s1 = c[:, None] / np.sqrt(den)
    good = real & (v > 0) & (np.abs(d) > 1e-12) & (u > 0) & (den > 0) & np.isfinite(s1)
    ti, ri = np.nonzero(good)
    if ti.size == 0:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, int)
    s = s1[ti, ri]
    P = np.stack([s[:, None] * b[ti, 0], (u[ti, ri] * s)[:, None] * b[ti, 1],
                  (v[ti, ri] * s)[:, None] * b[ti, 2]], axis=1)  # (M, 3, 3) camera frame
    Xs = X[ti]
    cx, cp = Xs.mean(axis=1), P.mean(axis=1)
    Hm = np.einsum("mki,mkj->mij", Xs - cx[:, None], P - cp[:, None])
    U, _, Vt = np.linalg.svd(Hm)
    det = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    det[det == 0] = 1.0
    Dg = np.zeros((len(ti), 3, 3))
    Dg[:, 0, 0] = Dg[:, 1, 1] = 1.0
    Dg[:, 2, 2] = det
    R = np.swapaxes(Vt, 1, 2) @ Dg @ np.swapaxes(U, 1, 2)
    t = cp - np.einsum("mij,mj->mi", R, cx)
    z = np.einsum("mkj,mij->mki", Xs, R)[..., 2] + t[:, None, 2]
    front = np.all(z > 0, axis=1)
    return R[front], t[front], ti[front]


def p3p(points3d, bearings) -> list[tuple[np.ndarray, np.ndarray]]:
    """All poses that put three model points on three lines of sight (perspective-3-point).

    Eliminates the three distances along the rays (Grunert's formulation) down to a quartic,
    solved as a companion-matrix eigenproblem, then aligns the model triangle with the
    camera-frame triangle.

    Parameters
    ----------
    points3d : (3, 3) array
        Model points.
    bearings : (3, 3) array
        Directions of their lines of sight in the camera frame (need not be unit).

    Returns
    -------
    list of ``(R, t)`` with ``x_cam = R X + t`` and the three points in front of the camera
    (up to four).
    """
    X = as_points(points3d, 3, "points3d")
    b = as_points(bearings, 3, "bearings")
    if len(X) != 3 or len(b) != 3:
        raise InputError("p3p: needs exactly three points and three bearings")
    if min(np.linalg.norm(X[1] - X[2]), np.linalg.norm(X[0] - X[2]),
           np.linalg.norm(X[0] - X[1])) <= 0:
        raise DegenerateError("p3p: two of the three points coincide")
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    R, t, _ = p3p_batch(X[None], b[None])
    return list(zip(R, t, strict=True))

