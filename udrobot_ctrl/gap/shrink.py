"""Score the gap in simulation: multiple-shooting replay of the logged commands, NRMSE per channel.

Definition used by the report (``metric: "nrmse"``):

* Each run is cut into consecutive windows of ``window_s`` seconds (default 8 s). Each window is simulated
  from the *measured* state at its start (smoothed velocities, logged pose) with the logged commands held
  (zero-order hold) -- a multiple-shooting replay. A pure open-loop replay of a closed-loop run drifts
  without bound (the logged controller stabilised the real vehicle, not the model), so a whole-run replay
  measures drift; short re-initialised windows measure the model error over a horizon of a few time
  constants. Windows whose start state is not measured (DVL gap) are skipped. A run of several segments (the
  ``segment`` column of a cut field log) is replayed as one run per segment (:func:`segment_runs`): its windows,
  smoothing and derivatives start afresh at each segment's first row and none crosses a cut.
* Per channel c (u v w p q r z phi theta psi, when logged): NRMSE_c = RMS(sim_c - meas_c) / std(meas_c)
  over all scored samples of all runs (angle errors wrapped to [-pi, pi)).
* The accelerometer (``ax ay az``), on runs whose unlogged velocities the smoother reconstructed: the replay's
  specific force ``f = v_dot + omega x v - R^T [0, 0, g]`` (:func:`specific_force`; ``v_dot`` the model's
  acceleration at each replayed sample, effects included) against the measurement minus the smoother's estimate of the
  accelerometer bias. Without a DVL this is the one measurement of the surge and sway dynamics (an added-mass
  error in surge, a thrust loss on the horizontal thrusters).
* A window *diverges* when its state turns non-finite or leaves the replay's envelope: a speed or rate above
  ``VELOCITY_ENVELOPE`` (1e3 m/s or rad/s) or a displacement from the window's start above ``POSITION_ENVELOPE``
  (1e4 m). Its remaining samples count as the worst error a channel can score: the error is held at the channel's
  cap (:data:`ERROR_CAP`: the velocity envelope for ``u v w p q r``, pi for the wrapped angles, the position envelope
  for ``z``, ``ACCEL_ENVELOPE`` = 1e4 m/s^2 for ``ax ay az``), and every finite error is clipped to that cap, so the
  NRMSE rises monotonically with the replay error and a model that blows up scores worse than any model that does
  not (a window left at its first sample, which equals the measurement, would otherwise score best). The gap says
  how many windows diverged in each run (:attr:`GapScore.diverged`).
* A channel is *scored* when the vehicle moved in it: std(meas_c) > 3 x its sensor noise (estimated from
  the sample-to-sample differences). The overall gap is the RMS of the scored channels' NRMSE.
* ``shrink`` = 1 - gap(model + effect) / gap(nominal); ``unexplained`` = gap_after / gap_before.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from udrobot_ctrl.constants import STATE_INDEX
from udrobot_ctrl.dynamics.effects import NUMPY
from udrobot_ctrl.dynamics.integrators import rk4_step
from udrobot_ctrl.dynamics.plant import PlantParameters, generalized_forces, kinematics, wrap_angle
from udrobot_ctrl.gap.data import Prepared, prepare
from udrobot_ctrl.gap.effects import PLANT_FORCES, PlantForces
from udrobot_ctrl.gap.smoother import GRAVITY, accelerometer, logged_noise_model
from udrobot_ctrl.io.runlog import Run, split_segments
from udrobot_ctrl.parallel import fork_map, shares, workers

CHANNELS = ("u", "v", "w", "p", "q", "r", "z", "phi", "theta", "psi")
ACCEL = ("ax", "ay", "az")
#: units of the channels (udrobot-run/1): positions m, angles rad, velocities m/s and rad/s, specific force m/s^2
UNITS = {"x": "m", "y": "m", "z": "m", "phi": "rad", "theta": "rad", "psi": "rad", "u": "m/s", "v": "m/s",
         "w": "m/s", "p": "rad/s", "q": "rad/s", "r": "rad/s", "ax": "m/s^2", "ay": "m/s^2", "az": "m/s^2"}
#: columns of a replay: the state (x y z phi theta psi u v w p q r), the specific force (ax ay az), then the window
#: column (:data:`WINDOW`)
SIM_COLUMNS = 16
#: the replay's window column: k + 1 on the samples of its k-th window (0-based) while the replay holds, -(k + 1) on
#: the samples after the window diverged, nan outside the windows
WINDOW = 15
ANGLES = ("phi", "theta", "psi")
#: the replay's envelope: a window whose speed or rate exceeds this (m/s, rad/s) has diverged
VELOCITY_ENVELOPE = 1e3
#: ... or whose position moves further than this from the window's start (m: beyond any water depth)
POSITION_ENVELOPE = 1e4
#: the accelerometer channels' error cap, m/s^2 (about 1000 g: the velocity envelope gained in 0.1 s)
ACCEL_ENVELOPE = 1e4
#: channel -> largest error it scores (channel units): a diverged window's samples score this, finite errors are
#: clipped to it (module docstring)
ERROR_CAP = {**dict.fromkeys(("u", "v", "w", "p", "q", "r"), VELOCITY_ENVELOPE),
             **dict.fromkeys(ANGLES, np.pi), "z": POSITION_ENVELOPE, **dict.fromkeys(ACCEL, ACCEL_ENVELOPE)}


def check_window(window_s, preps, option: str = "window") -> float:
    """The multiple-shooting window (s) checked against the prepared runs it will cut; returns it as a float.

    Raises
    ------
    ValueError
        If it is not a finite positive number, spans fewer than two samples of every run's grid (nothing to
        integrate), or is so long that no run holds a quarter of it (no window fits: the gap would be undefined),
        naming the limits.
    """
    try:
        w = float(window_s)
    except (TypeError, ValueError):
        raise ValueError(f"--{option} must be a number of seconds, got {window_s!r}") from None
    if not (math.isfinite(w) and w > 0):
        raise ValueError(f"--{option} must be a finite number of seconds > 0, got {window_s!r}")
    preps = list(preps)
    if preps:
        shortest = 2 * min(pr.dt for pr in preps)
        longest = max(pr.t[-1] - pr.t[0] for pr in preps)
        if w < shortest:
            raise ValueError(f"--{option} {w:g} s is shorter than two samples of the runs' grid ({shortest:g} s): "
                             f"nothing would be simulated; use a window of a few time constants (default 8 s)")
        if w >= 4 * longest:  # window_starts opens a window only where a quarter of it fits in the run
            raise ValueError(f"--{option} {w:g} s is longer than the longest run ({longest:.3g} s) can hold: no "
                             f"window fits (a window needs a quarter of its length in the run); use at most "
                             f"{longest:.3g} s")
    return w


def segment_runs(runs, labels=None) -> tuple:
    """Every run of ``runs`` cut into one run per segment (:func:`udrobot_ctrl.io.runlog.split_segments`): the single
    place the replays of ``diagnose`` and ``simulate --windows`` get their stretches from, so that each segment is
    prepared (resampled, smoothed, differentiated, reconstructed) and replayed on its own, its windows re-initialised
    from its own first row.

    Parameters
    ----------
    runs : sequence of Run
    labels : sequence of str, optional
        A label per run; a segment's is ``LABEL[segment k]`` (its path's tag, ``split_segments``, by default).

    Returns
    -------
    runs, labels : list of Run, list of str or None
        One entry per segment, in order (labels None when none were given).
    """
    out, names = [], []
    for i, run in enumerate(runs):
        parts = split_segments(run)
        out += parts
        if labels is not None:
            seg = run.segment
            names += ([labels[i]] if len(parts) == 1 else
                      [f"{labels[i]}[segment {int(seg[a])}]" for a, _ in run.segment_bounds()])
    return out, (names if labels is not None else None)


def window_starts(prep: Prepared, window_s: float):
    """Indices where windows start (start state measured)."""
    w = max(2, int(round(window_s / prep.dt)))
    starts = np.arange(0, prep.n - max(2, w // 4), w)
    ok = np.isfinite(prep.nu[starts][:, prep.dof_ok]).all(axis=1)
    return starts[ok], w


def _surface_ctx(prep: Prepared, k, xs, at_k=None):
    """Per-step surface distances for a batch of windows at absolute indices k (N,), simulated state xs.

    ``at_k``: :func:`_surfaces_at` (prep, k), when several states share the step's indices (RK4 stages).
    """
    out = []
    for (d_meas, pos_meas), (_, normal, label) in zip(at_k or _surfaces_at(prep, k), prep.surfaces):
        out.append((d_meas + (xs[:, :3] - pos_meas) @ normal, normal, label))
    return out


def _surfaces_at(prep: Prepared, k):
    """Measured distance to each surface and measured position (N, 3) at absolute indices k (N,)."""
    pos = prep.eta[k, :3]
    return [(dist[k], pos) for dist, _, _ in prep.surfaces]


def delivered_commands(prep: Prepared, hooks=()) -> np.ndarray:
    """(n, k) actuator commands after the effects' input filters (static nonlinearities first, then the lag)."""
    f = prep.f.copy()
    for h in sorted(hooks, key=lambda h: h.order):
        if h.input_filter is not None:
            f = h.input_filter(f, prep.dt)
    return f


