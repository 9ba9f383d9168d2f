"""Image <-> model surface mapping through the face-index image.

:class:`SurfaceMap` casts one Embree ray per pixel (the camera's line of sight through the
pixel centre, lens distortion included) and records which face every pixel sees and where
on it (barycentric coordinates). That is stored as a sparse face x pixel matrix, so that
mapping one frame, or every frame of a run at once, onto the surface is one sparse product:

* :meth:`SurfaceMap.to_surface`: image(s) -> per-face mean of the pixels that see the face,
  the number of (finite) pixels used, and the faces not seen;
* :meth:`SurfaceMap.to_image`: per-face values -> image, interpolated within faces (face
  values -> vertex values -> barycentric interpolation at each pixel's hit point), pixels
  that do not see the model left as a given background.

Conventions (DESIGN.md): pixel centres at integer ``(u, v)``, images indexed ``img[v, u]``,
model units of the mesh.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np

from resection.camera.model import Camera
from resection.defaults import DEFAULT_MAX_OBLIQUENESS
from resection.errors import InputError
from resection.memory import SURFACE_MAP_BYTES_PER_PIXEL, check_pixel_memory
from resection.surface.vertex_fit import _apply_vertex, _as_float, prepare_pattern, vertex_values
from resection.surface.visibility import RayCaster
from resection.trisurface import is_mesh

if TYPE_CHECKING:
    import scipy.sparse as sp
    import trimesh

__all__ = ["DEFAULT_MAX_OBLIQUENESS", "SurfaceMap", "SurfaceSample", "oblique_faces",
           "vertex_values"]



class SurfaceSample(NamedTuple):
    """Result of :meth:`SurfaceMap.to_surface`.

    Attributes
    ----------
    values : (F,) or (T, F) float64
        Mean of the finite pixels seeing each face (NaN where none).
    counts : (F,) or (T, F) int64
        Number of finite pixels averaged.
    unseen : (F,) or (T, F) bool
        Faces with no finite pixel (``counts == 0``).
    nan_counts : (F,) or (T, F) int64
        Number of pixels seeing the face that were NaN (or infinite) and ignored.
    """

    values: np.ndarray
    counts: np.ndarray
    unseen: np.ndarray
    nan_counts: np.ndarray


def _check_obliqueness(max_obliqueness) -> float | None:
    if max_obliqueness is None:
        return None
    try:
        lim = float(max_obliqueness)
    except (TypeError, ValueError):
        raise InputError(f"max_obliqueness: expected degrees, got {max_obliqueness!r}") from None
    if not (0.0 < lim <= 90.0):
        raise InputError(f"max_obliqueness must be in (0, 90] degrees, got {max_obliqueness}")
    return lim


def oblique_faces(
    mesh: trimesh.Trimesh, center, max_obliqueness: float | None = DEFAULT_MAX_OBLIQUENESS,
    *, normals=None, centroids=None,
) -> np.ndarray:
    """Faces seen from ``center`` more obliquely than a cut-off.

    The obliqueness of a face is the angle between its normal and the line from its
    centroid to the perspective centre, whichever side of the face is seen (grids' winding
    is not always consistent across blocks; back faces are the visibility test's business).

    Parameters
    ----------
    mesh : trimesh.Trimesh
    center : (3,) array_like
        Perspective centre (``Camera.center``), model units.
    max_obliqueness : float or None
        Cut-off in degrees, in (0, 90]. None: no cut-off (no face is oblique).
    normals, centroids : (F, 3) array_like, optional
        The faces' unit normals and centroids when already at hand (e.g.
        :attr:`RayCaster.normals <resection.surface.visibility.RayCaster.normals>`);
        computed from ``mesh`` otherwise.

    Returns
    -------
    (F,) bool
        True where the angle exceeds the cut-off (such faces count as unseen).
    """
    lim = _check_obliqueness(max_obliqueness)
    nf = len(mesh.faces)
    if lim is None:
        return np.zeros(nf, dtype=bool)
    cen = np.asarray(mesh.triangles_center if centroids is None else centroids,
                     dtype=np.float64)
    view = np.asarray(center, dtype=np.float64)[None, :] - cen
    n = np.asarray(mesh.face_normals if normals is None else normals, dtype=np.float64)
    cosang = np.abs(np.einsum("ij,ij->i", n, view)) / np.linalg.norm(view, axis=1)
    return cosang < np.cos(np.radians(lim)) - 1e-12


class SurfaceMap:
    """Which face, and where on it, every pixel of a camera sees.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Model surface (model units). Its face order indexes every per-face array.
    camera : Camera
        Calibrated camera with its pose; one ray per pixel centre through
        :meth:`Camera.rays` (distortion included).
    max_obliqueness : float or None, optional
        Obliqueness cut-off, degrees in (0, 90] (default 70, as uPSP): a face whose normal
        makes a larger angle with the line of sight from the perspective centre to its
        centroid (:func:`oblique_faces`) counts as unseen, and the pixels that hit it are
        background. None keeps every hit.

    Attributes
    ----------
    face_index : (H, W) int64
        Face seen by each pixel, -1 for background.
    barycentric : (H, W, 3) float64
        Barycentric coordinates of the hit point on the face's vertices (NaN background).
    depth : (H, W) float64
        Distance from the perspective centre to the hit point, model units (NaN background).
    matrix : scipy.sparse.csr_matrix, shape (F, H*W)
        1 where pixel (flattened ``v * W + u``) sees face.
    pixel_counts : (F,) int64
        Pixels seeing each face (before removing NaN pixels of an image).
    oblique : (F,) bool
        Faces beyond the obliqueness cut-off (unseen whether or not a pixel hits them).
    max_obliqueness : float or None
        The cut-off used, degrees.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        camera: Camera,
        *,
        max_obliqueness: float | None = DEFAULT_MAX_OBLIQUENESS,
        caster: RayCaster | None = None,
    ):
        if not isinstance(camera, Camera):
            raise InputError(f"camera: expected a resection.Camera, got {type(camera).__name__}")
        if not is_mesh(mesh):
            raise InputError(f"mesh: expected a trimesh.Trimesh or TriSurface, got "
                             f"{type(mesh).__name__}")
        self.mesh = mesh
        self.camera = camera
        self.max_obliqueness = _check_obliqueness(max_obliqueness)
        H, W = camera.height, camera.width
        check_pixel_memory(W, H, SURFACE_MAP_BYTES_PER_PIXEL, "SurfaceMap")
        self.shape = (H, W)
        caster = RayCaster(mesh) if caster is None else caster
        if caster.n_faces != len(mesh.faces):
            raise InputError(f"caster: built for {caster.n_faces} faces, the mesh has "
                             f"{len(mesh.faces)}")
        _, dirs = camera.rays()  # every pixel, from the camera's undistortion map
        face, dist, bary = caster.first_hit(camera.center, dirs, unit=True)
        self.oblique = oblique_faces(mesh, camera.center, self.max_obliqueness,
                                     normals=caster.normals, centroids=caster.centroids)
        if self.oblique.any():
            bad = np.flatnonzero(face >= 0)
            bad = bad[self.oblique[face[bad]]]
            face[bad] = -1
            dist[bad] = np.nan
            bary[bad] = np.nan
        self.face_index = face.reshape(H, W)
        self.barycentric = bary.reshape(H, W, 3)
        self.depth = dist.reshape(H, W)
        self._hit = np.flatnonzero(face >= 0)  # flattened pixel indices on the model
        self._hit_face = face[self._hit]
        nf = len(mesh.faces)
        self.pixel_counts = np.bincount(self._hit_face, minlength=nf).astype(np.int64)
        self._area, self._centroids = caster.areas, caster.centroids
        self._vcache: dict = {}
        self._interp = None

    # ------------------------------------------------------------------ properties
    @property
    def n_faces(self) -> int:
        return len(self.mesh.faces)

    @property
    def matrix(self) -> sp.csr_matrix:
        """(F, H*W) sparse: 1 where pixel (flattened ``v * W + u``) sees the face."""
        import scipy.sparse as sp
        H, W = self.shape
        return sp.csr_matrix(
            (np.ones(self._hit.size), (self._hit_face, self._hit)), shape=(self.n_faces, H * W)
        )

    def _interpolation_matrix(self) -> sp.csr_matrix:
        """(model pixels, V) sparse: barycentric weights of each pixel's hit face corners."""
        if self._interp is None:
            import scipy.sparse as sp

            corners = np.asarray(self.mesh.faces, dtype=np.int64)[self._hit_face]
            b = self.barycentric.reshape(-1, 3)[self._hit]
            n = self._hit.size
            self._interp = sp.csr_matrix(
                (b.ravel(), corners.ravel(), np.arange(0, 3 * n + 1, 3)),
                shape=(n, len(self.mesh.vertices)),
            )
        return self._interp

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: pixels that see the model."""
        return self.face_index >= 0

    @property
    def seen_faces(self) -> np.ndarray:
        """(F,) bool: faces seen by at least one pixel."""
        return self.pixel_counts > 0

    @property
    def points(self) -> np.ndarray:
        """(H, W, 3) model coordinates of each pixel's hit point (NaN background)."""
        out = np.full((self.shape[0] * self.shape[1], 3), np.nan)
        f = self.face_index.ravel()[self._hit]
        tri = np.asarray(self.mesh.vertices, dtype=np.float64)[np.asarray(self.mesh.faces)[f]]
        b = self.barycentric.reshape(-1, 3)[self._hit]
        out[self._hit] = np.einsum("pk,pkj->pj", b, tri)
        return out.reshape(self.shape + (3,))

    # ------------------------------------------------------------------ mapping
    def _check_images(self, image, name: str = "image") -> tuple[np.ndarray, bool]:
        arr = np.asarray(image)
        H, W = self.shape
        if arr.ndim == 2 and arr.shape == (H, W):
            return arr[None], True
        if arr.ndim == 3 and arr.shape[1:] == (H, W):
            if arr.shape[0] == 0:
                raise InputError(f"{name}: empty stack (0 frames)")
            return arr, False
        raise InputError(
            f"{name}: shape {arr.shape} does not match the camera image (H, W) = ({H}, {W})"
            " (or a stack (T, H, W))"
        )

    def to_surface(self, image) -> SurfaceSample:
        """Average image pixels onto the faces they see.

        Parameters
        ----------
        image : (H, W) or (T, H, W) array_like
            One image or a stack of T frames of this camera. NaN pixels are ignored (and
            not counted in ``counts``).

        Returns
        -------
        SurfaceSample
            ``(values, counts, unseen, nan_counts)``, each (F,) for one image or (T, F)
            for a stack.
        """
        arr, single = self._check_images(image)
        if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
            raise InputError(f"image: expected real numbers, got dtype {arr.dtype}")
        T, nf = arr.shape[0], self.n_faces
        # model pixels of every frame, (frames, pixels); per-face sums by bincount, a
        # frame at a time
        X = np.asarray(arr.reshape(T, -1)[:, self._hit], dtype=np.float64)
        finite = np.isfinite(X)
        counts = np.broadcast_to(self.pixel_counts, (T, nf)).copy()
        if not finite.all():
            X = np.where(finite, X, 0.0)
            for t in np.flatnonzero(~finite.all(axis=1)):
                counts[t] = np.bincount(self._hit_face[finite[t]], minlength=nf)
        sums = np.empty((T, nf))
        for t in range(T):
            sums[t] = np.bincount(self._hit_face, weights=X[t], minlength=nf)
        with np.errstate(invalid="ignore", divide="ignore"):
            values = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        unseen = counts == 0
        nan_counts = self.pixel_counts[None, :] - counts
        if single:
            return SurfaceSample(values[0], counts[0], unseen[0], nan_counts[0])
        return SurfaceSample(values, counts, unseen, nan_counts)

    def to_nodes(self, image) -> SurfaceSample:
        """Image pixels onto the grid's nodes (vertices), from the pixels around each node.

        A node's value is the mean of the finite pixels that see a face around it, each
        weighted by the barycentric coordinate of its hit point on that node (1 on the node,
        0 on the opposite edge): only pixels that see the model enter, never the background
        next to a silhouette. Accurate to first order in the face size (second order where
        the pixels surround the node evenly).

        Parameters
        ----------
        image : (H, W) or (T, H, W) array_like

        Returns
        -------
        SurfaceSample
            Per node: ``values`` (NaN where no pixel contributes), ``counts`` (pixels with a
            non-zero weight), ``unseen``, ``nan_counts``; (V,) or (T, V).
        """
        arr, single = self._check_images(image)
        if not np.issubdtype(arr.dtype, np.number) or np.issubdtype(arr.dtype, np.complexfloating):
            raise InputError(f"image: expected real numbers, got dtype {arr.dtype}")
        T = arr.shape[0]
        X = np.ascontiguousarray(arr.reshape(T, -1)[:, self._hit], dtype=np.float64)
        nv = len(self.mesh.vertices)
        sums, weights = np.zeros((T, nv)), np.zeros((T, nv))
        counts, total = np.zeros((T, nv), np.int64), np.zeros(nv, np.int64)
        _splat_nodes(np.asarray(self.mesh.faces, dtype=np.int64)[self._hit_face],
                     np.ascontiguousarray(self.barycentric.reshape(-1, 3)[self._hit]), X,
                     sums, weights, counts, total)
        with np.errstate(invalid="ignore", divide="ignore"):
            values = np.where(weights > 1e-12, sums / weights, np.nan)
        unseen = ~np.isfinite(values)
        counts[unseen] = 0
        nan_counts = total[None, :] - counts
        nan_counts[unseen] = np.broadcast_to(total, unseen.shape)[unseen]
        if single:
            return SurfaceSample(values[0], counts[0], unseen[0], nan_counts[0])
        return SurfaceSample(values, counts, unseen, nan_counts)

    def vertex_values(self, face_values, interpolation: str = "linear") -> np.ndarray:
        """Per-vertex values of per-face values (see :func:`vertex_values`)."""
        fv = _as_float(face_values, "face_values")
        if fv.ndim not in (1, 2) or fv.shape[0] != self.n_faces:
            raise InputError(f"face_values: expected ({self.n_faces},) or ({self.n_faces}, K) "
                             f"for the mesh's faces, got shape {fv.shape}")
        if interpolation not in ("linear", "mean"):
            raise InputError(f"interpolation must be 'linear' or 'mean', got {interpolation!r}")
        return _apply_vertex(self.mesh, self._area, fv, interpolation == "linear", self._vcache,
                             self._centroids)

    def prepare(self, valued, interpolation: str = "linear") -> None:
        """Build now what :meth:`to_image` and :meth:`vertex_values` will need for face
        values that are finite exactly on ``valued``: the vertex matrix of that pattern
        of faces (kept until the next call) and the pixels' interpolation matrix.

        Meant for a thread while other work runs (``selfillum correct`` calls it while the
        view factors' rays are traced): sparse and NumPy work that mostly runs without
        the GIL. The results are the same with or without it.

        Parameters
        ----------
        valued : (F,) array_like of bool
            The faces that will have a value.
        interpolation : {"linear", "mean"}
        """
        valued = np.asarray(valued, dtype=bool)
        if valued.shape != (self.n_faces,):
            raise InputError(f"valued: expected ({self.n_faces},) booleans, got shape "
                             f"{valued.shape}")
        if interpolation not in ("linear", "mean"):
            raise InputError(f"interpolation must be 'linear' or 'mean', got {interpolation!r}")
        prepare_pattern(self.mesh, self._area, valued, interpolation == "linear",
                        self._vcache, self._centroids)
        self._interpolation_matrix()

    def to_image(self, face_values, background=None, *, interpolation: str = "linear"):
        """Backproject per-face values into this camera's image.

        Parameters
        ----------
        face_values : (F,) or (T, F) array_like
            Value(s) per face. NaN faces are left out of the interpolation, and pixels on a
            NaN face take the background.
        background : None, float or (H, W) / (T, H, W) array_like
            What pixels that do not see the model (or see a NaN face) get: NaN (default), a
            constant, or the matching pixels of an image (e.g. the original camera image).
        interpolation : {"linear", "mean", "nearest"}
            ``"nearest"``: each pixel gets its face's value. Otherwise face values are
            turned into vertex values (``"mean"``: area-weighted mean of the faces around a
            vertex; ``"linear"``: that mean plus an area-weighted least-squares gradient
            correction, exact for fields linear in space, each vertex held within the
            values of the faces it is built from so that no pixel leaves the range of
            the values around it) and interpolated barycentrically at the pixel's hit
            point. Only valued faces enter a vertex value, and the
            barycentric weights are renormalised over the corners that have a value (NaN
            where none): a missing value is never mixed in.

        Returns
        -------
        (H, W) or (T, H, W) float64
        """
        fv = _as_float(face_values, "face_values")
        nf = self.n_faces
        if fv.ndim == 1 and fv.shape[0] == nf:
            fv2, single = fv[None], True
        elif fv.ndim == 2 and fv.shape[1] == nf:
            fv2, single = fv, False
        else:
            raise InputError(
                f"face_values: shape {fv.shape} does not match the mesh's {nf} faces "
                "(expected (F,) or (T, F))"
            )
        if interpolation not in ("linear", "mean", "nearest"):
            raise InputError(
                f"interpolation must be 'linear', 'mean' or 'nearest', got {interpolation!r}"
            )
        T = fv2.shape[0]
        H, W = self.shape
        if background is None:
            out = np.full((T, H * W), np.nan)
        elif np.ndim(background) == 0:
            out = np.full((T, H * W), float(_as_float(background, "background")))
        else:
            bg, _ = self._check_images(_as_float(background, "background"), "background")
            if bg.shape[0] not in (1, T):
                raise InputError(f"background: {bg.shape[0]} images for {T} sets of face "
                                 "values (give one image, or one per set)")
            out = np.broadcast_to(bg.reshape(bg.shape[0], -1), (T, H * W)).astype(np.float64)
        hit, f = self._hit, self._hit_face
        if interpolation == "nearest":
            vals = fv2[:, f]
        else:
            vert = self.vertex_values(fv2.T, interpolation)  # (V, T)
            # barycentric weights renormalised over the corners that have a value: a
            # missing value is never mixed in (NaN where no corner has one)
            Mi = self._interpolation_matrix()
            valued = np.isfinite(vert)
            if valued.all():  # the usual case: the weights sum to 1 already
                vals = (Mi @ vert).T  # (T, pixels)
            else:
                num = Mi @ np.where(valued, vert, 0.0)
                den = Mi @ valued.astype(np.float64)
                with np.errstate(invalid="ignore", divide="ignore"):
                    vals = np.where(den > 1e-12, num / den, np.nan).T  # (T, pixels)
        good = np.isfinite(fv2[:, f])
        if good.all():
            out[:, hit] = vals
        else:
            rows, cols = np.nonzero(good)
            out[rows, hit[cols]] = vals[rows, cols]
        out = out.reshape(T, H, W)
        return out[0] if single else out


@numba.njit(cache=True, nogil=True)
def _splat_nodes(corners, bary, X, sums, weights, counts, total):  # pragma: no cover
    """One pass over the model pixels of T frames: pixel j (corners, barycentrics) adds
    ``w * X[t, j]`` and ``w`` to its face's three nodes (finite pixels only), and counts
    the pixels with a weight above 1e-12 (``total``: finite or not)."""
    for j in range(corners.shape[0]):
        for c in range(3):
            w = bary[j, c]
            node = corners[j, c]
            big = w > 1e-12
            if big:
                total[node] += 1
            for t in range(X.shape[0]):
                x = X[t, j]
                if np.isfinite(x):
                    sums[t, node] += w * x
                    weights[t, node] += w
                    if big:
                        counts[t, node] += 1
