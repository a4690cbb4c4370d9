"""ArduSub's controllers (udrobot_ctrl.autopilot: pid, attitude, depth, modes, ardusub, validate): hand-computed
AC_PID steps, closed loops on simple rigid bodies, the mode logic, the gain fit on synthetic logs and the real sea
dive (../shared/data/guided_above_terrain, skipped when absent)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode, PilotInput, Targets, norm_input, pilot_lean_angles
from udrobot_ctrl.ardusub.params import ArduSubParameters, PIDGains, RCChannel
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, MixerInputs, VehicleState
from udrobot_ctrl.autopilot.attitude import ang_vel_to_euler_rate, quat_from_euler, quat_to_euler
from udrobot_ctrl.autopilot.motors import frame, motor_pwm
from udrobot_ctrl.autopilot.pid import ACPID, inv_sqrt_controller, lowpass_alpha, sqrt_controller
from udrobot_ctrl.autopilot.validate import (
    DataflashLog,
    check_log,
    fit_depth_gains,
    fit_pid_gains,
    fitted_parameters,
    read_log,
    replay_autopilot,
)

ROOT = Path(__file__).resolve().parents[3]
DIVE = ROOT.parent / "shared" / "data" / "guided_above_terrain" / "00000029_filtered.BIN"
DEG = math.pi / 180


# ------------------------------------------------------------------------------------------------ AC_PID


def test_pid_hand_computed_steps():
    """P, I (ki e dt), D on the error difference, first call resets the filters (AC_PID::update_all)."""
    pid = ACPID(PIDGains(p=2.0, i=1.0, d=0.1, imax=0.5))
    out = pid.update_all(1.0, 0.0, 0.1)
    # first call: E = 1, derivative 0, I = 1 * 1 * 0.1
    assert pid.terms.p == pytest.approx(2.0) and pid.terms.i == pytest.approx(0.1) and pid.terms.d == 0.0
    assert out == pytest.approx(2.1)
    out = pid.update_all(1.0, 0.5, 0.1)
    # E = 0.5, dE/dt = -5 -> D = -0.5, I = 0.1 + 0.5 * 0.1 = 0.15
    assert pid.terms.p == pytest.approx(1.0)
    assert pid.terms.d == pytest.approx(-0.5)
    assert pid.terms.i == pytest.approx(0.15)
    assert out == pytest.approx(1.0 + 0.15 - 0.5)


def test_pid_integrator_clamps_at_imax_and_only_shrinks_when_limited():
    pid = ACPID(PIDGains(p=0.0, i=1.0, d=0.0, imax=0.5))
    for _ in range(100):
        pid.update_all(1.0, 0.0, 0.1)
    assert pid.integrator == pytest.approx(0.5)
    pid.update_all(1.0, 0.0, 0.1, limit=True)          # saturated, error would grow I: frozen
    assert pid.integrator == pytest.approx(0.5)
    pid.update_all(-1.0, 0.0, 0.1, limit=True)         # saturated, error shrinks I: allowed
    assert pid.integrator == pytest.approx(0.4)
    zero_i = ACPID(PIDGains(p=1.0, i=0.0, d=0.0, imax=1.0))
    zero_i.set_integrator(0.3)
    zero_i.update_all(1.0, 0.0, 0.1)
    assert zero_i.integrator == 0.0                    # ki == 0 clears the integrator


def test_pid_derivative_and_target_filters():
    """FLTD low-passes the error derivative, FLTT the target, with alpha = dt / (dt + 1 / (2 pi f))."""
    dt, f = 0.0025, 30.0
    alpha = dt / (dt + 1 / (2 * math.pi * f))
    assert lowpass_alpha(dt, f) == pytest.approx(alpha)
    assert lowpass_alpha(dt, 0.0) == 1.0
    pid = ACPID(PIDGains(p=0.0, i=0.0, d=0.01, imax=1.0, filt_d_hz=f))
    pid.update_all(0.0, 0.0, dt)
    pid.update_all(0.0, -0.1, dt)                      # error steps by 0.1 -> raw derivative 40 /s
    assert pid.terms.d == pytest.approx(0.01 * alpha * 0.1 / dt)
    pid.update_all(0.0, -0.1, dt)                      # raw derivative 0: filtered derivative decays
    assert pid.terms.d == pytest.approx(0.01 * (1 - alpha) * alpha * 0.1 / dt)
    tpid = ACPID(PIDGains(p=1.0, i=0.0, d=0.0, imax=1.0, filt_t_hz=f))
    tpid.update_all(0.0, 0.0, dt)
    tpid.update_all(1.0, 0.0, dt)
    assert tpid.terms.target == pytest.approx(alpha)
    assert tpid.terms.p == pytest.approx(alpha)


def test_sqrt_controller_and_its_inverse():
    p, a = 2.0, 4.0                                    # linear below a / p^2 = 1
    assert sqrt_controller(0.5, p, a, 0.0) == pytest.approx(1.0)
    assert sqrt_controller(3.0, p, a, 0.0) == pytest.approx(math.sqrt(2 * a * (3.0 - 0.5)))
    assert sqrt_controller(-3.0, p, a, 0.0) == pytest.approx(-math.sqrt(2 * a * 2.5))
    assert sqrt_controller(0.01, p, a, 0.1) == pytest.approx(0.02)
    assert sqrt_controller(0.01, 50.0, 0.0, 0.1) == pytest.approx(0.1)  # limited to |error| / dt
    for out in (0.5, 3.0, 7.0):
        assert sqrt_controller(inv_sqrt_controller(out, p, a), p, a, 0.0) == pytest.approx(out)


# ------------------------------------------------------------------------------------------------ params


def test_params_convert_units_and_list_defaults():
    params = ArduSubParameters.from_log_params({"ANGLE_MAX": 3000, "PSC_ACCZ_P": 0.4, "PSC_ACCZ_IMAX": 600,
                                                "ATC_RAT_RLL_P": 0.2, "ATC_ACCEL_Y_MAX": 36000,
                                                "PILOT_SPEED_UP": 50, "SCHED_LOOP_RATE": 200})
    assert params.pilot.angle_max == pytest.approx(30 * DEG)
    assert params.depth.accel.p == pytest.approx(0.04)          # 0.4 * 100 cm/m * 0.001 throttle
    assert params.depth.accel.imax == pytest.approx(0.6)
    assert params.depth.accel.i == pytest.approx(0.1)           # default 1.0 in ArduSub's units
    assert params.attitude.rate_roll.p == 0.2 and params.attitude.rate_pitch.p == 0.135
    assert params.attitude.accel_max[2] == pytest.approx(360 * DEG)
    assert params.depth.speed_up == pytest.approx(0.5)
    assert params.loop_rate_hz == 200
    assert "ATC_RAT_PIT_P" in params.assumed and "ANGLE_MAX" not in params.assumed
    d = ArduSubParameters.defaults()
    assert d.attitude.angle_p == (6.0, 6.0, 6.0) and d.attitude.accel_max[0] == pytest.approx(1100 * DEG)
    assert d.pilot.angle_max == pytest.approx(45 * DEG) and d.depth.accel.p == pytest.approx(0.05)


# --------------------------------------------------------------------------------------- closed loops


class RigidBody:
    """Three decoupled rotational axes and heave: I w' = K u - c w - k sin(angle) + disturbance (SI)."""

    def __init__(self, inertia=(0.3, 0.4, 0.5), gain=(4.0, 4.0, 3.0), damping=(1.0, 1.0, 1.0),
                 restoring=(2.0, 2.0, 0.0), torque=(0.2, -0.1, 0.1)):
        self.I, self.K, self.c = np.array(inertia), np.array(gain), np.array(damping)
        self.k, self.torque = np.array(restoring), np.array(torque)
        self.angles = np.zeros(3)
        self.rates = np.zeros(3)
        self.depth, self.w, self.a = 0.0, 0.0, 0.0

    def state(self):
        return VehicleState(*self.angles, rates=tuple(self.rates), depth=self.depth, vel_down=self.w,
                            accel_down=self.a)

    def step(self, u: MixerInputs, dt, buoyancy=0.0, heave_gain=20.0, mass=12.0, heave_damping=10.0):
        rpy = np.array([u.roll, u.pitch, u.yaw])
        acc = (self.K * rpy - self.c * self.rates - self.k * np.sin(self.angles) + self.torque) / self.I
        self.rates += acc * dt
        self.angles += ang_vel_to_euler_rate(self.angles[:2], self.rates) * dt
        thrust_up = heave_gain * 2.0 * (u.throttle - 0.5)
        self.a = (-thrust_up + buoyancy - heave_damping * self.w) / mass  # down positive; buoyancy > 0 sinks
        self.w += self.a * dt
        self.depth += self.w * dt


