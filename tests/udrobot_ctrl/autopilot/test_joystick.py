"""Pilot inputs from the joystick QGroundControl sent (MANUAL_CONTROL, ~24 Hz) through ArduSub's conversion, the
pilot gain calibrated on the 2 Hz RC_CHANNELS: synthetic tlogs built with pymavlink's encoder (the overrides made
by ArduSub's own formula at a known gain, changed mid-log), and the shared real BlueROV2 tlog when present."""
from __future__ import annotations

import re
from importlib import resources

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from tests.udrobot_ctrl.io.test_field_logs import ARDUSUB_LOGS, T0, _mav, dive_tlog, params_events
from udrobot_ctrl.autopilot.joystick import GAIN_STEP, pilot_input, rc_override
from udrobot_ctrl.convert import convert_log
from udrobot_ctrl.io import load_mapping
from udrobot_ctrl.io.mapping import parse_mapping
from udrobot_ctrl.io.mavlink import read_tlog_streams

MC_RATE = 24.0  # Hz, QGC's joystick rate (23.6 Hz measured on the shared tlog)
RC_RATE = 2.0  # Hz, QGC's default RC_CHANNELS rate
UPLINK, DOWNLINK = 0.012, 0.020  # s, assumed link delays (the shared tlog: RC 3..66 ms after its MANUAL_CONTROL)
GAIN_CHANGE = 30.0  # s: the pilot presses gain-up (0.5 -> 0.75, the next JS_GAIN_STEPS = 4 setting)
HOLD = (45.0, 48.0)  # s: input hold engaged (forward trim the joystick does not show): ch5 reported at 1700 us
DURATION = 60.0
JS_PARAMS = {"JS_GAIN_DEFAULT": 0.5, "JS_GAIN_MIN": 0.25, "JS_GAIN_MAX": 1.0, "JS_GAIN_STEPS": 4, "JS_THR_GAIN": 1.0}
TILT = 1620  # us, camera tilt (channel 8), held by ArduSub, not from the sticks


def stick_program(seed=3):
    """Step times (s, not on any message grid) and the sticks x, y, z, r held from each step."""
    rng = np.random.default_rng(seed)
    steps = np.cumsum(rng.uniform(0.7, 1.9, 60))
    steps = steps[steps < DURATION - 1.0]
    sticks = np.column_stack([rng.integers(-1000, 1001, steps.size), rng.integers(-1000, 1001, steps.size),
                              rng.integers(0, 1001, steps.size), rng.integers(-1000, 1001, steps.size)])
    return np.r_[0.0, steps], np.vstack([[0, 0, 500, 0], sticks])


def sticks_at(t, program):
    steps, sticks = program
    return sticks[np.searchsorted(steps, t, side="right") - 1]


def gain_at(t):
    return np.where(np.asarray(t) < GAIN_CHANGE, 0.5, 0.75)


def joystick_events(program, rc=True, hold=True, seed=4):
    """MANUAL_CONTROL from QGC (system 255, component 190) at ~24 Hz with jitter; RC_CHANNELS at 2 Hz made by
    ArduSub's formula from the last MANUAL_CONTROL it received, at the gain of that moment."""
    rng = np.random.default_rng(seed)
    gcs = mav2.MAVLink(None, srcSystem=255, srcComponent=190)
    mav = _mav()
    ev = [(t + 0.5, gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(gcs)) for t in np.arange(0.0, DURATION, 1.0)]
    t_mc = np.arange(0.2, DURATION, 1.0 / MC_RATE) + rng.uniform(0.0, 0.008, int(np.ceil((DURATION - 0.2) * MC_RATE)))
    t_mc = np.sort(t_mc[t_mc < DURATION])
    axes = sticks_at(t_mc, program)
    for t, (x, y, z, r) in zip(t_mc, axes):
        ev.append((t, gcs.manual_control_encode(1, int(x), int(y), int(z), int(r), 0).pack(gcs)))
    if rc:
        for t in np.arange(0.13, DURATION, 1.0 / RC_RATE):
            j = np.searchsorted(t_mc + UPLINK, t - DOWNLINK, side="right") - 1
            if j < 0:
                continue
            chans = rc_override(*axes[j], gain_at(t_mc[j] + UPLINK), JS_PARAMS["JS_THR_GAIN"])
            ch = [1500, 1500, *[int(c) for c in chans], 1500, TILT]
            if hold and HOLD[0] <= t < HOLD[1]:
                ch[4] = 1700
            ev.append((t, mav.rc_channels_encode(int(t * 1000), 8, *ch, *[0] * 10, 255)))
            gain = float(gain_at(t - DOWNLINK))  # ArduSub's own report of its pilot gain
            ev.append((t + 0.001, mav.named_value_float_encode(int(t * 1000), b"PilotGain", gain)))
    return ev, t_mc


