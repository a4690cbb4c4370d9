"""``simulate`` replay speed: compiled (numba) interval RK4 vs the per-row Python RK4 it replaced.

    python bench/replay.py [--rows 1000000]

A 100 Hz run with jittered sample times (+-20 %) and random thrusts on cfd:chin, max sub-step 0.01 s
(one or two sub-steps per interval). The Python figure is timed on the first 2000 rows and extrapolated.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from udrobot_ctrl.cli.simulate import replay
from udrobot_ctrl.dynamics.plant import plant_parameters, thrust_to_wrench
from udrobot_ctrl.dynamics.sim import rk4_step
from udrobot_ctrl.vehicle import load_model


def python_replay(p, t, x0, tau, max_step):
    """The per-row Python RK4 that ``simulate`` used before (reference for speed and numbers)."""
    xs = np.empty((len(t), 12))
    x = np.asarray(x0, float).copy()
    xs[0] = x
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        m = max(1, int(np.ceil(h / max_step - 1e-9)))
        for _ in range(m):
            x = rk4_step(p, x, tau[k], h / m)
        xs[k + 1] = x
    return xs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    args = ap.parse_args(argv)
    p = plant_parameters(load_model("cfd:chin"))
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.008, 0.012, args.rows))
    f = np.clip(rng.normal(0, 8, (args.rows, p.T.shape[1])), p.f_min, p.f_max)
    tau = thrust_to_wrench(f, p, clip=True)
    x0 = np.zeros(12)
    replay(p, t[:10], x0, tau[:10])  # compile / load the numba cache
    t0 = time.perf_counter()
    xs = replay(p, t, x0, tau, progress=False)
    wall = time.perf_counter() - t0
    k = 2000
    t1 = time.perf_counter()
    ref = python_replay(p, t[:k], x0, tau[:k], 0.01)
    wall_py = time.perf_counter() - t1
    err = float(np.max(np.abs(xs[:k] - ref)))
    print(f"compiled replay: {args.rows} rows in {wall:.2f} s = {args.rows / wall:,.0f} rows/s "
          f"(10 M rows: {1e7 / (args.rows / wall):.0f} s)")
    print(f"python replay:   {k} rows in {wall_py:.2f} s = {k / wall_py:,.0f} rows/s "
          f"(10 M rows: {1e7 / (k / wall_py) / 3600:.1f} h); max |difference| on those rows {err:.2e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
