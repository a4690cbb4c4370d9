"""The converter's reading of logged values no vehicle writes as a command or a measurement (issue 62): a silent
motor output, a damaged pulse, a battery voltage from a vehicle without a monitor."""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.convert import silent_outputs, unmeasured_voltage
from udrobot_ctrl.io.runlog import Run


def _run(pwm, volts=None):
    t = np.arange(len(pwm)) * 0.1
    channels = {} if volts is None else {"voltage": np.asarray(volts, float)}
    return Run(path="log.csv", t=t, channels=channels, input_kind="pwm", inputs=np.asarray(pwm, float), extra={},
               metadata={})


def test_a_silent_output_is_a_stopped_motor_and_a_damaged_pulse_is_not_logged():
    run = _run([[1500.0, 0.0], [1600.0, 0.0], [65535.0, 1550.0]])
    note = silent_outputs(run)
    np.testing.assert_array_equal(run.inputs[:, 1], [1500.0, 1500.0, 1550.0])  # 0 us: no thrust
    assert np.isnan(run.inputs[2, 0]) and run.inputs[1, 0] == 1600.0
    assert "pwm_2: 2 at 0 us" in note and "pwm_1: 1 outside 500..2200 us" in note
    assert silent_outputs(_run([[1500.0, 1400.0]])) == ""


def test_a_voltage_no_battery_has_is_read_as_not_measured():
    run = _run([[1500.0]] * 4, volts=[15.2, 0.0, 65.535, 15.1])
    note = unmeasured_voltage(run)
    np.testing.assert_array_equal(np.isnan(run.channels["voltage"]), [False, True, True, False])
    assert "2 of 4 samples outside 0..60 V" in note and "65.535" in note
    assert unmeasured_voltage(_run([[1500.0]], volts=[15.0])) == ""
