"""``simulate --closed-loop`` refuses a run the converter kept no row of (its sidecar's ``cut.kept`` null: the whole
log at the surface, disarmed or upside down) instead of flying the model's own drift against a vehicle that floats.

A disarmed ArduSub holds its motors at neutral (AP_Motors6DOF::output_to_motors, SHUT_DOWN: 1500 us), so the flight
is the plant's free drift at its net buoyancy; the plant has no free surface, so a floating vehicle's log (the
``ardusub_log_tools`` logs: 100 % at the surface, 94 % disarmed) has nothing that flight can be compared with.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.dynamics.domain import idle_drift
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.screen import unrepresented_runs
from udrobot_ctrl.io.runlog import read_run, write_run
from udrobot_ctrl.vehicle import load_model

HEAVY = "bluerov2-heavy"
SURFACE_CHECK = "at or near the surface (z < 0.3 m, assumed threshold)"
SHARED = Path(os.environ.get("UDROBOT_SHARED", Path(__file__).resolve().parents[3] / ".." / "shared")) / "data"


def floating_run(path, seconds=10.0, dt=0.02, cut=True):
    """A converted-like Heavy run of a disarmed vehicle floating at the waterline (2 cm deep, still, motors at
    1500 us, centred sticks, MANUAL); with ``cut`` the sidecar says the converter kept no row of it."""
    t = np.arange(0.0, seconds, dt)
    states = {c: np.zeros_like(t) for c in STATE_NAMES}
    states["z"] = np.full(t.size, 0.02)
    extra = {"mode": np.full(t.size, float(Mode.MANUAL)), "armed": np.zeros(t.size),
             **{f"rcin_{i}": np.full(t.size, 1500.0) for i in range(1, 9)}}
    meta = {"vehicle": HEAVY}
    if cut:
        meta["cut"] = {"invalid_share": {SURFACE_CHECK: 1.0, "disarmed (armed = 0)": 1.0}, "kept": None}
    return write_run(path, t, states, "pwm", np.full((t.size, 8), 1500.0), extra=extra, metadata=meta)


def flown(argv, capsys):
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def test_a_floating_disarmed_log_is_refused_closed_loop_naming_the_drift_and_nothing_is_written(tmp_path, capsys):
    run = floating_run(tmp_path / "float.csv")
    out = tmp_path / "cl.csv"
    code, err = flown(["simulate", "--closed-loop", "--loop-rate", "50", "--model", HEAVY, "--input", run,
                       "--out", out], capsys)
    assert code == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    drift = idle_drift(plant_parameters(load_model(HEAVY)))
    assert drift.speed > 0  # the Heavy model is heavy: disarmed, it sinks where the logged vehicle floats
    for words in ("not represented by the plant", SURFACE_CHECK, "--closed-loop does not fly it", "no free surface",
                  f"sink at {drift.speed:.2g} m/s", "convert --no-cut"):
        assert words in err, err
    assert not out.exists() and not out.with_suffix(".json").exists()


def test_the_same_log_without_a_cut_record_is_flown_and_drifts_as_the_refusal_says(tmp_path, capsys):
    """convert --no-cut's run (no cut record) is flown as it is: disarmed, the emulated motors stay at neutral and the
    model sinks from the waterline at the terminal speed the refusal names; the open loop still replays the cut run
    with its warning."""
    run = floating_run(tmp_path / "nocut.csv", seconds=12.0, cut=False)
    out = tmp_path / "cl.csv"
    code, err = flown(["simulate", "--closed-loop", "--loop-rate", "50", "--model", HEAVY, "--input", run,
                       "--out", out], capsys)
    assert code == 0, err
    sim = read_run(out)
    np.testing.assert_array_equal(sim.inputs, 1500.0)  # disarmed: AP_Motors6DOF's neutral on every motor
    drift = idle_drift(plant_parameters(load_model(HEAVY)))
    assert sim.channels["w"][-1] == pytest.approx(drift.speed, rel=0.02)
    assert sim.channels["z"][-1] > 0.02 + 0.5 * drift.over(sim.duration)  # it left the surface the log holds
    cut = floating_run(tmp_path / "cut.csv")
    code, err = flown(["simulate", "--model", HEAVY, "--input", cut, "--out", tmp_path / "ol.csv"], capsys)
    assert code == 0 and "not represented by the plant" in err


def test_small_tlog_floating_disarmed_is_refused_closed_loop_and_the_sea_dive_is_not(tmp_path, capsys):
    """The real surface log (a BlueROV2 Heavy floating, 94 % disarmed) is refused closed loop; the converter kept
    segments of the sea dive, which is not (its flight: tests of the emulation)."""
    log = SHARED / "ardusub_log_tools" / "small.tlog"
    if not log.exists():
        pytest.skip("shared data absent")
    run = tmp_path / "small.csv"
    assert main(["convert", str(log), "--out", str(run)]) == 0
    capsys.readouterr()
    z = read_run(run).channels["z"]
    assert np.nanmax(z) < 0.1  # the logged vehicle stays at the waterline the whole log
    out = tmp_path / "cl.csv"
    code, err = flown(["simulate", "--closed-loop", "--model", HEAVY, "--input", run, "--out", out], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--closed-loop does not fly it" in err, err
    assert not out.exists()
    dive = SHARED / "guided_above_terrain" / "00000029_filtered.BIN"
    if dive.exists():  # submerged and armed: the converter kept it, so the closed loop flies it as before
        assert unrepresented_runs([convert_log(dive, "ardusub")]) == [None]