def fly(mode, seconds, body=None, pilot=None, targets=None, dt=0.005, buoyancy=0.0, params=None):
    ap = ArduSubAutopilot(params)
    body = body if body is not None else RigidBody()
    history = []
    for _ in range(int(seconds / dt)):
        u = ap.step(dt, body.state(), pilot, mode, targets)
        body.step(u, dt, buoyancy)
        history.append((body.angles.copy(), body.depth, u))
    return ap, body, history


@pytest.mark.slow
def test_attitude_loop_settles_a_10_degree_roll_step_without_steady_error():
    """GUIDED roll target 10 deg on a body with a restoring moment and a disturbance torque: the rate I terms
    carry the steady torque, so the angle error goes to zero."""
    ap, body, hist = fly(Mode.GUIDED, 40.0, targets=Targets(roll=10 * DEG, pitch=0.0, yaw=0.0))
    roll = np.array([h[0][0] for h in hist])
    assert abs(roll[-1] - 10 * DEG) < 0.01 * DEG
    # pitch and yaw carry their own disturbance torques; yaw's I gain (0.018) makes it the slowest to null
    assert abs(body.angles[1]) < 0.05 * DEG and abs(body.angles[2]) < 0.1 * DEG
    assert roll.max() < 13 * DEG                                   # no wild overshoot
    t_settle = np.argmax(np.abs(roll - 10 * DEG) < 0.5 * DEG) * 0.005
    assert t_settle < 5.0
    assert abs(ap.attitude.rate_pids[0].integrator) > 0.01         # the integrator holds the torque


