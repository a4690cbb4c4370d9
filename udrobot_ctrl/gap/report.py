"""The diagnosis end to end and its ``udrobot-diagnosis/1`` report (docs/formats/diagnosis.md).

:func:`diagnose` reads as its steps, each a small function over named results:

1. :func:`prepare_inputs` -> :class:`Inputs` (nominal plant, effects tested, prepared fit and holdout runs);
2. locate, :func:`locate_gap` -> :class:`Where`: nominal multiple-shooting replays of every run, each channel's
   noise floor and where the gap lies above it (:mod:`udrobot_ctrl.gap.locate`), the nominal holdout gap;
3. fit, :func:`build_stacks` -> :class:`Stacks` and :func:`single_fits`: the equation-error stacks, what the observed
   channels can identify, every effect fitted alone on the fit runs;
4. decide, :func:`table_decision` -> :class:`~udrobot_ctrl.gap.decide.Decision`: the one criterion on the fit runs
   (output-error BIC of the replays of every set the search visits), weights, inclusion probabilities, the named
   effects;
5. score, on the holdout runs only: :func:`chosen_model` -> :class:`Chosen` (``gap_after``) and :func:`shrink_each`
   (each effect alone);
6. report: :func:`effect_verdicts` -> :class:`EffectVerdict` per effect, :func:`verdict_line`, the JSON report.
"""
from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from udrobot_ctrl.dynamics.domain import SATURATION_TOLERANCE, SATURATION_WINDOW_FRACTION
from udrobot_ctrl.dynamics.effects import TETHER_ANCHOR, plant_effect, wall_parameters
from udrobot_ctrl.dynamics.plant import PlantParameters, plant_parameters, require_nominal, rotation_zyx
from udrobot_ctrl.gap import decide, identifiability
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import (
    Attributor,
    Combination,
    DesignStore,
    Selection,
    build_stack,
    finalize,
    refit,
    residual,
)
from udrobot_ctrl.gap.balance import SteadyBalance, balance_lines, steady_balance
from udrobot_ctrl.gap.data import observable, prepare
from udrobot_ctrl.gap.effects import Actuation
from udrobot_ctrl.gap.heading import CURRENT, HeadingCoverage, current_parts, heading_coverage
from udrobot_ctrl.gap.identifiability import Identifiability
from udrobot_ctrl.gap.locate import Located, locate, noise_floor
from udrobot_ctrl.gap.parts import named_parts
from udrobot_ctrl.gap.replay import domain_windows
from udrobot_ctrl.gap.screen import KINDS, UNEXCITED_COMMAND, Unexcited, run_label, screen_runs
from udrobot_ctrl.gap.sets import (
    Replay,
    ReplayCache,
    Replayer,
    fitted_hooks,
    replay_sets,
)
from udrobot_ctrl.gap.shrink import (
    UNITS,
    GapScore,
    check_window,
    gap,
    prepare_with_effects,
    segment_runs,
    simulate_windows_each,
)
from udrobot_ctrl.gap.top_end import TETHER, top_end
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.parallel import Background, fork_map, one_blas_thread
from udrobot_ctrl.vehicle import load_model
from udrobot_files.output import atomic_write

FORMAT = "udrobot-diagnosis/1"


def split_runs(runs, holdout):
    """Fit and holdout runs; without holdout runs, the last run is held out (one run: its last third). A run of
    several segments counts as one run per segment (:func:`~udrobot_ctrl.gap.shrink.segment_runs`, labelled
    ``NAME[segment k]``), each replayed from its own first row.

    Returns (fit runs, holdout runs, note saying which split was made).
    """
    runs = segment_runs(runs)[0]
    holdout = segment_runs(holdout)[0] if holdout else holdout
    if holdout:
        return list(runs), list(holdout), "holdout runs given on the command line"
    if len(runs) >= 2:
        return list(runs[:-1]), [runs[-1]], f"no --holdout: the last run ({run_label(runs[-1])}) is held out"
    r = runs[0]
    cut = r.t[0] + 2.0 / 3.0 * (r.t[-1] - r.t[0])
    a, b = r.t < cut, r.t >= cut

    def part(mask, tag):
        return Run(path=f"{run_label(r)}[{tag}]", t=r.t[mask], channels={c: v[mask] for c, v in r.channels.items()},
                   input_kind=r.input_kind, inputs=r.inputs[mask], extra={c: v[mask] for c, v in r.extra.items()},
                   metadata=r.metadata)
    return [part(a, "first two thirds")], [part(b, "last third")], \
        f"no --holdout and one run: the first two thirds fit, the last third ({cut - r.t[0]:.1f} s on) is held out"


def _clean(v):
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else round(float(v), 6)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    return v


WALL_FRACTION = 0.05


def wall_distances(params, surfaces, eta, p, speed):
    """Distance (m, body origin to surface) below which the fitted wall effect matters, per surface.

    It matters where the extra added mass along the surface normal exceeds ``WALL_FRACTION`` (5 %) of the
    vehicle's mass along that normal (n^T M n, rigid body plus added mass), or where the suction force at
    ``speed`` exceeds 5 % of the nominal surge drag at that speed (D_L u + Q u|u|). With the template's
    exp(-h / lambda) decay, the first gives h = lambda ln(a_m / (0.05 n^T M n)), the second
    h = lambda ln(a_s U^2 / (0.05 drag(U))); 0 when the effect never reaches the fraction.

    Parameters
    ----------
    params : dict
        Fitted ``decay_length_m``, ``added_mass_at_contact_kg``, ``suction_N_s2_per_m2`` and the ``planes_mask``
        of the planes it acts on (:func:`udrobot_ctrl.gap.effects.acts_on`; all of them without one).
    surfaces : dict
        label -> (distances (n,), unit normal (3,) NED) of the fit stack.
    eta : (n, 6) ndarray
        Poses of the fit stack (to express the normals in the body frame).
    p : PlantParameters
    speed : float
        Reference speed along the surface, m/s (the runs' 95th percentile horizontal speed).

    Returns
    -------
    dict label -> {"added_mass_m", "suction_m", "matters_below_m"}
        One entry per plane the effect acts on.
    """
    lam = params.get("decay_length_m", 0.0)
    am, as_ = params.get("added_mass_at_contact_kg", 0.0), params.get("suction_N_s2_per_m2", 0.0)
    drag = float(p.D_L[0, 0] * speed + p.Q[0, 0] * speed ** 2)
    R = rotation_zyx(eta[:, 3], eta[:, 4], eta[:, 5])
    out = {}
    for label, (_dist, normal) in surfaces.items():
        if not fx.acts_on(params.get("planes_mask"), fx.plane_bit(label)):
            continue
        nb = np.einsum("nji,j->ni", R, np.asarray(normal, float))
        m_n = float(np.mean(np.einsum("ni,ij,nj->n", nb, p.M[:3, :3], nb)))
        d_am = lam * math.log(am / (WALL_FRACTION * m_n)) if am > WALL_FRACTION * m_n > 0 else 0.0
        fs = as_ * speed ** 2
        d_s = lam * math.log(fs / (WALL_FRACTION * drag)) if fs > WALL_FRACTION * drag > 0 else 0.0
        out[label] = {"added_mass_m": d_am, "suction_m": d_s, "matters_below_m": max(d_am, d_s)}
    return out


