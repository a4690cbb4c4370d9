"""The dense (condensed, active-set) backend of LinearMPC against OSQP on the same QP (issue 38).

Same solution: at every call of a closed-loop flight the dense backend's first move equals a tight-tolerance
OSQP solve of the same QP (same linearisation point) within 0.02 N, on the UDrobot and on bluerov2-heavy; the
closed-loop IAE of the two backends (OSQP at its default tolerances) agrees within 1 %. No timing is asserted.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from udrobot_ctrl.control.fastpath import CondensedMPCQP
from udrobot_ctrl.control.missions import standard_mission
from udrobot_ctrl.control.mpc import LinearMPC, OSQPSettings, SparseMPCQP
from udrobot_ctrl.dynamics.plant import wrap_angle
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.vehicle import load_model

EXACT = OSQPSettings(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000)
MODELS = ["cfd:morison", "bluerov2-heavy"]


def _exact_first_move(exact: LinearMPC, t, x, op):
    """First move of a tight OSQP solve of the QP the controller saw (linearised at the same command)."""
    exact.last_command = op
    exact.build_qp(t, x)
    status, z, _ = exact.qp.solve()
    assert status == "solved"
    return np.clip(exact.qp.split(z)[1][0], exact.f_min, exact.f_max)


@pytest.mark.parametrize("model", MODELS)
def test_dense_first_move_equals_tight_osqp_along_a_flight(model):
    v = load_model(model)
    mission = standard_mission(quick=True)
    ctrl = LinearMPC(v, mission, dt=0.05, horizon=20)
    exact = LinearMPC(v, mission, dt=0.05, horizon=20, solver="osqp", settings=EXACT)
    errs = []

    def loop(t, x):
        op = ctrl.last_command
        f = ctrl(t, x)
        errs.append(np.max(np.abs(f - _exact_first_move(exact, t, x, op))))
        return f

    simulate(v, mission.x0(), 12.0, controller=loop, dt=0.01, control_dt=0.05)
    assert ctrl.stats["fast_fallbacks"] == 0 and ctrl.stats["fallbacks"] == 0
    assert len(errs) == 240 and max(errs) < 0.02, max(errs)


def _iae(res, mission):
    """Integrated absolute error (m s, rad s, m/s s) of depth, heading and surge."""
    dt = np.diff(res.t)
    out = {}
    for ch, i in (("z", 2), ("psi", 5), ("u", 6)):
        ref = np.array([mission.value(ch, t) for t in res.t])
        e = res.x[:, i] - ref
        if ch == "psi":
            e = wrap_angle(e)
        out[ch] = float(np.sum(np.abs(e[:-1]) * dt))
    return out


@pytest.mark.parametrize("model", MODELS)
def test_dense_closed_loop_iae_matches_osqp(model):
    v = load_model(model)
    mission = standard_mission(quick=True)
    iae = {}
    for solver in ("dense", "osqp"):
        ctrl = LinearMPC(v, mission, dt=0.05, horizon=20, solver=solver)
        res = simulate(v, mission.x0(), mission.t_final, controller=ctrl, dt=0.01, control_dt=0.05)
        assert ctrl.stats["fallbacks"] == 0
        iae[solver] = _iae(res, mission)
    for ch in ("z", "psi", "u"):
        assert iae["dense"][ch] == pytest.approx(iae["osqp"][ch], rel=0.01), (ch, iae)


def test_state_bounds_use_general_constraints_and_match_osqp():
    """A depth ceiling that binds along the horizon (general constraints: DAQP) gives OSQP's first move."""
    v = load_model("cfd:morison")
    kw = {"horizon": 20, "state_bounds": {"z": (0.0, 1.05)}}
    ctrl = LinearMPC(v, {"z": 1.5}, **kw)
    exact = LinearMPC(v, {"z": 1.5}, solver="osqp", settings=EXACT, **kw)
    x = np.zeros(12)
    for k, z in enumerate((0.6, 0.8, 0.95, 1.0)):
        x[2] = z
        op = ctrl.last_command
        f = ctrl(0.05 * k, x)
        assert ctrl.last_status == "solved" and ctrl.stats["fast_fallbacks"] == 0
        np.testing.assert_allclose(f, _exact_first_move(exact, 0.05 * k, x, op), atol=0.02)
    X = ctrl.dense._Xf  # the ceiling is active: the plan stops at it
    assert np.any(ctrl.dense._ab_hi < 0.2) and np.all(np.isfinite(X))


