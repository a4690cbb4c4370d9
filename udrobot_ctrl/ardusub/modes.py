"""ArduSub's flight modes' inputs: RC channels -> pilot demands, the mode numbers, GUIDED/SURFTRAK targets.

Sources (ArduPilot, ArduSub 4.1-4.5):

* ``ArduSub/radio.cpp`` ``init_rc_in``: channel order pitch 1, roll 2, throttle 3, yaw 4, forward 5, lateral 6
  (RCMAP disabled), roll/pitch/yaw/forward/lateral are *angle* channels of +-4500, throttle a *range* channel of
  0..1000 (:data:`~udrobot_ctrl.ardusub.params.RC_MAP`).
* ``libraries/RC_Channel/RC_Channel.cpp``: ``norm_input`` (-1..1 about the trim, each side scaled to its own end:
  with ``RCn_TRIM = RCn_MIN`` it runs 0..1), ``norm_input_dz`` (the same outside ``trim +- RCn_DZ``),
  ``pwm_to_angle_dz_trim`` (+-high_in outside the dead zone), ``pwm_to_range_dz`` (0..high_in from ``min + dz``),
  ``get_control_mid``; ``RCn_REVERSED`` flips each.
* ``ArduSub/Attitude.cpp``: ``get_pilot_desired_lean_angles`` (sticks scaled to ``ANGLE_MAX``, circular limit,
  lateral tilt -> Euler roll), ``get_pilot_desired_yaw_rate`` (``stick * ACRO_YAW_P`` cdeg/s),
  ``get_pilot_desired_climb_rate`` (``THR_DZ`` about mid stick, ``PILOT_SPEED_UP``/``DN``).
* ``ArduSub/mode_manual.cpp`` (``control_manual.cpp`` before 4.1): roll, pitch, forward, lateral = ``norm_input``;
  yaw = ``norm_input * ACRO_YAW_P / ACRO_YAW_P_default``; ``motors.set_throttle(channel_throttle->norm_input())``.
* ``ArduSub/mode_stabilize.cpp``, ``mode_althold.cpp``: lean angles and yaw rate from the sticks (the yaw stick's
  dead zone is ``RC4_DZ`` times the pilot gain: ``pwm_to_angle_dz_trim(get_dead_zone() * sub.gain, trim)``; on the
  sea dive, which logs no parameters, 40 x 0.5 fits its horizontal motors twice as well as 40); the heading is
  held (``input_euler_angle_roll_pitch_yaw`` with ``last_pilot_heading``) 250 ms after the yaw stick returns to
  centre; forward/lateral = ``norm_input``; STABILIZE's throttle ``set_throttle_out(channel_throttle->
  norm_input(), false, PILOT_THR_FILT)``, ALT_HOLD's from the depth loop with the stick as a climb rate.

Throttle in the manual modes (:func:`pilot_throttle`). ``AP_Motors6DOF`` reads the throttle as 0..1 with 0.5
neutral (``get_throttle_bidirectional = 2 (throttle - 0.5)``, clamped to +-1). ArduSub 4.1-4.5 give it the
throttle channel's ``norm_input`` *as it is*: on an ArduSub vehicle ``RC3_TRIM = RC3_MIN`` (1100, Sub's default
in those versions and what QGroundControl's calibration sets), so ``norm_input`` is ``(pwm - 1100) / (RC3_MAX -
1100)``: 0..1 with 0.5 at 1500 us. A log with another trim is read as the firmware reads it (e.g. a trim of 1500
puts a centred stick at throttle 0, full down-thrust, and below the trim the motors clamp the negative throttle).
ArduPilot master after 4.5 passes ``(norm_input + 1) / 2`` with a ``RC3_TRIM`` default of 1500 instead
(:attr:`~udrobot_ctrl.ardusub.params.PilotParameters.throttle_norm_centred`); both give 0.5 at a centred stick
with their own default trim.

RC overrides from a joystick (``ArduSub/joystick.cpp`` ``transform_manual_control_to_rc_override``,
:mod:`udrobot_ctrl.autopilot.joystick`) are PWM: channel 3 is ``z * 0.8 gain JS_THR_GAIN + 1500 - 500 * 0.8 gain
JS_THR_GAIN``, 1500 us at z = 500 whatever the trims; the trims act afterwards, here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from udrobot_ctrl.ardusub.params import CDEG, RC_MAP, DepthParameters, PilotParameters, RCChannel

ROLL_PITCH_INPUT_MAX = 4500.0   # ArduSub/config.h, centidegrees of stick
ACRO_YAW_P_DEFAULT = 3.375      # ArduSub/config.h ACRO_YAW_P (the MANUAL mode's yaw scaling reference)
YAW_HOLD_DELAY = 0.25           # s, mode_stabilize.cpp / mode_althold.cpp "give 250ms to slow down"
RC_MIN_LIMIT_PWM = 800.0        # us, RC_Channel.h: a pulse at or outside these bounds is a receiver or wiring error
RC_MAX_LIMIT_PWM = 2200.0       # us (0: no pulse; 65535: MAVLink's UINT16_MAX "unused")
PWM_CENTRE = 1500.0             # us, a centred stick


class Mode(IntEnum):
    """ArduSub's mode numbers (``ArduSub/defines.h`` / ``mode.h``, the MODE log's ``ModeNum``)."""

    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    CIRCLE = 7
    SURFACE = 9
    POSHOLD = 16
    MANUAL = 19
    MOTOR_DETECT = 20
    SURFTRAK = 21


@dataclass(frozen=True)
class PilotInput:
    """The RC inputs (``RCIN`` C1..C8 or the joystick's RC overrides), PWM in microseconds.

    Parameters
    ----------
    pwm : tuple of float
        Channels 1..n (at least 6), us.
    """

    pwm: tuple = (1500.0,) * 8

    def channel(self, name: str) -> float:
        """The PWM (us) of the named input (``RC_MAP``: pitch, roll, throttle, yaw, forward, lateral)."""
        return float(self.pwm[RC_MAP[name] - 1])

    @classmethod
    def centred(cls) -> PilotInput:
        """All sticks at 1500 us."""
        return cls()

    @classmethod
    def from_sticks(cls, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0, throttle: float = 0.0,
                    forward: float = 0.0, lateral: float = 0.0) -> PilotInput:
        """Sticks in -1..1 (0 centred) -> PWM ``1500 + 400 x`` in ArduSub's channel order."""
        pwm = [1500.0] * 8
        for name, x in (("roll", roll), ("pitch", pitch), ("yaw", yaw), ("throttle", throttle),
                        ("forward", forward), ("lateral", lateral)):
            pwm[RC_MAP[name] - 1] = 1500.0 + 400.0 * max(-1.0, min(1.0, x))
        return cls(tuple(pwm))


# ------------------------------------------------------------------------------------------ RC_Channel


def norm_input(pwm: float, ch: RCChannel) -> float:
    """``RC_Channel::norm_input``: -1..1 about the trim (dead zone ignored)."""
    sign = -1.0 if ch.reversed else 1.0
    if pwm < ch.trim:
        if ch.min >= ch.trim:
            return 0.0
        ret = sign * (pwm - ch.trim) / (ch.trim - ch.min)
    else:
        if ch.max <= ch.trim:
            return 0.0
        ret = sign * (pwm - ch.trim) / (ch.max - ch.trim)
    return max(-1.0, min(1.0, ret))


def norm_input_dz(pwm: float, ch: RCChannel) -> float:
    """``RC_Channel::norm_input_dz``: -1..1 outside ``trim +- RCn_DZ``, 0 inside (each side scaled to its end)."""
    sign = -1.0 if ch.reversed else 1.0
    dz_min, dz_max = ch.trim - ch.dead_zone, ch.trim + ch.dead_zone
    if pwm < dz_min and dz_min > ch.min:
        ret = sign * (pwm - dz_min) / (dz_min - ch.min)
    elif pwm > dz_max and ch.max > dz_max:
        ret = sign * (pwm - dz_max) / (ch.max - dz_max)
    else:
        ret = 0.0
    return max(-1.0, min(1.0, ret))


def pilot_throttle(norm: float, centred: bool = False) -> float:
    """The manual modes' throttle (``throttle_in``, 0..1 before the motors' clamp) from the throttle channel's
    ``norm_input`` (module notes): ``norm`` as it is (ArduSub 4.1-4.5) or ``(norm + 1) / 2`` (``centred``, master).

    Parameters
    ----------
    norm : float
        ``norm_input`` of the throttle channel (-1..1).
    centred : bool
        :attr:`~udrobot_ctrl.ardusub.params.PilotParameters.throttle_norm_centred`.

    Returns
    -------
    float
        Throttle; the motors clamp it to 0..1 (``throttle_bidirectional`` to +-1).
    """
    return (norm + 1.0) / 2.0 if centred else norm


def pwm_to_angle_dz_trim(pwm: float, ch: RCChannel, dead_zone: float, trim: float,
                         high_in: float = 4500.0) -> float:
    """``RC_Channel::pwm_to_angle_dz_trim``: +-``high_in`` outside ``trim +- dead_zone`` (ArduSub's int16 kept
    as float)."""
    sign = -1.0 if ch.reversed else 1.0
    hi, lo = trim + dead_zone, trim - dead_zone
    r = max(ch.min, min(ch.max, pwm))
    if r > hi and ch.max != hi:
        return sign * high_in * (r - hi) / (ch.max - hi)
    if r < lo and lo != ch.min:
        return sign * high_in * (r - lo) / (lo - ch.min)
    return 0.0


def pwm_to_range_dz(pwm: float, ch: RCChannel, dead_zone: float, high_in: float = 1000.0) -> float:
    """``RC_Channel::pwm_to_range_dz``: 0..``high_in`` from ``min + dead_zone`` to ``max``."""
    r = max(ch.min, min(ch.max, pwm))
    if ch.reversed:
        r = ch.max - (r - ch.min)
    low = ch.min + dead_zone
    return high_in * (r - low) / (ch.max - low) if r > low else 0.0


def control_mid(ch: RCChannel, high_in: float = 1000.0) -> float:
    """``RC_Channel::get_control_mid`` of a range channel: the control value at mid stick (0..1000)."""
    r = (ch.min + ch.max) / 2.0
    low = ch.min + ch.dead_zone
    return high_in * (r - low) / (ch.max - low)


# ------------------------------------------------------------------------------------ ArduSub/Attitude.cpp


def pilot_lean_angles(roll_in: float, pitch_in: float, angle_max: float, angle_limit: float) -> tuple:
    """``Sub::get_pilot_desired_lean_angles``: sticks (centidegrees, +-4500) -> Euler roll, pitch (rad).

    Parameters
    ----------
    roll_in, pitch_in : float
        Stick control values (cdeg, +-``ROLL_PITCH_INPUT_MAX``).
    angle_max : float
        ``ANGLE_MAX`` (rad), sanity-limited to 10..80 deg as ArduSub does.
    angle_limit : float
        The mode's limit (rad): ``ANGLE_MAX`` in STABILIZE, the alt-hold lean limit in ALT_HOLD.
    """
    amax = min(max(angle_max / CDEG, 1000.0), 8000.0)
    limit = min(max(angle_limit / CDEG, 1000.0), amax)
    scaler = amax / ROLL_PITCH_INPUT_MAX
    roll_in, pitch_in = roll_in * scaler, pitch_in * scaler
    total = math.hypot(pitch_in, roll_in)
    if total > limit:
        roll_in, pitch_in = roll_in * limit / total, pitch_in * limit / total
    roll_rad = math.atan(math.cos(pitch_in * CDEG) * math.tan(roll_in * CDEG))
    return roll_rad, pitch_in * CDEG


def pilot_pulses(pwm) -> np.ndarray:
    """Logged RC inputs (us) as pulses the emulation can read: a sample that is no pulse is a centred stick.

    A logged value outside ArduPilot's valid pulse range (``RC_Channel::RC_MIN_LIMIT_PWM`` 800 us to
    ``RC_MAX_LIMIT_PWM`` 2200 us, bounds excluded, as ``read_3pos_switch`` treats them: 0 for "no pulse", 65535
    for MAVLink's "unused") or not finite (no sample yet, a gap) is not a stick position; read as one, 0 us or
    65535 us would be a full stick. Such samples are read as :data:`PWM_CENTRE`, every channel's neutral.

    Parameters
    ----------
    pwm : array_like
        RC input samples, us.

    Returns
    -------
    ndarray
        The same shape, us, every sample within (800, 2200).
    """
    pwm = np.asarray(pwm, float)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(pwm) & (pwm > RC_MIN_LIMIT_PWM) & (pwm < RC_MAX_LIMIT_PWM)
    return np.where(ok, pwm, PWM_CENTRE)


def logged_pulses(extra, n: int, notes: list) -> np.ndarray | None:
    """The logged RC inputs ``rcin_1`` .. ``rcin_8`` of a run's columns as pulses (:func:`pilot_pulses`), (n, 8) us.

    A missing channel is a centred stick on that channel alone (never are the eight dropped for one), said in
    ``notes`` (appended to); None, also said, when the run has none of the eight.

    Parameters
    ----------
    extra : mapping of str to ndarray
        The run's extra columns.
    n : int
        Rows.
    notes : list of str
        Appended to (pass a throw-away list when no row is flown on the pilot's inputs).
    """
    rc = [extra.get(f"rcin_{i}") for i in range(1, 9)]
    missing = [i for i, c in enumerate(rc, start=1) if c is None]
    if len(missing) == 8:
        notes.append("closed loop: no rcin_1..rcin_8 columns: the pilot's sticks are read as centred (1500 us) in "
                     "MANUAL/STABILIZE/ALT_HOLD")
        return None
    if missing:
        notes.append(f"closed loop: no {', '.join(f'rcin_{i}' for i in missing)} column(s): that RC input is read as "
                     f"a centred stick (1500 us); the other channels as logged")
    return pilot_pulses(np.column_stack([np.full(n, np.nan) if c is None else np.asarray(c, float) for c in rc]))


def logged_targets(extra, column: str, rows, mode, t, where: str, notes: list) -> np.ndarray:
    """The logged target ``column`` (``roll_target`` ... ``z_target``) where ``rows`` are flown on it.

    Refused when it is missing, or empty in every such row: a target that was not logged is never flown as zero
    or as whatever the controller held. An empty cell between logged ones holds the last logged target (the
    first one before it); ``notes`` counts those rows.

    Parameters
    ----------
    extra : mapping of str to ndarray
        The run's extra columns.
    column : str
    rows : (n,) bool ndarray
        Rows flown on the logged targets.
    mode : (n,) ndarray
        The mode of each row (ArduSub numbers, for the message).
    t : (n,) ndarray
        Row times from the first row, s (for the message).
    where : str
        The run's file, for the message.
    notes : list of str
        Appended to.

    Raises
    ------
    ValueError
        Naming the file, the column, the modes and the first such row.
    """
    rows = np.asarray(rows, bool)
    names = ", ".join(Mode(int(m)).name for m in np.unique(mode[rows]))
    values = extra.get(column)
    values = None if values is None else np.asarray(values, float)
    if values is None or not np.isfinite(values[rows]).any():
        state = "no such column" if values is None else "an empty cell in every such row"
        raise ValueError(f"{where}: column '{column}': {state}, but {int(rows.sum())} rows are flown in {names} on "
                         f"the logged targets (the first {float(t[np.flatnonzero(rows)[0]]):.2f} s into the run); "
                         f"expected the logged target (docs/formats/runlog.md): a target that was not logged is not "
                         f"flown")
    finite = np.isfinite(values)
    last = np.maximum.accumulate(np.where(finite, np.arange(values.size), -1))
    held = values[np.where(last >= 0, last, int(np.flatnonzero(finite)[0]))]
    gaps = int((rows & ~finite).sum())
    if gaps:
        notes.append(f"closed loop: {column} empty in {gaps} of {int(rows.sum())} rows flown on the logged targets "
                     f"({names}): the last logged target is held there")
    return held


def pilot_yaw_rate(yaw_in: float, acro_yaw_p: float) -> float:
    """``Sub::get_pilot_desired_yaw_rate``: yaw stick (cdeg, +-4500) -> yaw rate (rad/s) = stick x ACRO_YAW_P cdeg/s."""
    return yaw_in * acro_yaw_p * CDEG


def pilot_climb_rate(throttle_control: float, mid: float, params: PilotParameters, depth: DepthParameters) -> float:
    """``Sub::get_pilot_desired_climb_rate``: throttle control (0..1000) -> climb rate (m/s, positive *up*).

    The dead band is ``mid +- THR_DZ * gain`` (``THR_DZ`` constrained to 0..400, ``gain`` the pilot gain,
    :attr:`~udrobot_ctrl.ardusub.params.PilotParameters.gain`); below it the rate runs to ``-PILOT_SPEED_DN`` at
    throttle 0, above it to ``PILOT_SPEED_UP`` at 1000; ``control_depth`` constrains it to those speeds.
    """
    dz = max(0.0, min(400.0, params.throttle_deadzone)) * params.gain
    top, bottom = mid + dz, mid - dz
    t = max(0.0, min(1000.0, throttle_control))
    if t < bottom:
        rate = depth.speed_down_effective * (t - bottom) / bottom
    elif t > top:
        rate = abs(depth.speed_up) * (t - top) / (1000.0 - top)
    else:
        rate = 0.0
    return min(max(rate, -depth.speed_down_effective), abs(depth.speed_up))


@dataclass(frozen=True)
class PilotCommand:
    """The pilot's sticks read as ArduSub's modes read them (SI).

    Attributes
    ----------
    norm : dict
        ``norm_input`` (-1..1) per input name (MANUAL's pass-through; forward and lateral in every pilot mode).
    roll, pitch : float
        Lean-angle targets (rad) in STABILIZE (``ANGLE_MAX`` limit).
    yaw_rate : float
        Yaw-rate target (rad/s) from the yaw stick outside its dead zone.
    throttle : float
        Manual throttle (:func:`pilot_throttle`; 0.5 neutral, the motors clamp it to 0..1).
    climb_rate : float
        ALT_HOLD's climb rate demand (m/s, positive up).
    """

    norm: dict
    roll: float
    pitch: float
    yaw_rate: float
    throttle: float
    climb_rate: float


def shape_pilot(pilot: PilotInput, params: PilotParameters, depth: DepthParameters,
                angle_limit: float | None = None) -> PilotCommand:
    """Read the RC inputs as ArduSub's STABILIZE / ALT_HOLD / MANUAL do (module docstring for the sources).

    Parameters
    ----------
    pilot : PilotInput
        RC PWM (us).
    params, depth : PilotParameters, DepthParameters
    angle_limit : float, optional
        Lean limit (rad); ``ANGLE_MAX`` if None.
    """
    ch = params.channels
    norm = {name: norm_input(pilot.channel(name), ch[name]) for name in RC_MAP}
    roll_in = pwm_to_angle_dz_trim(pilot.channel("roll"), ch["roll"], ch["roll"].dead_zone, ch["roll"].trim)
    pitch_in = pwm_to_angle_dz_trim(pilot.channel("pitch"), ch["pitch"], ch["pitch"].dead_zone, ch["pitch"].trim)
    roll, pitch = pilot_lean_angles(roll_in, pitch_in, params.angle_max,
                                    params.angle_max if angle_limit is None else angle_limit)
    # mode_stabilize.cpp / mode_althold.cpp: pwm_to_angle_dz_trim(channel_yaw->get_dead_zone() * sub.gain, trim)
    yaw_in = pwm_to_angle_dz_trim(pilot.channel("yaw"), ch["yaw"], ch["yaw"].dead_zone * params.gain, ch["yaw"].trim)
    thr_ch = ch["throttle"]
    throttle_control = pwm_to_range_dz(pilot.channel("throttle"), thr_ch, thr_ch.dead_zone)
    climb = pilot_climb_rate(throttle_control, control_mid(thr_ch), params, depth)
    return PilotCommand(norm=norm, roll=roll, pitch=pitch, yaw_rate=pilot_yaw_rate(yaw_in, params.acro_yaw_p),
                        throttle=pilot_throttle(norm["throttle"], params.throttle_norm_centred),
                        climb_rate=climb)


@dataclass(frozen=True)
class Targets:
    """GUIDED / SURFTRAK targets (the logged or the commanded ones), SI.

    Attributes
    ----------
    roll, pitch : float
        Attitude targets (rad) (ATT.DesRoll/DesPitch).
    yaw : float or None
        Heading target (rad) (ATT.DesYaw); None -> ``yaw_rate`` is used.
    yaw_rate : float
        Euler yaw-rate target (rad/s) when ``yaw`` is None; with ``shaped``, the target's Euler yaw rate.
    roll_rate, pitch_rate : float
        With ``shaped``: the target's Euler roll and pitch rates (rad/s), the feed-forward.
    shaped : bool
        The attitude targets are ArduSub's already *shaped* target (ATT.DesRoll/DesPitch/DesYaw are
        ``_attitude_target``, not the mode's input): set them directly with their rates as feed-forward
        (:meth:`~udrobot_ctrl.autopilot.attitude.AttitudeController.input_target`) instead of shaping them again.
    depth : float or None
        Depth target (m, down) (PSCD.TPD); None -> the depth loop holds its own target (as ALT_HOLD).
    vel_down, accel_down : float
        Feed-forward velocity (m/s) and acceleration (m/s^2) targets, down (PSCD.DVD, DAD).
    forward, lateral : float
        Horizontal mixer inputs (-1..1) from the horizontal position controller.
    """

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float | None = None
    yaw_rate: float = 0.0
    roll_rate: float = 0.0
    pitch_rate: float = 0.0
    shaped: bool = False
    depth: float | None = None
    vel_down: float = 0.0
    accel_down: float = 0.0
    forward: float = 0.0
    lateral: float = 0.0


__all__ = ["PWM_CENTRE", "Mode", "PilotCommand", "PilotInput", "Targets", "norm_input", "norm_input_dz",
           "logged_pulses", "logged_targets", "pilot_climb_rate", "pilot_pulses", "pilot_throttle", "pilot_lean_angles",
           "pilot_yaw_rate", "pwm_to_angle_dz_trim", "pwm_to_range_dz", "shape_pilot"]