def seabed_depth(runs) -> float | None:
    """Median NED depth of the seabed (z + altitude, m) over the runs that log both; else the sidecars'
    ``seabed_depth`` (their median); else None."""
    values = []
    for r in runs:
        z, alt = r.channels.get("z"), r.channels.get("altitude")
        if z is not None and alt is not None:
            s = np.asarray(z, float) + np.asarray(alt, float)
            values.append(s[np.isfinite(s)])
    values = np.concatenate(values) if values else np.zeros(0)
    if values.size:
        return float(np.median(values))
    meta = [float(r.metadata["seabed_depth"]) for r in runs if (r.metadata or {}).get("seabed_depth") is not None]
    return float(np.median(meta)) if meta else None


def run_walls(runs) -> list:
    """The distinct walls of the runs' sidecars (``walls``: point and normal, NED), in order of appearance, of the
    runs that log x and y (the diagnosis places walls only where the position is known: not dead-reckoned, i.e. not
    marked estimated-unaided in the sidecar)."""
    out = []
    for r in runs:
        logged, _, _ = observable(r)
        if not all(c in logged and np.isfinite(logged[c]).any() for c in ("x", "y")):
            continue
        for w in (r.metadata or {}).get("walls", []) or []:
            wall = {"point": [float(v) for v in w["point"]], "normal": [float(v) for v in w["normal"]]}
            if wall not in out:
                out.append(wall)
    return out


def corrected_model(model, report, runs=()):
    """The model plus the report's significant effects: what ``diagnose --out-model`` writes.

    Parameters
    ----------
    model : str, Path or Vehicle
        The nominal model that was diagnosed.
    report : dict
        A ``udrobot-diagnosis/1`` report.
    runs : sequence of Run
        The diagnosed runs (a significant ``wall_effect`` takes the seabed depth from their z + altitude, or their
        sidecars' ``seabed_depth``, and the walls of their sidecars).

    Returns
    -------
    vehicle : Vehicle
        With ``effects`` (each checked as a model file's entry would be) and their provenance.
    not_placed : dict
        Effect name -> reason, for significant effects the plant cannot carry: a static thrust map (deadband,
        asymmetry, inflow loss) fitted on runs that log a commanded wrench (``tau_*``) acts on the six wrench
        components, not on the model's thrusters. Each is also recorded in the provenance.

    Raises
    ------
    ValueError
        If a significant effect cannot be placed in the plant (a wall effect without a seabed or a wall).
    """
    vehicle = load_model(model)
    added, not_placed = [], {}
    wrench_runs = any(getattr(r, "input_kind", None) == "tau" for r in runs)
    for i, e in enumerate(x for x in report["effects"] if x["significant"]):
        params = dict(e["params"])
        if wrench_runs and e["name"] in ("thruster_deadband", "thruster_asymmetry", "thrust_inflow_loss"):
            not_placed[e["name"]] = ("fitted on runs that log a commanded wrench (tau_*): it acts on the six wrench "
                                     "components, which the plant's thrusters do not expose; fit it on thrust or "
                                     "pwm runs to place it")
            continue
        if e["name"] == "wall_effect":  # the planes the diagnosis saw and fitted it on: the seabed, sidecar walls
            mask = params.pop("planes_mask", None)
            depth = seabed_depth(runs) if fx.acts_on(mask, 0) else None
            walls = [w for i, w in enumerate(run_walls(runs)) if fx.acts_on(mask, i + 1)]
            if depth is None and not walls:
                raise ValueError("wall_effect is significant but the runs give neither an altitude or seabed_depth "
                                 "nor walls it acts on, so the planes the corrected plant needs are unknown; add a "
                                 "seabed_depth_m (or a wall) to the effect by hand")
            if depth is not None:
                params["seabed_depth_m"] = depth
            params.update(wall_parameters(walls))
        added.append(plant_effect({"name": e["name"], "params": params}, f"report effects[{i}] ({e['name']})"))
    prov = dict(vehicle.provenance)
    for e in added:
        prov[f"effects.{e.name}"] = (f"estimated: udrobot-ctrl diagnose, fitted on {', '.join(report['fit_runs'])}, "
                                     f"scored on {', '.join(report['holdout_runs'])} (shrink "
                                     f"{next(x['shrink'] for x in report['effects'] if x['name'] == e.name):.2f})")
    for name, why in not_placed.items():
        prov[f"effects.{name}"] = f"not placed: significant in the diagnosis but {why}"
    names = "+".join(e.name for e in added)
    return vehicle.with_changes(effects=tuple(vehicle.effects) + tuple(added), provenance=prov,
                                name=f"{vehicle.name}+{names}" if added else vehicle.name), not_placed


@dataclass(frozen=True)
class Inputs:
    """What is diagnosed: the nominal plant, the effects to test and the prepared fit and holdout runs."""

    label: str  # the model as the report names it
    p: PlantParameters
    catalogue: dict  # name -> Effect
    names: tuple  # effects tested
    fit: list  # Prepared fit runs
    holdout: list  # Prepared holdout runs
    notes: list  # what preparing the runs did, the split first
    window_s: float  # multiple-shooting window, s
    sources: tuple = ()  # the Run of each prepared run, fit then holdout (to prepare them again)
    #: the designs of this diagnosis by content, shared by its passes (copies made with ``replace`` share it): a
    #: design whose inputs the second reconstruction pass did not change (a thruster map's) is not computed again
    designs: DesignStore = field(default_factory=DesignStore, repr=False, compare=False)

    @property
    def runs(self) -> list:
        return self.fit + self.holdout


@dataclass(frozen=True)
class Where:
    """Step 1, locate: the nominal model's replays of every run, where they disagree, and the holdout gap."""

    nominal_sims: list  # (n, 15) per run (state and specific force), fit runs then holdout runs
    residuals: list  # equation-error residuals (n, 6) per run
    located: Located
    before: GapScore  # nominal gap on the holdout runs


@dataclass(frozen=True)
class Stacks:
    """The equation-error stacks of the fit and holdout runs and the actuation the replays use."""

    fit: Attributor
    holdout: Attributor
    actuation: Actuation
    identifiability: Identifiability  # what the observed channels can identify (all of it with every DOF measured)
    #: this pass's recent replays (:func:`_replayer`); copies made with ``replace`` share it
    replays: ReplayCache = field(default_factory=ReplayCache, repr=False, compare=False)


#: why an effect is not significant (the report's ``evidence.code``; rendered as sentences by :func:`reason_text`)
NOT_SELECTED = "not_selected"  # outside the set the criterion prefers
UNIDENTIFIABLE = "unidentifiable"  # the observed channels cannot identify it: not searched
LOOKALIKE = "lookalike"  # in the best set, but the data do not split its weight from a rival's
REASON_CODES = (NOT_SELECTED, UNIDENTIFIABLE, decide.AT_BOUND, decide.INCLUSION_LOW, LOOKALIKE)


@dataclass(frozen=True)
class Evidence:
    """Why an effect is (not) significant, from the selection table (:mod:`udrobot_ctrl.gap.decide`).

    Attributes
    ----------
    delta_bic : float
        The criterion of the effect alone minus the nominal model's, on the fit runs (nan when not searched).
    inclusion_probability : float
        Summed weight of the table's sets that hold it (0 when in none, nan when not searched).
    code : str or None
        None when significant, else one of :data:`REASON_CODES`.
    rivals : tuple of str
        Effects whose swap for it the data cannot tell apart (``code`` ``lookalike``).
    """

    delta_bic: float
    inclusion_probability: float
    code: str | None = None
    rivals: tuple = ()

    def to_json(self) -> dict:
        out = {"delta_bic": self.delta_bic, "inclusion_probability": self.inclusion_probability, "code": self.code}
        if self.rivals:
            out["rivals"] = list(self.rivals)
        return out


