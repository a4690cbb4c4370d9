"""A replay that blows up scores worst, not best (issue 40.1).

A window whose state turns non-finite or leaves the replay's envelope used to keep only its first sample, which is
the measurement: a model with a 1e5 N buoyancy error scored better than the model that flew the run. Its remaining
samples now score the channel's error cap, so the windowed gap rises monotonically with the model error.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.effects import PlantEffect, plant_effect
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.gap.confirm import Alone, MemberTest
from udrobot_ctrl.gap.replay import windowed_gap
from udrobot_ctrl.gap.shrink import ERROR_CAP, VELOCITY_ENVELOPE, WINDOW, errors, window_counts
from udrobot_ctrl.io.runlog import Run, write_run
from udrobot_ctrl.vehicle import load_model, write_model_file

RATE = 20.0  # Hz
OFFSETS = (0.0, 1.0, 10.0, 100.0, 1e3, 1e5)  # N, buoyancy errors of increasingly wrong models


@pytest.fixture(scope="module")
def flown():
    """A 40 s noise-free run of surge/heave thrust sweeps flown open loop by the nominal UDrobot (the right model)."""
    nominal = load_model("pendulum:chin")
    t = np.arange(0.0, 40.0, 1.0 / RATE)
    s = np.sin(2 * np.pi * t / 9.0)
    f = np.column_stack([20 * s + 10, 20 * s + 8, 6 * np.cos(2 * np.pi * t / 7.0), 6 * np.cos(2 * np.pi * t / 7.0)])
    x0 = np.zeros(12)
    x0[2] = 1.0
    res = simulate(nominal, x0, t[-1] + 1.0 / RATE, inputs=np.repeat(f, 5, axis=0), dt=1.0 / (5 * RATE))
    xs = res.x[::5][: t.size]
    run = Run(path="flown.csv", t=t, channels={c: xs[:, i] for i, c in enumerate(STATE_NAMES)}, input_kind="thrust",
              inputs=f, extra={}, metadata={"format": "udrobot-run/1"})
    return nominal, run


def _with_offset(nominal, dB):
    return nominal.with_changes(effects=(PlantEffect("buoyancy_offset", {"dB_N": dB}),)) if dB else nominal


@pytest.fixture(scope="module")
def family(flown):
    nominal, run = flown
    return {dB: windowed_gap(_with_offset(nominal, dB), [run], 8.0, names=["flown.csv"]) for dB in OFFSETS}


def test_the_windowed_gap_rises_monotonically_with_the_buoyancy_error(family):
    """0 N is the model that flew the run (only the start-velocity smoothing differs); each step up the family adds
    a larger constant heave force, so the replay errs more; 1e5 N (1e4 m/s^2 on a 10 kg vehicle) leaves the envelope
    within a step and must score worst, not keep only the windows' first samples."""
    values = [family[dB].value for dB in OFFSETS]
    assert values[0] < 0.05
    assert all(b >= a for a, b in zip(values, values[1:])), values
    assert values[-1] > values[-2]
    scored = family[0.0].scored
    for c in scored:  # channel by channel as well: no channel gets better when the model gets worse
        per = [family[dB].per_channel[c] for dB in OFFSETS]
        assert per[-1] >= max(per[:-1]), (c, per)


def test_the_gap_says_how_many_windows_diverged(family):
    right, blown = family[0.0], family[1e5]
    assert right.diverged == {"flown.csv": 0} and right.windows["flown.csv"] >= 4
    assert blown.diverged["flown.csv"] == blown.windows["flown.csv"] == right.windows["flown.csv"]
    d = blown.to_dict()
    assert d["diverged_windows"] == {"flown.csv": blown.windows["flown.csv"]}
    assert d["windows"] == {"flown.csv": blown.windows["flown.csv"]}
    # the replay still stops at the envelope: a 1e5 N model never keeps a speed above it in its stored states
    sim = blown.sims[0]
    assert not (np.abs(sim[:, 6:12]) > VELOCITY_ENVELOPE).any()
    assert (sim[:, WINDOW] < 0).any() and window_counts(sim) == (blown.windows["flown.csv"],) * 2


def test_a_diverged_window_scores_the_error_cap_and_finite_errors_are_clipped_to_it(flown, family):
    _, run = flown
    blown = family[1e5]
    prep, sim = blown.preps[0], blown.sims[0]
    err = errors(prep, sim)
    dead = sim[:, WINDOW] < 0
    for c, e in err.items():
        assert np.all(np.abs(e[np.isfinite(e)]) <= ERROR_CAP[c])
        assert np.all(e[dead & np.isfinite(prep.meas[c])] == ERROR_CAP[c])


def test_an_effect_whose_replay_alone_diverges_fails_alone_whatever_it_shrinks():
    """An effect cannot be scored on the windows its replay survives: even a positive shrink (the surviving windows
    fitting well) fails, and interacting with a partner does not rescue it."""
    blown = Alone(shrink=0.4, w=10.0, p=0.01, diverged=1)
    assert not blown.passed and "diverges in 1 window" in blown.reason()
    assert Alone(shrink=0.4, w=10.0, p=0.01).passed
    test = MemberTest("x", holdout_lr=100.0, gap_contribution=0.5, replay_w=10.0, replay_p=1e-4, alone=blown,
                      windows_worse=1.0, fit_delta_bic=-50.0)
    assert test.interacting and not test.passed_alone and not test.passed


def test_simulate_windows_reports_the_diverged_windows(flown, tmp_path, capsys):
    """A model file the loader accepts (a 1e5 N buoyancy error is refused there: beyond 0.5 W) whose replay still
    blows up: a gyroscopic surge-heave coupling of 1e4 N s/m (skew-symmetric, so it passes the damping check: it
    feeds no energy) turns the velocity at 1e4 / ~10 kg = 1000 rad/s, which the replay's 0.05 s RK4 step cannot
    follow."""
    nominal, run = flown
    path = write_run(tmp_path / "flown.csv", run.t, run.channels, "thrust", run.inputs)
    model = tmp_path / "blown.json"
    write_model_file(nominal.with_changes(effects=(plant_effect(
        {"name": "cross_coupled_damping", "params": {"D_Zu": 1e4, "D_Xw": -1e4}}, "test"),)), model)
    out = tmp_path / "gap.json"
    assert main(["simulate", "--model", str(model), "--windows", "--input", str(path), "--json", str(out)]) == 0
    g = json.loads(out.read_text())
    assert g["diverged_windows"]["flown.csv"] == g["windows"]["flown.csv"] > 0
    assert g["value"] > 100.0  # at the cap, not the 0.02 of the windows' first samples
    assert "diverged windows" in capsys.readouterr().out
