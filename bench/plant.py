"""Plant simulation speed: one vehicle 60 s and 1000 vehicles x 60 s at dt = 0.01 s (RK4).

Usage: ``python bench/plant.py [--json] [--model NAME] [--no-compile]``. Prints figures; with ``--json`` ends
with one JSON line holding sim_60s_single_ms, batch_1000x60s_s and peak_mem_mb. Figures depend on the machine
load (2 shared cores here); nothing is asserted.
"""
from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time

import numpy as np

from udrobot_ctrl.dynamics import fastsim
from udrobot_ctrl.dynamics.plant import plant_parameters, state_derivative
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.vehicle import load_model

DT, T_FINAL = 0.01, 60.0


def _best(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--model", default="pendulum:chin")
    ap.add_argument("--vehicles", type=int, default=1000)
    ap.add_argument("--no-compile", action="store_true", help="casadi virtual machine only (no gcc)")
    ap.add_argument("--cold", action="store_true", help="use an empty compile cache (measures the compile)")
    args = ap.parse_args(argv)
    if args.cold:
        import os

        os.environ["UDROBOT_CACHE"] = tempfile.mkdtemp(prefix="udrobot_fastsim_")
    compile_ = not args.no_compile
    v = load_model(args.model)
    p = plant_parameters(v)
    n = int(round(T_FINAL / DT))
    t = np.arange(n) * DT
    u = np.column_stack([15 + 5 * np.sin(0.3 * t), 12 + 5 * np.cos(0.2 * t), 3 * np.sin(0.5 * t), 2.0 + 0 * t])
    x0 = np.zeros(12)
    x0[3] = 0.1
    fig = {"model": args.model, "dt_s": DT, "t_final_s": T_FINAL}

    t0 = time.perf_counter()
    ro = fastsim.Rollout(p, DT, n, compile=compile_)
    fig["single_build_s"] = time.perf_counter() - t0
    fig["single_compiled"] = ro.compiled
    best, xs = _best(lambda: ro(x0, u))
    fig["sim_60s_single_ms"] = best * 1e3
    vm = fastsim.Rollout(p, DT, n, compile=False)
    fig["single_vm_ms"] = _best(lambda: vm(x0, u))[0] * 1e3

    t0 = time.perf_counter()
    ref = simulate(p, x0, T_FINAL, inputs=u, dt=DT)
    fig["numpy_sim_simulate_s"] = time.perf_counter() - t0
    fig["single_max_abs_diff_vs_numpy"] = float(np.abs(ref.x - xs).max())

    from scipy.integrate import solve_ivp

    def rhs(tt, xx):  # the same inputs as smooth functions of time (a ZOH staircase would force tiny steps)
        f = np.array([15 + 5 * np.sin(0.3 * tt), 12 + 5 * np.cos(0.2 * tt), 3 * np.sin(0.5 * tt), 2.0])
        return state_derivative(xx, np.clip(f, p.f_min, p.f_max) @ p.T.T, p)

    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0, T_FINAL), x0, method="RK45", rtol=1e-6, atol=1e-9)
    fig["solve_ivp_rk45_s"] = time.perf_counter() - t0
    fig["solve_ivp_nfev"] = int(sol.nfev)

    # 1000 vehicles: damping and added mass perturbed +-20 % (uniform), same thrusters and inputs
    rng = np.random.default_rng(0)
    models = [v.with_changes(linear_damping=v.linear_damping * s1, quadratic_damping=v.quadratic_damping * s2,
                             added_mass=v.added_mass * s3)
              for s1, s2, s3 in rng.uniform(0.8, 1.2, size=(args.vehicles, 3))]
    ps = [plant_parameters(m) for m in models]
    pat = fastsim.sparsity_patterns(ps)
    thetas = np.stack([fastsim.pack_parameters(q, pat) for q in ps])
    t0 = time.perf_counter()
    br = fastsim.BatchRollout(p.T, p.f_min, p.f_max, DT, n // 10, 10, len(ps), compile=compile_, patterns=pat)
    fig["batch_build_s"] = time.perf_counter() - t0
    fig["batch_compiled"] = br.compiled
    t0 = time.perf_counter()
    xb = br(x0, u, thetas)
    fig["batch_1000x60s_s"] = time.perf_counter() - t0
    fig["batch_vehicles"] = len(ps)
    fig["batch_max_abs_diff_vs_numpy_vehicle0"] = float(
        np.abs(xb[:, 0] - simulate(ps[0], x0, T_FINAL, inputs=u, dt=DT).x[::10]).max())
    fig["peak_mem_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    for key, val in fig.items():
        print(f"{key:>40}: {val:.4g}" if isinstance(val, float) else f"{key:>40}: {val}")
    print(f"single: {T_FINAL / (fig['sim_60s_single_ms'] / 1e3):.0f}x real time (goal >= 2000x, <= 30 ms); "
          f"batch goal <= 5 s")
    if args.json:
        print(json.dumps({k: fig[k] for k in ("sim_60s_single_ms", "batch_1000x60s_s", "peak_mem_mb")}
                         | {"details": fig}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