@dataclass(frozen=True)
class EffectVerdict:
    """One tested effect in the report."""

    name: str
    significant: bool
    params: dict  # fitted parameters (significant effects; empty otherwise)
    shrink: float  # 1 - holdout gap with the effect alone / gap_before
    evidence: Evidence
    meaning: str
    scope: str = "vehicle"  # "vehicle" (one parameter set for every dive) or "dive" (:data:`DIVE_SCOPED`)
    fitted_params_if_added: dict | None = None
    indistinguishable_from: tuple = ()  # (name, manoeuvre that separates them)
    wall: dict | None = None  # wall_effect only: {"matters_below_m", "matters_below"}
    not_identified: dict | None = None  # partly identified effects: {"params": [...], "reason": ...}
    at_bound: dict | None = None  # parameter -> (value, bound) of a best-set fit that ended on a bound
    replay_diverged_windows: int = 0  # holdout windows its single-effect replay diverged in
    #: tether_drag only: where its fitted top end lies (:class:`udrobot_ctrl.gap.top_end.TopEnd`)
    top_end: dict | None = None

    def to_json(self) -> dict:
        out = {"name": self.name, "significant": self.significant, "params": self.params, "shrink": self.shrink,
               "evidence": self.evidence.to_json(), "meaning": self.meaning, "scope": self.scope,
               "inclusion_probability": self.evidence.inclusion_probability}
        if self.fitted_params_if_added is not None:
            out["fitted_params_if_added"] = self.fitted_params_if_added
        if self.indistinguishable_from:
            out["indistinguishable_from"] = [{"name": a, "manoeuvre": m} for a, m in self.indistinguishable_from]
        if self.wall:
            out.update(self.wall)
        if self.not_identified:
            out["not_identified"] = self.not_identified
        if self.at_bound:
            out["at_bound"] = {k: {"value": v, "bound": b} for k, (v, b) in self.at_bound.items()}
        if self.top_end:
            out["top_end"] = self.top_end
        if self.replay_diverged_windows:
            out["replay_diverged_windows"] = self.replay_diverged_windows
        return out


#: effects whose parameters belong to a dive, not to the vehicle (the spec's ``scope``): what changes from dive to
#: dive (a current, a tether and its paid-out length, the trim with a payload, the walls nearby)
DIVE_SCOPED = ("water_current", "tether_drag", "buoyancy_offset", "wall_effect")


@dataclass(frozen=True)
class DiagnosisContext:
    """What the figures need besides the report (:func:`udrobot_ctrl.gap.plots.write_plots`)."""

    preps: list  # Prepared runs, fit then holdout
    n_fit: int
    nominal_sims: list
    after_sims: list  # holdout replays with the significant effects
    residuals: list
    location: list  # the report's location entries


def prepare_inputs(model, runs, holdout, effects, window_s, model_label=None) -> Inputs:
    """Load the nominal model, check the effect names, split and prepare the runs."""
    vehicle = load_model(model)
    p = plant_parameters(vehicle)
    require_nominal(p, "the diagnoser (it fits effects on top of the plant; a model's parameter effects are "
                       "folded in, its thrust, lag and force effects are not), so diagnose the model without them")
    cat = fx.catalogue()
    names = tuple(effects or fx.EFFECT_NAMES)
    for n in names:
        if n not in cat:
            raise ValueError(f"unknown effect {n!r}; the catalogue is {', '.join(fx.EFFECT_NAMES)}")
    fit_runs, ho_runs, split_note = split_runs(runs, holdout)
    preps = fork_map(lambda r: prepare(r, p, run_label(r)), [*fit_runs, *ho_runs], warm=True)  # a smoother each
    fit_p, ho_p = preps[:len(fit_runs)], preps[len(fit_runs):]
    window_s = check_window(window_s, ho_p or fit_p)
    label = model_label or (str(model) if not hasattr(model, "name") else model.name)
    return Inputs(label, p, cat, names, fit_p, ho_p, [split_note] + [n for pr in fit_p + ho_p for n in pr.notes],
                  window_s, tuple(fit_runs) + tuple(ho_runs))


def reconstructed(inp: Inputs) -> bool:
    """True when the smoother reconstructed some velocity of some run (a run without DVL)."""
    return any(pr.smoothed is not None for pr in inp.runs)


def reconstruct_with(inp: Inputs, actuation: Actuation, fit, members, which: str = "all") -> Inputs:
    """``inp`` with its runs prepared again, the unlogged velocities reconstructed by the nominal plant plus the
    ``members`` of ``fit`` (:func:`udrobot_ctrl.gap.shrink.prepare_with_effects`, along the nominal
    reconstruction); ``which``: ``"all"`` runs or only the ``"holdout"`` runs."""
    hooks = fitted_hooks(inp.catalogue, inp.p, actuation, fit, members)
    known = " + ".join(members)
    n_fit = len(inp.fit)
    again = [i for i in range(len(inp.runs)) if which == "all" or i >= n_fit]
    preps = list(inp.runs)
    for i, pr in zip(again, fork_map(lambda i: prepare_with_effects(inp.sources[i], inp.p, inp.runs[i], hooks, known),
                                     again, warm=True)):
        preps[i] = pr
    return replace(inp, fit=preps[:n_fit], holdout=preps[n_fit:],
                   notes=inp.notes[:1] + [n for pr in preps for n in pr.notes])


def locate_gap(inp: Inputs) -> Where:
    """Nominal multiple-shooting replays of every run (the nominal model is fitted to nothing), their noise floor,
    where the gap lies above it, and the nominal holdout gap."""
    runs = inp.runs
    sims = simulate_windows_each(runs, inp.p, (), inp.window_s)
    scale = gap(runs, sims).scale
    floor = noise_floor(runs, sims, inp.p, inp.window_s, scale)
    residuals = [residual(pr, inp.p) for pr in runs]
    located = locate(runs, sims, scale, floor, residuals, inp.p)
    return Where(sims, residuals, located, gap(inp.holdout, sims[len(inp.fit):]))


def build_stacks(inp: Inputs) -> Stacks:
    """Equation-error stacks of the fit and holdout runs, scored on the DOFs both observe, and what those observed
    channels can identify (:func:`udrobot_ctrl.gap.identifiability.assess`): the fits use the catalogue with each
    partly identified effect's unidentified parameters frozen."""
    M_A = np.asarray(inp.p.M_A, float)
    st, r, dofs = build_stack(inp.fit, inp.p, M_A)
    st_h, r_h, dofs_h = build_stack(inp.holdout, inp.p, M_A)
    probed = {}
    ident = identifiability.assess(st, r, dofs & dofs_h, inp.fit, inp.catalogue, inp.names, designs=probed,
                                   store=inp.designs)
    cat = ident.restrict(inp.catalogue)
    att = Attributor(st, r, dofs & dofs_h, cat, store=inp.designs)
    # the probes' designs of the effects fitted as they are (not restricted) are the fits' own: not computed again
    att.keep_designs({k: d for k, d in probed.items() if cat[k[0]] is inp.catalogue[k[0]]})
    att_h = Attributor(st_h, r_h, dofs & dofs_h, cat, store=inp.designs)
    h0 = inp.holdout[0]
    return Stacks(att, att_h, Actuation(h0.B, h0.inflow, st.f_ref, M_A), ident)


def _replayer(inp: Inputs, stacks: Stacks, scored, runs=None) -> Replayer:
    """The :class:`~udrobot_ctrl.gap.sets.Replayer` of fitted effect sets on ``runs`` (default: the holdout)."""
    runs = inp.holdout if runs is None else runs
    return Replayer(lambda sets: replay_sets(runs, inp.p, sets, inp.catalogue, stacks.actuation, inp.window_s, scored,
                                             cache=stacks.replays))


