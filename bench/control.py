"""Controller and estimator speed on this machine: linear MPC, nonlinear MPC (RTI-SQP, ipopt), EKF, fault
monitor, LQR design.

Usage: ``python bench/control.py [--json] [--quick]``. Prints median and p99 per solve / step and, with
``--json``, ends with one JSON line holding ``lmpc_median_ms``, ``lmpc_p99_ms``, ``lmpc_first_move_err_N``,
``nmpc_median_ms``, ``nmpc_p99_ms``, ``ekf_step_us``, ``fault_monitor_median_us`` (plus the tolerance sweep and
the LQR design times) and ``anchors``: per model (the UDrobot ``cfd:morison`` and ``bluerov2-heavy``) the linear
MPC step, NMPC RTI step, EKF step and fault-monitor step each beside its anchor measured in the same run, and the
ratio.
``--only anchors,ekf,faults`` runs a subset (anchors, lmpc, nmpc, ekf, faults, lqr).

Anchors (issue 38), measured in the same run, in passes alternating with the figure they anchor over the same
recorded states (each runs warm, as in a control loop, and both see the same machine load): the linear MPC's
step against **plain OSQP** on the same QP written in a few lines (:class:`PlainOSQP`: the textbook sparse
formulation, casadi's own call for the linearisation, the constraint values gathered into the fixed CSC pattern
and handed to ``OSQP.update``, warm-started); the EKF's predict + update against **filterpy's**
:class:`~filterpy.kalman.ExtendedKalmanFilter` with the same casadi RK4 Jacobians (no gating).
The NMPC's RTI step (dense backend) is shown against the same RTI on OSQP (the reference backend, the previous
implementation), with the closed-loop IAE of both.
QP-solver anchors (issue 63, :func:`qp_anchors`), on the same QP as the linear MPC's step, over the same recorded
states: **acados** (SQP_RTI, ``FULL_CONDENSING_HPIPM``, ``SPEED_ABS``; :class:`AcadosLMPC`), and the dense condensed
QP on **ProxQP** (proxsuite) and **DAQP** (:class:`CondensedAnchor`). The acados and proxsuite wheels are installed
by the bench itself, once, into private folders (``pip install --no-deps --target``, :func:`private_wheel`; never
the project's environment: the acados wheel vendors its own casadi), and the bench re-executes itself once with
``ACADOS_SOURCE_DIR`` and ``LD_LIBRARY_PATH`` set (:func:`acados_ready`); the generated solver is built in a
temporary folder. An anchor that cannot be reached (no network, no compiler) is skipped with a line saying why.
The fault monitor has no published anchor: its figure is shown against the plain-OSQP step of the same run and
the issue's goal (50 us). Ratios below 1 mean faster than the anchor. No figure is asserted anywhere.

Setup: design and plant ``cfd:morison``, horizon 20 at dt 0.05 s (12 states, 4 thrusts), the standard
mission (quick variant, 23 s = 460 control steps) flown on the nonlinear plant (RK4 at 0.01 s). Times are
wall-clock per controller call (re-linearisation + QP update + solve, the whole cost in the loop).
First-move error: at every call the same QP (same linearisation point) is also solved by a high-accuracy
OSQP (eps 1e-10, polishing, 2e5 iterations); the error is the largest |f_0 - f_0*| over the four thrusts.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

# this file is named control.py: keep its directory off sys.path so ``import control`` finds python-control
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import numpy as np  # noqa: E402
import osqp  # noqa: E402
import scipy.sparse as sp  # noqa: E402
from filterpy.kalman import ExtendedKalmanFilter  # noqa: E402

from udrobot_ctrl.control.ekf import UDrobotEKF, step_jacobian_function  # noqa: E402
from udrobot_ctrl.control.faults import EstimatorLoop  # noqa: E402
from udrobot_ctrl.control.missions import standard_mission  # noqa: E402
from udrobot_ctrl.control.mpc import (  # noqa: E402
    LinearMPC,
    NonlinearMPC,
    OSQPSettings,
    affine_model_function,
    maybe_compiled,
)
from udrobot_ctrl.control.sensors import CHANNEL_STATE, SensorConfig, measure  # noqa: E402
from udrobot_ctrl.dynamics.sim import simulate  # noqa: E402
from udrobot_ctrl.vehicle import load_model  # noqa: E402

MODEL = "cfd:morison"
ANCHOR_MODELS = ("cfd:morison", "bluerov2-heavy")
EXACT = OSQPSettings(eps_abs=1e-10, eps_rel=1e-10, polishing=True, max_iter=200000)


def _mission(quick):
    try:
        from udrobot_ctrl.control.missions import standard_mission

        m = standard_mission(quick=True)
        t_final = 8.0 if quick else m.t_final
        return m, m.x0(), t_final
    except ImportError:  # pragma: no cover - before missions.py existed
        ref = lambda t: {"z": 1.5 if t >= 0.5 else 0.5, "psi": np.pi / 2 if t >= 6 else 0.0,  # noqa: E731
                         "u": 0.5 if 11 <= t < 17 else 0.0}
        x0 = np.zeros(12)
        x0[2] = 0.5
        return ref, x0, 8.0 if quick else 23.0


def _stats(a, scale):
    a = np.asarray(a, float) * scale
    return float(np.median(a)), float(np.percentile(a, 99)), float(np.max(a))


def lmpc_run(v, mission, x0, t_final, settings, with_exact=True, solver="osqp"):
    """Fly the mission with a LinearMPC; returns (controller, first-move errors)."""
    ctrl = LinearMPC(v, mission, dt=0.05, horizon=20, settings=settings, solver=solver)
    exact = LinearMPC(v, mission, dt=0.05, horizon=20, settings=EXACT, solver="osqp") if with_exact else None
    errs = []

    def loop(t, x):
        op = ctrl.last_command
        f = ctrl(t, x)
        if exact is not None:
            exact.last_command = op
            exact.build_qp(t, x)
            status, z, _ = exact.qp.solve()
            if z is not None:
                fe = np.clip(exact.qp.split(z)[1][0], exact.f_min, exact.f_max)
                errs.append(float(np.max(np.abs(f - fe))))
        return f

    simulate(v, x0, t_final, controller=loop, dt=0.01, control_dt=0.05)
    return ctrl, np.array(errs)


def bench_lmpc(v, mission, x0, t_final):
    print("Linear MPC, OSQP backend (sparse, re-linearised every call, warm-started), horizon 20:")
    print(f"  {'eps_abs=eps_rel':>15} {'polish':>6} {'median ms':>10} {'p99 ms':>8} "
          f"{'err med N':>10} {'err p99 N':>10} {'err max N':>10}")
    sweep = []
    for eps in (1e-3, 1e-4, 1e-5):
        for polish in (False, True):
            s = OSQPSettings(eps_abs=eps, eps_rel=eps, polishing=polish)
            ctrl, errs = lmpc_run(v, mission, x0, t_final, s)
            med, p99, _ = _stats(ctrl.call_times, 1e3)
            row = {"eps": eps, "polishing": polish, "median_ms": med, "p99_ms": p99,
                   "err_median_N": float(np.median(errs)), "err_p99_N": float(np.percentile(errs, 99)),
                   "err_max_N": float(errs.max()), "fallbacks": ctrl.stats["fallbacks"]}
            sweep.append(row)
            print(f"  {eps:>15.0e} {polish!s:>6} {med:>10.3f} {p99:>8.3f} {row['err_median_N']:>10.2e} "
                  f"{row['err_p99_N']:>10.2e} {row['err_max_N']:>10.2e}")
    # the default settings, timed without the exact reference solves in the same loop (less cache pollution)
    ctrl, _ = lmpc_run(v, mission, x0, t_final, OSQPSettings(), with_exact=False)
    dense, derr = lmpc_run(v, mission, x0, t_final, OSQPSettings(), solver="dense")
    dmed, dp99, _ = _stats(dense.call_times, 1e3)
    print(f"  dense backend (Riccati active set, warm-started): per call median {dmed:.3f} ms, "
          f"p99 {dp99:.3f} ms; first move error max {derr.max():.2e} N; OSQP fallbacks {dense.stats['fast_fallbacks']}")
    med, p99, mx = _stats(ctrl.call_times, 1e3)
    smed, sp99, _ = _stats(ctrl.solve_times, 1e3)
    d = OSQPSettings()
    default = next(r for r in sweep if r["eps"] == d.eps_abs and r["polishing"] == d.polishing)
    print(f"  default {OSQPSettings()}:")
    print(f"    per call median {med:.3f} ms, p99 {p99:.3f} ms, max {mx:.3f} ms "
          f"(OSQP solve alone: median {smed:.3f} ms, p99 {sp99:.3f} ms)")
    print(f"    first move error max {default['err_max_N']:.2e} N; fallbacks {ctrl.stats['fallbacks']}")
    return {"lmpc_median_ms": dmed, "lmpc_p99_ms": dp99, "lmpc_first_move_err_N": float(derr.max()),
            "lmpc_osqp_median_ms": med, "lmpc_osqp_p99_ms": p99, "lmpc_osqp_first_move_err_N": default["err_max_N"],
            "lmpc_osqp_solve_median_ms": smed, "lmpc_tolerance_sweep": sweep}


def bench_nmpc(v, mission, x0, t_final, n_ipopt):
    print("Nonlinear MPC, horizon 20, multiple shooting:")
    out = {}
    for solver in ("osqp", "dense"):
        ctrl = NonlinearMPC(v, mission, dt=0.05, horizon=20, solver=solver)
        simulate(v, x0, t_final, controller=ctrl, dt=0.01, control_dt=0.05)
        med, p99, mx = _stats(ctrl.call_times, 1e3)
        what = "Riccati active set" if solver == "dense" else "OSQP"
        print(f"  RTI-SQP (1 Gauss-Newton QP/call, compiled QP data, {what}): median {med:.3f} ms, p99 {p99:.3f} ms, "
              f"max {mx:.3f} ms, fallbacks {ctrl.stats['fallbacks']}")
        out[solver] = (med, p99)
    med, p99 = out["dense"]
    ipo = NonlinearMPC(v, mission, dt=0.05, horizon=20, method="ipopt")
    simulate(v, x0, n_ipopt * 0.05, controller=ipo, dt=0.01, control_dt=0.05)
    imed, ip99, _ = _stats(ipo.call_times, 1e3)
    print(f"  ipopt (reference, warm-started, {n_ipopt} calls): median {imed:.1f} ms, p99 {ip99:.1f} ms, "
          f"fallbacks {ipo.stats['fallbacks']}")
    return {"nmpc_median_ms": med, "nmpc_p99_ms": p99, "nmpc_osqp_median_ms": out["osqp"][0],
            "nmpc_ipopt_median_ms": imed, "nmpc_ipopt_p99_ms": ip99}


def bench_ekf(v, n=1200):
    dt = 0.05
    t = np.arange(n) * dt
    f = np.zeros((n, 4))
    f[:, 0], f[:, 1] = 10 + 5 * np.sin(0.5 * t), 8 + 5 * np.cos(0.3 * t)
    f[:, 2] = f[:, 3] = 0.2 + 3 * np.sin(0.4 * t)
    res = simulate(v, np.r_[0, 0, 1.0, np.zeros(9)], (n - 1) * dt, inputs=f[:-1], dt=dt)
    cfg = SensorConfig(seabed_depth=20.0, usbl=True)
    stream = measure(res.t, res.x, cfg, seed=0)
    ekf = UDrobotEKF(v, dt, sensors=cfg, x0=res.x[0])
    ekf.run(stream, f[:-1])
    med, p99, _ = _stats(list(ekf.step_times), 1e6)
    print(f"EKF (compiled RK4 + Jacobian, gated Joseph update, numba kernel, 7-13 channels/step): "
          f"predict+update median {med:.1f} us, p99 {p99:.1f} us")
    return {"ekf_step_us": med, "ekf_step_p99_us": p99}


def _fault_monitor_steps(v, t_final=12.0):
    """(seconds of each fault-monitor step, the loop) over a healthy closed-loop LMPC + EKF mission."""
    m = standard_mission(quick=True)
    loop = EstimatorLoop(LinearMPC(v, m, dt=0.05, horizon=20), UDrobotEKF(v, 0.05, x0=m.x0()), seed=0)
    times = []
    step = loop.monitor.step

    def timed(*a, **k):
        t0 = time.perf_counter()
        out = step(*a, **k)
        times.append(time.perf_counter() - t0)
        return out

    loop.monitor.step = timed
    simulate(v, m.x0(), t_final, controller=loop, dt=0.01, control_dt=0.05)
    return times, loop


def bench_faults(v, t_final=12.0):
    """Fault monitor (frozen-sensor test + thruster GLR windows) per control step, healthy closed loop."""
    times, loop = _fault_monitor_steps(v, t_final)
    med, p99, mx = _stats(times, 1e6)
    print(f"Fault monitor (frozen test + thruster GLR, 1 s windows every 0.25 s): median {med:.0f} us, "
          f"p99 {p99:.0f} us, max {mx:.0f} us per control step; events {len(loop.report().events)}")
    return {"fault_monitor_median_us": med, "fault_monitor_p99_us": p99}


# ----------------------------------------------------------------------------- anchors (issue 38)
class PlainOSQP:
    """The linear MPC's QP on OSQP written plainly: the anchor of the linear MPC step.

    Sparse form over the controller's reduced states, variables ``[x_0 .. x_N, f_0 .. f_{N-1}]``, the same
    weights, references, trim thrusts, thrust limits and linearisation point; per step casadi's own call for
    ``[A | B | c]``, the constraint values in the fixed pattern of full A, B blocks (one gather through the
    triplet -> CSC order found once), ``OSQP.update`` and a solve warm-started from the previous one, at OSQP's
    default settings (eps 1e-3, the fastest plain choice; not accurate to 0.02 N).
    """

    def __init__(self, ctrl: LinearMPC):
        self.ctrl = ctrl
        nx, nu, N = len(ctrl.idx), ctrl.nu, ctrl.N
        self.nx, self.nu, self.N = nx, nu, N
        self.lin = maybe_compiled(affine_model_function(ctrl.params, ctrl.dt, ctrl.idx), ctrl.params, ctrl.dt,
                                  tuple(int(i) for i in ctrl.idx))
        P = sp.block_diag([sp.kron(sp.eye(N), ctrl.Q), ctrl.QN, sp.kron(sp.eye(N), ctrl.R)], format="csc")
        nX = (N + 1) * nx
        k, i, j = np.meshgrid(np.arange(N), np.arange(nx), np.arange(nx), indexing="ij")
        kb, ib, jb = np.meshgrid(np.arange(N), np.arange(nx), np.arange(nu), indexing="ij")
        self.rows = np.concatenate([np.arange(nX), ((k + 1) * nx + i).ravel(), ((kb + 1) * nx + ib).ravel(),
                                    nX + np.arange(N * nu)])
        self.cols = np.concatenate([np.arange(nX), (k * nx + j).ravel(), (nX + kb * nu + jb).ravel(),
                                    nX + np.arange(N * nu)])
        self.lead = np.concatenate([np.ones(nx), -np.ones(N * nx)])
        self.tail = np.ones(N * nu)
        self.shape = (nX + N * nu, nX + N * nu)
        self.lo, self.hi = np.tile(ctrl.f_min, N), np.tile(ctrl.f_max, N)
        order = sp.csc_matrix((np.arange(1.0, self.rows.size + 1), (self.rows, self.cols)), shape=self.shape)
        self.perm = order.data.astype(int) - 1  # CSC position -> triplet
        self.solver = osqp.OSQP()
        A0 = self.matrix(np.eye(nx), np.zeros((nx, nu)))
        self.solver.setup(P, np.zeros(self.shape[1]), A0, np.zeros(self.shape[0]), np.zeros(self.shape[0]),
                          verbose=False)  # OSQP's defaults (eps 1e-3, rho 0.1, no polishing): the plain user's
        self.times: list[float] = []

    def values(self, A, B):
        """Constraint-matrix values in CSC order."""
        return np.concatenate([self.lead, np.tile(A.ravel(), self.N), np.tile(B.ravel(), self.N), self.tail])[self.perm]

    def matrix(self, A, B):
        """The constraint matrix (CSC, explicit zeros kept: the pattern never changes)."""
        data = np.concatenate([self.lead, np.tile(A.ravel(), self.N), np.tile(B.ravel(), self.N), self.tail])
        return sp.csc_matrix((data, (self.rows, self.cols)), shape=self.shape)

    def __call__(self, t, x, f_op):
        t0 = time.perf_counter()
        nx, nu, N, c = self.nx, self.nu, self.N, self.ctrl
        xr, ftrim = c.references(t, x)
        M = self.lin(x, ftrim[0] if f_op is None else f_op).full()
        A, B, cc = M[:, :nx], M[:, nx:nx + nu], M[:, -1]
        x0 = x[c.idx]
        l = np.concatenate([x0, np.tile(-cc, N), self.lo])
        u = np.concatenate([x0, np.tile(-cc, N), self.hi])
        q = np.concatenate([-(xr[:N] @ c.Q).ravel(), -(xr[N] @ c.QN), -(ftrim @ c.R).ravel()])
        self.solver.update(q=q, l=l, u=u, Ax=self.values(A, B))
        res = self.solver.solve()
        f = np.clip(res.x[(N + 1) * nx:(N + 1) * nx + nu], c.f_min, c.f_max)
        self.times.append(time.perf_counter() - t0)
        return f


class _FilterpyPlant(ExtendedKalmanFilter):
    """filterpy's EKF with the RK4 step of the plant as the state prediction (the same casadi Jacobians)."""

    def __init__(self, step, nu):
        super().__init__(dim_x=12, dim_z=13, dim_u=nu)
        self._step = step

    def predict_x(self, u=0):
        xn, F = self._step(self.x, u)
        self.F = F.full()
        self.x = xn.full().ravel()


