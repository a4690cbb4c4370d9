"""The one decision's statistics (udrobot_ctrl.gap.decide): the likelihood's effective samples, the weights and
inclusion probabilities of the table, and an over-damped model losing to the true one on a synthetic truth."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import decide
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.shrink import WINDOW, gap, simulate_windows_each
from udrobot_ctrl.vehicle import load_model

from .truth import generate


class _Prep:
    """The least a prepared run offers :func:`udrobot_ctrl.gap.shrink.errors`: measurements, no smoother."""

    def __init__(self, meas):
        self.meas, self.smoothed, self.name = meas, None, "synthetic"


def _sim(n, windows, value):
    sim = np.full((n, WINDOW + 1), np.nan)
    sim[:, 3 + 3] = value  # the u column of the state (x y z phi theta psi u ...)
    sim[:, WINDOW] = 1 + np.arange(n) // (n // windows)
    return sim


def test_white_errors_count_every_sample_and_a_window_bias_counts_once_per_window():
    rng = np.random.default_rng(1)
    n, windows, sigma = 4000, 40, 0.02
    meas = {"u": rng.normal(0.0, sigma, n)}
    white = decide.channel_taus([_Prep(meas)], [_sim(n, windows, 0.0)], ["u"])["u"]
    # chi^2 spread of 40 window means: phi = 1 within its sampling error (sd of the estimate ~ sqrt(2 / 40))
    assert white == pytest.approx(1.0, abs=3 * math.sqrt(2 / windows))
    # the same noise with an error that is constant within each window and differs between windows: each window
    # carries one independent value, so the inflation approaches the samples per window
    bias = np.repeat(rng.normal(0.0, 5 * sigma, windows), n // windows)
    biased = decide.channel_taus([_Prep({"u": meas["u"] + bias})], [_sim(n, windows, 0.0)], ["u"])["u"]
    assert biased > 0.3 * (n // windows)


def test_the_likelihood_is_the_gaussian_profiled_over_each_channels_variance():
    sums = decide.ChannelSums({"u": 4.0, "w": 1.0}, {"u": 100, "w": 400})
    ll, n_eff = decide.log_likelihood(sums, {"u": 1.0, "w": 4.0})
    assert n_eff == pytest.approx(200.0)
    expect = -0.5 * 100 * (math.log(2 * math.pi * 0.04) + 1) - 0.5 * 100 * (math.log(2 * math.pi * 1 / 400) + 1)
    assert ll == pytest.approx(expect)


@pytest.mark.slow
def test_an_over_damped_model_scores_worse_than_the_true_one():
    """The truth generator's runs with no effect: the nominal plant is the truth. Every damping x5 makes a model that
    barely moves; on these runs its replays must score a lower likelihood and a larger gap than the true model's,
    and worse than the model-free baseline (the window's start held) on the velocity channels."""
    runs = generate({}, n_runs=1, duration=60.0, rate=20.0, seed=3)
    p = plant_parameters(load_model("pendulum:chin"))
    stiff = replace(p, D_L=5 * np.asarray(p.D_L), Q=5 * np.asarray(p.Q))
    prep = prepare(runs[0], p, "run")
    true_sims = simulate_windows_each([prep], p, (), 8.0)
    stiff_sims = simulate_windows_each([prep], stiff, (), 8.0)
    true_gap = gap([prep], true_sims)
    stiff_gap = gap([prep], stiff_sims, true_gap.scored)
    assert stiff_gap.value > true_gap.value
    channels = true_gap.scored
    taus = decide.channel_taus([prep], true_sims, channels)
    ll_true, _ = decide.log_likelihood(decide.channel_sums([prep], true_sims, channels), taus)
    ll_stiff, _ = decide.log_likelihood(decide.channel_sums([prep], stiff_sims, channels), taus)
    assert ll_stiff < ll_true
    assert stiff_gap.skill < true_gap.skill
    assert true_gap.skill > 0  # the true model predicts better than holding the window's start