class OnDemand(Mapping):
    """A read-only mapping whose values for ``keys`` are computed when first read and kept: ``compute(keys) ->
    {key: value}`` for the keys still missing, all of them at once when the values are iterated
    (:meth:`fill`; a stock diagnosis's first reconstruction pass needs the replays of its candidates only, the
    report those of every effect, replayed together)."""

    def __init__(self, keys, compute, pending=None):
        self._keys, self._compute, self._values = tuple(keys), compute, {}
        self._pending = pending  # (keys, Background job computing {key: value} for them), or None

    def fill(self, keys) -> None:
        """Compute the values of ``keys`` not computed yet, together (those a pending job computes: its result)."""
        missing = [k for k in dict.fromkeys(keys) if k not in self._values]
        unknown = [k for k in missing if k not in self._keys]
        if unknown:
            raise KeyError(unknown[0])
        if self._pending is not None and any(k in self._pending[0] for k in missing):
            job, self._pending = self._pending[1], None
            self._values.update({k: v for k, v in job.result().items() if k not in self._values})
            missing = [k for k in missing if k not in self._values]
        if missing:
            self._values.update(self._compute(missing))

    def __getitem__(self, key):
        self.fill((key,))
        return self._values[key]

    def __iter__(self):
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def items(self):
        self.fill(self._keys)
        return super().items()

    def values(self):
        self.fill(self._keys)
        return super().values()


def shrink_each(inp: Inputs, stacks: Stacks, sel: Selection, before: GapScore) -> OnDemand:
    """Shrink, scored on the holdout only: name -> holdout :class:`~udrobot_ctrl.gap.sets.Replay` with the effect
    alone (its single fit on the fit runs), replayed together when first read (:class:`OnDemand`); its shrink is
    1 - replay gap / gap_before. It chooses nothing."""
    run = _replayer(inp, stacks, before.scored)

    def replays(names):
        return dict(zip(names, run.many([(sel.singles[n], (n,)) for n in names])))
    return OnDemand(inp.names, replays)


def _wall_entry(params, stack, p) -> dict:
    """``matters_below_m`` and ``matters_below`` of a significant wall effect (see :func:`wall_distances`)."""
    speed95 = float(np.nanpercentile(np.hypot(stack.nu[:, 0], stack.nu[:, 1]), 95))
    per = wall_distances(params, stack.surfaces, stack.eta, p, speed95)
    return {"matters_below_m": max([v["matters_below_m"] for v in per.values()], default=0.0),
            "planes": list(per),
            "matters_below": {
                "criterion": f"extra added mass along the normal > {100 * WALL_FRACTION:g}% of the vehicle's "
                             f"mass along it, or suction at {speed95:.2f} m/s (95th percentile horizontal "
                             f"speed) > {100 * WALL_FRACTION:g}% of the nominal surge drag at that speed",
                "distance": "from the body origin to the surface, m",
                "per_surface": per}}


@dataclass(frozen=True)
class Chosen:
    """The model the table chose, fitted on the fit runs, and its one replay of the holdout runs (``gap_after``).

    Attributes
    ----------
    kept : tuple of str
        The named effects.
    combination : Combination
        Their joint fit on the fit runs (equation error) and its residual noise per DOF.
    after : Replay
        The holdout replay with them (the nominal replay when none is named).
    """

    kept: tuple
    combination: Combination
    after: Replay


def effect_code(n, dec: decide.Decision, ident: Identifiability, named) -> str | None:
    """The reason code of effect ``n`` (:data:`REASON_CODES`; None when named)."""
    if n in named:
        return None
    if n in dec.not_named:
        nn = dec.not_named[n]
        return LOOKALIKE if nn.code == decide.INCLUSION_LOW and nn.rivals else nn.code
    if n in ident.names:
        return UNIDENTIFIABLE
    return NOT_SELECTED


def effect_verdicts(inp: Inputs, stacks: Stacks, sel: Selection, dec: decide.Decision, chosen: Chosen,
                    shrink: Mapping, singles: Mapping) -> list:
    """Step 4, report: one :class:`EffectVerdict` per tested effect, the named ones first (by shrink), then the
    other members of the best set, then the rest by inclusion probability and shrink. ``shrink`` (name -> holdout
    shrink of the effect alone) and ``singles`` (name -> its single-effect holdout Replay) only score: they choose
    nothing."""
    kept, combo, best = chosen.kept, chosen.combination, dec.best
    shrink = dict(shrink.items())  # every effect's (an OnDemand replays the missing ones together)
    diverged = {n: singles[n].gap.n_diverged for n in inp.names}
    order = sorted(kept, key=lambda n: -shrink[n]) + sorted(
        [n for n in inp.names if n not in kept],
        key=lambda n: (n not in best.members, -dec.inclusion.get(n, 0.0), -shrink[n]))
    out = []
    for n in order:
        significant = n in kept
        code = effect_code(n, dec, stacks.identifiability, kept)
        nn = dec.not_named.get(n)
        ev = Evidence(dec.single_delta_bic.get(n, float("nan")), dec.inclusion.get(n, float("nan")), code,
                      nn.rivals if nn is not None else ())
        rivals = nn.rivals if nn is not None else ()
        shown = (combo.fit.params[n] if significant else best.fit.params[n] if n in best.members
                 else sel.singles[n].params[n])
        bound = nn.params_at_bound if nn is not None and nn.params_at_bound else None
        end = top_end(shown, stacks.fit.s.eta[:, :3], bound is not None and TETHER_ANCHOR[2] in bound) \
            if n == TETHER else None
        out.append(EffectVerdict(
            name=n, significant=significant, params=shown if significant else {}, shrink=shrink[n],
            evidence=ev, meaning=inp.catalogue[n].meaning, scope="dive" if n in DIVE_SCOPED else "vehicle",
            fitted_params_if_added=None if significant else shown,
            indistinguishable_from=tuple((a, fx.discriminating_manoeuvre(n, a)) for a in rivals),
            wall=_wall_entry(combo.fit.params[n], stacks.fit.s, inp.p) if significant and n == "wall_effect"
            else None, not_identified=stacks.identifiability.entry(n).get("not_identified"),
            at_bound=bound, replay_diverged_windows=diverged.get(n, 0),
            top_end=end.to_json() if end is not None else None))
    return out


def reason_text(code, inclusion_probability=None, rivals=()) -> str:
    """Why an effect is not significant, in a few words, from its reason code (:data:`REASON_CODES`; the console
    only: the report holds the code and its fields)."""
    if code == decide.AT_BOUND:
        return "its fit ends at the edge of its physical range (the catalogue's form does not fit: a missing term)"
    if code == LOOKALIKE:
        return (f"the fit runs cannot split its weight from {' or '.join(rivals)} (inclusion probability "
                f"{_num(inclusion_probability, '.2f')})")
    if code == decide.INCLUSION_LOW:
        return (f"in the best set, but with an inclusion probability of {_num(inclusion_probability, '.2f')} (below "
                f"{decide.P_NAMED:g})")
    if code == UNIDENTIFIABLE:
        return "listed under unidentifiable"
    return "outside the set the fit runs' likelihood prefers"


