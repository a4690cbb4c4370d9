"""Step 2b, the fit-run replay check (issue 37): when the forward-selected set does not replay the fit runs, the
effects that alone replay them better join the candidates.

On the shared sea dive the equation error (dominated by the closed-loop attitude residual) selected a set whose
fit-run replay diverged, while a drag centre below the origin, which alone shrank the fit runs' replay gap by 31 %,
was never a candidate. Here a pool vehicle with a drag centre off its origin is diagnosed, and the equation error's
selection is replaced by nothing (as if it had missed the effect): the check must bring the withheld effect back,
and must stay silent when the selected set replays the fit runs.
"""
from __future__ import annotations

from dataclasses import replace

import pytest

from udrobot_ctrl.gap import report as R
from udrobot_ctrl.gap.attribute import finalize
from udrobot_ctrl.gap.confirm import REPLAY_LARGE

from .truth import generate

MODEL = "pendulum:chin"
NAMES = ["drag_centre_offset", "buoyancy_offset", "thruster_lag", "wall_effect"]


@pytest.fixture(scope="module")
def steps():
    """Prepared inputs, located gap, stacks and forward selection of three 60 s pool runs (two fit, one held out)
    with a drag centre 1.2 cm ahead of and 1.5 cm below the CO."""
    runs = generate({"drag_centre_offset": {"r": (0.012, 0.0, 0.015)}}, n_runs=3, duration=60.0, seed=3)
    inp = R.prepare_inputs(MODEL, runs[:2], runs[2:], NAMES, 8.0)
    where = R.locate_gap(inp)
    stacks = R.build_stacks(inp)
    sel = R.attribute(stacks, inp.names)
    return inp, where, stacks, sel


@pytest.mark.slow
def test_a_set_that_replays_its_fit_runs_is_left_alone(steps):
    inp, where, stacks, sel = steps
    assert "drag_centre_offset" in sel.proposed  # the equation error finds it on these runs
    out, support = R.replay_supported(inp, stacks, sel, where)
    assert support.set_diverged == 0 and support.set_shrink > 0.3  # the set explains the fit runs' replay gap
    assert not support.triggered and support.tried == {} and support.added == ()
    assert out is sel
    assert support.to_json()["triggered"] is False


@pytest.mark.slow
def test_an_effect_the_equation_error_missed_joins_when_it_replays_the_fit_runs(steps):
    inp, where, stacks, sel = steps
    missed = replace(sel, candidates=finalize(stacks.fit, (), inp.names))  # the equation error selected nothing
    lines = []
    out, support = R.replay_supported(inp, stacks, missed, where, log=lines.append)
    assert support.triggered and support.set_shrink is None
    assert support.tried["drag_centre_offset"] > REPLAY_LARGE
    assert "drag_centre_offset" in support.added and "drag_centre_offset" in out.proposed
    # an effect that does not shrink the fit runs' replay gap by more than REPLAY_LARGE alone does not join
    assert all(support.tried[n] > REPLAY_LARGE for n in support.added)
    assert all(n in support.added or s <= REPLAY_LARGE for n, s in support.tried.items())
    assert not set(support.tried) & set(stacks.identifiability.names)  # only identifiable effects are tried
    # the joined set is fitted jointly on the fit runs: the drag centre's parameters are those of a joint fit
    assert set(out.candidates.fit.params) >= set(support.added)
    assert any("replay check on the fit runs" in line and "drag_centre_offset" in line for line in lines)


@pytest.mark.slow
def test_runs_whose_velocities_were_reconstructed_are_not_checked():
    """Without a DVL the smoother reconstructs surge and sway with the plant being checked, so the fit runs' replay
    favours it: the check is skipped and says so, and the selection is left as it is."""
    runs = generate({"drag_centre_offset": {"r": (0.012, 0.0, 0.015)}}, n_runs=2, duration=40.0, seed=3,
                    sensors="stock")
    inp = R.prepare_inputs(MODEL, runs[:1], runs[1:], NAMES, 8.0)
    assert R.reconstructed(inp)
    sentinel = object()
    out, support = R.replay_supported(inp, None, sentinel, R.locate_gap(inp))
    assert out is sentinel and support.skipped and not support.triggered
    assert support.to_json()["skipped"] is True and support.added == ()
