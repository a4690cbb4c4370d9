"""Simulation: RK4 vs solve_ivp, batch vs single, and the ``simulate`` replay command."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.cli.simulate import replay
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.io import runlog
from udrobot_ctrl.vehicle import load_model

F = np.array([[20.0, 12.0, 5.0, -3.0]])


def test_rk4_agrees_with_solve_ivp():
    x0 = np.zeros(12)
    x0[3] = 0.1
    a = simulate("cfd:morison", x0, 3.0, inputs=F, dt=0.01)
    b = simulate("cfd:morison", x0, 3.0, inputs=F, dt=0.01, method="solve_ivp")
    np.testing.assert_allclose(a.x, b.x, atol=1e-6)  # RK4 global error O(dt^4)


def test_batch_equals_single_runs():
    rng = np.random.default_rng(0)
    x0 = np.zeros((3, 12))
    x0[:, 6:] = rng.normal(scale=0.2, size=(3, 6))
    batch = simulate("pendulum:chin", x0, 1.0, inputs=np.repeat(F[None], 3, axis=1), dt=0.02)
    for i in range(3):
        single = simulate("pendulum:chin", x0[i], 1.0, inputs=F, dt=0.02)
        np.testing.assert_allclose(batch.x[:, i], single.x, atol=1e-12)


def test_closed_loop_controller_and_saturation():
    def ctrl(t, x):  # proportional surge speed control, asks for more than the thrusters give
        return np.array([400.0 * (0.5 - x[6])] * 2 + [0.0, 0.0])

    res = simulate("pendulum:chin", np.zeros(12), 20.0, controller=ctrl, dt=0.02)
    p = plant_parameters(load_model("pendulum:chin"))
    # steady state: 800 (0.5 - u) = K_L u + K_Q u^2
    k_l, k_q = p.D_L[0, 0] + 800.0, p.Q[0, 0]
    u_ss = (-k_l + np.sqrt(k_l ** 2 + 4 * k_q * 400.0)) / (2 * k_q)
    assert res.saturated[0] and not res.saturated[-1]
    assert res.x[-1, 6] == pytest.approx(u_ss, rel=2e-3)


def test_replay_nonuniform_matches_uniform_sim():
    p = plant_parameters(load_model("pendulum:chin"))
    tau = F @ p.T.T
    t = np.arange(0, 2.0001, 0.01)
    xs = replay(p, t, np.zeros(12), np.repeat(tau, len(t), axis=0))
    ref = simulate(p, np.zeros(12), 2.0, inputs=F, dt=0.01)
    np.testing.assert_allclose(xs, ref.x, atol=1e-12)
    tn = np.sort(np.r_[0.0, np.random.default_rng(2).uniform(0, 2, 60), 2.0])
    xn = replay(p, tn, np.zeros(12), np.repeat(tau, len(tn), axis=0))
    np.testing.assert_allclose(xn[-1], ref.x[-1], atol=1e-6)


def _write_run(path, kind, u, t, channels=None):
    n = len(t)
    runlog.write_run(path, t, channels or {"x": np.zeros(n), "u": np.full(n, 0.1)}, kind, np.repeat(u, n, 0))


@pytest.mark.parametrize("kind,u", [("thrust", F), ("tau", np.array([[30.0, 0, 10.0, 0, 0, 0.5]])),
                                    ("pwm", np.array([[1700.0, 1650.0, 1500.0, 1400.0]]))])
def test_simulate_command_replays_inputs(tmp_path, kind, u, capsys):
    t = np.sort(np.r_[0.0, np.random.default_rng(3).uniform(0, 3, 40), 3.0])
    src, out = tmp_path / "in.csv", tmp_path / "sim.csv"
    _write_run(src, kind, u, t)
    assert main(["simulate", "--model", "pendulum:chin", "--input", str(src), "--out", str(out)]) == 0
    assert "y at rest (0: never logged)" in capsys.readouterr().err  # the channels the first row lacks, named
    sim = runlog.read_run(out)
    np.testing.assert_array_equal(sim.t, t)
    assert sim.input_kind == kind
    np.testing.assert_allclose(sim.inputs, np.repeat(u, len(t), 0))
    assert sim.channels["u"][0] == pytest.approx(0.1) and sim.channels["u"][-1] > 0.2  # accelerated forward


def test_simulate_refuses_to_overwrite_input(tmp_path, capsys):
    src = tmp_path / "in.csv"
    _write_run(src, "thrust", F, np.linspace(0, 1, 11))
    before = src.read_bytes()
    assert main(["simulate", "--model", "cfd:chin", "--input", str(src), "--out", str(src)]) == 2
    assert src.read_bytes() == before
    assert "is the input" in capsys.readouterr().err


def test_fastsim_rollout_equals_numpy_rk4(tmp_path, monkeypatch):
    from udrobot_ctrl.dynamics import fastsim

    monkeypatch.setenv("UDROBOT_CACHE", str(tmp_path))
    x0 = np.zeros(12)
    x0[3] = 0.1
    u = np.tile(F, (150, 1))
    u[50:, 0] = 60.0  # beyond the forward limit: clipped like sim.simulate
    ref = simulate("cfd:chin", x0, 1.5, inputs=u, dt=0.01).x
    for compile_ in (False, True):
        xs = fastsim.Rollout("cfd:chin", 0.01, 150, compile=compile_)(x0, u)
        np.testing.assert_allclose(xs, ref, atol=1e-12)


def test_fastsim_batch_equals_single_vehicles():
    from udrobot_ctrl.dynamics import fastsim

    v = load_model("pendulum:chin")
    models = [v, load_model("free_decay:morison"), v.with_changes(linear_damping=2 * v.linear_damping)]
    x0 = np.zeros(12)
    x0[4] = 0.05
    u = np.tile(F, (100, 1))
    xb = fastsim.rollout_batch(models, x0, u, record_every=5)
    assert xb.shape == (21, 3, 12)
    for i, m in enumerate(models):
        ref = simulate(m, x0, 1.0, inputs=u, dt=0.01).x[::5]
        np.testing.assert_allclose(xb[:, i], ref, atol=1e-12)


def test_simulate_command_solve_ivp_matches_rk4_from_full_initial_state(tmp_path):
    t = np.sort(np.r_[0.0, np.random.default_rng(5).uniform(0, 2, 30), 2.0])
    n = len(t)
    names = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
    x0 = [0.0, 0.0, 1.0, 0.05, -0.03, 0.2, 0.3, 0.0, 0.05, 0.0, 0.1, 0.0]
    chans = {k: np.r_[x0[i], np.full(n - 1, np.nan)] for i, k in enumerate(names)}
    src = tmp_path / "in.csv"
    runlog.write_run(src, t, chans, "thrust", np.repeat(F, n, 0))
    outs = {}
    for method in ("rk4", "solve_ivp"):
        outs[method] = tmp_path / f"{method}.csv"
        assert main(["simulate", "--model", "cfd:morison", "--input", str(src), "--out", str(outs[method]),
                     "--method", method]) == 0
    a, b = runlog.read_run(outs["rk4"]), runlog.read_run(outs["solve_ivp"])
    np.testing.assert_allclose(a.state_matrix()[0], x0)
    np.testing.assert_allclose(a.state_matrix(), b.state_matrix(), atol=1e-6)
