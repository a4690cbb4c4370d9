"""The closed-loop replay (autopilot/feedback.py) and the closed-loop flight (autopilot/fly.py): a vehicle flown by
the emulated ArduSub, logged at 10 Hz as a field log is, replays stably once the attitude loop is closed, and the
flight reproduces the log it was made from."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.ardusub.params import ArduSubParameters
from udrobot_ctrl.autopilot.feedback import (
    OPEN_LOOP_MAX_INTERVAL,
    attitude_error,
    command_interval,
    emulated_mixer_inputs,
    output_refresh,
    replay_feedback,
)
from udrobot_ctrl.autopilot.fly import LoggedCommands, fly
from udrobot_ctrl.autopilot.motors import MotorParameters, frame, from_pwm, mix, to_pwm, unmix
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.shrink import errors, simulate_windows
from udrobot_ctrl.io.runlog import Run, hold_previous
from udrobot_ctrl.vehicle import load_model

MODEL = "bluerov2-heavy"


def test_attitude_error_is_the_body_rotation_from_the_replay_to_the_measurement():
    eta_sim = np.zeros((1, 6))
    eta_meas = np.zeros((1, 6))
    eta_meas[0, 4] = 0.1  # measured pitch up 0.1 rad
    np.testing.assert_allclose(attitude_error(eta_sim, eta_meas)[0], [0.0, 0.1, 0.0], atol=1e-12)
    eta_sim[0, 5], eta_meas[0, 5] = 1.0, 1.0  # same heading: still a pure body-y rotation
    np.testing.assert_allclose(attitude_error(eta_sim, eta_meas)[0], [0.0, 0.1, 0.0], atol=1e-12)
    eta_meas[0, 3:6] = [0.0, 0.0, 1.0 - 0.2]  # yawed left of the replay
    np.testing.assert_allclose(attitude_error(eta_sim, eta_meas)[0], [0.0, 0.0, -0.2], atol=1e-12)


def _pilot_run(duration=24.0, dt=0.02):
    """A STABILIZE run: the pilot pushes forward, yaws and comes back (RC inputs in ArduSub's channel order)."""
    t = np.arange(0.0, duration, dt)
    rc = np.full((t.size, 8), 1500.0)
    rc[(t > 2) & (t < 10), 4] = 1700.0   # forward (channel 5)
    rc[(t > 12) & (t < 15), 3] = 1650.0  # yaw (channel 4)
    rc[(t > 16) & (t < 20), 5] = 1350.0  # lateral (channel 6)
    x0 = np.zeros(12)
    x0[2] = 5.0
    channels = {name: np.full(t.size, x0[i]) for i, name in enumerate(("x", "y", "z", "phi", "theta", "psi",
                                                                        "u", "v", "w", "p", "q", "r"))}
    extra = {"mode": np.full(t.size, float(Mode.STABILIZE)), **{f"rcin_{i + 1}": rc[:, i] for i in range(8)}}
    return Run(path="pilot.csv", t=t, channels=channels, input_kind="pwm", inputs=np.full((t.size, 8), 1500.0),
               extra=extra, metadata={"vehicle": MODEL})


@pytest.fixture(scope="module")
def logged_dive():
    """The pilot run flown by the emulated ArduSub on the model, logged as a dataflash log would: states at 50 Hz,
    motor outputs at 10 Hz (held)."""
    plan = _pilot_run()
    flight = fly(MODEL, plan, loop_rate_hz=200.0)
    t = np.arange(0.0, flight.t[-1], 0.02)
    idx = np.searchsorted(flight.t, t)
    names = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
    channels = {name: flight.x[idx, i] for i, name in enumerate(names)}
    t_log = np.arange(0.0, flight.t[-1], 0.1)
    pwm = hold_previous(t_log, flight.pwm[np.searchsorted(flight.t, t_log)], t)
    run = Run(path="dive.csv", t=t, channels=channels, input_kind="pwm", inputs=pwm,
              extra={"mode": np.full(t.size, float(Mode.STABILIZE))}, metadata={"vehicle": MODEL})
    return flight, run


@pytest.mark.slow
def test_the_flight_follows_the_pilot(logged_dive):
    flight, _ = logged_dive
    u = flight.x[:, 6]
    assert u[(flight.t > 6) & (flight.t < 10)].mean() > 0.1  # forward stick: the vehicle moves ahead
    assert abs(u[flight.t > 22].mean()) < u[(flight.t > 6) & (flight.t < 10)].mean() / 2  # and slows when released
    # the forward thrust (thrusters below the centre of mass) pitches the model up; STABILIZE levels it again
    steady = (flight.t > 8) & (flight.t < 10)
    assert np.max(np.abs(flight.x[steady, 3:5])) < np.radians(1.5)
    assert np.max(np.abs(flight.x[:, 3:5])) < np.radians(25)
    assert flight.x[-1, 5] > np.radians(5)  # the yaw stick turned it right (positive yaw)


@pytest.mark.slow
def test_a_10hz_log_is_replayed_closed_loop_and_stays_level(logged_dive):
    _, run = logged_dive
    p = plant_parameters(load_model(MODEL))
    assert command_interval(run) > OPEN_LOOP_MAX_INTERVAL
    choice = replay_feedback(run, p, "dive")
    assert choice.feedback is not None and "closed loop in roll, pitch, yaw" in choice.note
    prep = prepare(run, p, "dive")
    closed = errors(prep, simulate_windows(prep, p, (), 8.0))
    opened = errors(prep, simulate_windows(dataclasses.replace(prep, feedback=None), p, (), 8.0))

    def rms(e):
        return float(np.sqrt(np.nanmean(e ** 2)))

    for c in ("phi", "theta"):  # the true model, replayed closed loop: attitude within 1 deg of the log
        assert rms(closed[c]) < np.radians(1.0), (c, rms(closed[c]), rms(opened[c]))
        assert rms(closed[c]) < rms(opened[c])
    assert rms(closed["u"]) < 0.05  # m/s: and the logged forward/lateral still drive the translation


@pytest.mark.slow
def test_manual_runs_and_fast_logs_replay_open_loop(logged_dive):
    _, run = logged_dive
    p = plant_parameters(load_model(MODEL))
    manual = dataclasses.replace(run, extra={"mode": np.full(run.n, float(Mode.MANUAL))})
    assert replay_feedback(manual, p).feedback is None
    fast = dataclasses.replace(run, inputs=run.inputs + 0.01 * np.arange(run.n)[:, None])  # changes every 20 ms
    assert command_interval(fast) == pytest.approx(0.02)
    assert replay_feedback(dataclasses.replace(fast, t=run.t / 4), p).feedback is None  # every 5 ms: open loop
    assert replay_feedback(run, plant_parameters(load_model("pendulum:chin"))).feedback is None  # no ArduSub frame


def test_flight_refuses_a_model_without_a_frame():
    with pytest.raises(ValueError, match="ArduSub frame"):
        fly("pendulum:chin", _pilot_run(2.0))


@pytest.mark.slow
def test_a_2hz_log_is_refreshed_between_its_samples_by_the_emulated_autopilot(logged_dive):
    """The same flight logged as a QGroundControl tlog is: motor outputs at 2 Hz, the pilot's sticks at the grid
    rate. Holding a 2 Hz sample of the attitude loop's output through the pitch kicks of the stick steps drives the
    true model with a correction the real loop applied for a fraction of the hold; refreshed by the emulated
    autopilot run on the measured states, the true model's replay follows the log."""
    flight, run = logged_dive
    plan = _pilot_run()
    p = plant_parameters(load_model(MODEL))
    t_log = np.arange(0.0, flight.t[-1], 0.5)
    pwm = hold_previous(t_log, flight.pwm[np.searchsorted(flight.t, t_log)], run.t)
    sticks = {f"rcin_{i + 1}": hold_previous(plan.t, plan.extra[f"rcin_{i + 1}"], run.t) for i in range(8)}
    slow = dataclasses.replace(run, inputs=pwm, extra={**run.extra, **sticks})
    choice = replay_feedback(slow, p, "dive")
    assert choice.feedback.refresh is not None and "refreshed between output samples" in choice.note
    prep = prepare(slow, p, "dive")
    refreshed = errors(prep, simulate_windows(prep, p, (), 8.0))
    held_loop = dataclasses.replace(prep.feedback, refresh=None)  # the samples held, in the replay as in its thrust
    held_prep = dataclasses.replace(prep, feedback=held_loop, f=held_loop.thrust)
    held = errors(held_prep, simulate_windows(held_prep, p, (), 8.0))

    def rms(e):
        return float(np.sqrt(np.nanmean(e ** 2)))

    # the loop emulated at the grid's 50 Hz instead of the flight's 200 Hz leaves a fraction of a degree; the held
    # samples leave the stick steps' kicks (1.4 deg RMS in pitch, 6 deg/s in q) and a forward thrust up to 0.5 s late
    for c in ("phi", "theta", "psi"):
        assert rms(refreshed[c]) < np.radians(0.5) and rms(refreshed[c]) < rms(held[c]) / 3, c
    for c in ("p", "q", "r"):
        assert rms(refreshed[c]) < rms(held[c]) / 3, c
    assert rms(refreshed["u"]) < 0.01 and rms(refreshed["u"]) < rms(held["u"]) / 3
    # the equation error and the smoother read the same refreshed thrust as the replay: between the 2 Hz samples
    # it follows what the thrusters delivered (the flight's 200 Hz outputs at the grid's rows), the held one lags it
    true = np.clip(pwm_to_thrust(flight.pwm[np.searchsorted(flight.t, run.t)], p.supply_voltage), p.f_min, p.f_max)
    np.testing.assert_array_equal(prep.f, prep.feedback.thrust)
    assert rms(prep.f - true) < rms(held_prep.f - true) / 3


def test_a_stick_step_beside_a_logged_sample_is_not_counted_twice():
    """Forward stick steps to +0.5 at a row where an output sample is logged (the sample holds it already) and to
    0 again between two samples (the sample before does not): the refresh adds nothing to the first and the
    whole step to the second, until the next sample takes over."""
    p = plant_parameters(load_model(MODEL))
    fr = frame(p.ardusub_frame)
    motors = dataclasses.replace(MotorParameters(), directions=(1,) * fr.n_motors)
    n, dt, every = 400, 0.02, 25  # a 2 Hz output log on a 50 Hz grid
    t = np.arange(n) * dt
    forward = np.where((np.arange(n) >= 100) & (np.arange(n) < 160), 0.5, 0.0)  # on at a sample, off between two
    inputs = np.zeros((n, 6))
    inputs[:, 4] = forward
    pwm_true = to_pwm(mix(fr, inputs, motors), motors, integer=False)
    samples = np.arange(0, n, every)
    pwm = pwm_true[samples][np.searchsorted(samples, np.arange(n), side="right") - 1]
    rc = np.full(n, 1500.0) + 400.0 * forward  # RC5 about its trim, full scale 400 us
    extra = {"mode": np.full(n, float(Mode.STABILIZE)), **{f"rcin_{i}": np.full(n, 1500.0) for i in range(1, 9)}}
    extra["rcin_5"] = rc
    channels = {c: np.zeros(n) for c in ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")}
    channels["z"][:] = 5.0
    run = Run(path="steps.csv", t=t, channels=channels, input_kind="pwm", inputs=pwm, extra=extra,
              metadata={"vehicle": MODEL})
    refresh = output_refresh(run, ArduSubParameters(), fr, motors, p)
    held_plus_refresh = unmix(fr, from_pwm(pwm, motors))[:, 4] + refresh[:, 4]
    # (the emulation passes a stick to the mixer one tick later, ArduSub's order: one grid row here)
    np.testing.assert_allclose(held_plus_refresh[101:125], 0.5, atol=1e-6)  # the sample at row 100 has the step
    np.testing.assert_allclose(held_plus_refresh[161:175], 0.0, atol=1e-6)  # released at 160, next sample at 175


def _sampled_run(inputs, rc5, mode, every=25, dt=0.02):
    """A run whose mixer ``inputs`` (n, 6) are logged every ``every`` rows (a 2 Hz output log on a 50 Hz grid),
    with RC5 ``rc5`` (n,) and ``mode`` (n,); returns (run, frame, motors, plant parameters)."""
    p = plant_parameters(load_model(MODEL))
    fr = frame(p.ardusub_frame)
    motors = dataclasses.replace(MotorParameters(), directions=(1,) * fr.n_motors)
    n = inputs.shape[0]
    pwm_true = to_pwm(mix(fr, inputs, motors), motors, integer=False)
    samples = np.arange(0, n, every)
    pwm = pwm_true[samples][np.searchsorted(samples, np.arange(n), side="right") - 1]
    extra = {"mode": np.asarray(mode, float), **{f"rcin_{i}": np.full(n, 1500.0) for i in range(1, 9)}}
    extra["rcin_5"] = np.asarray(rc5, float)
    channels = {c: np.zeros(n) for c in ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")}
    channels["z"][:] = 5.0
    run = Run(path="steps.csv", t=np.arange(n) * dt, channels=channels, input_kind="pwm", inputs=pwm, extra=extra,
              metadata={"vehicle": MODEL})
    return run, fr, motors, p


@pytest.mark.parametrize("rc_offset", [1, -3])
def test_a_stick_step_whose_pilot_sample_is_logged_after_the_output_sample_is_not_counted_twice(rc_offset):
    """Older QGC logs the pilot only in RC_CHANNELS, at the outputs' 2 Hz: a forward step between two samples is
    held by the next output sample (row 100) but reaches the pilot's inputs only at the next RC sample, one row
    later (RC sent after the outputs) or 22 rows later (RC sent 3 rows before them). The sample already holds the
    step: the refresh must not add it again until the next output sample."""
    n, every = 200, 25
    rows = np.arange(n)
    forward = np.where(rows >= 98, 0.5, 0.0)  # the true step, between the samples at rows 75 and 100
    inputs = np.zeros((n, 6))
    inputs[:, 4] = forward
    rc_rows = np.arange(every + rc_offset, n, every)  # RC samples, as sparse as the outputs
    rc = 1500.0 + 400.0 * forward[rc_rows][np.clip(np.searchsorted(rc_rows, rows, side="right") - 1, 0, None)]
    rc[rows < rc_rows[0]] = 1500.0
    run, fr, motors, p = _sampled_run(inputs, rc, np.full(n, float(Mode.STABILIZE)), every)
    refresh = output_refresh(run, ArduSubParameters(), fr, motors, p)
    held = unmix(fr, from_pwm(run.inputs, motors))[:, 4]
    total = held + (refresh[:, 4] if refresh is not None else 0.0)
    np.testing.assert_allclose(total[100:150], 0.5, atol=1e-6)


def test_the_depth_loops_throttle_is_interpolated_between_its_samples():
    """In ALT_HOLD the throttle is the depth loop's output: smooth next to the 2 Hz log (it brakes a 0.7 m/s climb
    over about a second). Held, a 2 Hz sample lags it by a quarter second on average; between its samples it is
    refreshed by the straight line through them, whose error on a 0.17 Hz swing of amplitude A is at most
    A (2 pi f)^2 T^2 / 8 (T = 0.5 s), against A 2 pi f T held."""
    n, dt, every, amp, f = 500, 0.02, 25, 0.3, 0.17  # (not 0.2 Hz: two equal samples would read as one)
    t = np.arange(n) * dt
    inputs = np.zeros((n, 6))
    inputs[:, 3] = amp * np.sin(2 * np.pi * f * t)
    run, fr, motors, p = _sampled_run(inputs, np.full(n, 1500.0), np.full(n, float(Mode.ALT_HOLD)), every, dt)
    refresh = output_refresh(run, ArduSubParameters(), fr, motors, p)
    held = unmix(fr, from_pwm(run.inputs, motors))[:, 3]
    inside = t <= t[(n - 1) // every * every]  # rows before the last sample (after it there is nothing to join)
    bound = amp * (2 * np.pi * f * every * dt) ** 2 / 8 + 2e-3  # + the PWM's 1 us rounding through the mixer
    err = np.abs(held + refresh[:, 3] - inputs[:, 3])[inside]
    assert err.max() < bound, (err.max(), bound)
    assert np.abs(held - inputs[:, 3])[inside].max() > 5 * bound


def test_a_missing_pilot_sample_reads_as_a_centred_stick():
    """Before a log's first RC sample the converter leaves rcin_i empty (nan): the autopilot must see the sticks
    centred there (a nan through RC_Channel's clamps reads as a full stick), so a STABILIZE vehicle at rest gets no
    forward command from it."""
    p = plant_parameters(load_model(MODEL))
    fr = frame(p.ardusub_frame)
    motors = dataclasses.replace(MotorParameters(), directions=(1,) * fr.n_motors)
    run = _pilot_run(duration=2.0)
    for i in range(1, 9):
        run.extra[f"rcin_{i}"][:20] = np.nan  # the first RC sample at 0.4 s
    commands = LoggedCommands.from_run(run, fr, motors, p.supply_voltage)
    assert np.all(commands.rcin[:20] == 1500.0)
    emulated = emulated_mixer_inputs(run, ArduSubParameters(), fr, motors, p)
    np.testing.assert_allclose(emulated[:20, 4:6], 0.0, atol=1e-12)  # no forward, no lateral from the gap


@pytest.mark.parametrize("sentinel", [0.0, 65535.0, 700.0, 2300.0])
def test_no_pulse_and_unused_rc_values_read_as_a_centred_stick(sentinel):
    """0 us ("no pulse") and 65535 (MAVLink's UINT16_MAX, "unused") are not stick positions: outside ArduPilot's
    valid pulse range (RC_Channel::RC_MIN_LIMIT_PWM 800 to RC_MAX_LIMIT_PWM 2200 us) a sample is read as a centred
    stick. Read as a pulse, 65535 on the throttle was a full climb and 0 a full dive; the forward stick alike."""
    p = plant_parameters(load_model(MODEL))
    fr = frame(p.ardusub_frame)
    motors = dataclasses.replace(MotorParameters(), directions=(1,) * fr.n_motors)
    run = _pilot_run(duration=2.0)
    for i in (3, 5):  # throttle and forward
        run.extra[f"rcin_{i}"][:50] = sentinel
    commands = LoggedCommands.from_run(run, fr, motors, p.supply_voltage)
    assert np.all(commands.rcin[:50, [2, 4]] == 1500.0)
    emulated = emulated_mixer_inputs(run, ArduSubParameters(), fr, motors, p)
    centred = emulated_mixer_inputs(_pilot_run(duration=2.0), ArduSubParameters(), fr, motors, p)
    np.testing.assert_allclose(emulated[:50], centred[:50], atol=1e-12)
