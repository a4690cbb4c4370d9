"""Demo speed: wall and CPU time of each step of ``udrobot-ctrl demo`` (quick missions, as the README runs it).

Usage: ``python bench/demo.py [--out DIR] [--workers N] [--json]``. Runs the demo's steps in order, in this
process (the controller step starts its own worker processes), into a temporary folder unless ``--out`` is
given, and prints per step: wall time, CPU time of this process and CPU time of finished child processes.
The machine may be shared: wall time depends on the load, CPU time (user + system) much less, so both are
printed. The CPU time of the pool's workers is counted once they have exited (``RUSAGE_CHILDREN``).
With ``--json`` ends with one JSON line ``{step: {"wall_s", "cpu_s", "children_cpu_s"}, "total": ...}``.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

os.environ.setdefault("MPLBACKEND", "Agg")

from udrobot_ctrl.cli import demo  # noqa: E402


def _cpu():
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="output folder (default: a temporary folder, removed afterwards)")
    ap.add_argument("--workers", type=int, default=None, help="controller-step processes (default: the demo's)")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    args = ap.parse_args(argv)
    figures = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        (out / "models").mkdir(parents=True, exist_ok=True)
        print(f"{'step':<16} {'wall s':>8} {'CPU s':>8} {'children CPU s':>15}", flush=True)
        for name, fn in demo.STEPS:
            w0, (c0, k0) = time.perf_counter(), _cpu()
            with open(os.devnull, "w") as devnull:
                stdout, sys.stdout = sys.stdout, devnull
                try:
                    if name == "controllers" and args.workers is not None:
                        fn(out, workers=args.workers)
                    else:
                        fn(out)
                finally:
                    sys.stdout = stdout
            w1, (c1, k1) = time.perf_counter(), _cpu()
            figures[name] = {"wall_s": w1 - w0, "cpu_s": c1 - c0, "children_cpu_s": k1 - k0}
            print(f"{name:<16} {w1 - w0:8.1f} {c1 - c0:8.1f} {k1 - k0:15.1f}", flush=True)
    total = {k: sum(f[k] for f in figures.values()) for k in ("wall_s", "cpu_s", "children_cpu_s")}
    figures["total"] = total
    print(f"{'total':<16} {total['wall_s']:8.1f} {total['cpu_s']:8.1f} {total['children_cpu_s']:15.1f}")
    print(f"on {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the end (shared machine: "
          "compare CPU times, not only wall times)")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
