"""The model grid of an unsteady run: its nodes in the grid file's order, as uPSP numbers
them, and the triangles that mapping and self-illumination work on.

A Plot3D grid's nodes are numbered block by block, ``i`` fastest, then ``j``, then ``k``
(the order of the file and of a Plot3D function file such as the steady Cp): node ``g`` of
the run's output is that point. Blocks share points along their seams; the triangle mesh
that mapping and the view factors use merges coincident points, so that a seam node gets
the pixels of the faces on both sides. :attr:`RunGrid.node_vertex` maps every grid node to
its merged vertex (seam copies share one value).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import trimesh

from resection.errors import InputError

__all__ = ["RunGrid", "load_run_grid", "read_steady_cp"]


@dataclass(frozen=True)
class RunGrid:
    """Attributes
    ----------
    path : str
    dims : list of (ni, nj, nk)
        Each block's dimensions.
    points : (N, 3) float64
        Grid nodes in file order.
    mesh : trimesh.Trimesh
        Triangles on merged vertices (``face_attributes["block"]`` from 1, as
        :func:`resection.io.meshes.plot3d_to_mesh`).
    node_vertex : (N,) int64
        The mesh vertex of every grid node.
    triangles : (F, 3) int64
        The mesh's faces written with grid-node numbers (for the output's topology).
    """

    path: str
    dims: list
    points: np.ndarray
    mesh: trimesh.Trimesh
    node_vertex: np.ndarray
    triangles: np.ndarray

    @property
    def n_nodes(self) -> int:
        return len(self.points)

    def to_nodes(self, vertex_values) -> np.ndarray:
        """Per-vertex values (last axis) as per-grid-node values."""
        return np.asarray(vertex_values)[..., self.node_vertex]


def _merged(path: str, raw, perm, dims, fmt: str) -> RunGrid:
    """Merge coincident points of ``raw`` (vertices in ``perm`` order = the file's nodes)."""
    from resection.io.meshes import check_mesh

    pts_u = np.asarray(raw.vertices, dtype=np.float64)
    scale = float(np.ptp(pts_u, axis=0).max()) or 1.0
    key = np.round(pts_u / (scale * 1e-9)).astype(np.int64)
    # np.unique(key, axis=0, return_index=True, return_inverse=True) by a lexsort of the
    # columns (the same sorted rows and first occurrences, without sorting rows as bytes)
    order = np.lexsort(key.T[::-1])
    ks = key[order]
    new = np.ones(len(key), bool)
    new[1:] = (ks[1:] != ks[:-1]).any(axis=1)
    first = order[new]
    inverse = np.empty(len(key), np.int64)
    inverse[order] = np.cumsum(new) - 1
    faces_u = np.asarray(raw.faces, dtype=np.int64)
    mesh = trimesh.Trimesh(pts_u[first], inverse[faces_u], process=False)
    for k, v in raw.face_attributes.items():
        mesh.face_attributes[k] = v
    mesh.metadata.update(raw.metadata)
    mesh.metadata["source"] = path
    mesh.metadata["format"] = fmt
    check_mesh(mesh, path)
    file_of_u = np.empty_like(perm)
    file_of_u[perm] = np.arange(perm.size)
    return RunGrid(path, dims, pts_u[perm], mesh, inverse[perm], file_of_u[faces_u])


def load_run_grid(path: str | os.PathLike) -> RunGrid:
    """Read the run's grid: a Plot3D surface grid (by content, any extension; nodes block by
    block, ``i`` fastest) or a Cart3D ``.tri`` (nodes = its vertices in file order)."""
    from resection.io.meshes import plot3d_to_mesh, read_cart3d_tri
    from resection.io.plot3d import read_plot3d

    p = os.fspath(path)
    if not os.path.isfile(p):
        raise InputError(f"grid file not found: {p}")
    if p.lower().endswith(".tri"):
        raw = read_cart3d_tri(p)
        return _merged(p, raw, np.arange(len(raw.vertices)), [], "cart3d")
    blocks = read_plot3d(p)
    raw = plot3d_to_mesh(blocks, merge_vertices=False, source=p)
    dims, perm, off = [], [], 0
    for xyz, _ in blocks:  # a handful of blocks
        d = tuple(int(x) for x in (xyz.shape[:3] + (1,))[:3])
        keep = [a for a in range(3) if d[a] > 1]
        na, nb = d[keep[0]], d[keep[1]]
        # mesh vertex of block point (a, b) is a * nb + b; the file runs a fastest
        perm.append((np.arange(na)[None, :] * nb + np.arange(nb)[:, None]).ravel() + off)
        dims.append(d)
        off += na * nb
    return _merged(p, raw, np.concatenate(perm), dims, "plot3d")


def read_steady_cp(path: str | os.PathLike, grid: RunGrid) -> np.ndarray:
    """The steady Cp per grid node in file order: a Plot3D function file on a Plot3D grid,
    or a Cart3D ``.triq`` on a Cart3D grid (its first scalar, Cp as Cart3D writes it first).

    Raises
    ------
    InputError
        A file of the other family than the grid, blocks that do not match the grid's
        (count or dimensions: the message names the first that differs), more than one
        variable, a ``.triq`` of other vertices, a non-finite value.
    """
    from resection.io.plot3d import read_plot3d_function

    p = os.fspath(path)
    is_triq = p.lower().endswith(".triq")
    if is_triq != (grid.mesh.metadata.get("format") == "cart3d"):
        raise InputError(f"{p}: a {'Cart3D .triq' if is_triq else 'Plot3D function file'} "
                         f"for the {grid.mesh.metadata.get('format')} grid {grid.path} (the "
                         "steady Cp comes on the grid's own kind of file)")
    if is_triq:
        return _triq_cp(p, grid)
    blocks = read_plot3d_function(p)
    if len(blocks) != len(grid.dims):
        raise InputError(f"{p}: {len(blocks)} blocks, the grid {grid.path} has "
                         f"{len(grid.dims)}")
    out = []
    for k, (b, d) in enumerate(zip(blocks, grid.dims, strict=True)):
        if tuple(b.shape[:3]) != tuple(d):
            raise InputError(f"{p}: block {k + 1} is {b.shape[0]}x{b.shape[1]}x{b.shape[2]}, "
                             f"the grid's is {d[0]}x{d[1]}x{d[2]}")
        if b.shape[3] != 1:
            raise InputError(f"{p}: block {k + 1} holds {b.shape[3]} variables; the steady "
                             "file holds Cp only (one)")
        out.append(b[..., 0].ravel(order="F"))  # i fastest, as the file
    cp = np.concatenate(out)
    if not np.all(np.isfinite(cp)):
        bad = int(np.flatnonzero(~np.isfinite(cp))[0])
        raise InputError(f"{p}: NaN or infinite Cp at node {bad}")
    return cp


def _triq_cp(p: str, grid: RunGrid) -> np.ndarray:
    from resection.io.triq import read_triq

    mesh, S = read_triq(p)
    if len(mesh.vertices) != grid.n_nodes or not np.allclose(
            mesh.vertices, grid.points, rtol=0,
            atol=1e-6 * (float(np.ptp(grid.points, axis=0).max()) or 1.0)):
        raise InputError(f"{p}: {len(mesh.vertices)} vertices that are not the grid "
                         f"{grid.path}'s {grid.n_nodes} nodes")
    if S.shape[1] < 1:
        raise InputError(f"{p}: no scalar (the steady Cp)")
    return S[:, 0].copy()