def _iae(res, mission):
    """Integrated absolute error (m s, rad s, m/s s) of depth, heading and surge (as tests/.../test_mpc_dense.py)."""
    dt = np.diff(res.t)
    out = {}
    for ch, i in (("z", 2), ("psi", 5), ("u", 6)):
        e = res.x[:, i] - np.array([mission.value(ch, t) for t in res.t])
        if ch == "psi":
            e = (e + np.pi) % (2 * np.pi) - np.pi
        out[ch] = float(np.sum(np.abs(e[:-1]) * dt))
    return out


def _ratio_line(label, value, unit, anchor_label, anchor, goal=None):
    goal_txt = f"; goal <= {goal:g} {unit}" if goal is not None else ""
    print(f"    {label:<34} {value:9.1f} {unit} | {anchor_label:<36} {anchor:9.1f} {unit} | ratio {value / anchor:6.3f}"
          f"{goal_txt}")


def bench_anchors(model, quick=False, repeats=3, acados_why="not tried", proxsuite_why="not tried"):
    """Linear MPC, EKF and fault-monitor steps of ``model`` beside their anchors, interleaved in one run
    (``acados_why``, ``proxsuite_why``: why that anchor is skipped, "" when it is reachable: :func:`qp_anchors`)."""
    v = load_model(model)
    m = standard_mission(quick=True)
    t_final = 12.0 if quick else m.t_final
    print(f"  {model} (medians over all steps; figure and anchor in alternating passes over the same steps):")
    # linear MPC: record a closed-loop flight, then replay its states through every candidate
    rec = []
    pilot = LinearMPC(v, m, dt=0.05, horizon=20)

    def record(t, x):
        rec.append((t, np.array(x, float), pilot.last_command))
        return pilot(t, x)

    simulate(v, m.x0(), t_final, controller=record, dt=0.01, control_dt=0.05)
    dense_t, osqp_t, plain_t, errs, fast_fb = [], [], [], [], 0
    for _ in range(repeats):  # passes alternate (each candidate runs warm, as in a loop; all see the same load)
        dense = LinearMPC(v, m, dt=0.05, horizon=20)
        for t, x, op in rec:
            dense.last_command = op
            dense(t, x)
        dense_t += dense.call_times
        fast_fb += dense.stats["fast_fallbacks"]
        plain = PlainOSQP(dense)
        for t, x, op in rec:
            plain(t, x, op)
        plain_t += plain.times
        ours_osqp = LinearMPC(v, m, dt=0.05, horizon=20, solver="osqp")
        for t, x, op in rec:
            ours_osqp.last_command = op
            ours_osqp(t, x)
        osqp_t += ours_osqp.call_times
    dense = LinearMPC(v, m, dt=0.05, horizon=20)  # same solution: first move against a tight OSQP, same QPs
    exact = LinearMPC(v, m, dt=0.05, horizon=20, solver="osqp", settings=EXACT)
    for t, x, op in rec:
        dense.last_command = exact.last_command = op
        f = dense(t, x)
        exact.build_qp(t, x)
        status, z, _ = exact.qp.solve()
        if z is not None:
            errs.append(float(np.max(np.abs(f - np.clip(exact.qp.split(z)[1][0], exact.f_min, exact.f_max)))))
    lmpc, anchor, ours = (float(np.median(a)) * 1e6 for a in (dense_t, plain_t, osqp_t))
    _ratio_line("linear MPC step, dense backend", lmpc, "us", "plain OSQP, same QP", anchor, 100)
    print(f"    {'(OSQP backend of the same class)':<34} {ours:9.1f} us | first move vs tight OSQP: max "
          f"{max(errs):.1e} N over {len(errs)} solves; fast-solve fallbacks {fast_fb}")
    qp = qp_anchors(v, m, rec, repeats, acados_why, proxsuite_why)
    # NMPC RTI: dense backend against the same RTI on OSQP (the previous implementation), alternating passes over
    # the same recorded states (each warm-started from its own shifted solution, as in a loop)
    nmpc_t, nmpc_osqp_t, nmpc_fb = [], [], 0
    for _ in range(repeats):
        for solver, acc in (("dense", nmpc_t), ("osqp", nmpc_osqp_t)):
            nm = NonlinearMPC(v, m, dt=0.05, horizon=20, solver=solver)
            for t, x, _op in rec:
                nm(t, x)
            acc += nm.call_times
            nmpc_fb += nm.stats["fast_fallbacks"]
    nmpc, nmpc_anchor = (float(np.median(a)) * 1e6 for a in (nmpc_t, nmpc_osqp_t))
    iae = {}
    for solver in ("dense", "osqp"):  # closed loop, the whole mission: the same result
        nm = NonlinearMPC(v, m, dt=0.05, horizon=20, solver=solver)
        iae[solver] = _iae(simulate(v, m.x0(), m.t_final, controller=nm, dt=0.01, control_dt=0.05), m)
    iae_diff = max(abs(iae["dense"][ch] / iae["osqp"][ch] - 1.0) for ch in iae["osqp"])
    _ratio_line("NMPC RTI step, dense backend", nmpc, "us", "same RTI on OSQP (reference backend)", nmpc_anchor, 400)
    print(f"    {'':<34} closed-loop IAE (z, psi, u) vs the OSQP backend: max relative difference {iae_diff:.1e}; "
          f"fast-solve fallbacks {nmpc_fb}")
    # EKF: ours and filterpy's on the same stream, step by step
    n = 400 if quick else 1200
    dt = 0.05
    nu = v.n_thrusters
    tt = np.arange(n) * dt
    f = np.zeros((n, nu))
    f[:, 0], f[:, 1] = 10 + 5 * np.sin(0.5 * tt), 8 + 5 * np.cos(0.3 * tt)
    f[:, 2] = f[:, 3] = 0.2 + 3 * np.sin(0.4 * tt)
    res = simulate(v, np.r_[0, 0, 1.0, np.zeros(9)], (n - 1) * dt, inputs=f[:-1], dt=dt)
    cfg = SensorConfig(seabed_depth=20.0, usbl=True)
    stream = measure(res.t, res.x, cfg, seed=0)
    r2 = cfg.sigmas() ** 2
    ekf_t, fp_t = [], []
    for _ in range(2):
        ekf = UDrobotEKF(v, dt, sensors=cfg, x0=res.x[0])
        ekf.update(stream.values[0])
        for k in range(1, n):
            ekf.step(f[k - 1], stream.values[k], t=stream.t[k])
        ekf_t += list(ekf.step_times)
        ref = _FilterpyPlant(step_jacobian_function(ekf.params, dt), nu)
        ref.x, ref.P, ref.Q = res.x[0].copy(), ekf.P0.copy(), ekf.kf.Q.copy()
        for k in range(1, n):
            z = stream.values[k]
            t0 = time.perf_counter()
            ref.predict(u=np.clip(f[k - 1], ekf.params.f_min, ekf.params.f_max))
            ch = np.flatnonzero(np.isfinite(z))
            st = CHANNEL_STATE[ch]
            H = np.zeros((ch.size, 12))
            H[np.arange(ch.size), st] = 1.0
            ref.update(z[ch], HJacobian=lambda _x, H=H: H, Hx=lambda x, st=st: x[st], R=np.diag(r2[ch]))
            fp_t.append(time.perf_counter() - t0)
    e_med, fp_med = float(np.median(ekf_t)) * 1e6, float(np.median(fp_t)) * 1e6
    _ratio_line("EKF predict + update (gated)", e_med, "us", "filterpy EKF, same Jacobians", fp_med, 40)
    # fault monitor, healthy closed loop (figure vs the plain-OSQP step of this run and the goal)
    times, loop = _fault_monitor_steps(v, 12.0)
    mon, mon99 = float(np.median(times)) * 1e6, float(np.percentile(times, 99)) * 1e6
    _ratio_line("fault monitor step", mon, "us", "plain OSQP step (no published anchor)", anchor, 50)
    print(f"    {'':<34} p99 {mon99:.0f} us, mean {np.mean(times) * 1e6:.0f} us (a window is evaluated every 0.25 s); "
          f"events {len(loop.report().events)}")
    return {"lmpc_us": lmpc, "lmpc_anchor_plain_osqp_us": anchor, "lmpc_ratio": lmpc / anchor,
            "lmpc_osqp_backend_us": ours, "lmpc_first_move_err_N": max(errs), "lmpc_fast_fallbacks": fast_fb,
            "ekf_us": e_med, "ekf_anchor_filterpy_us": fp_med, "ekf_ratio": e_med / fp_med,
            "fault_monitor_us": mon, "fault_monitor_p99_us": mon99, "fault_monitor_ratio_to_plain_osqp": mon / anchor,
            "nmpc_us": nmpc, "nmpc_anchor_osqp_rti_us": nmpc_anchor, "nmpc_ratio": nmpc / nmpc_anchor,
            "nmpc_iae_max_rel_diff": iae_diff, "nmpc_fast_fallbacks": nmpc_fb, "qp_anchors": qp}


