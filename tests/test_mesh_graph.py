"""The compiled mesh passes (resection._mesh_graph) against the trimesh and NumPy
functions they replace, on random face lists (repeats, opposite windings, non-manifold
edges, unused and coincident vertices) and on a real grid shape; and the users of them
(load_mesh's merging, face_adjacency_weights) against trimesh's own merge and
adjacency."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from resection._mesh_graph import (
    cross_squares,
    pair_weights,
    repeated_faces,
    shared_edges,
    vertex_classes,
)

DIGITS = trimesh.util.decimal_to_digits(trimesh.tol.merge)


def _random_faces(rng, nv, nf):
    f = rng.integers(0, nv, (nf, 3))
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    # exact repeats, a repeat rotated (the same triangle), an opposite winding
    return np.vstack([f, f[rng.integers(0, len(f), 4)], np.roll(f[:3], 1, axis=1),
                      f[3:5, ::-1]])


def _numpy_repeats(f):
    """The former NumPy formula: rotate the smallest index first, np.unique of rows."""
    r = np.argmin(f, axis=1)
    g = f[np.arange(len(f))[:, None], (r[:, None] + np.arange(3)) % 3]
    _, first, inv = np.unique(g, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    copies = np.flatnonzero(first[inv] != np.arange(len(f)))
    return np.column_stack([first[inv[copies]], copies])


def _rows(*cols):
    a = np.column_stack(cols)
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("seed", range(6))
def test_passes_match_trimesh_and_numpy_on_random_faces(seed):
    rng = np.random.default_rng(seed)
    for nv, nf in ((6, 20), (30, 80), (200, 300)):  # small: many repeats and junctions
        f = _random_faces(rng, nv, nf)
        np.testing.assert_array_equal(repeated_faces(f), _numpy_repeats(f))
        pairs, edges = shared_edges(f)
        tp, te = trimesh.graph.face_adjacency(f, return_edges=True)
        np.testing.assert_array_equal(_rows(pairs, edges), _rows(tp, te))
        # coincident vertices (equal at trimesh's merge precision), one unused vertex
        v = rng.integers(0, 3, (nv + 1, 3)) * 0.5 + rng.normal(0.0, 1e-11, (nv + 1, 3))
        rep, classes, all_used = vertex_classes(v, f, DIGITS)
        merged = trimesh.Trimesh(v, f, process=False)
        merged.merge_vertices()
        assert classes == len(merged.vertices) and not all_used  # vertex nv is unused
        assert rep[nv] == -1
        used = np.unique(f)
        assert np.all(rep[used] <= used) and np.all(rep[rep[used]] == rep[used])
        np.testing.assert_array_equal(v[rep[f]], merged.vertices[merged.faces])
        tri = v[f]
        c = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        np.testing.assert_allclose(cross_squares(v, f), np.einsum("ij,ij->i", c, c),
                                   rtol=1e-13, atol=0.0)


def test_pair_weights_are_the_numpy_formula():
    """sqrt(edge length / centroid distance) of each adjacent pair, against NumPy norms
    and trimesh's triangles_center on a perturbed sphere."""
    sphere = trimesh.creation.icosphere(3)
    v = sphere.vertices * (1.0 + 0.05 * np.random.default_rng(3).random((len(sphere.vertices),
                                                                          1)))
    m = trimesh.Trimesh(v, sphere.faces, process=False)
    pairs, edges = shared_edges(m.faces)
    length = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    c = m.triangles_center
    ref = np.sqrt(length / np.linalg.norm(c[pairs[:, 0]] - c[pairs[:, 1]], axis=1))
    np.testing.assert_allclose(pair_weights(v, m.faces, pairs, edges), ref, rtol=1e-13)


def test_shared_edges_of_a_closed_grid_are_trimesh_s():
    """A sphere of 20,480 faces: every edge shared by two faces."""
    mesh = trimesh.creation.icosphere(5)
    pairs, edges = shared_edges(mesh.faces)
    assert len(pairs) == 3 * len(mesh.faces) // 2
    np.testing.assert_array_equal(_rows(pairs, edges),
                                  _rows(mesh.face_adjacency, mesh.face_adjacency_edges))


def _trimesh_weights(mesh):
    """face_adjacency_weights as written with trimesh's own merge and adjacency."""
    import scipy.sparse as sp

    m = mesh.copy()
    m.merge_vertices()
    pairs, edges = m.face_adjacency, m.face_adjacency_edges
    length = np.linalg.norm(m.vertices[edges[:, 0]] - m.vertices[edges[:, 1]], axis=1)
    c = m.triangles_center
    w = np.sqrt(length / np.linalg.norm(c[pairs[:, 0]] - c[pairs[:, 1]], axis=1))
    p = np.arange(len(pairs))
    return sp.csr_matrix((np.concatenate([w, -w]), (np.concatenate([p, p]), pairs.T.ravel())),
                         shape=(len(pairs), len(mesh.faces)))


def test_face_adjacency_weights_are_trimesh_s_on_a_face_soup():
    """A sphere whose faces each have their own vertices, some moved by 1e-11 (coincident
    at trimesh's merge precision): the operator is trimesh's (merged copy) to rounding,
    row order aside (D^T D and the sorted rows compared)."""
    from selfillum.mesh import face_adjacency_weights

    sphere = trimesh.creation.icosphere(3)
    tri = np.asarray(sphere.triangles).reshape(-1, 3)
    tri = tri + np.random.default_rng(0).normal(0.0, 1e-11, tri.shape)
    soup = trimesh.Trimesh(tri, np.arange(len(tri)).reshape(-1, 3), process=False)
    D, R = face_adjacency_weights(soup), _trimesh_weights(soup)
    # a moved vertex may round to the other side of trimesh's grid: that edge is not
    # merged by either
    assert D.shape == R.shape and D.shape[0] > 0.9 * 3 * len(sphere.faces) // 2
    np.testing.assert_allclose((D.T @ D).toarray(), (R.T @ R).toarray(), rtol=0, atol=1e-12)
    assert len(soup.vertices) == len(tri)  # the mesh itself is not merged


def test_load_mesh_skips_merging_only_when_it_changes_nothing(tmp_path, monkeypatch):
    """A merged grid is read as it is, without trimesh's merge; one with coincident or
    unused vertices is merged as trimesh merges it."""
    from resection.io.meshes import load_mesh

    merges = []
    merge = trimesh.Trimesh.merge_vertices
    monkeypatch.setattr(trimesh.Trimesh, "merge_vertices",
                        lambda self, **kw: merges.append(1) or merge(self, **kw))
    sphere = trimesh.creation.icosphere(2)
    tri = np.asarray(sphere.triangles).reshape(-1, 3)
    soup = trimesh.Trimesh(np.vstack([tri, [[9.0, 9.0, 9.0]]]),
                           np.arange(len(tri)).reshape(-1, 3), process=False)
    for mesh, merged in ((sphere, False), (soup, True)):
        p = tmp_path / f"{merged}.ply"
        mesh.export(p)
        ref = trimesh.load(p, process=False)  # as written (float32)
        merge(ref, merge_tex=True, merge_norm=True)
        merges.clear()
        m = load_mesh(p)
        assert len(merges) == merged
        assert len(m.vertices) == len(ref.vertices) == len(sphere.vertices)
        np.testing.assert_array_equal(m.faces, ref.faces)
        np.testing.assert_array_equal(m.vertices, ref.vertices)
