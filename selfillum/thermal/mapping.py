"""Phase 1 of a thermal run whose model moves and has no light of its own to remove (no
face sees another, or ``--no-si``): every frame onto the nodes in one sparse product.

The unsteady run's fast way (:mod:`selfillum.unsteady.fastmap`) carries each frame back
onto its reference's pixels through the model (each reference pixel's surface point
projected with the frame's tracked pose and the frame sampled there), then makes the
face values (the merge, one sparse product) and from them the node values (a second
product, and a copy of each with and without the self-illumination). Without the
self-illumination the faces are only a step: here the reference's pixels go to the nodes
in one product built once a reference (:meth:`~selfillum.unsteady.fastmap.
FrameOperator.nodes`, the merge and the faces' area-weighted mean at the nodes composed,
uPSP's polynomial patch of the markers included), the same sums in another order.

A frame the product cannot take takes the unsteady run's way for that frame: a sampled
pixel off the sensor or not finite (saturated), the face values of
:meth:`~selfillum.unsteady.fastmap.FrameOperator.faces_moved`, which leave it out; a
point that moved past twice ``refresh_px`` from its reference (the references are
planned so that none does), a reference cast at this frame's pose.

The references are planned over the whole run from the tracked poses
(:func:`~selfillum.unsteady.fastmap.plan_references`) and cast from a pose alone, as the
unsteady run casts them, so a resumed run maps each frame through the same reference.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from selfillum.unsteady.phase1 import FrameNodes

__all__ = ["map_moving", "moving_phase1", "takes", "REFRESH_PX"]

#: Pixels a surface point may move from where its reference saw it (the unsteady run's
#: ``refresh_px``).
REFRESH_PX = 3.0

#: The merge of each overlap this path takes, as the unsteady run's map_run sets it (its
#: gains fixed at 1: ``merge``'s gains matched on frame 0 take the unsteady run's way).
_MERGE = {"average_view": dict(method="weighted", feather_px=0, edge_margin=1,
                               match_gain=False),
          "best_view": dict(method="best", feather_px=0, edge_margin=1, match_gain=False)}


def takes(registration: str, overlap: str, si: bool) -> bool:
    """Whether :func:`map_moving` maps this run: a tracked (moving) model, no
    self-illumination to remove, ``average_view`` or ``best_view``."""
    return registration == "track" and not si and overlap in _MERGE


def map_moving(grid, runs, frames, *, spots, patcher: str, overlap: str,
               max_obliqueness: float, caster, plan_frames, refresh_px: float = REFRESH_PX,
               counts: dict | None = None) -> Iterator[FrameNodes]:
    """The frames ``frames`` of every camera (:class:`selfillum.unsteady.phase1.CameraRun`
    with its ``poses``) on the grid's nodes, one :class:`FrameNodes` at a time (``raw`` is
    ``values``: no self-illumination). ``plan_frames``: the frames the references are
    planned over (the whole run); ``counts`` (created keys): ``"fast"`` frames by the one
    product, ``"faces"`` by the faces' way, ``"references"`` references cast."""
    from selfillum.unsteady.fastmap import _sample_moved, plan_references
    from selfillum.unsteady.phase1 import _face_to_vertex, _fast_nodes, _keep, _shed_mesh_cache

    mesh = grid.mesh
    W = _face_to_vertex(mesh)
    gains = np.ones(len(runs))
    counts = {} if counts is None else counts
    for key in ("fast", "faces", "references"):
        counts.setdefault(key, 0)
    ops: list = []
    plan: dict = {}
    pending: dict = {}  # maps already cast, by frame

    def reference(j):  # the operator of the reference at frame j's pose (cast if missing)
        op = next((o for o in ops if o.frame == j), None)
        if op is None:
            served = [k for k, r in plan.items() if r == j] or [j]
            op = _cast(j, served, runs, mesh, caster, max_obliqueness, spots, patcher,
                       _MERGE[overlap], gains, maps=pending.pop(j, None))
            _keep(ops, op)
            counts["references"] += 1
            _shed_mesh_cache(mesh)
        return op

    frames = [int(k) for k in frames]
    if not frames:
        return
    # the first frame's maps: their surface points plan the references (as the unsteady
    # run's first reference's), then they make the first reference
    from resection.surface.surface_map import SurfaceMap

    maps0 = [SurfaceMap(mesh, r.poses[frames[0]], max_obliqueness=max_obliqueness,
                        caster=caster) for r in runs]
    probes = []
    for m in maps0:  # a few cameras
        X = m.points.reshape(-1, 3)[m.mask.ravel()]
        probes.append(X[np.linspace(0, max(len(X) - 1, 0), min(len(X), 64)).astype(int)])
    plan.update(plan_references([r.poses for r in runs], probes,
                                [int(k) for k in plan_frames], refresh_px, first=frames[0]))
    pending[frames[0]] = maps0
    maps0 = None
    shapes = [(r.camera.height, r.camera.width) for r in runs]
    bufs = [np.zeros(h * w) for h, w in shapes]  # each camera's reference pixels
    for k in frames:  # frames, one at a time
        op = reference(plan.get(k, k))
        op.last_used = k
        imgs = [r.frames[k] for r in runs]
        cams = [r.poses[k] for r in runs]
        v = _one_product(op, imgs, cams, bufs, shapes, W, grid, refresh_px, _sample_moved)
        if v is not None:
            counts["fast"] += 1
            yield FrameNodes(k, v, v, cams, gains)
            continue
        B = op.faces_moved(imgs, cams, refresh_px)
        if B is None:  # moved past its reference: one cast at this frame's pose
            op = reference(k)
            op.last_used = k
            B = op.faces_moved(imgs, cams, refresh_px)
        counts["faces"] += 1
        seen = op.seen & np.isfinite(B)
        raw = np.where(seen, B, np.nan)
        v = _fast_nodes(op, W, grid, raw, B, seen)[0]
        yield FrameNodes(k, v, v, cams, gains)


