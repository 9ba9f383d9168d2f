"""Per-pixel quantities carried onto the faces with the weights of the cameras' merge.

:func:`resection.surface.merge.merge_views` makes each face's value a linear combination of
pixels: per camera ``c`` the feathered mean ``sum_k w_k x_k / sum_k w_k`` over the pixels
``k`` that see the face, then the cameras' values (divided by their gains) averaged with the
per-face weights ``W_c / sum_c W_c``. :class:`MergeWeights` holds those coefficients so
that a pixel variance (independent pixels: squared coefficients) or a pixel sensitivity
(linear: the coefficients themselves) goes onto the faces exactly as the values did.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MergeWeights"]


@dataclass
class MergeWeights:
    """The merge's pixel and camera weights.

    Attributes
    ----------
    maps : list of SurfaceMap
    pixel : list of (H_c, W_c) float64
        Each camera's pixel weights (0 off the model, on dropped or non-finite pixels).
    camera : (C, F) float64
        ``W_c / (g_c sum_c W_c)``: each camera's share of a face, its gain divided out
        (for values in counts).
    share : (C, F) float64
        ``W_c / sum_c W_c`` (for relative quantities, which the gains do not scale).
    """

    maps: list
    pixel: list
    camera: np.ndarray
    share: np.ndarray

    @classmethod
    def from_merge(cls, maps, images, merged, edge_margin: int = 1,
                   pixel_weights_=None) -> MergeWeights:
        """The weights :func:`selfillum.images.multiview.merge_views` used for ``images``
        (``merged`` its result; the default options); ``pixel_weights_``: the merge's
        :func:`resection.surface.merge.pixel_weights` per camera, when known."""
        from resection.surface.merge import pixel_weights

        pix = []
        for c, (m, img) in enumerate(zip(maps, images, strict=True)):
            pw = pixel_weights(m, edge_margin=edge_margin) if pixel_weights_ is None \
                else pixel_weights_[c]
            pix.append(np.where(np.isfinite(np.asarray(img, np.float64)), pw, 0.0))
        W = np.asarray(merged.camera_weights, np.float64)
        tot = W.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            share = np.where(tot > 0, W / np.where(tot > 0, tot, 1.0), 0.0)
        return cls(list(maps), pix, share / np.asarray(merged.gains, np.float64)[:, None],
                   share)

    def _camera_sums(self, c: int, planes: np.ndarray) -> np.ndarray:
        """``sum_k coef_k x_k`` per face for ``planes`` (P, H, W), ``coef`` = the pixel
        weights (first plane is the weights themselves)."""
        m = self.maps[c]
        f = m.face_index.ravel()
        hit = f >= 0
        nf = m.n_faces
        return np.stack([np.bincount(f[hit], weights=p.ravel()[hit], minlength=nf)
                         for p in planes])

    def mean(self, per_camera_planes, relative: bool = False) -> np.ndarray:
        """Merged face value of pixel quantities: ``per_camera_planes[c]`` (P, H, W) ->
        (P, F), each plane combined as the merge combines the images (NaN pixels as 0);
        ``relative``: quantities relative to the value (the gains left out)."""
        out = None
        coef = self.share if relative else self.camera
        for c, planes in enumerate(per_camera_planes):
            pw = self.pixel[c]
            x = np.nan_to_num(np.asarray(planes, np.float64))
            s = self._camera_sums(c, np.concatenate([pw[None], pw[None] * x]))
            with np.errstate(invalid="ignore", divide="ignore"):
                v = np.where(s[0] > 0, s[1:] / np.where(s[0] > 0, s[0], 1.0), 0.0)
            part = v * coef[c]
            out = part if out is None else out + part
        return out

    def variance(self, per_camera_var) -> np.ndarray:
        """Variance (F,) of the merged face value of independent pixels of variance
        ``per_camera_var[c]`` (H, W)."""
        out = 0.0
        for c, var in enumerate(per_camera_var):
            pw = self.pixel[c]
            x = np.nan_to_num(np.asarray(var, np.float64))
            s = self._camera_sums(c, np.stack([pw, pw * pw * x]))
            with np.errstate(invalid="ignore", divide="ignore"):
                v = np.where(s[0] > 0, s[1] / np.where(s[0] > 0, s[0], 1.0) ** 2, 0.0)
            out = out + v * self.camera[c] ** 2
        return np.asarray(out, np.float64)
