"""Isolated corrupt time stamps never stretch a stream (issue 40, item 4: bounded conversion of damaged logs).

A flipped byte in one record's ``TimeUS`` (or tlog receive time) moves it seconds to hours away; within the
clock-jump limit (1e4 median intervals) it used to stay, and once sorted it stretched its stream, and a conversion
grid across the stretch, in proportion to the flip."""
from __future__ import annotations

import numpy as np
from hypothesis import example, given, settings
from hypothesis import strategies as st

from udrobot_ctrl.io.streams import finish_stream, time_spikes

DT = 0.05  # s, a 20 Hz stream


@settings(max_examples=150, deadline=None)
@given(n=st.integers(20, 400), moves=st.lists(st.tuples(st.integers(0, 10_000), st.floats(-480.0, 480.0)),
                                              min_size=1, max_size=6))
@example(n=20, moves=[(1, 7.0), (43, 7.0), (85, 7.0)])  # every other record of 1-5 flipped: three among five
def test_isolated_displaced_stamps_are_dropped_and_the_span_stays(n, moves):
    t = 1000.0 + DT * np.arange(n)
    moved = set()
    for i, shift in moves:
        i %= n
        if abs(shift) <= 6.0 or {i - 1, i, i + 1} & moved:  # isolated records only, moved beyond jitter
            continue
        if (i == 0 and shift < 0) or (i == n - 1 and shift > 0):  # as a pause at either end looks: kept
            continue
        t[i] += shift
        moved.add(i)
    s = finish_stream("ATT", t, {"k": np.arange(n, dtype=float)}, "TimeUS")
    assert s.t[0] >= 1000.0 - 1e-9 and s.t[-1] <= 1000.0 + DT * (n - 1) + 1e-9, s.notes
    kept = set(s.fields["k"].astype(int))
    assert kept == set(range(n)) - moved
    if moved:
        assert any("corrupt time stamp out of line" in note for note in s.notes)


@settings(max_examples=60, deadline=None)
@given(n=st.integers(10, 200), at=st.integers(1, 199), pause=st.floats(0.0, 3000.0))
def test_a_genuine_pause_is_never_a_spike(n, at, pause):
    """Stamps that stay late after a pause (a logging gap) are kept whatever its length."""
    t = DT * np.arange(n)
    t[at % n:] += pause
    assert not time_spikes(t).any()


def test_jitter_below_a_second_is_kept():
    rng = np.random.default_rng(0)
    t = 0.01 * np.arange(500) + rng.uniform(-0.4, 0.4, 500)  # header stamps out of order by up to 0.8 s
    assert not time_spikes(t).any()