def effect_wrench(prep: Prepared, hooks) -> np.ndarray:
    """(n, 6) generalised force (N, N m) that ``hooks`` add to the nominal plant along a prepared run's own state.

    The thrust the filters take away or add, ``B (f_delivered - f)``, plus the effects' forces, minus their added
    mass times the run's acceleration: the same terms :func:`simulate_windows` integrates, evaluated on the
    prepared (measured or reconstructed) trajectory instead of a simulated one. Non-finite states count as zero.
    """
    f = delivered_commands(prep, hooks)
    x = np.nan_to_num(prep.state())
    nu_dot = np.nan_to_num(prep.nu_dot)
    ctx = {"surfaces": list(prep.surfaces)}
    out = (f - prep.f) @ prep.B.T
    for h in hooks:
        if h.force is not None:
            out = out + h.force(x, f, ctx)
        if h.mass is not None:
            out = out - np.einsum("nij,nj->ni", h.mass(x, ctx), nu_dot)
    return np.nan_to_num(out)


def prepare_with_effects(run: Run, p: PlantParameters, prep: Prepared, hooks, known_as: str) -> Prepared:
    """``run`` prepared again with its unlogged velocities reconstructed by the nominal plant *plus* ``hooks``.

    A stock run's velocities come from the model-based smoother, whose process model is the nominal plant: where
    an effect acts, the reconstruction leans towards the nominal dynamics. Given effects (a corrected model, or
    the effects a diagnosis attributed), their generalised force along ``prep``'s trajectory
    (:func:`effect_wrench`) is added to the smoother's input, so that the reconstruction follows the corrected
    plant. ``prep`` itself is returned when nothing was reconstructed or there is no effect.
    """
    if prep.smoothed is None or not hooks:
        return prep
    return prepare(run, p, prep.name, prep.window_s, prep.dt, known_wrench=effect_wrench(prep, hooks),
                   known_as=known_as)


