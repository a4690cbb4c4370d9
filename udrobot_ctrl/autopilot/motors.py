"""ArduSub's output side, written once from its source: frame factor tables, the mixer, PWM and its inverse.

Source (ArduPilot, ``libraries/AP_Motors/AP_Motors6DOF.cpp`` unless named otherwise; ArduSub 4.1-4.5):

* ``AP_Motors6DOF::setup_motors`` -- the factor tables :data:`FRAME_FACTORS` (roll, pitch, yaw, throttle,
  forward, lateral per motor, ``add_motor_raw_6dof``). ``FRAME_CONFIG`` numbers are ``sub_frame_t`` in
  ``AP_Motors6DOF.h``. ``SUB_FRAME_CUSTOM`` falls through to the default table in the source ("Put your custom
  motor setup here"), so a custom vehicle's factors must be given by the user (:func:`custom_frame`).
* ``AP_Motors6DOF::output_armed_stabilizing`` and its two frame-specific variants -- :func:`mix`:

  - VECTORED (``output_armed_stabilizing_vectored``): ``rpy_i + linear_i`` clipped to [-1, 1] per motor, no
    normalisation; the forward input of the "rear" vectored thrusters (motors 1-2 when going backwards, 3-4 when
    going forwards, ``forward_coupling_direction = {-1, -1, 1, 1, 0, ...}``) is limited to
    ``1 - MOT_FV_CPLNG_K |throttle|`` (floored at 0) to decouple forward motion from pitch.
  - VECTORED_6DOF (``output_armed_stabilizing_vectored_6dof``): the vertical group ``rpt = roll, pitch,
    throttle`` and the horizontal group ``yfl = yaw, forward, lateral`` are each divided by
    ``max(1, max_i |group_i|)`` -- when a group saturates, all its motors are scaled by the same factor, which keeps
    the ratio of that group's inputs -- and the sum is clipped to [-1, 1].
  - every other frame: ``rpy_i + linear_i`` clipped to [-1, 1].

  In all of them the throttle is ``get_throttle_bidirectional() = 2 (throttle_in - 0.5)`` (``AP_Motors_Class``;
  the RATE log's ``AOut`` is ``throttle_in``) clipped to +-1 (``_throttle_thrust_max`` is 1: Sub's
  ``get_current_limit_max_throttle`` returns 1), and on VECTORED_6DOF also to ``_max_throttle`` (the surface
  throttle limit, :attr:`MotorParameters.max_throttle`). The roll/pitch/yaw inputs are ``_roll_in + _roll_in_ff``
  etc., which is what the RATE log's ``ROut``/``POut``/``YOut`` record (``AC_AttitudeControl::Write_Rate``).
  The result is multiplied by ``MOT_i_DIRECTION`` (``_motor_reverse``) inside the clip; :func:`mix` returns the
  command before the reversal and :func:`to_pwm` applies it (the clip is symmetric, so the order is immaterial).
* ``AP_Motors6DOF::calc_thrust_to_pwm`` -- :func:`to_pwm`: ``1500 + t (MOT_PWM_MAX - 1500)`` for t > 0 and
  ``1500 + t (1500 - MOT_PWM_MIN)`` otherwise, converted to ``int16`` (truncation toward zero). This is the form
  since ArduPilot PR #20606 ("Sub: tweak output function", ArduSub 4.5). ArduSub 4.1-4.4 used
  ``constrain_int16(1500 + t * 400, _throttle_radio_min, _throttle_radio_max)``, which is the same law for
  Sub's default range 1100-1900 us (ArduSub ``Parameters.h`` ``defaults_table``: ``MOT_PWM_MIN`` 1100,
  ``MOT_PWM_MAX`` 1900). ``AP_Motors6DOF::output_to_motors`` writes 1500 us whenever the motors are not spooled up
  (disarmed / ground idle).

What ArduSub 4.1-4.5 does *not* do on its output side (read in the same files):

* no software dead zone: the dead band is the ESC's and the T200's own (``models/t200.toml``). (The ``DEAD_BAND``
  seen in some forks' ``calc_thrust_to_pwm`` is not ArduPilot's.)
* no battery-voltage compensation and no thrust-curve linearisation: ``AP_Motors6DOF`` overrides
  ``output_to_motors``/``calc_thrust_to_pwm`` and never calls ``AP_MotorsMulticopter``'s
  ``apply_thrust_curve_and_volt_scaling`` / ``get_compensation_gain`` (``update_lift_max_from_batt_voltage`` still
  runs and the MOTB log shows ``LiftMax`` = ``BatVolt`` = 1 when ``MOT_BAT_VOLT_MAX`` = 0). ArduPilot master after
  4.5 (``thr_lin.thrust_to_actuator`` and ``MOT_SLEW_UP/DN`` in ``output_to_motors``) does apply them: that newer
  path is **not** modelled here, and :meth:`MotorParameters.from_log_params` says so when the log enables it.
* ``MOT_BAT_CURR_MAX`` > 0 scales every output by a slowly varying ``_output_limited`` in [0, 1] (end of
  ``output_armed_stabilizing``); it is off by default, and :func:`mix` takes it as an optional factor.
* ``SERVOn_MIN/MAX/REVERSED`` do not act on motor outputs (``rc_write`` sets the PWM directly).

Rank of the factor matrix (6 inputs -> n motors; what :func:`unmix` can recover): VECTORED_6DOF and
VECTORED_6DOF_90DEG 6 (all inputs); VECTORED 5 (no pitch column: a VECTORED vehicle cannot be commanded in pitch);
BLUEROV1 6; SIMPLEROV_3 3 (no roll, pitch, lateral); SIMPLEROV_4 and SIMPLEROV_5 5 (one shared 5-motor table in
ArduSub 4.5, no pitch; before the ``_frame_class_string`` rewrite all three SIMPLEROV frames used one table whose
motors 3-4 had throttle only). :attr:`Frame.rank` and :attr:`Frame.unobservable` compute it.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # only an annotation: motors is imported by io, which vehicle imports
    from udrobot_ctrl.vehicle import Vehicle

#: The mixer's inputs, in the column order of :attr:`Frame.factors` (``add_motor_raw_6dof`` argument order).
MIXER_INPUTS = ("roll", "pitch", "yaw", "throttle", "forward", "lateral")
PWM_NEUTRAL = 1500.0  # us, AP_Motors6DOF::calc_thrust_to_pwm and output_to_motors

#: ``FRAME_CONFIG`` value -> frame name (``sub_frame_t`` in AP_Motors6DOF.h).
FRAME_CONFIGS = {0: "BLUEROV1", 1: "VECTORED", 2: "VECTORED_6DOF", 3: "VECTORED_6DOF_90DEG", 4: "SIMPLEROV_3",
                 5: "SIMPLEROV_4", 6: "SIMPLEROV_5", 7: "CUSTOM"}
#: The project's vehicle names -> their ArduSub frame (models/bluerov2.toml, models/bluerov2-heavy.toml).
VEHICLE_FRAMES = {"bluerov2": "VECTORED", "bluerov2-heavy": "VECTORED_6DOF"}

_SIMPLEROV_4 = ((0, 0, -1, 0, 1, 0), (0, 0, 1, 0, 1, 0), (1, 0, 0, -1, 0, 0), (-1, 0, 0, -1, 0, 0),
                (0, 0, 0, 0, 0, 1))
#: Factor tables of ``AP_Motors6DOF::setup_motors`` (ArduSub 4.5), rows = motors 1..n, columns = MIXER_INPUTS.
FRAME_FACTORS = {
    "BLUEROV1": ((0, 0, -1, 0, 1, 0), (0, 0, 1, 0, 1, 0), (-0.5, 0.5, 0, 0.45, 0, 0), (0.5, 0.5, 0, 0.45, 0, 0),
                 (0, -1, 0, 1, 0, 0), (-0.25, 0, 0, 0, 0, 1)),
    "VECTORED_6DOF_90DEG": ((1, 1, 0, 1, 0, 0), (0, 0, 1, 0, 1, 0), (1, -1, 0, 1, 0, 0), (0, 0, 0, 0, 0, 1),
                            (0, 0, 0, 0, 0, 1), (-1, 1, 0, 1, 0, 0), (0, 0, -1, 0, 1, 0), (-1, -1, 0, 1, 0, 0)),
    "VECTORED_6DOF": ((0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
                      (1, -1, 0, -1, 0, 0), (-1, -1, 0, -1, 0, 0), (1, 1, 0, -1, 0, 0), (-1, 1, 0, -1, 0, 0)),
    "VECTORED": ((0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
                 (1, 0, 0, -1, 0, 0), (-1, 0, 0, -1, 0, 0)),
    "SIMPLEROV_3": ((0, 0, -1, 0, 1, 0), (0, 0, 1, 0, 1, 0), (0, 0, 0, -1, 0, 0)),
    # SIMPLEROV_4, SIMPLEROV_5 and the default share one 5-motor table in the source ("DEFAULT")
    "SIMPLEROV_4": _SIMPLEROV_4,
    "SIMPLEROV_5": _SIMPLEROV_4,
}
#: ``forward_coupling_direction`` of output_armed_stabilizing_vectored (motors 1..4; 0 for the others).
_FORWARD_COUPLING_DIRECTION = (-1, -1, 1, 1)


@dataclass(frozen=True)
class Frame:
    """An ArduSub frame: its motors' factors for each mixer input.

    Attributes
    ----------
    name : str
        ArduSub's name (``VECTORED_6DOF`` ...) or the custom frame's name.
    config : int
        ``FRAME_CONFIG`` value (7 for a custom frame).
    factors : (n_motors, 6) ndarray
        Dimensionless factor of motor i for input j, columns in :data:`MIXER_INPUTS` order.
    """

    name: str
    config: int
    factors: np.ndarray = field(repr=False)

    @property
    def n_motors(self) -> int:
        return int(self.factors.shape[0])

    @property
    def rank(self) -> int:
        """Rank of the factor matrix: how many independent mixer inputs the motors can express."""
        return int(np.linalg.matrix_rank(self.factors))

    @property
    def unobservable(self) -> tuple:
        """Names of the mixer inputs with no factor on any motor (they do nothing on this frame)."""
        return tuple(n for n, col in zip(MIXER_INPUTS, self.factors.T) if not np.any(col))


def custom_frame(factors, name: str = "CUSTOM", config: int = 7) -> Frame:
    """A frame from user factors (``FRAME_CONFIG`` = 7, CUSTOM: ArduSub has no built-in table for it).

    Parameters
    ----------
    factors : (n_motors, 6) array_like
        Factors per motor in :data:`MIXER_INPUTS` order (roll, pitch, yaw, throttle, forward, lateral).
    """
    f = np.array(factors, float)
    if f.ndim != 2 or f.shape[1] != 6 or not 1 <= f.shape[0] <= 12 or not np.all(np.isfinite(f)):
        raise ValueError(f"custom frame {name!r}: factors must be a finite (n_motors <= 12, 6) table in the order "
                         f"{MIXER_INPUTS}, got shape {f.shape}")
    f.setflags(write=False)
    return Frame(name, int(config), f)


def frame(name_or_config) -> Frame:
    """The ArduSub frame by ``FRAME_CONFIG`` number, ArduSub name or this project's vehicle name.

    Parameters
    ----------
    name_or_config : int or str
        ``2``, ``"VECTORED_6DOF"`` (any case, ``SUB_FRAME_`` prefix allowed), or ``"bluerov2"`` /
        ``"bluerov2-heavy"``.

    Returns
    -------
    Frame
        The frame's name, ``FRAME_CONFIG`` number and motor factors.

    Raises
    ------
    ValueError
        Unknown frame, or CUSTOM (7), whose factors only the user knows (use :func:`custom_frame`).
    """
    if isinstance(name_or_config, Frame):
        return name_or_config
    if isinstance(name_or_config, (int, np.integer)) and not isinstance(name_or_config, bool):
        if int(name_or_config) not in FRAME_CONFIGS:
            raise ValueError(f"FRAME_CONFIG {name_or_config} is not an ArduSub frame; known: {FRAME_CONFIGS}")
        name = FRAME_CONFIGS[int(name_or_config)]
    elif isinstance(name_or_config, str):
        key = name_or_config.strip()
        name = VEHICLE_FRAMES.get(key.lower(), key.upper().removeprefix("SUB_FRAME_"))
        if name.isdigit():
            return frame(int(name))
    else:
        raise ValueError(f"frame: expected a FRAME_CONFIG int or a frame/vehicle name, got {name_or_config!r}")
    if name == "CUSTOM":
        raise ValueError("FRAME_CONFIG 7 (CUSTOM) has no factor table in ArduSub (setup_motors: 'Put your custom "
                         "motor setup here'); give the vehicle's factors with custom_frame(factors)")
    if name not in FRAME_FACTORS:
        raise ValueError(f"unknown ArduSub frame {name_or_config!r}; known: {sorted(FRAME_FACTORS)} or "
                         f"{sorted(VEHICLE_FRAMES)} or FRAME_CONFIG {sorted(FRAME_CONFIGS)}")
    config = {v: k for k, v in FRAME_CONFIGS.items()}[name]
    f = np.array(FRAME_FACTORS[name], float)
    f.setflags(write=False)
    return Frame(name, config, f)


def frame_of_vehicle(vehicle: Vehicle) -> Frame:
    """The ArduSub frame of a vehicle model: its ``ardusub_frame`` field, else its name (``bluerov2``...).

    Raises
    ------
    ValueError
        The vehicle names no ArduSub frame, or its frame's motor count differs from its thruster count.
    """
    tag = (vehicle.extras or {}).get("ardusub_frame")
    if tag is None and vehicle.name in VEHICLE_FRAMES:
        tag = vehicle.name
    if tag is None:
        raise ValueError(f"vehicle {vehicle.name!r} has no 'ardusub_frame' field (docs/vehicle_models.md) and is not "
                         f"one of {sorted(VEHICLE_FRAMES)}: give the frame explicitly")
    fr = frame(tag)
    if fr.n_motors != vehicle.n_thrusters:
        raise ValueError(f"vehicle {vehicle.name!r}: frame {fr.name} has {fr.n_motors} motors but the model has "
                         f"{vehicle.n_thrusters} thrusters")
    return fr


# ----------------------------------------------------------------------------- parameters
#: ArduSub's defaults of the parameters this module reads (ArduSub Parameters.h defaults_table and
#: AP_Motors6DOF / AP_MotorsMulticopter var_info).
PARAMETER_DEFAULTS = {"MOT_PWM_MIN": 1100.0, "MOT_PWM_MAX": 1900.0, "MOT_FV_CPLNG_K": 1.0,
                      "MOT_BAT_VOLT_MAX": 0.0, "MOT_BAT_VOLT_MIN": 0.0, "MOT_BAT_CURR_MAX": 0.0}


@dataclass(frozen=True)
class MotorParameters:
    """ArduSub's output-side parameters.

    Attributes
    ----------
    pwm_min, pwm_max : float
        ``MOT_PWM_MIN``/``MOT_PWM_MAX``, us (Sub defaults 1100/1900); full reverse / full forward command.
    directions : tuple of int
        ``MOT_i_DIRECTION`` (+1 normal, -1 reversed) per motor.
    forward_vertical_coupling : float
        ``MOT_FV_CPLNG_K`` (VECTORED frame only), dimensionless, default 1.0.
    max_throttle : float
        ``_max_throttle`` of AP_Motors6DOF (VECTORED_6DOF: upper limit of the bidirectional throttle), 1.0 = no
        limit. ArduSub lowers it (``set_max_throttle``) only while the vehicle is at the surface, so it is a state,
        not a log parameter; set it for such a stretch.
    bat_volt_max, bat_volt_min : float
        ``MOT_BAT_VOLT_MAX/MIN``, V (0 = off). Read and reported; ArduSub 4.1-4.5 does not apply them to
        AP_Motors6DOF's output (module docstring).
    bat_curr_max : float
        ``MOT_BAT_CURR_MAX``, A (0 = off): current limiting scales all outputs (``output_limit`` of :func:`mix`).
    assumed : tuple of str
        ``"NAME = default"`` for every parameter the log did not hold.
    """

    pwm_min: float = 1100.0
    pwm_max: float = 1900.0
    directions: tuple = ()
    forward_vertical_coupling: float = 1.0
    max_throttle: float = 1.0
    bat_volt_max: float = 0.0
    bat_volt_min: float = 0.0
    bat_curr_max: float = 0.0
    assumed: tuple = ()

    def __post_init__(self):
        if not (self.pwm_min < PWM_NEUTRAL < self.pwm_max):
            raise ValueError(f"MOT_PWM_MIN {self.pwm_min} us < 1500 us < MOT_PWM_MAX {self.pwm_max} us is required")
        if any(d not in (-1, 1) for d in self.directions):
            raise ValueError(f"MOT_i_DIRECTION must each be +1 or -1, got {self.directions}")

    @classmethod
    def default(cls, n_motors: int) -> MotorParameters:
        """ArduSub's defaults for ``n_motors`` motors (all directions +1), each listed in :attr:`assumed`."""
        return cls.from_log_params({}, n_motors)

    @classmethod
    def from_log_params(cls, params: dict, n_motors: int) -> MotorParameters:
        """Read ``MOT_PWM_MIN``, ``MOT_PWM_MAX``, ``MOT_1..n_DIRECTION``, ``MOT_FV_CPLNG_K`` and ``MOT_BAT_*`` from a
        log's parameters; each missing one takes ArduSub's default and is listed in
        :attr:`assumed`.

        As in ``AP_MotorsMulticopter::get_pwm_output_min/max``, a ``MOT_PWM_MIN/MAX`` pair that is not valid
        (<= 0 or max <= min) gives way to ``RC3_MIN/RC3_MAX``; ``MOT_BAT_VOLT_MAX`` > 0 is noted as not modelled.

        Parameters
        ----------
        params : dict
            Parameter name -> value (as the converters read them from PARM / PARAM_VALUE).
        n_motors : int
            Number of motors of the frame (1..12).
        """
        if not 1 <= int(n_motors) <= 12:
            raise ValueError(f"n_motors must be 1..12 (ArduSub's MOT_1..12_DIRECTION), got {n_motors}")
        assumed = []

        def get(name, default):
            v = params.get(name)
            if v is None or not np.isfinite(float(v)):
                assumed.append(f"{name} = {default:g}")
                return float(default)
            return float(v)

        pmin = get("MOT_PWM_MIN", PARAMETER_DEFAULTS["MOT_PWM_MIN"])
        pmax = get("MOT_PWM_MAX", PARAMETER_DEFAULTS["MOT_PWM_MAX"])
        if not (pmin > 0 and pmax > pmin):
            rmin, rmax = params.get("RC3_MIN"), params.get("RC3_MAX")
            pmin, pmax = (float(rmin), float(rmax)) if rmin and rmax else (1100.0, 1900.0)
            assumed.append(f"MOT_PWM_MIN/MAX not set: RC3_MIN/MAX range {pmin:g}-{pmax:g} us used "
                           "(AP_MotorsMulticopter::get_pwm_output_min/max)")
        dirs = []
        for i in range(1, int(n_motors) + 1):
            d = get(f"MOT_{i}_DIRECTION", 1.0)
            if d not in (-1.0, 1.0):
                raise ValueError(f"log parameter MOT_{i}_DIRECTION = {d:g}: ArduSub accepts 1 (normal) or -1 (reverse)")
            dirs.append(int(d))
        fv = get("MOT_FV_CPLNG_K", PARAMETER_DEFAULTS["MOT_FV_CPLNG_K"])
        vmax = get("MOT_BAT_VOLT_MAX", 0.0)
        vmin = get("MOT_BAT_VOLT_MIN", 0.0)
        imax = get("MOT_BAT_CURR_MAX", 0.0)
        if vmax > 0:
            assumed.append(f"MOT_BAT_VOLT_MAX = {vmax:g} V: ArduSub 4.1-4.5 does not compensate AP_Motors6DOF's "
                           "output for voltage; not modelled")
        return cls(pmin, pmax, tuple(dirs), fv, 1.0, vmax, vmin, imax, tuple(assumed))


