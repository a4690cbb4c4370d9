"""Values from a log, a sidecar or a ``.params`` file are checked once where they enter (issue 62, the validation
layer): ``simulate --closed-loop``, ``diagnose`` and ``design`` refuse the same damaged values with one line naming
the file, the field and what ArduSub documents, and nothing is written."""
from __future__ import annotations

import json

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.io.runlog import write_run

HEAVY = "bluerov2-heavy"


def flyable_run(path, seconds=1.0, dt=0.02, mode=Mode.STABILIZE, extra=None, params=None):
    """A converted-like Heavy run: level at 5 m, centred sticks, motors at 1500 us; ``params`` written into the
    sidecar as they are (bypassing the writer's own check, as a damaged or hand-edited sidecar would)."""
    t = np.arange(0.0, seconds, dt)
    states = {c: np.zeros_like(t) for c in STATE_NAMES}
    states["z"] = np.full(t.size, 5.0)
    columns = {"mode": np.full(t.size, float(mode)), **{f"rcin_{i}": np.full(t.size, 1500.0) for i in range(1, 9)}}
    columns.update(extra or {})
    path = write_run(path, t, states, "pwm", np.full((t.size, 8), 1500.0), extra=columns,
                     metadata={"vehicle": HEAVY})
    if params is not None:
        side = path.with_suffix(".json")
        meta = json.loads(side.read_text())
        meta["autopilot_params"] = params
        side.write_text(json.dumps(meta))
    return path


def refused(argv, capsys, *words):
    """The command exits 2 with one line on stderr holding every one of ``words``."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err, err
    return err


def commands(run, tmp_path):
    """The three consumers of a run's autopilot parameters, each with its output path."""
    return {"simulate": (["simulate", "--closed-loop", "--model", HEAVY, "--input", run, "--out", tmp_path / "o.csv"],
                         tmp_path / "o.csv"),
            "diagnose": (["diagnose", "--model", HEAVY, "--json", tmp_path / "r.json", run], tmp_path / "r.json"),
            "design": (["design", "ardusub", "--model", HEAVY, "--from", run, "--out", tmp_path / "g.params"],
                       tmp_path / "g.params")}


BAD_PARAMS = [  # (parameters, words of the refusal)
    ({"RC3_MIN": 1950.0, "RC3_MAX": 1900.0}, ("RC3_MIN = 1950", "below RC3_MAX = 1900")),
    ({"RC3_MIN": 1900.0, "RC3_MAX": 1900.0, "RC3_TRIM": 1900.0}, ("RC3_MIN = 1900", "below RC3_MAX = 1900")),
    ({"RC3_MIN": 1100.0, "RC3_MAX": 1250.0, "RC3_TRIM": 1100.0, "RC3_DZ": 200.0}, ("RC3_DZ = 200", "spans")),
    ({"RC1_MIN": 1300.0, "RC1_MAX": 1700.0, "RC1_DZ": 200.0}, ("RC1_DZ = 200", "spans")),
    ({"ATC_RAT_RLL_P": -0.1}, ("ATC_RAT_RLL_P = -0.1", "0 or more")),
    ({"ATC_RAT_PIT_IMAX": -1.0}, ("ATC_RAT_PIT_IMAX = -1", "0 or more")),
    ({"PSC_ACCZ_P": -0.5}, ("PSC_ACCZ_P = -0.5", "0 or more")),
    ({"ANGLE_MAX": 0.0}, ("ANGLE_MAX = 0", "1000 to 8000 cdeg")),
    ({"MOT_THST_HOVER": 5.0}, ("MOT_THST_HOVER = 5", "0.2 to 0.8")),
    ({"PILOT_SPEED_UP": 0.0}, ("PILOT_SPEED_UP = 0", "20 to 500 cm/s")),
    ({"SURFACE_DEPTH": 5000.0}, ("SURFACE_DEPTH = 5000", "-100 to 0 cm")),
    ({"SCHED_LOOP_RATE": 0.0}, ("SCHED_LOOP_RATE = 0", "50 to 400 Hz")),
    ({"SCHED_LOOP_RATE": 1e5}, ("SCHED_LOOP_RATE = 100000", "50 to 400 Hz")),
    ({"SCHED_LOOP_RATE": 5e6}, ("SCHED_LOOP_RATE = 5e+06", "50 to 400 Hz")),
    ({"SCHED_LOOP_RATE": 1e9}, ("SCHED_LOOP_RATE = 1e+09", "50 to 400 Hz")),
    ({"ATC_RAT_RLL_P": [0.1, 0.2]}, ("ATC_RAT_RLL_P = [0.1, 0.2]", "expected a number")),
    ({"ATC_RAT_RLL_P": "fast"}, ("ATC_RAT_RLL_P = 'fast'", "expected a number")),
    ({"ATC_RAT_RLL_P": None}, ("ATC_RAT_RLL_P = None", "expected a number")),
    ({"ATC_RAT_RLL_P": True}, ("ATC_RAT_RLL_P = True", "expected a number")),
    ({"ATC_RAT_RLL_P": float("nan")}, ("ATC_RAT_RLL_P = nan", "finite")),
    ({"ATC_RAT_RLL_P": 1e300}, ("ATC_RAT_RLL_P = 1e+300", "finite")),
]