def joystick_tlog(path, program, **kw):
    ev, t_mc = joystick_events(program, **kw)
    mav = _mav()
    return dive_tlog(path, lambda t: 1.0, duration=DURATION, extra=ev + params_events(mav, JS_PARAMS, 0.002)), t_mc


def grid_times(run):
    """Log times (s after T0) of the run's rows, from the notes' exact time origin."""
    origin = float(re.search(r"t = 0 is log time ([0-9.]+) s", run.metadata["notes"]).group(1))
    return origin - T0 + run.t


def expected_forward(t, program):
    """ArduSub's forward override (us) for the sticks held at log time ``t`` and the gain of that moment."""
    x, y, z, r = sticks_at(t, program).T
    return rc_override(x, y, z, r, gain_at(t))[:, 2]


def late_rows(t, steps, lag):
    """Rows within ``lag`` s after a stick step (where a held command may still be the old one), and within one
    RC_CHANNELS interval of the gain change (the 2 Hz reports place it no better)."""
    k = np.searchsorted(steps, t, side="right") - 1
    return ((k >= 0) & (t - steps[np.clip(k, 0, None)] <= lag)) | (np.abs(t - GAIN_CHANGE) <= 1.0 / RC_RATE)


def test_rcin_follows_the_24_hz_joystick_with_the_gain_fitted_on_rc_channels(tmp_path):
    program = stick_program()
    path, t_mc = joystick_tlog(tmp_path / "j.tlog", program)
    run = convert_log(path, "ardusub", cut=False)
    notes = run.metadata["notes"]
    t = grid_times(run)
    fwd = run.extra["rcin_5"]
    # timing: a stick step shows within one joystick interval (1/24 s + 8 ms jitter) and one 50 Hz grid step
    lag = 1.0 / MC_RATE + 0.008 + 1.0 / 50.0 + 1e-6
    clear = (t > t_mc[0] + 0.1) & ~((t >= HOLD[0] - 0.5) & (t < HOLD[1] + 0.5))
    expected = expected_forward(t, program)
    wrong = clear & (fwd != expected)
    assert not (wrong & ~late_rows(t, program[0], lag)).any()
    assert wrong.sum() < 0.5 * late_rows(t, program[0], lag).sum()  # most steps show on their first grid row
    assert "rcin_1/rcin_2/rcin_3/rcin_4/rcin_5/rcin_6/rcin_7/rcin_8 <- PILOT_RC" in notes
    # the same log from RC_CHANNELS alone (the mapping without the joystick rule) lags by up to 1/2 s
    slow = convert_log(path, rc_only_mapping(), cut=False)
    t_slow, fwd_slow = grid_times(slow), slow.extra["rcin_5"]
    clear_slow = (t_slow > 1.0) & ~((t_slow >= HOLD[0] - 0.5) & (t_slow < HOLD[1] + 0.5))
    late_slow = clear_slow & (fwd_slow != expected_forward(t_slow, program)) & ~late_rows(t_slow, program[0], lag)
    assert late_slow.mean() > 0.1
    # channels ArduSub does not take from the sticks come from RC_CHANNELS (held from its first report, 0.63 s)
    ok = t > 0.64
    np.testing.assert_array_equal(run.extra["rcin_8"][ok], TILT)
    np.testing.assert_array_equal(run.extra["rcin_1"][ok], 1500)
    # input hold: RC_CHANNELS says 1700 while the sticks say otherwise; there the converter keeps RC_CHANNELS
    inside = (t > HOLD[0] + 0.5) & (t < HOLD[1] - 0.5)
    np.testing.assert_array_equal(fwd[inside], 1700)
    assert "not reproduced by the joystick at one gain" in notes


