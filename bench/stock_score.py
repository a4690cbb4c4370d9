"""Blind score of the diagnoser with the stock sensor set (depth, attitude, gyro, accelerometer; no DVL, no position).

For every catalogue effect (and none), the suite's truth generator (tests/udrobot_ctrl/gap/truth.py, forms that
differ from the diagnoser's templates) simulates three closed-loop pool runs with that effect withheld and logs
the stock sensors; two runs fit, one is held out. Each case is scored:

* ``named``: the truth effect is significant (or listed indistinguishable from a significant one), nothing else;
* ``unidentifiable``: the truth effect is listed under ``unidentifiable`` and no effect is significant;
* ``named+extra``: the truth effect is named, with other significant effects besides (wrong by the goal);
* ``listed+wrong``: the truth effect is listed unidentifiable, but another effect is significant (wrong);
* ``wrong``: a wrong significant effect and the (identifiable) truth effect missed; ``missed``: nothing
  significant although the truth effect is identifiable.

Prints one line per case and the totals (and with --json one JSON line).
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "udrobot_ctrl" / "gap"))

from truth import generate, random_magnitudes  # noqa: E402

from udrobot_ctrl.gap.effects import EFFECT_NAMES  # noqa: E402
from udrobot_ctrl.gap.report import diagnose  # noqa: E402


def classify(report, truth_names) -> str:
    """Outcome of one case (see the module docstring); 'none' / 'wrong' for a case without effect."""
    sig = [e for e in report["effects"] if e["significant"]]
    unid = {u["name"] for u in report["unidentifiable"]}
    if not truth_names:
        return "none" if not sig else "wrong"
    truth = set(truth_names)
    named = {n for e in sig for n in ({e["name"]} | {a["name"] for a in e.get("indistinguishable_from", [])})
             if n in truth}
    extra = [e["name"] for e in sig if e["name"] not in truth
             and not truth & {a["name"] for a in e.get("indistinguishable_from", [])}]
    if named == truth:
        return "named" if not extra else "named+extra"
    if truth - named <= unid:
        return "unidentifiable" if not sig else "listed+wrong"
    return "wrong" if sig else "missed"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", nargs="*", default=["none"] + list(EFFECT_NAMES))
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per run (3 runs)")
    ap.add_argument("--rate", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--sensors", default="stock", choices=("stock", "full"))
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--cache", help="folder to keep the generated runs in (pickles; reused when present)")
    args = ap.parse_args(argv)
    tally, rows = {}, []
    for name in args.effects:
        names = [] if name == "none" else [name]
        rng = np.random.default_rng(args.seed + 100)
        truth = {n: random_magnitudes(n, rng) for n in names}
        cached = Path(args.cache) / f"{name}_{args.sensors}_{args.duration:g}_{args.rate:g}_{args.seed}.pkl" \
            if args.cache else None
        if cached is not None and cached.exists():
            runs = pickle.loads(cached.read_bytes())
        else:
            runs = generate(truth, n_runs=3, duration=args.duration, rate=args.rate, seed=args.seed,
                            sensors=args.sensors)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                cached.write_bytes(pickle.dumps(runs))
        t0 = time.perf_counter()
        report, _ = diagnose("pendulum:chin", runs[:2], runs[2:])
        dt = time.perf_counter() - t0
        verdict = classify(report, names)
        tally[verdict] = tally.get(verdict, 0) + 1
        sig = [e["name"] for e in report["effects"] if e["significant"]]
        unid = [u["name"] for u in report["unidentifiable"]]
        rows.append({"truth": name, "verdict": verdict, "significant": sig, "unidentifiable": unid,
                     "diagnose_s": round(dt, 1)})
        print(f"{name:<26s} {verdict:<15s} significant {sig}; unidentifiable {unid} ({dt:.1f} s)", flush=True)
    print("totals: " + ", ".join(f"{k} {v}" for k, v in sorted(tally.items())))
    if args.json:
        print(json.dumps({"sensors": args.sensors, "cases": rows, "totals": tally}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
