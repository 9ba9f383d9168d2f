"""Image alignment through the model surface (wind-on onto wind-off).

A PSP ratio ``I_off / I_on`` needs the two images registered to a small fraction of a
pixel: the model moves and deforms under load, and a 1-pixel misregistration of a paint
layer with any texture ruins the ratio. With both poses known (resection of each image),
the images are registered through the model surface: for every pixel of camera B take
the surface point it sees (:class:`~resection.surface.SurfaceMap`), project it with camera
A (distortion included) and sample A's image there (``scipy.ndimage.map_coordinates``,
bilinear by default).

Conventions (docs/design.md): pixel centres at integer ``(u, v)``, ``img[v, u]``.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy import ndimage

from resection.camera.model import Camera
from resection.errors import InputError
from resection.surface.surface_map import SurfaceMap
from resection.surface.visibility import RayCaster

__all__ = ["ViewWarp", "warp_image"]


class ViewWarp:
    """Resampling of camera A's images into camera B's view through the model surface.

    The sampling positions are computed once, so warping every frame of a run costs one
    interpolation per frame.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Model surface in model units, in the pose it has in *both* images (for a model that
        moved between the images, express the motion as camera poses: ``camera_a`` and
        ``camera_b`` are the two resections against the same marker coordinates).
    camera_a : Camera
        Camera of the images to warp (e.g. wind-on).
    target : Camera or SurfaceMap
        Camera B (e.g. wind-off), or a prebuilt SurfaceMap of it on ``mesh``.
    occlusion : bool
        Leave out (NaN) surface points that camera A does not see because another part of
        the model hides them.

    Attributes
    ----------
    uv : (H_b, W_b, 2) float64
        Position in A's image sampled for each pixel of B (NaN where nothing is sampled:
        background of B, points behind or outside A, occluded points).
    """

    def __init__(self, mesh: trimesh.Trimesh, camera_a: Camera, target, *,
                 occlusion: bool = True):
        if not isinstance(camera_a, Camera):
            raise InputError(f"camera_a: expected a resection.Camera, got "
                             f"{type(camera_a).__name__}")
        caster = RayCaster(mesh)
        if isinstance(target, SurfaceMap):
            smap = target
            if len(smap.mesh.faces) != len(mesh.faces):
                raise InputError(f"target: SurfaceMap of a mesh of {len(smap.mesh.faces)} "
                                 f"faces, the mesh has {len(mesh.faces)}")
        elif isinstance(target, Camera):
            smap = SurfaceMap(mesh, target, caster=caster)
        else:
            raise InputError(f"target: expected a Camera or SurfaceMap, got "
                             f"{type(target).__name__}")
        self.camera_a = camera_a
        self.surface_map = smap
        self.shape = smap.shape
        self.source_shape = (camera_a.height, camera_a.width)
        H, W = smap.shape
        uv = np.full((H * W, 2), np.nan)
        hit = np.flatnonzero(smap.mask.ravel())
        pts = smap.points.reshape(-1, 3)[hit]
        proj = camera_a.project(pts)
        ok = camera_a.in_image(proj)
        if occlusion and hit.size:
            C = camera_a.center
            d = pts - C
            face, dist, _ = caster.first_hit(C, d)
            target_dist = np.linalg.norm(d, axis=1)
            own = smap.face_index.ravel()[hit]
            ok &= (face == own) | ((face >= 0) & (dist >= target_dist * (1 - 1e-6)))
        uv[hit[ok]] = proj[ok]
        self.uv = uv.reshape(H, W, 2)

    @property
    def valid(self) -> np.ndarray:
        """(H_b, W_b) bool: pixels of B that receive a value from A."""
        return np.isfinite(self.uv[..., 0])

    def __call__(self, image, *, order: int = 1, fill: float = np.nan) -> np.ndarray:
        """Warp one image (H_a, W_a) or a stack (T, H_a, W_a) of camera A into B's view.

        Parameters
        ----------
        order : int
            Spline order of ``scipy.ndimage.map_coordinates`` (1 = bilinear, 3 = cubic).
        fill : float
            Value of pixels of B that get nothing from A.
        """
        arr = np.asarray(image)
        Ha, Wa = self.source_shape
        if arr.ndim == 2 and arr.shape == (Ha, Wa):
            stack, single = arr[None], True
        elif arr.ndim == 3 and arr.shape[1:] == (Ha, Wa):
            stack, single = arr, False
        else:
            raise InputError(
                f"image: shape {arr.shape} does not match camera A's image (H, W) = "
                f"({Ha}, {Wa}) (or a stack (T, H, W))"
            )
        if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool) \
                or np.issubdtype(arr.dtype, np.complexfloating):
            raise InputError(f"image: expected real numbers, got dtype {arr.dtype}")
        if not (0 <= int(order) <= 5):
            raise InputError(f"order must be 0..5, got {order}")
        H, W = self.shape
        valid = self.valid.ravel()
        coords = np.vstack([self.uv[..., 1].ravel()[valid], self.uv[..., 0].ravel()[valid]])
        out = np.full((len(stack), H * W), float(fill))
        for k, frame in enumerate(stack):  # loop over frames; pixels are vectorised
            out[k, valid] = ndimage.map_coordinates(
                np.asarray(frame, dtype=np.float64), coords, order=int(order),
                mode="nearest", prefilter=int(order) > 1,
            )
        out = out.reshape(len(stack), H, W)
        return out[0] if single else out


def warp_image(image, mesh: trimesh.Trimesh, camera_a: Camera, camera_b: Camera, *,
               order: int = 1, occlusion: bool = True, fill: float = np.nan) -> np.ndarray:
    """Warp ``image`` of ``camera_a`` into ``camera_b``'s view through ``mesh``.

    For every pixel of B: the surface point it sees, projected with A, sampled in A's
    image (``order`` 1 = bilinear). Pixels of B off the model, outside A's image or hidden
    from A get ``fill``. See :class:`ViewWarp` to warp many frames with the same poses.
    """
    return ViewWarp(mesh, camera_a, camera_b, occlusion=occlusion)(image, order=order,
                                                                  fill=fill)