# ----------------------------------------------------------------------------- QP-solver anchors (issue 63)
#: private folders the bench's anchor wheels are installed into (``pip install --no-deps --target``), never the
#: project's environment: comma-deps-acados vendors its own casadi beside acados, proxsuite installs under cmeel
ANCHOR_ROOT_ENV = "UDROBOT_BENCH_ANCHORS"
ACADOS_WHEEL = "comma-deps-acados"
PROXSUITE_WHEEL = "proxsuite"
_REEXEC_FLAG = "UDROBOT_BENCH_ACADOS_ENV"
#: HPIPM's stopping tolerance (stationarity, equality, inequality, complementarity) of the acados anchor
ACADOS_QP_TOL = 1e-8
#: ProxQP's absolute stopping tolerance: its default (1e-5) left first moves up to 13 N from the exact QP's on this
#: ill-conditioned condensed Hessian (thrust weights ~1/400 against state weights ~100), measured on this bench
PROXQP_EPS_ABS = 1e-9


def _anchor_root() -> Path:
    """The private (0700) folder holding the anchors' --target installs: ``$UDROBOT_BENCH_ANCHORS`` or the user
    cache's ``bench_anchors``."""
    import os

    from udrobot_ctrl.caches import private_dir, user_cache_root

    return private_dir(os.environ.get(ANCHOR_ROOT_ENV) or user_cache_root() / "bench_anchors", "bench_anchors")


