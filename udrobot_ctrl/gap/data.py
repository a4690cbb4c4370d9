"""Runs prepared for the gap diagnosis: uniform time base, smoothed velocities and accelerations, actuators.

Everything the diagnoser computes starts from a :class:`Prepared` run:

* the run is resampled to a uniform grid at its own median sample interval (runs may differ in rate);
* the body velocities ``nu`` are smoothed with a Savitzky-Golay filter on each contiguous stretch of data
  (DVL gaps are never bridged) and differentiated in the same pass (``nu_dot``); body rates that are not
  logged are recovered from the Euler-angle rates when the attitude is logged;
* the commanded inputs become *actuator commands* ``f`` (n, k) with an actuator matrix ``B`` (6 x k) so
  that the nominal wrench is ``B f``: per-thruster thrusts (``thrust_i``; ``pwm_i`` converted with a T200
  curve) with the model's thruster matrix, or six virtual actuators (``tau_*``, ``B = I``); ArduSub outputs
  logged more slowly than its attitude loop (a tlog's 2 Hz ``SERVO_OUTPUT_RAW``) are refreshed between their samples
  by the emulated autopilot on the measured states (:mod:`udrobot_ctrl.autopilot.feedback`) before the T200 curve,
  and that one thrust is what the equation error, the smoother and the replays read;
* the distances to the seabed and to the walls come from the sidecar metadata (``seabed_depth``,
  ``walls``) and the logged position, or from the logged ``altitude``;
* a run that logs no body velocity in some translational DOF (a stock ROV: no DVL) is passed through the
  model-based smoother (:mod:`udrobot_ctrl.gap.smoother`): every velocity that is not logged is *reconstructed*
  from what is (depth, attitude, rates, accelerometer, thrusts, position if any) and differentiated like a
  logged one, and ``x, y`` are dead-reckoned when not logged. A DOF is *observed* when a sensor measures its
  velocity or the integral of it (X: ``u`` or ``x``; Y: ``v`` or ``y``; Z: ``w`` or ``z``; K/M/N: the rate or the
  Euler angle); only observed DOFs are scored (``dof_ok``). Runs that log ``u v w`` take the path above unchanged.
* a column the run's sidecar marks ``estimated-unaided`` (dead reckoning: an EKF velocity or position with no sensor
  of it, e.g. XKF1 with its GPS source and no fix under water; docs/formats/runlog.md, ``channels``) is not logged
  from here on: it is left out of ``meas`` (so the smoother, the replays' scores, the equation error, the
  identifiability and the plots never read it) and kept in ``Prepared.unaided`` to say why.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import savgol_filter

from udrobot_ctrl.autopilot.feedback import ReplayFeedback, replay_feedback
from udrobot_ctrl.constants import DOF_NAMES
from udrobot_ctrl.constants import POSE_NAMES as POSE
from udrobot_ctrl.constants import VELOCITY_NAMES as VEL
from udrobot_ctrl.dynamics.domain import true_runs
from udrobot_ctrl.dynamics.plant import PlantParameters, restoring_forces
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.gap.smoother import SmoothedRun, SmootherError, smooth_run
from udrobot_ctrl.io.runlog import Run, check_time_gaps, resample, unaided_channels

#: a DOF's velocity is observed when any of these channels is logged (the velocity or its integral)
OBSERVING = {0: ("u", "x"), 1: ("v", "y"), 2: ("w", "z"), 3: ("p", "phi"), 4: ("q", "theta"), 5: ("r", "psi")}
MAX_GRID_RATIO = 100.0  # a uniform grid over 100 x the rows means a time column error, not a resampling need

@dataclass
class Prepared:
    """One run ready for the diagnosis (all arrays on the uniform grid ``t``, n samples).

    Attributes
    ----------
    name : str
        Run label (file name).
    t : (n,) ndarray
        Uniform time, s.
    dt : float
        Sample interval, s.
    meas : dict of str -> (n,) ndarray
        Measured channels after resampling (nan where missing).
    eta : (n, 6) ndarray
        Pose with nan filled (x, y: 0; attitude: interpolated, 0 when never logged), m and rad.
    nu, nu_dot : (n, 6) ndarray
        Smoothed body velocities (m/s, rad/s) and their derivatives; nan where not available.
    f : (n, k) ndarray
        Actuator commands (N for thrusters; N, N m for virtual wrench actuators), clipped to limits. On a run
        replayed closed loop (``feedback``), the logged outputs refreshed between their samples by the emulated
        autopilot (:attr:`udrobot_ctrl.autopilot.feedback.ReplayFeedback.thrust`): the equation error, the smoother
        and the replay read the same thrust.
    B : (6, k) ndarray
        Actuator matrix: nominal wrench = B f.
    inflow : (6, k) ndarray
        Axial inflow speed of actuator j is ``inflow[:, j] . nu`` (m/s); zero columns for torques.
    f_ref : (k,) ndarray
        Reference magnitude of each actuator (max thrust, or the 99th percentile of |tau_i|).
    surfaces : list of (distance (n,), normal_ned (3,), label)
        Seabed / walls with the distance (m) from the body origin and the unit normal into the water.
    dof_ok : (6,) bool
        DOFs whose velocity is observed and available (their equation of motion can be scored).
    notes : list of str
        What was assumed while preparing.
    window_s : float
        Savitzky-Golay window, s.
    observed : (6,) bool
        DOFs whose velocity a sensor observes (see :data:`OBSERVING`).
    reconstructed : (6,) bool
        DOFs whose ``nu`` (and ``nu_dot``) come from the smoother, not from a logged velocity.
    smoothed : SmoothedRun or None
        The smoother's result (with posterior std) when it ran.
    feedback : ReplayFeedback or None
        The vehicle's autopilot attitude loop, closed around the replay of a run whose logged outputs are too slow
        to replay open loop (:func:`udrobot_ctrl.autopilot.feedback.replay_feedback`); None: open-loop replay.
    unaided : dict of str -> ChannelSource
        Columns the run logs but its sidecar marks ``estimated-unaided`` (:func:`observable`): not in ``meas``.
    """

    name: str
    t: np.ndarray
    dt: float
    meas: dict
    eta: np.ndarray
    nu: np.ndarray
    nu_dot: np.ndarray
    f: np.ndarray
    B: np.ndarray
    inflow: np.ndarray
    f_ref: np.ndarray
    input_kind: str
    surfaces: list = field(default_factory=list)
    dof_ok: np.ndarray = field(default_factory=lambda: np.zeros(6, bool))
    notes: list = field(default_factory=list)
    window_s: float = 0.8
    observed: np.ndarray = field(default_factory=lambda: np.zeros(6, bool))
    reconstructed: np.ndarray = field(default_factory=lambda: np.zeros(6, bool))
    smoothed: SmoothedRun | None = None
    feedback: ReplayFeedback | None = None
    unaided: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.t.size)

    def raw_state(self) -> np.ndarray:
        """(n, 12) state for the equation error: filled pose, logged velocities (rates derived from the attitude
        where not logged, reconstructed by the smoother where it ran, zero for other unmeasured DOFs), nan inside
        velocity gaps."""
        nu = np.full((self.n, 6), 0.0)
        for i, c in enumerate(VEL):
            if c in self.meas and np.isfinite(self.meas[c]).any():
                nu[:, i] = self.meas[c]
            elif self.dof_ok[i] or self.reconstructed[i]:
                nu[:, i] = self.nu[:, i]
        return np.concatenate([self.eta, nu], axis=1)

    def state(self) -> np.ndarray:
        """(n, 12) state [eta, nu] with nu smoothed (nan where velocities are missing)."""
        return np.concatenate([self.eta, self.nu], axis=1)


def smooth_derivative(y, dt, window_s=0.8, order=2):
    """Savitzky-Golay smoothing and first derivative of y on each finite stretch (nan elsewhere).

    Parameters
    ----------
    y : (n,) ndarray
    dt : float
        Sample interval, s.
    window_s : float
        Filter window, s (at least 5 samples).

    Returns
    -------
    ys, yd : (n,) ndarray
        Smoothed values and derivative (units of y per second).
    """
    ys = np.full_like(y, np.nan, dtype=float)
    yd = np.full_like(y, np.nan, dtype=float)
    win = max(5, int(round(window_s / dt)) | 1)
    for a, b in true_runs(np.isfinite(y)):
        m = b - a
        if m < 5:
            continue
        w = min(win, m if m % 2 else m - 1)
        o = min(order, w - 1)
        ys[a:b] = savgol_filter(y[a:b], w, o, mode="interp")
        yd[a:b] = savgol_filter(y[a:b], w, o, deriv=1, delta=dt, mode="interp")
    return ys, yd


def _fill(y, default=0.0):
    """Linear interpolation over nan gaps, constant extrapolation; default when never measured."""
    ok = np.isfinite(y)
    if not ok.any():
        return np.full_like(y, default, dtype=float)
    idx = np.arange(y.size)
    return np.interp(idx, idx[ok], y[ok])


#: a velocity first logged later than this after a replay's start is not its start value (the rest value 0 is): one
#: Savitzky-Golay window of :func:`prepare` (0.8 s), the span the diagnoser's smoothed velocity at a sample draws on
START_VELOCITY_WITHIN_S = 0.8


@dataclass(frozen=True)
class StartFill:
    """How a replay's start state got a channel its first row lacks: ``how`` is ``first_sample`` (its first finite
    sample, logged at ``t_first`` s after the start) or ``rest`` (0: never logged, or a velocity first logged
    later than :data:`START_VELOCITY_WITHIN_S`; ``t_first`` None when never logged)."""

    channel: str
    how: str
    t_first: float | None = None


def start_state(t, X, names=POSE + VEL) -> tuple:
    """The state (12,) a replay of a run starts from, and a :class:`StartFill` per channel its first row lacks.

    ``simulate``'s start, on the diagnoser's rule: a pose channel takes its first finite sample, as :func:`_fill`
    (called here) extrapolates it back in :func:`prepare` (so a diagnoser's window at a run's first sample starts
    from that same value), 0 when never logged (level attitude, the origin, as :func:`prepare` assumes); a velocity
    takes its first finite sample when it comes within :data:`START_VELOCITY_WITHIN_S`, else 0 (at rest, as a
    window starts an unobserved DOF; the diagnoser skips a window whose observed velocity is missing at its start,
    which a whole-run replay, with one start, cannot).

    Parameters
    ----------
    t : (n,) array_like
        Time, s.
    X : (n, 12) array_like
        State rows [x y z phi theta psi u v w p q r] (m, rad, m/s, rad/s), nan where not logged.
    """
    t, X = np.asarray(t, float), np.asarray(X, float)
    x0, fills = np.array(X[0], float), []
    for i, c in enumerate(names):
        if np.isfinite(x0[i]):
            continue
        ok = np.flatnonzero(np.isfinite(X[:, i]))
        lead = float(t[ok[0]] - t[0]) if ok.size else None
        if ok.size and (i < 6 or lead <= START_VELOCITY_WITHIN_S):
            x0[i] = _fill(X[:, i])[0]
            fills.append(StartFill(c, "first_sample", lead))
        else:
            x0[i] = 0.0
            fills.append(StartFill(c, "rest", lead))
    return x0, fills


def actuators(run: Run, p: PlantParameters, f_raw=None):
    """Actuator commands f (n, k), matrix B (6, k), inflow matrix (6, k) and reference magnitudes (k,).

    Raises
    ------
    ValueError
        If per-thruster inputs do not match the model's thruster count.
    """
    f = np.asarray(run.inputs if f_raw is None else f_raw, float)
    if run.input_kind in ("thrust", "pwm"):
        k = p.T.shape[1]
        if f.shape[1] != k:
            raise ValueError(f"{run.path or 'run'}: {f.shape[1]} {run.input_kind}_i columns but the model has {k} "
                             f"thrusters (columns must follow the model's thruster order)")
        if run.input_kind == "pwm":  # the fitted T-200 curve at the logged battery voltage (the model's if absent)
            v = run.battery_voltage(p.supply_voltage)[:, None]
            if v.shape[0] != f.shape[0]:
                raise ValueError(f"{run.path or 'run'}: {v.shape[0]} voltage samples for {f.shape[0]} rows of "
                                 f"pwm_i (pass the run on the commands' grid)")
            f = pwm_to_thrust(f, v)
        f = np.clip(f, p.f_min, p.f_max)
        return f, p.T.copy(), p.T.copy(), np.maximum(p.f_max, -p.f_min)
    inflow = np.eye(6)
    inflow[3:, 3:] = 0.0
    ref = np.nanpercentile(np.abs(f), 99, axis=0) if np.isfinite(f).any() else np.ones(6)
    ref = np.where(np.isfinite(ref) & (ref > 1e-9), ref, 1.0)
    return f, np.eye(6), inflow, ref


ALTITUDE_VALID_MIN = 0.5  # fraction of samples with a valid altitude for it to place the seabed


def _surfaces(run: Run, meas, n, label="run", notes=None):
    """(distance (n,) m, unit normal into the water (NED), label) of each surface the run knows the distance to:
    the seabed from the logged ``altitude`` (valid in more than ``ALTITUDE_VALID_MIN`` of the samples) or from the
    sidecar's ``seabed_depth`` and the depth, and the sidecar's walls from the logged position. A logged altitude
    that is mostly invalid (a DVL or echo sounder out of range) is reported in ``notes``."""
    out = []
    meta = run.metadata or {}
    z = meas.get("z")
    altitude = meas.get("altitude")
    valid = np.isfinite(altitude) if altitude is not None else np.zeros(n, bool)
    n_alt = int(valid.sum())
    if altitude is not None and n_alt <= ALTITUDE_VALID_MIN * n and notes is not None:
        rng = f", {np.min(altitude[valid]):.3g}-{np.max(altitude[valid]):.3g} m where valid" if n_alt else ""
        notes.append(f"{label}: altitude logged but valid in only {n_alt} of {n} samples ({100 * n_alt / n:.0f}%"
                     f"{rng}; more than {100 * ALTITUDE_VALID_MIN:g}% needed), so it does not place the seabed"
                     + ("; the sidecar's seabed_depth is used instead" if meta.get("seabed_depth") is not None else
                        "; wall_effect cannot be tested near the seabed (give seabed_depth in the sidecar, or fly "
                        "within the altimeter's range)"))
    if n_alt > ALTITUDE_VALID_MIN * n:
        out.append((_fill(altitude, np.nan), np.array([0.0, 0.0, -1.0]), "seabed (altitude)"))
    elif meta.get("seabed_depth") is not None and z is not None and np.isfinite(z).any():
        out.append((float(meta["seabed_depth"]) - _fill(z), np.array([0.0, 0.0, -1.0]), "seabed"))
    x, y = meas.get("x"), meas.get("y")
    if x is not None and y is not None and np.isfinite(x).any() and np.isfinite(y).any():
        pos = np.column_stack([_fill(x), _fill(y), _fill(z) if z is not None else np.zeros(n)])
        for i, wall in enumerate(meta.get("walls", []) or []):
            nrm = np.asarray(wall["normal"], float)
            nrm = nrm / np.linalg.norm(nrm)
            d = (pos - np.asarray(wall["point"], float)) @ nrm
            out.append((d, nrm, f"wall {i}"))
    return out


def prepare(run: Run, p: PlantParameters, name=None, window_s=0.8, dt=None, known_wrench=None,
            known_as: str = "") -> Prepared:
    """Resample, smooth and differentiate one run (see the module docstring).

    Parameters
    ----------
    run : Run
    p : PlantParameters
        Nominal plant (thruster matrix and limits).
    window_s : float
        Savitzky-Golay window for velocities, s.
    dt : float, optional
        Grid interval, s; the run's median interval by default.
    known_wrench : (n, 6) ndarray, optional
        Generalised force (N, N m) on the run's grid that the smoother adds to the logged actuator wrench: what
        effects already attributed to the run contribute (:func:`udrobot_ctrl.gap.shrink.effect_wrench`), so that
        the unlogged velocities are reconstructed with the corrected plant, not the nominal one. Ignored when
        nothing is reconstructed.
    known_as : str
        What ``known_wrench`` is, for the run's note (e.g. the effects' names).
    """
    label = name or (run.path.split("/")[-1] if run.path else "run")
    notes = []
    if len(run.segment_bounds()) > 1:  # no resampling, smoothing or reconstruction across a cut
        raise ValueError(f"{label}: {len(run.segment_bounds())} segments; prepare each on its own "
                         f"(udrobot_ctrl.gap.shrink.segment_runs)")
    if run.n < 20:
        raise ValueError(f"{label}: only {run.n} samples; a run needs at least 20")
    check_time_gaps(run.t, label)
    dt = float(dt or run.dt_median)
    n_grid = int(np.floor((run.t[-1] - run.t[0]) / dt + 1e-9)) + 1
    if n_grid > MAX_GRID_RATIO * run.n + 1000:
        raise ValueError(f"{label}: resampling {run.n} samples spanning {run.t[-1] - run.t[0]:.6g} s at dt {dt:.6g} s "
                         f"would need {n_grid:.3g} samples (> {MAX_GRID_RATIO:g} x the rows); check the time column")
    t = run.t[0] + dt * np.arange(int(np.floor((run.t[-1] - run.t[0]) / dt + 1e-9)) + 1)
    r = resample(run, t) if (t.size != run.n or np.max(np.abs(t - run.t)) > 1e-9) else run
    meas, unaided, note = observable(r, label)
    if note:
        notes.append(note)
    n = t.size
    eta = np.zeros((n, 6))
    for i, c in enumerate(POSE):
        if c in meas and np.isfinite(meas[c]).any():
            y = meas[c].copy()
            if c in ("phi", "theta", "psi"):
                ok = np.isfinite(y)
                y[ok] = np.unwrap(y[ok])
            eta[:, i] = _fill(y)
        elif c in ("phi", "theta"):
            notes.append(f"{label}: {c} not logged; assumed 0 in the restoring forces")
    nu = np.full((n, 6), np.nan)
    nu_dot = np.full((n, 6), np.nan)
    for i, c in enumerate(VEL):
        if c in meas and np.isfinite(meas[c]).sum() >= 5:
            nu[:, i], nu_dot[:, i] = smooth_derivative(meas[c], dt, window_s)
    missing_rates = [i for i in (3, 4, 5) if not np.isfinite(nu[:, i]).any()]
    if missing_rates and all(c in meas and np.isfinite(meas[c]).any() for c in ("phi", "theta", "psi")):
        ang = np.column_stack([smooth_derivative(eta[:, 3 + j], dt, window_s)[1] for j in range(3)])
        phi, th = eta[:, 3], eta[:, 4]
        sf, cf, st, ct = np.sin(phi), np.cos(phi), np.sin(th), np.cos(th)
        rates = np.column_stack([ang[:, 0] - st * ang[:, 2], cf * ang[:, 1] + sf * ct * ang[:, 2],
                                 -sf * ang[:, 1] + cf * ct * ang[:, 2]])
        for i in missing_rates:
            nu[:, i], nu_dot[:, i] = smooth_derivative(rates[:, i - 3], dt, window_s)
        notes.append(f"{label}: body rates {', '.join(VEL[i] for i in missing_rates)} not logged; derived from "
                     f"the Euler-angle rates")
    f_raw = np.asarray(r.inputs, float)
    if np.isnan(f_raw).any():
        f_raw = np.column_stack([_fill(c) for c in f_raw.T])
    f, B, inflow, ref = actuators(r, p, f_raw)  # r: the grid of f_raw and of its voltage
    loop = replay_feedback(replace(r, inputs=f_raw), p, label)
    if loop.note:
        notes.append(loop.note)
    if loop.feedback is not None:  # the logged outputs refreshed between their samples: one thrust for every step
        f = loop.feedback.thrust
    observed = np.array([any(_logged(meas, c) for c in OBSERVING[i]) for i in range(6)])
    reconstructed = np.zeros(6, bool)
    smoothed = None
    if not all(_logged(meas, c) for c in ("u", "v", "w")):
        try:
            tau = f @ B.T
            if known_wrench is not None:
                known_wrench = np.asarray(known_wrench, float)
                if known_wrench.shape != tau.shape:
                    raise ValueError(f"{label}: known_wrench has shape {known_wrench.shape}, expected {tau.shape} "
                                     f"(one generalised force per sample of the run's grid)")
                tau = tau + np.nan_to_num(known_wrench)
            smoothed = smooth_run(t, meas, tau, p, label=label)
        except SmootherError as exc:
            notes.append(f"{label}: {exc}; the unlogged velocities are not reconstructed (only DOFs whose velocity "
                         f"is logged or derived from the attitude are scored)")
        if smoothed is not None:
            reconstructed = np.array([not _logged(meas, c) for c in VEL])
            for i in np.flatnonzero(reconstructed):
                nu[:, i], nu_dot[:, i] = smooth_derivative(smoothed.nu[:, i], dt, window_s)
            for i, c in enumerate(("x", "y")):
                if not _logged(meas, c):
                    eta[:, i] = smoothed.eta[:, i]
            notes.append(f"{label}: {', '.join(VEL[i] for i in np.flatnonzero(reconstructed))} not logged; "
                         f"reconstructed by the model-based smoother from {', '.join(smoothed.channels)} and the "
                         f"thrusts" + (f" plus the force of {known_as}" if known_wrench is not None else "")
                         + ("; x, y dead-reckoned" if not (_logged(meas, "x") or _logged(meas, "y")) else ""))
    dof_ok, note = without_stabilised(observed & np.isfinite(nu).any(axis=0), loop.feedback, label)
    if note:
        notes.append(note)
    return Prepared(name=label, t=t, dt=dt, meas=meas, eta=eta, nu=nu, nu_dot=nu_dot, f=f, B=B, inflow=inflow,
                    f_ref=ref, input_kind=run.input_kind, surfaces=_surfaces(run, meas, n, label, notes), dof_ok=dof_ok,
                    notes=notes, window_s=window_s, observed=observed, reconstructed=reconstructed,
                    smoothed=smoothed, feedback=loop.feedback, unaided=unaided)


def observable(run: Run, label: str = "run") -> tuple:
    """The run's channels the diagnosis may read: every logged column but those its sidecar marks
    ``estimated-unaided`` (dead reckoning, :func:`udrobot_ctrl.io.runlog.unaided_channels`).

    The one place where such a column stops being "logged": everything downstream reads ``Prepared.meas``.

    Returns
    -------
    meas : dict of str -> (n,) ndarray
        The channels kept.
    unaided : dict of str -> ChannelSource
        The logged columns left out, with their source and the evidence.
    note : str
        Empty when none was left out.
    """
    marked = unaided_channels(run.metadata)
    meas = {c: np.asarray(v, float) for c, v in run.channels.items() if c not in marked}
    unaided = {c: s for c, s in marked.items() if c in run.channels}
    if not unaided:
        return meas, unaided, ""
    sources = sorted({s.source for s in unaided.values()})
    return meas, unaided, (f"{label}: {', '.join(unaided)} logged but estimated-unaided (dead reckoning: "
                           f"{'; '.join(sources)}; {next(iter(unaided.values())).aiding or 'no sensor of them'}): not "
                           f"fitted, scored or counted as observed")


def without_stabilised(dof_ok, feedback: ReplayFeedback | None, label: str = "run") -> tuple:
    """The DOFs whose equation error can be scored on a run replayed closed loop: not the attitude DOFs ArduSub
    stabilised when its outputs were logged more slowly than its attitude loop responds (interval longer than the
    angle loop's time constant 1 / ATC_ANG_*_P, 0.17 s at ArduSub's default P of 6: QGC's 2 Hz SERVO_OUTPUT_RAW;
    a dataflash log's 10 Hz RCOU is kept). There the moment the loop applied between the logged samples is not in
    the log, and the equation error would hand its unlogged corrections (which oppose the rates, like damping) to
    the effects (on a synthetic 2 Hz STABILIZE / ALT_HOLD dive, tests/udrobot_ctrl/gap/field_dive.py: a pitch
    quadratic-damping scale at its bound of 10). The closed-loop replay still scores their channels. Kept when no
    other DOF would be left.

    Returns
    -------
    dof_ok : (6,) bool ndarray
    note : str
        Empty when nothing was left out.
    """
    dof_ok = np.asarray(dof_ok, bool)
    if feedback is None:
        return dof_ok, ""
    slow = feedback.interval > 1.0 / np.maximum(np.asarray(feedback.attitude.angle_p, float), 1e-9)
    held = np.zeros(6, bool)
    held[3:6] = np.asarray(feedback.axes, bool) & dof_ok[3:6] & slow
    if not held.any() or not (dof_ok & ~held).any():
        return dof_ok, ""
    names = ", ".join(n for n, h in zip(DOF_NAMES, held) if h)
    return dof_ok & ~held, (f"{label}: equation error without {names}: ArduSub stabilised them, and its outputs "
                            f"logged every {feedback.interval * 1e3:.0f} ms miss the moment its attitude loop (time "
                            f"constant 1 / angle P) applied between samples (the closed-loop replay still scores "
                            f"their channels)")


def _logged(meas, c) -> bool:
    """True when channel c has any finite sample."""
    return c in meas and bool(np.isfinite(meas[c]).any())


def restoring_gradient(eta, p: PlantParameters, which: str):
    """d g(eta) / d theta for a restoring parameter: 'B' (net buoyancy, per N) or 'BG_x'/'BG_y'/'BG_z'.

    ``BG_*`` are the moments (x_g W - x_b B) etc. in N m. Returns (n, 6).
    """
    if which == "B":
        return restoring_forces(eta, 0.0, 1.0, p.r_g, p.r_b)
    axis = {"BG_x": 0, "BG_y": 1, "BG_z": 2}[which]
    r = np.zeros(3)
    r[axis] = 1.0
    return restoring_forces(eta, 1.0, 1.0, r, np.zeros(3)) - restoring_forces(eta, 1.0, 1.0, np.zeros(3),
                                                                              np.zeros(3))