def verdict_line(kept, n_tested, before: GapScore, unexplained, verdicts=()) -> str:
    """The report's one-line verdict (also the console's last word on significance): the named effects, how much
    of the gap remains, and the members of the best set not named, with why."""
    if not before.scored:
        const = ", ".join(before.undefined) or "none"
        line = (f"gap undefined: no measured channel varies above its noise (constant channels: {const}), so "
                f"there is nothing to score; fly a manoeuvre that excites the channels")
    elif kept:
        line = f"significant: {len(kept)} of {n_tested} effects tested ({', '.join(kept)})"
    else:
        line = f"no catalogue effect explains the gap significantly ({n_tested} effects tested)"
    if kept and unexplained > 0.5:
        line += f"; {100 * unexplained:.0f}% of the gap remains unexplained"
    elif not kept and before.value > 0:
        line += f" (gap {before.value:.3f} stays unexplained)"
    held = [v for v in verdicts if not v.significant and v.evidence.code in (decide.AT_BOUND, decide.INCLUSION_LOW,
                                                                               LOOKALIKE)]
    if held and before.scored:
        line += "; not named: " + "; ".join(
            f"{v.name} ({reason_text(v.evidence.code, v.evidence.inclusion_probability, v.evidence.rivals)})"
            for v in held)
    return line


def _method(window_s) -> dict:
    return {
        "gap": f"NRMSE of multiple-shooting replays ({window_s:g} s windows from the measured state, logged "
               f"commands held), RMS over the scored channels; channel scale = std of the measurement; beside it "
               f"the model-free baseline (each window's measured start held) and the skill 1 - gap / baseline",
        "location": "channels ranked by their share of the excess of NRMSE^2 over the channel's noise floor "
                    "(the nominal replay re-measured with each channel's noise and replayed from noisy starts)",
        "fit": "equation error on residual generalised forces from Savitzky-Golay velocities, "
               "per-DOF noise variances estimated from the data",
        "significance": f"{decide.CRITERION}; every set the search visits is scored, weights exp(-dBIC/2); an "
                        f"effect is named when it is in the best set, its inclusion probability is at least "
                        f"{decide.P_NAMED:g} and no parameter of it ends on a bound; the holdout runs only score "
                        f"the chosen model",
    }


#: channel -> the rotational axis (0 roll, 1 pitch, 2 yaw) whose autopilot loop a closed-loop replay closes
LOOP_AXIS = {"phi": 0, "p": 0, "theta": 1, "q": 1, "psi": 2, "r": 2}
#: the console names the channels holding the gap after, largest first, until they hold this share of it
REMAINING_SHOWN = 0.8


@dataclass(frozen=True)
class Remaining:
    """One scored channel's part of the holdout gap that the significant effects leave (the report's ``remaining``):
    the NRMSE back in the channel's units, so that a large NRMSE of a channel that hardly moved (a regulated attitude,
    a steady transect's sway) reads as the small error it is.

    Attributes
    ----------
    channel : str
        Run-log channel name.
    share : float
        Its share of the gap after's summed NRMSE^2 (the shares sum to 1 over the scored channels).
    nrmse : float
        Its holdout NRMSE after.
    rms_error : float
        Its replay's RMS error on the holdout runs, channel units (``nrmse * spread``).
    spread : float
        Standard deviation of its measurement on the holdout runs (the NRMSE's denominator), channel units.
    floor : float
        Its replay noise floor (the NRMSE the nominal model scores from measurement noise, initial-state error and
        passive modes alone); nan without one.
    closed_loop : float
        Share of the holdout samples on which the replay closed the vehicle's autopilot around this channel's axis
        (0: replayed open loop).
    unit : str
        The channel's unit (SI).
    """

    channel: str
    share: float
    nrmse: float
    rms_error: float
    spread: float
    floor: float
    closed_loop: float
    unit: str

    def to_json(self) -> dict:
        return asdict(self)


def closed_loop_shares(holdout) -> dict:
    """Channel -> share of the samples of the prepared ``holdout`` runs on which the replay closed the autopilot's
    loop around the channel's axis (:data:`LOOP_AXIS`; its ``feedback``'s ``axes`` and ``stabilised`` samples)."""
    n = sum(pr.n for pr in holdout)
    out = {}
    for c, axis in LOOP_AXIS.items():
        closed = sum(float(np.count_nonzero(pr.feedback.stabilised)) for pr in holdout
                     if pr.feedback is not None and pr.feedback.axes[axis])
        out[c] = closed / n if n else 0.0
    return out


def remaining_gap(after: GapScore, floor: Mapping, closed: Mapping) -> list:
    """The gap ``after`` the significant effects, channel by channel, largest share first (:class:`Remaining`).

    Parameters
    ----------
    after : GapScore
        The holdout gap with the significant effects (the nominal's when none is significant).
    floor : mapping
        Channel -> replay noise floor (NRMSE).
    closed : mapping
        Channel -> share of the holdout samples replayed in closed loop (:func:`closed_loop_shares`).

    Returns
    -------
    list of Remaining
        One per scored channel with a finite NRMSE.
    """
    chans = [c for c in after.scored if np.isfinite(after.per_channel.get(c, np.nan))]
    total = sum(after.per_channel[c] ** 2 for c in chans)
    out = [Remaining(c, after.per_channel[c] ** 2 / total if total > 0 else 0.0, after.per_channel[c],
                     after.per_channel[c] * after.scale.get(c, np.nan), after.scale.get(c, np.nan),
                     floor.get(c, np.nan), closed.get(c, 0.0), UNITS.get(c, ""))
           for c in chans]
    return sorted(out, key=lambda r: -r.share)


def remaining_line(remaining) -> str | None:
    """The console's account of the gap after: the channels holding ``REMAINING_SHOWN`` of it (report
    ``remaining`` entries), each with its RMS error in its units against its measured spread."""
    shown, held = [], 0.0
    for r in remaining:
        if held >= REMAINING_SHOWN or r["share"] is None:
            break
        held += r["share"]
        loop = "; replayed in closed loop" if (r["closed_loop"] or 0) > 0.5 else ""
        shown.append(f"{r['channel']} {100 * r['share']:.0f}% (RMS error {_num(r['rms_error'], '.3g')} "
                     f"{r['unit']} against a measured spread of {_num(r['spread'], '.3g')} {r['unit']}, NRMSE "
                     f"{_num(r['nrmse'], '.2f')}, floor {_num(r['floor'], '.2g')}{loop})")
    return ("  what remains: " + ", ".join(shown)) if shown else None


def ranked_like(listed, verdicts) -> list:
    """The ``unidentifiable`` entries (``{"name", "reason"}``) in the order of the ranked ``effects`` (most of the
    holdout gap explained first), so that a long list (stock channels that confirm nothing leave most of the
    catalogue not excluded) opens with what the runs support most; names without a verdict keep their order, last."""
    rank = {v.name: i for i, v in enumerate(verdicts)}
    return sorted(listed, key=lambda e: rank.get(e["name"], len(rank)))


def headings_and_currents(inp: Inputs, stacks: Stacks, sel: Selection) -> HeadingCoverage | None:
    """The report's ``heading_coverage``: the headings of the fit and holdout runs and, when the channels identify
    every parameter of a steady current and the diagnosis fitted one, that current fitted on each part apart
    (:mod:`udrobot_ctrl.gap.heading`)."""
    hc = heading_coverage(inp.fit, inp.holdout)
    known = stacks.identifiability.effects.get(CURRENT)
    if hc is None or CURRENT not in sel.singles or known is None or not known.identified or known.not_identified:
        return hc
    return replace(hc, currents=current_parts(stacks.holdout, sel.singles[CURRENT], hc))


