"""An effect whose fit ends at the edge of its range is listed, not named (issue 37).

"A parameter at its bound is evidence of a missing term, not a finding": a dead band wider than the catalogue's
0.35 of the command range is fitted at 0.35 and explains most of the gap, yet the model it would give is not the
vehicle. It must not be significant, nor go into ``--out-model``; the report and the console say why.
"""
from __future__ import annotations

import pytest

from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.report import corrected_model, diagnose, summary

from .truth import generate


def _diagnosed(delta):
    """Three 60 s pool runs (full sensors) of UDrobot whose thrusters do nothing below ``delta`` of the normalised
    command (the truth's PWM-domain dead band)."""
    runs = generate({"thruster_deadband": {"delta": delta}}, n_runs=3, duration=60.0, rate=20.0, seed=4)
    report, _ = diagnose("pendulum:chin", runs)
    return report, runs


@pytest.mark.slow
def test_a_dead_band_wider_than_the_catalogue_allows_is_listed_at_its_bound_not_named():
    (_, top), _ = fx.catalogue()["thruster_deadband"].shape_bounds
    assert top == pytest.approx(0.35)
    report, runs = _diagnosed(0.55)  # 55 % of the command range: beyond the 35 % the catalogue searches
    e = next(x for x in report["effects"] if x["name"] == "thruster_deadband")
    assert not e["significant"] and e["params"] == {}
    assert e["at_bound"]["width_fraction"] == {"value": pytest.approx(top), "bound": pytest.approx(top)}
    assert "evidence of a missing term" in e["at_bound_reason"]
    assert e["shrink"] > 0.5  # it explains most of the gap: that is why it must not be read as the answer
    assert e["fitted_params_if_added"]["width_fraction"] == pytest.approx(top)
    assert report["effects"][0]["name"] == "thruster_deadband"  # listed first among the effects not named
    assert "at the edge of its range" in report["verdict"] and "thruster_deadband" in report["verdict"]
    text = summary(report)
    assert "thruster_deadband" in text and "AT BOUND" in text
    vehicle, _ = corrected_model("pendulum:chin", report, runs)
    assert "thruster_deadband" not in [x.name for x in vehicle.effects]
    assert all(not x.get("at_bound") for x in report["effects"] if x["significant"])


@pytest.mark.slow
def test_a_dead_band_inside_the_range_is_named_with_its_width():
    report, _ = _diagnosed(0.25)
    e = next(x for x in report["effects"] if x["name"] == "thruster_deadband")
    assert e["significant"] and not e.get("at_bound") and "at_bound_reason" not in e
    assert 0.1 < e["params"]["width_fraction"] < 0.35