def rc_only_mapping():
    """The shipped ardusub mapping without its PILOT_RC rule (pilot inputs from RC_CHANNELS alone)."""
    text = (resources.files("udrobot_ctrl.models") / "mappings" / "ardusub.toml").read_text(encoding="utf-8")
    block = re.search(r"\[\[channels\]\]\ncomment = \"\"\"tlog with MANUAL_CONTROL.*?\n\n", text, re.S).group(0)
    return parse_mapping(text.replace(block, ""), "ardusub without PILOT_RC")


def test_gain_and_its_change_are_recovered(tmp_path):
    program = stick_program(seed=5)
    path, _ = joystick_tlog(tmp_path / "g.tlog", program)
    mapping = load_mapping("ardusub")
    decoded = read_tlog_streams(path, mapping, mapping.optional_needs())
    rc = decoded.streams["RC_CHANNELS"]
    pilot = pilot_input(decoded.streams["MANUAL_CONTROL"], rc, decoded.facts.params,
                        decoded.facts.named["PilotGain"])
    gains = [s.gain for s in pilot.stretches]
    assert gains == [0.5, 0.75]
    for s, true in zip(pilot.stretches, (0.5, 0.75)):
        assert s.lo <= true <= s.hi and s.hi - s.lo < 2.5 * 1 / 400 + GAIN_STEP  # a full-stick sample: 1/400
    (a, b), = pilot.changes
    # the change is placed between the last sample of the old gain and the first of the new: within 1/2 s + delays
    assert a - T0 < GAIN_CHANGE + UPLINK + DOWNLINK < b - T0 + 1e-9 and b - a <= 1.0 / RC_RATE + 1e-6
    notes = "\n".join(pilot.notes)
    assert "gain changed from 0.5 to 0.75" in notes and "an ArduSub gain setting" in notes
    # ArduSub's own gain reports agree except, at most, the one report between the last old and first new sample
    used = re.search(r"PilotGain \(values 0.5, 0.75\) equals the gain used at (\d+) of (\d+) reports", notes)
    assert used and int(used.group(2)) - 1 <= int(used.group(1)) < int(used.group(2)) + 1


def test_rc_channels_only_log_converts_as_before(tmp_path):
    program = stick_program()
    ev, _ = joystick_events(program, hold=False)
    rc_only = [(t, m) for t, m in ev if not (isinstance(m, (bytes, bytearray)) and m[7] == 69)]  # MANUAL_CONTROL id 69
    assert len(rc_only) < len(ev)
    path = dive_tlog(tmp_path / "r.tlog", lambda t: 1.0, duration=DURATION, extra=rc_only)
    run = convert_log(path, "ardusub", cut=False)
    notes = run.metadata["notes"]
    assert "pilot input:" not in notes and "<- RC_CHANNELS[chan1_raw" in notes
    same = convert_log(path, rc_only_mapping(), cut=False)
    for c in range(1, 9):
        np.testing.assert_array_equal(run.extra[f"rcin_{c}"], same.extra[f"rcin_{c}"])


def test_without_rc_channels_the_gain_is_the_logged_default_and_tagged_assumed(tmp_path):
    program = stick_program()
    ev, _ = joystick_events(program, rc=False)
    mav = _mav()
    params = {**JS_PARAMS, "JS_GAIN_DEFAULT": 0.75}
    ev += params_events(mav, params, 0.002)
    path = dive_tlog(tmp_path / "n.tlog", lambda t: 1.0, duration=DURATION, extra=ev)
    run = convert_log(path, "ardusub", cut=False)
    notes = run.metadata["notes"]
    assert "no RC_CHANNELS to calibrate the pilot gain on: gain 0.75 ASSUMED (JS_GAIN_DEFAULT from the log" in notes
    t = grid_times(run)
    x, y, z, r = sticks_at(t, program).T
    lag = 1.0 / MC_RATE + 0.008 + 1.0 / 50.0 + 1e-6
    ok = ~late_rows(t, program[0], lag) & (t > 0.3)
    np.testing.assert_array_equal(run.extra["rcin_3"][ok], rc_override(x, y, z, r, 0.75)[ok, 0])
    assert np.isnan(run.extra["rcin_8"]).all() and (run.extra["rcin_1"][ok] == 1500).all()


