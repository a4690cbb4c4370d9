"""The per-step fast paths equal their reference paths (issue 38): compiled casadi calls, the EKF kernel, the
fault monitor's frozen-sensor statistics and window propagation. No timing is asserted."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.control.ekf import UDrobotEKF
from udrobot_ctrl.control.fastpath import CompiledFunction
from udrobot_ctrl.control.faults import FROZEN, RECOVERED, FrozenChannelDetector, ThrusterFaultDetector
from udrobot_ctrl.control.mpc import linearization_function
from udrobot_ctrl.control.sensors import ANGLE_CHANNELS, CHANNEL_STATE, CHANNELS, SensorConfig, measure
from udrobot_ctrl.dynamics.plant import plant_parameters, wrap_angle
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.vehicle import load_model

MODELS = ["cfd:morison", "bluerov2-heavy"]


@pytest.mark.parametrize("compile", [True, False])
def test_compiled_function_equals_casadi(compile):
    p = plant_parameters(load_model("cfd:morison"))
    lin = linearization_function(p, 0.05)
    fast = CompiledFunction(lin, p, 0.05, compile=compile)
    rng = np.random.default_rng(0)
    for _ in range(5):
        x, f = rng.normal(size=12) * 0.3, rng.normal(size=4) * 10
        for got, ref in zip(fast(x, f), lin(x, f)):
            np.testing.assert_allclose(got.reshape(ref.shape), ref.full(), rtol=1e-12, atol=1e-12)
    mapped = CompiledFunction(lin.map(3), p, 0.05, "map", 3, compile=compile)
    X, F = rng.normal(size=(12, 3)) * 0.3, rng.normal(size=(4, 3))
    for got, ref in zip(mapped(X, F), lin.map(3)(X, F)):
        np.testing.assert_allclose(got, ref.full(), rtol=1e-12, atol=1e-12)


def _stream(model, n=400, seed=0):
    v = load_model(model)
    dt = 0.05
    t = np.arange(n) * dt
    f = np.zeros((n, v.n_thrusters))
    f[:, 0], f[:, 1] = 10 + 5 * np.sin(0.5 * t), 8 + 5 * np.cos(0.3 * t)
    f[:, 2] = f[:, 3] = 0.2 + 3 * np.sin(0.4 * t)
    res = simulate(v, np.r_[0, 0, 1.0, np.zeros(9)], (n - 1) * dt, inputs=f[:-1], dt=dt)
    cfg = SensorConfig(seabed_depth=20.0, usbl=True)
    stream = measure(res.t, res.x, cfg, seed=seed)
    stream.values[120, CHANNELS.index("depth")] = 300.0  # a spike (gated out)
    stream.values[150, CHANNELS.index("dvl_u")] += 2.0  # one axis of a sensor
    stream.values[200:, CHANNELS.index("depth")] += 0.5  # a persistent jump (rejected, then re-initialised)
    return v, cfg, stream, f


@pytest.mark.parametrize("model", MODELS)
def test_ekf_fast_path_equals_reference(model):
    """Compiled step + numba update against filterpy's predict + the numpy update, gating and re-initialisation
    included: equal to 1e-9."""
    v, cfg, stream, f = _stream(model)
    runs = [UDrobotEKF(v, 0.05, sensors=cfg, x0=np.r_[0, 0, 1.0, np.zeros(9)], fast=fast).run(stream, f[:-1])
            for fast in (True, False)]
    a, b = runs
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.sigma, b.sigma, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.nis, b.nis, rtol=1e-9, atol=1e-9)
    assert np.array_equal(a.dof, b.dof) and np.array_equal(a.rejected, b.rejected) and a.status == b.status
    assert a.channels == b.channels and a.resets == b.resets
    assert [(c.t, c.channel) for c in a.channel_faults] == [(c.t, c.channel) for c in b.channel_faults]
    assert a.rejected.sum() >= 3 and a.channel_faults  # the gate and the re-initialisation were exercised


def _reference_frozen(sigmas, window, threshold, rows):
    """The frozen-sensor test written per channel with numpy (the previous implementation)."""
    bufs = [[] for _ in CHANNELS]
    frozen = np.zeros(len(CHANNELS), bool)
    events = []
    for k, z in enumerate(rows):
        for i in np.flatnonzero(np.isfinite(z)):
            bufs[i] = (bufs[i] + [float(z[i])])[-window:]
            if len(bufs[i]) < window:
                continue
            a = np.asarray(bufs[i])
            if ANGLE_CHANNELS[i]:
                a = np.unwrap(a)
            stat = float(np.var(a, ddof=1) * (window - 1) / sigmas[i] ** 2)
            if not frozen[i] and stat < threshold:
                frozen[i] = True
                events.append((k, FROZEN, int(i), stat))
            elif frozen[i] and stat > threshold:
                frozen[i] = False
                events.append((k, RECOVERED, int(i), stat))
    return events


def test_frozen_detector_equals_the_per_channel_reference():
    sig = SensorConfig().sigmas()
    rng = np.random.default_rng(1)
    n = 3000
    rows = np.cumsum(rng.normal(scale=0.01, size=(n, len(CHANNELS))), axis=0) + rng.standard_normal(
        (n, len(CHANNELS))) * sig
    rows[:, CHANNELS.index("psi")] = wrap_angle(np.linspace(0, 60, n) + rng.standard_normal(n) * sig[3])
    rows[::3, 7:10] = np.nan  # slower DVL
    rows[500:800, 0] = rows[500, 0]  # frozen depth, then alive
    rows[1200:1500, 3] = rows[1200, 3]  # frozen heading
    det = FrozenChannelDetector(sig, window=10)
    got = []
    for k, z in enumerate(rows):
        got += [(k, e.kind, e.index) for e in det.step(0.05 * k, z)]
    ref = _reference_frozen(sig, 10, det.threshold, rows)
    assert got == [r[:3] for r in ref]
    assert {(e[1], e[2]) for e in ref} >= {(FROZEN, 0), (RECOVERED, 0), (FROZEN, 3), (RECOVERED, 3)}


def test_thruster_windows_equal_per_window_propagation():
    """The batched window bank gives each window the states, sensitivities and residual rows that simulating
    it alone with the casadi linearisation gives."""
    p = plant_parameters(load_model("cfd:morison"))
    sig = SensorConfig().sigmas()
    det = ThrusterFaultDetector(p, 0.05, sig, window_s=1.0, stride_s=0.25)
    lin = linearization_function(p, 0.05)
    rng = np.random.default_rng(2)
    x_est = np.r_[0, 0, 1.0, np.zeros(9)]
    P_est = np.eye(12) * 1e-3
    captured = []
    det._evaluate = lambda t, win: captured.append(win)  # keep the finished windows, never detect
    fs, zs = [], []
    for k in range(26):
        f = rng.normal(size=4) * 5
        z = x_est[CHANNEL_STATE] + rng.normal(size=len(CHANNELS)) * sig
        z[7:10] = np.nan if k % 4 else z[7:10]
        det.step(0.05 * k, f, z, x_est, P_est)
        fs.append(f)
        zs.append(z)
    assert captured, "a window must have finished"
    win = captured[0]  # opened at step 0, fed the commands and samples of steps 1 .. 20
    x = x_est.copy()
    Phi, G, C = np.eye(12), np.zeros((12, 4)), np.zeros((12, 4))
    rows = []
    for step in range(1, det.window_steps + 1):
        fc = det.correct(fs[step])
        xn, A, B = (a.full() for a in lin(x, fc))
        x = xn.ravel()
        Phi, G, C = A @ Phi, A @ G + B, A @ C + B * fc
        np.testing.assert_allclose(win.Phi[step], Phi, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(win.G[step], G, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(win.C[step], C, rtol=1e-9, atol=1e-12)
        ch = np.flatnonzero(np.isfinite(zs[step]))
        e = zs[step][ch] - x[CHANNEL_STATE[ch]]
        e[ANGLE_CHANNELS[ch]] = wrap_angle(e[ANGLE_CHANNELS[ch]])
        rows += [(step, int(c), int(CHANNEL_STATE[c]), float(ei), float(zs[step][c])) for c, ei in zip(ch, e)]
    assert [r[:3] for r in win.rows] == [r[:3] for r in rows]
    np.testing.assert_allclose([r[3] for r in win.rows], [r[3] for r in rows], rtol=0, atol=1e-9)
    np.testing.assert_allclose(win.f, [det.correct(f) for f in fs[1:det.window_steps + 1]])
