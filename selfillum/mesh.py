"""Triangle meshes as radiosity elements: checks, areas, normals, adjacency.

Every face of a :class:`trimesh.Trimesh` is one radiosity element. The *painted side* of
a face is the side its normal points to; the normal follows the right-hand rule on the
vertex order ``(v0, v1, v2)``: ``n = (v1 - v0) x (v2 - v0) / |...|``. Light leaves a
one-sided face only from its painted side and a face only reflects light that reaches its
painted side.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from resection._mesh_graph import pair_weights, shared_edges, vertex_classes
from resection.errors import InputError
from resection.trisurface import MERGE_DIGITS, is_mesh

if TYPE_CHECKING:
    import scipy.sparse as sp
    import trimesh

__all__ = ["check_mesh", "face_areas", "face_normals", "face_adjacency_weights"]

_SHOW = 5  # how many offending indices an error message names


def _first(idx: np.ndarray) -> str:
    shown = ", ".join(str(int(i)) for i in idx[:_SHOW])
    more = f" and {idx.size - _SHOW} more" if idx.size > _SHOW else ""
    return shown + more


def check_mesh(mesh, name: str = "mesh", *, rel_area_tol: float = 1e-12) -> trimesh.Trimesh:
    """Validate a triangle mesh for radiosity work and return it.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Triangle mesh (model units). Not modified.
    name : str
        Name used in error messages.
    rel_area_tol : float
        A face whose area is below ``rel_area_tol * scale**2`` (``scale`` the bounding-box
        diagonal) is degenerate.

    Returns
    -------
    trimesh.Trimesh
        The same mesh.

    Raises
    ------
    InputError
        Not a ``Trimesh``, no faces, vertex coordinates that are NaN or infinite, face
        indices out of range, or degenerate (zero-area) triangles; the message names the
        offending vertex or face indices.
    """
    if not is_mesh(mesh):
        raise InputError(f"{name}: expected a trimesh.Trimesh or TriSurface, got "
                         f"{type(mesh).__name__}")
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces)
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        raise InputError(f"{name}: empty mesh (no triangles)")
    from resection._mesh_graph import cross_squares  # compiled passes
    from resection.surface.visibility import bounds

    lo, hi = bounds(vertices)
    bad_v = (np.zeros(0, np.int64) if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
             else np.flatnonzero(~np.all(np.isfinite(vertices), axis=1)))
    if bad_v.size:
        raise InputError(
            f"{name}: {bad_v.size} vertex(es) with NaN or infinite coordinates "
            f"(vertex {_first(bad_v)})"
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        bad_f = np.flatnonzero(np.any((faces < 0) | (faces >= len(vertices)), axis=1))
        raise InputError(f"{name}: face(s) {_first(bad_f)} index missing vertices")
    area2 = cross_squares(vertices, faces)  # |(v1 - v0) x (v2 - v0)|^2
    scale = float((hi - lo).max()) if len(vertices) else 0.0
    bad_f = np.flatnonzero(~(area2 > (rel_area_tol * scale**2) ** 2))
    if bad_f.size:
        raise InputError(
            f"{name}: {bad_f.size} degenerate (zero-area) triangle(s): face {_first(bad_f)}"
        )
    return mesh


def face_areas(mesh: trimesh.Trimesh) -> np.ndarray:
    """Areas of the faces, ``(N,)`` float64, in model units squared."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return 0.5 * np.linalg.norm(cross, axis=1)


def face_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    """Unit normals ``(N, 3)`` pointing to the painted side (right-hand rule on the
    vertex order), computed in float64 from the vertices, not from any cached normals."""
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return cross / np.linalg.norm(cross, axis=1, keepdims=True)


def face_adjacency_weights(mesh: trimesh.Trimesh) -> sp.csr_matrix:
    """Finite-volume difference operator over faces sharing an edge.

    Returns a sparse ``(P, N)`` matrix ``D`` with one row per pair of faces ``(i, j)``
    sharing an edge: ``D[p, i] = w``, ``D[p, j] = -w`` with ``w = sqrt(l_ij / d_ij)``
    (``l_ij`` the shared edge length, ``d_ij`` the distance between the face centroids),
    so that ``|D x|^2`` approximates the Dirichlet energy ``integral |grad x|^2 dA`` of a
    per-face field ``x``. Only edges shared by exactly two faces (manifold edges) count.
    Faces that touch through coincident but distinct vertices (a mesh built or read
    without merging them) are adjacent too: vertices that trimesh's ``merge_vertices``
    would merge (equal coordinates to ``trimesh.tol.merge``) count as one, the first of
    them giving the position (:func:`resection._mesh_graph.vertex_classes`); the mesh is
    not changed. The pairs are those of ``trimesh.graph.face_adjacency`` of the merged
    faces (:func:`resection._mesh_graph.shared_edges`), in another row order.
    """
    import scipy.sparse as sp
    n = len(mesh.faces)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if n == 0:
        return sp.csr_matrix((0, n))
    rep, _, _ = vertex_classes(v, faces, MERGE_DIGITS)  # trimesh's merge precision
    merged = rep[faces]
    pairs, edges = shared_edges(merged)
    if pairs.size == 0:
        return sp.csr_matrix((0, n))
    # edge lengths over the merged faces' centroid distances, in one compiled pass
    w = pair_weights(v, merged, pairs, edges)
    # row p: w at face pairs[p, 0], -w at pairs[p, 1] (the smaller index first: sorted)
    return sp.csr_matrix((np.column_stack([w, -w]).ravel(), pairs.ravel(),
                          np.arange(0, 2 * len(pairs) + 1, 2)), shape=(len(pairs), n))
