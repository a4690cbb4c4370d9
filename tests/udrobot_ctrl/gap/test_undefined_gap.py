"""A vehicle holding still: its channels are constant, the NRMSE gap is undefined and reported as such."""
from __future__ import annotations

import json

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.gap.report import summary
from udrobot_ctrl.gap.shrink import gap
from udrobot_ctrl.io.runlog import write_run


class _Prep:
    def __init__(self, t, meas):
        self.t, self.meas = t, meas


def test_constant_channel_has_undefined_nrmse_not_a_number(monkeypatch):
    t = np.arange(200) * 0.05
    meas = {"z": np.full(200, 1.0), "u": 0.2 * np.sin(t)}
    sim = np.zeros((200, 12))
    sim[:, 2], sim[:, 6] = 1.01, 0.2 * np.sin(t) + 0.01
    monkeypatch.setattr("udrobot_ctrl.gap.shrink.errors", lambda prep, s: {"z": s[:, 2] - prep.meas["z"],
                                                                          "u": s[:, 6] - prep.meas["u"]})
    g = gap([_Prep(t, meas)], [sim])
    assert np.isnan(g.per_channel["z"]) and "constant" in g.undefined["z"]
    assert g.scored == ["u"] and g.per_channel["u"] == pytest.approx(0.01 / np.std(meas["u"]), rel=1e-9)


def test_summary_prints_undefined_values():
    report = {"model": "m", "fit_runs": ["a.csv[first 2/3]"], "holdout_runs": ["a.csv[last 1/3]"],
              "gap_before": {"value": None, "per_channel": {"z": None}, "scored": [], "undefined": {"z": "constant"}},
              "gap_after": {"value": None, "per_channel": {"z": None}, "scored": []}, "location": [],
              "effects": [{"name": "buoyancy_offset", "significant": False, "shrink": None,
                           "evidence": {"delta_bic": None}, "params": {}}],
              "unexplained": None, "verdict": "gap undefined"}
    text = summary(report)
    assert "gap before undefined" in text and "z undefined: channel constant" in text
    assert "unexplained undefined" in text and "shrink undefined" in text


def test_summary_says_a_single_effect_replay_drifts_off_instead_of_a_huge_negative_shrink():
    report = {"model": "m", "fit_runs": ["a"], "holdout_runs": ["b"],
              "gap_before": {"value": 1.0, "per_channel": {"z": 1.0}, "scored": ["z"]},
              "gap_after": {"value": 1.0, "per_channel": {"z": 1.0}, "scored": ["z"]}, "location": [],
              "effects": [{"name": "cross_coupled_damping", "significant": False, "shrink": -7031.0,
                           "evidence": {"delta_bic": -5.0}, "params": {}},
                          {"name": "buoyancy_offset", "significant": False, "shrink": -0.5,
                           "evidence": {"delta_bic": 3.0}, "params": {}}],
              "unexplained": 1.0, "verdict": "nothing significant"}
    lines = summary(report).splitlines()
    ccd = next(ln for ln in lines if "cross_coupled_damping" in ln)
    assert "alone its replay drifts off (7.03e+03 x the nominal gap)" in ccd
    assert "drifts off" not in next(ln for ln in lines if "buoyancy_offset" in ln)  # twice the gap or less: a number


@pytest.mark.slow
def test_diagnose_a_vehicle_holding_still(tmp_path, capsys):
    """A vehicle held still (in a clamp) while its thrusters are commanded: the commands are an input, but no channel
    moves, so the gap is undefined. (With no command either, the run is unexcited: test_screen.py.)"""
    t = np.arange(0, 60, 0.05)
    channels = {c: np.zeros(t.size) for c in ("z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")}
    channels["z"][:] = 1.0
    run = write_run(tmp_path / "still.csv", t, channels, "thrust", np.full((t.size, 4), 5.0))
    out = tmp_path / "report.json"
    assert main(["diagnose", "--model", "cfd:chin", "--json", str(out), "--quiet", str(run)]) == 0
    text = capsys.readouterr().out
    assert "gap before undefined" in text and "psi undefined: channel constant" in text
    report = json.loads(out.read_text())
    assert report["gap_before"]["value"] is None and report["gap_before"]["scored"] == []
    assert set(report["gap_before"]["undefined"]) == set(channels)
    assert report["fit_runs"] == ["still.csv[first two thirds]"]
    assert "gap undefined" in report["verdict"]
