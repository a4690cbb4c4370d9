"""The replay scores the accelerometer of runs without a DVL: the specific force of the replayed motion against the
measurement minus the smoother's bias estimate."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.effects import Actuation, plant_hooks
from udrobot_ctrl.gap.locate import noise_floor
from udrobot_ctrl.gap.shrink import (
    SIM_COLUMNS,
    accel_bias,
    batchable,
    errors,
    gap,
    simulate_windows,
    simulate_windows_each,
    simulate_windows_runs,
    simulate_windows_sets,
    specific_force,
)
from udrobot_ctrl.vehicle import load_model

from .stock_sim import ACCEL_BIAS, STATE, STOCK, simulate

P = plant_parameters(load_model("pendulum:chin"))


def test_specific_force_of_a_vehicle_at_rest_and_accelerating():
    eta, nu = np.zeros(6), np.zeros(6)
    np.testing.assert_allclose(specific_force(eta, nu, np.zeros(6)), [0.0, 0.0, -9.81])
    pitched = np.array([0, 0, 0, 0, 0.3, 0])  # nose up: gravity has a forward component in body axes
    np.testing.assert_allclose(specific_force(pitched, nu, np.zeros(6)),
                               [9.81 * np.sin(0.3), 0.0, -9.81 * np.cos(0.3)], atol=1e-12)
    turning = np.array([0.5, 0, 0, 0, 0, 0.2])  # surging at 0.5 m/s, yawing at 0.2 rad/s: centripetal 0.1 m/s^2
    np.testing.assert_allclose(specific_force(eta, turning, np.array([0.3, 0, 0, 0, 0, 0])),
                               [0.3, 0.1, -9.81], atol=1e-12)


@pytest.fixture(scope="module")
def stock_run():
    run, truth = simulate(duration=40.0, seed=21, sensors=STOCK)
    return prepare(run, P), truth


def test_a_stock_replay_scores_the_accelerometer_at_its_noise_floor(stock_run):
    """The nominal plant flew the run, so the replayed specific force matches the accelerometer to its noise: the
    bias the smoother estimated is the one logged, and the NRMSE of ax ay az is the floor the noise alone gives."""
    prep, _ = stock_run
    np.testing.assert_allclose(accel_bias(prep), ACCEL_BIAS, atol=0.01)
    sim = simulate_windows(prep, P, (), 8.0)
    assert sim.shape == (prep.n, SIM_COLUMNS)
    assert {"ax", "ay", "az"} <= set(errors(prep, sim))
    score = gap([prep], [sim])
    floor = noise_floor([prep], [sim], P, 8.0, score.scale, draws=2)
    for c in ("ax", "ay", "az"):
        assert score.per_channel[c] < 1.2 * floor[c], (c, score.per_channel[c], floor[c])


def test_an_added_mass_error_in_surge_shows_in_ax(stock_run):
    """The vehicle as logged, replayed with twice the surge added mass: the surge acceleration of every thrust step
    is wrong, and ax is the one channel without a DVL that sees it."""
    prep, _ = stock_run
    heavy = replace(P, M=P.M + np.diag([P.M_A[0, 0], 0, 0, 0, 0, 0]),
                    M_inv=np.linalg.inv(P.M + np.diag([P.M_A[0, 0], 0, 0, 0, 0, 0])))
    nominal = gap([prep], [simulate_windows(prep, P, (), 8.0)])
    wrong = gap([prep], [simulate_windows(prep, heavy, (), 8.0)], nominal.scored)
    assert "ax" in nominal.scored
    assert wrong.per_channel["ax"] > 2.0 * nominal.per_channel["ax"], (wrong.per_channel, nominal.per_channel)


def test_runs_with_logged_velocities_do_not_score_the_accelerometer():
    """No smoother ran, so no bias estimate: the accelerometer is not compared (its bias would read as a gap)."""
    run, _ = simulate(duration=20.0, seed=22, sensors=STATE + ("ax", "ay", "az"))
    prep = prepare(run, P)
    assert accel_bias(prep) is None
    assert not {"ax", "ay", "az"} & set(errors(prep, simulate_windows(prep, P, (), 8.0)))


def test_effect_sets_replayed_together_are_each_their_own_replay(stock_run):
    """The batched replay (every set's windows integrated together) gives each set of effects what its own replay
    gives: the nominal plant, a force (buoyancy), an added mass (its own mass matrix per set), an input filter (a
    lag: its own commands per set) and two of them at once, states and specific force alike, to rounding."""
    prep, _ = stock_run
    act = Actuation(prep.B, prep.inflow, prep.f_ref, P.M_A)
    heavier = PlantEffect("added_mass_error", {f"scale_{d}d{v}": 0.0 for d, v in zip("XYZKMN", "uvwpqr")}
                          | {"scale_Xdu": 0.8, "scale_Zdw": 0.5})
    sets = [[], [PlantEffect("buoyancy_offset", {"dB_N": 2.0})], [heavier],
            [PlantEffect("thruster_lag", {"T_lag_s": 0.3})],
            [PlantEffect("thruster_lag", {"T_lag_s": 0.3}), heavier]]
    hook_sets = [[plant_hooks(e, P, act) for e in effects] for effects in sets]
    together = simulate_windows_sets(prep, P, hook_sets, 8.0)
    assert len(together) == len(sets)
    alone = [simulate_windows(prep, P, hooks, 8.0) for hooks in hook_sets]
    for a, b in zip(together, alone):
        assert a.shape == (prep.n, SIM_COLUMNS) and np.array_equal(np.isnan(a), np.isnan(b))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    # and the sets do differ: each was replayed with its own effects
    for k in range(1, len(sets)):
        assert np.nanmax(np.abs(together[k][:, 8] - together[0][:, 8])) > 1e-3


def test_runs_replayed_together_are_each_their_own_replay_bit_for_bit(stock_run):
    """Runs of different lengths integrated as one batch give each run, with each set of effects, exactly what its
    own replay gives (every term row by row, the inertia products on each run's rows alone): states, specific force
    and window column, the same bits; a closed-loop run is batched with no other."""
    prep, _ = stock_run
    other = prepare(simulate(duration=27.0, seed=22, sensors=STOCK)[0], P)
    act = Actuation(prep.B, prep.inflow, prep.f_ref, P.M_A)
    heavier = PlantEffect("added_mass_error", {f"scale_{d}d{v}": 0.0 for d, v in zip("XYZKMN", "uvwpqr")}
                          | {"scale_Xdu": 0.8, "scale_Zdw": 0.5})
    hook_sets = [[plant_hooks(e, P, act) for e in effects]
                 for effects in ([], [PlantEffect("buoyancy_offset", {"dB_N": 2.0})], [heavier])]
    runs = [prep, other, prep]
    assert batchable(runs, 8.0) == [[0, 1, 2]]
    together = simulate_windows_runs(runs, P, hook_sets, 8.0)
    for pr, sims in zip(runs, together):
        for a, b in zip(sims, simulate_windows_sets(pr, P, hook_sets, 8.0)):
            assert np.isfinite(a[:, 12]).any()  # the accelerometer is scored: its specific force is stored
            np.testing.assert_array_equal(a, b)
    for a, pr in zip(simulate_windows_each(runs, P, (), 8.0), runs):
        np.testing.assert_array_equal(a, simulate_windows(pr, P, (), 8.0))
    closed = replace(other, feedback=object())  # any loop: batchable only looks whether there is one
    assert batchable([prep, closed, other], 8.0) == [[0, 2], [1]]