def specific_force(eta, nu, nu_dot, g=GRAVITY) -> np.ndarray:
    """(..., 3) accelerometer reading at the body origin, body FRD, m/s^2: ``v_dot + omega x v - R^T [0, 0, g]``
    (the run-log format's definition) of pose ``eta`` (..., 6), velocity ``nu`` (..., 6) and its derivative
    ``nu_dot`` (..., 3 or 6): the smoother's measurement model (:func:`udrobot_ctrl.gap.smoother.accelerometer`)
    on numpy arrays."""
    arrays = [np.asarray(a, float) for a in (eta, nu, nu_dot)]
    out = np.empty(np.broadcast_shapes(*(a.shape[:-1] for a in arrays)) + (3,))
    for i, c in enumerate(accelerometer(NUMPY, *([a[..., j] for j in range(a.shape[-1])] for a in arrays), g)):
        out[..., i] = c
    return out


def simulate_windows(prep: Prepared, p: PlantParameters, hooks=(), window_s=8.0, M_A=None):
    """Multiple-shooting replay of one run; returns (n, :data:`SIM_COLUMNS`): the simulated state (12 columns),
    on runs whose accelerometer is scored (:func:`accel_bias`) its specific force (3, :func:`specific_force` of the
    plant's acceleration at each sample with that sample's command), nan outside windows, and the window column
    (:data:`WINDOW`: which window each sample belongs to, negative after the window diverged).

    Parameters
    ----------
    hooks : sequence of effects.Hooks
        Effects added to the nominal plant.
    """
    return simulate_windows_sets(prep, p, [hooks], window_s)[0]


