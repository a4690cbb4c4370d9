"""Speed of udrobot_ctrl.dynamics.sim.simulate (numba RK4): one vehicle 60 s open and closed loop, 1000 vehicles x 60 s.

Usage: ``python bench/sim_numba.py [--json] [--vehicles N]``. Prints figures; with ``--json`` ends with one JSON
line (sim_60s_single_ms, closed_loop_60s_single_ms, batch_1000x60s_s, batch_1000x60s_full_record_s,
kernel_load_s, peak_mem_mb). Figures depend on the machine load (2 shared cores); nothing is asserted.
The first ever run compiles the kernels (~5-10 s) and caches them in udrobot_ctrl/__pycache__;
``kernel_load_s`` is the start-up cost of a later process (import numba + load the cache).
"""
from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np

DT, T_FINAL = 0.01, 60.0


def _best(fn, repeats=5):
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--model", default="pendulum:chin")
    ap.add_argument("--vehicles", type=int, default=1000)
    args = ap.parse_args(argv)

    from udrobot_ctrl.dynamics.sim import as_parameters, simulate, stack_parameters
    from udrobot_ctrl.vehicle import load_model

    fig = {"model": args.model, "dt_s": DT, "t_final_s": T_FINAL}
    p = as_parameters(args.model)
    n = int(round(T_FINAL / DT))
    t = np.arange(n) * DT
    u = np.column_stack([15 + 5 * np.sin(0.3 * t), 12 + 5 * np.cos(0.2 * t), 3 * np.sin(0.5 * t), 2.0 + 0 * t])
    x0 = np.zeros(12)
    x0[3] = 0.1

    t0 = time.perf_counter()
    simulate(p, x0, 0.05, inputs=u[:5])
    simulate(p, x0, 0.05, controller=lambda tt, x: u[0])
    simulate(stack_parameters([p] * 16), np.zeros((16, 12)), 0.05, inputs=u[:5])
    fig["kernel_load_s"] = time.perf_counter() - t0

    fig["sim_60s_single_ms"] = _best(lambda: simulate(p, x0, T_FINAL, inputs=u, dt=DT)) * 1e3
    fig["realtime_factor_single"] = T_FINAL / (fig["sim_60s_single_ms"] / 1e3)

    def ctrl(tt, x):  # a cheap P controller: the figure is dominated by the per-step Python overhead
        return np.array([10.0 - 5 * x[6], 10.0 + 5 * x[6], -20 * x[3], 20 * x[3]])

    fig["closed_loop_60s_single_ms"] = _best(lambda: simulate(p, x0, T_FINAL, controller=ctrl, dt=DT), 3) * 1e3
    fig["closed_loop_60s_control_dt_0.05_ms"] = _best(
        lambda: simulate(p, x0, T_FINAL, controller=ctrl, dt=DT, control_dt=0.05), 3) * 1e3
    t0 = time.perf_counter()
    simulate(p, x0, 5.0, inputs=u, dt=DT, method="rk4_numpy")
    fig["numpy_rk4_60s_s_extrapolated"] = (time.perf_counter() - t0) * T_FINAL / 5.0

    v = load_model(args.model)
    rng = np.random.default_rng(0)
    vs = [v.with_changes(linear_damping=v.linear_damping * a, quadratic_damping=v.quadratic_damping * b)
          for a, b in rng.uniform(0.7, 1.3, (args.vehicles, 2))]
    P = stack_parameters(vs)
    xb = np.zeros((args.vehicles, 12))
    xb[:, 3] = 0.1
    t0 = time.perf_counter()
    r = simulate(P, xb, T_FINAL, inputs=u, dt=DT, record_every=10)
    fig["batch_1000x60s_s"] = time.perf_counter() - t0
    fig["batch_record_every"] = 10
    del r
    t0 = time.perf_counter()
    r = simulate(P, xb, T_FINAL, inputs=u, dt=DT)
    fig["batch_1000x60s_full_record_s"] = time.perf_counter() - t0
    fig["batch_full_record_x_mb"] = r.x.nbytes / 2 ** 20
    del r
    fig["vehicles"] = args.vehicles
    fig["peak_mem_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0

    for k, val in fig.items():
        print(f"{k:38s} {val:.4g}" if isinstance(val, float) else f"{k:38s} {val}")
    if args.json:
        print(json.dumps({k: (round(val, 4) if isinstance(val, float) else val) for k, val in fig.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
