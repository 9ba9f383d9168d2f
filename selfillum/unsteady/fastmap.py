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

Without the self-illumination removal the faces are only a step on the way to the nodes
(the area-weighted mean of the seen faces around each node, ``Wn``): a fixed map then goes
from pixels to nodes in one product a camera, ``nodes = sum_c (Wn A_c) img_c``
(:meth:`FrameOperator.nodes`), reading the video's counts as they are stored.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from selfillum.unsteady._fastmap_kernels import column_entries, project_sample, spmv_kernel

__all__ = ["FrameOperator", "PixelValues"]


class PixelValues:
    """A frame given as the values of the operator's pixels only (``cols`` of a camera, in
    their order): a warped frame sampled where it is read, not as a whole image."""

    __slots__ = ("values",)

    def __init__(self, values):
        self.values = np.asarray(values, dtype=np.float64)


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
    pre : sequence of PatchOperator or None, optional
        Per camera uPSP's polynomial patch of the dark spots
        (:func:`selfillum.unsteady.spots.patch_operator`), applied before the merge. It is
        linear and low-rank: ``B_c = A_c x + A2_c (C_c x)``, ``C_c`` the spots'
        coefficients from their rings' pixels, ``A2_c`` the merge's weights of the patched
        pixels times their polynomial terms. A ring pixel that sees no surface (a spot on
        the silhouette) is sampled where it is: the background does not move with the
        model.
    filter_size : int
        A moving model whose frames are filtered (uPSP's Gaussian of this size, pixels; 0:
        none): each frame is filtered in its own pixels and read at the points, and the
        pixels its dark spots reach are corrected (:mod:`selfillum.unsteady.spot_filter`).
    spots : sequence, optional
        With ``filter_size``, per camera its dark spots in the reference: a
        :class:`~selfillum.unsteady.spots.PatchOperator`, ``(centres, radii)`` left out, or
        None.
    """

    def __init__(self, maps, finite, merge_kw: dict, gains, unpainted=None, *,
                 sample_points: bool = False, pre=None, filter_size: int = 0,
                 spots=None):
        from resection.surface.merge import angle_weights, pixel_weights
        from selfillum.unsteady.spot_filter import spot_filter

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
        self.filter_size = int(filter_size) if sample_points else 0
        self.spot_filters = []  # per camera, a filtered moving frame's spots (or None)
        self.patch = []  # per camera None, or (A2, C over used, C over pixels, Aw)
        with np.errstate(invalid="ignore", divide="ignore"):
            for c in range(C):
                if method == "best":
                    coef = np.where(seen & (best == c), 1.0 / (g[c] * wsum[c]), 0.0)
                else:
                    coef = np.where(wts[c] > 0, wts[c] / (g[c] * wsum[c] * total), 0.0)
                A = sp.csc_matrix(sp.diags(coef) @ S[c])
                pat = None if pre is None else pre[c]
                if pat is not None and pat.inside.size:
                    A, A2, Aw = _split_patch(A, pat)
                    Cp = sp.csc_matrix(pat.C)
                    used = np.flatnonzero((np.diff(A.indptr) > 0)
                                          | (np.diff(Cp.indptr) > 0))
                    self.patch.append((A2, sp.csr_matrix(Cp[:, used]),
                                       sp.csr_matrix(pat.C), Aw))
                else:
                    A.eliminate_zeros()
                    used = np.flatnonzero(np.diff(A.indptr) > 0)  # pixels that count
                    self.patch.append(None)
                self.cols.append(used)
                self.A.append(sp.csr_matrix(A[:, used]))
                if sample_points:
                    X_all = maps[c].points.reshape(-1, 3)  # computed a call: once
                    X = X_all[used]
                    uv0 = _reference_pixels(maps[c], used, X)
                    self.X.append(X)
                    self.uv0.append(uv0.astype(np.float32))
                    if self.filter_size:  # (SpotFilter, its pixels' X and uv0) or None
                        sf = spot_filter(maps[c], used, None if spots is None else spots[c],
                                         self.filter_size)
                        if sf is not None:
                            Xs = X_all[sf.pixels]
                            sf = (sf, Xs, _reference_pixels(maps[c], sf.pixels, Xs)
                                  .astype(np.float32))
                        self.spot_filters.append(sf)
        # a sample of each camera's surface points: the probes that plan the references
        self.probe = []
        for X in self.X:
            on = np.flatnonzero(np.isfinite(X[:, 0]))
            self.probe.append(on[np.linspace(0, max(on.size - 1, 0),
                                             min(on.size, 256)).astype(np.int64)])
        self.seen = seen if unpainted is None else seen & ~np.asarray(unpainted, bool)
        self._nodes = None
        self.frame = None  # the reference's frame number, and the last frame that used it
        self.last_used = -1
        self._shares: dict = {}
        self._filtered_images: dict = {}  # per camera, :meth:`_filtered`
        self._direct = None
        self.workers = None  # threads of the products (default: the available cores)

    def node_matrix(self, W, grid):
        """(N, S) sparse over the ``S`` seen faces ``seen_faces``: the area-weighted mean
        of the seen faces around each grid node (rows of nodes with no seen face are
        empty: ``node_unseen``), built once."""
        if self._nodes is None:
            self.seen_faces = np.flatnonzero(self.seen)
            Ws = sp.csc_matrix(W)[:, self.seen_faces]
            den = np.asarray(Ws.sum(axis=1)).ravel()
            with np.errstate(divide="ignore"):
                inv = np.where(den > 0, 1.0 / den, 0.0)
            Wv = sp.diags(inv) @ Ws
            self._nodes = sp.csr_matrix(Wv[grid.node_vertex])
            self.node_unseen = (den == 0)[grid.node_vertex]
        return self._nodes

    def seen_node_rows(self, W, grid, by_columns: bool = False):
        """``(Wr, rows)``: :meth:`node_matrix`'s non-empty rows and their node numbers,
        built once: a frame's products over the nodes it can give a value (a quarter of a
        model's nodes for one camera), not over every node. ``by_columns``: ``Wr`` as a
        CSC matrix alone (the nodes around a few faces)."""
        if "seen_rows" not in self._shares:
            Wn = self.node_matrix(W, grid)
            rows = np.flatnonzero(~self.node_unseen)
            self._shares["seen_rows"] = (sp.csr_matrix(Wn[rows]), rows)
        if by_columns:
            if "seen_rows_csc" not in self._shares:
                self._shares["seen_rows_csc"] = sp.csc_matrix(self._shares["seen_rows"][0])
            return self._shares["seen_rows_csc"]
        return self._shares["seen_rows"]

    def nodes(self, images, W, grid) -> np.ndarray | None:
        """Node values (N,) float32 (NaN where no seen face) of a frame whose pose is the
        reference's, without the SI removal: one product a camera from its pixels (counts
        read as stored) to the nodes, ``Wn A_c`` (built once; the same sums as
        :meth:`faces` then :meth:`node_matrix`, in another order). None when a pixel that
        counts is not finite (the caller maps that frame the full way)."""
        if any(isinstance(img, PixelValues) for img in images):
            return None  # a warped frame's pixels: the faces' way
        if self._direct is None:
            Wn = self.node_matrix(W, grid)  # over the seen faces
            ops, self._direct_patch = [], []
            for A, used, pt in zip(self.A, self.cols, self.patch, strict=True):
                M = sp.csr_matrix(Wn @ A[self.seen_faces])
                M.sort_indices()
                # int32 pixel numbers and float32 weights (summed in float64): half the
                # bytes a frame reads
                ops.append((M.indptr.astype(np.int64), used[M.indices].astype(np.int32),
                            M.data.astype(np.float32)))
                self._direct_patch.append(None if pt is None else
                                          (sp.csr_matrix(Wn @ pt[0][self.seen_faces]),
                                           pt[2]))
            self._direct = ops
        from resection._threads import run_blocks, split_range

        N = len(self.node_unseen)
        out = np.zeros(N, np.float32)
        kern = spmv_kernel()
        for c, ((indptr, cols, data), img) in enumerate(zip(self._direct, images,
                                                             strict=True)):
            x = np.asarray(img)
            if x.dtype.kind not in "fiu" or x.dtype == np.float16:
                x = x.astype(np.float64)
            args = (indptr, cols, data, np.ascontiguousarray(x).ravel(), out)
            ok = run_blocks(lambda b, args=args, add=c > 0: kern(*args, b[0], b[1], add),
                            split_range(N, self.workers, min_size=65536), self.workers)
            if not all(ok):
                return None
            if self._direct_patch[c] is not None:  # the patched spots: M2 (C img)
                M2, Cpix = self._direct_patch[c]
                coef = Cpix @ args[3]
                if not np.isfinite(coef).all():
                    return None
                out += (M2 @ coef).astype(np.float32)
        out[self.node_unseen] = np.nan
        return out

    def faces(self, images) -> np.ndarray:
        """Face values of a frame whose pose is the reference's. A pixel that counts and
        is not finite in it (warped in from beyond the frame's edge) is left out, as
        :meth:`samples` leaves out a point off the sensor."""
        B = np.zeros(self.A[0].shape[0])
        for c, (used, img) in enumerate(zip(self.cols, images, strict=True)):
            x = img.values if isinstance(img, PixelValues) else \
                np.asarray(img, dtype=np.float64).ravel()[used]
            B += self._camera_faces(c, x, ~np.isfinite(x))
        return B

    def _share(self, c) -> np.ndarray:
        """Row sums of camera ``c``'s operator (its share of each face), kept."""
        if c not in self._shares:
            sh = np.asarray(self.A[c].sum(axis=1)).ravel()
            if self.patch[c] is not None:  # the patched pixels' weights
                sh = sh + np.asarray(self.patch[c][3].sum(axis=1)).ravel()
            self._shares[c] = sh
        return self._shares[c]

    def samples(self, images, cameras, refresh_px: float,
                workers: int | None = None, share=None) -> list | None:
        """A moving model's frame of pose ``cameras`` (one a camera) read at the
        reference's pixels: the images sampled (bilinear) where the reference's surface
        points project (the camera's own projection with its distortion,
        :meth:`resection.Camera.project`). Per camera ``(x, bad)``: the values of its
        operator's pixels and those left out (off the sensor, not finite), for
        :meth:`faces_of_samples`; None when a point moved more than twice ``refresh_px``
        (the reference was chosen on a sample of its points,
        :func:`selfillum.unsteady.references.plan_references`: the caller casts anew). A
        face that keeps none of a camera's pixels is NaN there.

        With ``filter_size``, the frame is filtered in its own pixels before it is read,
        and the pixels its dark spots reach are corrected for the patch (or the spots left
        out) before the filter, as uPSP orders them (:mod:`.spot_filter`). Reads only the
        operator's arrays (and a buffer a camera for the filtered frame): the part a helper
        thread makes for the next frame, one frame at a time; ``workers``: threads of the
        projection and the filter (default: the cores); ``share``: a
        :class:`~selfillum.unsteady.frames.Helping` whose caller takes blocks of the
        projection while it waits (instead of ``workers``)."""
        from selfillum.unsteady.lowpass import gaussian_lowpass

        out = []
        for c, (X, uv0, img, cam) in enumerate(zip(self.X, self.uv0, images, cameras,
                                                   strict=True)):
            src = np.asarray(img)
            if self.filter_size:
                src = gaussian_lowpass(src, self.filter_size, workers,
                                       out=self._filtered(c, src.shape), share=share)
            x, status = _sample_moved(X, uv0, src, cam, refresh_px, workers, share)
            if status is None:
                return None
            bad = _left_out(status, x, src)
            sf = self.spot_filters[c] if self.filter_size else None
            if sf is not None:
                sf, Xs, uvs = sf
                g, st = _sample_moved(Xs, uvs, img, cam, refresh_px, workers)
                if st is None:
                    return None
                sf.correct(x, bad, g, _left_out(st, g, img))
            out.append((x, bad))
        return out

    def _filtered(self, c: int, shape) -> np.ndarray:
        """Camera ``c``'s filtered frame: one float64 image kept from frame to frame (a
        frame neither allocates nor first touches it). :meth:`samples` runs one frame at a
        time."""
        bufs = self._filtered_images
        if c not in bufs or bufs[c].shape != tuple(shape):
            bufs[c] = np.empty(shape)
        return bufs[c]

    def faces_of_samples(self, samples) -> np.ndarray:
        """The face values from :meth:`samples`' values: every camera's part summed."""
        B = np.zeros(self.A[0].shape[0])
        for c, (x, bad) in enumerate(samples):
            B += self._camera_faces(c, x, bad)
        return B

    def _columns(self, c, patch: bool = False):
        """Camera ``c``'s operator (or its patch's coefficients) by columns, kept: the
        columns of a few pixels read cheaply."""
        key = ("C" if patch else "A", c)
        if key not in self._shares:
            M = self.patch[c][1] if patch else self.A[c]
            self._shares[key] = sp.csc_matrix(M)
        return self._shares[key]

    def _camera_faces(self, c, x, bad) -> np.ndarray:
        """Camera ``c``'s part of the face values from its pixels' values ``x`` (over
        ``cols[c]``). Pixels ``bad`` (off the sensor, NaN after a warp) are left out, the
        face's other pixels of this camera taking their weight; a face left without any
        pixel of a camera that had a share is NaN (not seen in this frame). A patched spot
        whose ring lost a pixel is left out as a whole. ``x`` is the caller's to give
        away: its ``bad`` values are set to 0 in place (a few hundred of 850,000 points in
        a moving frame: no copy of the frame's values)."""
        A, pt = self.A[c], self.patch[c]
        bi = np.flatnonzero(bad)  # few: the weight they leave, by their columns only
        if bi.size == 0:
            out = A @ x
            if pt is not None:
                out += pt[0] @ (pt[1] @ x)
            return out
        share = self._share(c)
        x[bi] = 0.0
        rows, lost_w = column_entries(self._columns(c), bi)
        num = A @ x
        if pt is not None:
            A2, Cu, _, Aw = pt
            nP = Cu.shape[0] // Aw.shape[1]
            lost = np.zeros(Aw.shape[1], bool)
            lost[column_entries(self._columns(c, patch=True), bi)[0] // nP] = True
            coef = (Cu @ x).reshape(-1, nP)
            coef[lost] = 0.0
            num += A2 @ coef.ravel()
            if lost.any():  # the spots' weights, by their columns
                r2, w2 = column_entries(sp.csc_matrix(Aw), np.flatnonzero(lost))
                rows, lost_w = np.concatenate([rows, r2]), np.concatenate([lost_w, w2])
        # only the faces that lost a pixel change: their sum scaled to their whole share
        # (NaN when none is left), not passes over every face
        r, inv = np.unique(rows, return_inverse=True)
        kept = share[r] - np.bincount(inv, lost_w, minlength=r.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            num[r] = np.where(kept > 1e-12 * share[r], num[r] * (share[r] / kept), np.nan)
        return num


def _sample_moved(X, uv0, img, cam, refresh_px, workers=None, share=None):
    """``(x, status)``: the frame ``img`` sampled where the points ``X`` project with the
    pose ``cam`` (the statuses of :func:`._fastmap_kernels.project_sample_kernel`: 0
    sampled, 2 off the sensor); ``status`` None when a point moved more than twice
    ``refresh_px`` from ``uv0`` (cast anew); on ``workers`` threads (default: the
    cores), or shared with a waiting caller (``share``,
    :class:`selfillum.unsteady.frames.Helping`)."""
    arr = np.asarray(img)
    if arr.dtype.kind not in "fiu":
        arr = arr.astype(np.float64)
    x = np.empty(len(X))
    status = project_sample(X, np.asarray(cam.R, np.float64),
                             np.asarray(cam.t, np.float64).ravel(),
                             np.asarray(cam.K, np.float64),
                             np.asarray(cam.dist, np.float64).ravel(),
                             float(cam.max_radius), uv0, arr, 2.0 * float(refresh_px), x,
                             workers=workers, share=share)
    return x, (None if (status == 1).any() else status)


def _left_out(status, x, img) -> np.ndarray:
    """The samples ``x`` of ``img`` (statuses ``status`` of :func:`_sample_moved`) left
    out: not sampled, or not finite (a video's counts always are)."""
    bad = status != 0
    if np.asarray(img).dtype.kind == "f":
        bad |= ~np.isfinite(x)
    return bad


def _reference_pixels(smap, pix, X) -> np.ndarray:
    """(n, 2): where the surface points ``X`` of the pixels ``pix`` project in the
    reference; a pixel on the background (``X`` NaN) is its own position (sampled in place:
    the background does not move with the model)."""
    W = smap.shape[1]
    uv0 = np.column_stack([pix % W, pix // W]).astype(np.float64)
    on = np.isfinite(X[:, 0])
    if on.any():
        uv0[on] = smap.camera.project(X[on])
    return uv0


def _split_patch(A, pat):
    """Split the merge's operator ``A`` (F, H W) of a camera whose spots are patched by
    ``pat`` (:class:`selfillum.unsteady.spots.PatchOperator`): ``A`` off the patched
    pixels, ``A2`` (F, m P) their weights times their polynomial terms, ``Aw`` (F, m) their
    weights summed by spot."""
    A = sp.csc_matrix(A)
    Ain = A[:, pat.inside]
    A2 = sp.csr_matrix(Ain @ pat.expand()[pat.inside])
    m = pat.C.shape[0] // pat.n_terms
    member = sp.csr_matrix((np.ones(pat.inside.size), (np.arange(pat.inside.size),
                                                        pat.spot)), shape=(pat.inside.size, m))
    Aw = sp.csr_matrix(Ain @ member)
    keep = np.ones(A.shape[1])
    keep[pat.inside] = 0.0
    A = sp.csc_matrix(A @ sp.diags(keep))
    A.eliminate_zeros()
    return A, A2, Aw