@pytest.mark.parametrize("command", ["simulate", "diagnose", "design"])
@pytest.mark.parametrize("params,words", BAD_PARAMS, ids=[w[0].replace(" ", "") for _, w in BAD_PARAMS])
def test_a_damaged_sidecar_parameter_is_refused_by_every_command(tmp_path, capsys, command, params, words):
    """One check for every consumer: the sidecar's file and field, the parameter and ArduSub's documented domain,
    before any flight (a SCHED_LOOP_RATE of 1e9 was a 2.6 TiB allocation, 0 a ZeroDivisionError)."""
    run = flyable_run(tmp_path / "run.csv", params=params)
    argv, out = commands(run, tmp_path)[command]
    refused(argv, capsys, str(run.with_suffix(".json")), "field 'autopilot_params'", *words)
    assert not out.exists()


def test_the_real_logs_documented_values_pass_the_check(tmp_path, capsys):
    """Values of the real ArduSub 4.1 logs (small.BIN, small.tlog: RC3_TRIM = RC3_MIN = 1100, SURFACE_DEPTH -10,
    MOT_k_DIRECTION -1, typed in here) are inside every domain: the check refuses only what ArduSub cannot hold, and
    the flight runs (the logs themselves: test_logged_inputs.py)."""
    params = {"RC3_MIN": 1100.0, "RC3_TRIM": 1100.0, "RC3_MAX": 1900.0, "RC3_DZ": 30.0, "RC4_DZ": 40.0,
              "SURFACE_DEPTH": -10.0, "MOT_1_DIRECTION": -1.0, "SCHED_LOOP_RATE": 200.0, "ANGLE_MAX": 4500.0,
              "MOT_THST_HOVER": 0.5, "PILOT_SPEED_UP": 500.0, "PILOT_SPEED_DN": 0.0, "FRAME_CONFIG": 2.0,
              "ATC_RAT_RLL_P": 0.135}
    run = flyable_run(tmp_path / "run.csv", params=params)
    assert main(["simulate", "--closed-loop", "--model", HEAVY, "--input", str(run), "--out",
                 str(tmp_path / "o.csv")]) == 0
    assert (tmp_path / "o.csv").exists()


# ------------------------------------------------------------------------------------------------ .params files


def _params_file(path, lines):
    path.write_text("# Onboard parameters for Vehicle 1\n" + "".join(f"{ln}\n" for ln in lines))
    return path


@pytest.mark.parametrize("value,words", [("nan", ("= nan", "finite")), ("inf", ("= inf", "finite")),
                                         ("1e300", ("= 1e+300", "finite")), ("-0.2", ("= -0.2", "0 or more"))])
def test_a_params_file_value_arduSub_cannot_hold_is_refused_naming_its_line(tmp_path, capsys, value, words):
    """NaN, inf or 1e300 in a ``.params`` were taken as 'not in the log' (ArduSub's default) or flown as the gain."""
    f = _params_file(tmp_path / "v.params", ["1\t1\tATC_RAT_YAW_P\t0.18\t9", f"1\t1\tATC_RAT_RLL_P\t{value}\t9"])
    refused(["design", "ardusub", "--model", HEAVY, "--from", f, "--out", tmp_path / "g.params"], capsys,
            f"{f}, line 3", "parameter ATC_RAT_RLL_P", *words)
    assert not (tmp_path / "g.params").exists()


