"""Phase 1: every frame of every camera onto the grid's nodes, one frame at a time.

For frame ``k``, each camera's image is

1. registered: mapped with the camera's own pose in that frame (``"track"``: a
   :class:`resection.SurfaceMap` per frame from the tracked pose, the visibility and the
   obliqueness cut-off exact per frame), or warped onto the first frame by an affine
   pixel registration and mapped through the first frame's map (``"first-frame"``, uPSP's
   method, :mod:`~selfillum.unsteady.registration`), or mapped through the first frame's
   map as it is (``"none"``, a model that does not move);
2. cleared of its dark spots (targets, taps, Kulites: :mod:`~selfillum.unsteady.spots`),
   masked or patched;
3. optionally low-pass filtered (``filter = gaussian``, NaN-aware);

then the cameras are combined on the faces (:func:`resection.surface.merge.merge_views`:
``average_view`` = view-angle weights, ``best_view`` = the camera of largest weight,
``merge`` = feathered weights with gains matched on frame 0 and kept), the
self-illumination is removed on the faces (``E = B - rho F B``: one sparse product a frame;
faces no camera sees in the frame take the radiosity of the frame-0 solve, see
:class:`SelfIllumination`), unpainted faces are dropped, and the faces' values go to the
nodes (area-weighted mean of the finite faces around each node) in grid-file order.

Frames are produced one at a time (:func:`map_run` is a generator), so a caller writes them
in blocks of frames and memory does not grow with the run.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from resection.errors import InputError
from resection.memory import release_freed_memory
from selfillum.unsteady.frames import FramesAhead, Helping, fixed_images, gaussian, read_frame
from selfillum.unsteady.options import FILTERS, OVERLAPS, REGISTRATIONS
from selfillum.unsteady.spots import DarkSpots, mask_spots, patch_operator, project_spots

__all__ = ["CameraRun", "SelfIllumination", "FrameNodes", "map_run", "REGISTRATIONS",
           "OVERLAPS", "FILTERS"]



@dataclass
class CameraRun:
    """One camera of the run.

    Attributes
    ----------
    number : int
        The deck's camera number.
    camera : resection.Camera
        Intrinsics and the pose of frame 0.
    frames : indexable of (H, W) arrays
        The video (``frames[k]``, e.g. :func:`resection.io.video.open_frames`).
    poses : sequence of Camera, optional
        The camera in every frame (``registration="track"``).
    """

    number: int
    camera: object
    frames: object
    poses: Sequence | None = None


@dataclass(frozen=True)
class FrameNodes:
    """One frame on the grid: ``index``, node ``values`` with the self-illumination
    removed (or not, with ``si=None``), ``raw`` without it (N,) float32 in grid order,
    NaN unseen; ``cameras`` the camera of each camera in this frame; ``gains`` the cameras'
    gains used by the merge."""

    index: int
    values: np.ndarray
    raw: np.ndarray
    cameras: list
    gains: np.ndarray | None = None


class SelfIllumination:
    """``E = B - rho F B`` per frame on the faces.

    Frame 0 is solved in full (:func:`selfillum.solve.radiosity.correct` with ``unseen``
    continued smoothly, then :func:`selfillum.solve.radiosity.forward`): every face's
    radiosity and emission. In each later frame the faces no camera sees take what the
    frame tells about them (``hidden="continue"``, :mod:`selfillum.unsteady.hidden`: their
    emission varies as that of the nearest seen face of the same part), or hold frame 0's
    radiosity (``hidden="frame0"``, the method before). A frame costs one sparse product
    and a gather. ``unpainted`` faces emit nothing.
    """

    def __init__(self, mesh, F, reflectance, unpainted=None, *, hidden: str = "continue",
                 crease_deg: float = 30.0):
        from selfillum.solve.radiosity import check_form_factors, check_reflectance

        if hidden not in ("continue", "frame0"):
            raise InputError(f"hidden must be 'continue' or 'frame0', got {hidden!r}")
        self.mesh = mesh
        self.F = check_form_factors(F)
        n = len(mesh.faces)
        if self.F.shape != (n, n):
            raise InputError(f"form factors: {self.F.shape} for {n} faces")
        self.rho = check_reflectance(reflectance, n)
        self.unpainted = None if unpainted is None else np.asarray(unpainted, bool)
        self.hidden_mode = hidden
        self.crease_deg = float(crease_deg)
        self.hidden = None
        self.continuation = None
        self._rows = None

    def reference(self, B0, seen0) -> None:
        """Solve frame 0 (seen and hidden faces) for every face's radiosity and emission."""
        from selfillum.solve.radiosity import correct, forward
        from selfillum.unsteady.hidden import HiddenContinuation, part_graph

        if seen0.all():
            self.hidden = np.asarray(B0, float)
            return
        # tol 1e-6 (not 1e-8): the seen faces' emission within 1.4e-5 (relative) of the
        # 1e-8 solve on the unsteady bench's frame 0, far under the noise of the form
        # factors, in 576 CG iterations instead of 898
        E0 = correct(self.F, np.where(seen0, B0, np.nan), self.rho, seen0, mesh=self.mesh,
                     unpainted=self.unpainted, tol=1e-6)
        E0 = np.where(np.isfinite(E0), E0, 0.0)
        if self.unpainted is not None:
            E0[self.unpainted] = 0.0
        self.hidden = forward(self.F, E0, self.rho)
        if self.hidden_mode == "continue":
            needed = np.zeros(len(E0), bool)
            needed[np.unique(self.F.indices)] = True
            keep = None if self.unpainted is None else ~self.unpainted
            self.continuation = HiddenContinuation(
                part_graph(self.mesh, self.crease_deg, keep), self.hidden, E0, needed,
                seen0=seen0)

    def __call__(self, B, seen) -> np.ndarray:
        if self.hidden is None:
            self.reference(B, seen)
        if self._rows is None:  # F restricted to its non-empty rows and columns, float32
            # (half the memory traffic, 1e-7 relative): a frame costs a product over the
            # faces that receive or send light, not passes over every face
            F = self.F
            rows = np.flatnonzero(np.diff(F.indptr) > 0)
            cols = np.unique(F.indices)
            self._rows = (rows, cols, sp.csr_matrix(F[rows][:, cols], dtype=np.float32),
                          self.rho[rows])
        rows, cols, Frc, rho_r = self._rows
        E = np.where(seen, B, np.nan)
        if self.continuation is not None:
            x = self.continuation.radiosity(B, seen)[cols].astype(np.float32)
        else:
            x = np.where(seen[cols], B[cols], self.hidden[cols]).astype(np.float32)
        E[rows] -= rho_r * (Frc @ x)
        return E