def simulate_windows_each(preps, p: PlantParameters, hooks=(), window_s=8.0) -> list:
    """:func:`simulate_windows` of each run of ``preps`` with the same effects ``hooks``, in order: the runs integrated
    together (:func:`simulate_windows_runs`), in as many shares as there are workers (:func:`~udrobot_ctrl.parallel.
    workers`; the same numbers whatever their number)."""
    pieces = shares(len(preps), workers())
    done = fork_map(lambda piece: simulate_windows_runs([preps[i] for i in piece], p, [hooks], window_s), pieces)
    out = [None] * len(preps)
    for piece, sims in zip(pieces, done):
        for i, sim in zip(piece, sims):
            out[i] = sim[0]
    return out


def simulate_windows_sets(prep: Prepared, p: PlantParameters, hook_sets, window_s=8.0) -> list:
    """:func:`simulate_windows` of one run for several sets of effects at once: one (n, :data:`SIM_COLUMNS`) array
    per set of ``hook_sets``, each as its own replay gives it.

    The windows of every set are integrated together as one batch (the nominal plant, kinematics and surfaces on all
    of them per step; each set's effects on its own windows), so that replaying the holdout with each candidate
    effect alone costs little more than one replay: the step's fixed cost is paid once, not once per set.
    """
    return simulate_windows_runs([prep], p, hook_sets, window_s)[0]


def batchable(preps, window_s) -> list:
    """The prepared runs ``preps`` in groups (lists of their indices, in order) that :func:`simulate_windows_runs`
    integrates as one batch: runs on the same time step (so the same window length in samples) replayed open loop;
    a closed-loop run (its autopilot emulated, ``Prepared.feedback``) is a group of its own."""
    groups, by_step = [], {}
    for i, pr in enumerate(preps):
        if pr.feedback is not None:
            groups.append([i])
            continue
        key = (float(pr.dt), window_starts(pr, window_s)[1])
        if key not in by_step:
            by_step[key] = []
            groups.append(by_step[key])
        by_step[key].append(i)
    return groups


def simulate_windows_runs(preps, p: PlantParameters, hook_sets, window_s=8.0) -> list:
    """:func:`simulate_windows_sets` of several runs at once: per run, one (n, :data:`SIM_COLUMNS`) array per set of
    ``hook_sets``, each as its own replay gives it (the same numbers: every term is evaluated row by row, and the
    inertia and surface products on each run's rows alone, as a replay of that run alone computes them).

    The runs of one :func:`batchable` group are integrated as one batch: a nominal replay of the few windows of one
    run costs the step's fixed cost more than the windows' arithmetic, and batching the runs pays it once per group
    (the noise floor's synthetic runs, :func:`udrobot_ctrl.gap.locate.noise_floor`).
    """
    out = [None] * len(preps)
    for group in batchable(preps, window_s):
        for i, sims in zip(group, _simulate_batch([preps[i] for i in group], p, hook_sets, window_s)):
            out[i] = sims
    return out


class _Block(NamedTuple):
    """One run's rows of a batch of :func:`_simulate_batch`: its sets' windows, contiguous, set after set."""

    run: int  # its index among the batch's runs
    prep: Prepared
    rows: slice  # its rows of the batch
    starts: np.ndarray  # (N,) its windows' first samples
    f: np.ndarray  # (sets, n, k) its delivered commands per set
    tau: np.ndarray  # (sets, n, 6) their wrench
    set_of: np.ndarray  # (sets N,) the set of each of its rows
    start_of: np.ndarray  # (sets N,) the window start of each of its rows
    groups: list  # per set: (its rows within the block, force hooks, added-mass hooks)
    accel: bool  # its accelerometer is scored (the specific force is stored, :func:`accel_bias`)


