"""EKF on simulated UDrobot data: accuracy below the sensor noise, NIS consistency, DVL dropout, divergence."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.control.ekf import ProcessNoise, UDrobotEKF
from udrobot_ctrl.control.sensors import CHANNELS, SensorConfig, dvl_valid, measure
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import rk4_step
from udrobot_ctrl.vehicle import load_model

DT = 0.05
MODEL = "cfd:morison"


def _thrusts(n):
    """Smooth thrust pattern: dives from the surface to ~1.5-2.5 m, turns and surges."""
    t = np.arange(n) * DT
    f = np.zeros((n, 4))
    f[:, 0] = 10 + 6 * np.sin(0.5 * t)
    f[:, 1] = 8 + 6 * np.cos(0.3 * t)
    f[:, 2] = f[:, 3] = np.where(t < 3.0, 12.0, 0.2 + 3.0 * np.sin(0.4 * t))
    f[:, 3] += 0.5 * np.sin(0.7 * t)
    return f


def _truth(n, noise=None, extra_force=None, seed=0, model=MODEL):
    """True trajectory with piecewise-constant random forces drawn as the EKF's process model assumes."""
    noise = noise or ProcessNoise()
    p = plant_parameters(load_model(model))
    rng = np.random.default_rng(seed)
    f = _thrusts(n)
    x = np.zeros((n, 12))
    w = rng.standard_normal((n, 6)) * np.array([noise.force_sigma] * 3 + [noise.moment_sigma] * 3)
    for k in range(n - 1):
        tau = p.T @ np.clip(f[k], p.f_min, p.f_max) + w[k]
        if extra_force is not None:
            tau = tau + extra_force(k * DT)
        x[k + 1] = rk4_step(p, x[k], tau, DT)
        x[k + 1, :6] += rng.standard_normal(6) * noise.pose_sigma
    return np.arange(n) * DT, x, f


def test_ekf_beats_sensor_noise_and_is_consistent():
    n = 600  # 30 s
    t, x, f = _truth(n)
    cfg = SensorConfig(seabed_depth=6.0)
    stream = measure(t, x, cfg, seed=1)
    ekf = UDrobotEKF(load_model(MODEL), DT, sensors=cfg)
    res = ekf.run(stream, f[:-1])
    rmse = res.rmse(x)
    # filtered states better than the raw sensor on the same channel
    assert rmse["z"] < cfg.depth_sigma
    assert rmse["phi"] < cfg.roll_pitch_sigma and rmse["theta"] < cfg.roll_pitch_sigma
    assert rmse["psi"] < cfg.heading_sigma
    assert rmse["u"] < cfg.dvl_sigma and rmse["w"] < cfg.dvl_sigma
    assert rmse["p"] < cfg.rate_sigma and rmse["r"] < cfg.rate_sigma
    # consistency: NIS averages its measurement dimension (chi-square mean)
    assert 0.85 < res.nis_normalised() < 1.15
    assert res.nis_mean() == pytest.approx(np.mean(res.dof[res.dof > 0]), rel=0.15)
    assert res.resets == 0 and not any(s.startswith("diverged") for s in res.status)
    # estimates stay within 3 sigma of the truth nearly all the time
    inside = np.abs(res.x[:, 2] - x[:, 2]) < 3 * res.sigma[:, 2]
    assert inside.mean() > 0.97


def test_dvl_dropout_near_surface_and_seabed():
    n = 400
    t, x, f = _truth(n)
    cfg = SensorConfig(seabed_depth=2.0)  # dives close to the seabed: dropout at both ends
    stream = measure(t, x, cfg, seed=2)
    dvl = np.isfinite(stream.values[:, CHANNELS.index("dvl_u")])
    lock = dvl_valid(x, cfg)
    assert not lock[0] and (~lock & (x[:, 2] > 1.0)).any()  # at the surface and near the seabed
    assert not np.any(dvl & ~lock)
    ekf = UDrobotEKF(load_model(MODEL), DT, sensors=cfg)
    res = ekf.run(stream, f[:-1])
    assert np.all(res.dof[~lock] <= 7)  # depth + attitude + rates only
    assert np.all(np.isfinite(res.x))
    gap = ~lock
    gap[:40] = False  # the surface start is also the filter's transient
    err_u = np.abs(res.x[gap, 6] - x[gap, 6])
    assert err_u.max() < 0.1  # the model carries the velocity through the dropout
    # the filter knows it is less certain without the DVL
    assert np.median(res.sigma[gap, 6]) > 1.1 * np.median(res.sigma[lock, 6])
    assert res.resets == 0


def test_divergence_is_flagged_and_filter_recovers():
    n = 400
    t, x, f = _truth(n, extra_force=lambda tt: np.array([0.0, 0.0, 80.0 if 5.0 < tt < 12.0 else 0.0, 0, 0, 0]))
    cfg = SensorConfig(seabed_depth=30.0)
    stream = measure(t, x, cfg, seed=3)
    ekf = UDrobotEKF(load_model(MODEL), DT, sensors=cfg)
    res = ekf.run(stream, f[:-1])
    assert res.resets >= 1
    flagged = [i for i, s in enumerate(res.status) if s.startswith("diverged")]
    assert flagged and 5.0 < t[flagged[0]] < 12.0
    assert np.all(np.isfinite(res.x))
    late = t > 16.0  # after the disturbance stops, the filter is consistent again
    assert np.sqrt(np.mean((res.x[late, 2] - x[late, 2]) ** 2)) < cfg.depth_sigma


def test_heading_residual_wraps_and_bad_input_never_throws():
    ekf = UDrobotEKF(load_model(MODEL), DT)
    x0 = np.zeros(12)
    x0[5] = np.pi - 0.01
    ekf.reset(x0)
    z = np.full(len(CHANNELS), np.nan)
    z[CHANNELS.index("psi")] = -np.pi + 0.01  # 0.02 rad away across the wrap
    ekf.step(np.zeros(4), z)
    assert abs(abs(ekf.x[5]) - np.pi) < 0.02 and ekf.nis < 1.0
    ekf.step(np.array([np.nan, 0, 0, 0]), z)  # NaN thrust: reinitialised, not raised
    assert np.all(np.isfinite(ekf.x)) and ekf.last_status.startswith("diverged")
    ekf.step(np.zeros(4), np.full(len(CHANNELS), np.nan))  # no measurement at all: prediction only
    assert np.isnan(ekf.nis) and np.all(np.isfinite(ekf.x))


def test_filter_model_mismatch_shows_in_rmse_and_nis():
    """EKF of model A on data of plant B (the compare matrix): the matched model tracks surge best."""
    from udrobot_ctrl.control.ekf import ekf_on_trajectory
    from udrobot_ctrl.dynamics.sim import simulate

    n = 300
    plant = "pendulum:chin"
    f = _thrusts(n)
    res = simulate(plant, np.r_[0, 0, 1.0, np.zeros(9)], (n - 1) * DT, inputs=f[:-1], dt=DT)
    matched = ekf_on_trajectory(plant, res.t, res.x, res.u, dt=DT)
    other = ekf_on_trajectory("free_decay:morison", res.t, res.x, res.u, dt=DT)
    assert matched["rmse"]["u"] < other["rmse"]["u"]
    assert matched["nis_per_dof"] < other["nis_per_dof"]
    assert matched["resets"] == 0
    with pytest.raises(ValueError, match="multiple"):
        ekf_on_trajectory(plant, res.t, res.x, res.u, dt=0.07)