def private_wheel(package: str, marker: str) -> tuple[Path | None, str]:
    """``package`` installed by ``pip install --no-deps --target DIR`` into its own folder under
    :func:`_anchor_root` (once; ``marker``, a path inside DIR, says it is there). Returns (DIR, "") or (None, why
    not: pip's last line)."""
    import subprocess

    target = _anchor_root() / package
    if (target / marker).exists():
        return target, ""
    cmd = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), package]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        return None, f"{' '.join(cmd[2:])}: {exc}"
    if done.returncode != 0 or not (target / marker).exists():
        last = (done.stderr or done.stdout).strip().splitlines()
        return None, f"{' '.join(cmd[2:])} failed: {last[-1] if last else f'exit {done.returncode}'}"
    return target, ""


def acados_layout(target: Path) -> tuple[Path, Path]:
    """(ACADOS_SOURCE_DIR, its lib/) for the wheel installed in ``target``: a folder of links, ``lib``, ``include``,
    ``bin`` -> ``target/acados/install/*`` and ``interfaces/acados_template/acados_template`` ->
    ``target/acados/acados_template`` (the layout acados_template expects of a source checkout)."""
    src = target.parent / "acados_source_dir"
    (src / "interfaces" / "acados_template").mkdir(parents=True, exist_ok=True)
    links = {src / k: target / "acados" / "install" / k for k in ("lib", "include", "bin")}
    links[src / "interfaces" / "acados_template" / "acados_template"] = target / "acados" / "acados_template"
    for link, to in links.items():
        if link.is_symlink() and link.resolve() != to.resolve():
            link.unlink()
        if not link.exists():
            link.symlink_to(to, target_is_directory=True)
    return src, src / "lib"