def test_duplicate_names_in_a_params_file_are_refused_naming_both_lines(tmp_path, capsys):
    f = _params_file(tmp_path / "d.params", ["1\t1\tATC_RAT_RLL_P\t0.1\t9", "1\t1\tPSC_ACCZ_P\t0.5\t9",
                                             "1\t1\tATC_RAT_RLL_P\t0.3\t9"])
    refused(["design", "ardusub", "--model", HEAVY, "--from", f, "--out", tmp_path / "g.params"], capsys,
            f"{f}, lines 2 and 4", "ATC_RAT_RLL_P given twice")


def test_an_empty_params_file_is_not_a_parameter_set(tmp_path, capsys):
    f = _params_file(tmp_path / "e.params", ["#", "# # Vehicle-Id Component-Id Name Value Type", ""])
    refused(["design", "ardusub", "--model", HEAVY, "--from", f, "--out", tmp_path / "g.params"], capsys,
            str(f), "no parameter lines")


# ------------------------------------------------------------------------------------------------ modes, targets


@pytest.mark.parametrize("value", [99.0, -1.0, 2.5, 1e300, float("inf")])
@pytest.mark.parametrize("command", ["simulate", "diagnose"])
def test_a_mode_number_arduSub_does_not_have_is_refused_naming_row_and_column(tmp_path, capsys, value, command):
    """Modes 99 and -1 were flown as GUIDED, 2.5 as ALT_HOLD (truncated), without a word."""
    t = np.arange(0.0, 1.0, 0.02)
    mode = np.full(t.size, float(Mode.STABILIZE))
    mode[10:] = value
    run = flyable_run(tmp_path / "run.csv", extra={"mode": mode})
    argv, out = commands(run, tmp_path)[command]
    refused(argv, capsys, str(run), "data row 11 (file line 12)", "column 'mode'", "not an ArduSub flight mode",
            "19 MANUAL")
    assert not out.exists()


@pytest.mark.parametrize("column", ["roll_target", "z_target"])
@pytest.mark.parametrize("how", ["missing", "all empty"])
def test_guided_without_its_logged_targets_is_refused_not_flown_on_zero(tmp_path, capsys, column, how):
    """A GUIDED row flies the logged attitude and depth targets: without them the run was flown at roll 0 / pitch 0
    or on whatever depth the controller held."""
    t = np.arange(0.0, 1.0, 0.02)
    targets = {c: np.zeros(t.size) for c in ("roll_target", "pitch_target", "yaw_target")}
    targets["z_target"] = np.full(t.size, 5.0)
    if how == "missing":
        del targets[column]
    else:
        targets[column] = np.full(t.size, np.nan)
    run = flyable_run(tmp_path / "run.csv", mode=Mode.GUIDED, extra=targets)
    refused(["simulate", "--closed-loop", "--model", HEAVY, "--input", run, "--out", tmp_path / "o.csv"], capsys,
            str(run), f"column '{column}'", "GUIDED", "expected the logged target")
    assert not (tmp_path / "o.csv").exists()


# ------------------------------------------------------------------------------------------------ options


def test_closed_loop_with_windows_is_refused_not_ignored(tmp_path, capsys):
    run = flyable_run(tmp_path / "run.csv")
    refused(["simulate", "--closed-loop", "--windows", "0.5", "--model", HEAVY, "--input", run], capsys,
            "--windows", "--closed-loop", "one or the other")


def test_design_refuses_an_infinite_specification_and_names_the_option(tmp_path, capsys):
    refused(["design", "ardusub", "--model", HEAVY, "--out", tmp_path / "g.params", "--depth-settling", "inf"],
            capsys, "--depth-settling must be a finite number > 0")
    refused(["design", "ardusub", "--model", HEAVY, "--out", tmp_path / "g.params", "--loop-rate", "0"],
            capsys, "--loop-rate must be between 10 and 2000 Hz")
    assert not (tmp_path / "g.params").exists()


def test_design_refuses_a_spread_model_of_another_thruster_count_up_front(tmp_path, capsys):
    refused(["design", "ardusub", "--model", HEAVY, "--spread", "bluerov2", "--out", tmp_path / "g.params"],
            capsys, "--spread bluerov2: 6 thrusters", f"--model {HEAVY} has 8")


def test_design_refuses_a_heavy_logs_parameters_on_a_six_thruster_model(tmp_path, capsys):
    run = flyable_run(tmp_path / "run.csv", params={"FRAME_CONFIG": 2.0, "ATC_RAT_RLL_P": 0.135})
    refused(["design", "ardusub", "--model", "bluerov2", "--from", run, "--out", tmp_path / "g.params"], capsys,
            "FRAME_CONFIG 2 (VECTORED_6DOF) is a 8-thruster vehicle", "--model bluerov2 has 6 thrusters")