@pytest.mark.slow
def test_depth_loop_holds_depth_against_a_buoyancy_offset():
    """ALT_HOLD, throttle centred, 3 N of negative buoyancy: the accel-loop integrator takes the offset and the
    depth returns to where the mode was entered."""
    body = RigidBody()
    body.depth = 5.0
    ap, body, hist = fly(Mode.ALT_HOLD, 60.0, body=body, pilot=PilotInput.centred(), buoyancy=3.0)
    depth = np.array([h[1] for h in hist])
    assert abs(depth[-1] - 5.0) < 0.01
    assert np.max(np.abs(depth - 5.0)) < 0.5
    thr = hist[-1][2].throttle
    assert thr == pytest.approx(0.5 + 3.0 / (2 * 20.0), abs=0.005)  # the thrust that cancels the offset
    assert ap.depth.pid_accel.integrator < -0.05                    # negative down-frame I = up-thrust


def test_manual_passes_the_sticks_through():
    ap = ArduSubAutopilot()
    pilot = PilotInput.from_sticks(roll=0.5, pitch=-0.25, yaw=0.4, throttle=0.2, forward=0.8, lateral=-0.6)
    state = VehicleState(roll=0.1, rates=(0.3, 0.0, 0.0))
    ap.step(0.0025, state, pilot, Mode.MANUAL)     # the mode's outputs reach the mixer on the next tick
    u = ap.step(0.0025, state, pilot, Mode.MANUAL)
    assert (u.roll, u.pitch, u.forward, u.lateral) == pytest.approx((0.5, -0.25, 0.8, -0.6))
    assert u.yaw == pytest.approx(0.4 * ap.params.pilot.acro_yaw_p / 3.375)
    assert u.throttle == pytest.approx((0.2 + 1) / 2)  # norm_input passed as is: RC3_TRIM = RC3_MIN, 0..1
    assert ap.attitude.rate_pids[0].terms.p == 0.0                 # no rate loop in MANUAL


def test_stabilize_levels_the_vehicle_with_sticks_centred_and_holds_heading():
    body = RigidBody(torque=(0.0, 0.0, 0.0))
    body.angles[:] = (8 * DEG, -6 * DEG, 30 * DEG)
    ap, body, hist = fly(Mode.STABILIZE, 10.0, body=body, pilot=PilotInput.centred())
    assert np.all(np.abs(body.angles[:2]) < 0.05 * DEG)
    assert body.angles[2] == pytest.approx(30 * DEG, abs=0.2 * DEG)
    assert hist[-1][2].throttle == pytest.approx(0.5)


def test_stabilize_yaw_stick_turns_then_holds_the_new_heading():
    """Yaw stick: a yaw rate; 250 ms after release the heading then is held (mode_stabilize.cpp)."""
    body = RigidBody(torque=(0.0, 0.0, 0.0))
    ap = ArduSubAutopilot()
    dt = 0.005                                                      # the dive's 200 Hz loop
    headings = []
    for k in range(int(12.0 / dt)):
        pilot = PilotInput.from_sticks(yaw=0.3) if k * dt < 2.0 else PilotInput.centred()
        u = ap.step(dt, body.state(), pilot, Mode.STABILIZE)
        body.step(u, dt)
        headings.append(body.angles[2])
    held = ap._last_pilot_heading
    assert held > 40 * DEG                                          # it turned at ~0.3 * 4500 * 3.375 cdeg/s
    assert abs(headings[int(2.0 / dt)] - held) < 15 * DEG    # held where it was 250 ms after release
    assert abs(body.angles[2] - held) < 1.0 * DEG                   # and returns to it


