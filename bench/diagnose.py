"""Benchmark: ten minutes of 50 Hz logs (three runs of 200 s) diagnosed against every catalogue effect.

The runs come from the test suite's truth generator (tests/udrobot_ctrl/gap/truth.py) with a buoyancy offset
withheld; two runs fit, one is held out. Prints the wall time of the diagnosis (data generation excluded) and,
with --json, ends with one JSON line holding ``diagnose_10min_s``. Goal (issue 38): <= 10 s on the 2-core machine
(the first goal was 30 s). The CPU time of the diagnosis (this process and its reaped workers) is printed too: on
a shared machine compare that.
``--sensors stock`` logs what a stock small ROV has (depth, attitude, gyro, accelerometer; no DVL, no
positioning): the velocities are then reconstructed by the model-based smoother, whose time is printed too, and
once an effect is significant, smoothed again with it and diagnosed a second time (both passes are counted).
The diagnosis spreads its independent work over ``--jobs`` worker processes (default: the cores this process may
use, :mod:`udrobot_ctrl.parallel`); ``--jobs 1`` measures it on one core. ``--report PATH`` writes the diagnosis
report (udrobot-diagnosis/1 JSON, as ``udrobot-ctrl diagnose --json`` does) to compare reports across code changes.
``--length 30min`` or ``--length 2h`` diagnoses longer logs (three runs of a third of it each; issue 63: the cost
must grow linearly with the run's length): the diagnosis's progress lines are then printed as they come, with the
seconds since it started, from "prepared" on. The peak resident memory of this process and of its largest reaped
worker is printed with the times.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "udrobot_ctrl" / "gap"))

from udrobot_ctrl.parallel import JOBS_ENV, default_jobs  # noqa: E402


def cpu_seconds() -> float:
    """CPU time of this process and of its workers that have ended (0 where :mod:`resource` is missing)."""
    try:
        import resource
    except ImportError:
        return 0.0
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


#: --length choices: minutes of logs in all (three runs of a third each)
LENGTHS = {"10min": 10.0, "30min": 30.0, "2h": 120.0}


def peak_memory_mb() -> tuple[float, float]:
    """Peak resident memory (MB) of this process and of its largest reaped worker (nan where :mod:`resource` is
    missing; Linux reports ru_maxrss in KiB)."""
    try:
        import resource
    except ImportError:
        return float("nan"), float("nan")
    return (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--duration", type=float, default=None, help="seconds per run (3 runs; default 200: 10 min)")
    ap.add_argument("--length", choices=tuple(LENGTHS), default=None,
                    help="minutes of logs in all, three runs of a third each (instead of --duration)")
    ap.add_argument("--sensors", default="full", choices=("full", "stock"), help="sensor set of the logs")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default: the cores)")
    ap.add_argument("--report", type=Path, default=None, metavar="PATH", help="write the diagnosis JSON report here")
    args = ap.parse_args(argv)
    if args.length is not None and args.duration is not None:
        ap.error("give --length or --duration, not both")
    duration = LENGTHS[args.length] * 60.0 / 3.0 if args.length else (args.duration or 200.0)
    live = 3 * duration > 600.0 + 1e-9  # longer than the 10 min case: say how far the diagnosis is as it goes
    if args.jobs is not None:
        os.environ[JOBS_ENV] = str(args.jobs)
    from truth import generate

    from udrobot_ctrl.gap.report import diagnose, write_report

    t0 = time.perf_counter()
    runs = generate({"buoyancy_offset": {"dB0": 2.0, "beta": 0.1}}, n_runs=3, duration=duration, rate=50.0,
                    seed=7, sensors=args.sensors)
    t_gen = time.perf_counter() - t0
    minutes = 3 * duration / 60.0
    if live:
        print(f"generated {minutes:.1f} min of 50 Hz logs ({args.sensors} sensors) in {t_gen:.1f} s (not counted); "
              f"diagnosing:", flush=True)
    t0, c0 = time.perf_counter(), cpu_seconds()
    lines = []

    def log(line):
        lines.append(line)
        if live:
            print(f"  [{time.perf_counter() - t0:6.1f} s] {line}", flush=True)

    report, _ = diagnose("pendulum:chin", runs[:2], runs[2:], log=log)
    t_diag, c_diag = time.perf_counter() - t0, cpu_seconds() - c0
    if args.report is not None:
        write_report(report, args.report)
    sig = [e["name"] for e in report["effects"] if e["significant"]]
    own_mb, worker_mb = peak_memory_mb()
    print(f"generated {minutes:.1f} min of 50 Hz logs ({args.sensors} sensors) in {t_gen:.1f} s (not counted)")
    print("  " + lines[0] + (" (includes the smoother)" if args.sensors == "stock" else ""))
    for line in lines:  # stock runs with a significant effect: the second reconstruction pass
        if line.startswith("reconstruction"):
            print("  " + line)
    per = "goal <= 10 s" if abs(minutes - 10.0) < 1e-9 else f"{t_diag / minutes:.2f} s per minute of logs"
    print(f"diagnosis against all {len(report['effects'])} catalogue effects: {t_diag:.1f} s with {default_jobs()} "
          f"worker(s) ({per}), {c_diag:.1f} s of CPU ({c_diag / minutes:.2f} s per minute); significant: "
          f"{', '.join(sig) or 'none'}; unexplained {report['unexplained']:.2f}")
    print(f"peak resident memory: {own_mb:.0f} MB this process, {worker_mb:.0f} MB its largest worker")
    if args.json:
        print(json.dumps({"diagnose_10min_s": round(t_diag, 2), "diagnose_s": round(t_diag, 2),
                          "cpu_s": round(c_diag, 2), "jobs": default_jobs(),
                          "peak_rss_mb": round(own_mb), "peak_worker_rss_mb": round(worker_mb),
                          "minutes": minutes, "sensors": args.sensors,
                          "significant": sig, "unidentifiable": [u["name"] for u in report["unidentifiable"]]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