def _face_to_vertex(mesh) -> sp.csr_matrix:
    """(V, F) sparse: face areas at each face's three corners."""
    faces = np.asarray(mesh.faces, dtype=np.int64)
    area = np.asarray(mesh.area_faces, dtype=np.float64)
    F = len(faces)
    return sp.csr_matrix((np.repeat(area, 3), (faces.ravel(), np.repeat(np.arange(F), 3))),
                         shape=(len(mesh.vertices), F))


def map_run(grid, cameras: Sequence[CameraRun], frame_numbers, *, spots: DarkSpots | None,
            registration: str = "track", patcher: str = "none", overlap: str = "merge",
            filter: str = "none", filter_size: int = 3, max_obliqueness: float = 70.0,
            si: SelfIllumination | None = None, unpainted=None,
            spot_margin_px: float = 1.0, gains=None, fast: bool = True,
            refresh_px: float = 3.0, workers: int | None = None,
            plan_frames=None, caster=None, counts: dict | None = None
            ) -> Iterator[FrameNodes]:
    """Map the frames ``frame_numbers`` of every camera onto the grid's nodes.

    Parameters
    ----------
    grid : selfillum.unsteady.grid.RunGrid
    cameras : sequence of CameraRun
    frame_numbers : sequence of int
    spots : DarkSpots or None
    registration : {"track", "first-frame", "none"}
    patcher : {"none", "polynomial"}
    overlap : {"average_view", "best_view", "merge"}
    filter : {"none", "gaussian"}
    filter_size : int
        Odd kernel size, pixels.
    max_obliqueness : float
        Degrees (uPSP's ``oblique_angle``).
    si : SelfIllumination, optional
        Remove the self-illumination (else ``values`` equals ``raw``).
    unpainted : (F,) bool, optional
        Faces left out of node values.
    gains : (C,) array_like, optional
        The cameras' gains (``overlap="merge"``; default: matched on the first frame and
        kept).
    fast : bool
        After the first frame, map frames by sparse products
        (:class:`~selfillum.unsteady.fastmap.FrameOperator`): the same answer to rounding
        for a fixed map (``none``, ``first-frame``); for ``track``, each frame sampled
        where the reference's surface points project with its own pose, the reference
        cast anew when a point moves more than ``refresh_px`` pixels. The polynomial
        patch joins the operator (it is linear in its ring's pixels). Not with a filter
        for ``track``: those frames take the full way.
    refresh_px : float
        Pixels (``track`` with ``fast``).
    workers : int, optional
        Threads of the fast way's products (default: the available cores; 1 on a Dask
        worker of one thread).
    plan_frames : sequence of int, optional
        The frames a moving model's references are planned over (``track`` with
        ``fast``; default: ``frame_numbers``). A Dask task mapping a block of the run
        passes all the run's frames, so it samples each frame through the same reference
        as one process mapping the whole run (the cameras' ``poses`` must hold them all).
    caster : resection.surface.visibility.RayCaster, optional
        The grid mesh's Embree scene when built already (the view factors'), cast in
        instead of building another.
    counts : dict, optional
        Counted into (created keys): ``"fast"`` frames mapped by the sparse products,
        ``"full"`` frames mapped the full way (a ray cast and merge), ``"references"``
        references cast from a pose alone.

    Yields
    ------
    FrameNodes
    """
    from resection.surface.merge import merge_views
    from resection.surface.surface_map import SurfaceMap
    from resection.surface.visibility import RayCaster
    from selfillum.unsteady.registration import AffineRegistration

    if registration not in REGISTRATIONS:
        raise InputError(f"registration must be one of {', '.join(REGISTRATIONS)}, got "
                         f"{registration!r}")
    if patcher not in ("none", "polynomial"):
        raise InputError(f"target_patcher must be 'none' or 'polynomial', got {patcher!r}")
    if overlap not in OVERLAPS:
        raise InputError(f"overlap must be one of {', '.join(OVERLAPS)}, got {overlap!r}")
    if filter not in FILTERS:
        raise InputError(f"filter must be 'none' or 'gaussian', got {filter!r}")
    if filter == "gaussian" and (filter_size < 3 or filter_size % 2 == 0):
        raise InputError(f"filter_size must be an odd number >= 3, got {filter_size}")
    mesh = grid.mesh
    caster = RayCaster(mesh) if caster is None else caster
    # frame 0's maps of a model that does not move: built when first needed, dropped once
    # the operator holds what they gave (a cast again only for a frame the operator
    # cannot take); a moving model maps each cast with its own pose
    maps0 = [None] * len(cameras)
    regs = [None] * len(cameras)
    W = _face_to_vertex(mesh)
    merge_kw = {"average_view": dict(method="weighted", feather_px=0, edge_margin=1,
                                     match_gain=False),
                "best_view": dict(method="best", feather_px=0, edge_margin=1,
                                  match_gain=False),
                "merge": dict(method="weighted")}[overlap]
    gains = None if gains is None else np.asarray(gains, dtype=np.float64)
    off = None if unpainted is None else np.asarray(unpainted, bool)
    moving = registration == "track"
    use_fast = fast
    # a moving model's filtered frames: filtered in their own pixels, read at the
    # reference's points, and corrected near the spots (patched or left out before the
    # filter, as uPSP orders them: selfillum.unsteady.spot_filter)
    moving_filter = filter_size if (moving and filter != "none") else 0
    # uPSP's polynomial patch is linear in the ring's pixels: without a filter it joins
    # the operator (A_c P_c); with one it is applied to the image before the filter
    pres = [None] * len(cameras)  # per camera (P, unfit) of the reference's spots
    compose = patcher == "polynomial" and filter == "none"
    ops: list = []  # references: frame 0's; for a moving model also later casts
    spot_px = [None] * len(cameras)
    frame_numbers = [int(k) for k in frame_numbers]
    plan_frames = frame_numbers if plan_frames is None else [int(k) for k in plan_frames]
    plan = None  # a moving model: each frame's reference, planned from the known poses

    def planned(k):  # the operator of frame k's planned reference (cast when missing)
        nonlocal plan
        if plan is None:  # planned piece by piece: a piece waits for its own poses only
            from selfillum.unsteady.references import ReferencePlan

            plan = ReferencePlan([c.poses for c in cameras],
                                 [X[pr[::4]] for X, pr in zip(ops[0].X, ops[0].probe,
                                                              strict=True)],
                                 plan_frames, refresh_px, first=ops[0].frame)
        j = plan(k)
        op = next((o for o in ops if o.frame == j), None)
        if op is None:
            op = _cast_reference(j, cameras, mesh, caster, max_obliqueness, spots,
                                 spot_margin_px, merge_kw, ops[0].gains, off, patcher,
                                 moving_filter)
            _keep(ops, op)
            counts["references"] += 1
            _shed_mesh_cache(mesh)
            release_freed_memory()
        op.last_used = k
        return op

    counts = {} if counts is None else counts
    for key in ("fast", "full", "references"):
        counts.setdefault(key, 0)
    ahead = None  # FramesAhead (the next frame made meanwhile), with the first reference
    inner = 1 if len(cameras) == 1 else None
    try:
        for i, k in enumerate(frame_numbers):  # frames, one at a time
            imgs = None  # a fixed map's frame: read, registered, patched, filtered
            if ops and not moving:  # the next one made meanwhile in a helper thread
                if ahead is None:  # (one camera: on one core; several: a thread each)
                    ahead = FramesAhead(
                        lambda q: fixed_images(cameras, q, regs, spot_px, filter,
                                               filter_size, pres, ops[0].cols, workers=inner),
                        frame_numbers[i:])
                imgs = ahead.get(k)
            if ops and si is None and not moving:  # a fixed map, no SI: pixels to nodes
                v = ops[0].nodes(imgs, W, grid)
                if v is not None:
                    counts["fast"] += 1
                    yield FrameNodes(k, v, v, [c.camera for c in cameras], ops[0].gains)
                    continue
                # else: a pixel that counts is not finite (warped in from beyond the edge):
                # the faces' way, which leaves it out
            if ops and moving:  # sampled at its reference's points; the next frame's
                if ahead is None:  # samples made meanwhile in a helper thread (on one
                    # core), and their faces there too unless this thread already waits
                    # (see _moved_samples)
                    helping = Helping()
                    ahead = FramesAhead(
                        lambda q, op, h=helping: _moved_samples(
                            q, op, cameras, refresh_px, workers=1, share=h,
                            faces=lambda: not h.waiting()),
                        frame_numbers[i:], before=planned, helping=helping)
                op, got, cams = ahead.get(k)
                if isinstance(got, list):  # samples: their faces made here
                    got = op.faces_of_samples(got)
                fv = None if got is None else (got, cams, op.seen, op)
            elif ops:
                fv = _fixed_frame(ops, cameras, k, regs, spot_px, filter, filter_size, pres,
                                  imgs)
            if ops:
                if fv is not None:
                    B, cams, op_seen, _ = fv
                    seen = op_seen & np.isfinite(B)
                    raw_f = np.where(seen, B, np.nan)
                    E = si(B, seen) if si is not None else raw_f
                    vals = _fast_nodes(fv[3], W, grid, E, B, seen)
                    counts["fast"] += 1
                    yield FrameNodes(k, vals[0], vals[1], cams, ops[0].gains)
                    continue
                # else: no reference near this pose: cast anew from this frame (the full way)
            counts["full"] += 1
            if ahead is not None:  # the registrations and spots change: the frame made
                ahead.drop()  # ahead is made again when asked for
            maps, imgs, cams, finite = [], [], [], []
            for ci, c in enumerate(cameras):  # a few cameras
                img = np.asarray(c.frames[k], dtype=np.float64)
                shape = (c.camera.height, c.camera.width)
                if img.shape != shape:
                    raise InputError(f"camera {c.number}: frame {k} is {img.shape}, its "
                                     f"calibration {shape}")
                if registration == "track":
                    cam = c.poses[k]
                    smap = SurfaceMap(mesh, cam, max_obliqueness=max_obliqueness, caster=caster)
                else:
                    if maps0[ci] is None:
                        maps0[ci] = SurfaceMap(mesh, c.camera, max_obliqueness=max_obliqueness,
                                               caster=caster)
                    cam, smap = c.camera, maps0[ci]
                    if registration == "first-frame":
                        if regs[ci] is None:
                            regs[ci] = AffineRegistration(img, smap.mask)
                        img = regs[ci].warp(img, regs[ci].fit(img))
                if spots is not None and len(spots):
                    cen, rad = project_spots(spots, smap, margin_px=spot_margin_px)
                    spot_px[ci] = (cen, rad)
                    if patcher == "polynomial":
                        pres[ci] = patch_operator(img.shape, cen, rad, finite=np.isfinite(img))
                        img = pres[ci].apply(img)
                    else:
                        img = mask_spots(img, cen, rad)
                finite.append(np.isfinite(img))
                if filter == "gaussian":
                    img = gaussian(img, filter_size)
                maps.append(smap)
                imgs.append(img)
                cams.append(cam)
            if use_fast and ops:  # a new reference of a moving model: its operator gives the
                # merge (the gains are frame 0's; the same sums as merge_views with them)
                from selfillum.unsteady.fastmap import FrameOperator

                op = FrameOperator(maps, finite, merge_kw, ops[0].gains, off, sample_points=True,
                                   pre=pres if compose else None, filter_size=moving_filter,
                                   spots=_spots_of(patcher, pres, spot_px))
                op.frame = op.last_used = k
                _keep(ops, op)
                B = op.faces(imgs)
                maps = imgs = finite = None  # not held while the frame is out
                seen = op.seen & np.isfinite(B)
                raw_f = np.where(seen, B, np.nan)
                E = si(B, seen) if si is not None else raw_f
                vals = _fast_nodes(op, W, grid, E, B, seen)
                _shed_mesh_cache(mesh)
                release_freed_memory()
                yield FrameNodes(k, vals[0], vals[1], cams, op.gains)
                continue
            B = None
            known = gains if gains is not None else (
                np.ones(len(cameras)) if overlap != "merge" else None)
            if use_fast and known is not None:  # the first reference, its gains known (not
                # matched on this frame): the operator gives this frame's merge too
                from selfillum.unsteady.fastmap import FrameOperator

                op = FrameOperator(maps, finite, merge_kw, known, off, sample_points=moving,
                                   pre=pres if compose else None, filter_size=moving_filter,
                                   spots=_spots_of(patcher, pres, spot_px))
                B = op.faces(imgs)
                if B is not None:
                    ops.append(op)
                    op.frame = op.last_used = k
                    op.workers = workers
                    maps0 = [None] * len(cameras)
                    seen, mv_gains = op.seen & np.isfinite(B), op.gains
            if B is None:
                mv = merge_views(maps, imgs, gains=gains, **merge_kw)
                if overlap == "merge" and gains is None:
                    gains = mv.gains  # matched on frame 0, kept: no seam moving over time
                if use_fast:  # the first reference
                    from selfillum.unsteady.fastmap import FrameOperator

                    ops.append(FrameOperator(maps, finite, merge_kw, mv.gains, off,
                                             sample_points=moving,
                                             pre=pres if compose else None,
                                             filter_size=moving_filter,
                                             spots=_spots_of(patcher, pres, spot_px)))
                    ops[0].frame = ops[0].last_used = k
                    ops[0].workers = workers
                    maps0 = [None] * len(cameras)
                B, seen, mv_gains = mv.values, mv.seen & np.isfinite(mv.values), mv.gains
            maps = imgs = finite = mv = None  # not held while the frame is out
            if off is not None:
                seen = seen & ~off
            raw_f = np.where(seen, B, np.nan)
            E = si(B, seen) if si is not None else raw_f
            vals = _to_nodes(W, np.vstack([E, raw_f]), grid)
            if use_fast:
                _shed_mesh_cache(mesh)
            release_freed_memory()  # the cast's, the merge's and the SI solve's work arrays
            yield FrameNodes(k, vals[0], vals[1], cams, mv_gains)
    finally:
        if ahead is not None:
            ahead.close()


