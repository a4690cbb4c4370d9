"""Runs a diagnosis cannot use are reported as such, not diagnosed.

A run with no commanded excitation (issue 42.3):
The shared bench log "2023-04-18 11-03-34.tlog" holds every PWM at 1500 us for 313 s while the depth moves 1.6 cm:
the diagnoser named no effect while its own table showed a buoyancy offset shrinking the gap by 84 %. Nothing was
commanded, so there is no input for a model to answer.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.report import diagnose, summary
from udrobot_ctrl.gap.screen import UNEXCITED_COMMAND, unexcited_runs, unrepresented_runs
from udrobot_ctrl.io.runlog import Run, write_run
from udrobot_ctrl.vehicle import load_model

from .stock_sim import simulate

REPO = Path(__file__).resolve().parents[3]
BENCH_LOG = REPO.parent / "shared" / "data" / "ardusub_log_tools" / "2023-04-18 11-03-34.tlog"
P = plant_parameters(load_model("pendulum:chin"))


def _idle(path="idle.csv", duration=30.0, kind="thrust", level=0.0, k=4):
    """A run with the vehicle floating at 1 m depth (2 mm of depth noise) and every command at ``level``."""
    t = np.arange(0.0, duration, 0.05)
    rng = np.random.default_rng(0)
    ch = {"z": 1.0 + rng.normal(0, 0.002, t.size), "phi": np.zeros(t.size), "theta": np.zeros(t.size),
          "psi": np.zeros(t.size), "p": np.zeros(t.size), "q": np.zeros(t.size), "r": np.zeros(t.size)}
    return Run(path=path, t=t, channels=ch, input_kind=kind, inputs=np.full((t.size, k), level), extra={},
               metadata={"format": "udrobot-run/1"})


def test_zero_commands_are_unexcited_and_commanded_thrust_is_not():
    flown, _ = simulate(duration=20.0, seed=1)
    idle, pwm_idle, wrench_idle = _idle(), _idle(kind="pwm", level=1500.0), _idle(kind="tau", k=6)
    out = unexcited_runs([flown, idle, pwm_idle, wrench_idle], P)
    assert out[0] is None
    assert [u.run for u in out[1:]] == ["idle.csv"] * 3
    assert all(u.max_command <= UNEXCITED_COMMAND for u in out[1:])
    assert out[1].depth_span_m == pytest.approx(np.ptp(idle.channels["z"]))
    # a command of 5 % of a thruster's capacity is an input, however small the motion it causes
    small = _idle(level=0.05 * float(np.max(P.f_max)))
    assert unexcited_runs([small], P) == [None]


def test_a_diagnosis_of_unexcited_runs_only_says_so(tmp_path, capsys):
    run = write_run(tmp_path / "idle.csv", *(lambda r: (r.t, r.channels, "pwm", r.inputs))(
        _idle(kind="pwm", level=1500.0)))
    out = tmp_path / "r.json"
    assert main(["diagnose", "--model", "pendulum:chin", "--json", str(out), "--quiet", str(run)]) == 0
    report = json.loads(out.read_text())
    assert report["effects"] == [] and report["location"] == [] and report["gap_before"]["value"] is None
    assert [u["run"] for u in report["unexcited_runs"]] == ["idle.csv"]
    assert report["verdict"].startswith("not diagnosed: no run is excited")
    text = capsys.readouterr().out
    assert "not diagnosed: idle.csv: no excitation" in text and "effects (ranked)" not in text


def test_an_unexcited_run_is_left_out_of_a_diagnosis_of_excited_ones():
    a, _ = simulate(duration=30.0, seed=1)
    b, _ = simulate(duration=30.0, seed=2)
    report, ctx = diagnose("pendulum:chin", [a, _idle()], [b], effects=["buoyancy_offset"])
    assert [u["run"] for u in report["unexcited_runs"]] == ["idle.csv"]
    assert report["fit_runs"] == ["nominal_1.csv"] and report["holdout_runs"] == ["nominal_2.csv"]
    assert any(n.startswith("not diagnosed (no excitation): idle.csv") for n in report["notes"])
    assert "not diagnosed: idle.csv" in summary(report)


@pytest.mark.skipif(not BENCH_LOG.exists(), reason="shared data (../shared/data) not present")
def test_the_shared_bench_log_with_every_pwm_at_neutral_is_reported_unexcited():
    from udrobot_ctrl.convert import load_any

    run = load_any(BENCH_LOG, "ardusub")
    report, _ = diagnose("bluerov2-heavy", [run])
    (u,) = report["unexcited_runs"]
    assert u["max_command_fraction"] == 0.0 and u["depth_span_m"] < 0.02
    (s,) = report["unrepresented_runs"]  # and it lies at the surface the whole time: the converter kept no row
    assert s["run"] == u["run"] and s["invalid_share"]["at or near the surface (z < 0.3 m, assumed threshold)"] == 1
    assert "not represented by the plant and no excitation" in report["verdict"]
    assert report["verdict"].startswith("not diagnosed") and report["effects"] == []


def test_a_wrench_on_a_model_without_thrusters_is_an_input():
    """A vehicle logged after its allocation (tau_* on a model with no thrusters, as the Tartan AUV's): the model
    gives no capacity to compare the wrench with, so any non-zero wrench excites the run; an all-zero one does not."""
    no_thrusters = dataclasses.replace(P, T=np.zeros((6, 0)), f_min=np.zeros(0), f_max=np.zeros(0))
    commanded, idle = _idle(kind="tau", k=6, level=2.0), _idle(kind="tau", k=6)
    out = unexcited_runs([commanded, idle], no_thrusters)
    assert out[0] is None and out[1] is not None and out[1].max_command == 0.0


SURFACE = "at or near the surface (z < 0.3 m, assumed threshold)"


def test_a_run_the_converter_kept_no_stretch_of_is_left_out_of_a_diagnosis():
    """A run whose sidecar says no row passed the converter's checks (``cut.kept`` null; ardusub_log_tools/small.tlog:
    the whole log at the surface, 94 % disarmed) is reported, not diagnosed, however well its thrusters were swept;
    a run with a kept stretch, or without a cut record (a pool CSV), is diagnosed."""
    a, _ = simulate(duration=30.0, seed=1)
    b, _ = simulate(duration=30.0, seed=2)
    c, _ = simulate(duration=30.0, seed=3)
    c = dataclasses.replace(c, path="surface.csv", metadata={
        **c.metadata, "cut": {"invalid_share": {SURFACE: 1.0, "disarmed (armed = 0)": 0.94}, "kept": None}})
    kept = dataclasses.replace(b, metadata={**b.metadata, "cut": {
        "invalid_share": {SURFACE: 0.2}, "kept": {"t_start": 6.0, "t_stop": 36.0, "rows": [120, 720], "of": 900}}})
    assert unrepresented_runs([a, kept]) == [None, None]
    (u,) = unrepresented_runs([c])
    assert u.run == "surface.csv" and "100 % of the rows" in u.reason() and "94 % of the rows" in u.reason()
    report, _ = diagnose("pendulum:chin", [a, c], [b], effects=["buoyancy_offset"])
    assert [x["run"] for x in report["unrepresented_runs"]] == ["surface.csv"] and report["unexcited_runs"] == []
    assert report["fit_runs"] == ["nominal_1.csv"] and report["holdout_runs"] == ["nominal_2.csv"]
    assert any(n.startswith("not diagnosed (not represented by the plant): surface.csv") for n in report["notes"])
    assert "not diagnosed: surface.csv: not represented by the plant" in summary(report)
