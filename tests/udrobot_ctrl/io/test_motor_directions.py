"""MOT_k_DIRECTION inferred from the logged mixer inputs when the log lacks it (the trimmed sea dive has no
parameters): the reversed motors' PWM is mirrored so that pwm_k > 1500 us is positive thrust in the model."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.autopilot.motors import MotorParameters, frame, motor_pwm, throttle_bidirectional
from udrobot_ctrl.convert import apply_motor_directions
from udrobot_ctrl.io.runlog import Run

TRUE_DIRECTIONS = (-1, -1, 1, 1, -1, 1, 1, -1)


def _logged_run(directions, with_outputs=True, seed=0):
    rng = np.random.default_rng(seed)
    n = 400
    outs = {"out_roll": 0.05 * rng.standard_normal(n), "out_pitch": 0.1 + 0.05 * rng.standard_normal(n),
            "out_yaw": 0.2 * rng.standard_normal(n), "out_throttle": 0.45 + 0.05 * rng.standard_normal(n)}
    forward, lateral = 0.2 * rng.standard_normal(n), 0.2 * rng.standard_normal(n)
    inputs = np.column_stack([outs["out_roll"], outs["out_pitch"], outs["out_yaw"],
                              throttle_bidirectional(outs["out_throttle"]), forward, lateral])
    fr = frame("VECTORED_6DOF")
    pwm = motor_pwm(fr, inputs, MotorParameters(directions=directions))  # what ArduSub writes (integer us)
    run = Run(path="dive.bin", t=np.arange(n) * 0.1, channels={}, input_kind="pwm", inputs=pwm.copy(),
              extra=outs if with_outputs else {}, metadata={"vehicle": "bluerov2-heavy", "notes": ""})
    return run, motor_pwm(fr, inputs, MotorParameters(directions=(1,) * 8))


def test_directions_are_inferred_and_reversed_motors_mirrored():
    run, command_pwm = _logged_run(TRUE_DIRECTIONS)
    note = apply_motor_directions(run, {})
    assert "inferred" in note and "(1: -1, 2: -1, 3: +1, 4: +1, 5: -1, 6: +1, 7: +1, 8: -1)" in note
    # mirrored to the motor-command PWM: within ArduSub's 1 us truncation of either side
    assert np.max(np.abs(run.inputs - command_pwm)) <= 2.0


@pytest.mark.parametrize("directions", [(1,) * 8, (1, -1, 1, -1, 1, -1, 1, -1)])
def test_other_patterns_are_found_too(directions):
    run, command_pwm = _logged_run(directions, seed=3)
    apply_motor_directions(run, {})
    assert np.max(np.abs(run.inputs - command_pwm)) <= 2.0


def test_without_logged_mixer_inputs_the_pwm_is_kept_and_the_note_says_so():
    run, _ = _logged_run(TRUE_DIRECTIONS, with_outputs=False)
    logged = run.inputs.copy()
    note = apply_motor_directions(run, {})
    assert "assumed MOT_k_DIRECTION = +1" in note and "no logged mixer inputs" in note
    np.testing.assert_array_equal(run.inputs, logged)


def test_logged_parameters_win_over_inference():
    run, _ = _logged_run(TRUE_DIRECTIONS)
    params = {f"MOT_{k}_DIRECTION": 1.0 for k in range(1, 9)}
    note = apply_motor_directions(run, params)
    assert "from the log" in note and "inferred" not in note
