"""Fault cases (issue 10 and later): each test drives the CLI or the API as a user would
and checks that a bad or surprising input ends in a clear decision (a one-line error with
exit status 2, a warning, or a refusal), never a traceback, a lost file or a silently wrong
answer. One section per fault family; append new sections at the end."""

from __future__ import annotations

import numpy as np
import pytest

from resection import InputError

# --------------------------------------------------------------------------------------
# Decisions on computed floats: a stated tolerance, not the sign of a rounding error
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("tiny", [2.2e-16, -2.2e-16, 4.4e-16, -4.4e-16, 0.0])
def test_constant_ratio_is_not_significant_whatever_the_rounding(tiny):
    """A ratio that does not vary with the pressure is 'not significant', whether the
    least-squares slope comes out as +1e-16, -1e-16 or exactly 0 (the CI failure of
    issue 10 item 1 was B = -8.3e-17 read as 'negative')."""
    from selfillum.psp import fit_stern_volmer

    p = np.array([80.0, 95.0, 110.0, 130.0])
    # the ratio is 1 up to one or two units in the last place, growing or falling with p:
    # the fitted slope has that rounding's sign, and the decision must not depend on it
    ratio = 1.0 + tiny * (p - p.min()) / np.ptp(p)
    with pytest.raises(InputError, match="not significantly") as err:
        fit_stern_volmer(ratio, p, 100.0)
    assert "must grow" not in str(err.value)
    # two taps: no scatter estimate at all, only the rounding tolerance decides
    with pytest.raises(InputError, match="not significantly"):
        fit_stern_volmer(ratio[[0, -1]], p[[0, -1]], 100.0)


def test_falling_ratio_is_refused_as_negative():
    """A ratio that clearly falls with the pressure (wind-on and wind-off swapped) gets the
    'must grow' message, not the 'not significant' one."""
    from selfillum.psp import SternVolmer, fit_stern_volmer

    p = np.array([80.0, 95.0, 110.0, 130.0])
    swapped = 1.0 / SternVolmer(0.15, 0.85, 100.0).ratio(p)
    with pytest.raises(InputError, match="must grow"):
        fit_stern_volmer(swapped, p, 100.0)
    with pytest.raises(InputError, match="must grow"):
        fit_stern_volmer(swapped[[0, -1]], p[[0, -1]], 100.0)
