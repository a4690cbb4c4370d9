"""``udrobot-ctrl simulate``: replay a run's commanded inputs through the plant and write the simulated run.

Open loop (default): inputs are held (zero-order hold) on the run's own timestamps, which may be non-uniform:
each interval [t_k, t_k+1) is integrated with RK4 sub-steps of at most ``--max-step`` (0.01 s), or with
``solve_ivp``. The initial state is the first row's measured state; a channel it lacks starts from its first
finite sample (a velocity: within 0.8 s, else at rest, 0), as the diagnoser's windows start, with a warning.
A run of several segments (the ``segment`` column a converter writes when it cuts surface or disarmed stretches)
is replayed segment by segment: each starts afresh from its own first row's measured state (open loop, and under
``--closed-loop`` with the emulated autopilot's integrators restarted), and no replay or window crosses a cut.

A run the converter kept no row of (its sidecar's ``cut`` with ``kept`` null: the whole log at the surface, disarmed
or upside down) is replayed open loop with a warning, and refused by ``--closed-loop``: there the logged vehicle
floats or idles where the plant (fully submerged, no free surface) drifts at its own net buoyancy, so the flight
has nothing to be compared with; the refusal says how the model would drift (convert --no-cut to fly it anyway).

Every replay (open and closed loop) is checked against the plant's domain: a warning line names each span above
the surface (z < 0), rolled or pitched over (cos phi cos theta < 0) or with a thruster held at its limit for 4 s
or more, and the simulated run's sidecar (NAME.json) holds them as ``replay_domain`` (codes and spans).

Windowed (``--windows [S]``, S = 8 s when omitted): the diagnoser's multiple-shooting replay and gap metric.
Each run is cut into windows of S seconds, each simulated from the measured state at its start with the logged
commands held; the NRMSE per channel (RMS error / std of the measurement, over all runs) and their RMS over the
channels that moved above their noise are printed (and written by ``--json``). This is the ``gap_before`` /
``gap_after`` of a diagnosis report: replaying a report's holdout runs with the model ``diagnose --out-model``
wrote gives its ``gap_after`` (with the same --windows as diagnose's --window). Several runs may be given; the
gap pools them as the report does.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
from tqdm import tqdm

from udrobot_ctrl.autopilot.fly import fly
from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.convert import load_any
from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics.domain import (
    DEFAULT_WINDOW_S,
    SATURATION_WINDOW_FRACTION,
    DomainCheck,
    domain_check,
    idle_drift,
    limit_rows,
    thrust_limits,
)
from udrobot_ctrl.dynamics.plant import plant_parameters, state_derivative
from udrobot_ctrl.dynamics.sim import Actuators, integrate_intervals, rk4_step
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.gap.data import START_VELOCITY_WITHIN_S, start_state
from udrobot_ctrl.gap.replay import WindowedGap, windowed_gap
from udrobot_ctrl.gap.screen import unrepresented_runs
from udrobot_ctrl.gap.shrink import check_window
from udrobot_ctrl.io import runlog
from udrobot_ctrl.io.runlog import check_time_gaps
from udrobot_ctrl.vehicle import ALL_MODEL_NAMES, load_model
from udrobot_files.output import (
    atomic_write,
    check_command,
    run_files,
    spec_files,
)


def register(subparsers):
    """Add the ``simulate`` sub-command."""
    parser = subparsers.add_parser(
        "simulate", help="replay a run's commanded inputs through the plant model",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=__doc__.replace("``", "") + "\nWhat the model predicts for the commands the vehicle really "
                    "received: compare --out with --input to see the sim-to-real gap (udrobot-ctrl diagnose "
                    "explains it).\nRun logs are udrobot-run/1 (docs/formats/runlog.md).",
        epilog="examples:\n  udrobot-ctrl simulate --model pendulum:chin --input pool.csv --out pool_sim.csv\n"
               "  udrobot-ctrl simulate --model corrected.json --windows 8 --input holdout.csv --json gap.json")
    parser.add_argument("--model", required=True, help=f"model name ({', '.join(ALL_MODEL_NAMES)}) or model file")
    parser.add_argument("--input", required=True, nargs="+", metavar="RUN",
                        help="run to replay (udrobot-run/1 CSV or a log io can convert); with --windows, one or more")
    parser.add_argument("--out", help="simulated run to write (udrobot-run/1 CSV); required without --windows; with "
                                      "--windows (one run) the windowed replay, empty cells between windows; its "
                                      "folder must exist")
    parser.add_argument("--windows", type=float, nargs="?", const=8.0, default=None, metavar="S",
                        help="windowed replay and NRMSE gap of diagnose (windows of S s from the measured state; "
                             "S = 8 s, diagnose's default, when omitted)")
    parser.add_argument("--json", metavar="GAP.json",
                        help="with --windows: write the gap (the report's gap object plus model, effects, runs, "
                             "window_s; its folder must exist)")
    parser.add_argument("--method", choices=("rk4", "solve_ivp"), default="rk4",
                        help="integrator: fixed-step RK4 sub-steps (default) or scipy solve_ivp (adaptive)")
    parser.add_argument("--max-step", type=float, default=0.01, help="largest RK4 sub-step, s (default 0.01)")
    parser.add_argument("--closed-loop", action="store_true",
                        help="fly the model under the emulated ArduSub autopilot from the run's logged pilot inputs, "
                             "modes and targets instead of replaying its logged motor outputs (an ArduSub run "
                             "converted from .bin/.tlog, a model with an ArduSub frame: bluerov2, bluerov2-heavy)")
    parser.add_argument("--loop-rate", type=float, default=None, metavar="HZ",
                        help="with --closed-loop: the autopilot's loop rate (default: the log's SCHED_LOOP_RATE, "
                             "else ArduSub's 400 Hz)")
    parser.add_argument("--mapping", default=None, help="mapping for non-udrobot-run logs (see convert)")
    parser.add_argument("--force", action="store_true", help="replace an existing output run (never an input)")
    parser.set_defaults(func=run)


def read_input_run(path, mapping=None, warn_unrepresented: bool = True):
    """A Run from a udrobot-run/1 CSV (runlog.read_run) or any log udrobot_ctrl.convert.load_any understands; a
    warning on stderr when the converter kept no stretch of it (the plant does not represent it: a replay's gap there
    is not a model error), unless ``warn_unrepresented`` is False (the caller refuses such a run itself)."""
    path = Path(path)
    run = None
    if path.suffix.lower() == ".csv":
        try:
            run = runlog.read_run(path)
        except runlog.RunLogError:
            if mapping is None:
                raise
    run = run if run is not None else load_any(path, mapping=mapping)
    for u in unrepresented_runs([run]) if warn_unrepresented else ():
        if u is not None:
            print(f"udrobot-ctrl simulate: warning: {u.reason()}", file=sys.stderr)
    return run


def unrepresented_flight(reason: str, model_name: str, drift, duration_s: float) -> str:
    """Why ``--closed-loop`` does not fly a run the converter kept no row of (the refusal's line).

    Parameters
    ----------
    reason : str
        The run's :meth:`~udrobot_ctrl.gap.screen.Unrepresented.reason` (which checks failed, on what share).
    model_name : str
        The model flown.
    drift : IdleDrift
        :func:`~udrobot_ctrl.dynamics.domain.idle_drift` of the model: what it does with its motors at neutral.
    duration_s : float
        The run's duration, s.

    Returns
    -------
    str
    """
    if drift.speed > 0:
        would = (f"{model_name} is {-drift.net_up:.3g} N heavy and would sink at {drift.speed:.2g} m/s, "
                 f"{drift.over(duration_s):.2g} m over the run's {duration_s:.0f} s")
    elif drift.speed < 0:
        would = (f"{model_name} is {drift.net_up:.3g} N buoyant and would rise at {-drift.speed:.2g} m/s through the "
                 f"waterline, with nothing to float on")
    else:
        would = f"{model_name} is neutrally buoyant and would hold any depth"
    return (f"{reason}. --closed-loop does not fly it: with the motors at neutral (disarmed: ArduSub's "
            f"AP_Motors6DOF outputs 1500 us) the plant, a fully submerged body with no free surface, drifts at its "
            f"own net buoyancy ({would}) where the logged vehicle floats at the surface or idles, so the flight would "
            f"compare the model's drift with a vehicle it does not represent (convert --no-cut flies the run as it is)")


def initial_state(run) -> tuple:
    """The replay's start state (12,) and how its missing channels were filled: the first row's state, a channel it
    lacks filled as the diagnoser fills it (:func:`udrobot_ctrl.gap.data.start_state`: a pose from its first finite
    sample, a velocity from its first sample within 0.8 s, else 0), with a warning naming each filled channel and
    how. Returns ``(x0, fills)``."""
    x0, fills = start_state(run.t, run.state_matrix())
    if fills:
        warnings.warn(f"{run.path or 'run'}: first row has no {', '.join(f.channel for f in fills)}; "
                      + "; ".join(_fill_text(f) for f in fills), stacklevel=2)
    return x0, fills


def _fill_text(f) -> str:
    """How one channel of the start state was filled, for the warning."""
    if f.how == "first_sample":
        return f"{f.channel} from its first sample ({f.t_first:.3g} s in)"
    if f.t_first is None:
        return f"{f.channel} at rest (0: never logged)"
    return f"{f.channel} at rest (0: first logged {f.t_first:.3g} s in, later than {START_VELOCITY_WITHIN_S:g} s)"


def domain_report(t, x, where: str, thrust=None, limits=(None, None)) -> DomainCheck:
    """Check a whole-run replay against the plant's domain (:func:`udrobot_ctrl.dynamics.domain.domain_check`:
    above the surface, inverted, a thruster at its limit for 4 s, half of the default 8 s window), print a warning
    line per span on stderr and return the check."""
    lo, hi = limits
    chk = domain_check(t, x, thrust if lo is not None else None, lo, hi,
                       saturation_s=SATURATION_WINDOW_FRACTION * DEFAULT_WINDOW_S)
    for span in chk.spans:
        print(f"udrobot-ctrl simulate: warning: {where}: the replay leaves the plant's domain, {span.describe()}: "
              f"{DOMAIN_REASON[span.code]}", file=sys.stderr)
    return chk


#: the warning's reason per code (:data:`udrobot_ctrl.dynamics.domain.CODES`)
DOMAIN_REASON = {"above_surface": "above the surface (z < 0; the plant has no free surface)",
                 "inverted": "rolled or pitched over (body z axis above the horizontal)",
                 "thrust_saturated": "a thruster held at its limit (the replay measures the limit, not the dynamics)"}


def replay_sidecar(domain: DomainCheck, x0_fills=()) -> dict:
    """The simulated run's sidecar (docs/formats/runlog.md): ``replay_domain`` (codes, spans, saturation_s) and,
    when the first row lacked some channel, ``start_state`` (channel, how, t_first)."""
    out = {"replay_domain": domain.to_json() | {"saturation_s": domain.saturation_s}}
    if x0_fills:
        out["start_state"] = [{"channel": f.channel, "how": f.how, "t_first": f.t_first} for f in x0_fills]
    return out


def input_wrenches(run, p) -> tuple:
    """Per-row body wrench (n, 6) N, N m, and the thrusts (n, n_thr) N (None for tau inputs).

    ``pwm`` inputs are mapped by the T-200 curve at the row's ``voltage`` channel (the model's supply voltage
    ``p.supply_voltage`` when absent or nan: 12 V UDrobot, 14.8 V BlueROV2); thrusts are clipped to each
    thruster's forward/reverse limit. Column i drives thruster i (the model's thruster order = motor order).
    """
    kind, u = run.input_kind, np.asarray(run.inputs, dtype=float)
    if not np.all(np.isfinite(u)):
        bad = np.argwhere(~np.isfinite(u))[0]
        raise ValueError(f"{run.path or 'run'}: row {bad[0] + 1}: input {run.input_names[bad[1]]} is not finite")
    if kind == "tau":
        return u, None
    n_thr = p.T.shape[1]
    if u.shape[1] != n_thr:
        raise ValueError(f"{run.path or 'run'}: {u.shape[1]} {kind} columns but the model has {n_thr} thrusters")
    if kind == "pwm":
        f = clipped_thrusts(u, run.battery_voltage(p.supply_voltage), p)
    elif kind == "thrust":
        f = np.clip(u, p.f_min, p.f_max)
    else:
        raise ValueError(f"{run.path or 'run'}: unknown input kind {kind!r}")
    return f @ p.T.T, f


def clipped_thrusts(pwm, voltage, p) -> np.ndarray:
    """Thrusts (n, n_thr) N of PWM commands (n, n_thr) us by the T-200 curve at each row's supply ``voltage`` (n,) V,
    clipped to each thruster's forward/reverse limit of the plant ``p``."""
    return np.clip(pwm_to_thrust(pwm, np.asarray(voltage, float)[:, None]), p.f_min, p.f_max)


