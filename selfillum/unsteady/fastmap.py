"""Phase 1 of a frame as sparse products: no ray cast, no pixel weights, per frame.

For a reference frame the full map (:func:`selfillum.unsteady.phase1.map_run`'s slow path:
a :class:`resection.SurfaceMap` per camera, dark spots, :func:`resection.surface.merge.
merge_views`) fixes, per camera ``c``, which pixel sees which face, each pixel's weight
(feathering, edges, spots left out: zero) and each face's camera weight (view angle). With
the cameras' gains fixed on frame 0 (as the slow path keeps them), the merged face value is
then *linear* in the images::

    B = sum_c A_c img_c,   A_c = diag(coef_c) S_c

``S_c[f, p]`` the weight of pixel ``p`` on face ``f``, ``coef_c`` the camera's share on the
face over its gain and its weight sum (``average_view``/``merge``) or 1 / (gain x weight sum)
on the faces where it is the best camera (``best_view``). A frame then costs one sparse
product a camera; this equals the slow path to rounding when the pose is the reference's
(``registration = none`` or ``first-frame``: the map is frame 0's).

For a moving model (``registration = track``) the frame's pose differs from the
reference's: each pixel's surface point ``X_p`` (hit at the reference) is projected with the
frame's own pose and the frame is sampled there (bilinear), i.e. the image is carried back
onto the reference's pixels through the model: ``B = sum_c A_c img_c(project_k(X))``.
What this leaves out: visibility and view angles changing with the pose (held at the
reference), so the reference is cast anew (the slow path for that frame) when a point
moves by more than ``refresh_px`` pixels from where the reference saw it. The spots move
with the model, so frame 0's spot pixels stay the right ones.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["FrameOperator"]


class FrameOperator:
    """Per camera the (F, P) operator of the merge (see the module notes).

    Parameters
    ----------
    maps : sequence of SurfaceMap
        The reference frame's maps, one a camera.
    finite : sequence of (H, W) bool
        Pixels usable in the reference frame (dark spots are False).
    merge_kw : dict
        ``method``, ``feather_px``, ``edge_margin`` as given to ``merge_views``.
    gains : (C,) array_like
        The cameras' gains (frame 0's).
    unpainted : (F,) bool, optional
    sample_points : bool
        Keep each used pixel's surface point (a moving model).
    """

    def __init__(self, maps, finite, merge_kw: dict, gains, unpainted=None, *,
                 sample_points: bool = False):
        from resection.surface.merge import angle_weights, pixel_weights

        nf = maps[0].n_faces
        C = len(maps)
        method = merge_kw.get("method", "weighted")
        S, wsum, wts = [], np.zeros((C, nf)), np.zeros((C, nf))
        for c, m in enumerate(maps):  # a few cameras
            pw = pixel_weights(m, feather_px=merge_kw.get("feather_px"),
                               edge_margin=merge_kw.get("edge_margin", 1))
            pw = np.where(finite[c], pw, 0.0).ravel()
            fi = m.face_index.ravel()
            hit = np.flatnonzero((fi >= 0) & (pw > 0))
            Sc = sp.csr_matrix((pw[hit], (fi[hit], hit)), shape=(nf, pw.size))
            wsum[c] = np.bincount(fi[hit], pw[hit], minlength=nf)
            npx = np.bincount(fi[hit], minlength=nf)
            ang = angle_weights(m)
            ok = (npx >= 1) & (wsum[c] > 0) & (ang > 0)
            wts[c] = np.where(ok, wsum[c] * ang, 0.0)
            S.append(Sc)
        g = np.asarray(gains, dtype=np.float64)
        self.gains = g
        total = wts.sum(axis=0)
        seen = total > 0
        best = np.argmax(wts, axis=0)
        self.A, self.cols, self.X, self.uv0 = [], [], [], []
        with np.errstate(invalid="ignore", divide="ignore"):
            for c in range(C):
                if method == "best":
                    coef = np.where(seen & (best == c), 1.0 / (g[c] * wsum[c]), 0.0)
                else:
                    coef = np.where(wts[c] > 0, wts[c] / (g[c] * wsum[c] * total), 0.0)
                A = (sp.diags(coef) @ S[c]).tocsc()
                used = np.flatnonzero(np.diff(A.indptr) > 0)  # pixels that count
                self.cols.append(used)
                self.A.append(sp.csr_matrix(A[:, used]))
                if sample_points:
                    X = maps[c].points.reshape(-1, 3)[used]
                    self.X.append(X)
                    self.uv0.append(maps[c].camera.project(X))
        self.seen = seen if unpainted is None else seen & ~np.asarray(unpainted, bool)

    def faces(self, images) -> np.ndarray | None:
        """Face values of a frame whose pose is the reference's; None when a pixel that
        counts is not finite in it (the caller maps that frame the full way)."""
        B = np.zeros(self.A[0].shape[0])
        for A, used, img in zip(self.A, self.cols, images, strict=True):
            x = np.asarray(img, dtype=np.float64).ravel()[used]
            if not np.isfinite(x).all():
                return None
            B += A @ x
        return B

    def faces_moved(self, images, cameras, refresh_px: float) -> np.ndarray | None:
        """Face values of a frame of pose ``cameras`` (one a camera): the images sampled
        (bilinear) where the reference's surface points project; None when a point moved
        more than ``refresh_px`` or falls outside its image (the caller casts anew)."""
        from scipy.ndimage import map_coordinates

        B = np.zeros(self.A[0].shape[0])
        for A, X, uv0, img, cam in zip(self.A, self.X, self.uv0, images, cameras,
                                       strict=True):
            uv = cam.project(X)
            if not np.all(np.isfinite(uv)):
                return None
            if np.max(np.abs(uv - uv0)) > refresh_px:
                return None
            arr = np.asarray(img, dtype=np.float64)
            H, W = arr.shape
            if (uv.min(axis=0) < -0.5).any() or uv[:, 0].max() > W - 0.5 \
                    or uv[:, 1].max() > H - 0.5:  # off the sensor (pixel edges)
                return None
            x = map_coordinates(arr, [uv[:, 1], uv[:, 0]], order=1, mode="nearest",
                                prefilter=False)
            if not np.isfinite(x).all():
                return None
            B += A @ x
        return B
