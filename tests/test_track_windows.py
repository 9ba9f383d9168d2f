"""The tracker's marker windows: placed where the reference frame saw each marker (its
survey error carried), not where the survey puts it."""

from __future__ import annotations

import numpy as np

from resection.sequence.predict import _survey_offsets
from resection.sequence.results import FrameResult


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