REPLAY_CHUNK = 200_000  # rows per compiled call (progress granularity)
MAX_SUBSTEPS_PER_ROW = 1.0e4  # assumed bound: beyond this the time column, not the dynamics, sets the work


def segments_duration(run) -> float:
    """Sum of the durations of ``run``'s segments, s (its duration when it has one): the time a replay covers."""
    return float(sum(run.t[b - 1] - run.t[a] for a, b in run.segment_bounds()))


def substep_count(t, max_step: float, segment=None) -> int:
    """Total RK4 sub-steps of a replay: sum over intervals of ceil(h_k / max_step), none for the intervals between
    two segments (``segment``: the run's segment column; nothing is integrated across a cut)."""
    h = np.diff(np.asarray(t, float))
    steps = np.maximum(1, np.ceil(h / max_step - 1e-9))
    return int(np.sum(steps[~runlog.segment_breaks(segment, len(t))]))


def check_work(t, max_step: float, where: str = "run", segment=None) -> int:
    """Refuse a replay whose sub-step count is absurd for the number of rows (a clock jump in ``t``); the intervals
    between segments (``segment``) are not integrated, so not counted.

    Returns the sub-step count. Raises ValueError naming the widest interval.
    """
    check_time_gaps(t, where, segment=segment)
    n_sub = substep_count(t, max_step, segment)
    if n_sub > MAX_SUBSTEPS_PER_ROW * max(len(t), 1e3):
        h = np.where(runlog.segment_breaks(segment, len(t)), 0.0, np.diff(t))
        k = int(np.argmax(h))
        raise ValueError(f"{where}: replay needs {n_sub:.3g} RK4 sub-steps of {max_step:g} s for {len(t)} rows; "
                         f"widest interval {t[k + 1] - t[k]:.6g} s (data rows {k + 1}-{k + 2}); check the time "
                         f"column or raise --max-step")
    return n_sub


