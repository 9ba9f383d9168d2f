"""Starting poses for :func:`resection.solve_pose`: the P3P solutions of well-spread
marker triplets, the linear DLT for six or more non-coplanar markers, and the homography
of coplanar ones.

All take model points ``X`` ``(N, 3)`` (model units) and normalised image coordinates
``xy`` ``(N, 2)`` (undistorted, divided by the focal length), and return rotations ``R``
and translations ``t`` with ``x_cam = R X + t``.
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np

from resection.errors import InputError, SolveError
from resection.pose.dlt import fit_dlt, fit_homography
from resection.pose.three_point import p3p_batch


def pick_triplets(X: np.ndarray, uv: np.ndarray, max_triplets: int,
                  rng: np.random.Generator) -> list[tuple[int, int, int]]:
    n = len(X)
    scale = np.linalg.norm(X - X.mean(axis=0), axis=1).max()

    def ok(tri):
        a, b, c = X[list(tri)]
        return np.linalg.norm(np.cross(b - a, c - a)) > 1e-6 * scale**2

    if math.comb(n, 3) <= max_triplets:
        return [tri for tri in combinations(range(n), 3) if ok(tri)]
    d = uv - uv.mean(axis=0)
    i0 = int(np.argmax(np.einsum("ij,ij->i", d, d)))
    e = uv - uv[i0]
    i1 = int(np.argmax(np.einsum("ij,ij->i", e, e)))
    a, b = uv[i1] - uv[i0], uv - uv[i0]
    area = np.abs(a[0] * b[:, 1] - a[1] * b[:, 0])
    i2 = int(np.argmax(area))
    out = []
    if len({i0, i1, i2}) == 3 and ok((i0, i1, i2)):
        out.append(tuple(sorted((i0, i1, i2))))
    tries = 0
    while len(out) < max_triplets and tries < 20 * max_triplets:
        tries += 1
        tri = tuple(sorted(rng.choice(n, 3, replace=False).tolist()))
        if tri not in out and ok(tri):
            out.append(tri)
    return out


def initial_poses(X, xy, planar: bool, max_triplets: int):
    """Candidate (R, t) from P3P triplets, the DLT and the homography (normalised image
    coordinates ``xy``)."""
    n = len(X)
    bear = np.column_stack([xy, np.ones(n)])
    cands = []
    rng = np.random.default_rng(12345)
    tris = pick_triplets(X, xy, max_triplets, rng)
    if tris:
        idx = np.array(tris)
        bu = bear / np.linalg.norm(bear, axis=1, keepdims=True)
        Rs, ts, _ = p3p_batch(X[idx], bu[idx])
        cands.extend(zip(Rs, ts, strict=True))
    if n >= 6 and not planar:
        try:
            P = fit_dlt(X, xy)
            U, S, Vt = np.linalg.svd(P[:, :3])
            R = U @ Vt
            if np.linalg.det(R) > 0:
                cands.append((R, P[:, 3] / S.mean()))
        except InputError:
            pass
    if n >= 4 and planar:
        try:
            cands.append(pose_from_plane(X, xy))
        except (InputError, SolveError):
            pass
    return cands


def pose_from_plane(X: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose of coplanar model points ``X`` from their normalised image coordinates ``xy``
    through the plane's homography (``H ~ [R e1, R e2, R c + t]`` in plane axes)."""
    c = X.mean(axis=0)
    _, _, Vt = np.linalg.svd(X - c, full_matrices=False)
    E = Vt.T.copy()  # columns e1, e2, normal
    if np.linalg.det(E) < 0:
        E[:, 2] *= -1
    H = fit_homography((X - c) @ E[:, :2], xy)
    lam = 0.5 * (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    if H[2, 2] < 0:  # the centroid must be in front of the camera
        lam = -lam
    r1, r2, tc = H[:, 0] / lam, H[:, 1] / lam, H[:, 2] / lam
    U, _, Vt2 = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    Rc = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt2))]) @ Vt2
    R = Rc @ E.T
    return R, tc - R @ c