def acados_ready() -> str:
    """Make acados importable in this process, or say why not ("" when ready).

    The wheel goes to its private folder (:func:`private_wheel`); ``DIR/acados`` (not ``DIR``, which holds the
    wheel's vendored casadi: the project's casadi generates the solvers) is put on ``sys.path``. The generated
    solvers link ``lib/libacados.so``, which the dynamic loader finds through ``LD_LIBRARY_PATH`` read at process
    start: when it lacks ``lib`` the bench is re-executed once with ``ACADOS_SOURCE_DIR`` and ``LD_LIBRARY_PATH``
    set (the same command line)."""
    import os

    target, why = private_wheel(ACADOS_WHEEL, "acados/acados_template/__init__.py")
    if target is None:
        return why
    src, lib = acados_layout(target)
    paths = os.environ.get("LD_LIBRARY_PATH", "").split(os.pathsep)
    if str(lib) not in paths:
        if os.environ.get(_REEXEC_FLAG):
            return f"LD_LIBRARY_PATH still lacks {lib} after the re-exec"
        env = dict(os.environ, ACADOS_SOURCE_DIR=str(src), LD_LIBRARY_PATH=os.pathsep.join([str(lib), *filter(None,
                   paths)]), **{_REEXEC_FLAG: "1"})
        sys.stdout.flush()
        os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], env)  # the same command line
    os.environ["ACADOS_SOURCE_DIR"] = str(src)
    if str(target / "acados") not in sys.path:
        sys.path.append(str(target / "acados"))
    try:
        import acados_template  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - any import failure is a skip line, not a crash of the bench
        return f"acados_template does not import: {type(exc).__name__}: {exc}"
    return ""