def replay(model, t, x0, tau, method: str = "rk4", max_step: float = 0.01,
           progress: bool | None = None, thrust=None) -> np.ndarray:
    """States (n, 12) at times ``t`` (n,) from ``x0`` with ``tau[k]`` held on [t_k, t_k+1).

    ``rk4`` runs compiled (numba, :func:`udrobot_ctrl.dynamics.sim.integrate_intervals`) in chunks of
    :data:`REPLAY_CHUNK` rows with a progress bar (``progress`` None: only on a terminal and for long runs).
    A model with run-time effects (a corrected model, ``dynamics.effects``) is replayed in numpy instead, with
    the clipped thrusts ``thrust`` (n, n_thr) N, which its thrust effects (maps, lag, inflow loss) act on.

    Raises
    ------
    FloatingPointError
        If the state becomes non-finite (naming the time).
    """
    p = model if hasattr(model, "M_inv") else plant_parameters(load_model(model))
    t = np.asarray(t, float)
    tau = np.asarray(tau, float)
    xs = np.empty((len(t), 12))
    x = np.asarray(x0, float).copy()
    xs[0] = x
    if method == "rk4" and p.effects:
        return _replay_with_effects(p, t, x, tau, thrust, max_step, xs)
    if method == "rk4":
        show = progress if progress is not None else (None if len(t) > REPLAY_CHUNK else False)
        with tqdm(total=len(t) - 1, unit="row", desc="replay", disable=None if show is None else not show,
                  leave=False) as bar:
            for a in range(0, len(t) - 1, REPLAY_CHUNK):
                b = min(len(t) - 1, a + REPLAY_CHUNK)
                _, bad = integrate_intervals(p, xs[a], t[a:b + 1], tau[a:b], max_step, out=xs[a:b + 1])
                if bad >= 0:
                    raise FloatingPointError(f"simulation diverged at t = {t[a + bad + 1]:.4f} s")
                bar.update(b - a)
        return xs
    if method != "solve_ivp":
        raise ValueError(f"method must be 'rk4' or 'solve_ivp', got {method!r}")
    if fx.thrust_effects(p.effects) or fx.lag_time_constant(p.effects) is not None:
        raise ValueError(f"model {p.name!r} has thrust effects, which --method solve_ivp does not replay; use rk4")
    from scipy.integrate import solve_ivp

    for k in range(len(t) - 1):
        sol = solve_ivp(lambda _t, xx, tk=tau[k]: state_derivative(xx, tk, p), (t[k], t[k + 1]), x,
                        rtol=1e-8, atol=1e-10)
        if not sol.success:
            raise FloatingPointError(f"solve_ivp failed on [{t[k]:.4f}, {t[k + 1]:.4f}] s: {sol.message}")
        x = sol.y[:, -1]
        if not np.all(np.isfinite(x)):
            raise FloatingPointError(f"simulation diverged at t = {t[k + 1]:.4f} s")
        xs[k + 1] = x
    return xs


