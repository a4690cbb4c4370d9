"""The dense backend (Riccati / condensed active set) of LinearMPC and of NonlinearMPC's RTI against OSQP on the
same QP (issue 38).

Same solution: at every call of a closed-loop flight the dense backend's first move equals a tight-tolerance
OSQP solve of the same QP (same linearisation point) within 0.02 N, on the UDrobot and on bluerov2-heavy; the
closed-loop IAE of the two backends (OSQP at its default tolerances) agrees within 1 %. The Riccati active set
(thrust limits only) equals the condensed one on random problems. No timing is asserted.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from udrobot_ctrl.control.fastpath import CondensedMPCQP, _box_qp, _condense, _factor, _riccati_box_qp
from udrobot_ctrl.control.missions import standard_mission
from udrobot_ctrl.control.mpc import LinearMPC, NonlinearMPC, OSQPSettings, SparseMPCQP
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


@pytest.mark.slow
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


def _random_problem(rng, nx, nu, N):
    A = np.eye(nx) + 0.1 * rng.normal(size=(nx, nx))
    B, c = rng.normal(size=(nx, nu)), 0.1 * rng.normal(size=nx)
    L = rng.normal(size=(nx, nx))
    Q = L @ L.T / nx
    QN = Q + np.diag(rng.uniform(0.5, 2.0, nx))
    Lr = rng.normal(size=(nu, nu))
    R = Lr @ Lr.T / nu + 0.3 * np.eye(nu)
    lo, hi = -rng.uniform(0.2, 1.0, nu), rng.uniform(0.2, 1.0, nu)
    x0, xr, ur = rng.normal(size=nx) * 3, rng.normal(size=(N + 1, nx)), rng.normal(size=(N, nu)) * 0.2
    return np.column_stack([A, B, c]), Q, QN, R, lo, hi, x0, xr, ur


def test_riccati_active_set_equals_the_condensed_active_set():
    """Box constraints: one Riccati recursion per active-set iteration (no condensing) gives the minimiser and the
    working set of the condensed Hessian's active set, active bounds and a fixed input (lo == hi) included."""
    rng = np.random.default_rng(11)
    n_active = 0
    for trial in range(60):
        nx, nu, N = int(rng.integers(2, 8)), int(rng.integers(1, 5)), int(rng.integers(2, 12))
        M, Q, QN, R, lo, hi, x0, xr, ur = _random_problem(rng, nx, nu, N)
        n = N * nu
        LO, HI = np.tile(lo, N), np.tile(hi, N)
        if trial % 5 == 0:
            LO[nu] = HI[nu] = 0.1  # a stuck input at stage 1
        H, g = np.zeros((n, n)), np.zeros(n)
        assert _condense(M, x0, xr, ur, Q, QN, R, _factor(Q), np.nan, np.zeros(0, np.int64), np.zeros(0),
                         np.zeros(0), np.zeros((nx, n)), H, g, np.zeros((0, n)), np.zeros(0), np.zeros(0),
                         np.zeros((N + 1, nx)), 1e20, True)
        s_ref, u_ref = np.zeros(n, np.int8), np.zeros(n)
        it_ref = _box_qp(H, g, LO, HI, s_ref, u_ref, 4 * n)
        state, U, X = np.zeros(n, np.int8), np.zeros(n), np.zeros((N + 1, nx))
        it = _riccati_box_qp(np.ascontiguousarray(M.T[None]), x0, xr, ur, Q, QN, R, LO, HI, state, U, X, 1e20, 4 * n)
        assert (it > 0) == (it_ref > 0), trial
        if it > 0:
            np.testing.assert_allclose(U, u_ref, rtol=0, atol=1e-9)
            assert np.array_equal(state, s_ref)
            n_active += bool(np.any(state != 0))
    assert n_active > 30


def test_per_stage_models_equal_the_sparse_qp():
    """A model per stage (the RTI's Gauss-Newton QP) through ``update``: the sparse QP's minimiser (tight OSQP)."""
    rng = np.random.default_rng(3)
    nx, nu, N = 4, 2, 6
    Q, QN, R = np.diag([1.0, 2.0, 0.5, 1.0]), np.diag([10.0, 20.0, 5.0, 10.0]), np.array([[1.0, 0.3], [0.3, 0.5]])
    lo, hi = np.array([-1.0, -0.5]), np.array([1.0, 0.8])
    for _ in range(5):
        A = np.eye(nx) + 0.1 * rng.normal(size=(N, nx, nx))
        B, c = rng.normal(size=(N, nx, nu)), 0.1 * rng.normal(size=(N, nx))
        x0, xr, ur = rng.normal(size=nx) * 3, rng.normal(size=(N + 1, nx)), rng.normal(size=(N, nu)) * 0.2
        dense = CondensedMPCQP(nx, nu, N, Q, QN, R, lo, hi)
        dense.update(np.concatenate([A, B, c[:, :, None]], axis=2), x0, xr, ur)
        sol = dense.solve()
        sparse = SparseMPCQP(nx, nu, N, Q, QN, R, lo, hi, settings=EXACT)
        sparse.update(A, B, c, x0, xr, ur)
        status, z, _ = sparse.solve()
        assert sol.status == "solved" and status == "solved"
        np.testing.assert_allclose(sol.U, sparse.split(z)[1], atol=1e-6)
        np.testing.assert_allclose(dense.states, sparse.split(z)[0], atol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("model", MODELS)
def test_nmpc_dense_rti_equals_osqp(model):
    """NMPC RTI: every call's Gauss-Newton QP solved by the dense backend has a tight OSQP's first move (0.02 N),
    and the closed-loop IAE of the two backends agrees within 1 %."""
    v = load_model(model)
    mission = standard_mission(quick=True)
    ctrl = NonlinearMPC(v, mission, dt=0.05, horizon=20)
    nx, nu, N = len(ctrl.idx), ctrl.nu, ctrl.N
    exact = SparseMPCQP(nx, nu, N, ctrl.Q, ctrl.QN, ctrl.R, ctrl.f_min, ctrl.f_max, settings=EXACT)
    errs = []

    def loop(t, x):
        f = ctrl(t, x)
        MT, x0, xr, ft = ctrl.dense._data  # this call's QP
        exact.update(MT[:, :nx].transpose(0, 2, 1), MT[:, nx:nx + nu].transpose(0, 2, 1), MT[:, nx + nu], x0, xr, ft)
        status, z, _ = exact.solve()
        assert status == "solved"
        errs.append(np.max(np.abs(f - np.clip(exact.split(z)[1][0], ctrl.f_min, ctrl.f_max))))
        return f

    res = simulate(v, mission.x0(), mission.t_final, controller=loop, dt=0.01, control_dt=0.05)
    assert ctrl.stats["fast_fallbacks"] == 0 and ctrl.stats["fallbacks"] == 0
    assert max(errs) < 0.02, max(errs)
    ref = NonlinearMPC(v, mission, dt=0.05, horizon=20, solver="osqp")
    res_ref = simulate(v, mission.x0(), mission.t_final, controller=ref, dt=0.01, control_dt=0.05)
    iae, iae_ref = _iae(res, mission), _iae(res_ref, mission)
    for ch in ("z", "psi", "u"):
        assert iae[ch] == pytest.approx(iae_ref[ch], rel=0.01), (ch, iae, iae_ref)