def proxsuite_ready() -> str:
    """Make proxsuite importable (its wheel in a private folder, :func:`private_wheel`; it installs under
    ``cmeel.prefix/lib/pythonX.Y/site-packages``, which is put on ``sys.path``), or say why not ("" when ready)."""
    site = f"cmeel.prefix/lib/python{sys.version_info.major}.{sys.version_info.minor}/site-packages"
    target, why = private_wheel(PROXSUITE_WHEEL, f"{site}/proxsuite/__init__.py")
    if target is None:
        return why
    if str(target / site) not in sys.path:
        sys.path.append(str(target / site))
    try:
        import proxsuite  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - any import failure is a skip line
        return f"proxsuite does not import: {type(exc).__name__}: {exc}"
    return ""


class AcadosLMPC:
    """The linear MPC's QP as an acados OCP: the anchor the issue names (acados, HPIPM).

    The same QP as :class:`~udrobot_ctrl.control.mpc.LinearMPC`'s step (its reduced states ``ctrl.idx``, 10 of the
    plant's 12 when x, y carry no weight, 4 thrusts, horizon N, the same weights, references and trim thrusts,
    thrust limits as box bounds on the inputs): discrete dynamics ``x+ = A x + B f + c`` with ``[A | B | c]`` the
    stage parameters (the controller's own compiled linearisation at the same operating point), LINEAR_LS cost
    ``|x - x_ref|_Q^2 + |f - f_trim|_R^2`` and ``|x_N - x_ref,N|_QN^2``, SQP_RTI (one Gauss-Newton QP: exact for
    this linear-quadratic problem), FULL_CONDENSING_HPIPM in SPEED_ABS mode. Per step, as a user's loop does it:
    the linearisation, the parameters of every stage, the references, x0, the solve and the first input, all
    through acados's Python interface (``times``), beside acados's own ``time_tot`` (``solver_times``). The
    generated code and its build go to ``build_dir`` (a temporary folder).
    """

    def __init__(self, ctrl: LinearMPC, build_dir: Path, qp_tol: float = ACADOS_QP_TOL):
        import os

        import casadi as ca
        from acados_template import AcadosModel, AcadosOcp, AcadosOcpSolver

        self.ctrl = ctrl
        nx, nu, N = len(ctrl.idx), ctrl.nu, ctrl.N
        self.nx, self.nu, self.N = nx, nu, N
        x, u = ca.SX.sym("x", nx), ca.SX.sym("u", nu)
        p = ca.SX.sym("p", nx * (nx + nu + 1))
        M = ca.reshape(p, nx, nx + nu + 1)  # column-major: [A | B | c] flattened in Fortran order
        model = AcadosModel()
        model.name = "udrobot_lmpc_anchor"
        model.x, model.u, model.p = x, u, p
        model.disc_dyn_expr = M[:, :nx] @ x + M[:, nx:nx + nu] @ u + M[:, nx + nu]
        ocp = AcadosOcp()
        ocp.model = model
        if hasattr(ocp.solver_options, "N_horizon"):
            ocp.solver_options.N_horizon = N
        else:  # pragma: no cover - older acados_template
            ocp.dims.N = N
        ocp.cost.cost_type = ocp.cost.cost_type_e = "LINEAR_LS"
        ocp.cost.W = np.block([[ctrl.Q, np.zeros((nx, nu))], [np.zeros((nu, nx)), ctrl.R]])
        ocp.cost.W_e = np.asarray(ctrl.QN, float)
        ocp.cost.Vx = np.vstack([np.eye(nx), np.zeros((nu, nx))])
        ocp.cost.Vu = np.vstack([np.zeros((nx, nu)), np.eye(nu)])
        ocp.cost.Vx_e = np.eye(nx)
        ocp.cost.yref, ocp.cost.yref_e = np.zeros(nx + nu), np.zeros(nx)
        ocp.constraints.lbu, ocp.constraints.ubu = np.asarray(ctrl.f_min, float), np.asarray(ctrl.f_max, float)
        ocp.constraints.idxbu = np.arange(nu)
        ocp.constraints.x0 = np.zeros(nx)
        ocp.parameter_values = np.zeros(p.shape[0])
        so = ocp.solver_options
        so.tf = float(N)  # steps of 1: acados scales each stage's cost by its time step (the discrete model has none)
        so.integrator_type = "DISCRETE"
        so.nlp_solver_type = "SQP_RTI"
        so.hessian_approx = "GAUSS_NEWTON"
        so.qp_solver = "FULL_CONDENSING_HPIPM"
        so.hpipm_mode = "SPEED_ABS"
        so.qp_tol = qp_tol
        ocp.code_export_directory = str(build_dir / "c_generated_code")
        cwd = os.getcwd()
        os.chdir(build_dir)  # acados_template writes some of its files relative to the working directory
        try:
            self.solver = AcadosOcpSolver(ocp, json_file=str(build_dir / "acados_ocp.json"), verbose=False)
        finally:
            os.chdir(cwd)
        self.yref = np.zeros((N, nx + nu))
        self.times: list[float] = []
        self.solver_times: list[float] = []
        self.status: list[int] = []

    def __call__(self, t, x, f_op):
        t0 = time.perf_counter()
        c, s, N, nx = self.ctrl, self.solver, self.N, self.nx
        xr, ftrim = c.references(t, x)
        pv = c._affine(x, ftrim[0] if f_op is None else f_op).ravel(order="F")
        x0 = x[c.idx]
        s.set(0, "lbx", x0)
        s.set(0, "ubx", x0)
        self.yref[:, :nx], self.yref[:, nx:] = xr[:N], ftrim
        for k in range(N):
            s.set(k, "p", pv)
            s.set(k, "yref", self.yref[k])
        s.set(N, "yref", xr[N])
        self.status.append(s.solve())
        f = np.clip(s.get(0, "u"), c.f_min, c.f_max)
        self.times.append(time.perf_counter() - t0)
        self.solver_times.append(float(np.asarray(s.get_stats("time_tot")).ravel()[0]))
        return f


