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

import numba
import numpy as np

from resection.errors import InputError
from selfillum.unsteady.options import PATCHERS  # re-exported

__all__ = ["DarkSpots", "project_spots", "mask_spots", "patch_spots", "patch_operator",
           "PatchOperator", "PATCHERS"]


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


@dataclass(frozen=True)
class PatchOperator:
    """uPSP's polynomial patch of an image's dark spots as linear maps (see
    :func:`patch_operator`).

    Attributes
    ----------
    shape : (H, W)
    inside : (n,) int
        The patched pixels (flat indices), each once.
    spot : (n,) int
        The spot whose fit each patched pixel takes.
    basis : (n, P) float
        The polynomial's terms at each patched pixel.
    C : scipy.sparse.csr_matrix
        (m P, H W): each spot's polynomial coefficients from its ring's pixels (rows of a
        spot that could not be fitted are empty).
    unfit : (H W,) bool
        Pixels of spots whose ring holds too few usable pixels (NaN once patched).
    """

    shape: tuple
    inside: np.ndarray
    spot: np.ndarray
    basis: np.ndarray
    C: object
    unfit: np.ndarray

    @property
    def n_terms(self) -> int:
        return self.basis.shape[1]

    def expand(self):
        """(H W, m P) sparse: a patched pixel's value from the spots' coefficients."""
        import scipy.sparse as sp

        P = self.n_terms
        n = self.inside.size
        return sp.csr_matrix((self.basis.ravel(), (np.repeat(self.inside, P),
                                                    (self.spot[:, None] * P
                                                     + np.arange(P)[None, :]).ravel())),
                             shape=(self.shape[0] * self.shape[1], self.C.shape[0])) \
            if n else sp.csr_matrix((self.shape[0] * self.shape[1], self.C.shape[0]))

    def apply(self, image, *, in_place: bool = False) -> np.ndarray:
        """The image (float64) with its spots patched; NaN where a spot could not be fitted
        and where a pixel that is not patched is not finite. ``in_place``: ``image`` (a
        C-contiguous float64 array the caller owns) is patched itself, not a copy.

        One compiled pass: the spots' coefficients from their rings (a value that is not
        finite weighs zero), then the patched pixels, the unfitted spots and the other
        values that are not finite; no whole-frame temporaries."""
        x = np.asarray(image)
        if not (in_place and x.dtype == np.float64 and x.flags.c_contiguous):
            x = np.array(x, dtype=np.float64, order="C")
        C = self.C
        _patch_into(x.reshape(-1), C.indptr, C.indices, C.data, self.basis, self.spot,
                    self.inside, self._unfit_pixels, self.n_terms)
        return x

    @property
    def _unfit_pixels(self) -> np.ndarray:
        got = self.__dict__.get("_unfit_idx")
        if got is None:  # computed once (the dataclass is frozen: kept in its dict)
            got = self.__dict__["_unfit_idx"] = np.flatnonzero(self.unfit)
        return got


@numba.njit(cache=True, nogil=True)
def _patch_into(x, indptr, indices, data, basis, spot, inside, unfit, nP):  # pragma: no cover
    """:meth:`PatchOperator.apply` on the flat image ``x`` in place."""
    coef = np.zeros(indptr.size - 1)
    for r in range(indptr.size - 1):
        s = 0.0
        for k in range(indptr[r], indptr[r + 1]):
            v = x[indices[k]]
            if v - v == 0.0:  # finite
                s += data[k] * v
        coef[r] = s
    for p in range(x.size):  # the unpatched values that are not finite: NaN
        if not (x[p] - x[p] == 0.0):
            x[p] = np.nan
    for i in range(inside.size):
        s = 0.0
        c0 = spot[i] * nP
        for q in range(nP):
            s += basis[i, q] * coef[c0 + q]
        x[inside[i]] = s
    for i in range(unfit.size):
        x[unfit[i]] = np.nan


