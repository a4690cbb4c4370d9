"""Physics of the 6-DOF plant: numpy/casadi twins agree, energy, C skew-symmetry, rest, terminal speed, periods."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics import plant_casadi
from udrobot_ctrl.dynamics.plant import coriolis_centripetal, plant_parameters, state_derivative, thrust_to_wrench
from udrobot_ctrl.dynamics.sim import rk4_step, simulate
from udrobot_ctrl.vehicle import MODEL_NAMES, load_model

ZERO6 = np.zeros((6, 6))


def _random_states(rng, n):
    x = rng.normal(size=(n, 12))
    x[:, 3:6] = rng.uniform(-1.2, 1.2, size=(n, 3))  # keep theta away from +-pi/2
    x[:, 6:9] *= 0.8
    x[:, 9:] *= 0.6
    return x


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_numpy_and_casadi_twins_agree(name):
    p = plant_parameters(load_model(name))
    rng = np.random.default_rng(7)
    f_tau = plant_casadi.dynamics_function(p, "tau")
    f_thr = plant_casadi.dynamics_function(p, "thrust")
    xs = _random_states(rng, 20)
    taus = rng.normal(scale=20.0, size=(20, 6))
    fs = rng.uniform(-28.0, 36.0, size=(20, p.T.shape[1]))
    ref = state_derivative(xs, taus, p)
    ref_f = state_derivative(xs, fs @ p.T.T, p)
    for k in range(len(xs)):
        got = np.asarray(f_tau(xs[k], taus[k])).ravel()
        np.testing.assert_allclose(got, ref[k], rtol=1e-9, atol=1e-9)
        got_f = np.asarray(f_thr(xs[k], fs[k])).ravel()
        np.testing.assert_allclose(got_f, ref_f[k], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_coriolis_does_no_work(name):
    p = plant_parameters(load_model(name))
    nu = np.random.default_rng(3).normal(size=(50, 6))
    power = np.einsum("ij,ij->i", nu, coriolis_centripetal(p.M, nu))
    scale = np.einsum("ij,ij->i", nu, nu @ p.M.T) * np.abs(nu).max(axis=1)
    assert np.all(np.abs(power) <= 1e-12 * scale + 1e-14)


def _frictionless(name, **more):
    v = load_model(name)
    kw = dict(linear_damping=ZERO6, quadratic_damping=ZERO6, buoyancy=v.weight,
              r_g=np.zeros(3), r_b=np.zeros(3))
    kw.update(more)
    return v.with_changes(**kw)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_kinetic_energy_conserved_without_damping_or_restoring(name):
    p = plant_parameters(_frictionless(name))
    x = np.zeros(12)
    x[6:] = [0.5, -0.3, 0.2, 0.4, -0.6, 0.7]
    e0 = 0.5 * x[6:] @ p.M @ x[6:]
    tau = np.zeros(6)
    energies = []
    for _ in range(400):  # 2 s at dt = 5 ms
        x = rk4_step(p, x, tau, 0.005)
        energies.append(0.5 * x[6:] @ p.M @ x[6:])
    assert np.max(np.abs(np.array(energies) - e0)) / e0 < 1e-7
    assert np.linalg.norm(x[6:]) > 0.1  # it really moved (energy exchanged between DOFs, not frozen)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_neutral_vehicle_with_coincident_cg_cb_stays_at_rest(name):
    v = load_model(name)
    v = v.with_changes(buoyancy=v.weight, r_b=np.array(v.r_g, float))
    res = simulate(v, np.zeros(12), 5.0, dt=0.05)
    assert np.max(np.abs(res.x)) < 1e-12


def _terminal_speed(K_L, K_Q, F):
    if K_Q == 0:
        return F / K_L
    return (-K_L + np.sqrt(K_L ** 2 + 4 * K_Q * F)) / (2 * K_Q)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_constant_surge_thrust_reaches_terminal_speed(name):
    # free_decay:morison is pitch-unstable above ~0.77 m/s (Munk moment, Z_wdot > X_udot): stay at ~0.5 m/s.
    v = load_model(name)
    v = v.with_changes(buoyancy=v.weight)  # no heave drift feeding the Munk moment
    p = plant_parameters(v)
    K_L, K_Q = p.D_L[0, 0], p.Q[0, 0]
    u_target = 0.5
    F = K_L * u_target + K_Q * u_target ** 2
    res = simulate(v, np.zeros(12), 40.0, dt=0.02, inputs=np.array([[F, 0, 0, 0, 0, 0]]), input_kind="tau")
    # the surge acceleration excites a lightly damped pitch oscillation (m z_g coupling in M_RB): average it out
    tail = res.x[res.t > 30.0]
    assert tail[:, 6].mean() == pytest.approx(_terminal_speed(K_L, K_Q, F), rel=2e-3)
    assert np.ptp(tail[:, 6]) < 5e-3  # steady
    # heave and pitch settle to a small trim (Munk moment); lateral DOFs stay untouched by symmetry
    assert np.max(np.abs(tail[:, [7, 9, 11]])) < 1e-9


def _period_from_zero_crossings(t, y):
    s = np.sign(y)
    idx = np.nonzero(s[:-1] * s[1:] < 0)[0]
    tc = t[idx] - y[idx] * (t[idx + 1] - t[idx]) / (y[idx + 1] - y[idx])  # linear interpolation
    return 2 * np.mean(np.diff(tc))


@pytest.mark.parametrize("name", ["pendulum:chin", "cfd:morison"])
@pytest.mark.parametrize("axis", [3, 4])  # roll phi, pitch theta
def test_small_roll_pitch_oscillation_frequency(name, axis):
    v = load_model(name)
    v = v.with_changes(linear_damping=ZERO6, quadratic_damping=ZERO6, buoyancy=v.weight)
    p = plant_parameters(v)
    k_restoring = v.r_g[2] * v.weight - v.r_b[2] * v.buoyancy  # z_g W - z_b B, N m/rad
    assert k_restoring > 0
    # exact linearisation: phi'' = -(M^-1)_ii k phi (sway/surge coupled through M_RB)
    omega_exact = np.sqrt(k_restoring * p.M_inv[axis, axis])
    # textbook: inertia about CO plus added inertia
    i = axis - 3
    inertia = v.inertia_cg[i, i] + v.mass * v.r_g[2] ** 2 + v.added_mass[axis, axis]
    omega_simple = np.sqrt(k_restoring / inertia)
    x0 = np.zeros(12)
    x0[axis] = np.deg2rad(2.0)
    t_final = 5 * 2 * np.pi / omega_exact
    res = simulate(v, x0, t_final, dt=0.01, input_kind="tau")
    omega_meas = 2 * np.pi / _period_from_zero_crossings(res.t, res.x[:, axis])
    assert omega_meas == pytest.approx(omega_exact, rel=2e-3)
    assert omega_meas == pytest.approx(omega_simple, rel=0.05)
    # amplitude preserved without damping
    assert np.max(np.abs(res.x[len(res.t) // 2:, axis])) == pytest.approx(np.deg2rad(2.0), rel=0.02)


def test_state_derivative_names_a_wrong_shape():
    """Per-thruster thrusts passed as the wrench get a clear error pointing at thrust_to_wrench, not a
    broadcast error; a wrong state length is named too."""
    p = plant_parameters(load_model("pendulum:chin"))
    x = np.zeros(12)
    with pytest.raises(ValueError, match=r"tau has shape \(4,\).*thrust_to_wrench"):
        state_derivative(x, np.ones(4), p)
    with pytest.raises(ValueError, match=r"x has shape \(6,\); expected \(\.\.\., 12\)"):
        state_derivative(np.zeros(6), np.zeros(6), p)
    tau = thrust_to_wrench(np.array([10.0, 10.0, 0.0, 0.0]), p)
    np.testing.assert_allclose(tau, [20.0, 0, 0, 0, 0, 0], atol=1e-12)  # two forward thrusters, symmetric
    xdot = state_derivative(x, tau, p)
    # at rest: surge acceleration X / (m + m_a), raised by ~1 % by the surge-pitch coupling m z_g of M_RB
    assert xdot[6] == pytest.approx(20.0 / p.M[0, 0], rel=0.02)
