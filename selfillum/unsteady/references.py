"""A moving model's reference frames, planned from its poses before its frames are mapped.

A reference is a frame mapped the full way (a ray cast a camera, the merge): the frames
near it in pose are then sampled through it (:class:`selfillum.unsteady.fastmap.
FrameOperator`). :func:`plan_references` picks few references that cover every frame
within ``refresh_px`` pixels; :class:`ReferencePlan` plans a run piece by piece, so that
its first frames are mapped while the tracker is still solving the last poses
(:class:`selfillum.unsteady.tracking.TrackingAhead`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["ReferencePlan", "plan_references"]

#: Frames of a :class:`ReferencePlan`'s first piece; each piece after it twice the one
#: before (64, 128, 256, ...): the first frames wait for 64 poses only, and a piece still
#: spans a vibration's period or more where the plan's choice matters.
FIRST_PIECE = 64


class ReferencePlan:
    """Each frame's reference, planned by pieces of the run's frames in their order.

    Piece ``j`` (``FIRST_PIECE * 2**j`` frames) is planned by :func:`plan_references`
    with the references of the pieces before it (and ``first``) already chosen, when one
    of its frames is first asked for: it reads the poses of its own frames and those
    references only. So the plan is the same whether the poses are all known at the start
    or handed over as the tracker solves them (the caller waits only for the poses up to
    the piece's last frame), in every process that plans the same frames (a cluster's
    workers).

    Parameters
    ----------
    poses, probes, refresh_px
        As :func:`plan_references`.
    frames : sequence of int
        The frames to cover, in the order they are mapped.
    first : int, optional
        The frame that is a reference already (the first frame's).
    """

    def __init__(self, poses, probes, frames, refresh_px: float, *,
                 first: int | None = None) -> None:
        self._poses, self._probes, self._refresh = poses, probes, float(refresh_px)
        order = [int(k) for k in frames]
        self._pieces, a, n = [], 0, FIRST_PIECE
        while a < len(order):
            self._pieces.append(order[a:a + n])
            a, n = a + n, 2 * n
        self._piece_of = {k: j for j, piece in enumerate(self._pieces) for k in piece}
        self._planned = 0  # pieces planned
        self._plan: dict[int, int] = {}
        self._refs: list[int] = [] if first is None else [int(first)]

    def __call__(self, k: int) -> int:
        """The reference of frame ``k`` (``k`` itself when it is not among the frames)."""
        k = int(k)
        j = self._piece_of.get(k)
        if j is None:
            return k
        while self._planned <= j:
            piece = self._pieces[self._planned]
            got = plan_references(self._poses, self._probes, piece, self._refresh,
                                  existing=self._refs)
            self._plan.update(got)
            self._refs += [r for r in dict.fromkeys(got.values()) if r not in self._refs]
            self._planned += 1
        return self._plan[k]

    @property
    def references(self) -> list[int]:
        """The references chosen so far (``first``, then in the order chosen)."""
        return list(self._refs)


def _frame_poses(poses, frames):
    """``(camera, R (T, 3, 3), t (T, 3))`` of ``frames`` from one camera's poses: a
    sequence of :class:`resection.Camera` (same intrinsics), or arrays of them (an object
    with ``camera``, ``R`` and ``t``, as :class:`selfillum.unsteady.cluster.PoseArrays`:
    no Camera built a frame)."""
    if all(hasattr(poses, a) for a in ("camera", "R", "t")):
        return (poses.camera, np.asarray(poses.R, np.float64)[frames],
                np.asarray(poses.t, np.float64).reshape(-1, 3)[frames])
    cams = [poses[int(k)] for k in frames]
    return (cams[0], np.stack([np.asarray(c.R, np.float64) for c in cams]),
            np.stack([np.asarray(c.t, np.float64).ravel() for c in cams]))


def _probe_pixels(X, cam, R, t) -> np.ndarray:
    """(T, m, 2) float32: the points ``X`` (m, 3) projected with the intrinsics of
    ``cam`` (a :class:`resection.Camera`) and the poses ``R`` (T, 3, 3), ``t`` (T, 3),
    NaN where a point cannot be projected (:func:`resection.camera.model.project_with_poses`)."""
    from resection.camera.model import project_with_poses

    return project_with_poses(cam, R, t, X).astype(np.float32)


def plan_references(poses, probes, frames, refresh_px: float, *, first: int | None = None,
                    existing: Sequence[int] = (), block: int = 4096,
                    n_candidates: int = 256, n_check: int = 2048, seed: int = 0) -> dict:
    """The reference frames of a moving model, chosen before Phase 1 from the known poses,
    so that every frame is within ``refresh_px`` of one and the references are few.

    The distance between two frames is the largest move (pixels, either axis, any
    camera) of the probe points (a sample of a reference's surface points, projected with
    each frame's pose; inf where one cannot be projected). Greedy cover: the
    first frame not yet covered (in time order) picks, among the frames within
    ``refresh_px`` of it (which all cover it), the one covering most of the uncovered
    frames (counted on a sample of ``n_check`` of them, over a sample of
    ``n_candidates`` candidates); repeated until every frame is covered. A periodic
    vibration needs a handful (5 for a pitch oscillation of 15 px with ``refresh_px`` 3
    in tests/test_si_reference.py, where a reference cast at each frame that moved past
    the others gives 7).

    Parameters
    ----------
    poses : sequence of sequences of Camera
        Per camera, the camera of every frame (indexed by frame number), or its poses as
        arrays (:class:`selfillum.unsteady.cluster.PoseArrays`).
    probes : sequence of (m, 3) arrays
        Per camera, surface points seen in the first reference (model units).
    frames : sequence of int
        The frames to cover.
    refresh_px : float
        Pixels.
    first : int, optional
        A frame that is a reference already (the first frame's).
    existing : sequence of int, optional
        Frames that are references already, among ``frames`` or not (an earlier piece's,
        :class:`ReferencePlan`): they cover what is within ``refresh_px`` of them, and are
        not in the returned mapping unless among ``frames``.

    Returns
    -------
    dict
        Frame number -> its reference's frame number (the nearest reference).
    """
    asked = [int(k) for k in frames]
    if not asked:
        return {}
    among = set(asked)
    # a first frame outside the frames is not a reference of theirs; existing ones are
    head = [int(first)] if first is not None and int(first) in among else []
    refs = list(dict.fromkeys([*head, *(int(k) for k in existing)]))
    frames = np.asarray(asked + [r for r in refs if r not in among], dtype=np.int64)
    T = len(frames)
    parts = [_probe_pixels(X, *_frame_poses(p, frames)) for X, p in
             zip(probes, poses, strict=True) if len(X)]
    if not parts:
        return {k: (refs[0] if refs else asked[0]) for k in asked}
    U = np.concatenate(parts, axis=1)  # (T, m, 2)

    def dist(rows, c):  # (len(rows),): frames' distance to frame position c
        d = np.abs(U[rows] - U[c][None])
        d = np.where(np.isnan(d), np.inf, d)
        return d.reshape(len(d), -1).max(axis=1)

    def dist_all(c):
        return np.concatenate([dist(np.arange(a, min(a + block, T)), c)
                               for a in range(0, T, block)])

    rng = np.random.default_rng(seed)
    best_d = np.full(T, np.inf)
    best_c = np.zeros(T, dtype=np.int64)

    def add(c):
        d = dist_all(c)
        closer = d < best_d
        best_d[closer] = d[closer]
        best_c[closer] = c

    position = {int(k): i for i, k in enumerate(frames.tolist())}
    for r in refs:
        add(position[r])
    while True:
        open_ = np.flatnonzero(best_d > refresh_px)
        if open_.size == 0:
            break
        f = int(open_[0])
        cand = np.flatnonzero(dist_all(f) <= refresh_px)  # f itself at least
        if cand.size > n_candidates:
            cand = rng.choice(cand, n_candidates, replace=False)
        chk = open_ if open_.size <= n_check else rng.choice(open_, n_check, replace=False)
        counts = [int((dist(chk, int(c)) <= refresh_px).sum()) for c in cand]
        add(int(cand[int(np.argmax(counts))]))
    return {int(frames[i]): int(frames[best_c[i]]) for i in range(len(asked))}
