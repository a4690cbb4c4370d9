"""Fly a model under the emulated ArduSub from a log's pilot inputs, modes and targets (``simulate --closed-loop``).

The open-loop replay holds the logged motor outputs; on a field log those are 2-10 Hz samples of ArduSub's 200-400 Hz
stabilising loop, and the replayed attitude runs away. Here the model is flown the way the vehicle was: the emulated
autopilot (:class:`~udrobot_ctrl.autopilot.ardusub.ArduSubAutopilot`, one tick per control step) reads the
simulated state and the log's own inputs to the autopilot, and its mixer output
(:func:`~udrobot_ctrl.autopilot.motors.motor_pwm`) drives the model's thrusters through the T-200 curve at the logged
battery voltage. What the log gives the autopilot, per mode:

* MANUAL, STABILIZE, ALT_HOLD: the pilot's RC inputs (``rcin_1`` .. ``rcin_8``), shaped as ArduSub shapes them;
  ALT_HOLD with its surface and bottom handling (:mod:`~udrobot_ctrl.autopilot.surface_bottom`: ``SURFACE_DEPTH``
  from the log, else ArduSub's -10 cm, and the result says which and how often a clamp moved the target);
* GUIDED: the logged attitude targets (``roll_target``, ``pitch_target``, ``yaw_target``) and depth
  target (``z_target``), with forward and lateral as the logged motor outputs hold them (the mixer inverse of
  ``pwm_i``: ArduSub does not log them);
* SURFTRAK (ArduSub 4.5 only, added in Sub-4.5.0-beta2): *not emulated* -- its rangefinder -> depth-target law
  (``ModeSurftrak::control_range`` / ``update_surface_offset``) would need the seabed under the simulated vehicle.
  It is flown on the logged depth and attitude targets like GUIDED, with the pilot's forward/lateral (as the mode
  takes them), and the result says so; without a logged depth target the depth target stays where it was;
* every other mode (POSHOLD, AUTO, ...), which is not emulated: flown like GUIDED on its logged targets, and the
  result says so.

The integration is :func:`udrobot_ctrl.dynamics.sim.simulate` with the autopilot as its controller (one definition
of the plant and of its integrator), the plant's state at the log's first row as the start.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from udrobot_ctrl.ardusub.modes import Mode, PilotInput, Targets, logged_pulses, logged_targets
from udrobot_ctrl.ardusub.params import ArduSubParameters, run_log_params
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot, MotorLimits, VehicleState
from udrobot_ctrl.autopilot.motors import Frame, MotorParameters, frame, from_pwm, mix, to_pwm, unmix
from udrobot_ctrl.dynamics.plant import PlantParameters, plant_parameters
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.io.runlog import Run, check_context_columns
from udrobot_ctrl.vehicle import load_model

#: modes the emulation flies from the pilot's inputs
PILOT_MODES = (Mode.MANUAL, Mode.STABILIZE, Mode.ALT_HOLD)
#: modes flown on the logged targets (GUIDED is emulated this way; SURFTRAK's own depth law is not emulated and is
#: flown so as a stand-in, and so are the other modes, see :func:`mode_notes`)
TARGET_MODES = (Mode.GUIDED, Mode.SURFTRAK)


@dataclass(frozen=True)
class LoggedCommands:
    """What a run logged of the autopilot's inputs, held between samples (zero-order hold on the run's ``t``).

    Attributes
    ----------
    t : (n,) ndarray
        Sample times, s.
    mode : (n,) ndarray
        ArduSub mode number (nan before the first mode message: the first logged mode is used there).
    armed : (n,) bool ndarray
        Armed (all True when the log does not tell).
    rcin : (n, 8) ndarray or None
        Pilot RC inputs, us (1500, centred, where the run has no sample).
    attitude_target : (n, 3) ndarray or None
        Roll, pitch, yaw targets, rad.
    z_target : (n,) ndarray or None
        Depth target, m down.
    horizontal : (n, 2) ndarray
        Forward and lateral mixer inputs held by the logged PWM (dimensionless).
    voltage : (n,) ndarray
        Battery voltage, V (the model's supply voltage where not logged).
    notes : tuple of str
        What was read in place of a missing input (a centred RC channel, a held target).
    """

    t: np.ndarray
    mode: np.ndarray
    armed: np.ndarray
    rcin: np.ndarray | None
    attitude_target: np.ndarray | None
    z_target: np.ndarray | None
    horizontal: np.ndarray
    voltage: np.ndarray
    notes: tuple = ()

    @classmethod
    def from_run(cls, run: Run, fr: Frame, motors: MotorParameters, supply_voltage: float) -> LoggedCommands:
        """The autopilot inputs of a converted ArduSub run (its context columns, docs/formats/runlog.md), checked
        (:func:`~udrobot_ctrl.io.runlog.check_context_columns`: ArduSub's own mode numbers only).

        A missing ``rcin_k`` column is a centred stick on that channel alone (noted), as is a sample that is no
        pulse (:func:`~udrobot_ctrl.ardusub.modes.pilot_pulses`). The rows flown on logged targets (every mode
        but MANUAL, STABILIZE, ALT_HOLD) need them: without an attitude target there (or, outside SURFTRAK, a depth
        target) the run is refused rather than flown on a target of zero; a row whose target is empty between
        logged ones holds the last logged target, and :attr:`notes` counts them.

        Raises
        ------
        ValueError
            If the run has no ``mode`` column, its inputs are not the frame's ``pwm_i``, a context column is
            not what the format says, or the rows flown on targets have none.
        """
        where = run.path or "run"
        if run.input_kind != "pwm" or run.inputs.shape[1] != fr.n_motors:
            raise ValueError(f"{where}: the closed-loop flight needs the {fr.n_motors} pwm_i columns of "
                             f"frame {fr.name}; the run has {run.inputs.shape[1]} {run.input_kind} columns")
        check_context_columns(run.extra, where)
        mode = run.extra.get("mode")
        if mode is None or not np.isfinite(mode).any():
            raise ValueError(f"{where}: no 'mode' column: the closed-loop flight needs the log's flight "
                             f"modes (convert an ArduSub .bin/.tlog with udrobot-ctrl convert)")
        first = mode[np.isfinite(mode)][0]
        mode = np.where(np.isfinite(mode), mode, first)
        notes = []
        armed = run.extra.get("armed")
        armed = np.ones(run.n, bool) if armed is None else np.nan_to_num(armed, nan=1.0) != 0
        by_pilot = np.isin(mode, [float(m) for m in PILOT_MODES])
        rcin = logged_pulses(run.extra, run.n, notes if by_pilot.any() else [])
        attitude, z_target = None, run.extra.get("z_target")
        if not by_pilot.all():  # flown on the logged targets; outside SURFTRAK a depth target too
            t = np.asarray(run.t, float) - float(run.t[0])
            attitude = np.column_stack([logged_targets(run.extra, c, ~by_pilot, mode, t, where, notes)
                                        for c in ("roll_target", "pitch_target", "yaw_target")])
            if (~by_pilot & (mode != float(Mode.SURFTRAK))).any():
                z_target = logged_targets(run.extra, "z_target", ~by_pilot & (mode != float(Mode.SURFTRAK)), mode,
                                          t, where, notes)
        voltage = run.battery_voltage(supply_voltage)
        horizontal = unmix(fr, from_pwm(run.inputs, motors))[:, 4:6]
        return cls(t=np.asarray(run.t, float), mode=mode, armed=armed, rcin=rcin, attitude_target=attitude,
                   z_target=z_target, horizontal=np.nan_to_num(horizontal), voltage=voltage, notes=tuple(notes))

    def index(self, t: float) -> int:
        """The row holding at time ``t`` (s from the run's first row)."""
        return int(min(max(np.searchsorted(self.t, self.t[0] + t + 1e-9, side="right") - 1, 0), self.t.size - 1))


class LoggedPilot:
    """The emulated ArduSub as a controller of :func:`udrobot_ctrl.dynamics.sim.simulate`: ``(t, x) -> thrusts``.

    Parameters
    ----------
    commands : LoggedCommands
    autopilot : ArduSubAutopilot
    fr : Frame
    motors : MotorParameters
        PWM range; directions +1 (the run's and the model's thrusters are in motor-command sense).
    p : PlantParameters
        For the thrust limits.
    dt : float
        Control step, s (one autopilot tick).
    """

    def __init__(self, commands: LoggedCommands, autopilot: ArduSubAutopilot, fr: Frame, motors: MotorParameters,
                 p: PlantParameters, dt: float):
        self.commands, self.autopilot, self.frame, self.motors, self.p, self.dt = commands, autopilot, fr, motors, p, dt
        self._vel_down = None
        self.pwm, self.modes, self.stand_ins = [], [], set()

    def _targets(self, k: int) -> Targets:
        c = self.commands
        att = c.attitude_target[k] if c.attitude_target is not None else (0.0, 0.0, math.nan)
        z = c.z_target[k] if c.z_target is not None and np.isfinite(c.z_target[k]) else None
        return Targets(roll=float(att[0]), pitch=float(att[1]), yaw=float(att[2]) if np.isfinite(att[2]) else None,
                       depth=None if z is None else float(z), forward=float(c.horizontal[k, 0]),
                       lateral=float(c.horizontal[k, 1]), shaped=True)  # logged targets: ArduSub shaped them

    def mixer_inputs(self, t: float, x) -> np.ndarray:
        """One autopilot tick at time ``t`` (s from the run's first row) on the plant state ``x`` (12): the mixer
        inputs (roll, pitch, yaw, throttle, forward, lateral; :data:`~udrobot_ctrl.autopilot.motors.MIXER_INPUTS`)."""
        c = self.commands
        k = c.index(t)
        state0 = VehicleState.from_plant(x)
        accel_down = 0.0 if self._vel_down is None else (state0.vel_down - self._vel_down) / self.dt
        self._vel_down = state0.vel_down
        state = VehicleState.from_plant(x, accel_down)
        mode = Mode(int(c.mode[k]))  # ArduSub's own numbers only (check_context_columns)
        if mode not in PILOT_MODES + TARGET_MODES:
            self.stand_ins.add(int(c.mode[k]))
            mode = Mode.GUIDED
        pilot = PilotInput(tuple(float(v) for v in c.rcin[k])) if c.rcin is not None else PilotInput.centred()
        targets = self._targets(k) if mode in TARGET_MODES else None
        inputs = self.autopilot.step(self.dt, state, pilot, mode, targets, MotorLimits(), bool(c.armed[k]))
        self.modes.append(int(mode))
        return inputs.as_array()

    def __call__(self, t: float, x) -> np.ndarray:
        command = mix(self.frame, self.mixer_inputs(t, x), self.motors)
        pwm = to_pwm(command, self.motors, integer=False)
        self.pwm.append(pwm)
        return np.clip(pwm_to_thrust(pwm, self.commands.voltage[self.commands.index(t)]), self.p.f_min, self.p.f_max)


@dataclass(frozen=True)
class ClosedLoopFlight:
    """A model flown under the emulated ArduSub (:func:`fly`).

    Attributes
    ----------
    t : (m,) ndarray
        Time from the run's first row, s (the control grid).
    x : (m, 12) ndarray
        Simulated state (x y z phi theta psi u v w p q r).
    pwm : (m, k) ndarray
        The emulated motor outputs (motor-command sense), us.
    mode : (m,) ndarray
        The mode flown at each step.
    notes : tuple of str
        What was assumed (defaulted parameters, modes flown on their logged targets).
    """

    t: np.ndarray
    x: np.ndarray
    pwm: np.ndarray
    mode: np.ndarray
    notes: tuple


def mode_notes(modes: np.ndarray, params: ArduSubParameters, autopilot: ArduSubAutopilot,
               has_depth_target: bool) -> list:
    """The result's notes on ALT_HOLD's surface / bottom handling and on SURFTRAK, for the modes flown.

    Parameters
    ----------
    modes : ndarray
        The mode flown at each step.
    params : ArduSubParameters
    autopilot : ArduSubAutopilot
        After the flight (its clamp counts).
    has_depth_target : bool
        The run has a logged depth target (``z_target``).
    """
    notes = []
    flown = set(int(m) for m in np.unique(modes))
    if int(Mode.ALT_HOLD) in flown:
        source = ("ArduSub's default, not in the log" if "SURFACE_DEPTH" in params.assumed else "from the log")
        notes.append(f"closed loop: ALT_HOLD's surface/bottom handling (ArduSub 4.1.1-4.5) with SURFACE_DEPTH "
                     f"{-100.0 * params.depth.surface_depth:g} cm ({source}); the depth target was clamped "
                     f"{autopilot.surface_clamps} tick(s) at the surface and {autopilot.bottom_clamps} on the bottom")
    if int(Mode.SURFTRAK) in flown:
        how = ("flown on the logged depth and attitude targets like GUIDED, with the pilot's forward/lateral"
               if has_depth_target else "no logged depth target: the depth target stays where it was")
        notes.append(f"closed loop: SURFTRAK is not emulated (its rangefinder depth-target law, ArduSub 4.5's "
                     f"ModeSurftrak::control_range, needs the seabed under the simulated vehicle); {how}")
    return notes


def fly(model, run: Run, loop_rate_hz: float | None = None, t_final: float | None = None) -> ClosedLoopFlight:
    """Fly ``model`` under the emulated ArduSub from ``run``'s logged pilot inputs, modes and targets.

    Parameters
    ----------
    model : str, Path or Vehicle
        A model with an ArduSub frame (``ardusub_frame``: the BlueROV2 models, or a model file that names it).
    run : Run
        A converted ArduSub run (``pwm_i`` and the context columns; docs/formats/runlog.md). Its sidecar's
        ``autopilot_params`` are the autopilot's parameters; ArduSub's defaults stand in for the missing ones.
    loop_rate_hz : float, optional
        Autopilot rate (Hz); the log's ``SCHED_LOOP_RATE`` or ArduSub's 400 Hz by default.
    t_final : float, optional
        Flight length, s (the run's duration by default).

    Returns
    -------
    ClosedLoopFlight
        Times (s), simulated states, emulated motor PWM (us), modes flown and the notes of what was assumed.

    Raises
    ------
    ValueError
        If the model names no ArduSub frame, the run's columns do not fit it, or the flight diverges.
    """
    vehicle = load_model(model)
    p = plant_parameters(vehicle)
    if not p.ardusub_frame:
        raise ValueError(f"model {vehicle.name!r} names no ArduSub frame ('ardusub_frame'): the closed-loop flight "
                         f"needs the vehicle's mixer (docs/formats/model.md)")
    fr = frame(p.ardusub_frame)
    log_params, estimated = run_log_params(run.metadata)
    params = ArduSubParameters.from_log_params(log_params, loop_rate_hz)
    k = fr.n_motors
    # the run's pwm_i are motor-command PWM (the converter mirrored the reversed motors): every direction +1
    motors = replace(MotorParameters.from_log_params(log_params, k), directions=(1,) * k)
    commands = LoggedCommands.from_run(run, fr, motors, p.supply_voltage)
    x0 = np.nan_to_num(run.state_matrix()[0])
    dt = 1.0 / params.loop_rate_hz
    pilot = LoggedPilot(commands, ArduSubAutopilot(params), fr, motors, p, dt)
    duration = float(t_final if t_final is not None else run.duration)
    if not duration > 0:
        raise ValueError(f"{run.path or 'run'}: nothing to fly (duration {duration:g} s)")
    try:
        res = simulate(vehicle, x0, duration, controller=pilot, dt=dt)
    except FloatingPointError as exc:
        raise ValueError(f"{run.path or 'run'} flown closed loop with {vehicle.name}: {exc}") from exc
    m = res.x.shape[0]
    pwm = np.array(pilot.pwm[:m - 1] + pilot.pwm[-1:])[:m]
    modes = np.array(pilot.modes[:m - 1] + pilot.modes[-1:])[:m]
    notes = [f"closed loop: gains {estimated}"] if estimated else []
    notes.extend(commands.notes)
    gains = [n for n in params.assumed]
    if gains:
        notes.append(f"closed loop: {len(gains)} ArduSub parameters not in the log, ArduSub's defaults used "
                     f"({', '.join(gains[:6])}{', ...' if len(gains) > 6 else ''})")
    if pilot.stand_ins:
        names = ", ".join(Mode(v).name if v in Mode._value2member_map_ else str(v) for v in sorted(pilot.stand_ins))
        notes.append(f"closed loop: mode(s) {names} are not emulated; flown like GUIDED on their logged attitude and "
                     f"depth targets and logged forward/lateral")
    notes.extend(mode_notes(modes, params, pilot.autopilot, commands.z_target is not None))
    notes.append(f"closed loop: ArduSub at {params.loop_rate_hz:g} Hz, frame {fr.name}, from the log's pilot inputs "
                 f"(MANUAL/STABILIZE/ALT_HOLD) and targets (GUIDED, SURFTRAK's stand-in); forward/lateral of GUIDED "
                 f"from the logged PWM (mixer inverse)")
    return ClosedLoopFlight(t=res.t, x=res.x, pwm=pwm, mode=modes, notes=tuple(notes))