def _params(params: MotorParameters | None, n: int) -> MotorParameters:
    p = params if params is not None else MotorParameters.default(n)
    if len(p.directions) == 0:
        p = MotorParameters(p.pwm_min, p.pwm_max, (1,) * n, p.forward_vertical_coupling, p.max_throttle,
                            p.bat_volt_max, p.bat_volt_min, p.bat_curr_max, p.assumed)
    if len(p.directions) != n:
        raise ValueError(f"{len(p.directions)} MOT_i_DIRECTION values for {n} motors")
    return p


# ----------------------------------------------------------------------------- mixer
def throttle_bidirectional(throttle_in):
    """``AP_Motors::get_throttle_bidirectional``: 2 (throttle_in - 0.5) clipped to [-1, 1].

    ``throttle_in`` is ArduSub's 0..1 throttle (RATE log ``AOut``; 0.5 = neutral); the result is the mixer's
    ``throttle`` input, positive = up (the vertical motors' throttle factor is -1 and their positive command pushes
    down, so a positive throttle pushes the vehicle towards -z).
    """
    return np.clip(2.0 * (np.asarray(throttle_in, float) - 0.5), -1.0, 1.0)


def mix(frame: Frame, inputs, params: MotorParameters | None = None, output_limit=1.0):
    """ArduSub's mixer: motor commands in [-1, 1] before ``MOT_i_DIRECTION`` (module docstring for the source).

    Parameters
    ----------
    frame : Frame
    inputs : (..., 6) array_like
        roll, pitch, yaw, throttle, forward, lateral (:data:`MIXER_INPUTS`), dimensionless, nominally in [-1, 1];
        throttle is the bidirectional one (:func:`throttle_bidirectional` of the 0..1 ``AOut``).
    params : MotorParameters, optional
        For ``MOT_FV_CPLNG_K`` (VECTORED) and ``max_throttle`` (VECTORED_6DOF); ArduSub defaults if None.
    output_limit : float or (...) array_like
        ``_output_limited`` of the current limiter (``MOT_BAT_CURR_MAX``), 1 when it is off.

    Returns
    -------
    (..., n_motors) ndarray
        Each motor's thrust command, dimensionless in [-1, 1] (positive = along the motor's direction with
        ``MOT_i_DIRECTION`` = +1). NaN inputs give NaN.
    """
    u = np.asarray(inputs, float)
    if u.shape[-1:] != (6,):
        raise ValueError(f"mix: inputs must have a last axis of 6 {MIXER_INPUTS}, got shape {u.shape}")
    p = _params(params, frame.n_motors)
    F = frame.factors
    roll, pitch, yaw, thr, fwd, lat = (u[..., k] for k in range(6))
    thr = np.clip(thr, -1.0, 1.0)  # _throttle_thrust_max = 1 for Sub
    if frame.name == "VECTORED_6DOF":
        thr = np.minimum(thr, p.max_throttle)
        rpt = roll[..., None] * F[:, 0] + pitch[..., None] * F[:, 1] + thr[..., None] * F[:, 3]
        yfl = yaw[..., None] * F[:, 2] + fwd[..., None] * F[:, 4] + lat[..., None] * F[:, 5]
        rpt_max = np.maximum(1.0, np.max(np.abs(rpt), axis=-1, keepdims=True))
        yfl_max = np.maximum(1.0, np.max(np.abs(yfl), axis=-1, keepdims=True))
        out = rpt / rpt_max + yfl / yfl_max
    else:
        rpy = roll[..., None] * F[:, 0] + pitch[..., None] * F[:, 1] + yaw[..., None] * F[:, 2]
        fwd_m = np.broadcast_to(fwd[..., None], rpy.shape)
        if frame.name == "VECTORED":
            limit = np.maximum(1.0 - p.forward_vertical_coupling * np.abs(thr), 0.0)[..., None]
            cdir = np.zeros(frame.n_motors)
            cdir[:4] = _FORWARD_COUPLING_DIRECTION
            rear = (cdir != 0) & ((fwd_m < 0) == (cdir < 0))
            fwd_m = np.where(rear & (fwd_m != 0), np.clip(fwd_m, -limit, limit), fwd_m)
        linear = thr[..., None] * F[:, 3] + fwd_m * F[:, 4] + lat[..., None] * F[:, 5]
        out = rpy + linear
    out = np.clip(out, -1.0, 1.0) * np.asarray(output_limit, float)[..., None]
    return np.where(np.isnan(out), np.nan, out)


