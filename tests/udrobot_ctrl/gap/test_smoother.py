"""The model-based smoother reconstructs unlogged velocities of a nominal-plant run within its stated uncertainty."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.data import actuators, prepare
from udrobot_ctrl.gap.smoother import SmootherError, smooth_run, spd_solve
from udrobot_ctrl.vehicle import load_model

from .stock_sim import ACCEL_BIAS, NOISE, STOCK, simulate

P = plant_parameters(load_model("pendulum:chin"))


@pytest.fixture(scope="module")
def stock():
    run, truth = simulate(duration=60.0, seed=1)
    f, B, _, _ = actuators(run, P)
    return run, truth, smooth_run(run.t, run.channels, f @ B.T, P)


def _rms(e):
    return float(np.sqrt(np.mean(e ** 2)))


def test_reconstructs_velocities_from_depth_imu_and_thrust(stock):
    run, truth, sm = stock
    assert set(sm.channels) == set(STOCK)
    inner = slice(20, -20)  # 1 s from the ends, where the smoother has data on one side only
    for i, c in enumerate(("u", "v", "w")):
        err = sm.nu[inner, i] - truth[c][inner]
        # the model is exact here, so the error is what the sensors leave: a few cm/s, well below the motion
        assert _rms(err) < 0.05 and _rms(err) < 0.25 * np.std(truth[c]), (c, _rms(err))
        # and the stated posterior std covers it (a consistent smoother: |err| < 3 sigma nearly everywhere)
        assert np.mean(np.abs(err) < 3 * sm.sigma_nu[inner, i]) > 0.9, c
    for i, c in enumerate(("p", "q", "r")):  # gyro-logged rates: smoothed below the gyro noise
        assert _rms(sm.nu[inner, 3 + i] - truth[c][inner]) < NOISE[c]
    # heave acceleration (depth + accelerometer) within 0.05 m/s^2 of the truth (accelerometer noise 0.03)
    assert _rms(sm.nu_dot[inner, 2] - truth["nu_dot"][inner, 2]) < 0.05
    # the accelerometer bias is found where depth pins the heave acceleration
    assert sm.accel_bias[2] == pytest.approx(ACCEL_BIAS[2], abs=0.015)


def test_dead_reckoned_position_follows_the_track(stock):
    run, truth, sm = stock
    track = np.hypot(np.diff(truth["x"]), np.diff(truth["y"])).sum()
    end = np.hypot(sm.eta[-1, 0] - truth["x"][-1], sm.eta[-1, 1] - truth["y"][-1])
    assert end < 0.15 * track, (end, track)


def test_position_fixes_pin_the_surge_velocity():
    run, truth = simulate(duration=40.0, seed=2, sensors=STOCK + ("x", "y"))
    f, B, _, _ = actuators(run, P)
    sm = smooth_run(run.t, run.channels, f @ B.T, P)
    ref = smooth_run(run.t, {c: v for c, v in run.channels.items() if c not in ("x", "y")}, f @ B.T, P)
    assert np.median(sm.sigma_nu[:, 0]) < np.median(ref.sigma_nu[:, 0])
    assert _rms(sm.eta[20:-20, 0] - truth["x"][20:-20]) < 3 * NOISE["x"]


def test_divergence_is_reported_and_prepare_falls_back():
    run, _ = simulate(duration=10.0, seed=3)
    f, B, _, _ = actuators(run, P)
    with pytest.raises(SmootherError, match="diverged at t ="):
        smooth_run(run.t, run.channels, f @ B.T * 1e200, P, label="blowup")
    run.channels["az"][50] = 1e300  # a corrupt reading (finite): the state overflows
    prep = prepare(run, P)
    assert not prep.reconstructed.any() and prep.smoothed is None
    assert any("not reconstructed" in n for n in prep.notes)
    assert prep.dof_ok.tolist() == [False, False, False, True, True, True]


def test_prepare_fills_velocities_only_where_not_logged():
    run, truth = simulate(duration=30.0, seed=4, sensors=STOCK + ("u",))
    prep = prepare(run, P)
    assert prep.observed.tolist() == [True, False, True, True, True, True]
    assert prep.reconstructed.tolist() == [False, True, True, False, False, False]
    assert prep.dof_ok.tolist() == [True, False, True, True, True, True]
    assert np.isfinite(prep.nu).all()
    assert _rms(prep.nu[20:-20, 2] - truth["w"][20:-20]) < 0.03


def test_the_covariance_solve_matches_the_general_one_and_refuses_a_singular_matrix():
    rng = np.random.default_rng(2)
    A = rng.normal(size=(19, 19))
    B = rng.normal(size=(19, 5))
    spd = A @ A.T + np.eye(19)
    np.testing.assert_allclose(spd_solve(spd, B), np.linalg.solve(spd, B), rtol=1e-10, atol=1e-12)
    indefinite = 0.5 * (A + A.T)  # Cholesky fails: the general solver takes it
    np.testing.assert_allclose(spd_solve(indefinite, B), np.linalg.solve(indefinite, B), rtol=1e-8, atol=1e-10)
    with pytest.raises(np.linalg.LinAlgError):
        spd_solve(np.zeros((19, 19)), B)
