"""``design ardusub``'s speed: the wall time of one design of one model (all four loops, the default search).

For each model: one short warm-up flight first (numba's compiled kernels and the imports are a once-per-process
cost, printed apart), then :func:`udrobot_ctrl.autopilot.design.design_ardusub` timed with ``time.perf_counter``
(wall) and ``getrusage`` (CPU of this process and of its forked workers). Printed per model: wall and CPU
seconds, the verdict, how many specification failures, and the gains left at
the end of ArduSub's documented range. The issue's target is 20 s of wall time on 2 cores.

Usage: ``python bench/design.py [--models bluerov2-heavy,bluerov2,pendulum:chin] [--evaluations N] [--json]``.
"""
from __future__ import annotations

import argparse
import json
import resource
import time

from udrobot_ctrl.ardusub.params import ArduSubParameters
from udrobot_ctrl.autopilot.design import design_ardusub, step_flight, vehicle_frame
from udrobot_ctrl.vehicle import load_model


def _cpu() -> float:
    """CPU seconds of this process and of its finished (waited-for) children: the design's forked workers."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="bluerov2-heavy,bluerov2,pendulum:chin")
    ap.add_argument("--evaluations", type=int, default=12, help="step flights per loop (the CLI's default)")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    args = ap.parse_args()
    t = time.perf_counter()
    v = load_model("bluerov2-heavy")
    step_flight(v, ArduSubParameters.defaults(100.0), vehicle_frame(v)[0], "yaw", t_final=2.0)
    warm = time.perf_counter() - t
    print(f"warm-up (imports and compiled kernels, once per process): {warm:.1f} s")
    figures = {"warm_up_s": round(warm, 2)}
    for name in args.models.split(","):
        t, c = time.perf_counter(), _cpu()
        d = design_ardusub(name, max_evaluations=args.evaluations)
        wall, cpu = time.perf_counter() - t, _cpu() - c
        code, _ = d.verdict()
        at_end = [n for n in d.notes if n.startswith("at the end of ArduSub's documented range")]
        print(f"{name}: {wall:.1f} s wall, {cpu:.1f} s CPU (with its forked workers), verdict "
              f"{code}, {len(d.failures)} failure(s){'; ' + at_end[0] if at_end else ''}")
        figures[name] = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "verdict": code,
                         "failures": len(d.failures)}
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
