"""Issue 37: a sea dive's current and tether, found on a dive of the shared sea dive's shape whose truth is known
(tests/.../sea_dive.py: transects out and back under ArduSub's ALT_HOLD, a DVL, the EKF's position, the motor outputs
at 10 Hz). Converted, replayed and diagnosed as a user would, through the command line.

What must hold (the physics):

* a steady current is named with its size and direction: within 0.03 m/s of the truth's 0.15 m/s toward east (a
  fifth of it; the DVL's 1 cm/s noise averages out over the transects, what is left is the replay's model error), and
  the current fitted on the holdout part apart is the same current (``one current``): the reverse transect tests its
  direction;
* a tether to a boat at the surface is named with its top end at the surface, within 2 m of the truth's anchor
  across (the cable's direction from the vehicle, 5-40 m away, to a few degrees), and a drag at the transects'
  0.5 m/s within 25 % of the truth's (the quadratic and linear amplitudes trade against each other over the few
  speeds flown: only their sum at those speeds is pinned);
* nothing else is named, and nothing at the edge of its range.
"""
from __future__ import annotations

import json
import math

import pytest

from tests.udrobot_ctrl.gap.field_dive import write_variant
from tests.udrobot_ctrl.gap.sea_dive import CASES, CURRENT, TETHER, sea_variant
from udrobot_ctrl.cli.main import main

pytestmark = pytest.mark.slow

CURRENT_TOL_MPS = 0.03  # see the module docstring
ANCHOR_TOL_M = 2.0
DRAG_TOL = 0.25
TRANSECT_SPEED = 0.5  # m/s, the forward legs' speed (ALT_HOLD at +200 us)


def _diagnosed(d, case):
    write_variant(d / "dive.tlog", sea_variant(case))
    assert main(["convert", str(d / "dive.tlog"), "--out", str(d / "dive.csv")]) == 0
    assert main(["diagnose", "--model", "bluerov2-heavy", "--json", str(d / "gap.json"), "--quiet",
                 str(d / "dive.csv")]) == 0
    return json.loads((d / "gap.json").read_text())


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """case -> report, diagnosed once per case on first use."""
    done = {}

    def get(case):
        if case not in done:
            done[case] = _diagnosed(tmp_path_factory.mktemp(case), case)
        return done[case]
    return get


def _named(report):
    return {e["name"]: e for e in report["effects"] if e["significant"]}


def _tether_drag(params, speed):
    return params["k_quadratic_N_s2_per_m2"] * speed ** 2 + params["k_linear_N_s_per_m"] * speed


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_named_effects_are_the_truths(reports, case):
    report = reports(case)
    named = _named(report)
    truth = {name for name, _ in CASES[case]}
    assert set(named) <= truth and set(named), (sorted(named), truth)
    assert not any(e.get("at_bound") for e in named.values())
    if case != "current_and_tether":  # alone, each is named
        assert set(named) == truth, sorted(named)


@pytest.mark.parametrize("case", ["current", "current_and_tether"])
def test_the_current_is_found_with_its_size_and_direction_on_both_parts(reports, case):
    report = reports(case)
    cur = _named(report)["water_current"]["params"]
    true = CURRENT[1]
    err = math.hypot(cur["current_north_mps"] - true["current_north_mps"],
                     cur["current_east_mps"] - true["current_east_mps"])
    assert err < CURRENT_TOL_MPS, cur
    currents = report["heading_coverage"]["currents"]
    assert currents["reading"] == "one current", currents


def test_the_tether_runs_to_its_boat_at_the_surface(reports):
    report = reports("tether")
    tether = _named(report)["tether_drag"]
    p, true = tether["params"], TETHER[1]
    assert math.hypot(p["anchor_north_m"] - true["anchor_north_m"],
                      p["anchor_east_m"] - true["anchor_east_m"]) < ANCHOR_TOL_M, p
    assert tether["top_end"]["reading"] == "at the surface", tether["top_end"]
    drag, true_drag = _tether_drag(p, TRANSECT_SPEED), _tether_drag(true, TRANSECT_SPEED)
    assert abs(drag - true_drag) < DRAG_TOL * true_drag, (drag, true_drag)
