"""``diagnose --out-model``: the significant effects become part of the plant a user redesigns on."""
from __future__ import annotations

import json

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import Actuators, simulate
from udrobot_ctrl.gap.report import corrected_model
from udrobot_ctrl.io.runlog import Run, write_run
from udrobot_ctrl.vehicle import load_model, read_model_file, to_model_dict

from .truth import generate, random_magnitudes


@pytest.fixture(scope="module")
def buoyancy_files(tmp_path_factory):
    """Three truth runs with a withheld buoyancy offset, diagnosed by the CLI with ``--out-model`` (the last run is
    held out): (runs, run files, report, corrected model file)."""
    rng = np.random.default_rng(104)
    truth = {"buoyancy_offset": random_magnitudes("buoyancy_offset", rng)}
    runs = generate(truth, n_runs=3, duration=90.0, rate=20.0, seed=4)
    d = tmp_path_factory.mktemp("buoyancy")
    files = [write_run(d / r.path, r.t, r.channels, r.input_kind, r.inputs,
                       metadata={k: v for k, v in r.metadata.items() if k != "format"}) for r in runs]
    report_path, model_path = d / "report.json", d / "corrected.json"
    assert main(["diagnose", "--model", "pendulum:chin", "--json", str(report_path), "--out-model", str(model_path),
                 "--quiet", *map(str, files)]) == 0
    return runs, files, json.loads(report_path.read_text()), model_path


@pytest.fixture(scope="module")
def buoyancy_case(buoyancy_files):
    runs, _, report, _ = buoyancy_files
    return runs, report


# The report rounds every number to 6 decimals (its gap values and the fitted parameters the corrected model
# takes): the value itself is within 5e-7 of the unrounded gap, and a parameter rounded by at most 5e-7 moves the
# gap by |d gap / d theta| x 5e-7, below 1e-6 for dB ~ 1 N whose whole effect is gap_before - gap_after < 1.
# Everything else (prepared runs, hooks, integrator, metric) is the same code on the same numbers.
REPLAY_TOL = 2e-6


@pytest.mark.slow
def test_windowed_simulate_with_the_corrected_model_reproduces_gap_after(buoyancy_files, tmp_path, capsys):
    runs, files, report, model_path = buoyancy_files
    assert report["holdout_runs"] == [files[-1].name]
    out = tmp_path / "gap.json"
    assert main(["simulate", "--model", str(model_path), "--input", str(files[-1]), "--windows", "8",
                 "--json", str(out)]) == 0
    g = json.loads(out.read_text())
    assert g["effects"] == [e["name"] for e in report["effects"] if e["significant"]] != []
    assert g["value"] == pytest.approx(report["gap_after"]["value"], abs=REPLAY_TOL)
    assert g["scored"] == report["gap_after"]["scored"]
    for c, v in report["gap_after"]["per_channel"].items():
        assert g["per_channel"][c] == pytest.approx(v, abs=REPLAY_TOL), c
    assert f"{report['gap_after']['value']:.6f}" in capsys.readouterr().out
    # the nominal model gives gap_before: the windowed replay is the report's, not just close to one number
    assert main(["simulate", "--model", "pendulum:chin", "--input", str(files[-1]), "--windows"]) == 0
    assert f"{report['gap_before']['value']:.6f}" in capsys.readouterr().out
    assert report["gap_after"]["value"] < 0.8 * report["gap_before"]["value"]


@pytest.mark.slow
def test_corrected_model_carries_the_significant_effects(buoyancy_case, tmp_path):
    runs, report = buoyancy_case
    sig = {e["name"]: e["params"] for e in report["effects"] if e["significant"]}
    assert "buoyancy_offset" in sig
    v, not_placed = corrected_model("pendulum:chin", report, runs)
    assert not_placed == {}
    assert {e.name: dict(e.params) for e in v.effects} == sig
    path = tmp_path / "corrected.json"
    path.write_text(json.dumps(to_model_dict(v)))
    back = read_model_file(path)
    assert back.effects == v.effects and "effects.buoyancy_offset" in back.provenance
    p0, p1 = plant_parameters(load_model("pendulum:chin")), plant_parameters(back)
    assert p1.buoyancy - p0.buoyancy == pytest.approx(sig["buoyancy_offset"]["dB_N"])


