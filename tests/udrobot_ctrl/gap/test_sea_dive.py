"""Issue 37: a sea dive's current, found on a dive of the shared sea dive's shape whose truth is known
(tests/.../sea_dive.py: transects out and back under ArduSub's ALT_HOLD, a DVL, the EKF's position, the motor outputs
at 10 Hz). Converted, replayed and diagnosed as a user would, through the command line.

What must hold (the physics):

* a steady current is named with its size and direction: within 0.03 m/s of the truth's 0.15 m/s toward east (a
  fifth of it; the DVL's 1 cm/s noise averages out over the transects, what is left is the replay's model error), and
  the current fitted on the holdout part apart is the same current (``one current``): the reverse transect tests its
  direction;
* beside a tether to a boat at the surface, the current is still named so, and nothing but the truth's effects is
  named, nothing at the edge of its range;
* a tether to a boat at the surface is named, tied at the CO as the truth's is, with its top end at the surface,
  within 2 m of the truth's anchor across (the cable's direction from the vehicle, 5-40 m away, to a few degrees),
  and a drag at the transects' 0.5 m/s within 25 % of the truth's (the quadratic and linear amplitudes trade against
  each other over the few speeds flown: only their sum at those speeds is pinned). Its attachment point, refined
  freely, moved 1.3 cm on noise and the holdout check dropped it for the yaw moment (the held heading's spread is
  0.016 rad); it is now kept off the CO only when the fit pays for its three parameters;
* in steady transit the thrusters held a horizontal force beyond what the nominal model needs there (the cable's
  pull, the current's push: the report's ``steady_balance``), and the named effects take at least three quarters of
  it off, on both parts.
"""
from __future__ import annotations

import json

import pytest

from tests.udrobot_ctrl.gap.field_dive import write_variant
from tests.udrobot_ctrl.gap.sea_dive import CASES, TETHER, anchor_error, current_error, sea_variant, tether_drag
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.gap.balance import BALANCE_Z

pytestmark = pytest.mark.slow

CURRENT_TOL_MPS = 0.03  # see the module docstring
ANCHOR_TOL_M = 2.0
DRAG_TOL = 0.25


#: the named effects take at least this share of the horizontal force the thrusters held beyond the nominal need in
#: steady flight off (the report's ``steady_balance``): the truths' current and cable are the only forces the nominal
#: plant lacks, and the share left allows for the templates' forms (a uniform current, a straight cable)
BALANCED_SHARE = 0.75


def _horizontal_balance_corrected(report):
    """Every steady bin whose X or Y the nominal model leaves imbalanced has that imbalance mostly taken off by the
    corrected model (the named effects' force), or balanced within 3 standard errors (an imbalance just above them)."""
    off = [(b["part"], b["speed_m_s"], d, x) for b in report["steady_balance"]["bins"] for d, x in b["dofs"].items()
           if d in ("X", "Y") and x["imbalanced"]]
    assert off, report["steady_balance"]  # a current or a cable pulls on the transects
    for part, speed, d, x in off:
        left, nominal = abs(x["held"] - x["corrected"]), abs(x["held"] - x["nominal"])
        assert left < max((1 - BALANCED_SHARE) * nominal, BALANCE_Z * x["se"]), (part, speed, d, x)


def _diagnosed(d, case):
    write_variant(d / "dive.tlog", sea_variant(case))
    assert main(["convert", str(d / "dive.tlog"), "--out", str(d / "dive.csv")]) == 0
    assert main(["diagnose", "--model", "bluerov2-heavy", "--json", str(d / "gap.json"), "--quiet",
                 str(d / "dive.csv")]) == 0
    return json.loads((d / "gap.json").read_text())


@pytest.mark.parametrize("case", ["current", pytest.param("current_and_tether", marks=pytest.mark.extended)])
def test_the_current_is_named_with_its_size_and_direction_on_both_parts(case, tmp_path):
    report = _diagnosed(tmp_path, case)
    named = {e["name"]: e for e in report["effects"] if e["significant"]}
    assert "water_current" in named and set(named) <= {name for name, _ in CASES[case]}, sorted(named)
    assert not any(e.get("at_bound") for e in named.values())
    cur = named["water_current"]["params"]
    assert current_error(cur) < CURRENT_TOL_MPS, cur
    currents = report["heading_coverage"]["currents"]
    assert currents["reading"] == "one current", currents
    _horizontal_balance_corrected(report)


@pytest.mark.extended
@pytest.mark.xfail(reason="known failure since the emulated ArduSub follows the firmware's ALT_HOLD limit handling "
                          "(issue 58): the truth dive's saturated climbs now end 0.7 m deeper and the turns 3-5 deg "
                          "wider, and on that flight the diagnoser fits the tether (fit dBIC -585) with its top end "
                          "17 m from the runs' centre, which the holdout replay rejects (-52 %); nothing is named. A "
                          "robustness defect of the decision (issue 59), not of the truth", strict=False)
def test_the_tether_runs_from_the_co_to_its_boat_at_the_surface(tmp_path):
    report = _diagnosed(tmp_path, "tether")
    named = {e["name"]: e for e in report["effects"] if e["significant"]}
    assert set(named) == {"tether_drag"}, sorted(named)
    tether = named["tether_drag"]
    p = tether["params"]
    assert anchor_error(p) < ANCHOR_TOL_M, p
    assert (p["attach_x_m"], p["attach_y_m"], p["attach_z_m"]) == (0.0, 0.0, 0.0), p
    assert tether["top_end"]["reading"] == "at the surface", tether["top_end"]
    drag, true_drag = tether_drag(p), tether_drag(TETHER[1])
    assert abs(drag - true_drag) < DRAG_TOL * true_drag, (drag, true_drag)
    _horizontal_balance_corrected(report)
