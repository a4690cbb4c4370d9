"""ArduSub's attitude loop closed around a replay: the diagnoser's closed-loop windows.

Why. A field log holds the motor outputs of ArduSub's 400 Hz stabilising loop at 2-10 Hz (tlog / dataflash). A
held sample of a fast stabilising loop, replayed open loop, destabilises any model: the real outputs were
corrections to the *measured* motion, and a replay that departs from it a little gets no correction at all (the
roll and pitch of an open-loop replay of a BlueROV2 dive run away within a window while the vehicle stayed level).

What. The logged command already holds the autopilot's reaction to the measured motion. When the simulated state
departs from the measured one, the real autopilot would have reacted to the *difference*, and for the attitude
loop of :mod:`udrobot_ctrl.autopilot.attitude` (angle P -> rate PID, ``AC_AttitudeControl_Sub``) that reaction is
linear in the deviation::

    e_att       = rotation vector of R_sim^T R_meas              (body axes, rad: how far the replay is off)
    rate target = ATC_ANG_*_P * e_att                             (rad/s)
    d_out       = rate PID (target = rate target, measurement = omega_sim - omega_meas)   per axis
    mixer input = logged mixer input + [d_out_roll, d_out_pitch, d_out_yaw, 0, 0, 0]

with the rate PIDs (:class:`udrobot_ctrl.autopilot.pid.ACPID`, the one emulation of ``AC_PID``: gains, target /
error / derivative filters) starting from rest at each window start: the logged output already holds the logged
integrators. The mixer input of the logged PWM comes from :func:`udrobot_ctrl.autopilot.motors.unmix`, and the
corrected one goes back through :func:`udrobot_ctrl.autopilot.motors.mix` (so the frame's saturation and
normalisation act on the total) and the T-200 curve. Exact for the PID and its filters; linearised for the sqrt
controller of the angle loop (linear below ``ACCEL_MAX / ANG_P^2``, 0.53 rad at ArduSub's defaults) and for the
integrator limit. The logged throttle, forward and lateral are not corrected by it: the depth and position loops
are slow next to the log rate, and their logged outputs are what a replay tests the heave, surge and sway dynamics
against (between samples they are refreshed, below).

Between two logged output samples the real autopilot kept reacting to the motion and the pilot, and a log often has
both far more often than the outputs (QGroundControl: ATTITUDE at 20 Hz and the pilot's MANUAL_CONTROL at ~24 Hz,
SERVO_OUTPUT_RAW at 2 Hz, in the same tlog). Holding a sample of a fast loop's output through a transient (a pitch
kick at a forward-stick reversal) drives the replay with a correction the real vehicle applied for a tenth of the
hold. So the held sample is **refreshed**: the emulated ArduSub (:class:`~udrobot_ctrl.autopilot.fly.LoggedPilot`,
the one emulation ``simulate --closed-loop`` flies) is stepped once per grid row on the *measured* states with the
log's modes, pilot inputs and targets, and its output's change since the sample was logged is added::

    mixer input = logged mixer input[k0] + (emulated[k] - emulated[a])      each input (throttle: see below)

(``k0`` the row where the held output was logged, ``a`` the row near it where the emulation agrees best with that
sample: the sample's instant is known to a row, and a stick step beside a sample must not be counted twice, once in
the sample and once in the change). ``a`` lies within :data:`ANCHOR_ROWS` of ``k0``, or within :data:`ANCHOR_ROWS`
of the row where the emulation shows the first change of the pilot's inputs logged after the sample and before the
next one (:func:`late_pilot_rows`): with the pilot only in a 2 Hz ``RC_CHANNELS`` (no ``MANUAL_CONTROL``) a sample
may hold a stick step whose pilot sample is logged after it. Rows before an anchor that lies after the sample keep
the sample. At the samples this is the log itself; between them it follows the autopilot's own reaction to what was
measured (the pilot's sticks pass straight through in MANUAL, STABILIZE and ALT_HOLD; GUIDED's forward and lateral
are held as logged), and whatever the emulation gets wrong slowly (an integrator, a trim) cancels in the difference.
The throttle is refreshed so where it is the pilot's stick (MANUAL, STABILIZE). In the other armed modes (ALT_HOLD
...) it is the depth loop's output on a depth and climb rate logged too coarsely to emulate it from (a tlog: depth
at 2 Hz, no vertical speed); it is smooth next to the log rate (it brakes a climb over about a second), so between
two samples logged in such modes it follows the straight line through them (:func:`throttle_interpolation`) instead
of lagging it by half a sample interval, held.
The closed loop above then acts on the replay's departure from the measured attitude.

Where the autopilot did not stabilise (``MANUAL`` mode, disarmed) the correction is zero: the logged command is
then the pilot's own, and the open-loop replay is the truth.
"""
from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np

