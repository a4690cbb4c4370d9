"""Identification speed: the paper's protocol (72 launches per test) through ``identify_files``.

Usage: ``python bench/identify.py [--json]``. Writes the synthetic protocol (6 launches x 4 amplitudes x
3 axes, 6.5 s spring / 8.5 s pendulum logs at 100 Hz) to a temporary folder, then times the batch
identification (read, validate, output-error fit with HAC intervals, outliers, rank-sum tests,
aggregate, similitude) for the spring and both pendulum forms, and the graphical method. The first
call includes numba's cached compile of the decay simulator (reported separately). With ``--json``
ends with one JSON line holding ``spring_72_s``, ``pendulum_72_s``, ``graphical_72_s``, ``per_launch_ms``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

from identification import synthetic  # noqa: E402
from identification.identify import RigOptions, identify_files  # noqa: E402
from udrobot_ctrl.vehicle import full_size_vehicle  # noqa: E402

UDROBOT = full_size_vehicle()  # its projected areas are the default areas for C_D


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        spring = synthetic.write_protocol(tmp / "s", synthetic.protocol("spring", synthetic.paper_spring_truth()), "s")
        pend = synthetic.write_protocol(tmp / "p", synthetic.protocol("pendulum", synthetic.paper_pendulum_truth()),
                                        "p")
        t0 = time.perf_counter()
        identify_files("spring", spring[:1], RigOptions(vehicle=UDROBOT))
        out["first_call_s"] = time.perf_counter() - t0
        for key, kind, files, opts, fit in (
                ("spring_72_s", "spring", spring, RigOptions(vehicle=UDROBOT), "output-error"),
                ("pendulum_72_s", "pendulum", pend, RigOptions(length=0.30, vehicle=UDROBOT), "output-error"),
                ("graphical_72_s", "spring", spring, RigOptions(vehicle=UDROBOT), "graphical")):
            best = float("inf")
            for _ in range(3):
                t0 = time.perf_counter()
                rep = identify_files(kind, files, opts, fit=fit)
                best = min(best, time.perf_counter() - t0)
            out[key] = best
            print(f"{key:16s} {best:7.3f} s  ({rep['n_ok']} ok, {rep['n_used']} used; {1e3 * best / 72:.1f} ms/launch;"
                  f" {'pendulum fits both Chin and Morison forms' if kind == 'pendulum' else fit})")
        out["per_launch_ms"] = 1e3 * out["spring_72_s"] / 72
    print(f"first call (includes cached numba load/compile) {out['first_call_s']:.2f} s")
    if args.json:
        print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
