"""The diagnoser against the truth generator (effects withheld, written in other forms than the templates)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.gap.effects import EFFECT_NAMES
from udrobot_ctrl.gap.report import diagnose
from udrobot_ctrl.io.runlog import write

from .truth import generate, random_magnitudes

REPO = Path(__file__).resolve().parents[3]


def _run(effects, seed=2, **kw):
    rng = np.random.default_rng(seed + 100)
    truth = {n: random_magnitudes(n, rng) for n in effects}
    runs = generate(truth, n_runs=3, duration=90.0, rate=20.0, seed=seed, **kw)
    report, _ = diagnose("pendulum:chin", runs)
    return report, truth


def _by_name(report):
    return {e["name"]: e for e in report["effects"]}


def _verdict_ok(report, name):
    eff = _by_name(report)
    if eff[name]["significant"]:
        return True
    top = [e for e in report["effects"] if e["significant"]]
    return any(name in [a["name"] for a in e.get("indistinguishable_from", [])] for e in top)


@pytest.mark.slow
def test_no_effect_no_false_alarm():
    report, _ = _run([])
    assert report["format"] == "udrobot-diagnosis/1"
    assert [e["name"] for e in report["effects"] if e["significant"]] == []
    assert sorted(e["name"] for e in report["effects"]) == sorted(EFFECT_NAMES)
    assert report["unexplained"] == pytest.approx(1.0)


SINGLE = ["thrust_inflow_loss", "thruster_deadband", "thruster_asymmetry", "thruster_lag", "tether_drag",
          "water_current", "quadratic_damping_error", "linear_damping", "added_mass_error", "cross_coupled_damping",
          "buoyancy_offset", "cg_cb_offset"]


@pytest.mark.slow
@pytest.mark.parametrize("name", SINGLE)
def test_single_effect_named_and_shrinks(name):
    report, truth = _run([name])
    assert _verdict_ok(report, name), (name, truth, [(e["name"], e["significant"]) for e in report["effects"]])
    assert _by_name(report)[name]["shrink"] >= 0.5, (name, _by_name(report)[name])
    assert report["effects"][0]["significant"]


@pytest.mark.slow
@pytest.mark.xfail(reason="truth fixture, not diagnoser: with its 2-3x image-law wall suction and no contact, the "
                          "unactuated sway lets the truth vehicle be pulled through the wall (tens of metres, rolling "
                          "over), a chaotic run no model replays; wall_effect is still named first. The physical wall "
                          "case is tests/udrobot_ctrl/gap/test_case_wall_effect.py", strict=False)
@pytest.mark.parametrize("name", ["wall_effect"])
def test_single_effect_hard_cases(name):
    report, truth = _run([name])
    assert _verdict_ok(report, name)
    assert _by_name(report)[name]["shrink"] >= 0.5


@pytest.mark.slow
def test_two_effects_together():
    report, truth = _run(["buoyancy_offset", "thrust_inflow_loss"], seed=5)
    assert _verdict_ok(report, "buoyancy_offset") and _verdict_ok(report, "thrust_inflow_loss")
    assert report["unexplained"] < 0.5


@pytest.mark.slow
def test_effect_outside_catalogue_is_unexplained():
    report, _ = _run(["periodic_disturbance"], seed=3)
    sig = [e for e in report["effects"] if e["significant"]]
    assert not sig or report["unexplained"] > 0.5
    assert report["location"], "the gap is still located"


@pytest.mark.slow
def test_partial_logs_and_buoyancy_parameter():
    report, truth = _run(["buoyancy_offset"], seed=4, partial=True)
    e = _by_name(report)["buoyancy_offset"]
    assert e["significant"]
    dB_mean = truth["buoyancy_offset"]["dB0"] * (1 - truth["buoyancy_offset"]["beta"] * 1.5)
    assert e["params"]["dB_N"] == pytest.approx(dB_mean, rel=0.35)


@pytest.mark.slow
def test_cli_end_to_end(tmp_path):
    rng = np.random.default_rng(7)
    runs = generate({"thrust_inflow_loss": random_magnitudes("thrust_inflow_loss", rng)}, n_runs=2, duration=60.0,
                    rate=25.0, seed=7)
    paths = []
    for i, r in enumerate(runs):
        paths.append(write(r, tmp_path / f"run{i}.csv"))
    out = tmp_path / "rep.json"
    proc = subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "diagnose", "--model", "pendulum:chin",
                           "--json", str(out), "--holdout", str(paths[1]), "--plot", str(tmp_path / "fig"),
                           "--quiet", str(paths[0])], capture_output=True, text=True, cwd=REPO,
                          env={"MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(out.read_text())
    assert rep["holdout_runs"] == ["run1.csv"] and rep["fit_runs"] == ["run0.csv"]
    assert {"gap_before", "gap_after", "location", "effects", "unexplained"} <= set(rep)
    assert any((tmp_path / "fig").glob("overlay_*.png"))


def test_cli_bad_input(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u\n0,1\n")
    proc = subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "diagnose", "--model", "pendulum:chin",
                           "--json", str(tmp_path / "r.json"), str(bad)], capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 2 and "bad.csv" in proc.stderr