#: References (full casts) a moving model keeps: a vibrating model returns to earlier poses.
MAX_REFERENCES = 8


#: trimesh's per-face arrays that a cast computes and caches on the mesh (1.1 M faces:
#: about 160 MB, the corners alone 9 float64 a face).
_MESH_CACHE = ("triangles", "triangles_cross", "triangles_center", "face_normals",
               "area_faces")


def _shed_mesh_cache(mesh) -> None:
    """Drop trimesh's cached per-face arrays once a cast is done: the fast way's frames
    do not use them, and the next cast computes them again."""
    cache = getattr(mesh, "_cache", None)
    for key in _MESH_CACHE if cache is not None else ():
        cache.delete(key)


def _keep(ops, op) -> None:
    """Add a reference; past :data:`MAX_REFERENCES`, drop the least recently used one
    (never the first frame's)."""
    ops.append(op)
    if len(ops) > MAX_REFERENCES:
        ops.pop(1 + int(np.argmin([o.last_used for o in ops[1:-1]])))


def _cast_reference(j, cameras, mesh, caster, max_obliqueness, spots, spot_margin_px,
                    merge_kw, gains, unpainted, patcher="none", filter_size=0):
    """The operator of a moving model's reference at frame ``j``'s poses: a
    :class:`resection.SurfaceMap` a camera (a ray cast), its dark spots left out or
    patched (the patch joins the operator); no image is needed (a video's pixels are
    finite)."""
    from resection.surface.surface_map import SurfaceMap
    from selfillum.unsteady.fastmap import FrameOperator

    maps, finite, pre, prep = [], [], [], []
    for c in cameras:  # a few cameras
        smap = SurfaceMap(mesh, c.poses[j], max_obliqueness=max_obliqueness, caster=caster)
        fin, P, spot = np.ones(smap.shape, bool), None, None
        if spots is not None and len(spots):
            cen, rad = project_spots(spots, smap, margin_px=spot_margin_px)
            spot = (cen, rad)
            if patcher == "polynomial":
                P = spot = patch_operator(smap.shape, cen, rad)
                fin = ~P.unfit.reshape(smap.shape)
            else:
                fin = np.isfinite(mask_spots(np.zeros(smap.shape, np.float32), cen, rad))
        maps.append(smap)
        finite.append(fin)
        pre.append(P)
        prep.append(spot)
    op = FrameOperator(maps, finite, merge_kw, gains, unpainted, sample_points=True,
                       pre=None if filter_size else pre, filter_size=filter_size,
                       spots=prep)
    op.frame = op.last_used = j
    return op


