"""The diagnoser's gap for any model: multiple-shooting replay of runs through a model with its effects.

``udrobot-ctrl diagnose`` scores a model on the holdout runs with :func:`udrobot_ctrl.gap.shrink.simulate_windows`
(windows of ``window_s`` seconds re-initialised from the measured state, logged commands held) and
:func:`udrobot_ctrl.gap.shrink.gap` (NRMSE per channel, RMS over the scored channels). :func:`windowed_gap` runs
the same two functions on the same prepared runs (:func:`udrobot_ctrl.gap.data.prepare`) for a model file, whose
``effects`` enter the replay through :func:`udrobot_ctrl.gap.effects.plant_hooks`, i.e. the plant's own definitions
(:mod:`udrobot_ctrl.dynamics.effects`), exactly as the diagnoser adds a fitted effect. So replaying the holdout
runs of a report with the corrected model its ``--out-model`` wrote gives the report's ``gap_after`` (up to the
6-decimal rounding of the parameters in the files), and with the nominal model its ``gap_before``.

Runs without a DVL (velocities reconstructed by the model-based smoother) are reconstructed with the model that is
replayed: its effects' force, along the nominal reconstruction, is added to the smoother's input
(:func:`udrobot_ctrl.gap.shrink.prepare_with_effects`), as the diagnoser does for its ``gap_after``. The report's
``gap_before`` of such runs comes from the diagnoser's second pass, whose windows start from states reconstructed
with the first pass's effects; the nominal model's windowed gap here starts from the nominal reconstruction and
differs from it by the reconstruction's change (the report's notes name both passes).

One difference is deliberate: a ``wall_effect`` acts on the planes the *model* defines (the seabed at
``seabed_depth_m`` and its walls, the distance moving with the simulated position), as the plant simulates them,
where the diagnoser uses the run's measured surfaces (logged altitude, sidecar walls). A corrected model holds the
sidecar walls and, as its seabed depth, the median of the runs' z + altitude, so the two differ by the altitude
noise (and the seabed's unevenness) only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from udrobot_ctrl.dynamics.domain import (
    SATURATION_WINDOW_FRACTION,
    DomainCheck,
    domain_check,
    limit_rows,
    thrust_limits,
)
from udrobot_ctrl.dynamics.effects import wall_planes
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.data import Prepared, prepare
from udrobot_ctrl.gap.effects import Actuation, plant_hooks
from udrobot_ctrl.gap.shrink import WINDOW, check_window, gap, prepare_with_effects, segment_runs, simulate_windows
from udrobot_ctrl.vehicle import load_model


@dataclass(frozen=True)
class WindowedGap:
    """Gap of a model on runs, as ``gap_before`` / ``gap_after`` of a ``udrobot-diagnosis/1`` report.

    Attributes
    ----------
    model : str
        Model name.
    effects : tuple of str
        The model's effects that were replayed.
    runs : tuple of str
        Run labels.
    window_s : float
        Multiple-shooting window, s.
    value : float
        RMS of the scored channels' NRMSE (nan when no channel is scored).
    per_channel : dict of str -> float
        NRMSE per logged channel (nan where undefined).
    scored : tuple of str
        Channels in ``value``.
    undefined : dict of str -> str
        Channels whose NRMSE is undefined, and why.
    preps : tuple of Prepared
        The prepared runs.
    sims : tuple of (n, 16) ndarray
        Simulated states, specific force and window column per run (shrink.simulate_windows), nan outside the
        windows.
    windows : dict of str -> int
        Run label -> windows replayed.
    diverged : dict of str -> int
        Run label -> windows whose replay diverged (non-finite, or out of the envelope: their remaining samples
        score the channel's error cap, :data:`udrobot_ctrl.gap.shrink.ERROR_CAP`).
    domain : tuple of WindowDomain
        The windows whose replay left the plant's domain (:func:`domain_windows`; still scored).
    """

    model: str
    effects: tuple
    runs: tuple
    window_s: float
    value: float
    per_channel: dict
    scored: tuple
    undefined: dict
    preps: tuple
    sims: tuple
    windows: dict = field(default_factory=dict)
    diverged: dict = field(default_factory=dict)
    domain: tuple = ()

    def to_dict(self) -> dict:
        """JSON form: the report's gap object (``metric``, ``value``, ``per_channel``, ``undefined``, ``scored``,
        ``windows``, ``diverged_windows``) plus ``model``, ``effects``, ``runs``, ``window_s`` and ``replay_domain``
        (the windows outside the plant's domain, as the report's ``replay_domain.nominal`` entries without ``part``);
        undefined numbers become null."""
        def num(v):
            return float(v) if v is not None and math.isfinite(v) else None
        return {"metric": "nrmse", "value": num(self.value),
                "per_channel": {c: num(v) for c, v in self.per_channel.items()},
                "undefined": dict(self.undefined), "scored": list(self.scored), "windows": dict(self.windows),
                "diverged_windows": dict(self.diverged), "model": self.model,
                "effects": list(self.effects), "runs": list(self.runs), "window_s": self.window_s,
                "replay_domain": [w.to_json() for w in self.domain]}


def model_surfaces(effects, prep: Prepared) -> list:
    """The planes of the model's ``wall_effect`` as :class:`Prepared` surfaces (distance (n,) m from the logged
    pose, unit normal into the water (3,), label); empty without one. The replay moves the distance with the
    simulated position, so the planes are the model's, not the run's."""
    out = []
    for e in effects:
        if e.name == "wall_effect":
            for k, (point, normal) in enumerate(wall_planes(e.params)):  # the seabed first, when given
                n = np.asarray(normal, float)
                out.append(((prep.eta[:, :3] - np.asarray(point, float)) @ n, n, f"plane {k} of the model"))
    return out


def windowed_gap(model, runs, window_s: float = 8.0, names=None, scored=None) -> WindowedGap:
    """Replay ``runs`` through ``model`` in windows of ``window_s`` s and score the NRMSE gap.

    Parameters
    ----------
    model : str, Path or Vehicle
        Any model, with or without ``effects`` (every effect of the catalogue is replayed).
    runs : sequence of Run
        Runs with logged commands (thrust, pwm or a commanded wrench). A run of several segments is replayed as one
        run per segment (:func:`segment_runs`, labelled ``LABEL[segment k]``): no window crosses a cut.
    window_s : float
        Multiple-shooting window, s (the diagnoser's default is 8 s).
    names : sequence of str, optional
        Run labels (default: the runs' file names).
    scored : sequence of str, optional
        Channels to score (default: those that moved above their noise, as the diagnoser chooses).

    Raises
    ------
    ValueError
        If ``window_s`` is not positive, or a run cannot be prepared (too short, inputs not matching the
        model's thrusters; the message names the run).
    """
    window_s = check_window(window_s, (), "windows")
    vehicle = load_model(model)
    p = plant_parameters(vehicle.with_changes(effects=()))  # the nominal; every effect enters through its hooks
    labels = list(names) if names is not None else [
        (r.path.replace("\\", "/").split("/")[-1] if r.path else f"run {i}") for i, r in enumerate(runs)]
    runs, labels = segment_runs(runs, labels)
    preps, sims = [], []
    for run, label in zip(runs, labels):
        prep = prepare(run, p, label)
        planes = model_surfaces(vehicle.effects, prep)
        if planes:
            prep = replace(prep, surfaces=planes)
        hooks = [plant_hooks(e, p, Actuation(prep.B, prep.inflow, prep.f_ref, p.M_A)) for e in vehicle.effects]
        if hooks and prep.smoothed is not None:  # unlogged velocities: reconstructed with this model, as diagnose
            prep = prepare_with_effects(run, p, prep, hooks, " + ".join(e.name for e in vehicle.effects))
            if planes:
                prep = replace(prep, surfaces=planes)
        preps.append(prep)
        sims.append(simulate_windows(prep, p, hooks, window_s))
    check_window(window_s, preps, "windows")
    g = gap(preps, sims, scored)
    return WindowedGap(model=vehicle.name, effects=tuple(e.name for e in vehicle.effects), runs=tuple(labels),
                       window_s=float(window_s), value=g.value, per_channel=g.per_channel,
                       scored=tuple(g.scored), undefined=dict(g.undefined), preps=tuple(preps),
                       sims=tuple(sims), windows=dict(g.windows), diverged=dict(g.diverged),
                       domain=tuple(domain_windows(preps, sims, p, window_s)))


@dataclass(frozen=True)
class WindowDomain:
    """A replay window that left the plant's domain (:func:`udrobot_ctrl.dynamics.domain.domain_check`).

    Attributes
    ----------
    run : str
        Run label.
    window : int
        The window's number in its run (1-based: the replay's window column, :data:`udrobot_ctrl.gap.shrink.WINDOW`).
    t0, t1 : float
        The window's first and last replayed sample, s.
    check : DomainCheck
        Its spans outside the domain (codes and times).
    """

    run: str
    window: int
    t0: float
    t1: float
    check: DomainCheck

    def to_json(self) -> dict:
        """``{"run", "window", "t": [t0, t1], "codes", "spans"}`` (s)."""
        return {"run": self.run, "window": self.window, "t": [round(self.t0, 3), round(self.t1, 3)],
                **self.check.to_json()}


def prep_thrust_limits(prep: Prepared, p) -> tuple:
    """(f_lo, f_hi) N of a prepared run's thrusters (:func:`udrobot_ctrl.dynamics.domain.thrust_limits`): the T-200
    curve's ends at the logged voltage (the model's supply voltage where not logged) for ``pwm`` runs, the model's
    limits for ``thrust`` runs, (None, None) for a commanded wrench."""
    v = prep.meas.get("voltage")
    v = np.full(prep.n, p.supply_voltage) if v is None else np.where(np.isfinite(v), v, p.supply_voltage)
    return thrust_limits(p.f_min, p.f_max, prep.input_kind, v)


def window_domains(prep: Prepared, sim, p, window_s: float) -> list:
    """The windows of one run's multiple-shooting replay ``sim`` (:func:`udrobot_ctrl.gap.shrink.simulate_windows`)
    that leave the plant's domain, each checked on its own samples (a span never crosses windows): above the
    surface, inverted, or a thruster at its limit for at least half the window
    (:data:`udrobot_ctrl.dynamics.domain.SATURATION_WINDOW_FRACTION`). The thrust checked is the command the
    window replays (``prep.f``; on a run replayed closed loop, the logged outputs refreshed by the emulated loop,
    without the loop's reaction to the replay's own departure). Diverged samples are not checked (the gap scores
    them at the error cap already)."""
    ids = np.abs(sim[:, WINDOW]) if sim.shape[1] > WINDOW else np.full(sim.shape[0], np.nan)
    alive = sim[:, WINDOW] > 0 if sim.shape[1] > WINDOW else np.zeros(sim.shape[0], bool)
    lo, hi = prep_thrust_limits(prep, p) if prep.input_kind != "tau" else (None, None)
    out = []
    for k in np.unique(ids[np.isfinite(ids)]).astype(int):
        rows = np.flatnonzero(ids == k)
        live = rows[alive[rows]]
        if live.size == 0:
            continue
        thrust = prep.f[live] if lo is not None else None
        lo_k, hi_k = (None, None) if lo is None else (limit_rows(lo, live), limit_rows(hi, live))
        chk = domain_check(prep.t[live], sim[live, :12], thrust, lo_k, hi_k,
                           saturation_s=SATURATION_WINDOW_FRACTION * window_s)
        if chk:
            out.append(WindowDomain(prep.name, int(k), float(prep.t[rows[0]]), float(prep.t[rows[-1]]), chk))
    return out


def domain_windows(preps, sims, p, window_s: float) -> list:
    """:func:`window_domains` of every run, in order: the windows that left the plant's domain."""
    return [w for prep, sim in zip(preps, sims) for w in window_domains(prep, sim, p, window_s)]