from udrobot_ctrl.ardusub.modes import Mode
from udrobot_ctrl.ardusub.params import ArduSubParameters, AttitudeParameters, run_log_params
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot
from udrobot_ctrl.autopilot.fly import LoggedCommands, LoggedPilot
from udrobot_ctrl.autopilot.motors import Frame, MotorParameters, frame, from_pwm, mix, to_pwm, unmix
from udrobot_ctrl.autopilot.pid import ACPID
from udrobot_ctrl.autopilot.validate import nrmse
from udrobot_ctrl.dynamics.plant import PlantParameters, rotation_zyx
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.io.runlog import Run

#: modes in which ArduSub does not stabilise the attitude (the logged output is the pilot's)
UNSTABILISED_MODES = (int(Mode.MANUAL),)
#: logged commands updated at least this often (s) replay open loop: ArduSub's rate loop runs at 200-400 Hz and its
#: closed-loop attitude time constant is about 0.1 s (rate P 0.135, angle P 6 on a BlueROV2), so a command held over
#: more than 10 ms is a stale sample of a stabilising loop (assumed bound: 4 loop ticks at 400 Hz)
OPEN_LOOP_MAX_INTERVAL = 0.01


def rotation_vector(R) -> np.ndarray:
    """(..., 3) rotation vector (axis times angle, rad) of rotation matrices ``R`` (..., 3, 3)."""
    R = np.asarray(R, float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin = np.sin(angle)
    scale = np.where(sin > 1e-9, angle / np.where(sin > 1e-9, 2.0 * sin, 1.0), 0.5)  # small angles: axis / 2
    return axis * scale[..., None]


def attitude_error(eta_sim, eta_meas) -> np.ndarray:
    """(..., 3) body-axis rotation (rad) that takes the simulated attitude to the measured one.

    ``eta_*`` (..., 6) poses (x y z phi theta psi, ZYX Euler angles, rad); the error is the rotation vector of
    ``R_sim^T R_meas``, the angle error ArduSub's quaternion attitude controller acts on.
    """
    Rs = rotation_zyx(eta_sim[..., 3], eta_sim[..., 4], eta_sim[..., 5])
    Rm = rotation_zyx(eta_meas[..., 3], eta_meas[..., 4], eta_meas[..., 5])
    return rotation_vector(np.swapaxes(Rs, -1, -2) @ Rm)


@dataclass(frozen=True)
class ReplayFeedback:
    """The autopilot's attitude loop closed around the replay of one run (module docstring).

    Attributes
    ----------
    frame : Frame
        ArduSub frame of the vehicle.
    motors : MotorParameters
        PWM range and ``MOT_i_DIRECTION`` of the run's ``pwm_i`` columns (all +1 when the converter already
        mirrored the reversed motors to motor-command PWM).
    attitude : AttitudeParameters
        Angle P and rate PID gains (the log's, or ArduSub's defaults: see ``assumed``).
    pwm : (n, k) ndarray
        The logged PWM on the replay's grid, us.
    voltage : (n, 1) ndarray or float
        Battery voltage for the T-200 curve, V.
    f_min, f_max : (k,) ndarray
        Thrust limits, N (the same clipping as the replay's logged thrust).
    stabilised : (n,) bool ndarray
        Samples on which ArduSub stabilised the attitude (not MANUAL, not disarmed).
    axes : (3,) bool ndarray
        Roll, pitch, yaw loops closed (an axis the frame cannot actuate stays open).
    assumed : tuple of str
        Parameters taken from ArduSub's defaults and other assumptions, for the report.
    interval : float
        Median interval between the logged outputs, s (:func:`command_interval`; nan when not known).
    refresh : (n, 6) ndarray or None
        Mixer-input change of the emulated autopilot since each row's held output was logged (:func:`output_refresh`;
        None: the outputs are held as logged).
    thrust : (n, k) ndarray
        Derived: the run's thrust, N: the logged PWM with ``refresh`` added through the mixer, through the T-200 curve
        at ``voltage`` and clipped to the limits. The one thrust the diagnosis reads for the run (its equation
        error, its smoother and the replays: :attr:`udrobot_ctrl.gap.data.Prepared.f`); the loop's
        :meth:`delta_thrust` is relative to it.
    """

    frame: Frame
    motors: MotorParameters
    attitude: AttitudeParameters
    pwm: np.ndarray
    voltage: np.ndarray | float
    f_min: np.ndarray
    f_max: np.ndarray
    stabilised: np.ndarray
    axes: np.ndarray
    assumed: tuple = ()
    interval: float = float("nan")
    refresh: np.ndarray | None = None
    logged_inputs: np.ndarray = field(init=False, repr=False)
    logged_mixed: np.ndarray = field(init=False, repr=False)
    thrust: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        inputs = unmix(self.frame, from_pwm(self.pwm, self.motors))
        object.__setattr__(self, "logged_inputs", inputs)
        object.__setattr__(self, "logged_mixed", to_pwm(mix(self.frame, inputs, self.motors), self.motors,
                                                        integer=False))
        pwm = self.pwm if self.refresh is None else self._pwm(self.refresh, slice(None))
        object.__setattr__(self, "thrust", self._thrust(pwm, slice(None)))

    def _pwm(self, d_in, k):
        """PWM (us) at samples ``k`` with the mixer inputs ``d_in`` added to the logged ones: the logged PWM plus
        the change the mixer makes of it (the logged PWM itself where ``d_in`` is 0, whatever the mixer's round
        trip)."""
        return self.pwm[k] + to_pwm(mix(self.frame, self.logged_inputs[k] + d_in, self.motors), self.motors,
                                    integer=False) - self.logged_mixed[k]

    def _thrust(self, pwm, k):
        v = self.voltage if np.ndim(self.voltage) == 0 else np.asarray(self.voltage)[k]
        return np.clip(pwm_to_thrust(pwm, v), self.f_min, self.f_max)

    def start(self, rows: int) -> FeedbackState:
        """A fresh loop for ``rows`` windows replayed together (the PIDs at rest: the window start)."""
        return FeedbackState([ACPID(g) for g in self.attitude.rate_pids()], rows)

    def delta_thrust(self, state: FeedbackState, x_sim, x_meas, k, dt: float) -> np.ndarray:
        """(N, k) thrust (N) the closed attitude loop adds to the run's thrust :attr:`thrust` at samples ``k`` (N,):
        zero while the replay follows the measured state.

        Parameters
        ----------
        state : FeedbackState
            The loop's PIDs (advanced by ``dt``).
        x_sim, x_meas : (N, 12) ndarray
            Simulated and measured states (x y z phi theta psi u v w p q r).
        k : (N,) int ndarray
            Grid sample of each row (the logged command held on it).
        dt : float
            Loop step, s.
        """
        error = attitude_error(x_sim[:, :6], x_meas[:, :6])
        rate_target = np.asarray(self.attitude.angle_p, float) * error
        rate_dev = x_sim[:, 9:12] - x_meas[:, 9:12]
        active = self.stabilised[k]
        d_in = np.zeros((len(k), 6))
        for axis, pid in enumerate(state.pids):
            if self.axes[axis]:
                out = pid.update_all(rate_target[:, axis], rate_dev[:, axis], dt)
                d_in[:, axis] = np.where(active & np.isfinite(out), out, 0.0)
        if self.refresh is not None:
            d_in += self.refresh[k]
        return self._thrust(self._pwm(d_in, k), k) - self.thrust[k]


@dataclass
class FeedbackState:
    """The rate PIDs (roll, pitch, yaw) of a batch of replayed windows; their state holds one value per row."""

    pids: list
    rows: int


def changed_rows(run: Run) -> np.ndarray:
    """Rows where a run's logged commands change: where each logged output sample lands on the grid (a converted
    log holds each command on its grid, zero-order hold)."""
    u = np.asarray(run.inputs, float)
    return np.flatnonzero(np.any(np.diff(u, axis=0) != 0, axis=1)) + 1


def command_interval(run: Run) -> float:
    """Median interval (s) between changes of a run's logged commands (the log's own output rate, not the grid's).

    A converted log holds each logged command on its grid (zero-order hold), so the interval between the rows where
    any input changes is the rate at which the autopilot's outputs were logged; nan with fewer than 3 changes.
    """
    changed = changed_rows(run)
    return float(np.median(np.diff(run.t[changed]))) if changed.size >= 3 else float("nan")


#: the throttle (mixer input 3) is refreshed only in the modes where it is the pilot's stick (``Sub::stabilize_run``,
#: ``Sub::manual_run``: ``attitude_control.set_throttle_out(channel_throttle->norm_input(), ...)``), not the depth
#: loop's; every other mixer input is refreshed in every armed mode (module docstring)
THROTTLE = 3
PILOT_THROTTLE_MODES = (int(Mode.MANUAL), int(Mode.STABILIZE))
#: rows either side of a held sample's row where the emulation may be anchored to it (module docstring)
ANCHOR_ROWS = 1


def emulated_mixer_inputs(run: Run, params: ArduSubParameters, fr: Frame, motors: MotorParameters,
                          p: PlantParameters, loop_rate_hz: float | None = None,
                          start_integrators: bool = False) -> np.ndarray | None:
    """Mixer inputs (n, 6) of the emulated ArduSub on the run's measured states, at each grid row.

    The log's modes, armed state, pilot inputs (``rcin_i``) and targets drive
    :class:`~udrobot_ctrl.autopilot.fly.LoggedPilot` (the emulation ``simulate --closed-loop`` flies); the measured
    pose and rates are its state (unlogged components 0). None when the run has no ``mode``.

    Parameters
    ----------
    loop_rate_hz : float, optional
        None: one autopilot tick per grid row (the grid's step). Given: the autopilot ticks at this rate (Hz) between
        rows on the states interpolated linearly between them (angles unwrapped), as ArduSub's loop runs between
        two log samples; each row gets the output of the tick that lands on it.
    start_integrators : bool
        At the first armed row with the logged mixer inputs (``out_roll`` ... ``out_throttle``, dataflash RATE), start
        the roll and pitch rate integrators at ``out_roll/pitch`` (yaw's at 0) and the depth loop's acceleration
        integrator at ``hover - out_throttle``
        (:meth:`~udrobot_ctrl.autopilot.ardusub.ArduSubAutopilot.set_integrators`):
        a log that starts in flight has its trims (buoyancy, tether, static moments) in ArduSub's integrators,
        which the logged states alone do not pin down. *Estimated*: the P, D and FF parts of that row are taken
        as 0.
    """
    try:
        commands = LoggedCommands.from_run(run, fr, motors, p.supply_voltage)
    except ValueError:
        return None
    x = np.nan_to_num(run.state_matrix())
    t = np.asarray(run.t, float) - float(run.t[0])
    start = _integrator_start(run, params) if start_integrators else None
    if loop_rate_hz is None:
        dt = float(np.median(np.diff(run.t)))
        pilot = LoggedPilot(commands, ArduSubAutopilot(params), fr, motors, p, dt)
        return np.array([pilot.mixer_inputs(float(tk), xk) for tk, xk in zip(t, x)])
    x[:, 3:6] = np.unwrap(x[:, 3:6], axis=0)  # no spurious turn where a logged angle wraps
    dt = 1.0 / float(loop_rate_hz)
    pilot = LoggedPilot(commands, ArduSubAutopilot(params), fr, motors, p, dt)
    out = np.empty((run.n, 6))
    if start is not None and start[0] == 0:
        pilot.autopilot.set_integrators(*start[1])
    out[0] = pilot.mixer_inputs(0.0, x[0])
    for k in range(1, run.n):
        if start is not None and start[0] == k:
            pilot.autopilot.set_integrators(*start[1])
        ticks = max(1, int(round((t[k] - t[k - 1]) / dt)))
        for j in range(1, ticks + 1):
            f = j / ticks
            u = pilot.mixer_inputs(float(t[k - 1] + f * (t[k] - t[k - 1])), x[k - 1] + f * (x[k] - x[k - 1]))
        out[k] = u
    return out


def _integrator_start(run: Run, params: ArduSubParameters) -> tuple | None:
    """(row, (roll, pitch, yaw, accel_down)) for ``start_integrators`` of :func:`emulated_mixer_inputs`, or None."""
    cols = [run.extra.get(f"out_{a}") for a in ("roll", "pitch", "yaw", "throttle")]
    if any(c is None for c in cols):
        return None
    armed = run.extra.get("armed")
    on = np.ones(run.n, bool) if armed is None else np.nan_to_num(armed, nan=1.0) != 0
    ok = np.flatnonzero(on & np.all(np.isfinite(np.column_stack(cols)), axis=1))
    if ok.size == 0:
        return None
    k = int(ok[0])
    roll, pitch, _, thr = (float(c[k]) for c in cols)
    # yaw stays 0: ArduSub's yaw output is mostly P and FF (ATC_RAT_YAW_I is a fifth of roll/pitch's); started from
    # out_yaw, the sea dive's horizontal motors replay twice as badly (NRMSE 0.26-0.34 -> 0.52-0.72)
    return k, (roll, pitch, 0.0, params.depth.throttle_hover - thr)


#: fewer output-sample rows than this and :func:`motor_output_check` compares every row (outputs constant)
MIN_SAMPLE_ROWS = 20


@dataclass(frozen=True)
class MotorOutputCheck:
    """The emulated ArduSub's motor outputs on a run against the logged ones (:func:`motor_output_check`).

    Attributes
    ----------
    frame : str
        ArduSub frame of the mixer.
    rows : (m,) ndarray
        Rows compared: where a logged output sample lands (every row when the outputs never change).
    emulated, logged : (m, k) ndarray
        Motor PWM at those rows, us (motor-command sense).
    nrmse : tuple of float
        Per motor: RMSE / std of the logged channel (nan where the logged channel is constant and the RMSE not 0).
    rmse_us, logged_std_us : tuple of float
        Per motor: RMSE (us) and std of the logged channel (us).
    mode_rows : dict
        ArduSub mode name (or number) -> rows compared in it.
    armed_fraction : float
        Fraction of the compared rows armed.
    assumed : tuple of str
        ArduSub parameters the run lacked (ArduSub's defaults used, :meth:`ArduSubParameters.from_log_params`).
    """

    frame: str
    rows: np.ndarray = field(repr=False)
    emulated: np.ndarray = field(repr=False)
    logged: np.ndarray = field(repr=False)
    nrmse: tuple
    rmse_us: tuple
    logged_std_us: tuple
    mode_rows: dict
    armed_fraction: float
    assumed: tuple


def motor_output_check(run: Run, p: PlantParameters, params: ArduSubParameters | None = None) -> MotorOutputCheck:
    """Emulate ArduSub on a converted run (:func:`emulated_mixer_inputs` at the autopilot's loop rate, integrators
    started from the logged mixer inputs where the run has them: the logged modes, armed state, pilot inputs and
    targets on the logged states) and compare its mixed PWM with the logged motor outputs.

    Parameters
    ----------
    run : Run
        A converted ArduSub run (``pwm_i`` in motor-command sense and the context columns).
    p : PlantParameters
        The vehicle's plant (its ``ardusub_frame`` names the mixer).
    params : ArduSubParameters, optional
        The autopilot's parameters; the run's own (sidecar ``autopilot_params``, ArduSub's defaults for the rest) if
        None.

    Raises
    ------
    ValueError
        If the plant names no ArduSub frame or the run has no ``mode`` column.
    """
    if not p.ardusub_frame:
        raise ValueError("the plant names no ArduSub frame ('ardusub_frame'): no mixer to emulate")
    fr = frame(p.ardusub_frame)
    log_params, _ = run_log_params(run.metadata)
    if params is None:
        params = ArduSubParameters.from_log_params(log_params)
    k = fr.n_motors
    # the run's pwm_i are motor-command PWM (the converter mirrored the reversed motors): every direction +1
    motors = replace(MotorParameters.from_log_params(log_params, k), directions=(1,) * k)
    u = emulated_mixer_inputs(run, params, fr, motors, p, loop_rate_hz=params.loop_rate_hz, start_integrators=True)
    if u is None:
        raise ValueError(f"{run.path or 'run'}: no 'mode' column: nothing to emulate")
    rows = changed_rows(run)
    if rows.size < MIN_SAMPLE_ROWS:
        rows = np.arange(run.n)
    emulated = to_pwm(mix(fr, u[rows], motors), motors, integer=True)
    logged = np.asarray(run.inputs, float)[rows]
    mode = run.extra.get("mode")
    names: dict = {}
    for m in (np.nan_to_num(mode[rows], nan=-1).astype(int) if mode is not None else ()):
        name = Mode(m).name if m in Mode._value2member_map_ else str(m)
        names[name] = names.get(name, 0) + 1
    armed = run.extra.get("armed")
    on = np.ones(rows.size, bool) if armed is None else np.nan_to_num(armed[rows], nan=1.0) != 0
    return MotorOutputCheck(
        frame=fr.name, rows=rows, emulated=emulated, logged=logged,
        nrmse=tuple(nrmse(emulated[:, i], logged[:, i]) for i in range(k)),
        rmse_us=tuple(float(np.sqrt(np.nanmean((emulated[:, i] - logged[:, i]) ** 2))) for i in range(k)),
        logged_std_us=tuple(float(np.nanstd(logged[:, i])) for i in range(k)), mode_rows=names,
        armed_fraction=float(on.mean()) if on.size else 0.0, assumed=tuple(params.assumed))


#: refreshes kept in memory (:func:`output_refresh`): a diagnosis prepares the same run several times (fit and
#: holdout parts, the second reconstruction pass), and the emulation costs ~0.2 ms a row
REFRESHES_KEPT = 8
_REFRESHES: OrderedDict = OrderedDict()


def _refresh_key(run: Run, params: ArduSubParameters, fr: Frame, motors: MotorParameters) -> bytes:
    """Digest of everything the emulation on the measured states reads (the model does not enter it)."""
    h = hashlib.blake2b(digest_size=16)
    for name, a in (("t", run.t), ("inputs", run.inputs), ("states", run.state_matrix()),
                    *sorted(run.extra.items())):
        h.update(name.encode())
        h.update(np.ascontiguousarray(np.asarray(a, float)).tobytes())
    h.update(repr((params, fr.name, motors)).encode())
    return h.digest()


def output_refresh(run: Run, params: ArduSubParameters, fr: Frame, motors: MotorParameters,
                   p: PlantParameters) -> np.ndarray | None:
    """Change (n, 6) of the emulated autopilot's mixer inputs since each row's held output was logged (module
    docstring): roll, pitch, yaw, forward, lateral, and the throttle where it is the pilot's; zero while disarmed.
    None when the run has no ``mode`` or the change is zero throughout (outputs logged at the grid's rate). Computed
    once per run content (kept in memory, :data:`REFRESHES_KEPT`)."""
    key = _refresh_key(run, params, fr, motors)
    if key not in _REFRESHES:
        _REFRESHES[key] = _output_refresh(run, params, fr, motors, p)
        while len(_REFRESHES) > REFRESHES_KEPT:
            _REFRESHES.popitem(last=False)
    _REFRESHES.move_to_end(key)
    return _REFRESHES[key]


def sample_rows(run: Run) -> tuple:
    """(k0, k1): for each grid row, the row of the logged output sample it holds and the row of the next one (the
    run's last row after the last sample)."""
    n = run.n
    changed = changed_rows(run)
    k0 = np.zeros(n, int)
    k0[changed] = changed
    k0 = np.maximum.accumulate(k0)
    k1 = np.full(n, n - 1)
    after = np.searchsorted(changed, np.arange(n), side="right")
    has_next = after < changed.size
    k1[has_next] = changed[after[has_next]]
    return k0, k1


def late_pilot_rows(run: Run, k0: np.ndarray, k1: np.ndarray) -> np.ndarray:
    """Rows (n,) where the emulation first shows a change of the pilot's inputs logged after each row's held output
    sample and before the next one, or -1.

    The sample holds the sticks up to its own instant, and the emulation shows a pilot sample one tick after its
    row: with the pilot's inputs logged as sparsely as the outputs (``RC_CHANNELS`` at 2 Hz) a sample may hold a
    stick step whose pilot sample is logged after it (the first change from :data:`ANCHOR_ROWS` before the sample
    on, when the emulation shows it more than :data:`ANCHOR_ROWS` after the sample).
    """
    late = np.full(run.n, -1)
    rc = [run.extra.get(f"rcin_{i}") for i in range(1, 9)]
    if any(c is None for c in rc):
        return late
    sticks = np.nan_to_num(np.column_stack(rc), nan=-1.0)
    moves = np.flatnonzero(np.any(np.diff(sticks, axis=0) != 0, axis=1)) + 1  # rows where the pilot's inputs change
    if moves.size == 0:
        return late
    nxt = np.searchsorted(moves, k0 - ANCHOR_ROWS)
    ok = nxt < moves.size
    c = np.where(ok, moves[np.minimum(nxt, moves.size - 1)], -1)
    shown = c + 1  # the emulation's one tick
    use = ok & (c < k1) & (shown > k0 + ANCHOR_ROWS)
    late[use] = shown[use]
    return late


def anchors(emulated: np.ndarray, logged: np.ndarray, k0: np.ndarray, late: np.ndarray) -> np.ndarray:
    """Anchor rows (n, 6): per mixer input, the row within :data:`ANCHOR_ROWS` of each row's held sample ``k0``, or
    of the row ``late`` where the emulation shows a pilot sample logged after it (-1: none), where ``emulated``
    agrees best with the ``logged`` sample (ties: the earliest)."""
    n = emulated.shape[0]
    near = np.arange(-ANCHOR_ROWS, ANCHOR_ROWS + 1)
    samples, which = np.unique(k0, return_inverse=True)
    best = np.empty((samples.size, emulated.shape[1]), int)
    for i, k in enumerate(samples):
        rows = k + near if late[k] < 0 else np.concatenate([k + near, late[k] + near])
        rows = rows[(rows >= 0) & (rows < n)]
        best[i] = rows[np.argmin(np.abs(emulated[rows] - logged[k]), axis=0)]
    return best[which]


def throttle_interpolation(run: Run, logged: np.ndarray, k0: np.ndarray, k1: np.ndarray,
                           loop: np.ndarray) -> np.ndarray:
    """Change (n,) of the throttle mixer input from its held sample to the straight line between the samples either
    side (module docstring), on rows where both samples were logged in a mode whose throttle is the depth loop's
    (``loop``: bool per row), else 0."""
    span = run.t[k1] - run.t[k0]
    frac = np.where(span > 0, (run.t - run.t[k0]) / np.where(span > 0, span, 1.0), 0.0)
    step = logged[k1, THROTTLE] - logged[k0, THROTTLE]
    return np.where(loop[k0] & loop[k1] & (k1 > k0), frac * step, 0.0)


def _output_refresh(run: Run, params: ArduSubParameters, fr: Frame, motors: MotorParameters,
                    p: PlantParameters) -> np.ndarray | None:
    emulated = emulated_mixer_inputs(run, params, fr, motors, p)
    if emulated is None:
        return None
    n = run.n
    k0, k1 = sample_rows(run)  # the row of the output sample each row holds, and of the next
    # the sample's instant is known to a grid row (stamps, the converter's hold, the emulation's one-tick lag) and a
    # stick step may reach the log's pilot inputs after the output sample that holds it: the emulation is anchored,
    # per input, at the row near k0 (or near a late pilot sample) where it agrees best with the logged sample, so that
    # a stick step next to a sample is not counted twice (once in the sample, once in the change); rows before an
    # anchor that lies after the sample keep the sample (the emulation has not reached it yet)
    logged = unmix(fr, from_pwm(run.inputs, motors))
    anchor = anchors(emulated, logged, k0, late_pilot_rows(run, k0, k1))
    out = emulated - emulated[anchor, np.arange(emulated.shape[1])]
    out[np.arange(n)[:, None] < anchor] = 0.0
    mode = run.extra.get("mode")
    known = np.nan_to_num(mode, nan=-1.0) if mode is not None else np.full(n, -1.0)
    pilot = np.isin(known, PILOT_THROTTLE_MODES)
    out[~(pilot & pilot[k0]), THROTTLE] = 0.0  # only where the throttle is the pilot's at both rows
    armed = run.extra.get("armed")
    on = np.nan_to_num(armed, nan=1.0) != 0 if armed is not None else np.ones(n, bool)
    loop = on & (known >= 0) & ~pilot  # the throttle of the depth loop: interpolated between its samples
    out[:, THROTTLE] += throttle_interpolation(run, logged, k0, k1, loop)
    out[~on] = 0.0
    out = np.nan_to_num(out)
    out.setflags(write=False)  # shared by every replay of the run (output_refresh keeps it)
    return out if np.any(out) else None


@dataclass(frozen=True)
class FeedbackChoice:
    """Whether a run is replayed with the autopilot's attitude loop closed, and why.

    Attributes
    ----------
    feedback : ReplayFeedback or None
        The loop (None: open-loop replay).
    note : str
        One line for the run's notes: the choice, the evidence and what was assumed.
    """

    feedback: ReplayFeedback | None
    note: str


def replay_feedback(run: Run, p: PlantParameters, label: str = "run") -> FeedbackChoice:
    """The closed-loop replay of ``run`` (on its own grid) with model ``p``, when the run needs one.

    Closed loop when: the run logs ArduSub PWM (``pwm_i``) of a vehicle whose model names its ArduSub frame
    (``ardusub_frame``), the logged commands change less often than :data:`OPEN_LOOP_MAX_INTERVAL`, and ArduSub
    stabilised the attitude on some of it (``mode`` not MANUAL, ``armed`` not 0; a run without a ``mode`` column is
    taken as stabilised, and the note says so). Gains: the sidecar's ``autopilot_params`` (the log's), ArduSub's
    defaults for the rest (named in the note). The run's ``pwm_i`` are motor-command PWM (the converter mirrored the
    reversed motors), so every direction is +1 here.
    """
    if run.input_kind != "pwm" or not p.ardusub_frame:
        return FeedbackChoice(None, "")
    try:
        fr = frame(p.ardusub_frame)
    except ValueError as exc:
        return FeedbackChoice(None, f"replay: open loop ({exc})")
    k = run.inputs.shape[1]
    if fr.n_motors != k:
        return FeedbackChoice(None, f"replay: open loop (frame {fr.name} has {fr.n_motors} motors, {label} has {k} "
                                    f"pwm columns)")
    interval = command_interval(run)
    if not interval > OPEN_LOOP_MAX_INTERVAL:
        return FeedbackChoice(None, f"replay: open loop ({label}: logged commands every {interval * 1e3:.0f} ms, "
                                    f"fast enough to replay ArduSub's outputs as logged)")
    mode = run.extra.get("mode")
    armed = run.extra.get("armed")
    stabilised = np.ones(run.n, bool)
    assumed = []
    if mode is None or not np.isfinite(mode).any():
        assumed.append("no mode logged: ArduSub taken as stabilising throughout")
    else:
        stabilised &= ~np.isin(np.nan_to_num(mode, nan=-1.0), UNSTABILISED_MODES)
    if armed is not None:
        stabilised &= ~(np.nan_to_num(armed, nan=1.0) == 0)
    if not stabilised.any():
        return FeedbackChoice(None, f"replay: open loop ({label}: ArduSub did not stabilise the attitude (MANUAL or "
                                    f"disarmed throughout): the logged commands are the pilot's)")
    log_params, estimated = run_log_params(run.metadata)
    params = ArduSubParameters.from_log_params(log_params)
    if estimated:
        assumed.append(f"gains {estimated}")
    gains = [n for n in params.assumed if n.startswith("ATC_")]
    if gains:
        listed = ", ".join(gains[:4]) + (", ..." if len(gains) > 4 else "")
        assumed.append(f"ArduSub's defaults for {len(gains)} attitude parameters ({listed}): not in the log")
    voltage = run.battery_voltage(p.supply_voltage)[:, None]
    axes = np.array([np.any(fr.factors[:, a]) for a in range(3)])
    motors = replace(MotorParameters.from_log_params(log_params, k), directions=(1,) * k)
    refresh = output_refresh(run, params, fr, motors, p)
    fb = ReplayFeedback(frame=fr, motors=motors,
                        attitude=params.attitude, pwm=np.asarray(run.inputs, float), voltage=voltage,
                        f_min=np.asarray(p.f_min, float), f_max=np.asarray(p.f_max, float), stabilised=stabilised,
                        axes=axes, assumed=tuple(assumed), interval=interval, refresh=refresh)
    closed = ", ".join(n for n, a in zip(("roll", "pitch", "yaw"), axes) if a)
    held = ("roll, pitch, yaw, forward and lateral refreshed between output samples by the emulated autopilot run on "
            "the measured states and the pilot's inputs, the throttle too where it is the pilot's (MANUAL, STABILIZE), "
            "elsewhere the straight line between its samples"
            if refresh is not None
            else "throttle, forward and lateral as logged")
    note = (f"replay: closed loop in {closed} ({label}: ArduSub's outputs logged every {interval * 1e3:.0f} ms, a "
            f"stale sample of its {params.loop_rate_hz:.0f} Hz attitude loop; the emulated loop (frame {fr.name}, "
            f"angle P {', '.join(f'{g:g}' for g in params.attitude.angle_p)}) acts on the replay's departure from "
            f"the measured attitude, on {100 * stabilised.mean():.0f}% of the samples; {held})"
            + (f"; assumed: {'; '.join(assumed)}" if assumed else ""))
    return FeedbackChoice(fb, note)
