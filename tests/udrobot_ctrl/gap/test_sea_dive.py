"""Issue 37: a sea dive's current, found on a dive of the shared sea dive's shape whose truth is known
(tests/.../sea_dive.py: transects out and back under ArduSub's ALT_HOLD, a DVL, the EKF's position, the motor outputs
at 10 Hz). Converted, replayed and diagnosed as a user would, through the command line.

What must hold (the physics):

* a steady current is named with its size and direction: within 0.03 m/s of the truth's 0.15 m/s toward east (a
  fifth of it; the DVL's 1 cm/s noise averages out over the transects, what is left is the replay's model error), and
  the current fitted on the holdout part apart is the same current (``one current``): the reverse transect tests its
  direction;
* beside a tether to a boat at the surface, the current is still named so, and nothing but the truth's effects is
  named, nothing at the edge of its range.

The tether alone is scored by ``bench/sea_dive.py``, not asserted here: its fit finds the boat (anchor 0.4-1.2 m from
the truth's, drag within 5 % at 0.5 m/s) but whether the holdout confirms it hangs on its attachment point, fitted a
centimetre off the CO from noise, whose yaw moment the holdout's held heading (spread 0.016 rad) scores.
"""
from __future__ import annotations

import json
import math

import pytest

from tests.udrobot_ctrl.gap.field_dive import write_variant
from tests.udrobot_ctrl.gap.sea_dive import CASES, CURRENT, sea_variant
from udrobot_ctrl.cli.main import main

pytestmark = pytest.mark.slow

CURRENT_TOL_MPS = 0.03  # see the module docstring


def _diagnosed(d, case):
    write_variant(d / "dive.tlog", sea_variant(case))
    assert main(["convert", str(d / "dive.tlog"), "--out", str(d / "dive.csv")]) == 0
    assert main(["diagnose", "--model", "bluerov2-heavy", "--json", str(d / "gap.json"), "--quiet",
                 str(d / "dive.csv")]) == 0
    return json.loads((d / "gap.json").read_text())


@pytest.mark.parametrize("case", ["current", "current_and_tether"])
def test_the_current_is_named_with_its_size_and_direction_on_both_parts(case, tmp_path):
    report = _diagnosed(tmp_path, case)
    named = {e["name"]: e for e in report["effects"] if e["significant"]}
    assert "water_current" in named and set(named) <= {name for name, _ in CASES[case]}, sorted(named)
    assert not any(e.get("at_bound") for e in named.values())
    cur, true = named["water_current"]["params"], CURRENT[1]
    err = math.hypot(cur["current_north_mps"] - true["current_north_mps"],
                     cur["current_east_mps"] - true["current_east_mps"])
    assert err < CURRENT_TOL_MPS, cur
    currents = report["heading_coverage"]["currents"]
    assert currents["reading"] == "one current", currents
