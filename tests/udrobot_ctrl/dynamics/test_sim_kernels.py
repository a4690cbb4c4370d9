"""The compiled (numba) RK4 of udrobot_ctrl.dynamics.sim equals the numpy RK4, open and closed loop, single, batch and
per-vehicle parameters; record_every and divergence reporting."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.equations import equations
from udrobot_ctrl.dynamics.plant import generalized_forces, kinematics, water_relative_terms
from udrobot_ctrl.dynamics.sim import SimResult, as_parameters, simulate, stack_parameters, vehicle_parameters
from udrobot_ctrl.vehicle import load_model

EQ = equations(np.sin, np.cos, np.tan)  # the numpy equations


def _x0(rng, n=None):
    shape = (12,) if n is None else (n, 12)
    x = rng.normal(scale=0.2, size=shape)
    x[..., 6:9] = rng.normal(scale=0.4, size=shape[:-1] + (3,))
    return x


@pytest.mark.parametrize("name", ["pendulum:chin", "cfd:morison"])
def test_open_loop_kernel_equals_numpy_rk4(name):
    p = as_parameters(name)
    rng = np.random.default_rng(0)
    u = rng.uniform(-30, 40, size=(300, 4))  # some commands beyond the limits: clipped
    x0 = _x0(rng)
    fast = simulate(p, x0, 3.0, inputs=u)
    ref = simulate(p, x0, 3.0, inputs=u, method="rk4_numpy")
    assert isinstance(fast, SimResult)
    assert fast.x.shape == ref.x.shape == (301, 12)
    assert fast.u.shape == ref.u.shape and fast.tau.shape == ref.tau.shape
    np.testing.assert_allclose(fast.x, ref.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fast.tau, ref.tau, atol=1e-12)
    np.testing.assert_array_equal(fast.saturated, ref.saturated)
    assert fast.saturated.any()


def test_rk4_converges_to_the_solve_ivp_reference_at_fourth_order():
    rng = np.random.default_rng(1)
    x0 = _x0(rng)
    u = np.array([[20.0, 10.0, -5.0, 8.0]])
    ref = simulate("pendulum:morison", x0, 2.0, inputs=u, dt=0.1, method="solve_ivp")
    err = []
    for dt in (0.01, 0.005, 0.0025):
        fast = simulate("pendulum:morison", x0, 2.0, inputs=u, dt=dt)
        err.append(np.abs(fast.x[:: int(round(0.1 / dt))] - ref.x).max())
    assert err[-1] < 1e-6
    assert np.log2(err[0] / err[1]) > 3.5 and np.log2(err[1] / err[2]) > 3.5


def test_batch_with_per_vehicle_parameters_equals_single_runs():
    v = load_model("pendulum:chin")
    rng = np.random.default_rng(2)
    vs = [v.with_changes(linear_damping=v.linear_damping * a, quadratic_damping=v.quadratic_damping * b,
                         r_g=v.r_g * c) for a, b, c in rng.uniform(0.5, 1.5, size=(20, 3))]
    P = stack_parameters(vs)
    x0 = _x0(rng, 20)
    u = rng.uniform(-20, 30, size=(150, 20, 4))  # per-vehicle inputs
    batch = simulate(P, x0, 1.5, inputs=u)
    assert batch.x.shape == (151, 20, 12) and batch.u.shape == (150, 20, 4)
    for i in (0, 7, 19):
        single = simulate(vs[i], x0[i], 1.5, inputs=u[:, i], method="rk4_numpy")
        np.testing.assert_allclose(batch.x[:, i], single.x, atol=1e-12)
        np.testing.assert_allclose(vehicle_parameters(P, i).M, as_parameters(vs[i]).M)
    shared = simulate(vs, x0, 1.5, inputs=u[:, 0])  # list of models, one shared input sequence
    np.testing.assert_allclose(shared.x[:, 3], simulate(vs[3], x0[3], 1.5, inputs=u[:, 0]).x, atol=1e-12)
    with pytest.raises(ValueError, match="thruster layout"):
        stack_parameters([v, v.with_changes(thrusters=v.thrusters[:2])])


def test_closed_loop_kernel_equals_numpy_and_holds_the_command():
    p = as_parameters("cfd:chin")
    calls = []

    def depth_controller(t, x):
        calls.append(t)
        e = 1.0 - x[..., 2]
        f = np.clip(40.0 * e - 20.0 * x[..., 8], -20, 20)
        return np.stack([np.full_like(f, 5.0), np.full_like(f, 5.0), f, f], axis=-1)

    x0 = np.zeros(12)
    fast = simulate(p, x0, 4.0, controller=depth_controller, control_dt=0.05)
    n_fast = len(calls)
    ref = simulate(p, x0, 4.0, controller=depth_controller, control_dt=0.05, method="rk4_numpy")
    assert n_fast == 80 and len(calls) == 160
    np.testing.assert_allclose(fast.x, ref.x, atol=1e-12)
    np.testing.assert_allclose(fast.u, ref.u, atol=0)
    assert np.all(fast.u[0:5] == fast.u[0])  # zero-order hold over the 5 steps of a control period
    # the same controller on a batch of 3 vehicles
    xb = np.zeros((3, 12))
    xb[:, 2] = [0.0, 0.5, 2.0]
    batch = simulate(p, xb, 4.0, controller=depth_controller, control_dt=0.05)
    np.testing.assert_allclose(batch.x[:, 0], fast.x, atol=1e-12)
    assert batch.x[-1, :, 2] == pytest.approx([batch.x[-1, 0, 2]] * 3, abs=0.1)


def test_record_every_keeps_every_kth_state():
    rng = np.random.default_rng(3)
    x0 = _x0(rng, 4)
    full = simulate("free_decay:morison", x0, 1.0, inputs=np.array([[10.0, -5.0, 3.0, 3.0]]))
    sparse = simulate("free_decay:morison", x0, 1.0, inputs=np.array([[10.0, -5.0, 3.0, 3.0]]), record_every=10)
    assert sparse.x.shape == (11, 4, 12) and sparse.u.shape == (10, 4, 4)
    np.testing.assert_allclose(sparse.x, full.x[::10], atol=0)
    np.testing.assert_allclose(sparse.t, full.t[::10])


def test_divergence_is_reported_with_time_and_vehicle():
    v = load_model("pendulum:chin")
    bad = v.with_changes(linear_damping=-50.0 * np.eye(6))  # energy-injecting damping
    with pytest.raises(FloatingPointError, match=r"diverged at t = .*vehicles \[1\]"):
        simulate([v, bad], np.full((2, 12), 0.1), 200.0, inputs=np.zeros((1, 4)))
    with pytest.raises(ValueError, match="inputs"):
        simulate(v, np.zeros(12), 1.0, inputs=np.zeros((10, 3)))


@pytest.mark.parametrize("name", ["pendulum:chin", "bluerov2-heavy"])
def test_compiled_forces_and_kinematics_equal_the_numpy_equations(name):
    """plant.generalized_forces / kinematics of one vehicle run the compiled twin; a stacked copy of the same vehicle
    takes the numpy path of the equations: both agree to round-off, for a batch and for a single state."""
    p = as_parameters(name)
    rng = np.random.default_rng(3)
    x = _x0(rng, 9)
    x[:, 3:6] = rng.uniform(-1.2, 1.2, size=(9, 3))
    stacked = stack_parameters([p] * 9)
    fast, ref = generalized_forces(x, p), generalized_forces(x, stacked)
    np.testing.assert_allclose(fast, ref, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(generalized_forces(x[4], p), ref[4], rtol=1e-13, atol=1e-12)
    ref_kin = kinematics(x[:, None, :6], x[:, None, 6:])[:, 0]  # 3-D: the numpy path
    np.testing.assert_allclose(kinematics(x[:, :6], x[:, 6:]), ref_kin, rtol=1e-13, atol=1e-13)
    assert np.all(np.abs(ref) > 0) and kinematics(x[0, :6], x[0, 6:]).shape == (6,)


@pytest.mark.parametrize("shape", [(), (25,), (3, 4)])
def test_water_relative_terms_compiled_equal_the_equations(shape):
    """The current's terms C_A(nu) nu + D(nu) nu: a batch of at most one axis runs the compiled twin (added mass as
    the inertia, no restoring force), others the equations; both equal the equations' damping + Coriolis."""
    p = as_parameters("bluerov2-heavy")
    nu = np.random.default_rng(5).normal(scale=0.5, size=(6,) + shape)
    got = water_relative_terms(list(nu), p)
    M_A, D_L, Q = (np.asarray(a, float) for a in (p.M_A, p.D_L, p.Q))
    ref = [a + b for a, b in zip(EQ.damping(D_L, Q, nu), EQ.coriolis(M_A, nu))]
    for g, r in zip(got, ref):
        assert np.shape(g) == shape
        np.testing.assert_allclose(g, r, rtol=1e-13, atol=1e-13)
    assert np.abs(np.asarray(got[0])).max() > 0  # damping acts
