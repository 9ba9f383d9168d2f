"""The radiometric balance at the grid's nodes: what the camera sees of a node is its own
emission plus the reflection of what lights it, the tunnel's walls and the model's other
parts.

For a grey opaque surface (Kirchhoff: directional reflectance ``1 - eps(theta)``), in the
camera's signal units ``U = S - O`` (:mod:`selfillum.thermal.radiometry`)::

    M = eps(theta) U(T) + (1 - eps(theta)) H,    H = F J + f_wall U(T_wall)

``F`` the view factors between the model's faces, ``f_wall = 1 - sum_j F_ij`` the part of
the hemisphere that sees the walls, ``J`` the radiosity leaving the other faces. The camera
measures ``J`` where it sees them (taken as diffuse: the radiance leaving a face toward
another face is the one the camera sees; the faces it does not see take the radiosity of
a full solve of the first frame, :class:`selfillum.unsteady.phase1.SelfIllumination`).
Phase 1 stores the node values with and without ``rho F M`` removed (``rho = 1 - eps_h``,
the hemispherical reflectance), so ``F M = (raw - values) / rho`` per node and the balance
is solved per node without a system.

The view angle of a node in a frame is that of its (area-weighted) normal to the camera's
centre in that frame's pose; with several cameras, the camera that sees it most squarely
(exact for one camera and for ``overlap = best_view``; an approximation for
``average_view``, whose node value mixes the cameras' views).

A directional emissivity is taken at each pixel's view angle on the map
(:func:`pixel_emissivity`): a node's value is the area-weighted mean of the faces around it
that the camera sees, each face's the mean of the pixels on it, and the pixels on a face
see it along one line of sight (a face is small against the camera's distance). As ``M``
is linear in ``eps``, the node's ``M`` is that of the faces' mean emissivity,
``eps_n = sum_f a_f eps(theta_f) / sum_f a_f`` over the faces seen (facing the camera
within the obliqueness cut-off; a face another part hides is counted where it faces the
camera: the ray cast's visibility is Phase 1's, not known here). Where the grid's faces
around a node are nearly coplanar this is the emissivity at the node's normal; at a crease
or on a coarse grid at grazing angles it is not (``bench/bench_thermal_view_angle.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["NodeGeometry", "camera_centres", "view_cosines", "pixel_emissivity"]


@dataclass(frozen=True)
class NodeGeometry:
    """Grid nodes' ``points`` (N, 3), unit ``normals`` (N, 3) and ``wall`` (N,): the share
    of the hemisphere that sees the tunnel (1 where no view factors are used); the faces'
    unit ``face_normals`` and ``face_centres`` (F, 3), and ``node_faces`` (N, F) sparse:
    each face's area at its three nodes (the weights of a node's mean of its faces)."""

    points: np.ndarray
    normals: np.ndarray
    wall: np.ndarray
    face_normals: np.ndarray | None = None
    face_centres: np.ndarray | None = None
    node_faces: object = None

    @classmethod
    def from_grid(cls, grid, F=None) -> NodeGeometry:
        """Normals: the area-weighted mean of the faces' normals around each node (in the
        grid's own orientation: the view angle takes its absolute cosine);
        ``wall`` from the faces' row sums of ``F``, area-weighted to the nodes."""
        import scipy.sparse as sp

        mesh = grid.mesh
        faces = np.asarray(mesh.faces, dtype=np.int64)
        area = np.asarray(mesh.area_faces, dtype=np.float64)
        nf, nv = len(faces), len(mesh.vertices)
        W = sp.csr_matrix((np.repeat(area, 3), (faces.ravel(), np.repeat(np.arange(nf), 3))),
                          shape=(nv, nf))
        n = W @ np.asarray(mesh.face_normals, dtype=np.float64)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        if F is None:
            wall = np.ones(nv)
        else:
            rs = np.asarray(F.sum(axis=1)).ravel()
            wall = np.clip(1.0 - (W @ rs) / np.maximum(W @ np.ones(nf), 1e-300), 0.0, 1.0)
        return cls(np.asarray(grid.points, float), grid.to_nodes(n.T).T, grid.to_nodes(wall),
                   np.asarray(mesh.face_normals, dtype=np.float64),
                   np.asarray(mesh.triangles_center, dtype=np.float64),
                   sp.csr_matrix(W[np.asarray(grid.node_vertex)]))