def _replay_with_effects(p, t, x, tau, thrust, max_step, xs):
    """The numpy RK4 of :mod:`udrobot_ctrl.dynamics.sim` with the model's effects, sub-step by sub-step."""
    actuators = None
    if fx.thrust_effects(p.effects) or fx.lag_time_constant(p.effects) is not None:
        if thrust is None:
            raise ValueError(f"model {p.name!r} has thrust effects; the run must give thrust or pwm inputs, not a "
                             f"commanded wrench")
        actuators = Actuators(p, max_step)
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        m = max(1, int(np.ceil(h / max_step - 1e-9)))
        for _ in range(m):
            tau_k, dist = tau[k], None
            if actuators is not None:
                actuators.dt = h / m
                tau_k, dist = actuators.step(thrust[k], None)
            x = rk4_step(p, x, tau_k, h / m, dist)
        if not np.all(np.isfinite(x)):
            raise FloatingPointError(f"simulation diverged at t = {t[k + 1]:.4f} s")
        xs[k + 1] = x
    return xs


def _format_gap(g: WindowedGap) -> str:
    """Console lines of a windowed gap: the overall value and every channel (scored ones marked)."""
    lines = [f"gap (NRMSE, {g.window_s:g} s windows) of {g.model} on {', '.join(g.runs)}: "
             + (f"{g.value:.6f}" if np.isfinite(g.value) else "undefined (no channel moved above its noise)"),
             "effects replayed: " + (", ".join(g.effects) or "none (nominal model)")]
    for c, v in g.per_channel.items():
        tag = "scored" if c in g.scored else ("undefined: " + g.undefined[c] if c in g.undefined else "not scored: "
                                              "did not move above its noise")
        lines.append(f"  {c:<6s} {v:10.6f}  {tag}")
    if any(g.diverged.values()):
        lines.append("diverged windows (their remaining samples score the error cap): " + ", ".join(
            f"{run} {n} of {g.windows.get(run, 0)}" for run, n in g.diverged.items() if n))
    for w in g.domain:
        lines.append(f"warning: {w.run} window {w.window} ({w.t0:.2f}-{w.t1:.2f} s) leaves the plant's domain: "
                     + "; ".join(f"{sp.describe()}: {DOMAIN_REASON[sp.code]}" for sp in w.check.spans)
                     + " (scored, not a finding)")
    return "\n".join(lines)


