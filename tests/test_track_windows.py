"""The tracker's marker windows: fitted on several threads with the same result as on one,
and placed where the reference frame saw each marker (its survey error carried), not
where the survey puts it."""

from __future__ import annotations

import numpy as np
import pytest

from resection.markers.refine import refine_markers
from resection.sequence.predict import _survey_offsets
from resection.sequence.results import FrameResult


def _frame(seed=0, n=14, d=12.0):
    rng = np.random.default_rng(seed)
    H, W = 240, 320
    yy, xx = np.mgrid[:H, :W]
    img = np.full((H, W), 100.0)
    cu = np.linspace(25, W - 25, n)
    cv = 40 + (np.arange(n) % 4) * 50.0
    cen = np.column_stack([cu + rng.uniform(-3, 3, n), cv + rng.uniform(-3, 3, n)])
    for u, v in cen:
        r = np.hypot(xx - u, yy - v) - d / 2
        img += 800.0 * 0.5 * (1 - np.tanh(r / 1.2))
    img += rng.normal(0, 5, img.shape)
    return img, cen, d


@pytest.mark.parametrize("workers", [2, 3, 8])
def test_windows_on_threads_equal_one_thread(workers):
    img, cen, d = _frame()
    start = cen + np.random.default_rng(1).normal(0, 0.4, cen.shape)
    one = refine_markers(img, start, d, workers=1)
    many = refine_markers(img, start, d, workers=workers)
    for k in one:
        np.testing.assert_array_equal(one[k], many[k])
    assert one["ok"].all()
    assert np.hypot(one["u"] - cen[:, 0], one["v"] - cen[:, 1]).max() < 0.05


def test_survey_offsets_are_the_reference_residuals_by_id():
    ids = np.array(["T1", "T2", "T3", "T4"])
    ref = FrameResult(frame=3, file="", status="ok", ids=np.array(["T3", "T1", "X9"]),
                      uv=np.zeros((3, 2)),
                      residuals=np.array([[0.7, -1.2], [np.nan, 0.1], [5.0, 5.0]]))
    off = _survey_offsets(ids, ref)
    # T3's residual; T1's is not finite and T2, T4 were not seen: no offset; X9 is no marker
    np.testing.assert_array_equal(off, [[0.0, 0.0], [0.0, 0.0], [0.7, -1.2], [0.0, 0.0]])
    empty = FrameResult(frame=0, file="", status="ok")
    np.testing.assert_array_equal(_survey_offsets(ids, empty), np.zeros((4, 2)))
