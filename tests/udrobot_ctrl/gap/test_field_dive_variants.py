"""Issue 37: the heave-drag verdict of test_field_dive.py on the two variants of the synthetic QGC dive that failed
before the output refresh learnt what they need (bench/field_dive_variants.py tabulates all variants):

* ``no_joystick``: an older QGC tlog without ``MANUAL_CONTROL``, the pilot only in the 2 Hz ``RC_CHANNELS``. An
  output sample may hold a stick step whose RC sample is logged after it; refreshed from the sample the step was
  added twice (holdout gap 0.80, q NRMSE 1.66 for the nominal and the true model alike; nothing named);
* ``scale -0.3``: a heave drag error smaller than the users' fits suggest. The ALT_HOLD throttle held between its
  2 Hz samples lagged each stop of a climb by a quarter second, so the true model replayed the holdout depth no
  better than the nominal (the effect was dropped, +5.9 % not consistent over the windows).

* ``six_gentle_no_joystick``: the 6-thruster ``bluerov2`` flown gently (60 us forward; at 200 us its model tumbles
  in pitch, see ``Variant.forward``) without ``MANUAL_CONTROL``. VECTORED cannot actuate pitch, so M stays in the
  equation error, and there the heave drag error's pitch scale ran to its bound -0.95 beside the right heave scale
  (-0.496): the whole effect was set aside. Now a per-DOF amplitude at its bound is held at nominal and the rest
  refitted and checked on the holdout (``report.hold_at_nominal``): the heave scale is named, its pitch scale nominal
  (the truth's). With ``MANUAL_CONTROL`` the pitch scale fitted in range (-0.83) and was named with the heave scale: the
  holdout confirmed the effect as a whole; now each amplitude of a per-DOF effect is checked on its own
  (``report.confirm_components``) and the pitch scale, not confirmed (the holdout replay is 7.8 % of gap_before
  better without it), is held at nominal.

What must hold is test_field_dive.py's physics: the equation error selects the heave drag error first, its
``scale_Zw|w|`` within 0.1 of the withheld scale, nothing else is named and nothing at a bound; the verdict names it
on every variant. On the -0.3 dive the holdout replay preferred the heave drag (+6 to +8 % of gap_before when
dropped) but not consistently over the 8 windows (p 0.15 to 0.29) while the window test weighed every channel alike,
the pitch and yaw rates at their noise floors holding most of the gap; weighed where the heave drag changes the
replay, against the error there (``confirm.change_weights``), the rise is consistent (p 0.016, 88 % of the windows
worse; second reconstruction pass p 0.055) and the effect is named.
"""
from __future__ import annotations

import json

import pytest

from tests.udrobot_ctrl.gap.field_dive import Variant, write_variant
from udrobot_ctrl.cli.main import main

pytestmark = pytest.mark.slow

SCALE_TOL = 0.1  # as test_field_dive.py (its module docstring)
VARIANTS = {"no_joystick": Variant(manual_control=False), "scale_m03": Variant(scale=-0.3),
            "six_gentle": Variant(model="bluerov2", forward=60.0),
            "six_gentle_no_joystick": Variant(model="bluerov2", forward=60.0, manual_control=False)}


@pytest.mark.extended
@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_the_verdict_names_the_withheld_heave_drag(name, tmp_path):
    variant = VARIANTS[name]
    write_variant(tmp_path / "dive.tlog", variant)
    assert main(["convert", str(tmp_path / "dive.tlog"), "--out", str(tmp_path / "dive.csv")]) == 0
    assert main(["diagnose", "--model", variant.model, "--json", str(tmp_path / "gap.json"), "--quiet",
                 str(tmp_path / "dive.csv")]) == 0
    report = json.loads((tmp_path / "gap.json").read_text())
    assert report["selection_steps"][0]["effect"] == "quadratic_damping_error", report["selection_steps"]
    named = [e for e in report["effects"] if e["significant"]]
    assert {e["name"] for e in named} <= {"quadratic_damping_error"}, [e["name"] for e in named]
    assert not any("at_bound" in e for e in named)
    qde = next(e for e in report["effects"] if e["name"] == "quadratic_damping_error")
    fitted = qde["params"] or qde.get("fitted_params_if_added", {})
    assert abs(fitted["scale_Zw|w|"] - variant.scale) < SCALE_TOL, fitted
    assert qde["significant"]
    if name.startswith("six_gentle"):  # the truth's pitch drag is the published one: held at nominal, or near it
        pitch = qde["params"]["scale_Mq|q|"]
        assert "scale_Mq|q|" in qde.get("held_at_nominal", {}) and pitch == 0.0 or abs(pitch) < 0.3, qde