REAL_TLOGS = ("2023-04-18 11-03-34.tlog", "small.tlog")
REPORT_DELAY = 0.12  # s: a report shows a joystick message sent at most this long before it (<= 82 ms measured)


@pytest.mark.skipif(not ARDUSUB_LOGS.is_dir(), reason="shared ArduSub logs not present")
@pytest.mark.parametrize("name", REAL_TLOGS)
def test_real_qgc_tlog_pilot_input_from_manual_control_agrees_with_rc_channels(name):
    """The shared BlueROV2 tlogs: QGC's MANUAL_CONTROL at ~23.6 Hz; every RC_CHANNELS report (2 Hz) of ArduSub's
    overrides is met within its report delay by the converted joystick on the run's grid, at the fitted gain, which
    is the boot gain JS_GAIN_DEFAULT and what ArduSub's own PilotGain reports say."""
    path = ARDUSUB_LOGS / name
    run = convert_log(path, "ardusub", cut=False)
    notes = run.metadata["notes"]
    src = re.search(r"rcin_1/\S+ <- PILOT_RC\[[^]]*\] \(none, scale 1, offset 0; (\d+) samples", notes)
    assert src and "system 255, component 190" in notes
    assert 20.0 < float(re.search(r"messages, ([0-9.]+) Hz", notes).group(1)) < 26.0
    gain = float(re.search(r"pilot input: gain ([0-9.]+) \(", notes).group(1))
    mapping = load_mapping("ardusub")
    decoded = read_tlog_streams(path, mapping, mapping.optional_needs())
    assert gain == decoded.facts.params["JS_GAIN_DEFAULT"]
    reports = re.search(r"PilotGain \(values ([0-9., ]+)\) equals the gain used at (\d+) of (\d+) reports", notes)
    assert reports.group(1) == f"{gain:g}" and reports.group(2) == reports.group(3)
    mc, rc = decoded.streams["MANUAL_CONTROL"], decoded.streams["RC_CHANNELS"]
    t = grid_times(run)
    inside = (rc.t - T0 > max(t[0], mc.t[0] - T0) + 1.0) & (rc.t - T0 < t[-1])
    assert inside.sum() > 100
    assert int(src.group(1)) >= mc.t.size  # every joystick message is a pilot-input sample
    joy = np.column_stack([run.extra[f"rcin_{c}"] for c in (3, 4, 5, 6)])
    reported = np.column_stack([rc.fields[f"chan{c}_raw"] for c in (3, 4, 5, 6)])
    for t_rc, chans in zip(rc.t[inside] - T0, reported[inside]):
        rows = (t >= t_rc - REPORT_DELAY) & (t <= t_rc + 1.0 / 50.0)
        assert (np.abs(joy[rows] - chans).max(axis=1) <= 2.0).any()  # us: ArduSub's integer arithmetic reproduced


@pytest.mark.skipif(not ARDUSUB_LOGS.is_dir(), reason="shared ArduSub logs not present")
def test_real_sticks_show_at_the_joystick_rate():
    """small.tlog, where the pilot moved the sticks for its last minute: the pilot inputs change several times more
    often than the 2 Hz RC_CHANNELS alone shows."""
    path = ARDUSUB_LOGS / "small.tlog"
    run = convert_log(path, "ardusub", cut=False)
    slow = convert_log(path, rc_only_mapping(), cut=False)
    for c in (3, 4, 5, 6):
        fast_changes = np.count_nonzero(np.diff(run.extra[f"rcin_{c}"]))
        slow_changes = np.count_nonzero(np.diff(slow.extra[f"rcin_{c}"]))
        assert fast_changes > 3 * slow_changes > 0
