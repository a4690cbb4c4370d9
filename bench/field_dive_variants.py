"""Robustness study of the synthetic field dive's verdict (issue 37): variants of the QGC-logged dive of
``tests/udrobot_ctrl/gap/field_dive.py`` converted and diagnosed through the command line as a user would, one
variant per call (each diagnose of a 180 s dive costs 1-2 CPU-minutes).

A variant passes when the verdict names ``quadratic_damping_error`` significant with ``scale_Zw|w|`` within 0.1 of
the withheld scale and nothing else is named significant.

Usage: ``python bench/field_dive_variants.py NAME [NAME ...] --dir DIR [--json OUT]``; names: see ``VARIANTS``.
Prints one summary line per variant; ``--json`` appends one JSON line per variant to OUT.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.udrobot_ctrl.gap.field_dive import Variant, write_variant  # noqa: E402
from udrobot_ctrl.cli.main import main  # noqa: E402

SCALE_TOL = 0.1  # as tests/udrobot_ctrl/gap/test_field_dive.py
TARGET = "quadratic_damping_error"

VARIANTS = {
    "default": Variant(),
    "six_thruster": Variant(model="bluerov2"),
    "alt_hold": Variant(alt_hold_from=0.0),
    "no_joystick": Variant(manual_control=False),
    "slow_attitude": Variant(attitude_hz=10.0, vfr_hz=4.0),
    "seed7": Variant(seed=7),
    "scale_m03": Variant(scale=-0.3),
    "scale_m03_seed5": Variant(scale=-0.3, seed=5),
    "scale_m07": Variant(scale=-0.7),
    "six_no_joystick": Variant(model="bluerov2", manual_control=False),
    "six_slow_attitude": Variant(model="bluerov2", attitude_hz=10.0, vfr_hz=4.0),
    "six_alt_hold": Variant(model="bluerov2", alt_hold_from=0.0),
    "six_gentle": Variant(model="bluerov2", forward=60.0),  # no tumble (max pitch 52 deg; see Variant.forward)
    "six_gentle_no_joystick": Variant(model="bluerov2", forward=60.0, manual_control=False),
    "six_gentle_servo10": Variant(model="bluerov2", forward=60.0, servo_hz=10.0),
    "default_16v": Variant(voltage=16.0),  # a battery logged 1.2 V above the one the truth flew at
    "jitter": Variant(jitter=0.05),
    "no_joystick_jitter": Variant(manual_control=False, jitter=0.05),
    "combined": Variant(model="bluerov2", scale=-0.3, alt_hold_from=0.0, manual_control=False, attitude_hz=10.0,
                        vfr_hz=4.0, seed=3),
}


@dataclass(frozen=True)
class Outcome:
    """What one variant's diagnosis found (the study table's row)."""

    name: str
    steps: list
    scale: float | None
    significant: list
    gap_before: float
    gap_after: float
    at_bound: list
    unidentifiable: list
    passed: bool
    cpu_s: float


def outcome(name: str, variant: Variant, report: dict, cpu_s: float) -> Outcome:
    """The table row of ``report`` for ``variant``."""
    effects = {e["name"]: e for e in report["effects"]}
    qde = effects.get(TARGET, {})
    fitted = qde.get("params") or qde.get("fitted_params_if_added") or {}
    scale = fitted.get("scale_Zw|w|")
    significant = [e["name"] for e in report["effects"] if e["significant"]]
    passed = (significant == [TARGET] and scale is not None and abs(scale - variant.scale) < SCALE_TOL)
    return Outcome(name=name, steps=[s["effect"] for s in report["selection_steps"]], scale=scale,
                   significant=significant, gap_before=report["gap_before"]["value"],
                   gap_after=report["gap_after"]["value"],
                   at_bound=[e["name"] for e in report["effects"] if "at_bound" in e],
                   unidentifiable=[u["name"] if isinstance(u, dict) else str(u) for u in report["unidentifiable"]],
                   passed=passed, cpu_s=cpu_s)


def run(name: str, variant: Variant, directory: Path) -> Outcome:
    """Write, convert and diagnose one variant in ``directory / name``."""
    d = directory / name
    d.mkdir(parents=True, exist_ok=True)
    write_variant(d / "dive.tlog", variant)
    assert main(["convert", str(d / "dive.tlog"), "--out", str(d / "dive.csv")]) == 0
    c0 = time.process_time()
    assert main(["diagnose", "--model", variant.model, "--json", str(d / "gap.json"), "--quiet",
                 "--out-model", str(d / "corrected.json"), str(d / "dive.csv")]) == 0
    return outcome(name, variant, json.loads((d / "gap.json").read_text()), time.process_time() - c0)


def cli(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="+", choices=sorted(VARIANTS))
    ap.add_argument("--dir", type=Path, required=True)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    for name in a.names:
        o = run(name, VARIANTS[name], a.dir)
        print(o)
        if a.json:
            with open(a.json, "a") as fh:
                fh.write(json.dumps(asdict(o) | {"variant": asdict(VARIANTS[name])}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(cli())