def _blocks(preps, hook_sets, window_s) -> list:
    """The :class:`_Block` of each run of ``preps`` that has a window, in order."""
    n_sets, blocks, row = len(hook_sets), [], 0
    for i, pr in enumerate(preps):
        starts, _ = window_starts(pr, window_s)
        N = starts.size
        if N == 0:
            continue
        groups = [(slice(v * N, (v + 1) * N), [h.force for h in hooks if h.force is not None],
                   [h.mass for h in hooks if h.mass is not None]) for v, hooks in enumerate(hook_sets)]
        f = np.stack([delivered_commands(pr, hooks) for hooks in hook_sets])  # (sets, n, k)
        blocks.append(_Block(i, pr, slice(row, row + n_sets * N), starts, f, f @ pr.B.T,
                             np.repeat(np.arange(n_sets), N), np.tile(starts, n_sets), groups,
                             accel_bias(pr) is not None))
        row += n_sets * N
    return blocks


def _simulate_batch(preps, p: PlantParameters, hook_sets, window_s) -> list:
    """:func:`simulate_windows_runs` of one :func:`batchable` group of runs."""
    n_sets = len(hook_sets)
    sims = [np.full((n_sets, pr.n, SIM_COLUMNS), np.nan) for pr in preps]
    blocks = _blocks(preps, hook_sets, window_s) if n_sets else []
    if not blocks:
        return [list(sim) for sim in sims]
    w = window_starts(blocks[0].prep, window_s)[1]
    x = np.concatenate([np.tile(np.concatenate([b.prep.eta[b.starts],
                                                np.where(np.isfinite(b.prep.nu), b.prep.nu, 0.0)[b.starts]], axis=1),
                                (n_sets, 1)) for b in blocks])
    nsub = max(1, int(np.ceil(blocks[0].prep.dt / 0.05)))
    h_dt = blocks[0].prep.dt / nsub
    # else no surface is read (nominal replays)
    hooked = any(h.force is not None or h.mass is not None for hooks in hook_sets for h in hooks)

    def deriv(xx, ks, fk, tk, at_k):
        plant = generalized_forces(xx, p)
        tot = tk - plant
        nd = np.empty_like(tot)
        for b, k, at in zip(blocks, ks, at_k):  # a run's rows alone: its products are those of its own replay
            xb, tb = xx[b.rows], tot[b.rows].copy()
            heavier = []  # (rows, mass matrices) of the sets whose effects add mass
            surfaces = _surface_ctx(b.prep, k, xb, at) if hooked else []
            for rows, forces, masses in b.groups:
                if not (forces or masses):
                    continue
                ctx = {"surfaces": [(dist[rows], normal, label) for dist, normal, label in surfaces],
                       PLANT_FORCES: PlantForces(p, plant[b.rows][rows])}
                for fo in forces:
                    tb[rows] = tb[rows] + fo(xb[rows], fk[b.rows][rows], ctx)
                if masses:
                    heavier.append((rows, p.M + sum(m(xb[rows], ctx) for m in masses)))
            ndb = tb @ p.M_inv.T
            for rows, Mt in heavier:
                ndb[rows] = np.linalg.solve(Mt, tb[rows][..., None])[..., 0]
            nd[b.rows] = ndb
        return np.concatenate([kinematics(xx[:, :6], xx[:, 6:]), nd], axis=1)

    def store_accel(xx, x_dot):  # the specific force of the states just stored, from the plant's x_dot
        sf = None
        for b, rows_b, which_b in zip(blocks, now, which):
            if b.accel:
                sf = specific_force(xx[:, :6], xx[:, 6:], x_dot[:, 6:]) if sf is None else sf
                sims[b.run][b.set_of[which_b], rows_b, 12:WINDOW] = sf[b.rows][which_b]

    def inputs(j):  # per block: command, wrench and surfaces at its windows' sample j (the run's last, beyond it)
        ks = [np.tile(np.minimum(b.starts + j, b.prep.n - 1), n_sets) for b in blocks]
        fk = np.concatenate([b.f[b.set_of, k] for b, k in zip(blocks, ks)])
        tk = np.concatenate([b.tau[b.set_of, k] for b, k in zip(blocks, ks)])
        return fk, tk, ks, [_surfaces_at(b.prep, k) if hooked else None for b, k in zip(blocks, ks)]

    start_of = np.concatenate([b.start_of for b in blocks])
    n_of = np.concatenate([np.full(b.start_of.size, b.prep.n) for b in blocks])
    window_id = np.concatenate([np.tile(np.arange(1, b.starts.size + 1, dtype=float), n_sets) for b in blocks])
    for b in blocks:  # the window column's value of each row: its window's number in its run
        sims[b.run][b.set_of, b.start_of, :12] = x[b.rows]
        sims[b.run][b.set_of, b.start_of, WINDOW] = window_id[b.rows]
    x_start = x[:, :3].copy()
    now = [b.start_of for b in blocks]  # per block: the samples holding its current states, and which states
    which = [np.ones(b.start_of.size, bool) for b in blocks]
    alive = np.ones(len(x), bool)
    fb = blocks[0].prep.feedback  # a closed-loop run is replayed alone (batchable)
    loop = fb.start(len(x)) if fb is not None else None  # the autopilot's attitude loop
    x_meas = np.nan_to_num(blocks[0].prep.state()) if loop is not None else None
    for j in range(1, w):
        fk, tk, ks, at_k = inputs(j - 1)
        if loop is not None:  # closed-loop replay: the loop's reaction to the departure from the measured state
            df = fb.delta_thrust(loop, x, x_meas[ks[0]], ks[0], blocks[0].prep.dt)
            fk, tk = fk + df, tk + df @ blocks[0].prep.B.T

        def step(_t, xx):
            return deriv(xx, ks, fk, tk, at_k)  # noqa: B023 - used within this iteration

        # a window on its way out of the envelope overflows before the check below marks it diverged: its
        # non-finite arithmetic is expected, and scored (the error cap), not warned about
        with np.errstate(over="ignore", invalid="ignore"):
            x_dot = step(0.0, x)  # the first stage of the step is the acceleration the accelerometer reads now
            store_accel(x, x_dot)
            for i_sub in range(nsub):
                x = rk4_step(step, 0.0, x, h_dt, k1=x_dot if i_sub == 0 else None)
        with np.errstate(invalid="ignore"):
            bad = (~np.all(np.isfinite(x), axis=1) | (np.abs(x[:, 6:]).max(axis=1) > VELOCITY_ENVELOPE)
                   | (np.abs(x[:, :3] - x_start).max(axis=1) > POSITION_ENVELOPE))
        alive &= ~bad
        x[bad] = 0.0
        idx = start_of + j
        keep = alive & (idx < n_of)
        dead = ~alive & (idx < n_of)  # the rest of a diverged window: its samples score the error cap
        for i, b in enumerate(blocks):
            sim, kp, dd, ix = sims[b.run], keep[b.rows], dead[b.rows], idx[b.rows]
            sim[b.set_of[kp], ix[kp], :12] = x[b.rows][kp]
            sim[b.set_of[kp], ix[kp], WINDOW] = window_id[b.rows][kp]
            sim[b.set_of[dd], ix[dd], WINDOW] = -window_id[b.rows][dd]
            now[i], which[i] = ix[kp], kp
    if any(b.accel for b in blocks):  # the last sample of each window: its own command
        fk, tk, ks, at_k = inputs(w - 1)
        store_accel(x, deriv(x, ks, fk, tk, at_k))
    return [list(sim) for sim in sims]


