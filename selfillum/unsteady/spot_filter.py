"""A moving model's filtered frame near its dark spots, as small sparse maps.

uPSP's order for a frame is: the dark spots patched (``target_patcher = polynomial``) or
left out (``none``), then the Gaussian filter (``filter = gaussian``), then the grid. For a
moving model (``registration = track``) the spots move with the model, so their pixels are
the reference's, carried with the frame's pose. The fast way reads a frame at the
reference's surface points (:meth:`selfillum.unsteady.fastmap.FrameOperator.samples`); with
the filter it reads the *filtered frame* there, and corrects the pixels the spots reach:

    F(P g) = F g + F (P g - g)

``g`` the frame read at the reference's pixels, ``P`` the patch, ``F`` the filter. The
filter of the frame read at the moved points, ``F g``, is taken as the frame filtered in its
own pixels and then read there, ``(F f)(project(X))``: the two are equal for a model that
translates in the image, and differ by the filter's radius times the warp's change across
it (a vibration of 0.15 degree: 3e-3 of a pixel's shift a pixel) elsewhere. ``P g - g`` is
nonzero only on the spots' pixels, so the second term is a sparse map of the frame read at
the spots' and their rings' pixels (a few thousand points, against the 850,000 of a
609,000-face model's frame):

* patched pixels ``j`` (their spot's polynomial, fitted on its ring: ``E C g``):
  ``sum_j w_ij ((E C g)_j - g_j)``;
* pixels left out ``n`` (``target_patcher = none``, or a spot whose ring could not be
  fitted): the filter's window renormalised without them, as the NaN-aware filter does,
  ``(F g - sum_n w_in g_n) / (1 - sum_n w_in)``.

Before this, the whole frame was carried back onto the reference's pixels (850,000 points
and a halo), patched there and filtered there with its NaN off the model: on the 609k run,
about 12 ms a frame more than the unfiltered tracked run. A spot's pixels' window is cut at
the frame's edge (the filter reflects there): a spot within the filter's radius of the
sensor's edge is corrected a little differently than the filter weighs it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from selfillum.unsteady._fastmap_kernels import column_entries

__all__ = ["SpotFilter", "spot_filter"]


@dataclass(frozen=True)
class SpotFilter:
    """What the dark spots change in a camera's filtered frame, read at a reference's
    pixels (see the module notes).

    Attributes
    ----------
    pixels : (n,) int
        The spots' and their rings' pixels (flat, ascending): the frame is read at their
        surface points.
    rows : (q,) int
        Positions in the operator's pixels (``cols``) that the spots change.
    coef : scipy.sparse.csr_matrix or None
        (m P, n): the spots' polynomial coefficients from the ring's values (None: no patch).
    gain : scipy.sparse.csr_matrix or None
        (q, m P): the filter's weights of the patched pixels times their terms.
    drop : scipy.sparse.csr_matrix
        (q, n): the filter's weights of the patched and left-out pixels (subtracted).
    scale : (q,) float
        1 over the filter's weights left in each window (1 where no pixel is left out).
    blank : (b,) int
        Positions in ``cols`` that are left out themselves (a spot's pixel with no fit).
    by_value : tuple of scipy.sparse.csc_matrix
        ``drop``, ``coef`` and ``gain`` by columns: the rows a value reaches, directly or
        through its spot's fit (a value not read: those rows are left out; kept by columns
        rather than as one (q, n) map, which holds every ring pixel of a spot against every
        row near it: 14 million entries on the 609k run's 28 targets).
    """

    pixels: np.ndarray
    rows: np.ndarray
    coef: object
    gain: object
    drop: object
    scale: np.ndarray
    blank: np.ndarray
    by_value: tuple

    def correct(self, x: np.ndarray, bad: np.ndarray, g: np.ndarray,
                g_bad: np.ndarray) -> None:
        """Correct in place the filtered frame's values ``x`` (over ``cols``) by the frame's
        values ``g`` at :attr:`pixels`' points (``g_bad``: not read, off the sensor); the
        pixels left out are set in ``bad``."""
        gb = np.flatnonzero(g_bad)
        if gb.size:
            g = np.where(g_bad, 0.0, g)
        corr = -(self.drop @ g)
        if self.coef is not None:
            corr += self.gain @ (self.coef @ g)
        x[self.rows] = (x[self.rows] + corr) * self.scale
        bad[self.blank] = True
        if gb.size:
            bad[self.rows[self.reached(gb)]] = True

    def reached(self, values) -> np.ndarray:
        """Positions in :attr:`rows` that the values ``values`` (indices into
        :attr:`pixels`) reach: through the filter's weights, and through their spots'
        fits."""
        drop, coef, gain = self.by_value
        hit = column_entries(drop, values)[0]
        if coef is not None:
            terms = np.unique(column_entries(coef, values)[0])
            hit = np.concatenate([hit, column_entries(gain, terms)[0]])
        return np.unique(hit)


def spot_filter(smap, cols: np.ndarray, spots, size: int) -> SpotFilter | None:
    """The :class:`SpotFilter` of a camera's reference map ``smap`` whose operator reads
    the pixels ``cols`` (flat, ascending), its spots ``spots`` (a
    :class:`~selfillum.unsteady.spots.PatchOperator`, or ``(centres, radii)`` left out, or
    None) and a Gaussian of ``size`` pixels. None when the spots change no pixel read."""
    from selfillum.unsteady.lowpass import gaussian_weights
    from selfillum.unsteady.spots import mask_spots

    H, W = smap.shape
    n_pix = H * W
    w1 = gaussian_weights(size)
    r = (w1.size - 1) // 2
    patch = spots if hasattr(spots, "inside") else None
    if patch is not None:
        patched = np.asarray(patch.inside, np.int64)
        left = np.flatnonzero(patch.unfit)
        C = sp.csc_matrix(patch.C)  # by pixels: the rings' pixels are its columns in use
        ring = np.flatnonzero(np.diff(C.indptr) > 0) if patch.inside.size else \
            np.zeros(0, np.int64)
    else:
        patched, ring = np.zeros(0, np.int64), np.zeros(0, np.int64)
        left = np.zeros(0, np.int64) if spots is None or len(spots[1]) == 0 else \
            np.flatnonzero(np.isnan(mask_spots(np.zeros((H, W), np.float32), *spots)))
    pts = np.unique(np.concatenate([patched, left, ring]))
    if pts.size == 0:
        return None
    # every pixel of the spots against every pixel of its filter's window that is read
    src = np.concatenate([patched, left])
    kind = np.r_[np.zeros(patched.size, bool), np.ones(left.size, bool)]  # True: left out
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    w2 = np.outer(w1, w1).ravel()
    sv, su = np.divmod(src, W)
    iv = sv[:, None] + dy.ravel()[None, :]
    iu = su[:, None] + dx.ravel()[None, :]
    inb = (iv >= 0) & (iv < H) & (iu >= 0) & (iu < W)
    pos = np.full(n_pix, -1, np.int64)
    pos[np.asarray(cols, np.int64)] = np.arange(len(cols))
    tgt = np.where(inb, pos[np.clip(iv, 0, H - 1) * W + np.clip(iu, 0, W - 1)], -1)
    si, ki = np.nonzero(tgt >= 0)
    if si.size == 0:
        return None
    rows, ri = np.unique(tgt[si, ki], return_inverse=True)
    wk = w2[ki]
    col = np.searchsorted(pts, src[si])
    q, n = rows.size, pts.size
    drop = sp.csr_matrix((wk, (ri, col)), shape=(q, n))
    lost = np.bincount(ri, np.where(kind[si], wk, 0.0), minlength=q)
    with np.errstate(divide="ignore"):
        scale = np.where(lost < 1.0 - 1e-9, 1.0 / (1.0 - lost), 0.0)
    blank = pos[left]
    blank = np.unique(np.r_[blank[blank >= 0], rows[scale == 0.0]])
    scale[scale == 0.0] = 1.0
    coef = gain = None
    if patch is not None and patched.size:
        P = patch.n_terms
        coef = sp.csr_matrix(C[:, pts])
        on = ~kind[si]  # the filter's weights of the patched pixels, times their terms
        order = np.argsort(patched, kind="stable")
        k_of = order[np.searchsorted(patched[order], src[si][on])]
        Fp = sp.csr_matrix((wk[on], (ri[on], k_of)), shape=(q, patched.size))
        E = sp.csr_matrix((patch.basis.ravel(), (np.repeat(np.arange(patched.size), P),
                                                 (patch.spot[:, None] * P
                                                  + np.arange(P)[None, :]).ravel())),
                          shape=(patched.size, coef.shape[0]))
        gain = sp.csr_matrix(Fp @ E)
    by_value = (sp.csc_matrix(drop), None if coef is None else sp.csc_matrix(coef),
                None if gain is None else sp.csc_matrix(gain))
    return SpotFilter(pts, rows, coef, gain, drop, scale, blank, by_value)
