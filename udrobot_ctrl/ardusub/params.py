"""ArduSub's controller parameters as plain data, read from a log's parameter dict (ArduSub 4.1-4.5).

One dataclass per loop: :class:`PIDGains` (one ``AC_PID``), :class:`AttitudeParameters` (``ATC_*``),
:class:`DepthParameters` (``PSC_*`` z axis, ``MOT_THST_HOVER``), :class:`PilotParameters` (``RCn_*``, ``PILOT_*``,
``ACRO_YAW_P``, ``ANGLE_MAX``), gathered in :class:`ArduSubParameters`. :meth:`ArduSubParameters.from_log_params`
takes the log's ``PARM`` values (ArduSub's own names and units) and fills each missing one with ArduSub's
documented default, listing it in ``.assumed``.

Units. Everything here is SI (rad, rad/s, m, m/s, s, Hz); the autopilot's own units are converted at this edge:

* ``ATC_ACCEL_R/P/Y_MAX`` (cdeg/s^2) -> rad/s^2; ``ATC_SLEW_YAW`` (cdeg/s) -> rad/s; ``ATC_RATE_*_MAX`` (deg/s)
  -> rad/s; ``ANGLE_MAX`` (cdeg) -> rad; ``PILOT_SPEED_UP/DN`` (cm/s), ``PILOT_ACCEL_Z`` (cm/s^2) -> m/s, m/s^2.
* The rate PIDs (``ATC_RAT_RLL/PIT/YAW_*``) already take rad/s and give a normalised output (-1..1): unchanged.
* ``PSC_VELZ_*`` takes cm/s and gives cm/s^2: the same gains in m/s -> m/s^2; ``PSC_VELZ_IMAX`` (cm/s^2) / 100.
* ``PSC_ACCZ_*`` takes cm/s^2 and its output is multiplied by 0.001 to give throttle (``AC_PosControl::
  update_z_controller``): in m/s^2 -> throttle the gains are ``0.1 x`` ArduSub's (P, I, D, FF), ``IMAX / 1000``.
  (The dive's PIDA log agrees: P / Err = 0.05 throttle per m/s^2 for the default ``PSC_ACCZ_P`` = 0.5.)

Defaults (ArduPilot source, ArduSub 4.1-4.5):

* ``libraries/AC_AttitudeControl/AC_AttitudeControl_Sub.h``: ``AC_ATC_SUB_ANGLE_P`` 6.0, ``AC_ATC_SUB_ACCEL_Y_MAX``
  110000 cdeg/s^2, rate roll/pitch P 0.135 I 0.090 D 0.0036 IMAX 0.444 filter 30 Hz (FLTT and FLTD, FLTE 0), rate
  yaw P 0.180 I 0.018 D 0 IMAX 0.222 filter 5 Hz (FLTT and FLTD, FLTE 0).
* ``libraries/AC_AttitudeControl/AC_AttitudeControl.cpp/.h`` (``var_info``): ``INPUT_TC`` 0.15 s (Copter and Sub),
  ``ACCEL_R_MAX``/``ACCEL_P_MAX`` 110000 cdeg/s^2, ``RATE_FF_ENAB`` 1, ``SLEW_YAW`` 6000 cdeg/s, ``RATE_R/P/Y_MAX``
  0 (no limit), ``ANGLE_BOOST`` 1 (Sub's ``set_throttle_out`` ignores it).
* ``ArduSub/Parameters.h`` ``defaults_table`` (Sub's overrides of library defaults): ``ATC_ACCEL_Y_MAX`` 110000,
  ``ATC_RATE_Y_MAX`` 180 deg/s, ``PILOT_SPEED_UP`` 100 cm/s, ``PSC_JERK_Z`` 50 m/s^3. That table is ArduPilot
  master's (after 4.5); in it ``RC3_TRIM`` is 1500 -- together with master's ``mode_stabilize.cpp`` /
  ``mode_manual.cpp`` passing ``(norm_input + 1) / 2`` to the motors. ArduSub 4.0-4.5 set the same Sub defaults by
  ``AP_Param::set_default_by_name`` in ``Sub::load_parameters`` (``ArduSub/Parameters.cpp``), there with
  ``RC3_TRIM`` **1100** (= ``RC3_MIN``: the throttle's ``norm_input`` runs 0..1, 0.5 at 1500 us), and its modes pass
  ``norm_input`` as it is; QGroundControl's radio calibration also sets the throttle trim to its minimum for Sub.
  The default here is the 4.0-4.5 one (1100), the generation of every ArduSub log read so far (see
  :attr:`PilotParameters.throttle_norm_centred` for master's form).
* ``libraries/AC_AttitudeControl/AC_PosControl.h`` (Copter/Sub branch): ``POSCONTROL_POS_Z_P`` 1.0,
  ``POSCONTROL_VEL_Z_P`` 5.0 (I, D 0), ``VEL_Z_IMAX`` 1000, ``VEL_Z_FILT_HZ`` 5 (FLTE), ``VEL_Z_FILT_D_HZ`` 5,
  ``POSCONTROL_ACC_Z_P`` 0.5, ``ACC_Z_I`` 1.0, ``ACC_Z_D`` 0, ``ACC_Z_IMAX`` 800, ``ACC_Z_FILT_HZ`` 20 (FLTE; FLTT
  and FLTD 0), ``POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ`` 2.0.
* ``libraries/AP_Motors/AP_MotorsMulticopter.cpp``: ``MOT_THST_HOVER`` 0.5 for Sub (the dive's CTUN.ThH is 0.5).
* ``ArduSub/config.h`` and ``ArduSub/Parameters.cpp``: ``ANGLE_MAX`` 4500 cdeg (``DEFAULT_ANGLE_MAX``),
  ``ACRO_YAW_P`` 3.375 (the value in the stored ``config.h``; older trees had 4.5),
  ``PILOT_SPEED_DN`` 0 (= up), ``PILOT_ACCEL_Z`` 100 cm/s^2 (``PILOT_ACCEL_Z_DEFAULT``), ``THR_DZ`` 100
  (``THR_DZ_DEFAULT``), ``PILOT_THR_FILT`` 0 (off), ``SURFACE_DEPTH`` -10 cm (``SURFACE_DEPTH_DEFAULT``).
* ``libraries/RC_Channel/RC_Channel.cpp``: ``RCn_MIN`` 1100, ``RCn_MAX`` 1900, ``RCn_TRIM`` 1500, ``RCn_DZ`` 0,
  ``RCn_REVERSED`` 0, except ``RC3_TRIM`` (above) and the dead zones ArduSub's ``radio.cpp`` ``Sub::init_rc_in``
  sets by ``set_default_dead_zone``: roll, pitch, throttle, forward, lateral 30 us, yaw 40 us.

The main loop rate: ``MAIN_LOOP_RATE`` 400 Hz in ``ArduSub/config.h``; ``SCHED_LOOP_RATE`` overrides it (the
Seattle dive's ANG.Dt says 200 Hz). ``loop_rate_hz`` is a field so the caller can pass the log's rate.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

CDEG = math.radians(0.01)  # rad per centidegree


@dataclass(frozen=True)
class PIDGains:
    """Gains and filters of one ``AC_PID`` (``libraries/AC_PID/AC_PID.cpp``, ``var_info``), in the loop's units.

    Parameters
    ----------
    p, i, d, ff : float
        Proportional (output per unit error), integral (output per unit error per s), derivative (output per
        unit error rate, s) and feed-forward (output per unit target) gains.
    imax : float
        Integrator limit (output units): the I term is clamped to +-imax.
    filt_t_hz, filt_e_hz, filt_d_hz : float
        First-order low-pass cut-offs (Hz) on the target (FLTT), the error (FLTE) and the derivative (FLTD);
        0 disables the filter (``calc_lowpass_alpha_dt`` returns 1).
    d_ff : float
        Derivative feed-forward gain (``D_FF``, ArduPilot 4.3+), output per unit target rate (s).
    pd_max : float
        Limit on P + D (``PDMX``, 4.5+; 0 = none).
    smax : float
        Slew-rate limit (``SMAX``; 0 = off, Sub's default). A positive value is not emulated (``Dmod`` stays 1).
    """

    p: float
    i: float
    d: float
    imax: float
    filt_t_hz: float = 0.0
    filt_e_hz: float = 0.0
    filt_d_hz: float = 0.0
    ff: float = 0.0
    d_ff: float = 0.0
    pd_max: float = 0.0
    smax: float = 0.0


#: (ArduSub suffix, PIDGains field, scale from ArduSub's units to SI)
_PID_FIELDS = (("P", "p"), ("I", "i"), ("D", "d"), ("FF", "ff"), ("IMAX", "imax"), ("FLTT", "filt_t_hz"),
               ("FLTE", "filt_e_hz"), ("FLTD", "filt_d_hz"), ("D_FF", "d_ff"), ("PDMX", "pd_max"),
               ("SMAX", "smax"))

#: ArduSub defaults of the rate PIDs (AC_AttitudeControl_Sub.h)
RATE_ROLL_PITCH_DEFAULT = PIDGains(p=0.135, i=0.090, d=0.0036, imax=0.444, filt_t_hz=30.0, filt_e_hz=0.0,
                                   filt_d_hz=30.0)
RATE_YAW_DEFAULT = PIDGains(p=0.180, i=0.018, d=0.0, imax=0.222, filt_t_hz=5.0, filt_e_hz=0.0, filt_d_hz=5.0)
#: PSC_VELZ (AC_PID_Basic), cm/s -> cm/s^2 == m/s -> m/s^2; IMAX converted to m/s^2
VEL_Z_DEFAULT = PIDGains(p=5.0, i=0.0, d=0.0, imax=10.0, filt_e_hz=5.0, filt_d_hz=5.0)
#: PSC_ACCZ in SI (m/s^2 -> throttle): ArduSub's 0.5 / 1.0 / 0 / IMAX 800 times 0.1 / 0.1 / 0.1 / 0.001
ACC_Z_DEFAULT = PIDGains(p=0.05, i=0.1, d=0.0, imax=0.8, filt_t_hz=0.0, filt_e_hz=20.0, filt_d_hz=0.0)


#: PSC_ACCZ's ArduSub units (throttle per cm/s^2 x 1000 ...) -> SI: the factor each field is multiplied by
ACC_Z_SCALE = {"p": 0.1, "i": 0.1, "d": 0.1, "ff": 0.1, "imax": 0.001, "d_ff": 0.1, "pd_max": 0.001}
#: sidecar keys of a run's autopilot parameters: as the log stored them, and as estimated from its controller logs
LOGGED_PARAMS, ESTIMATED_PARAMS = "autopilot_params", "autopilot_params_estimated"


def gain_log_params(params: ArduSubParameters) -> dict:
    """The rate-loop and depth-loop gains of ``params`` as ArduSub parameters (name -> value, ArduSub's units):
    ``ATC_RAT_RLL/PIT/YAW_P/I/D``, ``PSC_ACCZ_P/I/D``, ``PSC_POSZ_P``, ``PSC_VELZ_P`` and ``SCHED_LOOP_RATE``; the
    inverse of :meth:`ArduSubParameters.from_log_params` for these names."""
    out = {}
    for prefix, gains in zip(("ATC_RAT_RLL_", "ATC_RAT_PIT_", "ATC_RAT_YAW_"), params.attitude.rate_pids()):
        out.update({prefix + "P": gains.p, prefix + "I": gains.i, prefix + "D": gains.d})
    acc = params.depth.accel
    out.update({f"PSC_ACCZ_{k.upper()}": getattr(acc, k) / ACC_Z_SCALE[k] for k in ("p", "i", "d")})
    out.update({"PSC_POSZ_P": params.depth.pos_p, "PSC_VELZ_P": params.depth.vel.p,
                "SCHED_LOOP_RATE": round(params.loop_rate_hz)})  # an integer parameter (Hz)
    return {k: float(v) for k, v in out.items()}


def run_log_params(metadata: Mapping) -> tuple:
    """(parameters, note) for a run's autopilot: the sidecar's logged ``autopilot_params`` over the ones estimated
    from the log's controller messages (``autopilot_params_estimated``); the note names the estimated ones used."""
    logged = dict(metadata.get(LOGGED_PARAMS) or {})
    estimated = {k: v for k, v in (metadata.get(ESTIMATED_PARAMS) or {}).items() if k not in logged}
    note = (f"estimated from the log's controller messages: {', '.join(sorted(estimated))}" if estimated else "")
    return {**estimated, **logged}, note


@dataclass(frozen=True)
class AttitudeParameters:
    """``AC_AttitudeControl_Sub``: angle P, input shaping and the three rate PIDs (SI units).

    Parameters
    ----------
    angle_p : tuple of 3 float
        ``ATC_ANG_RLL_P``, ``ATC_ANG_PIT_P``, ``ATC_ANG_YAW_P`` (rad/s per rad).
    rate_roll, rate_pitch, rate_yaw : PIDGains
        ``ATC_RAT_RLL_*``, ``ATC_RAT_PIT_*``, ``ATC_RAT_YAW_*`` (rad/s in, normalised output).
    accel_max : tuple of 3 float
        ``ATC_ACCEL_R/P/Y_MAX`` in rad/s^2 (0 disables the limit and the sqrt controller on that axis).
    input_tc : float
        ``ATC_INPUT_TC`` (s), the input shaping time constant.
    rate_ff_enabled : bool
        ``ATC_RATE_FF_ENAB``: body-frame rate feed-forward with input shaping.
    slew_yaw : float
        ``ATC_SLEW_YAW`` (rad/s).
    rate_max : tuple of 3 float
        ``ATC_RATE_R/P/Y_MAX`` (rad/s, 0 = no limit).
    """

    angle_p: tuple = (6.0, 6.0, 6.0)
    rate_roll: PIDGains = RATE_ROLL_PITCH_DEFAULT
    rate_pitch: PIDGains = RATE_ROLL_PITCH_DEFAULT
    rate_yaw: PIDGains = RATE_YAW_DEFAULT
    accel_max: tuple = (110000 * CDEG, 110000 * CDEG, 110000 * CDEG)
    input_tc: float = 0.15
    rate_ff_enabled: bool = True
    slew_yaw: float = 6000 * CDEG
    rate_max: tuple = (0.0, 0.0, math.radians(180.0))

    def rate_pids(self) -> tuple:
        """The three rate PID gain sets in roll, pitch, yaw order."""
        return (self.rate_roll, self.rate_pitch, self.rate_yaw)


@dataclass(frozen=True)
class DepthParameters:
    """``AC_PosControl`` z axis as ArduSub uses it (SI, the down axis of NED; see :mod:`.depth`).

    Parameters
    ----------
    pos_p : float
        ``PSC_POSZ_P`` (1/s): velocity target per metre of depth error.
    vel : PIDGains
        ``PSC_VELZ_*`` (m/s -> m/s^2).
    accel : PIDGains
        ``PSC_ACCZ_*`` (m/s^2 -> throttle, 0..1 scale), see the module notes for the 0.1 / 0.001 factors.
    throttle_hover : float
        ``MOT_THST_HOVER`` (0..1); 0.5 is neutral buoyancy for a sub (bidirectional throttle).
    speed_up, speed_down : float
        ``PILOT_SPEED_UP`` and ``PILOT_SPEED_DN`` (m/s, both positive; speed_down 0 means speed_up).
    accel_max : float
        ``PILOT_ACCEL_Z`` (m/s^2), the z acceleration limit of the position shaping and sqrt controller.
    throttle_cutoff_hz : float
        Motors' throttle low-pass when the position controller drives it (``POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ``).
    surface_depth : float
        ``-SURFACE_DEPTH / 100`` (m, positive down): shallower than this ArduSub's detector sets ``at_surface``
        and ALT_HOLD holds its target 5 cm deeper (:mod:`.surface_bottom`). ``SURFACE_DEPTH`` is in cm, up.
    """

    pos_p: float = 1.0
    vel: PIDGains = VEL_Z_DEFAULT
    accel: PIDGains = ACC_Z_DEFAULT
    throttle_hover: float = 0.5
    speed_up: float = 1.0
    speed_down: float = 0.0
    accel_max: float = 1.0
    throttle_cutoff_hz: float = 2.0
    surface_depth: float = 0.10

    @property
    def speed_down_effective(self) -> float:
        """``Sub::get_pilot_speed_dn``: PILOT_SPEED_DN, or PILOT_SPEED_UP when it is 0 (m/s)."""
        return abs(self.speed_down) if self.speed_down else abs(self.speed_up)


@dataclass(frozen=True)
class RCChannel:
    """One RC input's calibration (``RCn_MIN``, ``RCn_MAX``, ``RCn_TRIM``, ``RCn_DZ`` in microseconds,
    ``RCn_REVERSED``)."""

    min: float = 1100.0
    max: float = 1900.0
    trim: float = 1500.0
    dead_zone: float = 0.0
    reversed: bool = False


def boot_gain(default: float, gain_min: float, gain_max: float, steps: float) -> float:
    """``Sub::init_joystick``: the pilot gain at boot from ``JS_GAIN_DEFAULT``, ``JS_GAIN_MIN``, ``JS_GAIN_MAX`` and
    ``JS_GAIN_STEPS`` (dimensionless, 0.1..1.0)."""
    steps = max(1, int(steps))
    if steps == 1 or gain_min - 0.01 < default < gain_max + 0.01:
        gain = min(max(default, gain_min), gain_max)
    else:  # the setting closest to the middle of min and max (integer division as in the source)
        gain = gain_min + (steps // 2 - 1) * (gain_max - gain_min) / (steps - 1)
    return min(max(gain, 0.1), 1.0)


#: ``RC3_TRIM`` default of ArduSub 4.0-4.5 (``Sub::load_parameters``: ``set_default_by_name("RC3_TRIM", 1100)``),
#: us; ArduPilot master's ``defaults_table`` has 1500 (module notes)
RC3_TRIM_DEFAULT = 1100.0

#: ArduSub's RC input order (``ArduSub/radio.cpp`` ``init_rc_in``, RCMAP disabled): 1-based channel numbers
RC_MAP = {"pitch": 1, "roll": 2, "throttle": 3, "yaw": 4, "forward": 5, "lateral": 6}


@dataclass(frozen=True)
class PilotParameters:
    """Pilot input shaping (``ArduSub/Attitude.cpp``, ``radio.cpp``, ``RC_Channel.cpp``).

    Parameters
    ----------
    channels : dict
        Input name (``RC_MAP`` keys) -> :class:`RCChannel`.
    angle_max : float
        ``ANGLE_MAX`` (rad), the lean angle at full roll/pitch stick.
    acro_yaw_p : float
        ``ACRO_YAW_P``: yaw rate in cdeg/s per centidegree of yaw stick (ArduSub's own unit; a full stick of
        4500 gives ``4500 * acro_yaw_p`` cdeg/s).
    throttle_deadzone : float
        ``THR_DZ`` (0..1000 throttle stick units) around mid stick where the climb rate is 0.
    throttle_filt_hz : float
        ``PILOT_THR_FILT`` (Hz; 0 = off), the motors' throttle filter when the pilot drives the throttle.
    gain : float
        The pilot gain ``Sub::gain`` at boot (``ArduSub/joystick.cpp`` ``init_joystick``: ``JS_GAIN_DEFAULT`` 0.5
        within ``JS_GAIN_MIN`` 0.25 .. ``JS_GAIN_MAX`` 1.0, else the setting nearest their middle, then 0.1..1.0).
        ``get_pilot_desired_climb_rate`` scales ``THR_DZ`` by it (``mid_stick +- g.throttle_deadzone * gain``).
        Gain changes by joystick buttons during a dive are not followed (the log has them only as ``PilotGain``
        texts; assumed constant).
    throttle_norm_centred : bool
        How MANUAL and STABILIZE turn the throttle stick into the motors' throttle (0..1, 0.5 neutral):
        False (ArduSub 4.1-4.5, ``Sub::manual_run`` / ``ModeManual::run``: ``motors.set_throttle(channel_throttle->
        norm_input())``, ``ModeStabilize::run``: ``set_throttle_out(channel_throttle->norm_input(), ...)``) passes
        ``norm_input`` as it is -- 0..1 with the vehicle's ``RC3_TRIM = RC3_MIN``; True (ArduPilot master after 4.5,
        whose ``RC3_TRIM`` default is 1500) passes ``(norm_input + 1) / 2``. Not a parameter of the log: the
        firmware generation decides it.
    """

    channels: dict = field(default_factory=lambda: {
        "pitch": RCChannel(dead_zone=30.0), "roll": RCChannel(dead_zone=30.0),
        "throttle": RCChannel(trim=RC3_TRIM_DEFAULT, dead_zone=30.0), "yaw": RCChannel(dead_zone=40.0),
        "forward": RCChannel(dead_zone=30.0), "lateral": RCChannel(dead_zone=30.0)})
    angle_max: float = 4500 * CDEG
    acro_yaw_p: float = 3.375
    throttle_deadzone: float = 100.0
    throttle_filt_hz: float = 0.0
    gain: float = 0.5
    throttle_norm_centred: bool = False


# ----------------------------------------------------------------------------- the check of logged values


class ParameterError(ValueError):
    """An autopilot parameter read from a log, a sidecar or a ``.params`` file that ArduSub cannot hold; the message
    names the file, the parameter and what was expected."""


@dataclass(frozen=True)
class ParameterDomain:
    """The values ArduSub documents for one parameter, in its own units (the firmware's ``var_info`` metadata).

    Attributes
    ----------
    low, high : float
        Inclusive bounds (ArduSub's units).
    unit : str
        ArduSub's unit (``cm``, ``cdeg``, ``Hz``, ``us``; '' for a gain or a ratio).
    source : str
        File and metadata line the bounds come from.
    values : tuple of float
        For an enumerated parameter, the values it may take (empty: any value within ``low``..``high``).
    """

    low: float
    high: float
    unit: str
    source: str
    values: tuple = ()

    def expected(self) -> str:
        """What the parameter may be, as a phrase for an error line."""
        unit = f" {self.unit}" if self.unit else ""
        if self.values:
            return f"one of {', '.join(f'{v:g}' for v in self.values)}{unit} ({self.source})"
        return f"{self.low:g} to {self.high:g}{unit} ({self.source})"

    def holds(self, value: float) -> bool:
        """True when ``value`` is one of :attr:`values` or inside ``low``..``high``."""
        return value in self.values if self.values else self.low <= value <= self.high


_SUB = "ArduSub/Parameters.cpp @Range"
_RC = "libraries/RC_Channel/RC_Channel.cpp var_info @Range"
_PID = "libraries/AC_PID/AC_PID.cpp: a gain, limit or filter below 0 is no controller setting"
#: documented domains of the parameters the emulation reads, by name (ArduSub's units). The rate gains' upper
#: @Range bounds are advisory tuning limits (:func:`~udrobot_ctrl.autopilot.firmware.range_violations` reports them);
#: what is refused here is what no firmware build can hold or fly: a negative gain, limit or filter.
PARAMETER_DOMAINS = {
    "SCHED_LOOP_RATE": ParameterDomain(50, 400, "Hz", "libraries/AP_Scheduler/AP_Scheduler.cpp LOOP_RATE @Range 50 "
                                                      "400; older trees' @Values 50, 100, 200, 250, 300, 400"),
    "ANGLE_MAX": ParameterDomain(1000, 8000, "cdeg", f"{_SUB} 1000 8000"),
    "MOT_THST_HOVER": ParameterDomain(0.2, 0.8, "", "libraries/AP_Motors/AP_MotorsMulticopter.cpp THST_HOVER @Range"),
    "PILOT_SPEED_UP": ParameterDomain(20, 500, "cm/s", f"{_SUB} 20 500"),
    "PILOT_SPEED_DN": ParameterDomain(0, 500, "cm/s", f"{_SUB} 20 500, and 0 for 'PILOT_SPEED_UP' (its default)"),
    "PILOT_ACCEL_Z": ParameterDomain(50, 500, "cm/s/s", f"{_SUB} 50 500"),
    "PILOT_THR_FILT": ParameterDomain(0, 10, "Hz", f"{_SUB} 0 10"),
    "SURFACE_DEPTH": ParameterDomain(-100, 0, "cm", f"{_SUB} -100 0"),
    "THR_DZ": ParameterDomain(0, 300, "us", f"{_SUB} 0 300"),
    "FRAME_CONFIG": ParameterDomain(0, 7, "", "ArduSub/Parameters.cpp FRAME_CONFIG @Values",
                                    tuple(float(v) for v in range(8))),
    "ATC_RATE_FF_ENAB": ParameterDomain(0, 1, "", "AC_AttitudeControl.cpp RATE_FF_ENAB @Values", (0.0, 1.0)),
    **{f"RC{k}_{f}": ParameterDomain(800, 2200, "us", f"{_RC} 800 2200") for k in range(1, 9)
       for f in ("MIN", "TRIM", "MAX")},
    **{f"RC{k}_DZ": ParameterDomain(0, 200, "us", f"{_RC} 0 200") for k in range(1, 9)},
    **{f"RC{k}_REVERSED": ParameterDomain(0, 1, "", "RC_Channel.cpp REVERSED @Values", (0.0, 1.0))
       for k in range(1, 9)},
    **{f"MOT_{k}_DIRECTION": ParameterDomain(-1, 1, "", "AP_Motors6DOF.cpp MOT_n_DIRECTION @Values", (-1.0, 1.0))
       for k in range(1, 13)},
    "JS_GAIN_DEFAULT": ParameterDomain(0.1, 1.0, "", f"{_SUB} 0.1 1.0"),
    "JS_GAIN_MAX": ParameterDomain(0.2, 1.0, "", f"{_SUB} 0.2 1.0"),
    "JS_GAIN_MIN": ParameterDomain(0.1, 0.8, "", f"{_SUB} 0.1 0.8"),
    "JS_GAIN_STEPS": ParameterDomain(1, 10, "", f"{_SUB} 1 10"),
}
#: the gains, limits and filters of every PID and the shaping limits read by the emulation: 0 or more
_NON_NEGATIVE = re.compile(r"^(ATC_(RAT_(RLL|PIT|YAW)_[A-Z_]+|ANG_(RLL|PIT|YAW)_P|ACCEL_[RPY]_MAX|INPUT_TC|SLEW_YAW|"
                           r"RATE_[RPY]_MAX)|PSC_(POSZ_P|VELZ_[A-Z_]+|ACCZ_[A-Z_]+|D_(POS|VEL|ACC)_[A-Z_]+)|"
                           r"ACRO_YAW_P)$")
#: the RC inputs the emulation reads: their calibration must let ``norm_input`` and the dead-zone maps divide
_RC_INPUTS = tuple(RC_MAP.values())


@dataclass(frozen=True)
class ParameterProblem:
    """One logged parameter value ArduSub cannot hold (structured: the code says which check failed).

    Attributes
    ----------
    name : str
        ArduSub's parameter name (for a consistency check, the first of those involved).
    value : object
        The value as read (a list, a string or a non-finite number included).
    code : str
        ``not_a_number``, ``not_finite``, ``out_of_range``, ``negative`` or ``inconsistent``.
    expected : str
        What the parameter may be (with its source), as printed.
    """

    name: str
    value: object
    code: str
    expected: str

    def sentence(self) -> str:
        shown = f"{self.value:g}" if isinstance(self.value, float) else repr(self.value)
        return f"parameter {self.name} = {shown}: expected {self.expected}"


def parameter_problems(params: Mapping) -> list:
    """Every value of ``params`` (name -> value, ArduSub's names and units) that ArduSub cannot hold.

    Checked: each value is a finite number (not a list, string, bool or null); the parameters of
    :data:`PARAMETER_DOMAINS` lie in their documented domain; PID gains, limits, filters and the attitude shaping
    limits are not negative; each RC input the modes read (channels 1-6) has ``RCn_MIN < RCn_MAX``, its trim
    within them and a dead zone that leaves part of the range outside it (``RC_Channel::norm_input_dz``,
    ``pwm_to_range_dz`` and ``get_control_mid`` divide by what is left: the throttle's ``RCn_MIN + RCn_DZ`` below
    ``RCn_MAX``, an angle channel's ``RCn_TRIM +- RCn_DZ`` not covering both ends).

    Parameters
    ----------
    params : mapping of str to object

    Returns
    -------
    list of ParameterProblem
        Empty when every value is usable.
    """
    out, values = [], {}
    for name, raw in params.items():
        if isinstance(raw, bool) or not isinstance(raw, (int, float)):
            out.append(ParameterProblem(str(name), raw, "not_a_number", "a number (ArduSub stores every parameter "
                                                                         "as one)"))
            continue
        value = float(raw)
        if not math.isfinite(value) or abs(value) > _FLOAT32_MAX:
            out.append(ParameterProblem(str(name), value, "not_finite", "a finite number (a MAVLink / dataflash "
                                                                         "parameter is a float32)"))
            continue
        values[name] = value
        domain = PARAMETER_DOMAINS.get(name)
        if domain is not None and not domain.holds(value):
            out.append(ParameterProblem(name, value, "out_of_range", domain.expected()))
        elif domain is None and _NON_NEGATIVE.match(name) and value < 0:
            out.append(ParameterProblem(name, value, "negative", f"0 or more ({_PID})"))
    bad = {p.name for p in out}
    for k in _RC_INPUTS:
        names = [f"RC{k}_{f}" for f in ("MIN", "TRIM", "MAX", "DZ")]
        if bad & set(names) or not any(n in values for n in names):
            continue
        default = PilotParameters().channels[next(n for n, c in RC_MAP.items() if c == k)]
        lo, trim, hi, dz = (values.get(n, d) for n, d in zip(names, (default.min, default.trim, default.max,
                                                                        default.dead_zone)))
        if not lo < hi:
            out.append(ParameterProblem(names[0], lo, "inconsistent", f"below RC{k}_MAX = {hi:g} us (RC_Channel.cpp: "
                                                                       f"the channel's travel runs from MIN to MAX)"))
        elif not lo <= trim <= hi:
            out.append(ParameterProblem(names[1], trim, "inconsistent", f"within RC{k}_MIN {lo:g} .. RC{k}_MAX "
                                                                         f"{hi:g} us (RC_Channel.cpp norm_input)"))
        elif k == RC_MAP["throttle"] and not lo + dz < hi:
            out.append(ParameterProblem(names[3], dz, "inconsistent", f"below RC{k}_MAX - RC{k}_MIN = {hi - lo:g} us "
                                                                       f"(the dead zone spans the throttle range; "
                                                                       f"RC_Channel::pwm_to_range_dz)"))
        elif k != RC_MAP["throttle"] and trim - dz <= lo and trim + dz >= hi:
            out.append(ParameterProblem(names[3], dz, "inconsistent", f"below {max(trim - lo, hi - trim):g} us (the "
                                                                       f"dead zone about RC{k}_TRIM spans the "
                                                                       f"channel's range; RC_Channel::norm_input_dz)"))
    return out


def check_log_params(params, source: str) -> dict:
    """The one check of an autopilot parameter set read from a log, a sidecar or a ``.params`` file.

    Parameters
    ----------
    params : mapping of str to object
        Name -> value in ArduSub's names and units.
    source : str
        Where they were read (file and field), for the message.

    Returns
    -------
    dict of str to float

    Raises
    ------
    ParameterError
        On the first problem of :func:`parameter_problems`: one line naming ``source``, the parameter and what
        was expected.
    """
    if not isinstance(params, Mapping):
        raise ParameterError(f"{source}: expected an object of ArduSub parameter name -> number, got "
                             f"{type(params).__name__}")
    problems = parameter_problems(params)
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise ParameterError(f"{source}: {problems[0].sentence()}{more}")
    return {str(k): float(v) for k, v in params.items()}


def usable_log_params(params: Mapping) -> tuple:
    """(the usable parameters, the problems of the others) of a log's parameter records, for a converter that
    passes the log on: a damaged record (:func:`parameter_problems`) is dropped, never written on without a note.
    A consistency problem drops the parameters of that RC channel."""
    problems = parameter_problems(params)
    drop = {p.name for p in problems}
    for p in problems:
        if p.code == "inconsistent":
            drop |= {f"{p.name.split('_')[0]}_{f}" for f in ("MIN", "TRIM", "MAX", "DZ")}
    return {k: float(v) for k, v in params.items() if k not in drop}, problems


_FLOAT32_MAX = 3.4028234663852886e38  # a parameter is a float32 on the autopilot (AP_Param, MAVLink PARAM_VALUE)


@dataclass(frozen=True)
class ArduSubParameters:
    """All of ArduSub's controller parameters, SI, with the list of those that were defaulted.

    Parameters
    ----------
    attitude, depth, pilot : AttitudeParameters, DepthParameters, PilotParameters
        The attitude controller's (AC_AttitudeControl), the depth controller's (AC_PosControl z) and the
        pilot-input shaping parameters, SI units.
    loop_rate_hz : float
        Main loop rate (Hz): the PID filters and integrators step at ``1 / loop_rate_hz``.
    assumed : tuple of str
        ArduSub parameter names that the log lacked and were given ArduSub's default.
    """

    attitude: AttitudeParameters = field(default_factory=AttitudeParameters)
    depth: DepthParameters = field(default_factory=DepthParameters)
    pilot: PilotParameters = field(default_factory=PilotParameters)
    loop_rate_hz: float = 400.0
    assumed: tuple = ()

    @classmethod
    def defaults(cls, loop_rate_hz: float = 400.0) -> ArduSubParameters:
        """ArduSub's defaults for every parameter (all of them listed in ``assumed``)."""
        return cls.from_log_params({}, loop_rate_hz=loop_rate_hz)

    @classmethod
    def from_log_params(cls, params: Mapping, loop_rate_hz: float | None = None) -> ArduSubParameters:
        """Read ArduSub's parameters (name -> value, ArduSub units) and default the missing ones.

        Parameters
        ----------
        params : mapping of str to float
            A log's ``PARM`` values (e.g. ``DecodedLog``'s parameters). Unknown names are ignored.
        loop_rate_hz : float, optional
            Main loop rate (Hz); if None, ``SCHED_LOOP_RATE`` from ``params`` or ArduSub's 400 Hz.

        Returns
        -------
        ArduSubParameters
            With ``assumed`` listing every parameter taken from ArduSub's defaults.
        """
        assumed: list[str] = []

        def get(name, default, scale=1.0):
            """The parameter (or its default, both in ArduSub's units) times ``scale``."""
            value = params.get(name)
            if value is None or not math.isfinite(float(value)):
                assumed.append(name)
                value = default
            return float(value) * scale

        def pid(prefix, default: PIDGains, scales: dict | None = None) -> PIDGains:
            scales = scales or {}
            values = {}
            for suffix, attr in _PID_FIELDS:
                scale = scales.get(attr, 1.0)
                name = prefix + suffix
                if name in params and params[name] is not None and math.isfinite(float(params[name])):
                    values[attr] = float(params[name]) * scale
                elif suffix in ("FLTT", "FLTE", "FLTD") and prefix + "FILT" in params:
                    # ArduSub < 4.0 had one FILT per rate PID (AC_PID's FILT became FLTT/FLTE/FLTD), still
                    # accepted as a fallback for the target and derivative filters
                    values[attr] = float(params[prefix + "FILT"]) if suffix != "FLTE" else default.filt_e_hz
                else:
                    if suffix in ("P", "I", "D", "IMAX", "FF", "FLTT", "FLTE", "FLTD"):
                        assumed.append(name)
                    values[attr] = getattr(default, attr)
            return PIDGains(**values)

        att_default = AttitudeParameters()
        accel = tuple(get(f"ATC_ACCEL_{a}_MAX", d / CDEG, CDEG) for a, d in zip("RPY", att_default.accel_max))
        attitude = AttitudeParameters(
            angle_p=tuple(get(f"ATC_ANG_{a}_P", 6.0) for a in ("RLL", "PIT", "YAW")),
            rate_roll=pid("ATC_RAT_RLL_", RATE_ROLL_PITCH_DEFAULT),
            rate_pitch=pid("ATC_RAT_PIT_", RATE_ROLL_PITCH_DEFAULT),
            rate_yaw=pid("ATC_RAT_YAW_", RATE_YAW_DEFAULT),
            accel_max=accel,
            input_tc=get("ATC_INPUT_TC", 0.15),
            rate_ff_enabled=bool(get("ATC_RATE_FF_ENAB", 1.0)),
            slew_yaw=get("ATC_SLEW_YAW", 6000.0, CDEG),
            rate_max=tuple(get(f"ATC_RATE_{a}_MAX", d, math.radians(1.0))
                           for a, d in zip("RPY", (0.0, 0.0, 180.0))))
        # defaults are the SI constants above; values read from the log are converted from ArduSub's units
        accel_pid = pid("PSC_ACCZ_", ACC_Z_DEFAULT, ACC_Z_SCALE)
        vel_pid = pid("PSC_VELZ_", VEL_Z_DEFAULT, {"imax": 0.01})
        depth = DepthParameters(
            pos_p=get("PSC_POSZ_P", 1.0), vel=vel_pid, accel=accel_pid,
            throttle_hover=get("MOT_THST_HOVER", 0.5),
            speed_up=get("PILOT_SPEED_UP", 100.0, 0.01), speed_down=get("PILOT_SPEED_DN", 0.0, 0.01),
            accel_max=get("PILOT_ACCEL_Z", 100.0, 0.01), surface_depth=get("SURFACE_DEPTH", -10.0, -0.01))
        default_pilot = PilotParameters()
        channels = {}
        for name, number in RC_MAP.items():
            d = default_pilot.channels[name]
            channels[name] = RCChannel(min=get(f"RC{number}_MIN", d.min), max=get(f"RC{number}_MAX", d.max),
                                       trim=get(f"RC{number}_TRIM", d.trim),
                                       dead_zone=get(f"RC{number}_DZ", d.dead_zone),
                                       reversed=bool(get(f"RC{number}_REVERSED", 0.0)))
        pilot = PilotParameters(channels=channels, angle_max=get("ANGLE_MAX", 4500.0, CDEG),
                                acro_yaw_p=get("ACRO_YAW_P", 3.375), throttle_deadzone=get("THR_DZ", 100.0),
                                throttle_filt_hz=get("PILOT_THR_FILT", 0.0),
                                gain=boot_gain(get("JS_GAIN_DEFAULT", 0.5), get("JS_GAIN_MIN", 0.25),
                                               get("JS_GAIN_MAX", 1.0), get("JS_GAIN_STEPS", 4.0)))
        if loop_rate_hz is None:
            loop_rate_hz = get("SCHED_LOOP_RATE", 400.0)
        return cls(attitude=attitude, depth=depth, pilot=pilot, loop_rate_hz=float(loop_rate_hz),
                   assumed=tuple(assumed))
