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

from udrobot_ctrl.dynamics.effects import wall_planes
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.data import Prepared, prepare
from udrobot_ctrl.gap.effects import Actuation, plant_hooks
from udrobot_ctrl.gap.shrink import check_window, gap, prepare_with_effects, segment_runs, simulate_windows
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

    def to_dict(self) -> dict:
        """JSON form: the report's gap object (``metric``, ``value``, ``per_channel``, ``undefined``, ``scored``,
        ``windows``, ``diverged_windows``) plus ``model``, ``effects``, ``runs`` and ``window_s``; undefined numbers
        become null."""
        def num(v):
            return float(v) if v is not None and math.isfinite(v) else None
        return {"metric": "nrmse", "value": num(self.value),
                "per_channel": {c: num(v) for c, v in self.per_channel.items()},
                "undefined": dict(self.undefined), "scored": list(self.scored), "windows": dict(self.windows),
                "diverged_windows": dict(self.diverged), "model": self.model,
                "effects": list(self.effects), "runs": list(self.runs), "window_s": self.window_s}


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
                       sims=tuple(sims), windows=dict(g.windows), diverged=dict(g.diverged))
