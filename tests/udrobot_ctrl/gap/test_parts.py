"""The named effects fitted on the holdout runs apart (udrobot_ctrl/gap/parts.py)."""
from __future__ import annotations

import math

import pytest

from udrobot_ctrl.gap.parts import SAME_SHARE, Agreement, named_parts
from udrobot_ctrl.gap.report import attribute, build_stacks, prepare_inputs

from .truth import generate

NAME = "buoyancy_offset"


def _parts(fit_dB, holdout_dB):
    """Two fit runs with a net buoyancy change of ``fit_dB`` (N, compressible foam: 10 %/m less with depth), one
    holdout run with ``holdout_dB``; the offset fitted on the fit runs, then on the holdout apart."""
    fit = generate({NAME: {"dB0": fit_dB, "beta": 0.1}}, n_runs=2, duration=60.0, seed=5)
    hold = generate({NAME: {"dB0": holdout_dB, "beta": 0.1}}, n_runs=1, duration=60.0, seed=6)
    inp = prepare_inputs("pendulum:chin", fit, hold, [NAME], 8.0)
    stacks = build_stacks(inp)
    sel = attribute(stacks, [NAME])
    return sel.singles[NAME], named_parts(stacks.holdout, sel.singles[NAME], [NAME])


def test_the_agreement_is_the_share_of_the_holdouts_own_gain():
    assert Agreement(100.0, SAME_SHARE).agrees and not Agreement(100.0, SAME_SHARE - 0.01).agrees
    idle = Agreement(-0.5, math.nan)  # the holdout's own fit gains nothing: the share is undefined
    assert not idle.agrees and not idle.excited and "do not excite it" in idle.words() and "nan" not in idle.words()
    assert "-141%" in Agreement(54.0, -1.41).words()


@pytest.mark.slow
def test_an_offset_that_holds_on_both_parts_is_fitted_alike_on_each():
    fitted, parts = _parts(2.0, 2.0)
    assert parts.agrees and parts.share > 0.8
    own, theirs = parts.holdout_params[NAME]["dB_N"], fitted.params[NAME]["dB_N"]
    assert own == pytest.approx(theirs, rel=0.25) and 1.0 < own < 2.5  # foam: 2 N at the surface, less below


@pytest.mark.slow
def test_a_vehicle_ballasted_again_between_the_parts_is_fitted_differently():
    """2 N light on the fit runs, 2 N heavy on the holdout: the fit runs' offset makes the holdout worse."""
    fitted, parts = _parts(2.0, -2.0)
    assert not parts.agrees and parts.share < 0.0
    assert parts.holdout_params[NAME]["dB_N"] < 0.0 < fitted.params[NAME]["dB_N"]
    assert "the parts fit it differently" in parts.text