def test_a_model_file_with_a_second_effects_key_is_refused(tmp_path, capsys):
    """json keeps the last of two equal keys: the first "effects" list was dropped without a word."""
    assert main(["model", "export", "--model", HEAVY, "--out", str(tmp_path / "m.json")]) == 0
    text = (tmp_path / "m.json").read_text()
    doc = json.loads(text)
    first = '"effects": [{"name": "tether_drag", "cd_a": 0.01}], '
    bad = tmp_path / "dup.json"
    bad.write_text(text.replace("{", "{" + first + '"effects": [], ', 1))
    assert "effects" not in doc or doc["effects"] == []
    run = flyable_run(tmp_path / "run.csv")
    refused(["simulate", "--model", bad, "--input", run, "--out", tmp_path / "o.csv"], capsys,
            str(bad), "key 'effects' given twice")


@pytest.mark.parametrize("value,words", [(0.0, ("0 us", "'no pulse'", "500..2200 us")),
                                         (65535.0, ("65535 us", "500..2200 us"))])
@pytest.mark.parametrize("command", ["simulate", "diagnose"])  # design --from reads the sidecar, not the samples
def test_an_esc_pulse_outside_the_servo_range_is_refused_naming_row_and_column(tmp_path, capsys, value, words,
                                                                               command):
    """``pwm 0`` (a disabled output's "no pulse") was clipped to the curve's 1100 us: full reverse thrust."""
    run = flyable_run(tmp_path / "run.csv", params={"ATC_RAT_RLL_P": 0.135})
    text = run.read_text().splitlines()
    header = text[0].split(",")
    cells = text[7].split(",")
    cells[header.index("pwm_3")] = f"{value:g}"
    text[7] = ",".join(cells)
    run.write_text("\n".join(text) + "\n")
    before = run.read_bytes()
    argv, out = commands(run, tmp_path)[command]
    refused(argv, capsys, str(run), "data row 7 (file line 8)", "column 'pwm_3'", *words)
    assert not out.exists() and run.read_bytes() == before


@pytest.mark.parametrize("value", [1e6, 0.0, -12.0, 61.0])
def test_a_battery_voltage_no_small_rov_has_is_refused(tmp_path, capsys, value):
    """A voltage of 1e6 V scaled every thrust of the replay by the curve's power law, without a word."""
    t = np.arange(0.0, 1.0, 0.02)
    volts = np.full(t.size, 15.5)
    volts[20] = value
    run = tmp_path / "run.csv"
    states = {c: np.zeros_like(t) for c in STATE_NAMES}
    states["z"] = np.full(t.size, 5.0)
    write_run(run, t, {**states, "voltage": volts}, "pwm", np.full((t.size, 8), 1500.0), metadata={"vehicle": HEAVY})
    refused(["simulate", "--model", HEAVY, "--input", run, "--out", tmp_path / "o.csv"], capsys,
            str(run), "data row 21 (file line 22)", "column 'voltage'", f"{value:g} V", "at most 60 V")
    assert not (tmp_path / "o.csv").exists()


def test_a_model_whose_weight_is_not_mass_times_g_is_refused(tmp_path, capsys):
    """A weight of 50 N on a 9.36 kg model flew as a 4 kg vehicle's restoring forces with a 9.36 kg inertia."""
    assert main(["model", "export", "--model", "pendulum:chin", "--out", str(tmp_path / "m.json")]) == 0
    doc = json.loads((tmp_path / "m.json").read_text())
    doc["weight"] = 50.0
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    run = tmp_path / "run.csv"
    t = np.arange(0.0, 0.5, 0.02)
    write_run(run, t, {c: np.zeros_like(t) for c in STATE_NAMES}, "thrust", np.zeros((t.size, 4)))
    refused(["simulate", "--model", bad, "--input", run, "--out", tmp_path / "o.csv"], capsys,
            str(bad), "field 'weight' = 50.0 N", "mass * g", "'buoyancy'")
    doc["weight"] = round(doc["mass"] * doc["g"], 1)  # rounded as the format's example writes it: accepted
    bad.write_text(json.dumps(doc))
    assert main(["simulate", "--model", str(bad), "--input", str(run), "--out", str(tmp_path / "o.csv")]) == 0
