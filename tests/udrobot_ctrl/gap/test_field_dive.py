"""Issue 37: a real dive's heave-drag finding, end to end on a synthetic QGroundControl tlog (tests/.../field_dive.py):
a BlueROV2 Heavy whose heave quadratic drag is half the published value, flown by a pilot under ArduSub in STABILIZE
and ALT_HOLD, logged at the rates of a real QGC tlog (motor outputs 2 Hz, attitude 20 Hz, depth 2 Hz, the pilot's
joystick 24 Hz), no DVL. Converted, replayed and diagnosed as a user would, through the command line.

What must hold (the physics):

* the equation error on the fit runs selects the heave drag error with the withheld scale: ``scale_Zw|w|`` within
  0.1 of -0.5 (the depth at 2 Hz with 1 cm noise pins the heave speed of the 10 s climbs and descents at 0.7-1 m/s
  to about 1 %, and the drag goes with its square: a few % of the scale; 0.1 leaves room for the smoother's
  reconstruction of w from depth alone);
* no effect whose parameters sit at the edge of their range is named, and nothing acting on the attitude is named
  from an equation error the autopilot's unlogged corrections would fill (the roll / pitch / yaw DOFs are left out
  of it on such runs, and say so);
* the verdict names the heave drag error: the holdout replay confirms it once the 2 Hz output samples are
  refreshed between samples by the emulated autopilot on the measured motion (autopilot/feedback.py; held, the
  pitch kicks of the stick steps made q hold the gap for the nominal and the true model alike, NRMSE 0.9) and
  each channel's noise is measured at its own logging rate (the level-held roll is noise, not scored).
"""
from __future__ import annotations

import json

import pytest

from tests.udrobot_ctrl.gap.field_dive import HEAVE_DRAG_SCALE, flight, write_tlog
from udrobot_ctrl.cli.main import main

pytestmark = pytest.mark.slow

SCALE_TOL = 0.1  # see the module docstring


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    """The tlog converted and diagnosed with the published model: (report, console output)."""
    d = tmp_path_factory.mktemp("field_dive")
    f, plan = flight()
    write_tlog(d / "dive.tlog", f, plan)
    assert main(["convert", str(d / "dive.tlog"), "--out", str(d / "dive.csv")]) == 0
    assert main(["diagnose", "--model", "bluerov2-heavy", "--json", str(d / "gap.json"), "--quiet",
                 "--out-model", str(d / "corrected.json"), str(d / "dive.csv")]) == 0
    return json.loads((d / "gap.json").read_text()), json.loads((d / "corrected.json").read_text())


def _effect(report, name):
    return next(e for e in report["effects"] if e["name"] == name)


def test_the_fit_finds_the_withheld_heave_drag(diagnosed):
    report, _ = diagnosed
    steps = report["selection_steps"]
    assert steps and steps[0]["effect"] == "quadratic_damping_error", steps
    qde = _effect(report, "quadratic_damping_error")
    fitted = qde["params"] or qde.get("fitted_params_if_added", {})
    assert abs(fitted["scale_Zw|w|"] - HEAVE_DRAG_SCALE) < SCALE_TOL, fitted
    # the autopilot's attitude DOFs are not in the equation error: no attitude scale is fitted
    for k in ("scale_Kp|p|", "scale_Mq|q|", "scale_Nr|r|"):
        assert fitted[k] == 0.0, fitted
    assert any("equation error without K, M, N" in n for n in report["notes"])


def test_nothing_at_the_edge_of_its_range_or_wrong_is_named(diagnosed):
    report, corrected = diagnosed
    named = {e["name"] for e in report["effects"] if e["significant"]}
    assert named <= {"quadratic_damping_error"}, named
    assert not any("at_bound" in e for e in report["effects"] if e["significant"])
    assert {e["name"] for e in corrected.get("effects") or []} <= {"quadratic_damping_error"}


def test_the_verdict_names_the_heave_drag_error(diagnosed):
    report, corrected = diagnosed
    qde = _effect(report, "quadratic_damping_error")
    assert qde["significant"]
    assert abs(qde["params"]["scale_Zw|w|"] - HEAVE_DRAG_SCALE) < SCALE_TOL
    assert [e["name"] for e in corrected["effects"]] == ["quadratic_damping_error"]
    assert report["unexplained"] < 0.9


def test_what_remains_is_told_in_each_channels_units(diagnosed):
    """The pilot flew STABILIZE and ALT_HOLD throughout: the attitude channels were replayed in closed loop, the
    depth open loop; the depth error left after the heave drag is centimetres, a small fraction of the metres the
    vehicle climbed (the true model replays z at NRMSE ~0.02)."""
    report, _ = diagnosed
    rem = {r["channel"]: r for r in report["remaining"]}
    assert rem["z"]["closed_loop"] == 0.0
    assert all(rem[c]["closed_loop"] > 0.9 for c in ("phi", "theta", "q") if c in rem)
    assert rem["z"]["rms_error"] < 0.1 * rem["z"]["spread"]
    assert sum(r["share"] for r in report["remaining"]) == pytest.approx(1.0, abs=1e-5)