def _cast(j, served, runs, mesh, caster, max_obliqueness, spots, patcher, merge_kw, gains,
          maps=None):
    """The reference at frame ``j``'s poses, as the unsteady run casts one (a
    :class:`resection.SurfaceMap` a camera, the markers left out or patched, the patch
    joined to the operator), less the pixels whose surface point leaves the sensor in one
    of the ``served`` frames (those mapped through it): so that a frame's pixels are all
    sampled and the one product takes it. A face at the sensor's edge keeps its other
    pixels, as the unsteady run's frame keeps them when a point falls off. ``maps``: the
    cameras' maps at that pose when cast already."""
    from resection.surface.surface_map import SurfaceMap
    from selfillum.unsteady.fastmap import FrameOperator
    from selfillum.unsteady.spots import mask_spots, patch_operator, project_spots

    given = maps
    maps, finite, pre, prep = [], [], [], []
    for ci, r in enumerate(runs):  # a few cameras
        smap = given[ci] if given is not None else SurfaceMap(
            mesh, r.poses[j], max_obliqueness=max_obliqueness, caster=caster)
        fin = _stays_on_sensor(smap, [r.poses[k] for k in served])
        P = spot = None
        if spots is not None and len(spots):
            cen, rad = project_spots(spots, smap, margin_px=1.0)
            spot = (cen, rad)
            if patcher == "polynomial":
                P = spot = patch_operator(smap.shape, cen, rad, finite=fin)
                fin = fin & ~P.unfit.reshape(smap.shape)
            else:
                fin = fin & np.isfinite(mask_spots(np.zeros(smap.shape, np.float32), cen,
                                                   rad))
        maps.append(smap)
        finite.append(fin)
        pre.append(P)
        prep.append(spot)
    op = FrameOperator(maps, finite, merge_kw, gains, None, sample_points=True, pre=pre)
    op.spots = prep
    op.frame = op.last_used = j
    return op


def _stays_on_sensor(smap, cams) -> np.ndarray:
    """(H, W) bool: False at the pixels whose surface point projects off the sensor with
    one of the poses ``cams`` (only pixels near the sensor's edge can: those within the
    largest move of the model's outline of the edge are projected)."""
    H, W = smap.shape
    ok = np.ones(H * W, bool)
    X = smap.points.reshape(-1, 3)
    on = np.flatnonzero(np.isfinite(X[:, 0]))
    if on.size == 0 or not cams:
        return ok.reshape(H, W)
    uv0 = smap.camera.project(X[on])
    edge = np.minimum.reduce([uv0[:, 0] + 0.5, W - 0.5 - uv0[:, 0], uv0[:, 1] + 0.5,
                              H - 0.5 - uv0[:, 1]])
    probe = on[np.linspace(0, on.size - 1, min(on.size, 256)).astype(np.int64)]
    U0 = smap.camera.project(X[probe])
    move = max(float(np.nanmax(np.abs(c.project(X[probe]) - U0))) for c in cams)
    near = on[~(edge > 2.0 * max(move, 1.0) + 1.0)]  # a margin over the probes' move
    for c in cams:  # the frames a reference serves (each a projection of a few pixels)
        uv = c.project(X[near])
        off = ~((uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5)
                & (uv[:, 1] <= H - 0.5))
        ok[near[off]] = False
    return ok.reshape(H, W)


def _one_product(op, imgs, cams, bufs, shapes, W, grid, refresh_px, sample):
    """Node values (N,) float32 of a frame through ``op``'s one product, or None when a
    sampled pixel is off the sensor, not finite, or moved past twice ``refresh_px``."""
    for c, (img, cam, buf) in enumerate(zip(imgs, cams, bufs, strict=True)):
        x, status = sample(op.X[c], op.uv0[c], img, cam, refresh_px)
        if status is None or status.any():
            return None
        buf[op.cols[c]] = x  # the other pixels are never read
    return op.nodes([b.reshape(s) for b, s in zip(bufs, shapes, strict=True)], W, grid)


def moving_phase1(p1, grid, runs, todo, spots, store, R, t, done, fb, T, N, prog,
                  caster=None, counts=None) -> None:
    """Phase 1 of such a run (:func:`takes`), committed to ``store`` block by block of
    ``fb`` frames, as :func:`selfillum.unsteady.blocks.local_phase1` commits the unsteady
    run's."""
    from selfillum.unsteady.work import BlockBuffer

    buf = BlockBuffer(fb, N, with_raw=False)
    a = done
    for fn in map_moving(grid, runs, todo, spots=spots, patcher=p1.target_patcher,
                         overlap=p1.overlap, max_obliqueness=p1.oblique_angle,
                         caster=caster, plan_frames=range(T), counts=counts):
        k = fn.index
        if k < done:
            continue  # frame 0 again (a resume), already stored
        buf.put(k - a, fn.values)
        for ci, cm in enumerate(fn.cameras):
            R[ci, k], t[ci, k] = cm.R, cm.t
        if k - a + 1 == fb or k == T - 1:
            store.write_block(a, buf.rows(k + 1 - a), R[:, a:k + 1], t[:, a:k + 1])
            a = k + 1
        prog.frame(k + 1)