class CondensedAnchor:
    """The linear MPC's QP condensed to the thrusts (``0.5 U'HU + g'U``, box bounds on U; H and g by the project's
    own condensing kernel, :func:`udrobot_ctrl.control.fastpath._condense`, from the controller's linearisation
    at the same operating point) on a general dense QP solver: ``"proxqp"`` (proxsuite's dense ProxQP with box
    constraints, warm-started from its previous result) or ``"daqp"`` (DAQP with simple bounds, warm-started from
    the previous working set shifted by one stage, as :class:`~udrobot_ctrl.control.fastpath.CondensedMPCQP`
    does with state bounds). ``times``: the whole step (linearisation, references, condensing, solve);
    ``solver_times``: the solve alone."""

    def __init__(self, ctrl: LinearMPC, which: str):
        from udrobot_ctrl.control.fastpath import _condense, _factor

        self.ctrl, self.which = ctrl, which
        nx, nu, N = len(ctrl.idx), ctrl.nu, ctrl.N
        self.n = n = N * nu
        self._condense = _condense
        self._args = dict(Q=np.ascontiguousarray(ctrl.Q, float), QN=np.ascontiguousarray(ctrl.QN, float),
                          R=np.ascontiguousarray(ctrl.R, float))
        self._Lq = _factor(self._args["Q"])
        self.Gm, self.H, self.g = np.zeros((nx, n)), np.zeros((n, n)), np.zeros(n)
        self._Ab, self._e = np.zeros((0, n)), np.zeros(0)
        self._Xf = np.zeros((N + 1, nx))
        self.lo, self.hi = np.tile(ctrl.f_min, N).astype(float), np.tile(ctrl.f_max, N).astype(float)
        self._model = None
        self._sense = np.zeros(n, np.int32)
        self._state = np.zeros(n, np.int8)
        self.times: list[float] = []
        self.solver_times: list[float] = []

    def __call__(self, t, x, f_op):
        t0 = time.perf_counter()
        c, a = self.ctrl, self._args
        xr, ftrim = c.references(t, x)
        M = np.ascontiguousarray(c._affine(x, ftrim[0] if f_op is None else f_op))
        ok = self._condense(M, np.ascontiguousarray(x[c.idx], float), np.ascontiguousarray(xr),
                            np.ascontiguousarray(ftrim), a["Q"], a["QN"], a["R"], self._Lq, np.nan,
                            np.zeros(0, np.int64), self._e, self._e, self.Gm, self.H, self.g, self._Ab, self._e,
                            self._e, self._Xf, 1e12, True)
        if not ok:
            raise FloatingPointError("condensed QP data non-finite")
        t1 = time.perf_counter()
        U = self._proxqp() if self.which == "proxqp" else self._daqp()
        t2 = time.perf_counter()
        f = np.clip(U[:c.nu], c.f_min, c.f_max)
        self.solver_times.append(t2 - t1)
        self.times.append(time.perf_counter() - t0)
        return f

    def _proxqp(self):
        from proxsuite import proxqp

        if self._model is None:
            qp = proxqp.dense.QP(self.n, 0, 0, True)
            qp.settings.initial_guess = proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
            qp.settings.eps_abs, qp.settings.eps_rel = PROXQP_EPS_ABS, 0.0
            qp.init(self.H, self.g, None, None, None, None, None, self.lo, self.hi)
            self._model = qp
        else:
            self._model.update(H=self.H, g=self.g)
        self._model.solve()
        return np.asarray(self._model.results.x)

    def _daqp(self):
        import daqp

        n, nu = self.n, self.ctrl.nu
        st = self._state
        st[:n - nu] = st[nu:].copy()
        self._sense[:] = 0
        self._sense[st > 0], self._sense[st < 0] = 1, 3
        if self._model is None:
            self._model = daqp.Model()
            self._model.setup(self.H, self.g, self._Ab, self.hi, self.lo, self._sense)
        else:
            self._model.update(H=self.H, f=self.g, bupper=self.hi, blower=self.lo, sense=self._sense)
        U, _, flag, info = self._model.solve()
        if flag != 1:
            raise RuntimeError(f"DAQP exit flag {flag}")
        lam = np.asarray(info["lam"])[:n]
        st[:] = np.where(lam > 0, 1, np.where(lam < 0, -1, 0))
        return np.asarray(U)