def to_pwm(thrust_out, params: MotorParameters | None = None, integer: bool = True):
    """``AP_Motors6DOF::calc_thrust_to_pwm`` with ``MOT_i_DIRECTION``: motor commands -> PWM (us).

    pwm_i = 1500 + c (MOT_PWM_MAX - 1500) for c > 0, 1500 + c (1500 - MOT_PWM_MIN) otherwise, with
    c = MOT_i_DIRECTION * thrust_out_i: a reversed motor's PWM is mirrored about 1500 us.

    Parameters
    ----------
    thrust_out : (..., n) array_like
        Commands in [-1, 1] (:func:`mix`), clipped to it.
    integer : bool
        Truncate toward zero as the C ``int16_t`` return does (ArduSub's exact output); False for the
        continuous value.

    Returns
    -------
    (..., n) ndarray
        PWM, us.
    """
    t = np.clip(np.asarray(thrust_out, float), -1.0, 1.0)
    p = _params(params, t.shape[-1])
    c = t * np.asarray(p.directions, float)
    pwm = PWM_NEUTRAL + c * np.where(c > 0, p.pwm_max - PWM_NEUTRAL, PWM_NEUTRAL - p.pwm_min)
    return np.trunc(pwm) if integer else pwm


def from_pwm(pwm, params: MotorParameters | None = None):
    """Inverse of :func:`to_pwm`: PWM (us, (..., n)) -> motor commands in [-1, 1] before ``MOT_i_DIRECTION``.

    PWM outside [MOT_PWM_MIN, MOT_PWM_MAX] is clipped to it; NaN stays NaN.
    """
    pwm = np.asarray(pwm, float)
    p = _params(params, pwm.shape[-1])
    d = np.clip(pwm, p.pwm_min, p.pwm_max) - PWM_NEUTRAL
    c = d / np.where(d > 0, p.pwm_max - PWM_NEUTRAL, PWM_NEUTRAL - p.pwm_min)
    return c * np.asarray(p.directions, float)


