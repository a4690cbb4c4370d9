"""Linear and nonlinear MPC on the nonlinear plant: settling, thrust limits, heading wrap, exact QP, fallbacks."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from udrobot_ctrl.control.mpc import LinearMPC, NonlinearMPC, OSQPSettings
from udrobot_ctrl.dynamics.plant import plant_parameters, wrap_angle
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.vehicle import load_model

DESIGN = "cfd:morison"
PLANT = "pendulum:chin"  # fly on a different coefficient set than the design


def _reference(t):
    """Depth step 0 -> 1 m at t = 0, heading 0 -> 90 deg at t = 4 s, hovering."""
    return {"z": 1.0, "psi": np.pi / 2 if t >= 4.0 else 0.0, "u": 0.0}


def _fly(ctrl, t_final=10.0, x0=None, plant=PLANT):
    x0 = np.zeros(12) if x0 is None else x0
    return simulate(plant, x0, t_final, controller=ctrl, dt=0.01, control_dt=ctrl.dt)


def _assert_within_limits(res, p):
    assert np.all(res.u >= p.f_min - 1e-9) and np.all(res.u <= p.f_max + 1e-9)


@pytest.mark.parametrize("kind", ["lmpc", "nmpc"])
def test_mpc_settles_depth_step_and_heading_change(kind):
    v = load_model(DESIGN)
    cls = LinearMPC if kind == "lmpc" else NonlinearMPC
    ctrl = cls(v, _reference, dt=0.05, horizon=20)
    res = _fly(ctrl)
    p = plant_parameters(load_model(PLANT))
    _assert_within_limits(res, p)
    t, x = res.t, res.x
    assert np.any(np.isclose(np.abs(res.u), 36.42) | np.isclose(np.abs(res.u), 28.61)), "step should saturate"
    late_depth = (t > 3.5) & (t < 4.0)
    assert np.all(np.abs(x[late_depth, 2] - 1.0) < 0.02)  # depth settled (2 cm) within 3.5 s
    end = t > 8.5
    assert np.all(np.abs(wrap_angle(x[end, 5] - np.pi / 2)) < 0.02)  # heading settled within 4.5 s
    assert np.all(np.abs(x[end, 2] - 1.0) < 0.02)  # depth held during the turn
    assert np.max(np.abs(x[:, 3])) < 0.2  # roll stays small
    assert ctrl.stats["fallbacks"] == 0 and ctrl.stats["solves"] == 200


def test_asymmetric_limits_are_the_constraints():
    """A large descent asks for forward thrust (limit 36.42 N), a large ascent for reverse (-28.61 N)."""
    v = load_model(DESIGN)
    p = plant_parameters(v)
    for z_ref, bound in ((5.0, p.f_max[2]), (-5.0, p.f_min[2])):
        ctrl = LinearMPC(v, {"z": z_ref}, horizon=10)
        x = np.zeros(12)
        x[2] = 0.0 if z_ref > 0 else 3.0
        f = ctrl(0.0, x)
        assert f[2] == pytest.approx(bound, abs=1e-3) and f[3] == pytest.approx(bound, abs=1e-3)


@pytest.mark.parametrize("cls", [LinearMPC, NonlinearMPC])
def test_heading_wraps_the_short_way(cls):
    v = load_model(DESIGN)
    ctrl = cls(v, {"z": 0.0, "psi": -3.0}, horizon=20)
    x0 = np.zeros(12)
    x0[5] = 3.0  # 3.0 rad -> -3.0 rad is a 0.28 rad turn through +pi
    res = _fly(ctrl, t_final=5.0, x0=x0, plant=DESIGN)
    psi = np.unwrap(res.x[:, 5])
    assert psi.min() > 2.95 and abs(wrap_angle(psi[-1] + 3.0)) < 0.01


def test_linear_mpc_first_move_matches_exact_qp():
    """Default OSQP tolerances give a first move within 0.1 N of a 1e-10 OSQP solve of the same QP."""
    v = load_model(DESIGN)
    fast = LinearMPC(v, _reference, horizon=20, solver="osqp")
    exact = LinearMPC(v, _reference, horizon=20, solver="osqp",
                      settings=OSQPSettings(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000))
    rng = np.random.default_rng(3)
    for i in range(5):
        x = np.zeros(12)
        x[2], x[5], x[6:] = rng.uniform(0, 2), rng.uniform(-1, 3), rng.normal(scale=0.1, size=6)
        fast.last_command = exact.last_command = None  # same linearisation point (trim thrust)
        f = fast(4.0 * (i % 2), x)
        exact.build_qp(4.0 * (i % 2), x)
        status, z, _ = exact.qp.solve()
        assert status == "solved"
        f_exact = np.clip(exact.qp.split(z)[1][0], exact.f_min, exact.f_max)
        assert np.max(np.abs(f - f_exact)) < 0.1


def test_rti_converges_to_ipopt_solution():
    """Iterated to convergence, the RTI-SQP and ipopt solve the same NLP: first moves agree."""
    v = load_model(DESIGN)
    ref = {"z": 1.0, "psi": 0.5, "u": 0.3}
    x = np.zeros(12)
    x[2], x[6] = 0.3, 0.1
    rti = NonlinearMPC(v, ref, horizon=10, sqp_iterations=15,
                       settings=OSQPSettings(eps_abs=1e-8, eps_rel=1e-8, polishing=True))
    ipo = NonlinearMPC(v, ref, horizon=10, method="ipopt")
    f_rti, f_ipopt = rti(0.0, x), ipo(0.0, x)
    assert ipo.last_status == "Solve_Succeeded"
    np.testing.assert_allclose(f_rti, f_ipopt, atol=0.05)


@pytest.mark.parametrize("kind", ["lmpc", "lmpc-osqp", "rti", "ipopt"])
def test_failed_solve_falls_back_without_raising(kind):
    v = load_model(DESIGN)
    p = plant_parameters(v)
    kw = {"horizon": 8}
    if kind.startswith("lmpc"):
        solver = "osqp" if kind == "lmpc-osqp" else "dense"
        make = lambda **k: LinearMPC(v, {"z": 1.0}, solver=solver, **kw, **k)  # noqa: E731
    else:
        make = lambda **k: NonlinearMPC(v, {"z": 1.0}, method=kind, **kw, **k)  # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        # NaN state before any solve: trim thrust (holds against the net buoyancy), no exception
        ctrl = make()
        x = np.zeros(12)
        x[2] = np.nan
        f = ctrl(0.0, x)
        assert np.all(np.isfinite(f)) and np.all(f >= p.f_min) and np.all(f <= p.f_max)
        assert ctrl.stats["fallbacks"] == 1 and ctrl.last_status.startswith("fallback (trim thrust)")
        # after a good solve, a NaN state applies the next move of the previous plan
        good = ctrl(0.0, np.zeros(12))
        assert not ctrl.last_status.startswith("fallback")
        plan = ctrl._plan.copy()
        f = ctrl(0.05, x)
        assert ctrl.last_status.startswith("fallback (shifted previous solution)")
        np.testing.assert_allclose(f, np.clip(plan[1], p.f_min, p.f_max))
        assert np.all(np.isfinite(good))
        # impossible constraint: depth ceiling 0.5 m while the vehicle is at 2 m (x_1 cannot reach it)
        ctrl = make(state_bounds={"z": (0.0, 0.5)})
        x = np.zeros(12)
        x[2] = 2.0
        f = ctrl(0.0, x)
        assert ctrl.last_status.startswith("fallback") and ctrl.stats["fallbacks"] == 1
        assert np.all(f >= p.f_min) and np.all(f <= p.f_max)


def test_bad_reference_is_reported():
    v = load_model(DESIGN)
    with pytest.raises(ValueError, match="not a state"):
        LinearMPC(v, {"depth_m": 1.0})


def _make(kind, reference, **kw):
    v = load_model(DESIGN)
    if kind == "lmpc":
        return LinearMPC(v, reference, **kw)
    if kind == "lmpc-osqp":
        return LinearMPC(v, reference, solver="osqp", **kw)
    return NonlinearMPC(v, reference, method=kind, **kw)


@pytest.mark.parametrize("kind", ["lmpc", "lmpc-osqp", "rti", "ipopt"])
def test_poisoned_states_cost_only_their_own_calls(kind):
    """Issue 16: one 1e44 state (an EKF that swallowed a 300 m depth spike) made every later solve fall back.
    Now the poisoned calls fall back (previous plan) and every sane call before and after solves."""
    ctrl = _make(kind, {"z": 1.0, "psi": 0.3}, horizon=10 if kind == "ipopt" else 20)
    x = np.zeros(12)
    x[2] = 0.8
    poison = {3: 1e44, 4: np.nan, 6: np.inf, 7: -1e44, 9: "all"}  # call index -> poisoned value of z (or all states)
    n_calls = 14 if kind == "ipopt" else 30
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for k in range(n_calls):
            xk = x.copy()
            if k in poison:
                xk[:] = 1e44 if poison[k] == "all" else xk
                xk[2] = 1e44 if poison[k] == "all" else poison[k]
            f = ctrl(0.05 * k, xk)
            assert np.all(np.isfinite(f)) and np.all(f >= ctrl.f_min) and np.all(f <= ctrl.f_max)
            if k in poison:
                assert ctrl.last_status.startswith("fallback (shifted previous solution)")
                assert "z" in ctrl.last_status or "x = " in ctrl.last_status  # names the offending state
            else:
                assert not ctrl.last_status.startswith("fallback"), (k, ctrl.last_status)
    assert ctrl.stats["fallbacks"] == len(poison) and ctrl.stats["solves"] == n_calls


@pytest.mark.parametrize("kind", ["lmpc", "lmpc-osqp", "rti"])
def test_qp_data_is_validated_before_it_reaches_osqp(kind, monkeypatch):
    """Second line of defence: with the plausibility envelope switched off, a 1e44 state makes non-finite or
    1e30-scale QP data, which must be refused before OSQP (which would keep its old data and 'solve' it)."""
    import udrobot_ctrl.control.mpc as mpc

    monkeypatch.setattr(mpc, "STATE_LIMITS", np.full(12, np.inf))
    ctrl = _make(kind, {"z": 1.0}, horizon=20)
    x = np.zeros(12)
    x[2] = 0.8
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        ctrl(0.0, x)
        bad = x.copy()
        bad[8] = 1e44
        ctrl(0.05, bad)
        assert ctrl.last_status.startswith("fallback") and "FloatingPointError" in ctrl.last_status
        for k in range(2, 12):
            ctrl(0.05 * k, x)
            assert not ctrl.last_status.startswith("fallback"), ctrl.last_status
    assert ctrl.stats["fallbacks"] == 1 and ctrl.stats["solver_resets"] == 1


@pytest.mark.parametrize("kind", ["lmpc", "lmpc-osqp", "rti"])
def test_infeasible_solve_then_feasible_state_solves_again(kind):
    """An infeasible QP (depth ceiling 0.5 m, vehicle at 2 m) falls back; the next feasible state solves."""
    ctrl = _make(kind, {"z": 0.3}, horizon=10, state_bounds={"z": (0.0, 0.5)})
    x = np.zeros(12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for k, z in enumerate([0.3, 2.0, 2.0, 0.35, 0.3, 0.3]):
            x[2] = z
            ctrl(0.05 * k, x)
            assert ctrl.last_status.startswith("fallback") == (z > 1.0), (k, ctrl.last_status)
    assert ctrl.stats["fallbacks"] == 2


def test_reset_solver_clears_diverged_iterates():
    """Diverged ADMM iterates (huge primal/dual, rho blown up) are forgotten by reset_solver."""
    ctrl = LinearMPC(load_model(DESIGN), {"z": 1.0}, horizon=20, solver="osqp")
    x = np.zeros(12)
    x[2] = 0.8
    ctrl.build_qp(0.0, x)
    _, z_ref, info_ref = ctrl.qp.solve()
    qp = ctrl.qp
    qp.solver.warm_start(x=np.full(qp.n, 1e25), y=np.full(qp.m, 1e25))
    qp.solver.update_settings(rho=1e6)
    status, _, _ = qp.solve()
    assert status not in ("solved",)  # the poisoned solver does not converge
    qp.reset_solver()
    status, z, info = qp.solve()
    assert status == "solved" and info.iter <= 2 * info_ref.iter + 50
    np.testing.assert_allclose(qp.split(z)[1][0], qp.split(z_ref)[1][0], atol=0.1)


@pytest.mark.parametrize("kind", ["lmpc", "lmpc-osqp", "rti", "ipopt"])
def test_thruster_reconfiguration_after_a_fault(kind):
    """set_thruster_limits(j, a, a): the plan holds thruster j at a (dead: 0 N, stuck: a) and the others take
    over; the depth step still asks both vertical thrusters before, only thruster 3 after thruster 2 died."""
    ctrl = _make(kind, {"z": 2.0}, horizon=10)
    x = np.zeros(12)
    x[2] = 0.5
    f = ctrl(0.0, x)
    assert f[2] > 5.0 and f[3] > 5.0
    ctrl.set_thruster_limits(2, 0.0, 0.0)
    f = ctrl(0.05, x)
    assert not ctrl.last_status.startswith("fallback")
    assert abs(f[2]) < 1e-3 and f[3] > 5.0
    ctrl.set_thruster_limits(0, 7.0, 7.0)  # stuck horizontal thruster
    f = ctrl(0.1, x)
    assert not ctrl.last_status.startswith("fallback") and abs(f[0] - 7.0) < 1e-3
    with pytest.raises(ValueError, match="thruster index"):
        ctrl.set_thruster_limits(4, 0.0, 0.0)