def patch_operator(shape, centres, radii, *, ring_px: float = 3.0, order: int = 3,
                   finite=None) -> PatchOperator:
    """uPSP's polynomial patch as linear maps on the image's pixels.

    Each spot's pixels become a 2-D polynomial of ``order`` fitted (least squares) to the
    pixels of a ring ``ring_px`` wide around it. The fit's coefficients are linear in the
    ring's pixels (``coef = C image``), and a patched pixel is its terms times its spot's
    coefficients: the patched image is ``image`` off the spots and ``basis coef[spot]`` on
    them. A pixel inside several spots takes the last one's fit (as a fancy assignment
    does). Kept low-rank, it costs the ring's pixels times the terms, not the spot's pixels
    times its ring's.

    Parameters
    ----------
    shape : (H, W)
    centres : (m, 2) array_like
        Pixels.
    radii : (m,) array_like
        Pixels.
    ring_px : float
    order : int
    finite : (H, W) bool, optional
        Pixels usable in a ring (default all).

    Returns
    -------
    PatchOperator
    """
    import scipy.sparse as sp

    H, W = shape
    n = H * W
    centres, radii = np.asarray(centres, float).reshape(-1, 2), np.asarray(radii, float)
    powers = [(i, j) for i in range(order + 1) for j in range(order + 1 - i)]
    nP = len(powers)
    if len(radii) == 0:
        return PatchOperator((H, W), np.zeros(0, np.int64), np.zeros(0, np.int64),
                             np.zeros((0, nP)), sp.csr_matrix((0, n)), np.zeros(n, bool))
    u, v, d, inb, R = _windows(shape, centres, radii, ring_px)
    inside = inb & (d <= radii[:, None])
    ring = inb & (d > radii[:, None]) & (d <= radii[:, None] + ring_px)
    if finite is not None:
        ring &= np.asarray(finite, bool)[v, u]
    s = max(R, 1)
    x = (u - centres[:, 0:1]) / s
    y = (v - centres[:, 1:2]) / s
    A = np.stack([x**i * y**j for i, j in powers], axis=-1)  # (m, K, P)
    w = ring.astype(np.float64)
    M = np.einsum("mkp,mk,mkq->mpq", A, w, A) + 1e-9 * np.eye(nP)[None]
    good = ring.sum(axis=1) >= 2 * nP
    pix = v * W + u  # (m, K)
    # coefficients from the ring: Minv A^T w, only on ring pixels (m, P, K)
    mi, ki = np.nonzero(ring & good[:, None])
    Minv = np.zeros_like(M)
    if good.any():
        Minv[good] = np.linalg.inv(M[good])
    cw = np.einsum("npq,nq->np", Minv[mi], A[mi, ki]) * w[mi, ki][:, None]  # (r, P)
    C = sp.csr_matrix((cw.ravel(), ((mi[:, None] * nP + np.arange(nP)[None, :]).ravel(),
                                    np.repeat(pix[mi, ki], nP))), shape=(len(radii) * nP, n))
    # the patched pixels: the last spot's fit wins where spots overlap
    mi, ki = np.nonzero(inside)
    row_pix = pix[mi, ki]
    order_ = np.arange(len(row_pix))
    last = np.full(n, -1, np.int64)
    last[row_pix] = order_
    keep = last[row_pix] == order_
    mi, ki, row_pix = mi[keep], ki[keep], row_pix[keep]
    unfit = np.zeros(n, bool)
    unfit[row_pix[~good[mi]]] = True
    ok = good[mi]
    return PatchOperator((H, W), row_pix[ok], mi[ok], A[mi[ok], ki[ok]], C, unfit)


def patch_spots(image, centres, radii, *, ring_px: float = 3.0, order: int = 3) -> np.ndarray:
    """A float copy of ``image`` with each spot's pixels replaced by a 2-D polynomial of
    ``order`` fitted to the finite pixels of a ring ``ring_px`` wide around it (spots whose
    ring holds too few pixels are masked, NaN, instead): :func:`patch_operator` applied."""
    img = np.array(image, dtype=np.float64)
    if len(np.asarray(radii)) == 0:
        return img
    return patch_operator(img.shape, centres, radii, ring_px=ring_px, order=order,
                          finite=np.isfinite(img)).apply(img)