def motor_pwm(frame: Frame, inputs, params: MotorParameters | None = None, integer: bool = True, output_limit=1.0):
    """ArduSub's PWM (us, (..., n)) for mixer ``inputs`` (..., 6): ``to_pwm(mix(frame, inputs, params))``."""
    return to_pwm(mix(frame, inputs, params, output_limit), params if params is not None else
                  MotorParameters.default(frame.n_motors), integer)


def unmix(frame: Frame, thrust_out, rcond: float = 1e-10):
    """Least-squares mixer inputs (..., 6) whose *linear* mix is ``thrust_out`` (..., n).

    The minimum-norm solution of ``factors @ u = thrust_out``: exact for unsaturated outputs of a full-rank
    frame (VECTORED_6DOF, VECTORED_6DOF_90DEG, BLUEROV1); on a rank-deficient frame the inputs the frame cannot
    express (VECTORED: pitch; see the module docstring) come back as 0. Saturated or normalised outputs give the
    scaled inputs that were actually delivered, not those requested.
    """
    t = np.asarray(thrust_out, float)
    if t.shape[-1:] != (frame.n_motors,):
        raise ValueError(f"unmix: thrust_out must have a last axis of {frame.n_motors} (frame {frame.name}), got "
                         f"shape {t.shape}")
    return t @ np.linalg.pinv(frame.factors, rcond=rcond).T


