"""ArduSub's input side as the firmware computes it (udrobot_ctrl.ardusub.modes, params, depth, ardusub): the RC
channels' ``norm_input`` / ``norm_input_dz`` with the log's trims (the throttle trim at its minimum, as ArduSub
vehicles have it), the manual throttle, ALT_HOLD's climb rate and its saturation handling."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import (
    Mode,
    PilotInput,
    norm_input,
    norm_input_dz,
    pilot_climb_rate,
    pilot_throttle,
    shape_pilot,
)
from udrobot_ctrl.ardusub.params import ArduSubParameters, RCChannel, boot_gain
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, MixerInputs, VehicleState
from udrobot_ctrl.autopilot.motors import frame, motor_pwm
from udrobot_ctrl.autopilot.pid import inv_sqrt_controller

#: a BlueROV2 throttle channel as QGroundControl calibrates it for ArduSub: trim at the minimum
TRIM_AT_MIN = {"RC3_MIN": 1100.0, "RC3_MAX": 1900.0, "RC3_TRIM": 1100.0, "RC3_DZ": 30.0}


def test_norm_input_with_the_trim_at_min_runs_zero_to_one():
    ch = RCChannel(min=1100.0, max=1900.0, trim=1100.0)
    assert norm_input(1100, ch) == 0.0 and norm_input(1500, ch) == 0.5 and norm_input(1900, ch) == 1.0
    assert norm_input(1000, ch) == 0.0                                # below the trim: min >= trim -> 0
    # a centred trim: each side scaled to its own end (asymmetric ends)
    ch = RCChannel(min=1000.0, max=1900.0, trim=1500.0)
    assert norm_input(1250, ch) == -0.5 and norm_input(1700, ch) == 0.5
    assert norm_input(1700, RCChannel(reversed=True)) == -0.5


def test_norm_input_dz_is_zero_inside_the_dead_zone_and_full_at_the_ends():
    ch = RCChannel(min=1100.0, max=1900.0, trim=1500.0, dead_zone=50.0)
    assert norm_input_dz(1549, ch) == 0.0 and norm_input_dz(1451, ch) == 0.0
    assert norm_input_dz(1900, ch) == 1.0 and norm_input_dz(1100, ch) == -1.0
    assert norm_input_dz(1725, ch) == pytest.approx(175 / 350)


@pytest.mark.parametrize("mode", [Mode.MANUAL, Mode.STABILIZE])
def test_a_centred_throttle_stick_is_neutral_with_the_trim_at_min(mode):
    """ArduSub 4.1-4.5 pass norm_input as it is: with RC3_TRIM = RC3_MIN a centred stick is throttle 0.5, neutral
    vertical thrusters (1500 us) -- the (norm + 1) / 2 form would give 0.75 (half up-thrust)."""
    params = ArduSubParameters.from_log_params(TRIM_AT_MIN)
    ap = ArduSubAutopilot(params)
    for _ in range(3):  # the mode's output reaches the mixer on the next tick
        u = ap.step(0.0025, VehicleState(depth=2.0), PilotInput.centred(), mode)
    assert u.throttle == pytest.approx(0.5)
    vertical = motor_pwm(frame("VECTORED"), u.as_array())[4:]
    assert vertical == pytest.approx([1500.0, 1500.0], abs=1.0)
    full_up = PilotInput.from_sticks(throttle=1.0)
    assert shape_pilot(full_up, params.pilot, params.depth).throttle == pytest.approx(1.0)


def test_another_trim_is_read_as_the_firmware_reads_it():
    """A centred trim (1500) with 4.1-4.5's pass-through: a centred stick is throttle 0 (full down-thrust), as the
    firmware would do; master's (norm + 1) / 2 form with that trim gives 0.5."""
    params = ArduSubParameters.from_log_params({**TRIM_AT_MIN, "RC3_TRIM": 1500.0})
    assert shape_pilot(PilotInput.centred(), params.pilot, params.depth).throttle == 0.0
    assert pilot_throttle(-0.5) == -0.5                                # the motors clamp it (throttle_lower)
    assert pilot_throttle(0.0, centred=True) == 0.5 and pilot_throttle(-1.0, centred=True) == 0.0


