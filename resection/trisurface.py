"""A triangle surface without trimesh: vertices, faces and the face geometry the package reads.

:class:`TriSurface` holds what the mapping and the self-illumination correction use of a
model surface: the vertex coordinates, the triangles, per-face attributes and metadata, and
the face normals, areas, centres and corner coordinates computed from them once (cached)
with the same arithmetic as :class:`trimesh.Trimesh` (``process=False``). Reading a grid
into one (:func:`resection.io.meshes.read_surface`) needs no ``import trimesh`` (0.3-0.4 s
of imports: scipy.spatial, networkx, ...). :meth:`TriSurface.to_trimesh` gives the trimesh
mesh for code that needs its other methods.

Functions that only read these attributes accept either kind; :func:`is_mesh` is their
check. The arrays are read-only: a surface is not changed in place (the cached geometry
would go stale); build a new one instead.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

__all__ = ["TriSurface", "is_mesh", "MERGE_DIGITS", "ZERO_NORM"]

#: Decimal digits of trimesh's vertex merge: ``trimesh.util.decimal_to_digits(tol.merge)``
#: with ``tol.merge = 1e-8``; two vertices merge when their coordinates times ``10**8``
#: round to the same integers.
MERGE_DIGITS = 8
#: Cross-product length at or under which trimesh's normals are zero (``util.TOL_ZERO``:
#: 100 times float64's resolution).
ZERO_NORM = float(np.finfo(np.float64).resolution * 100)


def _frozen(a, dtype) -> np.ndarray:
    """A read-only C-contiguous view (the caller's array keeps its own flags)."""
    out = np.ascontiguousarray(a, dtype=dtype).view()
    out.flags.writeable = False
    return out


@dataclass(eq=False)
class TriSurface:
    """Triangles of a model surface, face order as given.

    Parameters
    ----------
    vertices : (V, 3) array_like of float
        Coordinates (model units), stored as read-only float64.
    faces : (F, 3) array_like of int
        Vertex indices of each triangle; the winding gives the normal (right-hand rule).
        Stored as read-only int64.
    face_attributes : dict of str to (F,) arrays, optional
        Per-face values (``component``, ``block``, ``cell_i``, ``cell_j``, ...).
    metadata : dict, optional
        ``source``, ``format`` and what the readers add (``plot3d_dims``, ...).

    Notes
    -----
    The cached properties are those of trimesh with ``process=False``, computed the same
    way: ``triangles = vertices[faces]``; ``triangles_cross = cross(v1 - v0, v2 - v1)``;
    ``face_normals`` the cross products over their length, zero where the length is at or
    under :data:`ZERO_NORM`; ``area_faces`` half the cross length; ``triangles_center``
    the mean of the three corners. (A trimesh read from an STL may keep the file's own
    float32 normals instead when they agree with the triangles.)
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_attributes: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        self.vertices = _frozen(self.vertices, np.float64).reshape(-1, 3)
        self.faces = _frozen(self.faces, np.int64).reshape(-1, 3)
        self.face_attributes = dict(self.face_attributes)
        self.metadata = dict(self.metadata)

    @classmethod
    def from_trimesh(cls, mesh) -> TriSurface:
        """The vertices, faces, face attributes and metadata of a ``trimesh.Trimesh``."""
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.faces),
                   dict(mesh.face_attributes), dict(mesh.metadata))

    def to_trimesh(self):
        """The same surface as a ``trimesh.Trimesh`` (``process=False``: same vertices,
        faces and face order; copies of the arrays, attributes and metadata)."""
        import trimesh

        mesh = trimesh.Trimesh(np.array(self.vertices), np.array(self.faces), process=False)
        for key, value in self.face_attributes.items():
            mesh.face_attributes[key] = np.array(value)
        mesh.metadata.update(self.metadata)
        return mesh

    @cached_property
    def triangles(self) -> np.ndarray:
        """Corner coordinates ``(F, 3, 3)`` float64: ``vertices[faces]``."""
        return self.vertices[self.faces]

    @cached_property
    def triangles_cross(self) -> np.ndarray:
        """``(v1 - v0) x (v2 - v1)`` of every face, ``(F, 3)`` (trimesh's edge pair)."""
        tri = self.triangles
        edges = tri[:, 1:, :] - tri[:, :2, :]
        return np.cross(edges[:, 0], edges[:, 1])

    @cached_property
    def face_normals(self) -> np.ndarray:
        """Unit normals ``(F, 3)`` (right-hand rule); zero for a degenerate face."""
        c = self.triangles_cross
        norm = np.sqrt(np.dot(c * c, [1.0, 1.0, 1.0]))
        valid = norm > ZERO_NORM
        norm[valid] **= -1
        out = c * norm.reshape(-1, 1)
        out[~valid] = 0.0
        return out

    @cached_property
    def area_faces(self) -> np.ndarray:
        """Face areas ``(F,)`` (model units squared)."""
        c = self.triangles_cross
        return np.sqrt((c**2).sum(axis=1)) / 2.0

    @cached_property
    def triangles_center(self) -> np.ndarray:
        """Face centroids ``(F, 3)``: the mean of the three corners."""
        return self.triangles.mean(axis=1)

    @property
    def bounds(self) -> np.ndarray:
        """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` of the vertices."""
        return np.array([self.vertices.min(axis=0), self.vertices.max(axis=0)])


def is_mesh(obj) -> bool:
    """Whether ``obj`` is a :class:`TriSurface` or a ``trimesh.Trimesh`` (checked without
    importing trimesh: an object cannot be a Trimesh when trimesh was never imported)."""
    if isinstance(obj, TriSurface):
        return True
    tm = sys.modules.get("trimesh")
    return tm is not None and isinstance(obj, tm.Trimesh)
