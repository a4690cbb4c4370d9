"""Controller and estimator speed on this machine: linear MPC (OSQP), nonlinear MPC (RTI-SQP, ipopt), EKF, LQR design.

Usage: ``python bench/control.py [--json] [--quick]``. Prints median and p99 per solve / step and, with
``--json``, ends with one JSON line holding ``lmpc_median_ms``, ``lmpc_p99_ms``, ``lmpc_first_move_err_N``,
``nmpc_median_ms``, ``nmpc_p99_ms``, ``ekf_step_us``, ``fault_monitor_median_us`` (plus the tolerance sweep and
the LQR design times). ``--only ekf,faults`` runs a subset (lmpc, nmpc, ekf, faults, lqr).

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

from udrobot_ctrl.control.mpc import LinearMPC, NonlinearMPC, OSQPSettings  # noqa: E402
from udrobot_ctrl.dynamics.sim import simulate  # noqa: E402
from udrobot_ctrl.vehicle import load_model  # noqa: E402

MODEL = "cfd:morison"
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


def lmpc_run(v, mission, x0, t_final, settings, with_exact=True):
    """Fly the mission with a LinearMPC; returns (controller, first-move errors)."""
    ctrl = LinearMPC(v, mission, dt=0.05, horizon=20, settings=settings)
    exact = LinearMPC(v, mission, dt=0.05, horizon=20, settings=EXACT) if with_exact else None
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
    print("Linear MPC (OSQP, sparse, re-linearised every call, warm-started), horizon 20:")
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
    med, p99, mx = _stats(ctrl.call_times, 1e3)
    smed, sp99, _ = _stats(ctrl.solve_times, 1e3)
    d = OSQPSettings()
    default = next(r for r in sweep if r["eps"] == d.eps_abs and r["polishing"] == d.polishing)
    print(f"  default {OSQPSettings()}:")
    print(f"    per call median {med:.3f} ms, p99 {p99:.3f} ms, max {mx:.3f} ms "
          f"(OSQP solve alone: median {smed:.3f} ms, p99 {sp99:.3f} ms)")
    print(f"    first move error max {default['err_max_N']:.2e} N; fallbacks {ctrl.stats['fallbacks']}")
    return {"lmpc_median_ms": med, "lmpc_p99_ms": p99, "lmpc_first_move_err_N": default["err_max_N"],
            "lmpc_osqp_solve_median_ms": smed, "lmpc_tolerance_sweep": sweep}


def bench_nmpc(v, mission, x0, t_final, n_ipopt):
    print("Nonlinear MPC, horizon 20, multiple shooting:")
    ctrl = NonlinearMPC(v, mission, dt=0.05, horizon=20)
    simulate(v, x0, t_final, controller=ctrl, dt=0.01, control_dt=0.05)
    med, p99, mx = _stats(ctrl.call_times, 1e3)
    print(f"  RTI-SQP (1 Gauss-Newton QP/call, compiled Jacobians, OSQP): median {med:.3f} ms, p99 {p99:.3f} ms, "
          f"max {mx:.3f} ms, fallbacks {ctrl.stats['fallbacks']}")
    ipo = NonlinearMPC(v, mission, dt=0.05, horizon=20, method="ipopt")
    simulate(v, x0, n_ipopt * 0.05, controller=ipo, dt=0.01, control_dt=0.05)
    imed, ip99, _ = _stats(ipo.call_times, 1e3)
    print(f"  ipopt (reference, warm-started, {n_ipopt} calls): median {imed:.1f} ms, p99 {ip99:.1f} ms, "
          f"fallbacks {ipo.stats['fallbacks']}")
    return {"nmpc_median_ms": med, "nmpc_p99_ms": p99, "nmpc_ipopt_median_ms": imed, "nmpc_ipopt_p99_ms": ip99}


def bench_ekf(v, n=1200):
    from udrobot_ctrl.control.ekf import UDrobotEKF
    from udrobot_ctrl.control.sensors import SensorConfig, measure

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
    print(f"EKF (filterpy predict, gated Joseph update, compiled casadi RK4 + Jacobian, 7-13 channels/step): "
          f"predict+update median {med:.1f} us, p99 {p99:.1f} us")
    return {"ekf_step_us": med, "ekf_step_p99_us": p99}


def bench_faults(v, t_final=12.0):
    """Fault monitor (frozen-sensor test + thruster GLR windows) per control step, healthy closed loop."""
    from udrobot_ctrl.control.ekf import UDrobotEKF
    from udrobot_ctrl.control.faults import EstimatorLoop
    from udrobot_ctrl.control.missions import standard_mission

    m = standard_mission(quick=True)
    ekf = UDrobotEKF(v, 0.05, x0=m.x0())
    loop = EstimatorLoop(LinearMPC(v, m, dt=0.05, horizon=20), ekf, seed=0)
    times = []
    step = loop.monitor.step

    def timed(*a, **k):
        t0 = time.perf_counter()
        out = step(*a, **k)
        times.append(time.perf_counter() - t0)
        return out

    loop.monitor.step = timed
    simulate(v, m.x0(), t_final, controller=loop, dt=0.01, control_dt=0.05)
    med, p99, mx = _stats(times, 1e6)
    print(f"Fault monitor (frozen test + thruster GLR, 1 s windows every 0.25 s): median {med:.0f} us, "
          f"p99 {p99:.0f} us, max {mx:.0f} us per control step; events {len(loop.report().events)}")
    return {"fault_monitor_median_us": med, "fault_monitor_p99_us": p99}


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
    ap.add_argument("--only", default="lmpc,nmpc,ekf,faults,lqr", help="comma-separated subset to run")
    args = ap.parse_args(argv)
    only = set(args.only.split(","))
    v = load_model(MODEL)
    mission, x0, t_final = _mission(args.quick)
    out = {}
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
    print("Goals: LMPC median <= 0.5 ms, p99 <= 2 ms, first move <= 0.1 N; NMPC median <= 10 ms, p99 <= 30 ms; "
          "EKF <= 150 us.")
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
