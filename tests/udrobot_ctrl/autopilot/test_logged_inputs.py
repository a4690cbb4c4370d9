"""The autopilot's logged inputs as the closed loop reads them (issue 62): one missing RC column centres that channel
alone, targets missing between logged ones are held and said so, and a log's damaged parameter records are left out
with a note (autopilot.params.parameter_problems, the one check)."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.ardusub.params import ParameterError, check_log_params, parameter_problems, usable_log_params
from udrobot_ctrl.autopilot.fly import LoggedCommands, fly
from udrobot_ctrl.autopilot.motors import MotorParameters, frame
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model

HEAVY = "bluerov2-heavy"


def _run(mode, extra, seconds=2.0, dt=0.02):
    t = np.arange(0.0, seconds, dt)
    channels = {c: np.full(t.size, 5.0 if c == "z" else 0.0) for c in STATE_NAMES}
    return Run(path="run.csv", t=t, channels=channels, input_kind="pwm", inputs=np.full((t.size, 8), 1500.0),
               extra={"mode": np.full(t.size, float(mode)), **extra}, metadata={"vehicle": HEAVY})


def _sticks(t, forward=1700.0):
    rc = {f"rcin_{i}": np.full(t.size, 1500.0) for i in range(1, 9)}
    rc["rcin_5"] = np.where(t > 0.2, forward, 1500.0)  # forward stick pushed
    return rc


def test_one_missing_rc_column_centres_that_channel_only():
    """Without rcin_3 the other seven were dropped with it (no forward from the pushed stick); now the flight is the
    one with rcin_3 logged at 1500 us, and the note names the channel."""
    t = np.arange(0.0, 2.0, 0.02)
    full = _run(Mode.STABILIZE, _sticks(t))
    partial = _run(Mode.STABILIZE, {k: v for k, v in _sticks(t).items() if k != "rcin_3"})
    a, b = fly(HEAVY, full, loop_rate_hz=100.0), fly(HEAVY, partial, loop_rate_hz=100.0)
    np.testing.assert_array_equal(a.x, b.x)
    assert a.x[-1, 6] > 0.05  # the pushed forward stick moved the vehicle forward (u, m/s)
    assert any("no rcin_3 column(s)" in n for n in b.notes)
    assert not any("rcin" in n for n in a.notes)


def test_a_target_gap_between_logged_targets_is_held_and_counted():
    """Empty target cells in GUIDED hold the last logged target (not zero), and the note counts the rows."""
    t = np.arange(0.0, 2.0, 0.02)
    roll = np.where(t > 0.5, 0.2, 0.0)
    gappy = roll.copy()
    gappy[40:60] = np.nan  # 0.8-1.2 s: empty cells after a logged 0.2 rad
    base = {"pitch_target": np.zeros(t.size), "yaw_target": np.zeros(t.size), "z_target": np.full(t.size, 5.0)}
    held = dict(base, roll_target=gappy)
    full = dict(base, roll_target=roll)
    fr = frame("VECTORED_6DOF")
    motors = dataclasses.replace(MotorParameters(), directions=(1,) * fr.n_motors)
    p = plant_parameters(load_model(HEAVY))
    c = LoggedCommands.from_run(_run(Mode.GUIDED, held), fr, motors, p.supply_voltage)
    np.testing.assert_array_equal(c.attitude_target[:, 0], roll)
    assert c.notes == ("closed loop: roll_target empty in 20 of 100 rows flown on the logged targets (GUIDED): the "
                       "last logged target is held there",)
    a, b = fly(HEAVY, _run(Mode.GUIDED, full), loop_rate_hz=100.0), fly(HEAVY, _run(Mode.GUIDED, held),
                                                                       loop_rate_hz=100.0)
    np.testing.assert_array_equal(a.x, b.x)


def test_surftrak_without_a_depth_target_keeps_its_documented_stand_in():
    """SURFTRAK's depth law is not emulated; without a logged depth target it holds its target (said so): not a
    refusal, unlike GUIDED."""
    t = np.arange(0.0, 1.0, 0.02)
    att = {f"{a}_target": np.zeros(t.size) for a in ("roll", "pitch", "yaw")}
    flight = fly(HEAVY, _run(Mode.SURFTRAK, att, seconds=1.0), loop_rate_hz=100.0)
    assert any("no logged depth target" in n for n in flight.notes)


@pytest.mark.parametrize("params,code", [({"SCHED_LOOP_RATE": 1e5}, "out_of_range"),
                                         ({"ATC_RAT_YAW_I": -0.1}, "negative"),
                                         ({"RC3_MIN": 1900.0, "RC3_MAX": 1100.0}, "inconsistent"),
                                         ({"X": "fast"}, "not_a_number"), ({"X": float("inf")}, "not_finite")])
def test_problems_carry_a_structured_code_and_usable_params_drop_them(params, code):
    problems = parameter_problems(params)
    assert [p.code for p in problems] == [code]
    kept, _ = usable_log_params({**params, "ATC_RAT_RLL_P": 0.135})
    assert kept == {"ATC_RAT_RLL_P": 0.135}  # an inconsistent RC channel loses all its calibration
    with pytest.raises(ParameterError, match="^sidecar: parameter"):
        check_log_params(params, "sidecar")


def test_convert_drops_impossible_ekf_velocities_and_damaged_parameter_records(tmp_path):
    """A LOCAL_POSITION_NED vx of 1e30 m/s (beyond EKF3's 500 m/s state limit) and a SCHED_LOOP_RATE record of 1e5
    were written on; now both are left out with a note, and the sidecar's parameters pass the reader's check."""
    from tests.udrobot_ctrl.io.test_field_logs import _mav, dive_tlog
    from udrobot_ctrl.convert import convert_log
    from udrobot_ctrl.io.runlog import read_run, write

    mav = _mav()
    ev = [(t + 0.001, mav.local_position_ned_encode(int(t * 1000), 0.0, 0.0, 2.0, 1e30 if k == 50 else 0.2, 0.0,
                                                    0.0)) for k, t in enumerate(np.arange(0.02, 20.0, 0.1))]
    log = dive_tlog(tmp_path / "spike.tlog", lambda t: 2.0, duration=20.0, extra=ev,
                    params={"SCHED_LOOP_RATE": 1e5, "ATC_RAT_RLL_P": 0.2, "FRAME_CONFIG": 2})
    run = convert_log(log, "ardusub", cut=False)
    notes = run.metadata["notes"]
    assert "LOCAL_POSITION_NED.vx: 1 of 200 samples beyond the EKF's velocity limit of +-500 m/s" in notes
    assert "parameter SCHED_LOOP_RATE = 100000: expected 50 to 400 Hz" in notes
    assert "SCHED_LOOP_RATE" not in run.metadata["autopilot_params"]
    assert run.metadata["autopilot_params"]["FRAME_CONFIG"] == 2.0
    speed = np.sqrt(sum(run.channels[c] ** 2 for c in "uvw"))
    ok = np.isfinite(speed)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(speed[ok], 0.2, atol=1e-3)  # the 0.2 m/s as logged; the damaged sample is a gap
    again = read_run(write(run, tmp_path / "spike.csv"))
    assert again.metadata["autopilot_params"] == run.metadata["autopilot_params"]


SHARED = Path(os.environ.get("UDROBOT_SHARED", Path(__file__).resolve().parents[3] / ".." / "shared")) / "data"
REAL_LOGS = [SHARED / "ardusub_log_tools" / "small.BIN", SHARED / "ardusub_log_tools" / "small.tlog",
             SHARED / "guided_above_terrain" / "00000029_filtered.BIN"]


@pytest.mark.parametrize("log", REAL_LOGS, ids=lambda p: p.name)
def test_real_logs_parameters_and_context_pass_the_checks(log):
    """The real logs convert with no parameter record left out and no velocity dropped, and their closed-loop inputs
    are read without a refusal (GUIDED and SURFTRAK rows of the sea dive carry their targets)."""
    if not log.exists():
        pytest.skip("shared data absent")
    from udrobot_ctrl.convert import convert_log

    run = convert_log(log, "ardusub")
    notes = run.metadata["notes"]
    assert "parameters: " not in notes and "velocity limit" not in notes
    for key in ("autopilot_params", "autopilot_params_estimated"):
        assert parameter_problems(run.metadata.get(key, {})) == []
    fr = frame("VECTORED_6DOF" if run.inputs.shape[1] == 8 else "VECTORED")
    motors = dataclasses.replace(MotorParameters(), directions=(1,) * fr.n_motors)
    commands = LoggedCommands.from_run(run, fr, motors, 16.0)
    assert commands.rcin is not None and commands.notes == ()


def test_validate_read_log_leaves_a_damaged_loop_rate_record_out(tmp_path):
    """validate.read_log (the emulation check and the converter's gain estimate) took 1 / SCHED_LOOP_RATE as its tick:
    a record of 1e5 made a 10 us tick (a run of hours); now the record is left out with its problem kept, and the
    tick is ArduSub's 400 Hz (MAIN_LOOP_RATE) as for a log without the parameter."""
    from tests.udrobot_ctrl.io.test_ardusub_dive import write_dataflash
    from udrobot_ctrl.autopilot.validate import read_log

    records = [("PARM", (0, b"SCHED_LOOP_RATE", 1e5)), ("PARM", (1, b"ATC_RAT_RLL_P", 0.2))]
    records += [("MODE", (int(t * 1e6), 19, 19, 0)) for t in (0.5,)]
    log = read_log(write_dataflash(tmp_path / "d.bin", records))
    assert log.loop_dt == pytest.approx(1.0 / 400.0)
    assert "SCHED_LOOP_RATE" not in log.params and log.params["ATC_RAT_RLL_P"] == pytest.approx(0.2)
    assert [p.code for p in log.param_problems] == ["out_of_range"]
