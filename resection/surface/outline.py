"""The outline of a model as a picture should draw it: silhouettes and creases only.

A grid's edges fall in three kinds:

* **creases**: edges between two faces whose normals differ by more than a dihedral angle
  (``crease_deg``): the block's corners, a wing's trailing edge;
* **boundaries**: edges of one face only (free edges of an open surface), drawn too,
  except where another face's boundary edge lies on them: that is an interface between
  grid blocks whose nodes were not merged, not an edge of the model;
* **silhouettes** (for a camera): edges between a face turned towards the camera and one
  turned away.

Edges between faces of different grid blocks across a smooth surface are none of these: the
block structure of a Plot3D grid is never drawn.
"""

from __future__ import annotations

import numpy as np
import trimesh

from resection.camera.model import Camera
from resection.errors import InputError
from resection.surface.visibility import RayCaster

__all__ = ["outline_edges", "visible_segments"]


def _edge_keys(points: np.ndarray, scale: float) -> np.ndarray:
    """Order-free keys of segments (E, 2, 3) from their end points rounded to ``scale``."""
    q = np.rint(points / scale).astype(np.int64)
    a, b = q[:, 0], q[:, 1]
    less = _lex_less(a, b)[:, None]
    return np.concatenate([np.where(less, a, b), np.where(less, b, a)], axis=1)


def _lex_less(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise lexicographic ``a < b`` for (N, 3) integer arrays."""
    diff = a != b
    first = np.argmax(diff, axis=1)
    rows = np.arange(len(a))
    return diff.any(axis=1) & (a[rows, first] < b[rows, first])


def outline_edges(mesh: trimesh.Trimesh, crease_deg: float = 30.0, *,
                  camera: Camera | None = None, boundaries: bool = True) -> np.ndarray:
    """Segments worth drawing as the model's outline.

    Parameters
    ----------
    mesh : trimesh.Trimesh
    crease_deg : float
        Dihedral angle (degrees, between the two faces' normals) above which an edge is a
        crease.
    camera : Camera, optional
        Add the silhouette edges seen from its perspective centre.
    boundaries : bool
        Include the free edges of the surface (those not matched by another face's free
        edge at the same place: block interfaces are left out).

    Returns
    -------
    (E, 2, 3) float64
        Segments in model coordinates.
    """
    if not 0.0 <= crease_deg <= 180.0:
        raise InputError(f"crease_deg must be in [0, 180] degrees, got {crease_deg}")
    V = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1).astype(np.int64)
    # the edges as one integer each (a, b) -> a nV + b: the same sorted unique rows as
    # np.unique(axis=0), a sort of integers instead of rows (a tenth of the time)
    nV = max(len(V), 1)
    ukey, inv, counts = np.unique(edges[:, 0] * nV + edges[:, 1], return_inverse=True,
                                  return_counts=True)
    uniq = np.column_stack([ukey // nV, ukey % nV])
    keep = np.zeros(len(uniq), dtype=bool)
    n = np.asarray(mesh.face_normals, dtype=np.float64)
    front = None
    if camera is not None:
        cen = V[faces].mean(axis=1)
        front = np.einsum("ij,ij->i", n, camera.center[None, :] - cen) > 0
    cos_lim = np.cos(np.radians(crease_deg))
    if boundaries:
        free = np.flatnonzero(counts == 1)
        if free.size:
            # free edges that coincide with another free edge (nodes of neighbouring grid
            # blocks not merged) are drawn only where the two faces make a crease or a
            # silhouette: elsewhere they are a block interface
            owner = np.empty(len(uniq), dtype=np.int64)
            owner[inv.ravel()] = np.arange(len(edges)) // 3
            span = float(np.ptp(V, axis=0).max()) or 1.0
            keys = _edge_keys(V[uniq[free]], span * 1e-7)
            _, kinv, kcount = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
            kinv = kinv.ravel()
            mult = kcount[kinv]
            draw = mult != 2
            pair = np.flatnonzero(mult == 2)
            if pair.size:
                order = pair[np.argsort(kinv[pair], kind="stable")]
                f1, f2 = owner[free[order[0::2]]], owner[free[order[1::2]]]
                sharp = np.einsum("ij,ij->i", n[f1], n[f2]) < cos_lim
                if front is not None:
                    sharp |= front[f1] != front[f2]
                draw[order[0::2]] = sharp  # one segment of the two
            keep[free[draw]] = True
    adj = np.asarray(mesh.face_adjacency)
    if len(adj):
        adj_edges = np.sort(np.asarray(mesh.face_adjacency_edges), axis=1)
        sel = np.asarray(mesh.face_adjacency_angles) > np.radians(crease_deg)
        if front is not None:
            sel |= front[adj[:, 0]] != front[adj[:, 1]]
        if sel.any():
            nv = len(V) + 1
            key_u = uniq[:, 0] * nv + uniq[:, 1]
            key_s = adj_edges[sel, 0] * nv + adj_edges[sel, 1]
            keep |= np.isin(key_u, key_s)
    return V[uniq[keep]]


def visible_segments(mesh: trimesh.Trimesh, camera: Camera, segments, *,
                     samples: int = 3, caster: RayCaster | None = None) -> np.ndarray:
    """(E,) bool: segments not hidden by the model from ``camera`` (a majority of
    ``samples`` points along each, strictly inside it, reached by the camera's ray before
    any other surface, within 0.1 % of the distance) and in front of it."""
    seg = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 3)
    if len(seg) == 0:
        return np.zeros(0, dtype=bool)
    caster = RayCaster(mesh) if caster is None else caster
    s = (np.arange(samples) + 0.5) / samples
    P = seg[:, None, 0, :] + s[None, :, None] * (seg[:, None, 1, :] - seg[:, None, 0, :])
    P = P.reshape(-1, 3)
    d = P - camera.center[None, :]
    dist = np.linalg.norm(d, axis=1)
    _, hit, _ = caster.first_hit(camera.center, d / dist[:, None])
    tol = 1e-3 * dist + 1e-9
    seen = ~(np.isfinite(hit) & (hit < dist - tol))
    seen &= camera.to_camera_frame(P)[:, 2] > 0
    return seen.reshape(len(seg), samples).sum(axis=1) * 2 > samples
