"""What a frame tells about the faces no camera sees in it: their emission continued from
the seen faces of the same part, frame by frame.

The self-illumination of a seen face needs the radiosity of every face it sees, hidden
ones included. The frame-0 solve (:func:`selfillum.solve.radiosity.correct`) gives each
hidden face a radiosity ``B0`` and an emission ``E0`` (the smooth continuation of the seen
emission). A model's emission varies in time everywhere, so holding ``B0`` for every frame
leaves the time-varying light of the hidden faces on the seen ones (a painted block's
tone reflected on the plate next to its unseen sides).

The stated assumption, per frame ``t``: **a hidden face's emission varies in time as that
of the nearest seen face of the same part**::

    E_h(t) = E0_h r_s(t),   r_s(t) = B_s(t) / B0_s,   s = nearest(h)

* *nearest*: along the surface (the face graph, edges weighted by the distance between
  face centres), a multi-source shortest-path search from the seen faces
  (:func:`scipy.sparse.csgraph.dijkstra`, ``min_only``);
* *the same part*: the search does not cross a **concave crease** (two faces meeting at a
  concave edge whose normals differ by more than ``crease_deg``, 30 degrees by default):
  the junction of a block and the plate it stands on, of a fin and a body, of a wing and a
  fuselage. Convex edges (a block's own edges, a wing's trailing edge) and smooth ones are
  crossed. A hidden side of a block so takes its time history from the block's seen
  faces, not from the plate beside it;
* the sources are the faces seen in this frame *and* in frame 0 (whose ``B0`` was
  measured, not itself continued);
* the radiosity ratio of the seen face stands for its emission ratio (they differ by the
  change of its reflected light: a second-order term); a ratio outside ``[1/2, 2]`` (a
  face's brightness halved or doubled from frame 0: an edge pixel or a glint, not the
  paint's emission) is clipped to it;
* the hidden face's radiosity is ``B_h(t) = B0_h + E0_h (r_s(t) - 1)``: its own reflected
  light held at frame 0 (second order again);
* a hidden face that no seen face reaches without crossing a concave crease keeps ``B0``
  (the frame-0 assumption: nothing in the frame tells about it).

The assignment is a fixed sparse gather (one index a hidden face), recomputed only when the
set of seen faces changes (a new reference of a moving model, a face leaving the sensor):
a frame costs a gather and a multiply over the hidden faces that light a seen one.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

__all__ = ["HiddenContinuation", "part_graph"]


def part_graph(mesh, crease_deg: float = 30.0, keep=None):
    """(F, F) symmetric sparse graph of the faces: an edge between faces sharing an edge,
    weighted by the distance between their centres, except across a concave crease of more
    than ``crease_deg`` degrees (see the module notes).

    Parameters
    ----------
    mesh : trimesh.Trimesh
    crease_deg : float
        Degrees between the two faces' normals beyond which a concave edge separates parts.
    keep : (F,) bool, optional
        Faces in the graph (others have no edge: e.g. unpainted faces).

    Returns
    -------
    scipy.sparse.csr_matrix
    """
    import scipy.sparse as sp

    adj = np.asarray(mesh.face_adjacency, dtype=np.int64).reshape(-1, 2)
    n = len(mesh.faces)
    if len(adj):
        ang = np.asarray(mesh.face_adjacency_angles, dtype=np.float64)
        convex = np.asarray(mesh.face_adjacency_convex, dtype=bool)
        ok = convex | (ang <= np.radians(crease_deg))
        if keep is not None:
            k = np.asarray(keep, bool)
            ok &= k[adj[:, 0]] & k[adj[:, 1]]
        adj = adj[ok]
        c = np.asarray(mesh.triangles_center, dtype=np.float64)
        w = np.linalg.norm(c[adj[:, 0]] - c[adj[:, 1]], axis=1)
        w = np.maximum(w, 1e-12 * max(float(np.ptp(c)), 1e-300))  # dijkstra drops zeros
    else:
        w = np.zeros(0)
    g = sp.csr_matrix((np.concatenate([w, w]),
                       (np.concatenate([adj[:, 0], adj[:, 1]]),
                        np.concatenate([adj[:, 1], adj[:, 0]]))), shape=(n, n))
    return g


class HiddenContinuation:
    """Per frame, the radiosity of the hidden faces that light a seen one (see the module
    notes).

    Parameters
    ----------
    graph : scipy.sparse.csr_matrix
        :func:`part_graph` of the mesh.
    B0, E0 : (F,) array_like
        The frame-0 solve's radiosity and emission of every face (NaN or 0 where it gives
        none).
    needed : (F,) bool
        Faces whose radiosity the self-illumination reads (the columns of ``F``).
    seen0 : (F,) bool, optional
        The faces seen in frame 0 (default: every face with ``B0 > 0``).
    cache : int
        Assignments kept (one a set of seen faces).
    """

    #: The range a seen face's ratio to frame 0 is clipped to.
    RATIO_RANGE = (0.5, 2.0)

    def __init__(self, graph, B0, E0, needed, seen0=None, cache: int = 8):
        self.graph = graph
        self.B0 = np.asarray(B0, dtype=np.float64)
        E0 = np.asarray(E0, dtype=np.float64)
        self.E0 = np.where(np.isfinite(E0), E0, 0.0)
        self.needed = np.asarray(needed, bool)
        ok = np.isfinite(self.B0) & (self.B0 > 0)
        self.source_ok = ok if seen0 is None else ok & np.asarray(seen0, bool)
        self._cache: OrderedDict = OrderedDict()
        self._size = int(cache)

    def assignment(self, seen) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(hidden, source, base)``: the needed hidden faces that a seen face reaches
        within their part, that seen face (nearest along the surface), and the set of seen
        faces the search was made for.

        A set of seen faces within ``1 %`` of the faces of one already searched (a frame
        that lost a few faces at the image's edge) reuses that search: the faces it lost
        keep their frame-0 radiosity, and a hidden face whose source it lost keeps its own.
        """
        seen = np.asarray(seen, bool)
        key = np.packbits(seen).tobytes()
        hit = self._cache.get(key)
        if hit is None:
            tol = max(1, len(seen) // 100)
            for k, v in self._cache.items():
                if np.count_nonzero(v[2] != seen) <= tol:
                    hit = v
                    key = k
                    break
        if hit is not None:
            self._cache.move_to_end(key)
            return hit
        from scipy.sparse.csgraph import dijkstra

        hid = np.flatnonzero(self.needed & ~seen)
        src_faces = np.flatnonzero(seen & self.source_ok)
        if hid.size == 0 or src_faces.size == 0:
            out = (np.zeros(0, np.int64), np.zeros(0, np.int64), seen)
        else:
            _, _, sources = dijkstra(self.graph, directed=False, indices=src_faces,
                                     min_only=True, return_predecessors=True)
            s = sources[hid]
            ok = s >= 0
            out = (hid[ok], s[ok].astype(np.int64), seen)
        self._cache[key] = out
        if len(self._cache) > self._size:
            self._cache.popitem(last=False)
        return out

    def radiosity(self, B, seen) -> np.ndarray:
        """(F,) the radiosity to use for every face in this frame: ``B`` where seen, the
        continued estimate on the hidden faces a seen face reaches, ``B0`` elsewhere."""
        seen = np.asarray(seen, bool)
        x = np.where(seen, B, self.B0)
        hid, src, _ = self.assignment(seen)
        if hid.size:
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.asarray(B, dtype=np.float64)[src] / self.B0[src]
            r = np.clip(np.where(np.isfinite(r) & seen[src], r, 1.0), *self.RATIO_RANGE)
            est = self.B0[hid] + self.E0[hid] * (r - 1.0)
            x[hid] = np.where(seen[hid], x[hid], est)
        return x