def run_windows(args) -> int:
    """``--windows``: the diagnoser's windowed replay and gap of ``args.model`` on the ``args.input`` runs."""

    srcs = [Path(s) for s in args.input]
    for src in srcs:
        if not src.exists():
            raise FileNotFoundError(f"input run {src} does not exist")
    check_window(args.windows, (), "windows")
    inputs = [*srcs, *spec_files(args.model, getattr(args, "mapping", None))]
    if args.out and len(srcs) > 1:
        raise ValueError(f"--out writes one simulated run; {len(srcs)} --input runs were given (use --json for the "
                         f"gap of several runs)")
    check_command({"--json": args.json, "--out": run_files(args.out) if args.out else None}, inputs,
                  force=getattr(args, "force", False))
    runs = [read_input_run(src, getattr(args, "mapping", None)) for src in srcs]
    g = windowed_gap(args.model, runs, args.windows, names=[src.name for src in srcs])
    print(_format_gap(g))
    if args.json:
        atomic_write(Path(args.json), json.dumps(g.to_dict(), indent=2) + "\n", protect=inputs)
        print(f"wrote {args.json}")
    if args.out:  # one input run: its segments' preps, in order (one without segments)
        preps, sims = g.preps, g.sims
        xs = np.concatenate(sims)
        channels = {name: xs[:, i] for i, name in enumerate(STATE_NAMES)}
        t = np.concatenate([pr.t for pr in preps])
        extra = None
        if len(preps) > 1:
            numbers = [int(part.segment[0]) for part in runlog.split_segments(runs[0])]
            extra = {runlog.SEGMENT: np.concatenate([np.full(pr.n, k) for pr, k in zip(preps, numbers)])}
        kind = preps[0].input_kind
        runlog.write_run(args.out, t, channels, "thrust" if kind == "pwm" else kind,
                         np.concatenate([pr.f for pr in preps]), protect=inputs, extra=extra)
        grid = f"{t.size} rows, dt {preps[0].dt:g} s" + (f", {len(preps)} segments" if len(preps) > 1 else "")
        print(f"wrote {args.out}: windowed replay on the run's uniform grid ({grid}; inputs are the clipped "
              f"commands{' in N (converted from pwm)' if kind == 'pwm' else ''})")
    return 0