def qp_anchors(v, m, rec, repeats, acados_why: str, proxsuite_why: str) -> dict:
    """The linear MPC's dense step against acados (HPIPM), ProxQP and DAQP on the same QP, over the recorded
    closed-loop states ``rec`` in alternating passes (each warm, as in a loop). Prints one line per anchor (or why
    it is skipped) and returns the medians (us), the ratios and the largest first-move difference (N) to ours."""
    import shutil
    import tempfile

    out, built = {}, {}
    build = Path(tempfile.mkdtemp(prefix="udrobot_acados_"))  # the generated solver's code and build
    try:
        if not acados_why:
            try:
                built["acados"] = AcadosLMPC(LinearMPC(v, m, dt=0.05, horizon=20), build)
            except Exception as exc:  # noqa: BLE001 - a failed code generation or compile is a skip line
                first = (str(exc).strip().splitlines() or [""])[0][:200]
                acados_why = f"the solver did not build: {type(exc).__name__}: {first}"
        if not proxsuite_why:
            built["proxqp"] = CondensedAnchor(LinearMPC(v, m, dt=0.05, horizon=20), "proxqp")
        built["daqp"] = CondensedAnchor(LinearMPC(v, m, dt=0.05, horizon=20), "daqp")
        ours_t, times, solve, diff = [], {k: [] for k in built}, {k: [] for k in built}, {k: 0.0 for k in built}
        for _ in range(repeats):
            ours = LinearMPC(v, m, dt=0.05, horizon=20)
            firsts = []
            for t, x, op in rec:
                ours.last_command = op
                firsts.append(ours(t, x))
            ours_t += ours.call_times
            for k, a in built.items():
                n0 = len(a.times)
                for (t, x, op), f_ours in zip(rec, firsts):
                    diff[k] = max(diff[k], float(np.max(np.abs(a(t, x, op) - f_ours))))
                times[k] += a.times[n0:]
                solve[k] += a.solver_times[n0:]
        lmpc = float(np.median(ours_t)) * 1e6
        out["lmpc_us"] = lmpc
        labels = {"acados": "acados SQP_RTI, HPIPM full cond.", "proxqp": "ProxQP, dense condensed QP",
                  "daqp": "DAQP, dense condensed QP"}
        for k in ("acados", "proxqp", "daqp"):
            if k not in built:
                why = acados_why if k == "acados" else proxsuite_why
                print(f"    {labels[k]:<36} skipped: {why}")
                out[f"{k}_skipped"] = why
                continue
            med, smed = float(np.median(times[k])) * 1e6, float(np.median(solve[k])) * 1e6
            extra = ""
            if k == "acados":
                bad = sum(s != 0 for s in built[k].status)
                extra = f"; status != 0 in {bad} of {len(built[k].status)} solves"
            print(f"    {'linear MPC step, dense backend':<34} {lmpc:9.1f} us | {labels[k]:<36} {med:9.1f} us | ratio "
                  f"{lmpc / med:6.3f}  (its solve alone {smed:.1f} us, ratio {lmpc / smed:.3f}; first move vs ours "
                  f"max {diff[k]:.1e} N{extra})")
            out.update({f"{k}_us": med, f"{k}_solve_us": smed, f"{k}_ratio": lmpc / med,
                        f"{k}_solve_ratio": lmpc / smed, f"{k}_first_move_diff_N": diff[k]})
    finally:
        shutil.rmtree(build, ignore_errors=True)
    return out


def bench_lqr(v, repeats=50):
    import control

    from udrobot_ctrl.control.mpc import linearization_function
    from udrobot_ctrl.dynamics.plant import plant_parameters

    p = plant_parameters(v)
    x = np.zeros(12)
    x[2] = 1.0
    _, A, B = linearization_function(p, 0.05)(x, np.zeros(4))
    idx = np.arange(2, 12)  # x, y are not stabilisable (pure integrators without a position loop)
    A, B = A.full()[np.ix_(idx, idx)], B.full()[idx]
    Q, R = np.diag([100, 100, 10, 100, 100, 0, 4, 4, 4, 4.0]), np.eye(4) / 400.0
    out = {}
    for method in ("scipy", None):
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            control.dlqr(A, B, Q, R) if method is None else control.dlqr(A, B, Q, R, method=method)
            ts.append(time.perf_counter() - t0)
        out["lqr_design_scipy_ms" if method else "lqr_design_default_ms"] = float(np.median(ts) * 1e3)
    try:
        import slycot  # noqa: F401

        default = "slycot"
    except ImportError:
        default = "scipy (slycot not installed)"
    print(f"LQR design (control.dlqr, 10 states, 4 inputs): method='scipy' {out['lqr_design_scipy_ms']:.3f} ms, "
          f"default [{default}] {out['lqr_design_default_ms']:.3f} ms (median of {repeats})")
    out["lqr_default_method"] = default
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--quick", action="store_true", help="shorter runs (8 s of the mission)")
    ap.add_argument("--only", default="anchors,lmpc,nmpc,ekf,faults,lqr", help="comma-separated subset to run")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    only = set(args.only.split(","))
    acados_why = proxsuite_why = "not run"
    if "anchors" in only:  # before anything is imported or timed: this may re-execute the bench (acados_ready)
        acados_why = acados_ready()
        proxsuite_why = proxsuite_ready()
    v = load_model(MODEL)
    mission, x0, t_final = _mission(args.quick)
    out = {}
    if "anchors" in only:
        print("Per-step figures against anchors measured in the same run (issue 38):")
        out["anchors"] = {name: bench_anchors(name, args.quick, acados_why=acados_why, proxsuite_why=proxsuite_why)
                          for name in ANCHOR_MODELS}
    if "lmpc" in only:
        out.update(bench_lmpc(v, mission, x0, t_final))
    if "nmpc" in only:
        out.update(bench_nmpc(v, mission, x0, t_final, 20 if args.quick else 60))
    if "ekf" in only:
        out.update(bench_ekf(v, 400 if args.quick else 1200))
    if "faults" in only:
        out.update(bench_faults(v, 8.0 if args.quick else 12.0))
    if "lqr" in only:
        out.update(bench_lqr(v))
    print("Goals (issue 38): LMPC step <= 0.1 ms, first move within 0.02 N of tight OSQP; EKF <= 40 us; fault "
          "monitor <= 50 us; NMPC RTI <= 0.4 ms.")
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
