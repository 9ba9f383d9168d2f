"""Targets, taps and transducers in a frame: the dark spots that must never darken a node.

Every point of the ``.tgts`` (``*Targets``, ``*Taps``, ``*Virtuals``/``*Kulites``) is a
circle of known diameter on the model. In each frame and camera it is projected with that
frame's pose; its radius in pixels comes from its diameter and its depth
(``r = d/2 f / z``, plus a margin of ``margin_px`` for the blur and the pose error). A spot
is handled only where the camera sees it: facing the camera and not hidden (the surface
point the pixel under its centre sees lies at the spot's distance).

Two ways, as uPSP's ``target_patcher`` option:

* ``none`` (:func:`mask_spots`): the pixels inside are NaN, left out of every face and node
  value (a node under a target gets its value from the painted pixels around it, or none);
* ``polynomial`` (:func:`patch_spots`): the pixels inside are replaced by a 2-D polynomial
  of order 3 fitted to a ring of ``ring_px`` pixels around the spot (uPSP's patch).

Both are vectorised over the spots (one window of offsets for all of them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from resection.errors import InputError
from selfillum.unsteady.options import PATCHERS  # re-exported

__all__ = ["DarkSpots", "project_spots", "mask_spots", "patch_spots", "PATCHERS"]


@dataclass(frozen=True)
class DarkSpots:
    """Circles on the model: ``ids``, ``xyz`` (M, 3), ``normals`` (M, 3) or None,
    ``diameter`` (M,) model units."""

    ids: tuple
    xyz: np.ndarray
    normals: np.ndarray | None
    diameter: np.ndarray

    @classmethod
    def from_markers(cls, ms, source: str = "targets") -> DarkSpots:
        """From a :class:`resection.io.markers.MarkerSet` (every row: targets, taps, Kulites)."""
        if ms.diameter is None or not np.all(np.isfinite(ms.diameter)):
            raise InputError(f"{source}: every target, tap and transducer needs a diameter "
                             "(their image size comes from it)")
        return cls(tuple(ms.ids), np.asarray(ms.xyz, float), None if ms.normals is None
                   else np.asarray(ms.normals, float), np.asarray(ms.diameter, float))

    def __len__(self) -> int:
        return len(self.ids)


def project_spots(spots: DarkSpots, smap, *, margin_px: float = 1.0):
    """Centres ``(m, 2)`` and radii ``(m,)`` (pixels) of the spots ``smap``'s camera sees.

    ``smap`` is the frame's :class:`resection.SurfaceMap` (its camera and its depth map).
    """
    cam = smap.camera
    if len(spots) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    Xc = cam.to_camera_frame(spots.xyz)
    z = Xc[:, 2]
    uv, ok = cam.project(spots.xyz, return_valid=True)
    ok = ok & (z > 0) & cam.in_image(uv)
    C = cam.center
    dist = np.linalg.norm(spots.xyz - C, axis=1)
    if spots.normals is not None:
        ok &= np.einsum("ij,ij->i", spots.normals, C[None, :] - spots.xyz) > 0
    H, W = smap.shape
    iu = np.clip(np.rint(uv[:, 0]), 0, W - 1).astype(np.int64)
    iv = np.clip(np.rint(uv[:, 1]), 0, H - 1).astype(np.int64)
    d_seen = smap.depth[iv, iu]
    tol = np.maximum(spots.diameter, 1e-3 * dist)
    ok &= np.isfinite(d_seen) & (np.abs(d_seen - dist) <= tol)
    f = 0.5 * (cam.K[0, 0] + cam.K[1, 1])
    r = 0.5 * spots.diameter * f / np.where(z > 0, z, np.inf) + margin_px
    return uv[ok], r[ok]


def _windows(shape, centres, radii, extra: float):
    H, W = shape
    R = int(np.ceil(radii.max() + extra)) if radii.size else 0
    o = np.arange(-R, R + 1)
    du, dv = np.meshgrid(o, o)
    du, dv = du.ravel(), dv.ravel()
    cu = np.rint(centres[:, 0]).astype(np.int64)
    cv = np.rint(centres[:, 1]).astype(np.int64)
    u = cu[:, None] + du[None, :]
    v = cv[:, None] + dv[None, :]
    d = np.hypot(u - centres[:, 0:1], v - centres[:, 1:2])
    inb = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    return np.clip(u, 0, W - 1), np.clip(v, 0, H - 1), d, inb, R


def mask_spots(image, centres, radii) -> np.ndarray:
    """A float copy of ``image`` with the pixels within ``radii`` of ``centres`` NaN."""
    img = np.array(image, dtype=np.float32 if np.asarray(image).dtype != np.float64
                   else np.float64)
    if len(radii) == 0:
        return img
    u, v, d, inb, _ = _windows(img.shape, np.asarray(centres), np.asarray(radii), 0.0)
    inside = inb & (d <= np.asarray(radii)[:, None])
    img[v[inside], u[inside]] = np.nan
    return img


def patch_spots(image, centres, radii, *, ring_px: float = 3.0, order: int = 3) -> np.ndarray:
    """A float copy of ``image`` with each spot's pixels replaced by a 2-D polynomial of
    ``order`` fitted to the finite pixels of a ring ``ring_px`` wide around it (spots whose
    ring holds too few pixels are masked, NaN, instead)."""
    img = np.array(image, dtype=np.float64)
    centres, radii = np.asarray(centres, float), np.asarray(radii, float)
    if len(radii) == 0:
        return img
    u, v, d, inb, R = _windows(img.shape, centres, radii, ring_px)
    inside = inb & (d <= radii[:, None])
    vals = img[v, u]
    ring = inb & (d > radii[:, None]) & (d <= radii[:, None] + ring_px) & np.isfinite(vals)
    s = max(R, 1)
    x = (u - centres[:, 0:1]) / s
    y = (v - centres[:, 1:2]) / s
    powers = [(i, j) for i in range(order + 1) for j in range(order + 1 - i)]
    A = np.stack([x**i * y**j for i, j in powers], axis=-1)  # (m, K, P)
    w = ring.astype(np.float64)
    M = np.einsum("mkp,mk,mkq->mpq", A, w, A) + 1e-9 * np.eye(len(powers))[None]
    b = np.einsum("mkp,mk->mp", A, w * np.where(ring, vals, 0.0))
    good = ring.sum(axis=1) >= 2 * len(powers)
    coef = np.zeros((len(radii), len(powers)))
    if good.any():
        coef[good] = np.linalg.solve(M[good], b[good][..., None])[..., 0]
    fit = np.einsum("mkp,mp->mk", A, coef)
    fit[~good] = np.nan
    img[v[inside], u[inside]] = fit[inside]
    return img