def _one_run_in_one_out(args, what: str, hint: str = "") -> tuple:
    """The single ``--input`` run and the ``--out`` run of a replay, checked: exactly one input (``what``, got N,
    ``hint``), that exists, and an output that destroys no input (its folder must exist). Returns (src, out,
    inputs): the files the writes must protect."""
    if len(args.input) != 1:
        raise ValueError(f"{what}, got {len(args.input)}{hint}")
    src, out = Path(args.input[0]), Path(args.out)
    if not src.exists():
        raise FileNotFoundError(f"input run {src} does not exist")
    inputs = [src, *spec_files(args.model, getattr(args, "mapping", None))]
    check_command({"--out": run_files(out)}, inputs, force=getattr(args, "force", False))
    return src, out, inputs


def run_closed_loop(args) -> int:
    """``--closed-loop``: fly ``args.model`` under the emulated ArduSub from the run's logged pilot inputs and modes.

    Each segment of the run is flown on its own (:func:`udrobot_ctrl.io.runlog.split_segments`): from its first row's
    state with a new autopilot (integrators and targets reset), written on its control grid in the run's t with the
    ``segment`` column (a run of one segment: t from its first row, as before)."""
    src, out, inputs = _one_run_in_one_out(args, "--closed-loop flies one --input run")
    if args.loop_rate is not None and not 10.0 <= args.loop_rate <= 2000.0:
        raise ValueError(f"--loop-rate must be between 10 and 2000 Hz (ArduSub runs 100-400 Hz), got {args.loop_rate}")
    rn = read_input_run(src, getattr(args, "mapping", None), warn_unrepresented=False)
    p = plant_parameters(load_model(args.model))
    (unrepresented,) = unrepresented_runs([rn])
    if unrepresented is not None:
        raise ValueError(unrepresented_flight(unrepresented.reason(), args.model, idle_drift(p), rn.duration))
    parts = runlog.split_segments(rn)
    flights = [fly(args.model, part, args.loop_rate) for part in parts]  # each from its first row, a new autopilot
    for note in dict.fromkeys(n for f in flights for n in f.notes):
        print(note)
    segmented = len(parts) > 1
    # each segment's control grid in the run's own t (s from the run's first row when it has one segment)
    t_parts = [(part.t[0] - rn.t[0] if not segmented else part.t[0]) + f.t for part, f in zip(parts, flights)]
    t = np.concatenate(t_parts)
    x = np.concatenate([f.x for f in flights])
    pwm = np.concatenate([f.pwm for f in flights])
    channels = {name: x[:, i] for i, name in enumerate(STATE_NAMES)}
    extra = {"mode": np.concatenate([f.mode for f in flights]).astype(float)}
    if segmented:
        extra[runlog.SEGMENT] = np.concatenate([np.full(f.t.size, part.segment[0]) for part, f in zip(parts, flights)])
    errors, checks = {}, []
    for part, f, t_part in zip(parts, flights, t_parts):
        logged = runlog.resample(part, part.t[0] + f.t)
        volts = logged.battery_voltage(p.supply_voltage)
        checks.append(domain_report(t_part, f.x, str(src), clipped_thrusts(f.pwm, volts, p),
                                    thrust_limits(p.f_min, p.f_max, "pwm", volts)))
        for name in ("z", "phi", "theta", "psi", "u", "v", "w"):
            meas = logged.channels.get(name)
            if meas is None or not np.isfinite(meas).any():
                continue
            err = f.x[:, STATE_NAMES.index(name)] - meas
            if name in ("phi", "theta", "psi"):
                err = np.angle(np.exp(1j * err))
            errors.setdefault(name, []).append(err)
    runlog.write_run(out, t, channels, "pwm", pwm, protect=inputs, extra=extra,
                     metadata=replay_sidecar(DomainCheck.joined(checks)))
    lines = [f"{name} {np.sqrt(np.nanmean(np.concatenate(e) ** 2)):.3g}" for name, e in errors.items()]
    print(f"closed-loop flight against the log (RMS error, m, rad, m/s): {', '.join(lines)}")
    flown = sum(float(f.t[-1]) for f in flights)
    where = f" in {len(parts)} segments, each from its own first row" if segmented else ""
    print(f"wrote {out}: {t.size} rows, {flown:.3f} s flown under the emulated ArduSub{where} (pwm_i are its motor "
          f"outputs)")
    return 0