def test_althold_climbs_with_the_throttle_stick_and_holds_when_centred():
    body = RigidBody()
    body.depth = 5.0
    ap = ArduSubAutopilot()
    dt = 0.005                                                      # the dive's 200 Hz loop
    for k in range(int(30.0 / dt)):
        pilot = PilotInput.from_sticks(throttle=0.8) if k * dt < 3.0 else PilotInput.centred()
        u = ap.step(dt, body.state(), pilot, Mode.ALT_HOLD)
        body.step(u, dt)
        if k * dt == pytest.approx(20.0, abs=dt / 2):
            held = body.depth
    assert body.depth < 4.0                                        # up by over a metre
    assert abs(body.depth - held) < 0.02                           # then held


def test_outputs_feed_the_mixer():
    ap = ArduSubAutopilot()
    u = ap.step(0.0025, VehicleState(), PilotInput.centred(), Mode.STABILIZE)
    pwm = motor_pwm(frame("VECTORED_6DOF"), u.as_array())
    assert np.all(pwm == 1500)
    assert u.as_array()[3] == 0.0 and u.as_array(bidirectional=False)[3] == 0.5


def test_unsupported_mode_and_disarmed():
    ap = ArduSubAutopilot()
    with pytest.raises(ValueError, match="not emulated"):
        ap.step(0.0025, VehicleState(), None, Mode.AUTO)
    u = ap.step(0.0025, VehicleState(roll=0.3), PilotInput.from_sticks(throttle=1.0), Mode.MANUAL, armed=False)
    assert u == MixerInputs(0.0, 0.0, 0.0, 0.5, 0.0, 0.0)


def test_pilot_input_shaping():
    ch = RCChannel()
    assert norm_input(1900, ch) == 1.0 and norm_input(1300, ch) == -0.5 and norm_input(1500, ch) == 0.0
    roll, pitch = pilot_lean_angles(4500, 0, 45 * DEG, 45 * DEG)
    assert roll == pytest.approx(45 * DEG) and pitch == 0.0
    roll, pitch = pilot_lean_angles(4500, 4500, 45 * DEG, 45 * DEG)  # circular limit
    assert math.hypot(math.tan(roll) / math.cos(pitch), 0) > 0 and abs(pitch) == pytest.approx(45 / math.sqrt(2)
                                                                                                * DEG)


def test_quaternion_round_trip():
    for e in ((0.1, -0.2, 2.5), (-1.0, 0.5, -3.0)):
        assert quat_to_euler(quat_from_euler(*e)) == pytest.approx(e)


# ---------------------------------------------------------------------------------------- the gain fit


def synthetic_pid_log(gains: PIDGains, seconds=120.0, loop_dt=0.0025, noise=1e-5, seed=0) -> DataflashLog:
    """A PIDR stream logged at 10 Hz from our own AC_PID running at 400 Hz on smooth random signals."""
    rng = np.random.default_rng(seed)
    n = int(seconds / loop_dt)
    t = np.arange(n) * loop_dt
    # band-limited signals (sums of sines 0.05-3 Hz), rad/s
    tar = sum(rng.normal(0, 0.05) * np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in rng.uniform(0.05, 1, 8))
    act = tar - sum(rng.normal(0, 0.03) * np.sin(2 * np.pi * f * t + rng.uniform(0, 6))
                    for f in rng.uniform(0.1, 3, 8))
    pid = ACPID(gains)
    rows = {k: [] for k in ("t", "Tar", "Act", "Err", "P", "I", "D")}
    for k in range(n):
        pid.update_all(tar[k], act[k], loop_dt)
        if k % 40 == 0:
            tm = pid.terms
            for key, v in (("t", t[k]), ("Tar", tm.target), ("Act", tm.actual), ("Err", tm.error), ("P", tm.p),
                           ("I", tm.i), ("D", tm.d)):
                rows[key].append(v)
    m = {k: np.asarray(v) for k, v in rows.items()}
    for key in ("P", "I", "D"):
        m[key] = m[key] + rng.normal(0, noise, m[key].shape)
    return DataflashLog("synthetic", {"PIDR": m}, {}, (), loop_dt)