def accel_bias(prep: Prepared):
    """(3,) accelerometer bias the smoother estimated for the run (m/s^2), or None: then the accelerometer is not
    scored (its bias cannot be told from a model error)."""
    sm = prep.smoothed
    return sm.accel_bias if sm is not None and np.all(np.isfinite(sm.accel_bias)) else None


def diverged_samples(sim) -> np.ndarray:
    """(n,) True on the samples of a replay after their window diverged (:data:`WINDOW` negative)."""
    if sim.shape[1] <= WINDOW:
        return np.zeros(sim.shape[0], bool)
    with np.errstate(invalid="ignore"):
        return sim[:, WINDOW] < 0


def window_counts(sim) -> tuple:
    """(windows replayed, windows that diverged) of one run's replay, from its window column (:data:`WINDOW`)."""
    if sim.shape[1] <= WINDOW:
        return 0, 0
    ids = sim[:, WINDOW]
    ids = ids[np.isfinite(ids)]
    return int(np.unique(np.abs(ids)).size), int(np.unique(ids[ids < 0]).size)


def _capped(e, meas, dead, cap):
    """The error ``e`` clipped to ``cap``, held at ``cap`` on the diverged samples that have a measurement."""
    e = np.clip(e, -cap, cap)
    e[dead & np.isfinite(meas)] = cap
    return e