# ----------------------------------------------------------------------------- directions from a log
def fit_horizontal_inputs(frame: Frame, known, thrust_out) -> np.ndarray:
    """Forward and lateral inputs (N, 2) whose linear mix, with the ``known`` inputs (N, 4: roll, pitch, yaw,
    bidirectional throttle), best matches the motor commands ``thrust_out`` (N, n), by least squares.

    ArduSub logs the attitude and throttle outputs (RATE ``ROut/POut/YOut/AOut``) but not forward and lateral
    (the pilot's or the position controller's); this recovers them per sample.
    """
    f = frame.factors
    residual = np.asarray(thrust_out, float) - np.asarray(known, float) @ f[:, :4].T
    return residual @ np.linalg.pinv(f[:, 4:6]).T


@dataclass(frozen=True)
class DirectionFit:
    """``MOT_i_DIRECTION`` inferred from a log that lacks the parameters.

    Attributes
    ----------
    directions : tuple of int
        +1 or -1 per motor.
    rms : float
        RMS residual of the best sign pattern's linear mix against the logged commands (dimensionless, 1 = full
        scale).
    runner_up : float
        RMS residual of the second-best pattern: the margin says how clear the inference is.
    samples : int
        Samples used (all of the known inputs and the PWM finite).
    """

    directions: tuple
    rms: float
    runner_up: float
    samples: int


