"""The synthetic sea dive's verdicts (issue 37): the cases of ``tests/udrobot_ctrl/gap/sea_dive.py`` (a current, a
tether to a boat at the surface, both; transects out and back under ALT_HOLD with a DVL) converted and diagnosed
through the command line as a user would, each with a few noise seeds.

Prints per case and seed: what was named, the current fitted against the truth and its reading on the two parts, the
tether's anchor, its drag at the transects' 0.5 m/s against the truth's, its top end, the holdout check's outcome,
the gap before and after, and the steady-flight balance (what the thrusters held against what the nominal and
corrected models need: the cable's pull and the current's push in newtons).

Usage: ``python bench/sea_dive.py [CASE ...] [--seeds 0 1 2] --dir DIR``; cases: see ``sea_dive.CASES``.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.udrobot_ctrl.gap import sea_dive  # noqa: E402
from tests.udrobot_ctrl.gap.field_dive import write_variant  # noqa: E402
from udrobot_ctrl.cli.main import main  # noqa: E402
from udrobot_ctrl.gap.balance import balance_lines  # noqa: E402


def describe(case: str, report: dict) -> list:
    """Lines on one diagnosis of ``case``."""
    truth = dict(sea_dive.CASES[case])
    by = {e["name"]: e for e in report["effects"]}
    named = [e["name"] for e in report["effects"] if e["significant"]]
    lines = [f"  named: {', '.join(named) or 'nothing'}; gap {report['gap_before']['value']:.3f} -> "
             f"{report['gap_after']['value']:.3f}"]
    if "water_current" in truth:
        e = by["water_current"]
        p = e["params"] or e.get("fitted_params_if_added") or {}
        if p:
            err = sea_dive.current_error(p)
            cur = report.get("heading_coverage", {}).get("currents") or {}
            lines.append(f"  current: fitted N {p['current_north_mps']:+.3f} E {p['current_east_mps']:+.3f} m/s, "
                         f"{err:.3f} m/s from the truth; parts: {cur.get('reading', '-')}")
    if "tether_drag" in truth:
        e, t = by["tether_drag"], truth["tether_drag"]
        p = e["params"] or e.get("fitted_params_if_added") or {}
        test = next((r["tests"]["tether_drag"] for r in report.get("backward_elimination", [])[::-1]
                     if "tether_drag" in r["tests"]), None)
        if p:
            off = sea_dive.anchor_error(p)
            attach = [p.get(k, 0.0) for k in ("attach_x_m", "attach_y_m", "attach_z_m")]
            drag, true_drag = sea_dive.tether_drag(p), sea_dive.tether_drag(t)
            lines.append(f"  tether: anchor {off:.2f} m from the truth's (down {p['anchor_down_m']:.2f} m), drag at "
                         f"{sea_dive.TRANSECT_SPEED} m/s {drag:.2f} N against {true_drag:.2f} N; attached at "
                         f"({', '.join(f'{100 * a:+.1f}' for a in attach)}) cm; top end: "
                         f"{(e.get('top_end') or {}).get('reading', '-')}; holdout: "
                         + (f"replay gap {100 * test['holdout_gap_contribution']:+.1f}% when dropped, "
                            f"{'passed' if test['passed'] else 'dropped'}" if test else "not a candidate"))
    return lines + balance_lines(report.get("steady_balance"))


def main_(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=sorted(sea_dive.CASES))
    ap.add_argument("--seeds", nargs="*", type=int, default=[0])
    ap.add_argument("--dir", type=Path, required=True)
    args = ap.parse_args(argv)
    for case in args.cases:
        for seed in args.seeds:
            d = args.dir / f"{case}_{seed}"
            d.mkdir(parents=True, exist_ok=True)
            t0 = time.process_time()
            write_variant(d / "dive.tlog", sea_dive.sea_variant(case, seed))
            with contextlib.redirect_stdout(io.StringIO()):  # the commands' own console output
                main(["convert", str(d / "dive.tlog"), "--out", str(d / "dive.csv"), "--force"])
                main(["diagnose", "--model", "bluerov2-heavy", "--json", str(d / "gap.json"), "--quiet",
                      str(d / "dive.csv")])
            report = json.loads((d / "gap.json").read_text())
            print(f"{case}, seed {seed} ({time.process_time() - t0:.0f} CPU-s):")
            print("\n".join(describe(case, report)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main_())