def test_gain_fit_recovers_known_gains_from_a_synthetic_log():
    truth = PIDGains(p=0.12, i=0.07, d=0.004, imax=1.0, filt_d_hz=20.0)
    fit = fit_pid_gains(synthetic_pid_log(truth), "PIDR", window=1.0)
    assert fit.p == pytest.approx(0.12, rel=1e-3)
    assert fit.i == pytest.approx(0.07, rel=0.01)
    assert fit.d == pytest.approx(0.004, rel=0.05)
    assert fit.i_corr > 0.99


# ------------------------------------------------------------------------------------------- the dive

needs_dive = pytest.mark.skipif(not DIVE.exists(), reason="../shared/data/guided_above_terrain not available")


@pytest.fixture(scope="module")
def dive_check():
    log = read_log(DIVE)
    return log, check_log(log, "default")


@needs_dive
@pytest.mark.slow
def test_dive_p_terms_match_the_logged_ones(dive_check):
    """The rate loops' P is kP (Tar - Act) at the log instant itself (FLTE = 0): nothing between 10 Hz samples
    enters it, so only float32 logging separates the emulation from the log (NRMSE ~1e-7; threshold 1e-3).
    PIDA's error is low-passed at FLTE = 20 Hz (memory ~40 ms) over an accelerometer signal the 10 Hz log does
    not resolve: the emulated filter sees interpolated inputs, so its P may differ by a few per cent (0.1)."""
    log, check = dive_check
    assert log.loop_dt == pytest.approx(0.005, rel=0.02)           # ANG.Dt: this vehicle ran at 200 Hz
    for ax in ("PIDR", "PIDP", "PIDY"):
        assert check.terms[ax].p < 1e-3, ax
        assert check.terms[ax].i_step < 0.01, ax                   # one-step integrator from the logged I
    assert check.terms["PIDA"].p < 0.1
    assert check.terms["PIDA"].p_from_err < 1e-3                   # the P gain itself is ArduSub's default


@needs_dive
@pytest.mark.slow
def test_dive_fitted_gains_and_motor_outputs(dive_check):
    log, check = dive_check
    f = check.fitted
    assert f["PIDR"].p == pytest.approx(0.135, rel=1e-4) and f["PIDY"].p == pytest.approx(0.180, rel=1e-4)
    assert f["PIDR"].i == pytest.approx(0.090, rel=0.03) and f["PIDY"].i == pytest.approx(0.018, rel=0.03)
    assert f["PIDR"].i == pytest.approx(0.090, rel=0.005) and f["PIDP"].i == pytest.approx(0.090, rel=0.005)
    assert f["PIDR"].d == pytest.approx(0.0036, rel=0.05) and f["PIDP"].d == pytest.approx(0.0036, rel=0.05)
    assert max(check.rcou_mixer) < 0.05                            # the mixer reproduces RCOU
    # the angle layer (sqrt controller on the thrust/heading error + feed-forward) gives RATE's desired rates;
    # the feed-forward comes from a spline derivative of the 10 Hz targets, looser on the turning yaw axis
    assert check.rate_targets[0] < 0.02 and check.rate_targets[1] < 0.02 and check.rate_targets[2] < 0.1
    assert check.forward_lateral[0] < 0.1 and check.forward_lateral[1] < 0.1
    fitted = check_log(log, "fitted")
    assert max(fitted.rcou_emulated) < 0.2


@needs_dive
@pytest.mark.slow
def test_dive_whole_autopilot_replays_the_guided_leg(dive_check):
    """ArduSubAutopilot stepped at 200 Hz on the logged states, shaped targets and modes of the first GUIDED leg
    (669.5-700 s), gains fitted from the log: its mixer inputs follow RATE's and its PWM follows RCOU within a
    couple of microseconds. Between 10 Hz samples it runs on interpolated inputs (the D terms and integrators
    drift a little), hence thresholds of a few per cent rather than the P terms' 1e-3."""
    log, _ = dive_check
    depth = fit_depth_gains(log)
    assert depth.vel_p == pytest.approx(8.0, rel=0.05)             # not the library's 5.0
    assert depth.pos_p == pytest.approx(1.0, rel=0.05)
    r = replay_autopilot(log, fitted_parameters(log), start=669.5, end=700.0)
    assert max(r.inputs[:3]) < 0.1 and r.inputs[3] < 0.2
    assert max(r.rcou_rmse) < 3.0                                  # us