def balance_of(inp: Inputs, where: Where, stacks: Stacks, chosen: Chosen) -> SteadyBalance:
    """The report's ``steady_balance`` (:mod:`udrobot_ctrl.gap.balance`): the fit and holdout runs' steady flight
    with the nominal residuals of step 1 and the named effects' force."""
    hooks = (fitted_hooks(inp.catalogue, inp.p, stacks.actuation, chosen.combination.fit, chosen.kept)
             if chosen.kept else ())
    n_fit = len(inp.fit)
    return steady_balance(inp.fit, inp.holdout, where.residuals[:n_fit], where.residuals[n_fit:], hooks, chosen.kept)


def report_json(inp: Inputs, where: Where, stacks: Stacks, sel: Selection, dec: decide.Decision, chosen: Chosen,
                verdicts, verdict, elapsed_s) -> dict:
    """The ``udrobot-diagnosis/1`` report (docs/formats/diagnosis.md) of the diagnosis' steps (not yet rounded)."""
    before, after = where.before, chosen.after.gap
    return {
        "format": FORMAT,
        "model": inp.label,
        "fit_runs": [pr.name for pr in inp.fit],
        "holdout_runs": [pr.name for pr in inp.holdout],
        "gap_before": before.to_json(),
        "location": [x.to_json() for x in where.located.locations],
        "effects": [v.to_json() for v in verdicts],
        "selection": dec.to_json(),
        "unidentifiable": ranked_like(stacks.identifiability.report(), verdicts),
        "sensors": identifiability.sensors(inp.runs),
        "gap_after": after.to_json() | {"scored": before.scored},
        "unexplained": (after.value / before.value) if before.value > 0 else float("nan"),
        "remaining": [r.to_json() for r in remaining_gap(after, where.located.floor,
                                                          closed_loop_shares(inp.holdout))],
        "steady_balance": balance_of(inp, where, stacks, chosen).to_json(),
        "heading_coverage": (hc.to_json() if (hc := headings_and_currents(inp, stacks, sel)) is not None else None),
        "parts": (pt.to_json() if (pt := named_parts(stacks.holdout, chosen.combination.fit, list(chosen.kept)))
                  else None),
        "verdict": verdict,
        "location_detail": where.located.detail_json(),
        "noise": {"tau_int_samples": sel.tau_int, "n_eff": sel.n_eff, "n_samples": stacks.fit.N,
                  "sigma_residual_per_dof": dict(zip(fx.DOF, chosen.combination.noise_sigma))},
        "method": _method(inp.window_s) | {"split": inp.notes[0]},
        "notes": inp.notes,
        "elapsed_s": elapsed_s,
    }


def _where_line(x) -> str:
    """One located channel for the console: its share of the excess, and its replay NRMSE against the floor when
    the channel is logged (a DOF ranked by its residual force may have no logged velocity channel)."""
    replay = (f"; replay NRMSE {_num(x.nrmse, '.3g')}, floor {_num(x.floor, '.3g')}"
              if x.nrmse is not None and math.isfinite(x.nrmse) else "; channel not logged: ranked by its force")
    return f"{x.channel} ({100 * x.share:.0f}% of the excess over the noise floor{replay})"


def diagnose(model, runs, holdout=None, window_s=8.0, effects=None, log=None, model_label=None):
    """Run the whole diagnosis: locate -> attribute -> shrink and confirm -> report.

    Parameters
    ----------
    model : str, Path or Vehicle
        Nominal model.
    runs : list of Run
        Fit runs (positional runs of the CLI).
    holdout : list of Run, optional
        Runs used only to score.
    window_s : float
        Multiple-shooting window, s.
    effects : list of str, optional
        Catalogue subset to test (default: all).
    log : callable, optional
        Receives the progress lines (the console story: candidates, holdout check, significant set).
    model_label : str, optional
        The model's name in the report.

    Returns
    -------
    report : dict
        The ``udrobot-diagnosis/1`` report (JSON-ready).
    ctx : DiagnosisContext
        What the figures need.

    Notes
    -----
    BLAS runs on one thread throughout (:func:`~udrobot_ctrl.parallel.one_blas_thread`): the work is spread over
    worker processes instead, and the report does not depend on how many there are.
    """
    with one_blas_thread():
        return _diagnose(model, runs, holdout, window_s, effects, log, model_label)


def _diagnose(model, runs, holdout, window_s, effects, log, model_label):
    """:func:`diagnose` computed."""
    t0 = time.perf_counter()
    say = log or (lambda s: None)
    why = screen_runs([*runs, *(holdout or [])], plant_parameters(load_model(model)))  # per run, why not diagnosed
    skipped = [u for reasons in why for u in reasons]
    for u in skipped:
        say(f"not diagnosed: {u.reason()}")
    if skipped:
        fit_x = [r for r, reasons in zip(runs, why) if not reasons]
        hold_x = [r for r, reasons in zip(holdout or [], why[len(runs):]) if not reasons]
        if not fit_x and not hold_x:
            return not_diagnosed_report(model, runs, holdout or [], skipped, model_label, time.perf_counter() - t0)
        runs, holdout = (fit_x, hold_x) if fit_x and hold_x else (fit_x + hold_x, None)
    inp = prepare_inputs(model, runs, holdout, effects, window_s, model_label)
    say(f"prepared {len(inp.fit)} fit and {len(inp.holdout)} holdout runs ({time.perf_counter() - t0:.1f} s)")
    for note in dict.fromkeys(n.split(" (", 1)[0] for n in inp.notes if n.startswith("replay: ")):
        say(f"{note}: the vehicle's autopilot emulated in the replay windows (the report's notes say why)"
            if "closed loop" in note else note)

    # the nominal replays and their noise floor in a worker while the fits run (the console story keeps its order)
    locating = Background(lambda: locate_gap(inp))
    stacks = build_stacks(inp)
    ident = stacks.identifiability
    # the effects the runs cannot identify are fitted in a helper process, beside the others' fits
    stacks.fit.delegate(ident.names)
    try:
        sel = single_fits(stacks, inp.names)
        where = locating.result()
        say("where: " + (", ".join(_where_line(x) for x in where.located.locations)
                         or "no channel above its noise floor"))
        if ident.names:
            say(f"not identifiable from the observed channels ({', '.join(ident.observed_dofs())}): "
                f"{', '.join(ident.names)} (not searched; see the report's unidentifiable list)")
        dec = table_decision(inp, stacks, where, sel.singles, log=say)
    finally:
        stacks.fit.delegate(())
    say(f"selection: best {{{', '.join(dec.best.members) or 'nominal'}}}, named "
        f"{', '.join(dec.named) or 'none'} ({time.perf_counter() - t0:.1f} s)")
    stacks = replace(stacks, identifiability=ident.with_ambiguous(
        {n: nn.rivals for n, nn in dec.not_named.items() if nn.rivals}))

    chosen = chosen_model(inp, stacks, where, dec)
    singles = shrink_each(inp, stacks, sel, where.before)
    b = where.before.value
    shrink = OnDemand(inp.names, lambda names: {n: (1 - singles[n].gap.value / b) if b > 0 else 0.0 for n in names})
    after = chosen.after.gap
    unexplained = (after.value / where.before.value) if where.before.value > 0 else float("nan")
    verdicts = effect_verdicts(inp, stacks, sel, dec, chosen, shrink, singles)
    verdict = verdict_line(chosen.kept, len(inp.names), where.before, unexplained, verdicts=verdicts)
    after_sims = chosen.after.sims if chosen.kept else where.nominal_sims[len(inp.fit):]
    domain = replay_domain(inp, where.nominal_sims, after_sims if chosen.kept else None)
    verdict += domain_caveat(domain)
    say(f"{verdict} ({time.perf_counter() - t0:.1f} s)")

    location = [x.to_json() for x in where.located.locations]
    inp = replace(inp, notes=inp.notes + _not_diagnosed_notes(skipped))
    report = report_json(inp, where, stacks, sel, dec, chosen, verdicts, verdict, time.perf_counter() - t0)
    report.update(_not_diagnosed_fields(skipped))
    report["replay_domain"] = domain
    ctx = DiagnosisContext(inp.runs, len(inp.fit), where.nominal_sims, after_sims, where.residuals, location)
    return _clean(report), ctx