def _fixed_frame(ops, cameras, k, regs, spot_px, filter, filter_size, pres=None,
                 imgs=None):
    """Face values of frame ``k`` of a fixed map by frame 0's operator (``imgs``: its
    images, made ahead)."""
    if imgs is None:
        imgs = fixed_images(cameras, k, regs, spot_px, filter, filter_size, pres,
                            ops[0].cols)
    B = ops[0].faces(imgs)
    return None if B is None else (B, [c.camera for c in cameras], ops[0].seen, ops[0])


def _moved_samples(k, op, cameras, refresh_px, workers=None, faces=True, share=None):
    """``(op, values, cameras)`` of frame ``k`` of a moving model by its reference ``op``:
    the samples (:meth:`.fastmap.FrameOperator.samples`, filtered when the operator
    filters), or with ``faces`` (a bool, or a callable asked once the samples are made)
    the face values from them (:meth:`.fastmap.FrameOperator.faces_of_samples`); values
    None: a point moved too far. Reads the frames and the operator only: made ahead in a
    helper thread (:class:`.FramesAhead`, ``workers`` threads within; or with ``share``,
    a :class:`.frames.Helping`, its sampling shared with the caller while it waits).

    The helper makes the faces too unless the caller already waits for the frame: the
    frame's work is then balanced between the two threads on any machine. The samples
    (850,000 points on the 609k run) took 10-11 ms a frame on session 18's machine and
    22 ms on session 19's, the faces 5-8 ms, the caller's self-illumination and nodes
    12-16 ms: with the faces always in the helper, the caller waited 4.1 s of Phase 1's
    8.3 s on the slower machine."""
    imgs = [read_frame(c.frames, k) for c in cameras]
    cams = [c.poses[k] for c in cameras]
    got = op.samples(imgs, cams, refresh_px, workers=workers, share=share)
    if got is not None and (faces() if callable(faces) else faces):
        got = op.faces_of_samples(got)
    return op, got, cams


