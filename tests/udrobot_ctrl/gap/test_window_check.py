"""The multiple-shooting window is checked before any replay (issue 40.7): finite, positive, at least two samples of
the runs' grid and short enough that a window fits in some run (a quarter of it, as window_starts opens them),
with a message naming the limit."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from udrobot_ctrl.gap.shrink import check_window


class _Prep:  # the two things check_window reads of a prepared run
    def __init__(self, dt, duration):
        self.dt = dt
        self.t = np.arange(0.0, duration + dt / 2, dt)


RUNS = [_Prep(0.02, 60.0), _Prep(0.1, 120.0)]


@settings(max_examples=200, deadline=None)
@given(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12)))
def test_every_window_is_accepted_within_its_limits_or_refused_with_a_reason(w):
    ok = math.isfinite(float(w)) and 2 * 0.02 <= float(w) < 4 * 120.0
    if ok:
        assert check_window(w, RUNS) == float(w)
    else:
        with pytest.raises(ValueError, match="window"):
            check_window(w, RUNS)


@pytest.mark.parametrize("w, words", [(float("nan"), "finite"), (float("inf"), "finite"), (0.0, "> 0"),
                                      (0.001, "two samples"), (1e9, "longer than the longest run"),
                                      (480.0, "no window fits")])
def test_messages_name_the_limit(w, words):
    with pytest.raises(ValueError, match=words):
        check_window(w, RUNS)


def test_without_runs_only_the_number_is_checked():
    assert check_window(8, ()) == 8.0
    with pytest.raises(ValueError, match="number of seconds"):
        check_window("eight", ())
