"""Actuation check (udrobot_ctrl.autopilot.actuation) on runs simulated with the project's own plant, driven by
ArduSub's mixer: it must agree when the log is right and say "reversed" when directions are flipped."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.autopilot.actuation import VERDICTS, actuation_check
from udrobot_ctrl.autopilot.motors import MotorParameters, frame_of_vehicle, motor_pwm
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.io.runlog import Run, read_run
from udrobot_ctrl.vehicle import load_model

SHARED = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"
VOLTAGE = 14.8


def _simulated_run(name, seconds=90.0, dt=0.02, seed=3):
    """A run of ``name`` driven open loop by ArduSub's mixer from random inputs held 1 s, as a converter writes it."""
    vehicle = load_model(name)
    fr = frame_of_vehicle(vehicle)
    rng = np.random.default_rng(seed)
    n, hold = int(round(seconds / dt)), int(round(1.0 / dt))
    u = rng.uniform(-0.15, 0.15, (n // hold + 1, 6))
    pwm = np.repeat(motor_pwm(fr, u, MotorParameters.default(fr.n_motors)), hold, axis=0)[:n]
    x0 = np.zeros(12)
    x0[2] = 5.0
    res = simulate(vehicle, x0, seconds, inputs=pwm_to_thrust(pwm, VOLTAGE), dt=dt)
    channels = {s: res.x[:-1, i] for i, s in enumerate(STATE_NAMES)}
    channels["voltage"] = np.full(n, VOLTAGE)
    return vehicle, Run("", res.t[:-1], channels, "pwm", pwm)


def _flipped(run, motors):
    pwm = run.inputs.copy()
    pwm[:, list(motors)] = 3000.0 - pwm[:, list(motors)]
    return Run(run.path, run.t, run.channels, "pwm", pwm)


@pytest.fixture(scope="module")
def heavy():
    return _simulated_run("bluerov2-heavy")


@pytest.mark.slow
def test_agrees_on_every_excited_dof_and_thruster(heavy):
    vehicle, run = heavy
    check = actuation_check(run, vehicle)
    excited = [d for d in check.dofs if d.verdict != "not excited"]
    assert len(excited) == 6
    assert all(d.verdict == "agrees" for d in excited), check.table()
    # the fitted gain is of the order of the model's 1/(m + added mass)
    assert all(0.3 < d.gain_ratio < 1.5 for d in excited), check.table()
    assert all(c.verdict == "agrees" for c in check.thrusters), check.table()
    assert all(d.verdict in VERDICTS for d in check.dofs)


@pytest.mark.slow
def test_one_flipped_thruster_is_named_reversed(heavy):
    vehicle, run = heavy
    check = actuation_check(_flipped(run, [4]), vehicle)
    verdicts = [c.verdict for c in check.thrusters]
    assert verdicts[4] == "reversed", check.table()
    assert all(v == "agrees" for i, v in enumerate(verdicts) if i != 4), check.table()
    # the DOFs motor 5 serves lose most of their gain (the three other verticals still outweigh it)
    assert check.dof("Z").gain_ratio < 0.5 * actuation_check(run, vehicle).dof("Z").gain_ratio


@pytest.mark.slow
def test_all_thrusters_flipped_reverses_every_excited_dof(heavy):
    vehicle, run = heavy
    check = actuation_check(_flipped(run, range(8)), vehicle)
    excited = [d for d in check.dofs if d.verdict != "not excited"]
    assert excited and all(d.verdict == "reversed" for d in excited), check.table()


def test_not_excited_and_bad_input():
    vehicle, run = _simulated_run("bluerov2", seconds=30.0)
    still = Run("", run.t, run.channels, "pwm", np.full_like(run.inputs, 1500.0))
    check = actuation_check(still, vehicle)
    assert all(d.verdict == "not excited" for d in check.dofs), check.table()
    with pytest.raises(ValueError, match="thrusters"):
        actuation_check(run, load_model("bluerov2-heavy"))


@pytest.mark.slow
@pytest.mark.skipif(not (SHARED / "ardusub_log_tools" / "small.tlog").exists(), reason="shared data absent")
def test_runs_on_a_real_bluerov2_heavy_tlog(tmp_path):
    out = tmp_path / "small.csv"
    subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "convert", str(SHARED / "ardusub_log_tools" /
                    "small.tlog"), "--mapping", "ardusub", "--out", str(out)], check=True, capture_output=True)
    run = read_run(out)
    check = actuation_check(run, load_model("bluerov2-heavy"))
    assert [d.dof for d in check.dofs] == ["X", "Y", "Z", "K", "M", "N"]
    assert all(d.verdict in VERDICTS for d in check.dofs)
    assert not any(d.verdict == "reversed" for d in check.dofs), check.table()
