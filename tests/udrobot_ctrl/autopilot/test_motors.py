"""ArduSub's output side (udrobot_ctrl.autopilot.motors): factor signs against the vehicle models' physics,
the mixer's saturation handling, PWM round trip and motor reversal, unmix."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pymavlink import DFReader

from udrobot_ctrl.autopilot.motors import (
    FRAME_CONFIGS,
    FRAME_FACTORS,
    MIXER_INPUTS,
    MotorParameters,
    custom_frame,
    frame,
    frame_of_vehicle,
    from_pwm,
    mix,
    motor_pwm,
    throttle_bidirectional,
    to_pwm,
    unmix,
)
from udrobot_ctrl.dynamics.plant import plant_parameters, thrust_to_wrench
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.io.mavlink import ARDUSUB_FRAMES, motor_command_pwm
from udrobot_ctrl.vehicle import load_model

DIVE = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "guided_above_terrain" / "00000029_filtered.BIN"
#: The body wrench component (X Y Z K M N) each mixer input must push, and its sign: throttle > 0 is up (-z).
EXPECTED = {"roll": (3, +1), "pitch": (4, +1), "yaw": (5, +1), "throttle": (2, -1), "forward": (0, +1),
            "lateral": (1, +1)}


@pytest.mark.parametrize("name", ["bluerov2", "bluerov2-heavy"])
def test_each_input_pushes_its_own_dof_through_the_vehicle_model(name):
    vehicle = load_model(name)
    fr = frame_of_vehicle(vehicle)
    p = plant_parameters(vehicle)
    params = MotorParameters.default(fr.n_motors)
    for j, inp in enumerate(MIXER_INPUTS):
        u = np.zeros(6)
        u[j] = 0.5
        # the project's own path: ArduSub PWM -> T200 curve -> thruster matrix
        tau = thrust_to_wrench(pwm_to_thrust(motor_pwm(fr, u, params), 14.8), p)
        k, sign = EXPECTED[inp]
        if inp in fr.unobservable:  # VECTORED: no pitch factor at all
            assert np.allclose(tau, 0.0), (name, inp, tau)
            continue
        assert sign * tau[k] > 1.0, (name, inp, tau)
        # no other force of the same kind larger than the intended one (moments vs moments, forces vs forces)
        same = [0, 1, 2] if k < 3 else [3, 4, 5]
        others = [abs(tau[i]) for i in same if i != k]
        assert max(others) < 0.2 * abs(tau[k]), (name, inp, tau)


def test_frame_lookup_by_config_name_and_vehicle():
    assert frame(2).name == frame("VECTORED_6DOF").name == frame("bluerov2-heavy").name == "VECTORED_6DOF"
    assert frame("vectored").config == 1 and frame("bluerov2").n_motors == 6
    assert frame("SUB_FRAME_VECTORED_6DOF_90DEG").config == 3
    with pytest.raises(ValueError, match="CUSTOM"):
        frame(7)
    with pytest.raises(ValueError, match="unknown ArduSub frame"):
        frame("HEXA")
    with pytest.raises(ValueError, match="not an ArduSub frame"):
        frame(12)
    assert custom_frame(np.eye(6)).rank == 6


def test_frame_table_agrees_with_the_log_readers_table():
    """io.mavlink.ARDUSUB_FRAMES (FRAME_CONFIG -> name, motor count) is a twin: checked equal here."""
    for config, (name, n_motors, _vehicle) in ARDUSUB_FRAMES.items():
        assert FRAME_CONFIGS[config] == name
        if name == "SIMPLEROV_4":  # 4 thrusters on the vehicle, but ArduSub enables the shared 5-motor table
            assert n_motors == 4 and frame(config).n_motors == 5
        elif name in FRAME_FACTORS:
            assert frame(config).n_motors == n_motors, name


def test_ranks_per_frame():
    assert frame("VECTORED_6DOF").rank == 6 and frame("VECTORED").rank == 5
    assert frame("VECTORED").unobservable == ("pitch",)
    assert frame("SIMPLEROV_3").unobservable == ("roll", "pitch", "lateral")


def test_vectored_6dof_normalisation_keeps_the_ratio_of_inputs():
    fr = frame("VECTORED_6DOF")
    # yaw 0.8 + forward 0.8: motors would need 1.6 -> the yaw/forward/lateral group is divided by 1.6
    out = mix(fr, [0, 0, 0.8, 0, 0.8, 0])
    assert np.max(np.abs(out)) == pytest.approx(1.0)
    u = unmix(fr, out)
    assert u[2] / u[4] == pytest.approx(1.0)  # the ratio of the requested inputs is kept
    assert u[2] == pytest.approx(0.5)
    # the vertical group is normalised on its own: roll 1 + throttle 1 -> divided by 2, ratio kept
    out = mix(fr, [1.0, 0, 0.3, 1.0, 0, 0])
    u = unmix(fr, out)
    assert u[0] == pytest.approx(0.5) and u[3] == pytest.approx(0.5) and u[2] == pytest.approx(0.3)
    # unsaturated: untouched
    assert np.allclose(unmix(fr, mix(fr, [0.1, -0.2, 0.1, 0.3, -0.2, 0.1])), [0.1, -0.2, 0.1, 0.3, -0.2, 0.1])


def test_vectored_clips_per_motor_and_limits_the_rear_thrusters_with_throttle():
    fr = frame("VECTORED")
    out = mix(fr, [0, 0, 0.8, 0, 0.8, 0])  # no normalisation on VECTORED: motor-wise clip
    assert np.allclose(out[:4], [0.0, -1.0, 0.0, 1.0])
    # forward 0.6 with throttle 0.5 (MOT_FV_CPLNG_K = 1): the rear motors 3, 4 get at most 1 - 0.5 = 0.5
    out = mix(fr, [0, 0, 0, 0.5, 0.6, 0])
    assert np.allclose(out[:4], [-0.6, -0.6, 0.5, 0.5])
    out = mix(fr, [0, 0, 0, 0.5, -0.6, 0])  # backwards: the front motors 1, 2 are the rear ones
    assert np.allclose(out[:4], [0.5, 0.5, -0.6, -0.6])
    no_coupling = MotorParameters(directions=(1,) * 6, forward_vertical_coupling=0.0)
    assert np.allclose(mix(fr, [0, 0, 0, 0.5, 0.6, 0], no_coupling)[:4], [-0.6, -0.6, 0.6, 0.6])


def test_pwm_round_trip_and_range():
    params = MotorParameters(pwm_min=1100, pwm_max=1900, directions=(1, -1, 1))
    t = np.array([[0.25, 0.25, -1.0], [1.0, -0.5, 0.0]])
    pwm = to_pwm(t, params, integer=False)
    assert np.allclose(pwm, [[1600, 1400, 1100], [1900, 1700, 1500]])
    assert np.allclose(from_pwm(pwm, params), t)
    # asymmetric range (ArduSub 4.5 calc_thrust_to_pwm): up and down use their own half-ranges
    asym = MotorParameters(pwm_min=1000, pwm_max=1900, directions=(1, 1))
    assert np.allclose(to_pwm([0.5, -0.5], asym), [1700, 1250])
    assert np.allclose(from_pwm([1700, 1250], asym), [0.5, -0.5])
    # int16 truncation toward zero, as the C return
    assert to_pwm([0.00374], MotorParameters(directions=(1,)))[0] == 1501.0


def test_direction_reverses_about_1500():
    fr = frame("VECTORED_6DOF")
    u = [0.1, -0.2, 0.3, 0.2, 0.4, -0.1]
    normal = motor_pwm(fr, u, MotorParameters(directions=(1,) * 8), integer=False)
    dirs = (-1, -1, 1, 1, -1, 1, 1, -1)
    rev = motor_pwm(fr, u, MotorParameters(directions=dirs), integer=False)
    d = np.array(dirs)
    assert np.allclose(np.where(d < 0, 3000 - normal, normal), rev)


def test_throttle_bidirectional_and_clip():
    assert np.allclose(throttle_bidirectional([0.5, 0.75, 0.0, 1.2]), [0.0, 0.5, -1.0, 1.0])


def test_unmix_recovers_inputs_on_the_full_rank_frame_and_leaves_pitch_out_on_vectored():
    rng = np.random.default_rng(0)
    u = rng.uniform(-0.15, 0.15, (50, 6))
    assert np.allclose(unmix(frame("VECTORED_6DOF"), mix(frame("VECTORED_6DOF"), u)), u)
    got = unmix(frame("VECTORED"), mix(frame("VECTORED"), u))
    keep = [0, 2, 3, 4, 5]
    assert np.allclose(got[:, keep], u[:, keep]) and np.allclose(got[:, 1], 0.0)


def test_parameters_from_log_defaults_are_listed():
    p = MotorParameters.from_log_params({"MOT_PWM_MIN": 1100, "MOT_1_DIRECTION": -1}, 2)
    assert p.directions == (-1, 1)
    assert "MOT_PWM_MAX = 1900" in p.assumed and "MOT_2_DIRECTION = 1" in p.assumed
    assert not any(a.startswith("MOT_PWM_MIN") for a in p.assumed)
    p = MotorParameters.from_log_params({"MOT_PWM_MIN": 0, "MOT_PWM_MAX": 0, "RC3_MIN": 1000, "RC3_MAX": 2000}, 1)
    assert (p.pwm_min, p.pwm_max) == (1000, 2000)
    with pytest.raises(ValueError, match="MOT_1_DIRECTION"):
        MotorParameters.from_log_params({"MOT_1_DIRECTION": 0}, 1)
    with pytest.raises(ValueError, match="inputs must have a last axis of 6"):
        mix(frame(2), [0, 0, 0])


def test_log_mirror_is_the_mixers_direction_at_the_default_range():
    """io.mavlink.motor_command_pwm (the converters' mirror 3000 - pwm) is the twin of to_pwm/from_pwm's direction
    for Sub's default symmetric range 1100-1900 us."""
    dirs = (-1, -1, 1, 1, -1, 1, 1, -1)
    pwm = np.random.default_rng(1).uniform(1100, 1900, (20, 8))
    ours = to_pwm(from_pwm(pwm, MotorParameters(directions=dirs)), MotorParameters(directions=(1,) * 8),
                  integer=False)
    assert np.allclose(motor_command_pwm(pwm, dirs), ours)


@pytest.mark.skipif(not DIVE.exists(), reason="shared data absent")
def test_mixer_reproduces_the_logged_vertical_motor_pwm_of_a_real_dive():
    """The real sea dive (BlueROV2 Heavy): RATE ROut/POut/AOut through ArduSub's mixer give RCOU C5..C8 to the us.

    The verticals need only roll, pitch and throttle, all logged; MOT_5..8_DIRECTION (-1, 1, 1, -1) are those of
    the project's Heavy logs (the dive's own parameters are not in it)."""
    log = DFReader.DFReader_binary(str(DIVE))
    rate, rcou = [], []
    while (m := log.recv_match(type=["RATE", "RCOU"])) is not None:
        if m.get_type() == "RATE":
            rate.append((m.TimeUS, m.ROut, m.POut, m.YOut, m.AOut))
        else:
            rcou.append([m.TimeUS] + [getattr(m, f"C{i}") for i in range(1, 9)])
    rate, rcou = np.array(rate, float), np.array(rcou, float)
    j = np.searchsorted(rate[:, 0], rcou[:, 0], side="right") - 1
    ok = (j >= 0) & (rcou[:, 0] - rate[np.maximum(j, 0), 0] < 50e3)
    r, out = rate[j[ok]], rcou[ok, 1:]
    assert len(out) > 1000
    u = np.column_stack([r[:, 1], r[:, 2], r[:, 3], throttle_bidirectional(r[:, 4]), np.zeros((len(r), 2))])
    pwm = motor_pwm(frame("VECTORED_6DOF"), u, MotorParameters(directions=(-1, -1, 1, 1, -1, 1, 1, -1)))
    assert np.max(np.abs(pwm[:, 4:] - out[:, 4:])) <= 1.0


#: ``AP_Motors6DOF::setup_motors`` (ArduSub 4.1-4.5), the ``add_motor_raw_6dof(motor, roll, pitch, yaw, throttle,
#: forward, lateral, testing_order)`` calls of the two BlueROV2 frames, written out from the source motor by motor
SOURCE_TABLES = {
    "VECTORED": {1: (0, 0, 1.0, 0, -1.0, 1.0), 2: (0, 0, -1.0, 0, -1.0, -1.0), 3: (0, 0, -1.0, 0, 1.0, 1.0),
                 4: (0, 0, 1.0, 0, 1.0, -1.0), 5: (1.0, 0, 0, -1.0, 0, 0), 6: (-1.0, 0, 0, -1.0, 0, 0)},
    "VECTORED_6DOF": {1: (0, 0, 1.0, 0, -1.0, 1.0), 2: (0, 0, -1.0, 0, -1.0, -1.0), 3: (0, 0, -1.0, 0, 1.0, 1.0),
                      4: (0, 0, 1.0, 0, 1.0, -1.0), 5: (1.0, -1.0, 0, -1.0, 0, 0), 6: (-1.0, -1.0, 0, -1.0, 0, 0),
                      7: (1.0, 1.0, 0, -1.0, 0, 0), 8: (-1.0, 1.0, 0, -1.0, 0, 0)},
}


@pytest.mark.parametrize("name", sorted(SOURCE_TABLES))
def test_factors_equal_the_source_table_factor_by_factor(name):
    fr = frame(name)
    table = SOURCE_TABLES[name]
    assert fr.n_motors == len(table)
    for motor, row in table.items():
        for column, (want, got) in enumerate(zip(row, fr.factors[motor - 1])):
            assert got == want, f"{name} motor {motor} {MIXER_INPUTS[column]}: {got} != source {want}"


def test_vectored_vertical_motors_carry_throttle_and_roll_only():
    """VECTORED's vertical thrusters (5, 6): a centred throttle (0.5 -> bidirectional 0) leaves them at 1500 us,
    full up-throttle drives both to the same end, roll splits them; pitch does nothing (no pitch column)."""
    fr = frame("VECTORED")
    neutral = motor_pwm(fr, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    up = motor_pwm(fr, np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0]))
    roll = motor_pwm(fr, np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0]))
    pitch = motor_pwm(fr, np.array([0.0, 0.5, 0.0, 0.0, 0.0, 0.0]))
    assert np.all(neutral == 1500)
    assert up[4] == up[5] == 1100 and np.all(up[:4] == 1500)      # factor -1: full up-throttle is 1100 us
    assert roll[4] == 1700 and roll[5] == 1300
    assert np.all(pitch == 1500)