def fit_directions(frame: Frame, known, pwm, params: MotorParameters | None = None) -> DirectionFit:
    """The ``MOT_i_DIRECTION`` pattern (+-1 per motor) that best explains logged ``pwm`` (N, n, us) given the
    ``known`` mixer inputs (N, 4: roll, pitch, yaw, bidirectional throttle), forward and lateral fitted per sample
    (:func:`fit_horizontal_inputs`); all 2^n patterns are tried.

    Raises
    ------
    ValueError
        If fewer than 10 samples have finite known inputs and PWM.
    """
    known = np.asarray(known, float)
    pwm = np.asarray(pwm, float)
    n = frame.n_motors
    p = _params(params, n)
    ok = np.all(np.isfinite(known), axis=1) & np.all(np.isfinite(pwm), axis=1)
    if ok.sum() < 10:
        raise ValueError(f"fit_directions: only {int(ok.sum())} samples with finite mixer inputs and PWM; need 10")
    base = from_pwm(pwm[ok], MotorParameters(p.pwm_min, p.pwm_max, (1,) * n))
    costs = []
    for signs in itertools.product((1, -1), repeat=n):
        thrust = base * np.asarray(signs, float)
        fl = fit_horizontal_inputs(frame, known[ok], thrust)
        lin = np.concatenate([known[ok], fl], axis=1) @ frame.factors.T
        costs.append((float(np.sqrt(np.mean((lin - thrust) ** 2))), signs))
    costs.sort(key=lambda c: c[0])
    return DirectionFit(tuple(int(s) for s in costs[0][1]), costs[0][0], costs[1][0], int(ok.sum()))
