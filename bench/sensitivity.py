"""Bench: a 1,024-sample Sobol study of compare's LQR on the standard quick mission, local processes vs dask.

"1,024-sample" = SALib base sample N = 1024 (Saltelli/Sobol' design, first-order and total indices),
i.e. N (d + 2) closed-loop simulations: with the default 12 coefficients of the cfd:morison space
(3 added masses, 3 C_D, 6 rotational scale factors) that is 14,336 runs of ``compare``'s gain-scheduled LQR
(designed on the nominal model) on the standard quick mission (23 s, RK4 at 0.01 s = 2,300 steps, controller
at 0.05 s, as ``compare``), batched 256 vehicles per task (one compiled call flies the whole mission of every
vehicle, law and RK4: ``udrobot_ctrl.sensitivity.batch``; the metrics of the batch at once).

Also printed: the first evaluation in this process (loading the numba kernels, or compiling them on a fresh
machine, and the nominal LQR design; run with an empty ``NUMBA_CACHE_DIR`` to measure the cold compile) and the
CPU time of the local run (this process and its workers), to compare on a loaded machine.

Wall times are measured for (a) 2 local worker processes (ProcessPoolExecutor) and (b) a
2-worker dask LocalCluster (processes, 1 thread each); the cluster start-up is reported separately and
not included in ``sobol_1024_dask_s``. Both runs use the same design and must give identical tables.

    python bench/sensitivity.py [--N 1024] [--workers 2] [--json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

# ``python bench/sensitivity.py`` puts bench/ first on sys.path, where a sibling script may shadow a
# library (bench/control.py hides python-control): drop it, this script imports only installed packages
_HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [p for p in sys.path if os.path.abspath(p or os.curdir) != _HERE]


def _cpu_s() -> float:
    """CPU time (user + system, s) of this process and of its finished child processes (the pool's workers)."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--N", type=int, default=1024, help="Sobol base sample (power of 2)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--model", default="cfd:morison")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--skip-dask", action="store_true")
    args = ap.parse_args(argv)

    from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator
    from udrobot_ctrl.sensitivity.executor import SweepExecutor
    from udrobot_ctrl.sensitivity.global_ import run_sobol
    from udrobot_ctrl.sensitivity.parameters import default_space

    space = default_space(args.model)
    ev = MissionEvaluator(space, "lqr")
    d = len(space)
    n_runs = args.N * (d + 2)
    print(f"Sobol base N = {args.N}, d = {d} coefficients -> {n_runs} closed-loop runs "
          f"({ev.mission.t_final:g} s mission, dt {ev.sim_dt:g} s, control {ev.control_dt:g} s); "
          f"machine: {os.cpu_count()} CPUs")

    # first call: loads (or, on a fresh machine, compiles) the numba kernels and designs the nominal LQR
    t0, c0 = time.perf_counter(), time.process_time()
    X1 = np.tile(space.nominal, (ev.max_chunk, 1))
    ev(X1[:2])  # warm the design cache (the forked workers inherit it and the loaded kernels)
    warm_s, warm_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    print(f"first evaluation (kernel load or compile, LQR design): {warm_s:.1f} s wall, {warm_cpu_s:.1f} s CPU")
    # single-batch cost, for the per-run figure
    t0, c0 = time.perf_counter(), time.process_time()
    ev(X1)
    per_run_ms = (time.perf_counter() - t0) / len(X1) * 1e3
    per_run_cpu_ms = (time.process_time() - c0) / len(X1) * 1e3
    print(f"one {len(X1)}-vehicle batch (one task): {per_run_ms:.2f} ms per closed-loop run in-process "
          f"({per_run_cpu_ms:.2f} ms CPU)")

    cpu0 = _cpu_s()
    t0 = time.perf_counter()
    with SweepExecutor(workers=args.workers) as ex:
        res_local = run_sobol(ev, space, args.N, executor=ex, seed=1, progress=False)
    local_s = time.perf_counter() - t0
    local_cpu_s = _cpu_s() - cpu0
    print(f"local ProcessPool, {args.workers} workers: {local_s:.1f} s ({res_local.n_runs / local_s:.0f} runs/s; "
          f"{local_cpu_s:.1f} s CPU of this process and its workers, load average {os.getloadavg()[0]:.1f})")

    dask_s = startup_s = None
    same = None
    if not args.skip_dask:
        from distributed import Client, LocalCluster

        t0 = time.perf_counter()
        with LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True, dashboard_address=None) as lc, \
                Client(lc) as client:
            startup_s = time.perf_counter() - t0
            t0 = time.perf_counter()
            res_dask = run_sobol(ev, space, args.N, executor=client, seed=1, progress=False)
            dask_s = time.perf_counter() - t0
        same = all(np.array_equal(res_local.table[m], res_dask.table[m], equal_nan=True) for m in res_local.metrics)
        print(f"dask LocalCluster, {args.workers} workers: {dask_s:.1f} s ({res_dask.n_runs / dask_s:.0f} runs/s; "
              f"cluster start-up {startup_s:.1f} s not included); identical table: {same}")

    for m in ("iae_u", "energy_J", "iae_z", "settling_z_s", "lost_control"):
        idx = res_local.indices[m]
        top = res_local.ranking(m)[:3]
        items = ", ".join(f"{n} ST {idx['ST'][res_local.names.index(n)]:.2f}"
                          f"+-{idx['ST_conf'][res_local.names.index(n)]:.2f}" for n in top)
        print(f"  {m:<15} {items}")
    from SALib.analyze import sobol as sobol_analyze
    from scipy.stats import rankdata

    for m in ("energy_J", "iae_z"):  # the same runs, indices of the ranks (robust to lost-control outliers)
        r = sobol_analyze.analyze(space.salib_problem(), rankdata(res_local.table[m]), calc_second_order=False,
                                  num_resamples=200, seed=1)
        top = np.argsort(-r["ST"])[:3]
        print(f"  {m + ' (ranks)':<15} " + ", ".join(f"{space.names[j]} ST {r['ST'][j]:.2f}+-{r['ST_conf'][j]:.2f}"
                                                     for j in top))
    lost = int(np.nansum(res_local.table["lost_control"]))
    print(f"  runs that lost pitch control (|theta| > 45 deg): {lost} of {res_local.n_runs}")
    figures = {"sobol_1024_local_s": round(local_s, 2), "sobol_1024_local_cpu_s": round(local_cpu_s, 2),
               "first_evaluation_s": round(warm_s, 2), "first_evaluation_cpu_s": round(warm_cpu_s, 2),
               "per_run_cpu_ms_in_process": round(per_run_cpu_ms, 3),
               "sobol_1024_dask_s": None if dask_s is None else round(dask_s, 2),
               "dask_cluster_startup_s": None if startup_s is None else round(startup_s, 2),
               "base_N": args.N, "d": d, "model_runs": n_runs, "workers": args.workers,
               "per_run_ms_in_process": round(per_run_ms, 3), "identical_tables": same,
               "load_average_1min": round(os.getloadavg()[0], 2),
               "definition": "SALib base N (Saltelli/Sobol', first+total order): N*(d+2) model runs"}
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