def test_defaults_where_the_log_has_none_are_arduSub_4x_ones_and_listed():
    params = ArduSubParameters.from_log_params({})
    thr = params.pilot.channels["throttle"]
    assert (thr.min, thr.max, thr.trim, thr.dead_zone) == (1100.0, 1900.0, 1100.0, 30.0)   # Sub::load_parameters
    assert params.pilot.channels["yaw"].dead_zone == 40.0                                    # Sub::init_rc_in
    assert {"RC3_TRIM", "RC3_DZ", "RC4_DZ", "JS_GAIN_DEFAULT"} <= set(params.assumed)
    logged = ArduSubParameters.from_log_params(TRIM_AT_MIN)
    assert "RC3_TRIM" not in logged.assumed and logged.pilot.channels["throttle"].trim == 1100.0


def test_boot_gain_follows_init_joystick():
    assert boot_gain(0.5, 0.25, 1.0, 4) == 0.5
    assert boot_gain(2.0, 0.25, 1.0, 1) == 1.0                  # one setting: the default, constrained
    assert boot_gain(2.0, 0.2, 0.8, 4) == pytest.approx(0.2 + (4 // 2 - 1) * 0.6 / 3)   # mid setting
    assert boot_gain(0.05, 0.01, 0.06, 1) == 0.1                # never below 0.1


def test_climb_rate_dead_band_is_thr_dz_times_the_pilot_gain():
    params = ArduSubParameters.from_log_params({**TRIM_AT_MIN, "THR_DZ": 100.0, "JS_GAIN_DEFAULT": 0.5})
    pilot, depth = params.pilot, params.depth
    mid = 500.0
    assert pilot_climb_rate(mid + 49.0, mid, pilot, depth) == 0.0        # inside 100 * 0.5
    assert pilot_climb_rate(mid + 60.0, mid, pilot, depth) > 0.0         # outside it (100 would still be 0)
    assert pilot_climb_rate(1000.0, mid, pilot, depth) == pytest.approx(depth.speed_up)
    assert pilot_climb_rate(0.0, mid, pilot, depth) == pytest.approx(-depth.speed_down_effective)


def heave(ap: ArduSubAutopilot, seconds: float, pilot: PilotInput, state: dict, dt: float = 0.005,
          max_thrust: float = 4.0, buoyancy: float = -3.0, mass: float = 12.0, damping: float = 10.0) -> list:
    """A buoyant body (``buoyancy`` < 0 floats up, N) with weak vertical thrust (``max_thrust`` N at throttle 0/1):
    full down-thrust gives 0.1 m/s, below the pilot's descent speed, so a descent saturates."""
    out = []
    for _ in range(int(seconds / dt)):
        u: MixerInputs = ap.step(dt, VehicleState(depth=state["z"], vel_down=state["w"], accel_down=state["a"]),
                                 pilot, Mode.ALT_HOLD)
        thrust_down = -max_thrust * 2.0 * (u.throttle - 0.5)
        state["a"] = (thrust_down + buoyancy - damping * state["w"]) / mass
        state["w"] += state["a"] * dt
        state["z"] += state["w"] * dt
        out.append((state["z"], u.throttle))
    return out


def test_althold_after_a_saturated_descent_does_not_keep_full_down_thrust():
    """Full down stick for 40 s on a vehicle that cannot descend at PILOT_SPEED_DN (the motors at throttle_lower
    throughout), then the stick centred: ArduSub stops the integrators and the target at the throttle limit
    (update_z_controller's limit flags, update_pos_vel_accel), so the vehicle stops within the position-error
    limit of AC_P_1D (inv_sqrt_controller of the descent speed) below where it was, and the throttle leaves 0."""
    params = ArduSubParameters.defaults(loop_rate_hz=200.0)
    ap = ArduSubAutopilot(params)
    state = {"z": 2.0, "w": 0.0, "a": 0.0}
    dive = heave(ap, 40.0, PilotInput.from_sticks(throttle=-1.0), state)
    assert sum(thr <= 0.0 for _, thr in dive) > 0.9 * len(dive)        # saturated: full down-thrust
    d = params.depth
    # while limited the acceleration integrator may only shrink: it stays near its value at the saturation's start
    assert abs(ap.depth.pid_accel.integrator) < 0.5 * d.accel.imax
    released_at = state["z"]
    hold = heave(ap, 40.0, PilotInput.centred(), state)
    err_max = inv_sqrt_controller(d.speed_down_effective, d.pos_p, d.accel_max)
    assert max(z for z, _ in hold) - released_at < err_max + 0.1       # + what 0.1 m/s carries the body
    dt = 0.005
    assert sum(thr <= 0.0 for _, thr in hold) * dt < 1.0                 # full down-thrust ends within 1 s
    assert abs(hold[-1][0] - released_at) < err_max                      # settled near the release depth


def trim_at_min_tlog(path, seconds: float = 30.0):
    """A BlueROV2 (FRAME_CONFIG 1, VECTORED) in MANUAL as QGroundControl logs it, ``RC3_TRIM = RC3_MIN = 1100``: the
    throttle stick (RC_CHANNELS chan3, 10 Hz) steps through 1500, 1700, 1500, 1300 us, 2 s each, and the vertical
    thrusters (SERVO_OUTPUT_RAW 5, 6, 10 Hz, 5 ms after each RC sample) follow ArduSub 4.1-4.5's law: throttle =
    norm_input = (pwm - 1100) / 800, bidirectional 2 (throttle - 0.5), factor -1, 1500 + 400 x thrust (int)."""
    from pymavlink.dialects.v20 import ardupilotmega as mav2

    from tests.udrobot_ctrl.io.test_field_logs import RHO_G, params_events, write_events
    mav = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
    params = {**TRIM_AT_MIN, "FRAME_CONFIG": 1.0, "MOT_PWM_MIN": 1100.0, "MOT_PWM_MAX": 1900.0,
              **{f"SERVO{i}_FUNCTION": 32.0 + i for i in range(1, 7)}}
    ev = params_events(mav, params)
    for t in np.arange(0.0, seconds, 1.0):
        ev.append((t + 0.5, mav.heartbeat_encode(12, 3, 81 | 128, int(Mode.MANUAL), 4)))  # armed, MANUAL
        ev.append((t + 0.6, mav.sys_status_encode(0, 0, 0, 500, 16000, 500, 90, 0, 0, 0, 0, 0, 0)))
    for t in np.arange(0.01, seconds, 0.02):
        ev.append((t, mav.attitude_encode(int(t * 1000), 0.0, 0.0, 0.5, 0.0, 0.0, 0.0)))
    for t in np.arange(0.02, seconds, 0.5):
        ev.append((t, mav.scaled_pressure2_encode(int(t * 1000), (101325.0 + RHO_G * 2.0) / 100.0, 0.0, 1200)))
    steps = (1500, 1700, 1500, 1300)
    for t in np.arange(1.0, seconds, 0.1):
        thr_pwm = steps[int(t // 2.0) % len(steps)]
        rc = [1500, 1500, thr_pwm, 1500, 1500, 1500, 1500, 1500]
        ev.append((t, mav.rc_channels_encode(int(t * 1000), 8, *rc, *[0] * 10, 255)))
        thrust = -2.0 * ((thr_pwm - 1100.0) / 800.0 - 0.5)
        vertical = int(1500 + 400 * thrust)
        servo = [1500, 1500, 1500, 1500, vertical, vertical] + [0] * 10
        ev.append((t + 0.005, mav.servo_output_raw_encode(int((t + 0.005) * 1e6), 0, *servo)))
    return write_events(path, mav, ev)


def test_trim_at_min_log_replays_its_vertical_thrusters(tmp_path):
    """The whole path a user's log takes (convert -> emulation -> mixer): with the log's RC3_TRIM = RC3_MIN the
    emulated vertical thrusters equal the logged ones (a row or two per stick step aside, where the converter's
    grid and the emulation's one-tick lag place the step), and a centred stick is 1500 us; the (norm + 1) / 2 form
    misses them by hundreds of us."""
    from udrobot_ctrl.autopilot.feedback import motor_output_check
    from udrobot_ctrl.convert import convert_log
    from udrobot_ctrl.dynamics.plant import plant_parameters
    from udrobot_ctrl.vehicle import load_model

    run = convert_log(trim_at_min_tlog(tmp_path / "trim.tlog"), cut=False)
    assert run.metadata["vehicle"] == "bluerov2"
    assert run.metadata["autopilot_params"]["RC3_TRIM"] == 1100.0
    p = plant_parameters(load_model("bluerov2"))
    check = motor_output_check(run, p)
    vertical = check.emulated[:, 4:6] - check.logged[:, 4:6]
    assert np.mean(np.abs(vertical) < 1.0) > 0.9          # equal to the us on all rows but the step ones
    assert max(check.nrmse[4:6]) < 0.3
    rc3 = np.asarray(run.extra["rcin_3"])
    held = (rc3[check.rows] == 1500) & (rc3[np.maximum(check.rows - 1, 0)] == 1500)  # centred since the last row
    assert held.sum() > 100
    assert np.all(check.emulated[held][:, 4:6] == 1500)
    params = ArduSubParameters.from_log_params(run.metadata["autopilot_params"])
    wrong = replace(params, pilot=replace(params.pilot, throttle_norm_centred=True))
    assert min(motor_output_check(run, p, wrong).rmse_us[4:6]) > 100.0