def single_fits(stacks: Stacks, names) -> Selection:
    """Every tested effect fitted alone on the fit runs (equation error; the identifiable ones refined, the others on
    their grid only: their parameters are not identified), the nominal fit and the residual's noise (N_eff): the
    table's first step and the record of the effects it does not search. ``steps`` is empty: the table chooses."""
    att, exclude = stacks.fit, stacks.identifiability.names
    nominal = att.fit([])
    singles = dict(zip(names, att.best_shapes((n, (), n not in exclude, ()) for n in names)))
    tau, _ = att.estimate_noise(singles)
    bic0 = att.bic(nominal)
    combo = finalize(att, (), names, final=nominal, lookalikes=False)
    return Selection(nominal=nominal, singles=singles, delta_bic={n: att.bic(f) - bic0 for n, f in singles.items()},
                     tau_int=tau, n_eff=att.n_eff, candidates=combo)


def chosen_model(inp: Inputs, stacks: Stacks, where: Where, dec: decide.Decision) -> Chosen:
    """The named effects fitted jointly on the fit runs (the best set's fit when all of it is named, refitted without
    the members not named otherwise) and replayed once on the holdout runs: ``gap_after``. On runs whose unlogged
    velocities the smoother reconstructed, the holdout is reconstructed with the corrected model first, as
    ``simulate --windows --model CORRECTED.json`` replays it."""
    named = dec.named
    nf = len(inp.fit)
    if not named:
        combo = finalize(stacks.fit, (), inp.names, final=stacks.fit.fit([]), lookalikes=False)
        return Chosen((), combo, Replay((), where.before, where.nominal_sims[nf:]))
    final = (dec.best.fit if set(named) == set(dec.best.members)
             else refit(stacks.fit, named, dec.best.fit.shapes))
    combo = finalize(stacks.fit, named, inp.names, final=final, lookalikes=False)
    held = reconstruct_with(inp, stacks.actuation, combo.fit, named, "holdout") if reconstructed(inp) else inp
    return Chosen(tuple(named), combo, _replayer(held, stacks, where.before.scored)(combo.fit, named))


def table_decision(inp: Inputs, stacks: Stacks, where: Where, singles: Mapping, log=None) -> decide.Decision:
    """The one decision (:mod:`udrobot_ctrl.gap.decide`) on the fit runs only: every identifiable effect searched,
    each set scored by the fit runs' output-error BIC of its replays (``singles``: the effects' single fits, the
    search's first step)."""
    nf = len(inp.fit)
    nominal = where.nominal_sims[:nf]
    channels = gap(inp.fit, nominal).scored
    replay = _replayer(inp, stacks, channels, runs=inp.fit).many
    names = [n for n in inp.names if n not in stacks.identifiability.names]
    return decide.decision(decide.search(stacks.fit, replay, inp.fit, channels, nominal, names,
                                         singles={n: singles[n] for n in names}, log=log))


def replay_domain(inp: Inputs, nominal_sims, after_sims) -> dict:
    """The report's ``replay_domain``: the replay windows that left the plant's domain
    (:func:`udrobot_ctrl.gap.replay.domain_windows`; docs/formats/diagnosis.md).

    ``nominal``: the nominal model's windows on every run (fit and holdout: the location's and ``gap_before``'s
    replays); ``after``: the holdout windows replayed with the significant effects (``gap_after``'s; empty when
    ``after_sims`` is None: no effect is significant, the corrected replay is the nominal one). Such windows
    stay scored (left out, a model whose replays leave the water would score better than one whose replays stay
    in it); ``holdout_flagged`` counts the holdout's flagged windows of each, and when any is flagged the verdict
    says that the gap there is not a finding (:func:`domain_caveat`)."""
    nominal = domain_windows(inp.runs, nominal_sims, inp.p, inp.window_s)
    after = domain_windows(inp.holdout, after_sims, inp.p, inp.window_s) if after_sims is not None else []
    holdout = {pr.name for pr in inp.holdout}
    return {"criteria": {"above_surface_z_m": 0.0, "inverted_cos_phi_cos_theta": 0.0,
                         "saturation_tolerance": SATURATION_TOLERANCE,
                         "saturation_s": SATURATION_WINDOW_FRACTION * inp.window_s},
            "scored": True,
            "nominal": [w.to_json() | {"part": "holdout" if w.run in holdout else "fit"} for w in nominal],
            "after": [w.to_json() | {"part": "holdout"} for w in after],
            "holdout_flagged": {"nominal": sum(w.run in holdout for w in nominal), "after": len(after)}}


def domain_caveat(domain: dict) -> str:
    """The verdict's caveat when holdout replay windows left the plant's domain ("" otherwise)."""
    n = domain["holdout_flagged"]
    if not (n["nominal"] or n["after"]):
        return ""
    codes = sorted({c for w in domain["nominal"] + domain["after"] if w["part"] == "holdout" for c in w["codes"]})
    which = f"{n['nominal']} nominal" + (f" and {n['after']} corrected" if n["after"] else "")
    return (f"; {which} holdout replay windows leave the plant's domain ({', '.join(codes)}; replay_domain): they "
            f"are scored, but their gap is not a finding")


def domain_lines(domain) -> list:
    """Console lines of the report's ``replay_domain``: each flagged window with its codes."""
    lines = []
    for which, label in (("nominal", "nominal replay"), ("after", "corrected replay")):
        ws = (domain or {}).get(which) or []
        if ws:
            lines.append(f"  {label} windows outside the plant's domain (scored, not a finding): " + "; ".join(
                f"{w['run']} ({w['part']}) window {w['window']} {w['t'][0]:.1f}-{w['t'][1]:.1f} s: "
                f"{', '.join(w['codes'])}" for w in ws))
    return lines


def _not_diagnosed_notes(skipped) -> list:
    """The report's notes on the runs screened out (:func:`~udrobot_ctrl.gap.screen.screen_runs`)."""
    return [f"not diagnosed ({u.kind}): {u.reason()}" for u in skipped]


def _not_diagnosed_fields(skipped) -> dict:
    """The report's lists of the runs screened out, one field per kind (``unexcited_runs``, ``unrepresented_runs``;
    each present, empty when no run is of that kind)."""
    return {kind.field: [u.to_json() for u in skipped if isinstance(u, kind)] for kind in KINDS}


def not_diagnosed_report(model, runs, holdout, skipped, model_label, elapsed_s):
    """(report, context) when every run is screened out (unexcited or not represented): the report says so (the
    runs' fields, ``verdict``) with no gap, location or effect (nothing to diagnose), and the context holds no run
    (no figure)."""
    label = model_label or (str(model) if not hasattr(model, "name") else model.name)
    empty = {"metric": "nrmse", "value": None, "per_channel": {}, "undefined": {}, "scored": [], "windows": {},
             "diverged_windows": {}}
    if all(isinstance(u, Unexcited) for u in skipped):
        verdict = (f"not diagnosed: no run is excited ({', '.join(u.run for u in skipped)}: every actuator command "
                   f"within {100 * UNEXCITED_COMMAND:g}% of its capacity for the whole run), so there is no commanded "
                   f"input for a model to answer; fly commanded manoeuvres to diagnose")
    else:
        kinds = {}
        for u in skipped:
            kinds.setdefault(u.run, []).append(u.kind)
        each = "; ".join(f"{run}: {' and '.join(k)}" for run, k in kinds.items())
        verdict = (f"not diagnosed: no run is left to diagnose ({each}); fly commanded manoeuvres of the submerged, "
                   f"armed vehicle to diagnose")
    report = {"format": FORMAT, "model": label, "fit_runs": [run_label(r) for r in runs],
              "holdout_runs": [run_label(r) for r in holdout], "gap_before": dict(empty), "location": [],
              "effects": [], "unidentifiable": [], "gap_after": dict(empty), "unexplained": None, "verdict": verdict,
              **_not_diagnosed_fields(skipped), "replay_domain": None, "notes": _not_diagnosed_notes(skipped),
              "elapsed_s": elapsed_s}
    return _clean(report), DiagnosisContext([], 0, [], [], [], [])