def _spots_of(patcher, pres, spot_px) -> list:
    """Per camera the reference's dark spots as the operator takes them: the patch's
    operators (``polynomial``), else the spots' centres and radii (left out)."""
    return list(pres) if patcher == "polynomial" else list(spot_px)


def _fast_nodes(op, W, grid, E, B, seen) -> np.ndarray:
    """Node values of a frame of the fast way: the face-to-node operator of the
    reference's seen faces (built once a reference) applied to ``E`` and ``B``. When
    some of the reference's faces are not seen in this frame (points off the sensor), the
    same operator on them, divided by its weight of the faces left (the area-weighted
    mean of the seen faces around each node, as :func:`_to_nodes`); the full way when this
    frame sees a face the reference does not."""
    same = np.array_equal(seen, op.seen)
    if not same and (seen & ~op.seen).any():
        return _to_nodes(W, np.vstack([E, np.where(seen, B, np.nan)]), grid)
    Wn = op.node_matrix(W, grid)  # over the reference's seen faces
    Wr, rows = op.seen_node_rows(W, grid)  # its non-empty rows (each sums to 1)
    idx = op.seen_faces
    out = np.full((2, Wn.shape[0]), np.nan, np.float32)
    e, b = E[idx], B[idx]
    if same:
        out[0, rows], out[1, rows] = Wr @ e, Wr @ b
        return out
    lost = np.flatnonzero(~seen[idx])  # few (at the frame's edge): their nodes rescaled
    e[lost], b[lost] = 0.0, 0.0
    ye, yb = Wr @ e, Wr @ b
    Wc = op.seen_node_rows(W, grid, by_columns=True)
    starts, ends = Wc.indptr[lost], Wc.indptr[lost + 1]
    n = ends - starts
    at = np.repeat(starts - np.cumsum(n) + n, n) + np.arange(n.sum())
    hit, inv = np.unique(Wc.indices[at], return_inverse=True)
    kept = 1.0 - np.bincount(inv, Wc.data[at], minlength=hit.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(kept > 1e-9, 1.0 / kept, np.nan)
    ye[hit] *= scale
    yb[hit] *= scale
    out[0, rows], out[1, rows] = ye, yb
    return out


def _to_nodes(W, face_values, grid) -> np.ndarray:
    fin = np.isfinite(face_values)
    num = (W @ np.where(fin, face_values, 0.0).T).T
    den = (W @ fin.T.astype(np.float64)).T
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.where(den > 0, num / den, np.nan)
    return grid.to_nodes(v).astype(np.float32)
