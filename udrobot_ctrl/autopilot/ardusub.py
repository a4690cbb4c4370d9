"""ArduSub's controllers in one object: modes -> attitude and depth loops -> the six mixer inputs.

:class:`ArduSubAutopilot` steps like ``Sub::fast_loop`` (``ArduSub/ArduSub.cpp``, 4.1-4.5)::

    rate_controller_run()      rate PIDs on the rate demand of the previous tick (not in MANUAL)
    motors_output()            mixer inputs: roll/pitch/yaw just computed, throttle (through the motors'
                               throttle low-pass) and forward/lateral from the previous tick's mode update
    update_flight_mode()       the mode: attitude targets -> next rate demand, throttle, forward, lateral
    update_surface_and_bottom_detector()   ap.at_surface / ap.at_bottom for the next tick's mode
                               (:mod:`~udrobot_ctrl.autopilot.surface_bottom`)

so :meth:`ArduSubAutopilot.step` returns :class:`MixerInputs` -- ``(roll, pitch, yaw, throttle, forward,
lateral)``, :data:`~udrobot_ctrl.autopilot.motors.MIXER_INPUTS` order -- for
:func:`~udrobot_ctrl.autopilot.motors.motor_pwm`. The throttle is the motors' filtered ``throttle_in``
(``AP_MotorsMulticopter::update_throttle_filter``; the RATE log's ``AOut``, CTUN's ``ThO``); the cut-off is the
one the mode sets (``PILOT_THR_FILT`` for pilot throttle, ``POSCONTROL_THROTTLE_CUTOFF_FREQ_HZ`` = 2 Hz in the
depth-holding modes).

Modes: MANUAL, STABILIZE, ALT_HOLD (pilot), GUIDED and SURFTRAK (attitude and depth targets given, as logged
or commanded, see :class:`~udrobot_ctrl.ardusub.modes.Targets`; ``Targets(shaped=True)`` takes a log's
already-shaped ATT Des* targets with their rates as feed-forward); ACRO, AUTO, POSHOLD, CIRCLE, SURFACE are not
emulated and raise. ALT_HOLD has ArduSub 4.1.1-4.5's surface and bottom handling: the detector's ``at_surface``
(shallower than ``SURFACE_DEPTH``) and ``at_bottom`` (throttle at its lower limit and no vertical speed for 400
ticks) and, with the throttle stick centred, the depth target held at least 5 cm below ``SURFACE_DEPTH`` or
raised to 10 cm above a bottomed vehicle (:mod:`~udrobot_ctrl.autopilot.surface_bottom`, which also lists the
variants that are not emulated). The detector's ``motors.limit.throttle_lower`` is the autopilot's own (its
filtered throttle at 0, ``AP_Motors6DOF::output_armed_stabilizing``) or the ``limits`` given, and so is the depth
loop's: ``throttle_lower`` / ``throttle_upper`` at the motors' throttle clamp (0 / 1) of this tick's output stop
the depth loop's integrators from growing and its target from moving further towards the limit (the saturation
handling of :mod:`~udrobot_ctrl.autopilot.depth`).
Not emulated: the surface throttle limit ``SURFACE_MAX_THR`` (after 4.5), SURFTRAK's rangefinder ->
depth-target law (``ModeSurftrak::control_range``, ArduSub 4.5 only: give the depth target, e.g. the logged one),
the ``SET_ATTITUDE_TARGET`` override of ALT_HOLD, failsafes.

Closed loop (the plant's 12-state ``x``, NED, body velocities)::

    ap = ArduSubAutopilot(ArduSubParameters.from_log_params(log_params, loop_rate_hz=400.0))
    fr = frame("VECTORED_6DOF"); mp = MotorParameters.from_log_params(log_params, fr.n_motors)
    for k in range(n):
        u = ap.step(dt, VehicleState.from_plant(x, accel_down=a_down), pilot, Mode.ALT_HOLD)
        pwm = motor_pwm(fr, u.as_array(), mp)          # -> thrusters -> plant -> x, a_down

Checked against the Seattle dive by :func:`udrobot_ctrl.autopilot.validate.replay_autopilot` (bench/autopilot.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from udrobot_ctrl.ardusub.modes import YAW_HOLD_DELAY, Mode, PilotInput, Targets, shape_pilot
from udrobot_ctrl.ardusub.params import ArduSubParameters
from udrobot_ctrl.autopilot.attitude import AttitudeController, euler_rate_to_ang_vel, quat_from_euler
from udrobot_ctrl.autopilot.depth import DepthController
from udrobot_ctrl.autopilot.motors import throttle_bidirectional
from udrobot_ctrl.autopilot.pid import PIDTerms, lowpass_alpha
from udrobot_ctrl.autopilot.surface_bottom import SurfaceBottomDetector, althold_depth_target

SUPPORTED_MODES = (Mode.MANUAL, Mode.STABILIZE, Mode.ALT_HOLD, Mode.GUIDED, Mode.SURFTRAK)


@dataclass(frozen=True)
class VehicleState:
    """What ArduSub's controllers read from the AHRS and inertial navigation (SI, NED).

    Attributes
    ----------
    roll, pitch, yaw : float
        Attitude, 3-2-1 Euler angles (rad).
    rates : tuple of 3 float
        Body angular rates p, q, r (rad/s) (the gyro).
    depth : float
        Depth (m, positive down).
    vel_down : float
        Vertical velocity (m/s, positive down).
    accel_down : float
        Kinematic vertical acceleration (m/s^2, positive down; ArduSub's ``-(accel_ef.z + g)`` with the sign
        flipped).
    """

    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    rates: tuple = (0.0, 0.0, 0.0)
    depth: float = 0.0
    vel_down: float = 0.0
    accel_down: float = 0.0

    @classmethod
    def from_plant(cls, x, accel_down: float = 0.0) -> VehicleState:
        """From the plant's 12-state ``x`` (x y z phi theta psi, u v w p q r; NED, body velocities).

        Parameters
        ----------
        x : array (12,)
            Plant state (m, rad, m/s, rad/s).
        accel_down : float
            Vertical kinematic acceleration (m/s^2, down), e.g. from the state derivative.
        """
        x = np.asarray(x, dtype=float)
        phi, theta, psi = x[3], x[4], x[5]
        u, v, w = x[6], x[7], x[8]
        # third row of the body->NED rotation
        vel_down = -math.sin(theta) * u + math.sin(phi) * math.cos(theta) * v + math.cos(phi) * math.cos(theta) * w
        return cls(roll=phi, pitch=theta, yaw=psi, rates=(x[9], x[10], x[11]), depth=x[2], vel_down=vel_down,
                   accel_down=accel_down)

    def quaternion(self) -> np.ndarray:
        """Body-to-NED quaternion ``[w, x, y, z]``."""
        return quat_from_euler(self.roll, self.pitch, self.yaw)


@dataclass(frozen=True)
class MixerInputs:
    """The six inputs of ArduSub's mixer (``AP_Motors6DOF``).

    Attributes
    ----------
    roll, pitch, yaw : float
        Rate-controller outputs incl. FF (-1..1; the RATE log's ROut, POut, YOut).
    throttle : float
        ArduSub's ``throttle_in`` after the motors' filter, 0..1 with 0.5 neutral (RATE.AOut, CTUN.ThO).
    forward, lateral : float
        -1..1.
    """

    roll: float
    pitch: float
    yaw: float
    throttle: float
    forward: float
    lateral: float

    def as_array(self, bidirectional: bool = True) -> np.ndarray:
        """``[roll, pitch, yaw, throttle, forward, lateral]`` (``MIXER_INPUTS`` order) for :func:`motors.mix`.

        With ``bidirectional`` (default) the throttle is ``get_throttle_bidirectional`` = 2 (throttle - 0.5),
        what :func:`~udrobot_ctrl.autopilot.motors.mix` and ``motor_pwm`` take; otherwise the 0..1 ``throttle_in``.
        """
        thr = float(throttle_bidirectional(self.throttle)) if bidirectional else self.throttle
        return np.array([self.roll, self.pitch, self.yaw, thr, self.forward, self.lateral])


@dataclass(frozen=True)
class MotorLimits:
    """``AP_Motors::limit`` flags fed back from the mixer (saturation): integrators only shrink."""

    roll: bool = False
    pitch: bool = False
    yaw: bool = False
    throttle_lower: bool = False
    throttle_upper: bool = False


class ArduSubAutopilot:
    """ArduSub's flight controller (4.1-4.5): modes, attitude and depth loops, with their state.

    Parameters
    ----------
    params : ArduSubParameters, optional
        ArduSub's parameters (SI); :meth:`ArduSubParameters.defaults` if None.

    Examples
    --------
    >>> ap = ArduSubAutopilot()
    >>> u = ap.step(0.0025, VehicleState(depth=2.0), PilotInput.centred(), Mode.ALT_HOLD)
    >>> u.as_array().shape
    (6,)
    """

    def __init__(self, params: ArduSubParameters | None = None):
        self.params = params if params is not None else ArduSubParameters.defaults()
        self.reset()

    def reset(self) -> None:
        """Back to power-on: no mode yet, controllers reset, neutral outputs."""
        self.attitude = AttitudeController(self.params.attitude)
        self.depth = DepthController(self.params.depth)
        self.surface_bottom = SurfaceBottomDetector(self.params.depth.surface_depth)
        #: ticks on which ALT_HOLD's surface / bottom clamp moved the depth target
        self.surface_clamps = 0
        self.bottom_clamps = 0
        self.mode: Mode | None = None
        self.time = 0.0
        self._throttle_in = 0.5
        self._throttle_out = 0.5
        self._throttle_cutoff = self.params.pilot.throttle_filt_hz
        self._forward = 0.0
        self._lateral = 0.0
        self._manual_rpy = np.zeros(3)
        self._last_pilot_heading = 0.0
        self._last_yaw_input_time = -math.inf
        self._started = False
        self._pending_integrators = None

    # ----------------------------------------------------------------------------------------------- modes
    def _enter(self, mode: Mode, state: VehicleState) -> None:
        """``Mode*::init`` of ArduSub for ``mode``."""
        if mode not in SUPPORTED_MODES:
            raise ValueError(f"ArduSub mode {mode!r} is not emulated; supported: "
                             f"{', '.join(m.name for m in SUPPORTED_MODES)}")
        if mode == Mode.MANUAL:
            self._manual_rpy[:] = 0.0  # set_neutral_controls
        if mode in (Mode.ALT_HOLD, Mode.SURFTRAK, Mode.GUIDED) and (
                self.mode not in (Mode.ALT_HOLD, Mode.SURFTRAK, Mode.GUIDED) or not self.depth.active):
            self.depth.init(state.depth, state.vel_down, self._throttle_in)
        self._last_pilot_heading = state.yaw
        self.mode = mode

    def _pilot_attitude(self, state: VehicleState, cmd, dt: float) -> None:
        """STABILIZE / ALT_HOLD attitude part (``mode_stabilize.cpp``, ``ModeAlthold::run_pre``)."""
        q, gyro = state.quaternion(), state.rates
        if cmd.yaw_rate != 0.0:
            self.attitude.input_euler_angle_roll_pitch_euler_rate_yaw(cmd.roll, cmd.pitch, cmd.yaw_rate, q, gyro, dt)
            self._last_pilot_heading = state.yaw
            self._last_yaw_input_time = self.time
        elif self.time < self._last_yaw_input_time + YAW_HOLD_DELAY:
            self.attitude.input_euler_angle_roll_pitch_euler_rate_yaw(cmd.roll, cmd.pitch, 0.0, q, gyro, dt)
            self._last_pilot_heading = state.yaw
        else:
            self.attitude.input_euler_angle_roll_pitch_yaw(cmd.roll, cmd.pitch, self._last_pilot_heading, True, q,
                                                           gyro, dt)

    def _update_flight_mode(self, dt: float, state: VehicleState, pilot: PilotInput, targets: Targets | None,
                            limits: MotorLimits) -> None:
        p = self.params
        mode = self.mode
        if mode in (Mode.ALT_HOLD, Mode.SURFTRAK):
            limit = self.attitude_lean_limit()
        else:
            limit = None
        cmd = shape_pilot(pilot, p.pilot, p.depth, angle_limit=limit)
        if mode == Mode.MANUAL:
            self._manual_rpy[:] = (cmd.norm["roll"], cmd.norm["pitch"],
                                   cmd.norm["yaw"] * p.pilot.acro_yaw_p / 3.375)
            self._throttle_in = cmd.throttle
            self._throttle_cutoff = p.pilot.throttle_filt_hz
            self._forward, self._lateral = cmd.norm["forward"], cmd.norm["lateral"]
            return
        if mode == Mode.STABILIZE:
            self._pilot_attitude(state, cmd, dt)
            self._throttle_in = cmd.throttle
            self._throttle_cutoff = p.pilot.throttle_filt_hz
            self._forward, self._lateral = cmd.norm["forward"], cmd.norm["lateral"]
            return
        if mode == Mode.GUIDED or (mode == Mode.SURFTRAK and targets is not None):
            t = targets if targets is not None else Targets()
            q = state.quaternion()
            if t.shaped:
                euler_rates = (t.roll_rate, t.pitch_rate, t.yaw_rate)
                yaw = t.yaw if t.yaw is not None else state.yaw
                self.attitude.input_target(quat_from_euler(t.roll, t.pitch, yaw),
                                           euler_rate_to_ang_vel((t.roll, t.pitch), euler_rates), q, state.rates, dt)
            elif t.yaw is not None:
                self.attitude.input_euler_angle_roll_pitch_yaw(t.roll, t.pitch, t.yaw, True, q, state.rates, dt)
            else:
                self.attitude.input_euler_angle_roll_pitch_euler_rate_yaw(t.roll, t.pitch, t.yaw_rate, q,
                                                                          state.rates, dt)
            if t.depth is not None:
                self.depth.set_targets(t.depth, t.vel_down, t.accel_down)
            if mode == Mode.GUIDED:
                self._forward, self._lateral = t.forward, t.lateral
            else:
                self._forward, self._lateral = cmd.norm["forward"], cmd.norm["lateral"]
        else:  # ALT_HOLD, SURFTRAK without targets (ALT_HOLD's depth hold)
            self._pilot_attitude(state, cmd, dt)
            self._clamp_depth_target(state, cmd.climb_rate)
            self.depth.set_pos_target_from_climb_rate(cmd.climb_rate, dt)
            self._forward, self._lateral = cmd.norm["forward"], cmd.norm["lateral"]
        self._throttle_in = self.depth.update(state.depth, state.vel_down, state.accel_down, dt,
                                              limits.throttle_lower, limits.throttle_upper)
        self._throttle_cutoff = p.depth.throttle_cutoff_hz

    def _clamp_depth_target(self, state: VehicleState, climb_rate: float) -> None:
        """``control_depth``'s surface / bottom clamp of the depth target (:func:`.althold_depth_target`)."""
        det = self.surface_bottom
        clamp = althold_depth_target(self.depth.pos_target, state.depth, climb_rate, det.at_surface, det.at_bottom,
                                     self.params.depth.surface_depth)
        self.depth.pos_target = clamp.target
        self.surface_clamps += clamp.reason == "surface"
        self.bottom_clamps += clamp.reason == "bottom"

    def attitude_lean_limit(self) -> float:
        """ALT_HOLD's lean limit (rad): ``get_althold_lean_angle_max`` is at least 10 deg and ``ANGLE_MAX`` at
        most; for a sub at neutral throttle ``acos(throttle / (0.8 thr_max))`` is near 51 deg, so ``ANGLE_MAX``
        (45 deg by default) binds; the ANGLE_MAX limit is used."""
        return self.params.pilot.angle_max

    # ------------------------------------------------------------------------------------------------ step
    def step(self, dt: float, state: VehicleState, pilot: PilotInput | None = None, mode: Mode | int = Mode.STABILIZE,
             targets: Targets | None = None, limits: MotorLimits | None = None, armed: bool = True) -> MixerInputs:
        """One main-loop tick; returns the mixer inputs.

        Parameters
        ----------
        dt : float
            Tick (s), normally ``1 / params.loop_rate_hz``.
        state : VehicleState
            The vehicle's attitude, rates, depth, vertical velocity and acceleration (SI, NED).
        pilot : PilotInput, optional
            RC inputs (us); all centred if None.
        mode : Mode or int
            ArduSub mode number; a change runs the new mode's ``init``.
        targets : Targets, optional
            GUIDED / SURFTRAK attitude, depth and horizontal targets.
        limits : MotorLimits, optional
            Mixer saturation flags of the previous output (none if None); the surface/bottom detector also sets
            ``throttle_lower`` from the autopilot's own throttle at 0.
        armed : bool
            False: outputs neutral, controllers relaxed (``relax_attitude_controllers``, depth relaxed).

        Returns
        -------
        MixerInputs
            ``(roll, pitch, yaw, throttle, forward, lateral)``.
        """
        mode = Mode(int(mode))
        pilot = pilot if pilot is not None else PilotInput.centred()
        limits = limits if limits is not None else MotorLimits()
        if not armed:
            self.attitude.relax(state.quaternion(), state.rates)
            self.depth.relax(state.depth, 0.5)
            self.surface_bottom.update(state.depth, state.vel_down, False, armed=False)
            self._throttle_in = self._throttle_out = 0.5
            self._forward = self._lateral = 0.0
            self.mode = mode
            self._last_pilot_heading = state.yaw
            self.time += dt
            return MixerInputs(0.0, 0.0, 0.0, 0.5, 0.0, 0.0)
        if not self._started:
            self.attitude.relax(state.quaternion(), state.rates)
            self._started = True
        if mode != self.mode:
            self._enter(mode, state)
        self._apply_integrators()
        # 1. rate controller (not in MANUAL: Sub::fast_loop)
        if mode == Mode.MANUAL:
            rpy = self._manual_rpy.copy()
        else:
            rpy = self.attitude.rate_controller_run(state.rates, dt, (limits.roll, limits.pitch, limits.yaw))
        # 2. motors output: throttle filter on the previous tick's throttle_in
        self._throttle_out += lowpass_alpha(dt, self._throttle_cutoff) * (self._throttle_in - self._throttle_out)
        self._throttle_out = min(max(self._throttle_out, 0.0), 1.0)
        out = MixerInputs(float(rpy[0]), float(rpy[1]), float(rpy[2]), self._throttle_out, self._forward,
                          self._lateral)
        # motors.limit of this output (AP_Motors6DOF::output_armed_stabilizing: bidirectional throttle at -1 / +1),
        # read by this tick's update_z_controller
        limits = replace(limits, throttle_lower=limits.throttle_lower or self._throttle_out <= 0.0,
                         throttle_upper=limits.throttle_upper or self._throttle_out >= 1.0)
        # 3. flight mode update for the next tick
        self._update_flight_mode(dt, state, pilot, targets, limits)
        # 4. surface and bottom detector (read by the next tick's mode); motors.limit.throttle_lower as above
        self.surface_bottom.update(state.depth, state.vel_down, limits.throttle_lower)
        self.time += dt
        return out

    def set_integrators(self, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0,
                        accel_down: float | None = None) -> None:
        """Start the integrators where a log has them (PIDR/PIDP/PIDY ``I``; PIDA ``I``, down frame, throttle).

        For replays that begin inside a log: ArduSub's integrators carry the trims (buoyancy, tether, current)
        that the first seconds of a replay would otherwise have to wind up again. Applied at once when the
        autopilot is running, else at the first :meth:`step` after its start-up relax and mode ``init``.
        """
        self._pending_integrators = (roll, pitch, yaw, accel_down)
        if self._started:
            self._apply_integrators()

    def _apply_integrators(self) -> None:
        if self._pending_integrators is None:
            return
        *rpy, accel = self._pending_integrators
        for pid, value in zip(self.attitude.rate_pids, rpy):
            pid.set_integrator(value)
        if accel is not None:
            self.depth.pid_accel.set_integrator(accel)
        self._pending_integrators = None

    @property
    def pid_terms(self) -> dict[str, PIDTerms]:
        """The last PID terms as the log names them: PIDR, PIDP, PIDY (rate loops), PIDA (depth accel loop)."""
        r, p, y = self.attitude.terms
        return {"PIDR": r, "PIDP": p, "PIDY": y, "PIDA": self.depth.terms}


__all__ = ["ArduSubAutopilot", "MixerInputs", "MotorLimits", "SUPPORTED_MODES", "VehicleState"]
