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


# ----------------------------------------------------------------------------- innovation gating (issue 16)
def _gated_run(values_edit, n=400, seed=4, **ekf_kw):
    t, x, f = _truth(n, seed=seed)
    cfg = SensorConfig(seabed_depth=30.0)
    stream = measure(t, x, cfg, seed=seed)
    values_edit(t, stream.values)
    ekf = UDrobotEKF(load_model(MODEL), DT, sensors=cfg, **ekf_kw)
    return t, x, ekf.run(stream, f[:-1]), cfg


def test_300m_depth_spike_is_rejected_and_estimate_stays_within_sensor_noise():
    """The issue's spike: one 300 m depth sample. Gated out, counted, the estimate never moves beyond
    a few sensor sigmas of the truth, no filter reset."""
    iz = CHANNELS.index("depth")
    k_spike = 200

    def spike(t, v):
        v[k_spike, iz] = 300.0

    t, x, res, cfg = _gated_run(spike)
    err = np.abs(res.x[:, 2] - x[:, 2])
    assert err[20:].max() < 4 * cfg.depth_sigma  # 4 sigma of the 1 cm sensor, everywhere after the start
    assert err[k_spike] < 4 * cfg.depth_sigma
    assert res.rejected[k_spike, iz] and res.rejected[:, iz].sum() == 1
    depth = next(c for c in res.channels if c.channel == "depth")
    assert depth.rejected == 1 and depth.reinitialisations == 0 and depth.samples == len(t)
    assert res.resets == 0 and not res.channel_faults
    # the same spike without gating: the estimate jumps by metres (the failure the gate prevents)
    _, _, raw, _ = _gated_run(spike, gate_probability=0.0)
    assert np.abs(raw.x[k_spike, 2] - x[k_spike, 2]) > 10.0


def test_spike_in_one_axis_keeps_the_other_axes_of_that_sensor():
    """A 2 m/s spike on the DVL's u axis and a 5 rad/s spike on the gyro's p: only those channels are dropped."""
    iu, ip = CHANNELS.index("dvl_u"), CHANNELS.index("p")

    def spikes(t, v):
        k_dvl = np.flatnonzero(np.isfinite(v[:, iu]) & (t > 8.0))[0]
        v[k_dvl, iu] += 2.0
        v[250, ip] += 5.0

    t, x, res, cfg = _gated_run(spikes)
    k_dvl = np.flatnonzero(res.rejected[:, iu])
    assert k_dvl.size == 1 and t[k_dvl[0]] > 8.0
    assert not res.rejected[k_dvl[0], [iu + 1, iu + 2]].any()  # dvl_v, dvl_w of the same ping used
    assert np.flatnonzero(res.rejected[:, ip]).tolist() == [250]
    assert not res.rejected[250, [ip + 1, ip + 2]].any()
    assert np.abs(res.x[:, 6] - x[:, 6]).max() < 5 * cfg.dvl_sigma
    assert np.abs(res.x[:, 9] - x[:, 9]).max() < 5 * cfg.rate_sigma


def test_gate_rarely_rejects_correct_samples():
    """On clean data the false-rejection rate follows gate_probability (1e-4 per sensor sample)."""
    t, x, res, _ = _gated_run(lambda t, v: None, n=600)
    sensor_samples = sum(c.samples for c in res.channels) / 2.5  # ~2.5 channels per sensor sample
    expected = 1e-4 * sensor_samples
    assert res.rejected.sum() <= max(3, 10 * expected)
    assert res.resets == 0


def test_persistent_jump_is_reported_and_the_channel_is_not_locked_out():
    """A real 0.5 m jump of the depth reading (sensor re-zeroed) is rejected at first, then reported as a
    ChannelFault after reject_timeout_s and followed: the filter must not ignore a sensor forever."""
    iz = CHANNELS.index("depth")
    t_jump = 8.0

    def jump(t, v):
        v[t >= t_jump, iz] += 0.5

    t, x, res, cfg = _gated_run(jump, n=500)
    faults = [f for f in res.channel_faults if f.channel == "depth"]
    assert faults, "the depth channel's continuous rejection must be reported"
    f0 = faults[0]
    assert t_jump <= f0.since < t_jump + 0.2
    assert 2.0 <= f0.t - f0.since <= 2.0 + 2 * DT and f0.rejections >= 3  # reject_timeout_s = 2 s
    assert abs(f0.innovation - 0.5) < 0.1
    late = t > f0.t + 1.0  # afterwards the filter follows the (offset) sensor and accepts it again
    assert np.abs(res.x[late, 2] - (x[late, 2] + 0.5)).max() < 5 * cfg.depth_sigma
    assert res.rejected[late, iz].mean() < 0.01
    depth = next(c for c in res.channels if c.channel == "depth")
    assert depth.reinitialisations == len(faults) and depth.longest_rejection_s >= 1.9


def test_excluded_channel_is_not_used():
    ekf = UDrobotEKF(load_model(MODEL), DT)
    ekf.exclude_channel("depth")
    z = np.full(len(CHANNELS), np.nan)
    z[CHANNELS.index("depth")] = 3.0
    ekf.step(np.zeros(4), z)
    assert np.isnan(ekf.nis) and abs(ekf.x[2]) < 0.01
    ekf.include_channel("depth")
    ekf.step(np.zeros(4), np.where(np.isfinite(z), 0.02, np.nan))
    assert ekf.dof == 1
    with pytest.raises(ValueError, match="unknown sensor channel"):
        ekf.exclude_channel("pressure")