def errors(prep: Prepared, sim):
    """Channel -> (sim - meas) (n,) with angle wrapping; only channels logged in the run, the accelerometer where
    its bias is known (:func:`accel_bias`). Each error is clipped to its channel's :data:`ERROR_CAP` and held there
    on the samples after a window diverged (the worst error the channel scores; module docstring)."""
    out = {}
    dead = diverged_samples(sim)
    for c in CHANNELS:
        if c not in prep.meas or not np.isfinite(prep.meas[c]).any():
            continue
        e = sim[:, STATE_INDEX[c]] - prep.meas[c]
        if c in ANGLES:
            e = wrap_angle(e)
        out[c] = _capped(e, prep.meas[c], dead, ERROR_CAP[c])
    bias = accel_bias(prep)
    if bias is not None:
        for j, c in enumerate(ACCEL):
            if c in prep.meas and np.isfinite(prep.meas[c]).any():
                out[c] = _capped(sim[:, 12 + j] - (prep.meas[c] - bias[j]), prep.meas[c], dead, ERROR_CAP[c])
    return out


@dataclass(frozen=True)
class GapScore:
    """The NRMSE gap of replays against runs (see the module docstring).

    Attributes
    ----------
    value : float
        RMS over the scored channels of their NRMSE (nan when no channel is scored).
    per_channel : dict
        Channel -> NRMSE (nan for a constant channel).
    scored : list of str
        Channels in ``value``.
    scale : dict
        Channel -> std of its measurement (the NRMSE's denominator, channel units).
    undefined : dict
        Channel -> why its NRMSE is undefined (e.g. a constant channel).
    windows : dict
        Run name -> windows replayed.
    diverged : dict
        Run name -> windows whose replay diverged (their remaining samples scored at the error cap).
    """

    value: float
    per_channel: dict
    scored: list
    scale: dict
    undefined: dict = field(default_factory=dict)
    metric: str = "nrmse"
    windows: dict = field(default_factory=dict)
    diverged: dict = field(default_factory=dict)
    #: channel -> NRMSE of the model-free baseline on the same samples: the persistence forecast, each window's
    #: measured start held (:func:`persistence_errors`)
    baseline: dict = field(default_factory=dict)

    @property
    def baseline_value(self) -> float:
        """RMS over the scored channels of the baseline's NRMSE (nan when no channel is scored)."""
        use = [self.baseline[c] for c in self.scored if np.isfinite(self.baseline.get(c, np.nan))]
        return float(np.sqrt(np.mean(np.square(use)))) if use else float("nan")

    @property
    def skill(self) -> float:
        """1 - value / baseline_value: above 0 the replays predict the runs better than holding each window's
        measured start; a model that barely moves scores about 0 however small its error, one that departs further
        than holding still below 0."""
        b = self.baseline_value
        return float(1.0 - self.value / b) if b > 0 else float("nan")

    @property
    def n_diverged(self) -> int:
        """Windows that diverged, over all runs."""
        return int(sum(self.diverged.values()))

    def to_json(self) -> dict:
        """The report's ``gap_before`` / ``gap_after`` object."""
        return {"metric": self.metric, "value": self.value, "per_channel": self.per_channel,
                "undefined": self.undefined, "scored": self.scored, "windows": self.windows,
                "diverged_windows": self.diverged,
                "baseline": {"metric": "nrmse of the persistence forecast (each window's measured start held)",
                             "value": self.baseline_value, "per_channel": self.baseline},
                "skill": self.skill}


class LoggedChannel(NamedTuple):
    """What :func:`gap` reads of one logged channel whatever the replay: its finite samples (angles unwrapped) and
    its sensor-noise std (:func:`~udrobot_ctrl.gap.smoother.logged_noise_model`), same units."""

    finite: np.ndarray
    noise: float


_LOGGED: dict = {}  # (channel, id(array)) -> (array, LoggedChannel), see logged_channel
#: logged arrays :func:`logged_channel` keeps at most (the oldest dropped all at once beyond it): a diagnosis's runs
#: times their channels, both reconstruction passes
LOGGED_KEPT = 64