def run(args) -> int:
    """Replay ``args.input`` through ``args.model`` and write ``args.out`` (or ``--windows``: score the gap)."""

    if getattr(args, "windows", None) is not None:
        if getattr(args, "closed_loop", False) or getattr(args, "loop_rate", None) is not None:
            raise ValueError("--windows scores the open-loop windowed replay (each window from its measured state); "
                             "--closed-loop" + (" / --loop-rate" if getattr(args, "loop_rate", None) else "")
                             + " flies one run under the emulated ArduSub: give one or the other")
        return run_windows(args)
    if getattr(args, "json", None):
        raise ValueError("--json writes the gap of a windowed replay; add --windows")
    if args.out is None:
        raise ValueError("--out is required (the simulated run), unless --windows scores the gap")
    if getattr(args, "closed_loop", False):
        return run_closed_loop(args)
    if getattr(args, "loop_rate", None) is not None:
        raise ValueError("--loop-rate sets the emulated autopilot's rate; add --closed-loop")
    src, out, inputs = _one_run_in_one_out(args, "the open-loop replay takes one --input run",
                                           " (--windows scores several)")
    if not args.max_step > 0:
        raise ValueError(f"--max-step must be > 0, got {args.max_step}")
    vehicle = load_model(args.model)
    p = plant_parameters(vehicle)
    rn = read_input_run(src, getattr(args, "mapping", None))
    if rn.n < 2:
        raise ValueError(f"{src}: need at least 2 rows to simulate, got {rn.n}")
    check_work(rn.t, args.max_step, str(src), rn.segment)
    tau, thrust = input_wrenches(rn, p)
    parts = runlog.split_segments(rn)
    xs = np.empty((rn.n, 12))
    fills = []
    for part, (a, b) in zip(parts, rn.segment_bounds()):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            x0, filled = initial_state(part)
        fills += filled
        for w in caught:
            print(f"udrobot-ctrl simulate: warning: {w.message}", file=sys.stderr)
        try:
            xs[a:b] = replay(p, rn.t[a:b], x0, tau[a:b], args.method, args.max_step, progress=True,
                             thrust=None if thrust is None else thrust[a:b])
        except FloatingPointError as exc:
            raise ValueError(f"{part.path or src} with model {vehicle.name}: {exc}") from exc
    channels = {name: xs[:, i] for i, name in enumerate(STATE_NAMES)}
    if "voltage" in rn.channels:
        channels["voltage"] = rn.channels["voltage"]
    extra = {runlog.SEGMENT: rn.extra[runlog.SEGMENT]} if rn.segment is not None else None
    volts = rn.battery_voltage(p.supply_voltage) if rn.input_kind == "pwm" else None
    lo, hi = thrust_limits(p.f_min, p.f_max, rn.input_kind, volts)
    domain = DomainCheck.joined(  # each segment on its own: a stretch at a limit never runs across a cut
        domain_report(rn.t[a:b], xs[a:b], str(src), None if thrust is None else thrust[a:b],
                      (None, None) if lo is None else (limit_rows(lo, slice(a, b)), limit_rows(hi, slice(a, b))))
        for a, b in rn.segment_bounds())
    runlog.write_run(out, rn.t, channels, rn.input_kind, rn.inputs, protect=inputs, extra=extra,
                     metadata=replay_sidecar(domain, fills))
    where = f" in {len(parts)} segments, each from its own first row" if len(parts) > 1 else ""
    print(f"wrote {out}: {rn.n} rows, {segments_duration(rn):.3f} s simulated with {vehicle.name} ({args.method})"
          f"{where}")
    return 0
