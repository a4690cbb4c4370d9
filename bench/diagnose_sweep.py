"""The test suite's single-effect diagnosis sweeps, every case (the suite keeps one case per mechanism).

Two sweeps moved here from the suite (issue 63: the long sweeps belong in bench/):

* ``full``: every catalogue effect alone, full sensors, at tests/udrobot_ctrl/gap/test_diagnose.py's settings
  (3 x 90 s at 20 Hz, truth seed 2, magnitudes drawn with seed 102; ``test_diagnose._run``). A case passes as
  ``test_single_effect_named_and_shrinks`` does: the effect (or a look-alike of a significant one) is named, the first
  effect of the report is significant, and its fit removes at least half of the gap (shrink >= 0.5). The suite runs
  ``test_diagnose.SUITE_SINGLE``.
* ``stock``: stock sensors (no DVL), tests/udrobot_ctrl/gap/test_stock_sensors.py's lean runs (3 x 60 s at 20 Hz,
  ``test_stock_sensors._stock``); the expected outcome of each effect is ``STOCK_EXPECTED`` ('named' or
  'unidentifiable', ``test_stock_sensors._outcome``). The suite runs its tether case; the lag and the buoyancy offset
  are named in the suite's stock pair and reconstruction tests.

Usage: ``PYTHONPATH=. python bench/diagnose_sweep.py [--sweep full|stock|both] [--only NAME] [--jobs J] [--json]``.
Prints one line per case (verdict, shrink or outcome, seconds) and the score; with ``--json`` ends with one JSON line.
Nothing here is asserted: the figures are printed.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.udrobot_ctrl.gap import test_diagnose, test_stock_sensors  # noqa: E402
from udrobot_ctrl.parallel import fork_map  # noqa: E402

#: the stock sweep's cases and the outcome the suite's test expected of each (test_stock_effect_named_or_listed)
STOCK_EXPECTED = {"thruster_lag": "named", "buoyancy_offset": "named", "tether_drag": "unidentifiable"}


def full_case(name: str) -> dict:
    """One full-sensor single-effect case: whether it is named, its shrink, what was significant, CPU seconds."""
    t0 = time.process_time()
    report, _ = test_diagnose._run([name])
    named = test_diagnose._verdict_ok(report, name) and report["effects"][0]["significant"]
    shrink = test_diagnose._by_name(report)[name]["shrink"]
    return {"sweep": "full", "effect": name, "named": bool(named), "shrink": float(shrink),
            "passes": bool(named and shrink >= 0.5),
            "significant": [e["name"] for e in report["effects"] if e["significant"]],
            "cpu_s": time.process_time() - t0}


def stock_case(name: str) -> dict:
    """One stock-sensor single-effect case: its outcome against the expected one, CPU seconds."""
    t0 = time.process_time()
    report = test_stock_sensors._stock([name])
    outcome = test_stock_sensors._outcome(report, name)
    return {"sweep": "stock", "effect": name, "outcome": outcome, "expected": STOCK_EXPECTED[name],
            "passes": outcome == STOCK_EXPECTED[name], "cpu_s": time.process_time() - t0}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sweep", choices=("full", "stock", "both"), default="both")
    ap.add_argument("--only", default=None, help="one effect name")
    ap.add_argument("--jobs", type=int, default=None, help="worker processes (default: one per core)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    todo = []
    if args.sweep in ("full", "both"):
        todo += [(full_case, n) for n in test_diagnose.SINGLE]
    if args.sweep in ("stock", "both"):
        todo += [(stock_case, n) for n in STOCK_EXPECTED]
    if args.only:
        todo = [(f, n) for f, n in todo if n == args.only]
        if not todo:
            ap.error(f"no case {args.only!r} in the {args.sweep} sweep")
    t0 = time.perf_counter()
    rows = fork_map(lambda case: case[0](case[1]), todo, jobs=args.jobs)
    wall = time.perf_counter() - t0
    for r in rows:
        if r["sweep"] == "full":
            detail = f"named {r['named']}, shrink {r['shrink']:.3f}, significant {r['significant']}"
        else:
            detail = f"{r['outcome']} (expected {r['expected']})"
        verdict = "pass" if r["passes"] else "FAIL"
        print(f"{r['sweep']:5s} {r['effect']:24s} {verdict}  {detail}  {r['cpu_s']:.1f} s CPU")
    n_pass = sum(r["passes"] for r in rows)
    print(f"{n_pass} of {len(rows)} cases pass; {wall:.1f} s wall, {sum(r['cpu_s'] for r in rows):.1f} s CPU in cases")
    if args.json:
        print(json.dumps({"passed": n_pass, "cases": len(rows), "wall_s": wall, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
