"""The model-based smoother reconstructs unlogged velocities of a nominal-plant run within its stated uncertainty."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.data import actuators, prepare
from udrobot_ctrl.gap.smoother import (
    ChannelNoise,
    SmootherError,
    measurement_noise,
    noise_draw,
    noise_model,
    smooth_run,
    spd_solve,
)
from udrobot_ctrl.io.runlog import interpolate_linear
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


# --- noise at each channel's own logging rate -------------------------------------------------------------------

GRID_DT = 0.02  # s, a 50 Hz run-log grid
SIGMA = 0.01  # the channels' noise std, their units
KNOTS = 1200  # samples of the slow stream: the MAD of ~1200 knot differences is within ~5 % (1 sigma) of sigma
SIGMA_TOL = 0.2  # relative: 4 sigma of that, plus the motion's part of the differences


def _logged(rate_hz, seed, t0=0.0, decimals=None, motion=0.1):
    """A channel logged at ``rate_hz`` with jittered stamps (5 % of the interval) and white noise SIGMA, on a slow
    manoeuvre (amplitude ``motion``, periods 20 and 7 s: its curvature between 2 Hz samples, ~motion (2 pi / 7)^2
    0.5^2 / 2 = 0.1 SIGMA, stays below the noise), linearly interpolated onto the 50 Hz grid as a converter does
    (stamps from ``t0``, e.g. a Unix time); optionally written with ``decimals`` decimals."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t_own = np.arange(KNOTS) * dt + rng.uniform(-0.05, 0.05, KNOTS) * dt
    truth = lambda t: motion * (np.sin(2 * np.pi * t / 20.0) + 0.5 * np.sin(2 * np.pi * t / 7.0))  # noqa: E731
    y_own = truth(t_own) + rng.normal(0.0, SIGMA, KNOTS)
    grid = np.arange(0.0, t_own[-1], GRID_DT)
    y = interpolate_linear(t0 + t_own, y_own, t0 + grid)
    return np.round(y, decimals) if decimals is not None else y


@pytest.mark.parametrize("rate_hz, interval", [(20.0, 2.5), (10.0, 5.0), (4.0, 12.5), (2.0, 25.0)])
def test_a_channel_interpolated_from_a_slower_stream_gets_its_own_noise_and_rate(rate_hz, interval):
    m = noise_model(_logged(rate_hz, seed=int(rate_hz)))
    assert m.interpolated and abs(m.interval - interval) <= 0.1 * interval, m
    assert abs(m.sigma / SIGMA - 1.0) < SIGMA_TOL, m
    # grid-to-grid differences would see a fraction of it: about sigma times sqrt(2) / interval
    d = np.diff(_logged(rate_hz, seed=int(rate_hz)))
    d = d[np.isfinite(d)]
    assert 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2) < 0.5 * SIGMA


def test_interpolation_on_unix_stamps_or_few_decimals_is_still_recognised():
    for y in (_logged(10.0, seed=3, t0=1.7e9), _logged(10.0, seed=4, decimals=6)):
        m = noise_model(y)
        assert m.interpolated and abs(m.interval - 5.0) <= 0.5, m
        assert abs(m.sigma / SIGMA - 1.0) < SIGMA_TOL, m


def test_a_channel_sampled_at_the_grid_rate_is_not_mistaken_quantised_or_not():
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 120.0, GRID_DT)
    y = 0.3 * np.sin(2 * np.pi * t / 20.0) + rng.normal(0.0, SIGMA, t.size)
    m = noise_model(y)
    assert not m.interpolated and abs(m.sigma / SIGMA - 1.0) < SIGMA_TOL, m
    # a pressure depth quantised to 2 mm with 1 mm noise, holding still half the time: flat stretches are no lines
    hold = np.where(t < 60.0, 5.0, 5.0 + 0.05 * (t - 60.0))
    q = np.round((hold + rng.normal(0.0, 0.001, t.size)) / 0.002) * 0.002
    assert not noise_model(q).interpolated
    # quantised to 1 mm with 2 mm noise: consecutive differences are equal by chance in ~15 % of the rows, no more
    # than their few values make likely
    q = np.round((5.0 + 0.3 * np.sin(t / 5.0) + rng.normal(0.0, 0.002, t.size)) / 0.001) * 0.001
    m = noise_model(q)
    assert not m.interpolated and abs(m.sigma / 0.002 - 1.0) < SIGMA_TOL, m


def test_a_steady_climb_between_slow_samples_is_not_counted_as_noise():
    """2 Hz depth of a vehicle climbing at 0.5 m/s: 0.25 m between samples, yet the noise is 1 cm."""
    rng = np.random.default_rng(6)
    t_own = np.arange(400) * 0.5
    z = 20.0 - 0.5 * t_own + rng.normal(0.0, SIGMA, t_own.size)
    m = noise_model(interpolate_linear(t_own, z, np.arange(0.0, t_own[-1], GRID_DT)))
    assert abs(m.interval - 25.0) <= 2.5 and abs(m.sigma / SIGMA - 1.0) < SIGMA_TOL, m


def test_drawn_noise_is_interpolated_like_the_log_and_measures_back():
    model = ChannelNoise(SIGMA, 5.0)
    e = noise_draw(model, 6000, np.random.default_rng(7))
    back = noise_model(e)
    assert abs(back.interval - 5.0) <= 0.5 and abs(back.sigma / SIGMA - 1.0) < SIGMA_TOL, back
    # between its knots an interpolated draw has less variance than at them: 2/3 sigma^2 on average
    assert 0.7 < np.var(e) / (2.0 / 3.0 * SIGMA ** 2) < 1.3
    # a sampled channel's draw is white at the grid rate
    w = noise_draw(ChannelNoise(SIGMA), 6000, np.random.default_rng(8))
    assert abs(np.std(w) / SIGMA - 1.0) < 0.05 and abs(np.corrcoef(w[1:], w[:-1])[0, 1]) < 0.05


def test_the_filter_weighs_an_interpolated_channel_as_one_sample_per_knot():
    y = _logged(10.0, seed=9)
    own = noise_model(y).sigma
    # every grid row taken: each of the 5 rows per sample carries 1/5 of its information
    assert measurement_noise({"z": y}, ["z"], step=1)["z"] == pytest.approx(own * np.sqrt(noise_model(y).interval))
    # a filter at the channel's own rate (or slower) takes its noise as it is
    assert measurement_noise({"z": y}, ["z"], step=5)["z"] == pytest.approx(own, rel=0.05)