def camera_centres(R, t) -> np.ndarray:
    """``(C, T, 3)`` camera centres ``-R^T t`` from poses ``R`` (C, T, 3, 3), ``t`` (C, T, 3)
    (``x_cam = R X + t``, model units)."""
    return -np.einsum("ctji,ctj->cti", np.asarray(R, float), np.asarray(t, float))


def view_cosines(centres, points, normals) -> np.ndarray:
    """``(T, n)`` cosine of each node's view angle in each frame, the largest over the
    cameras (``centres`` (C, T, 3); ``points``, ``normals`` (n, 3)). Its absolute value,
    as :func:`resection.surface.surface_map.oblique_faces` takes it: a grid's faces may
    point in or out, and whether a node is seen at all is the ray cast's answer (Phase 1)."""
    p = np.asarray(points, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    pn = np.einsum("nk,nk->n", p, n)
    pp = np.einsum("nk,nk->n", p, p)
    best = None
    for C in np.asarray(centres, dtype=np.float64):  # a few cameras
        # (C - p).n and |C - p|^2 by products of (T, 3) and (3, n): no (T, n, 3) array
        dn = C @ n.T - pn
        d2 = np.einsum("tk,tk->t", C, C)[:, None] - 2.0 * (C @ p.T) + pp
        c = np.abs(dn) / np.sqrt(np.maximum(d2, 1e-300))
        best = c if best is None else np.maximum(best, c)
    return np.clip(best, 0.0, 1.0)


def pixel_emissivity(emissivity, centres, geom: NodeGeometry, nodes, cosines,
                     max_obliqueness: float) -> np.ndarray:
    """``(T, n)`` emissivity of the nodes ``nodes`` in each frame at each pixel's view angle
    on the map (module notes): the area-weighted mean, over the faces around each node that
    the camera sees (facing it, within ``max_obliqueness`` degrees), of the emissivity at
    each face's view angle; with several cameras, that of the camera whose view of the
    node is the squarest (as ``cosines``, :func:`view_cosines`, the node's (T, n)). A node
    none of whose faces passes is given the emissivity at its own view angle.

    Parameters
    ----------
    emissivity : Emissivity
        Its ``of_cosine``.
    centres : (C, T, 3) array
        The cameras' centres (:func:`camera_centres`).
    geom : NodeGeometry
        With its faces (:meth:`NodeGeometry.from_grid`).
    nodes : (n,) int array
    cosines : (T, n) array
        The nodes' view cosines.
    max_obliqueness : float
        Degrees.
    """
    nodes = np.asarray(nodes, dtype=np.int64)
    A = geom.node_faces[nodes]  # (n, F) areas
    used = np.unique(A.indices)
    A = A[:, used].tocsr()  # (n, m)
    fn, fc = geom.face_normals[used], geom.face_centres[used]
    fcn = np.einsum("mk,mk->m", fc, fn)
    fcc = np.einsum("mk,mk->m", fc, fc)
    lo = np.cos(np.radians(max_obliqueness))
    best = None
    out = None
    for C in np.asarray(centres, dtype=np.float64):  # a few cameras
        dn = C @ fn.T - fcn  # (T, m): (C - c).n, the faces' front toward the camera
        d2 = np.einsum("tk,tk->t", C, C)[:, None] - 2.0 * (C @ fc.T) + fcc
        c = dn / np.sqrt(np.maximum(d2, 1e-300))
        w = (c > lo).astype(np.float64)  # (T, m) seen
        num = (A @ (w * emissivity.of_cosine(c)).T).T  # (T, n)
        den = (A @ w.T).T
        with np.errstate(invalid="ignore", divide="ignore"):
            eps = np.where(den > 0, num / den, np.nan)
        if out is None:
            out = eps
            if len(centres) > 1:
                p, nn = geom.points[nodes], geom.normals[nodes]
                best = view_cosines(C[None], p, nn)
        else:
            cc = view_cosines(C[None], geom.points[nodes], geom.normals[nodes])
            take = cc > best
            out = np.where(take, eps, out)
            best = np.maximum(best, cc)
    own = np.isnan(out)
    if own.any():
        out[own] = emissivity.of_cosine(np.asarray(cosines)[own])
    return out
