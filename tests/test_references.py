"""``selfillum.unsteady.references.ReferencePlan``: a moving model's references planned
piece by piece cover every frame within ``refresh_px`` (checked with the camera's own
projection), read only the poses of the pieces asked for, and give the same plan whatever
the order the frames are asked in."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from scenes.slab_block import slab_camera
from selfillum.unsteady.references import FIRST_PIECE, ReferencePlan, plan_references


class _Recorded(Sequence):
    """Poses that note which frames were read (a tracker's poses, handed over in turn)."""

    def __init__(self, poses):
        self.poses, self.read = poses, set()

    def __len__(self):
        return len(self.poses)

    def __getitem__(self, k):
        self.read.add(int(k))
        return self.poses[k]


def _run(T=400, amp_deg=5.0, period=67.0):
    cam = slab_camera(640, 480)
    rng = np.random.default_rng(2)
    X = np.column_stack([rng.uniform(-0.2, 0.2, 200), rng.uniform(-0.15, 0.15, 200),
                         np.zeros(200)])
    theta = np.radians(amp_deg) * np.sin(2 * np.pi * np.arange(T) / period + 0.3)
    poses = [cam.with_pose(R=cam.R @ Rotation.from_rotvec([th, 0, 0]).as_matrix(), t=cam.t)
             for th in theta]
    return X, poses


def test_a_piece_reads_only_its_own_poses_and_the_references():
    X, poses = _run()
    rec = _Recorded(poses)
    plan = ReferencePlan([rec], [X], range(len(poses)), 3.0, first=0)
    plan(5)
    assert max(rec.read) == FIRST_PIECE - 1  # the first piece: frames 0-63 only
    plan(FIRST_PIECE)
    assert max(rec.read) == 3 * FIRST_PIECE - 1  # the second: 64 to 191
    assert plan(7) == plan(7)
    assert max(rec.read) == 3 * FIRST_PIECE - 1  # planned already: nothing read


def test_every_frame_within_refresh_of_its_reference_and_few_references():
    X, poses = _run()
    uv = np.stack([p.project(X) for p in poses])  # the camera's projection
    refresh = 3.0
    plan = ReferencePlan([poses], [X], range(len(poses)), refresh, first=0)
    got = {k: plan(k) for k in range(len(poses))}
    for k, j in got.items():
        assert np.abs(uv[k] - uv[j]).max() <= refresh
    assert plan.references[0] == 0 and set(got.values()) == set(plan.references)
    whole = plan_references([poses], [X], range(len(poses)), refresh, first=0)
    # the pieces cost at most a few references more than planning over every pose
    assert len(plan.references) <= len(set(whole.values())) + 3
    assert len(plan.references) >= 3  # the vibration needs several


def test_the_same_plan_whatever_the_order_asked():
    X, poses = _run()
    frames = range(len(poses))
    a = ReferencePlan([poses], [X], frames, 3.0, first=0)
    b = ReferencePlan([poses], [X], frames, 3.0, first=0)
    in_order = [a(k) for k in frames]
    backwards = [b(k) for k in reversed(frames)][::-1]
    assert in_order == backwards
    assert b(10_000) == 10_000  # not among the frames: its own reference


def test_existing_references_cover_what_they_reach():
    """``plan_references(existing=...)``: a frame within ``refresh_px`` of a reference
    chosen before (outside the frames asked for) takes it; none is added for it."""
    X, poses = _run(T=200, amp_deg=0.05)  # a move far under refresh_px
    got = plan_references([poses], [X], range(100, 200), 3.0, existing=[0])
    assert set(got) == set(range(100, 200)) and set(got.values()) == {0}