def test_a_failed_fast_solve_falls_back_to_osqp_and_is_counted(monkeypatch):
    v = load_model("cfd:morison")
    ctrl = LinearMPC(v, {"z": 1.0, "psi": 0.3}, horizon=20)
    ref = LinearMPC(v, {"z": 1.0, "psi": 0.3}, horizon=20, solver="osqp")
    x = np.zeros(12)
    x[2] = 0.4
    monkeypatch.setattr(ctrl.dense, "max_iter", 0)  # the active-set solve reports failure
    f = ctrl(0.0, x)
    assert ctrl.stats["fast_fallbacks"] == 1 and ctrl.stats["fallbacks"] == 0
    assert "OSQP fallback" in ctrl.last_status and "active set failed" in ctrl.stats["fast_failure"]
    np.testing.assert_allclose(f, ref(0.0, x), atol=1e-9)  # the same OSQP solve as the reference backend
    monkeypatch.setattr(ctrl.dense, "max_iter", 80)
    ctrl(0.05, x)
    assert ctrl.last_status == "solved" and ctrl.stats["fast_fallbacks"] == 1


def test_stuck_thruster_is_held_by_the_dense_backend():
    v = load_model("cfd:morison")
    ctrl = LinearMPC(v, {"z": 2.0}, horizon=10)
    x = np.zeros(12)
    x[2] = 0.5
    ctrl.set_thruster_limits(2, 5.0, 5.0)
    f = ctrl(0.0, x)
    assert ctrl.last_status == "solved" and f[2] == 5.0 and f[3] > 5.0


def test_condensed_qp_rejects_bad_data_and_unknown_solver():
    qp = CondensedMPCQP(2, 1, 3, np.eye(2), 10 * np.eye(2), np.eye(1), np.array([-1.0]), np.array([1.0]))
    ABc = np.array([[1.0, 0.1, 0.0, 0.0], [0.0, 1.0, 0.1, np.nan]])
    with pytest.raises(FloatingPointError):
        qp.update(ABc, np.zeros(2), np.zeros((4, 2)), np.zeros((3, 1)))
    assert qp.solve().U is None
    with pytest.raises(ValueError, match="solver"), warnings.catch_warnings():
        LinearMPC(load_model("cfd:morison"), {"z": 1.0}, solver="qpoases")


def test_condensed_qp_equals_the_sparse_qp_for_general_weights():
    """Non-diagonal Q and R, a terminal weight that is not a multiple of Q, active and inactive bounds: the
    condensed active-set solution is the sparse QP's (tight OSQP)."""
    rng = np.random.default_rng(5)
    nx, nu, N = 4, 2, 6
    A = np.eye(nx) + 0.1 * rng.normal(size=(nx, nx))
    B, c = rng.normal(size=(nx, nu)), 0.1 * rng.normal(size=nx)
    L = rng.normal(size=(nx, nx))
    Q = L @ L.T / nx
    QN = Q + np.diag(rng.uniform(0.5, 2.0, nx))
    R = np.array([[1.0, 0.3], [0.3, 0.5]])
    lo, hi = np.array([-1.0, -0.5]), np.array([1.0, 0.8])
    x0, xr, ur = rng.normal(size=nx) * 3, rng.normal(size=(N + 1, nx)), rng.normal(size=(N, nu)) * 0.2
    dense = CondensedMPCQP(nx, nu, N, Q, QN, R, lo, hi)
    dense.update(np.column_stack([A, B, c]), x0, xr, ur)
    sol = dense.solve()
    sparse = SparseMPCQP(nx, nu, N, Q, QN, R, lo, hi, settings=EXACT)
    sparse.update(A, B, c, x0, xr, ur)
    status, z, _ = sparse.solve()
    assert sol.status == "solved" and status == "solved"
    U = sparse.split(z)[1]
    assert np.any(np.isclose(U, hi) | np.isclose(U, lo)) and not np.all(np.isclose(U, hi) | np.isclose(U, lo))
    np.testing.assert_allclose(sol.U, U, atol=1e-6)