def logged_channel(c: str, m: np.ndarray) -> LoggedChannel:
    """:class:`LoggedChannel` of channel ``c`` logged as ``m`` (n,), kept for the most recent arrays: a diagnosis
    scores every replay of a run against the same logs (the entry holds ``m``, so its id is its own)."""
    hit = _LOGGED.get((c, id(m)))
    if hit is not None and hit[0] is m:
        return hit[1]
    finite = m[np.isfinite(m)]
    out = LoggedChannel(finite if c not in ANGLES else np.unwrap(finite), logged_noise_model(m).sigma)
    if len(_LOGGED) >= LOGGED_KEPT:
        _LOGGED.clear()
    _LOGGED[(c, id(m))] = (m, out)
    return out


def persistence_errors(prep: Prepared, sim) -> dict:
    """Channel -> error of the model-free baseline on the samples of the replay ``sim``'s windows: each window's
    first measured value held through it (angles wrapped), as :func:`errors` gives for the replay (nan outside the
    windows and where the start is not measured)."""
    out = {}
    if sim.shape[1] <= WINDOW:
        return out
    win = np.abs(sim[:, WINDOW])
    ok = np.isfinite(win)
    idx = np.flatnonzero(ok)
    new = np.r_[True, (win[idx][1:] != win[idx][:-1]) | (np.diff(idx) > 1)] if idx.size else np.zeros(0, bool)
    start = np.zeros(win.shape, int)
    start[idx] = idx[new][np.cumsum(new) - 1]
    channels = [c for c in CHANNELS if c in prep.meas] + ([c for c in ACCEL if c in prep.meas]
                                                          if accel_bias(prep) is not None else [])
    for c in channels:
        m = prep.meas[c]
        e = np.full(m.shape, np.nan)
        e[ok] = m[ok] - m[start[ok]]
        if c in ANGLES:
            e = wrap_angle(e)
        out[c] = e
    return out


def gap(preps, sims, scored=None) -> GapScore:
    """NRMSE gap over runs (see the module docstring); ``scored`` fixes the channels (default: those that move)."""
    acc, windows, diverged = {}, {}, {}
    for prep, sim in zip(preps, sims):
        n_win, n_div = window_counts(sim)
        name = getattr(prep, "name", None) or f"run {len(windows)}"
        windows[name] = windows.get(name, 0) + n_win
        diverged[name] = diverged.get(name, 0) + n_div
        base = persistence_errors(prep, sim)
        for c, e in errors(prep, sim).items():
            ok = np.isfinite(e)
            a = acc.setdefault(c, {"se": 0.0, "n": 0, "meas": [], "noise": [], "base": 0.0, "nb": 0})
            a["se"] += float(np.sum(e[ok] ** 2))
            a["n"] += int(ok.sum())
            eb = base.get(c)
            if eb is not None:
                okb = ok & np.isfinite(eb)
                a["base"] += float(np.sum(eb[okb] ** 2))
                a["nb"] += int(okb.sum())
            logged = logged_channel(c, prep.meas[c])
            a["meas"].append(logged.finite)
            a["noise"].append(logged.noise)
    per, scale, auto, undefined, baseline = {}, {}, [], {}, {}
    for c, a in acc.items():
        if a["n"] == 0:
            continue
        allm = np.concatenate(a["meas"])
        sd = float(np.std(allm)) if allm.size > 1 else 0.0
        scale[c] = sd
        per[c] = float(np.sqrt(a["se"] / a["n"]) / sd) if sd > 0 else float("nan")
        baseline[c] = float(np.sqrt(a["base"] / a["nb"]) / sd) if sd > 0 and a["nb"] else float("nan")
        if not sd > 0:
            undefined[c] = "channel constant (standard deviation 0): NRMSE undefined"
        noise = np.nanmedian(a["noise"]) if np.isfinite(a["noise"]).any() else 0.0
        if sd > 3 * noise and sd > 1e-6 and np.isfinite(per[c]):
            auto.append(c)
    use = [c for c in (scored if scored is not None else auto) if c in per and np.isfinite(per[c])]
    value = float(np.sqrt(np.mean([per[c] ** 2 for c in use]))) if use else float("nan")
    return GapScore(value=value, per_channel=per, scored=use, scale=scale, undefined=undefined, windows=windows,
                    diverged=diverged, baseline=baseline)