@pytest.mark.slow
def test_corrected_plant_settles_at_the_heave_speed_of_its_fitted_net_buoyancy(buoyancy_case):
    """Open loop from rest the corrected plant drifts in heave until its damping balances the net buoyancy
    B + dB - W (D_L w + Q |w| w = W - B'), the fitted dB included."""
    runs, report = buoyancy_case
    v, _ = corrected_model("pendulum:chin", report, runs)
    p = plant_parameters(v)
    res = simulate(v, np.r_[0, 0, 1.0, np.zeros(9)], 40.0, dt=0.02)
    dl, q, net = p.D_L[2, 2], p.Q[2, 2], p.weight - p.buoyancy
    w_terminal = np.sign(net) * (-dl + np.sqrt(dl ** 2 + 4 * q * abs(net))) / (2 * q) if q > 0 else net / dl
    assert res.x[-1, 8] == pytest.approx(w_terminal, rel=0.03)
    nominal = plant_parameters(load_model("pendulum:chin"))
    assert abs(net - (nominal.weight - nominal.buoyancy)) > 0.5  # the fitted offset is not negligible


def test_thrust_maps_fitted_on_a_commanded_wrench_are_not_placed_and_said_so():
    runs = [Run(path="w.csv", t=np.arange(3.0), channels={}, input_kind="tau", inputs=np.zeros((3, 6)), extra={},
                metadata={})]
    report = {"fit_runs": ["w.csv"], "holdout_runs": ["w.csv"], "effects": [
        {"name": "cg_cb_offset", "significant": True, "shrink": 0.6,
         "params": {"dBG_x_Nm": -5.5, "dBG_y_Nm": 1.0, "dBG_z_Nm": -5.3}},
        {"name": "thruster_deadband", "significant": True, "shrink": -0.1,
         "params": {"width_fraction": 0.25, **{f"shift_{d}": 1.0 for d in "XYZKMN"}}}]}
    v, not_placed = corrected_model("pendulum:chin", report, runs)
    assert [e.name for e in v.effects] == ["cg_cb_offset"]
    assert set(not_placed) == {"thruster_deadband"} and "commanded wrench" in not_placed["thruster_deadband"]
    assert v.provenance["effects.thruster_deadband"].startswith("not placed")


def test_fitted_thruster_exponents_reach_the_model_file_and_the_simulator(tmp_path):
    """A fitted rotor-speed lag (thrust_exponent) and command-domain deadband (command_exponent) are written with their
    exponents, read back, and simulated with them: the model file's thrust at the step's T differs from a thrust
    lag's (F (1 - 1/e)^2 against F (1 - 1/e))."""
    runs = [Run(path="r.csv", t=np.arange(3.0), channels={}, input_kind="thrust", inputs=np.zeros((3, 4)), extra={},
                metadata={})]
    lag = {"T_lag_s": 0.4, "thrust_exponent": 2.0}
    deadband = {"width_fraction": 0.2, "command_exponent": 1.8, "shift": 0.9}
    report = {"fit_runs": ["r.csv"], "holdout_runs": ["r.csv"], "effects": [
        {"name": "thruster_lag", "significant": True, "shrink": 0.9, "params": lag},
        {"name": "thruster_deadband", "significant": True, "shrink": 0.9, "params": deadband}]}
    v, not_placed = corrected_model("pendulum:chin", report, runs)
    assert not not_placed
    path = tmp_path / "corrected.json"
    path.write_text(json.dumps(to_model_dict(v)))
    back = {e.name: dict(e.params) for e in read_model_file(path).effects}
    assert back == {"thruster_lag": lag, "thruster_deadband": deadband}
    p = plant_parameters(read_model_file(path).with_changes(
        effects=tuple(e for e in read_model_file(path).effects if e.name == "thruster_lag")))
    dt, F = 0.001, 20.0
    act = Actuators(p, dt)
    u = np.zeros(4)
    act.delivered(u)
    u[0] = F
    for _ in range(400):  # 0.4 s = T
        f = act.delivered(u)
    assert f[0] == pytest.approx(F * (1 - np.exp(-1.0)) ** 2, rel=1e-9)