#: a single-effect replay with a shrink below this (holdout gap more than twice the nominal's: the fit run's equation
#: error gave it parameters the replay cannot hold, e.g. a cross-coupled damping fitted on a 2 cm depth log, shrink
#: -7031) is said to drift off in the summary, so that its number is not read as how much worse the effect is
DRIFTS_OFF = -1.0


def _num(value, spec: str, undefined: str = "undefined") -> str:
    """``value`` formatted with ``spec``, or ``undefined`` for None / nan (JSON null)."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return undefined
    return format(value, spec)


def nothing_diagnosed(report) -> bool:
    """True for a report whose every run was screened out (:func:`not_diagnosed_report`): no gap, no effect, so no
    corrected model either."""
    return not report["effects"] and any(report.get(kind.field) for kind in KINDS)


def summary(report) -> str:
    """Human-readable summary of a report (undefined numbers, e.g. the gap of constant channels, say so)."""
    gb, ga = report["gap_before"], report["gap_after"]
    skipped = [u for kind in KINDS for u in report.get(kind.field, [])]
    if nothing_diagnosed(report):
        return "\n".join([f"model {report['model']}: runs {', '.join(report['fit_runs'] + report['holdout_runs'])}"]
                         + [f"  not diagnosed: {u['reason']}" for u in skipped] + [report["verdict"]])
    why = gb.get("undefined") or {}
    per = [f"{c} {_num(v, '.2f')}" for c, v in gb["per_channel"].items() if c in gb["scored"]]
    per += [f"{c} undefined: channel constant" for c in why]
    lines = [f"model {report['model']}: fit {', '.join(report['fit_runs'])}; "
             f"holdout {', '.join(report['holdout_runs'])}",
             f"gap before {_num(gb['value'], '.3f', 'undefined (no channel to score)')} (NRMSE; "
             + ", ".join(per) + ")"]
    for loc in report["location"]:
        where = f"; windows {loc['windows'][:3]} in {loc['run']}" if loc.get("windows") else ""
        lines.append(f"  where: {loc['channel']} holds {100 * loc['share']:.0f}% -- {loc['condition']}{where}")
    lines.append("effects (ranked):")
    for e in report["effects"]:
        ev = e["evidence"]
        tag = "SIGNIFICANT" if e["significant"] else {decide.AT_BOUND: "AT BOUND", LOOKALIKE: "LOOK-ALIKE",
                                                      decide.INCLUSION_LOW: "UNSETTLED"}.get(ev.get("code"), "-")
        extra = ""
        if e.get("indistinguishable_from"):
            extra = "; indistinguishable from " + ", ".join(a["name"] for a in e["indistinguishable_from"])
        if e.get("matters_below_m") is not None:
            extra += f"; matters below {e['matters_below_m']:.2f} m" + (
                f" of {', '.join(e['planes'])}" if e.get("planes") else "")
        if e["shrink"] is not None and e["shrink"] < DRIFTS_OFF:  # a fit the replay cannot hold, not a measure
            extra += f"; alone its replay drifts off ({1 - e['shrink']:.3g} x the nominal gap)"
        if e.get("at_bound"):
            extra += "; at the edge of its range: " + ", ".join(f"{k}={_num(v['value'], '.4g')}"
                                                                for k, v in e["at_bound"].items())
        if e.get("replay_diverged_windows"):
            extra += f"; alone its replay diverges in {e['replay_diverged_windows']} holdout windows"
        lines.append(f"  {e['name']:<26s} {tag:<11s} shrink {_num(e['shrink'], '+.2f')}  "
                     f"P {_num(ev.get('inclusion_probability'), '.2f')}  dBIC {_num(ev.get('delta_bic'), '.0f')}"
                     f"{extra}")
        if e["significant"]:
            lines.append("      params " + ", ".join(f"{k}={_num(v, '.4g')}" for k, v in e["params"].items()))
            if (report.get("parts") or {}).get("holdout_params", {}).get(e["name"]):
                lines.append("      fitted on the holdout runs apart: " + ", ".join(
                    f"{k}={_num(v, '.4g')}" for k, v in report["parts"]["holdout_params"][e["name"]].items()))
        elif ev.get("code") in (decide.AT_BOUND, LOOKALIKE, decide.INCLUSION_LOW):
            lines.append("      not named: " + reason_text(ev["code"], ev.get("inclusion_probability"),
                                                           ev.get("rivals", ())))
            lines.append("      fitted " + ", ".join(f"{k}={_num(v, '.4g')}"
                                                     for k, v in (e.get("fitted_params_if_added") or {}).items()))
        if e.get("top_end"):
            lines.append("      top end: " + e["top_end"]["text"])
        if e["name"] == CURRENT and report.get("heading_coverage"):  # the current is world-fixed: turns with psi
            lines.append("      headings: " + report["heading_coverage"]["text"])
            if report["heading_coverage"].get("currents"):
                lines.append("      currents: " + report["heading_coverage"]["currents"]["text"])
    if report.get("parts"):
        lines.append(f"  {', '.join(report['parts']['members'])} {report['parts']['text']}")
    for u in report.get("unidentifiable", []):
        lines.append(f"  unidentifiable with these sensors: {u['name']} ({u['reason']})")
        lines += [f"      {identifiability.describe_missing(m)}" for m in u.get("missing", ())
                  if m["code"] == identifiability.UNAIDED_ESTIMATE]
    for u in skipped:
        lines.append(f"  not diagnosed: {u['reason']}")
    for which, g in (("before", gb), ("after", ga)):
        div = {r: n for r, n in (g.get("diverged_windows") or {}).items() if n}
        if div:
            lines.append(f"  diverged windows {which} (scored at the error cap): " + ", ".join(
                f"{r} {n} of {(g.get('windows') or {}).get(r, '?')}" for r, n in div.items()))
    lines += domain_lines(report.get("replay_domain"))
    lines.append(f"gap after {_num(ga['value'], '.3f')}; unexplained {_num(report['unexplained'], '.2f')}")
    left = remaining_line(report.get("remaining") or [])
    if left:
        lines.append(left)
    lines += balance_lines(report.get("steady_balance"))
    lines.append(report["verdict"])
    return "\n".join(lines)


def write_report(report, path, protect=()) -> None:
    """Write the JSON report atomically (never over a file in ``protect``, see :mod:`udrobot_files.output`).

    Parameters
    ----------
    report : dict
        The ``udrobot-diagnosis/1`` report of :func:`diagnose` (docs/formats/diagnosis.md).
    path : str or Path
        Destination JSON file.
    protect : sequence of path, optional
        Files that must not be overwritten (the command's inputs).
    """
    atomic_write(path, json.dumps(report, indent=2) + "\n", protect=protect)
