"""The diagnosis end to end and its ``udrobot-diagnosis/1`` report (docs/formats/diagnosis.md).

:func:`diagnose` reads as its steps, each a small function over named results:

1. :func:`prepare_inputs` -> :class:`Inputs` (nominal plant, effects tested, prepared fit and holdout runs);
2. locate, :func:`locate_gap` -> :class:`Where`: nominal multiple-shooting replays of every run, each channel's
   noise floor and where the gap lies above it (:mod:`udrobot_ctrl.gap.locate`), the nominal holdout gap;
3. attribute, :func:`build_stacks` -> :class:`Stacks` and :func:`attribute` -> :class:`~udrobot_ctrl.gap.attribute.
   Selection`: equation-error fits of every effect on the fit runs and forward selection of candidates;
4. shrink and confirm on the holdout runs only: :func:`shrink_each` (each effect alone) and :func:`confirm`
   -> :class:`~udrobot_ctrl.gap.confirm.Elimination` (backward elimination: the significant set);
5. report: :func:`effect_verdicts` -> :class:`EffectVerdict` per effect, :func:`verdict_line`, the JSON report.
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
    BIC_STRONG,
    HOLDOUT_CHI2,
    Attributor,
    DesignStore,
    Fit,
    Selection,
    SelectionStep,
    build_stack,
    finalize,
    forward_select,
    holdout_loglik,
    holdout_lr,
    passes_forward_test,
    refit,
    residual,
)
from udrobot_ctrl.gap.balance import SteadyBalance, balance_lines, steady_balance
from udrobot_ctrl.gap.confirm import (
    CONSISTENT_WINDOWS,
    INTERACTING_P,
    REPLAY_LARGE,
    REPLAY_MATERIAL,
    REPLAY_P,
    Elimination,
    MemberTest,
    Replay,
    ReplayCache,
    Replayer,
    alone_tests,
    backward_eliminate,
    check_members,
    fitted_hooks,
    member_test,
    replay_sets,
    separations,
)
from udrobot_ctrl.gap.data import observable, prepare
from udrobot_ctrl.gap.effects import Actuation
from udrobot_ctrl.gap.heading import CURRENT, HeadingCoverage, current_parts, heading_coverage
from udrobot_ctrl.gap.identifiability import Identifiability
from udrobot_ctrl.gap.locate import Located, locate, noise_floor
from udrobot_ctrl.gap.parts import named_parts
from udrobot_ctrl.gap.plots import write_plots
from udrobot_ctrl.gap.replay import domain_windows
from udrobot_ctrl.gap.screen import KINDS, UNEXCITED_COMMAND, Unexcited, run_label, screen_runs
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
#: the confirmed effects leave more than this fraction of the holdout gap unexplained (the verdict line's threshold),
#: or leave a replay still more than REPLAY_ABOVE_FLOOR above its noise floor (:func:`remaining_to_floor`):
#: candidates that only the replay rejected, and whose replay lacks the parameters the channels cannot identify, are
#: then listed as unidentifiable instead of dropped silently (:func:`set_aside_unconfirmed`)
UNEXPLAINED_LARGE = 0.5
#: ... and the nominal replay is this far above its noise floor (summed NRMSE^2 over summed floor^2,
#: :meth:`~udrobot_ctrl.gap.locate.Located.replay_to_floor`): with no gap to explain, an equation-error selection is
#: the reconstruction's, not an effect's
REPLAY_ABOVE_FLOOR = 2.0


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


@dataclass(frozen=True)
class Evidence:
    """Why an effect is (not) significant: fit-run BIC, forward step, holdout backward check."""

    delta_bic: float  # single-effect BIC change on the fit runs
    selection: SelectionStep | None = None  # its forward-selection step, if it reached one
    backward: MemberTest | None = None  # its last backward check, if it was a candidate
    note: str | None = None

    def to_json(self) -> dict:
        out = {"delta_bic": self.delta_bic}
        if self.backward is not None:  # rise of the holdout gap (fraction of gap_before) when removed from the set
            out["holdout_gap_contribution"] = self.backward.gap_contribution
            out["backward_elimination"] = self.backward.to_json()
        if self.note:
            out["note"] = self.note
        if self.selection is not None:
            out["selection_delta_bic"] = self.selection.delta_bic
            out["holdout_likelihood_ratio"] = self.selection.holdout_lr
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
    fitted_params_if_added: dict | None = None
    indistinguishable_from: tuple = ()  # (name, manoeuvre that separates them)
    wall: dict | None = None  # wall_effect only: {"matters_below_m", "matters_below"}
    not_identified: dict | None = None  # partly identified effects: {"params": [...], "reason": ...}
    at_bound: dict | None = None  # parameter -> (value, bound) of a confirmed fit that ended on a bound
    at_bound_reason: str | None = None  # why an effect at a bound is not significant
    replay_diverged_windows: int = 0  # holdout windows its single-effect replay diverged in
    #: amplitudes of a named per-DOF effect held at nominal: parameter -> (value, bound) where their fit ended
    held_at_nominal: dict | None = None
    #: tether_drag only: where its fitted top end lies (:class:`udrobot_ctrl.gap.top_end.TopEnd`)
    top_end: dict | None = None

    def to_json(self) -> dict:
        out = {"name": self.name, "significant": self.significant, "params": self.params, "shrink": self.shrink,
               "evidence": self.evidence.to_json(), "meaning": self.meaning}
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
        if self.at_bound_reason:
            out["at_bound_reason"] = self.at_bound_reason
        if self.replay_diverged_windows:
            out["replay_diverged_windows"] = self.replay_diverged_windows
        if self.held_at_nominal:
            out["held_at_nominal"] = {k: {"fitted": v, "bound": b} for k, (v, b) in self.held_at_nominal.items()}
        return out


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


def attribute(stacks: Stacks, names, log=None) -> Selection:
    """Step 2, attribute: fit every tested effect on the fit runs and select forward among the identifiable ones
    (fit-run BIC, holdout equation error, :func:`~udrobot_ctrl.gap.attribute.forward_select`); then set the holdout
    stack's N_eff from the fit runs' noise whiteness for the backward check. Unidentifiable effects are fitted for
    the record and still count as look-alikes."""
    sel = forward_select(stacks.fit, stacks.holdout, names, log=log, exclude=stacks.identifiability.names)
    stacks.holdout.n_eff = max(10.0, stacks.holdout.N / max(sel.tau_int, 1.0))
    return sel


@dataclass(frozen=True)
class ReplaySupport:
    """Step 2b: whether the forward-selected set replays the fit runs it was fitted on, and the effects that joined
    the candidates because alone they replay the fit runs better (:func:`replay_supported`)."""

    fit_gap_before: float  # nominal replay gap of the fit runs
    set_shrink: float | None  # the forward-selected set's shrink of that gap (None: nothing was selected)
    set_diverged: int  # fit-run windows in which the set's replay diverged
    tried: dict = field(default_factory=dict)  # name -> shrink of the fit runs' gap with the effect alone
    added: tuple = ()  # the effects that joined the candidates
    skipped: bool = False  # not checked: the fit runs' velocities were reconstructed with the plant itself

    @property
    def triggered(self) -> bool:
        """The set does not replay its own fit runs: it diverges, or shrinks their gap by no more than
        ``REPLAY_MATERIAL``."""
        if self.skipped:
            return False
        return self.set_shrink is None or self.set_diverged > 0 or not self.set_shrink > REPLAY_MATERIAL

    def to_json(self) -> dict:
        """The report's ``replay_support`` object."""
        return {"fit_gap_before": self.fit_gap_before, "set_shrink": self.set_shrink,
                "set_diverged_windows": self.set_diverged, "triggered": self.triggered, "skipped": self.skipped,
                "tried": self.tried, "added": list(self.added)}


def replay_supported(inp: Inputs, stacks: Stacks, sel: Selection, where: Where, log=None):
    """Step 2b, on the fit runs only: when the forward-selected set does not replay the runs it was fitted on (its
    replay diverges in some window, or shrinks their replay gap by no more than ``REPLAY_MATERIAL``), the equation
    error was not a trustworthy guide on these runs, and every identifiable effect whose single fit lowers the fit-run
    BIC by more than ``BIC_STRONG`` and alone shrinks the fit runs' replay gap by more than ``REPLAY_LARGE`` (without
    diverging) joins the candidates; the set is fitted again jointly and goes to the holdout check like any other.

    Why: under a closed-loop autopilot the equation error is dominated by the fast attitude loop's residual, while a
    small steady moment (a drag centre away from the origin) shows as a slow drift that only a replay integrates;
    on the shared sea dive, the selected set diverged in 16 of its fit-run windows while a drag centre alone shrank
    their gap by 31 %. The holdout is not read here: it only scores the candidates afterwards.

    Not on runs whose unlogged velocities were reconstructed (:func:`reconstructed`, a stock vehicle without a DVL):
    the model-based smoother reconstructed them with the nominal plant (or, in the second pass, with the confirmed
    effects), so their replay favours the plant that reconstructed them (on the templates generator's stock runs the
    true set worsened the fit runs' replay by 24-37 %, and so did the nominal model's of runs with no
    effect); ``skipped`` says so.

    Returns
    -------
    sel : Selection
        ``sel`` with the joined effects among its candidates (unchanged when nothing joined).
    support : ReplaySupport
    """
    nf = len(inp.fit)
    before = gap(inp.fit, where.nominal_sims[:nf])
    if not before.value > 0 or reconstructed(inp):
        return sel, ReplaySupport(float(before.value), None, 0, skipped=reconstructed(inp))

    run = _replayer(inp, stacks, before.scored, runs=inp.fit).many
    rest = [n for n in inp.names if n not in sel.proposed and n not in stacks.identifiability.names
            and sel.delta_bic[n] < -BIC_STRONG]
    if sel.proposed:
        set_replay = run([(sel.candidates.fit, sel.proposed)])[0]
        support = ReplaySupport(float(before.value), float(1 - set_replay.gap.value / before.value),
                                set_replay.gap.n_diverged)
    else:
        support = ReplaySupport(float(before.value), None, 0)
    if not support.triggered or not rest:
        return sel, support
    reps = run([(sel.singles[n], (n,)) for n in rest])
    tried = {n: float(1 - r.gap.value / before.value) for n, r in zip(rest, reps)}
    added = tuple(n for n, r in zip(rest, reps) if r.gap.n_diverged == 0 and tried[n] > REPLAY_LARGE)
    support = replace(support, tried=tried, added=added)
    if log:
        state = ("nothing was selected" if support.set_shrink is None else
                 f"its replay diverges in {support.set_diverged} fit-run windows" if support.set_diverged else
                 f"it shrinks their replay gap by {100 * support.set_shrink:.0f}%")
        log(f"  replay check on the fit runs: the selected set does not replay them ({state}); "
            + (f"joining the candidates, alone shrinking the fit runs' replay gap by more than "
               f"{100 * REPLAY_LARGE:.0f}%: " + ", ".join(f"{n} ({100 * tried[n]:.0f}%)" for n in added)
               if added else f"no other effect alone shrinks it by more than {100 * REPLAY_LARGE:.0f}%"))
    if not added:
        return sel, support
    return replace(sel, candidates=finalize(stacks.fit, (*sel.proposed, *added), inp.names)), support


def _replayer(inp: Inputs, stacks: Stacks, scored, runs=None) -> Replayer:
    """The :class:`~udrobot_ctrl.gap.confirm.Replayer` of fitted effect sets on ``runs`` (default: the holdout)."""
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
    """Step 3, shrink: name -> holdout :class:`~udrobot_ctrl.gap.confirm.Replay` with the effect alone (its single
    fit), replayed when first read (:class:`OnDemand`); its shrink is 1 - replay gap / gap_before."""
    run = _replayer(inp, stacks, before.scored)

    def replays(names):
        return dict(zip(names, run.many([(sel.singles[n], (n,)) for n in names])))
    # the candidates' replays are read first (the holdout check); the others', for the rivals and the report, are
    # replayed meanwhile in a worker
    rest = tuple(n for n in inp.names if n not in sel.proposed)
    return OnDemand(inp.names, replays, (rest, Background(lambda: replays(rest))) if rest else None)


def confirm(inp: Inputs, stacks: Stacks, sel: Selection, where: Where, singles: OnDemand, log=None) -> Elimination:
    """Step 3, confirm on the holdout: backward elimination from the forward-selected candidates, each of which must
    also shrink the holdout gap on its own (its replay in ``singles`` against the nominal one)."""
    before = where.before
    nominal = Replay((), before, where.nominal_sims[len(inp.fit):])
    singles.fill(sel.proposed)
    alone = alone_tests(inp.holdout, nominal, {n: singles[n] for n in sel.proposed}, inp.window_s)
    return backward_eliminate(stacks.fit, stacks.holdout, sel.candidates, inp.names, before,
                              _replayer(inp, stacks, before.scored), inp.window_s, inp.holdout, alone=alone, log=log)


def set_aside_ambiguous(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, log=None, prior=None,
                        shrink=None, prior_forms=None):
    """Step 3b: a confirmed effect whose fit another effect matches as well (a look-alike within ``BIC_STRONG`` on
    the observed DOFs) is not significant: the runs cannot say which of the two acts (e.g. without a DVL, a
    heave-side thrust loss and a tether whose drag needs the unobserved surge speed; a pitch added-mass error and a
    CG-CB offset in free pitch oscillations). It is listed as unidentifiable with that reason, and so are its
    look-alikes; the rest is refitted and replayed. An identifiable look-alike counts only on runs whose velocities
    the smoother reconstructed (the channels leave the fit little to go on); with every velocity measured the
    holdout replay separates identifiable look-alikes, and only an unidentifiable one sets an effect aside.

    On reconstructed runs the holdout replay also names look-alikes (:func:`replay_rivals`): an effect outside the
    confirmed set that alone (``shrink``: name -> its single-effect holdout shrink) shrinks the holdout gap by more
    than ``REPLAY_MATERIAL`` beyond what the whole confirmed set does is a look-alike of every confirmed member
    (without a DVL, an inflow loss and a linear damping that the equation error on the reconstructed surge speed
    ranks below a quadratic-damping error, which alone explains less of the holdout than either of them).

    On reconstructed runs an identifiable look-alike must also be shown on the holdout (:func:`_holdout_separated`):
    swapped in for the member and replayed, it sets the member aside only when the two sets score equally there.

    On reconstructed runs a member may also be the look-alike of an effect in the form the channels cannot test
    (:func:`form_alikes`). It is listed as unidentifiable with that reason, and so is that effect unless it is
    confirmed in the form the search kept (then it stays significant).

    ``prior`` (name -> look-alikes) holds the effects set aside in the first reconstruction pass: confirmed in the
    second, they and their look-alikes stay set aside, since that pass reconstructed the velocities with the force
    of one of them and so cannot settle which look-alike acts (it would confirm whichever one it assumed, or the
    look-alike that best matches the assumed force). ``prior_forms`` (name -> ``FormAlike``) does the same for the
    form look-alikes of the first pass.

    Returns
    -------
    elim : Elimination
        With the ambiguous effects removed from the confirmed set (unchanged when there are none).
    stacks : Stacks
        With the ambiguous effects added to its identifiability.
    """
    prior, prior_forms = _lookalike_groups(prior or {}), prior_forms or {}
    # with every velocity measured the holdout replay separates identifiable look-alikes (the tether of a tank run
    # and its quadratic-damping look-alike): only an unidentifiable one sets a confirmed effect aside there
    hidden, any_alike = set(stacks.identifiability.names), reconstructed(inp)
    rivals = replay_rivals(elim, where.before, shrink or {}) if any_alike else []
    amb = {k: [a for a in dict.fromkeys([*elim.combination.indistinguishable.get(k, ()), *prior.get(k, ()), *rivals])
               if any_alike or a in hidden] for k in elim.kept}
    amb = {k: v for k, v in amb.items() if v}
    amb, seps = _holdout_separated(inp, stacks, where, elim, amb, hidden, prior, log)
    forms = {**{k: a for k, a in prior_forms.items() if k in elim.kept},
             **(form_alikes(elim, stacks.identifiability, stacks.fit, inp.catalogue, inp.names) if any_alike
                else {})}
    forms = {k: a for k, a in forms.items() if k not in amb}
    if not amb and not any(k in elim.kept for k in forms):
        return elim, replace(stacks, identifiability=stacks.identifiability.with_form_alike(forms))
    rest = [k for k in elim.kept if k not in amb and k not in forms]
    combo = finalize(stacks.fit, rest, inp.names)
    after = (_replayer(inp, stacks, where.before.scored)(combo.fit, combo.members) if rest else
             Replay((), where.before, where.nominal_sims[len(inp.fit):]))
    if log:
        for k, v in amb.items():
            fit_alike, by_replay = [a for a in v if a not in rivals], [a for a in v if a in rivals]
            why = ([f"its fit is matched as well by {', '.join(fit_alike)}"] if fit_alike else []) + (
                [f"alone, {', '.join(by_replay)} explain more of the holdout gap than the confirmed set"]
                if by_replay else [])
            log(f"  set aside: {k} (" + "; ".join(why) + "; the runs cannot say which acts"
                + ("; it or a look-alike was set aside in the first pass, whose reconstruction this pass assumed"
                   if k in prior else "")
                + ")")
        for k, a in forms.items():
            if a.held_by_rival:
                log(f"  set aside: {k} (its fit is matched as well by {a.rival} with {a.form} = {a.other:g}, a form "
                    f"these channels cannot test: BIC {a.delta_bic:+.0f} when swapped; the runs cannot say which acts)")
    ident = stacks.identifiability.with_ambiguous(amb).with_form_alike(forms).with_separations(seps)
    return replace(elim, kept=tuple(rest), combination=combo, after=after), replace(stacks, identifiability=ident)


def _holdout_separated(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, amb: dict, hidden, prior, log):
    """Keep, of each confirmed member's look-alikes, those the holdout replay cannot tell from it.

    An identifiable look-alike (the channels identify it: its regressors act in the observed DOFs without hinging on
    a reconstructed velocity) is swapped in for the member, the set refitted on the fit runs and replayed on the
    holdout (:func:`~udrobot_ctrl.gap.confirm.separations`). When the swapped set scores materially and consistently
    worse, the runs do separate the two (a CG-CB offset's restoring moment and an added-mass error in roll and pitch:
    the held angles of the holdout runs tell them apart, the fit-run BIC of free oscillations does not) and it is no
    longer a look-alike. Otherwise the two fits score equally on the holdout and the member stays set aside, its
    reason giving both scores. Unidentifiable look-alikes (their fit hinges on what no sensor measures) and those of
    the first reconstruction pass (``prior``) are kept without the test.

    Returns
    -------
    amb : dict
        Name -> look-alikes left.
    seps : dict
        Name -> tuple of :class:`~udrobot_ctrl.gap.confirm.Separation` (those the holdout did not separate, kept for
        the reason; and those it did, for the record).
    """
    pairs = [(k, a) for k, alts in amb.items() for a in alts
             if a not in hidden and a not in elim.kept and a not in prior.get(k, ())]
    if not pairs or not where.before.value > 0:
        return amb, {}
    found = separations(stacks.fit, elim.kept, pairs, elim.after, where.before,
                        _replayer(inp, stacks, where.before.scored), inp.window_s, inp.holdout,
                        shapes=elim.combination.fit.shapes)
    seps = {}
    for sp in found:
        seps.setdefault(sp.member, []).append(sp)
        if log:
            log(f"  look-alike check: {sp.member} vs {sp.rival}: {sp.describe()} -> "
                + {"separated": "the holdout separates them", "equal": "equal on the holdout",
                   "rival better": f"the holdout prefers {sp.rival}"}[sp.verdict])
    gone = {(sp.member, sp.rival) for sp in found if sp.separated}
    out = {k: [a for a in v if (k, a) not in gone] for k, v in amb.items()}
    return {k: v for k, v in out.items() if v}, {k: tuple(v) for k, v in seps.items()}


def form_alikes(elim: Elimination, ident: Identifiability, att: Attributor, catalogue, names) -> dict:
    """Confirmed members whose fit an effect matches as well in the form the channels cannot test: swapped for that
    effect held at the untested end of its form parameter (the rest of the set kept, and that effect's own member
    replaced when it is in the set), the fit-run BIC rises by less than ``BIC_STRONG`` (the look-alike test of
    :func:`~udrobot_ctrl.gap.attribute.finalize`, with the form the search does not use). Without a DVL a
    quadratic-damping error is fitted on each axis' speed only; the truth's drag on the speed norm adds a heave force
    that grows with the unobserved surge speed, which an inflow loss on the vertical thrusters takes up (beside the
    per-axis fit, or instead of it).

    Returns
    -------
    dict
        Name -> :class:`~udrobot_ctrl.gap.identifiability.FormAlike`: each such member, and each look-alike that is
        not in the set (the relation is symmetric: the runs cannot say which acts).
    """
    fit, out = elim.combination.fit, {}
    current = att.bic(fit)
    for h in names:
        chk = ident.effects.get(h)
        if chk is None or not chk.identified or not chk.forms:
            continue
        for form, f in chk.forms.items():
            other = att.with_effect(h, identifiability.Restricted(catalogue[h], (), {form: f.other}))
            for m in elim.kept:
                if m == h or m in out:
                    continue
                rest = [(n, fit.shapes[n]) for n in elim.kept if n not in (m, h)]
                dbic = other.bic(other.best_shape(h, rest, refine=False)) - current
                if dbic < BIC_STRONG:
                    out[m] = identifiability.FormAlike(h, form, f.other, dbic, held_by_rival=True)
                    if h not in elim.kept:
                        out.setdefault(h, identifiability.FormAlike(m, form, f.other, dbic, held_by_rival=False))
    return out


def replay_rivals(elim: Elimination, before: GapScore, shrink: dict) -> list:
    """Effects outside the confirmed set that alone shrink the holdout gap by more than ``REPLAY_MATERIAL`` beyond
    what the whole set shrinks it (at least beyond no shrink; ``shrink``: name -> single-effect holdout shrink), best
    first. An unidentifiable one counts too: its replay with what the channels fit of it explains more of the gap
    than the set (without a DVL, an inflow loss whose fit hinges on the reconstructed surge speed)."""
    if not elim.kept or not before.value > 0:
        return []
    floor = max(1 - elim.after.gap.value / before.value, 0.0) + REPLAY_MATERIAL
    out = [n for n, s in shrink.items() if n not in elim.kept and s > floor]
    return sorted(out, key=lambda n: -shrink[n])


def _lookalike_groups(prior: dict) -> dict:
    """``prior`` (name -> look-alikes) made symmetric: each member of a group (a name and its look-alikes) maps to
    the group's other members, in order."""
    out = {}
    for k, alts in prior.items():
        group = (k, *alts)
        for m in group:
            out[m] = tuple(dict.fromkeys([*out.get(m, ()), *(g for g in group if g != m)]))
    return out


def remaining_to_floor(where: Where, after: GapScore) -> float:
    """How far the replay with the confirmed effects stays above the noise floor (the nominal's
    :meth:`~udrobot_ctrl.gap.locate.Located.replay_to_floor` times the share of the holdout replay's summed NRMSE^2
    that ``after`` leaves, over the channels with a floor; nan without one): above ``REPLAY_ABOVE_FLOOR``, a gap
    that noise and reconstruction cannot account for is left, however much of the nominal gap was explained."""
    floor = where.located.floor
    both = [c for c in where.before.scored if floor.get(c, 0.0) > 0 and np.isfinite(after.per_channel.get(c, np.nan))
            and np.isfinite(where.before.per_channel.get(c, np.nan))]
    den = sum(where.before.per_channel[c] ** 2 for c in both)
    if not den > 0:
        return float("nan")
    return where.located.replay_to_floor() * sum(after.per_channel[c] ** 2 for c in both) / den


def set_aside_unconfirmed(stacks: Stacks, sel: Selection, where: Where, elim: Elimination, log=None) -> Stacks:
    """Step 3c: a forward-selection candidate that the holdout replay dropped is listed as unidentifiable when the
    replay could not have confirmed it: the effect is identified in part only (parameters or a form that hinge on a
    channel the runs do not measure are frozen: e.g. without a DVL, a surge added mass, a heave drag on the flow
    speed), its equation error on the observed DOFs still held on the holdout when it was dropped, the nominal replay
    is more than ``REPLAY_ABOVE_FLOOR`` above its noise floor (there is a gap), and the confirmed effects leave more
    than ``UNEXPLAINED_LARGE`` of the holdout gap unexplained or a replay still more than ``REPLAY_ABOVE_FLOOR``
    above that floor (:func:`remaining_to_floor`: a lag that explains 62 % of a gap 250 x its floor leaves 36 x
    the floor to explain). Its evidence and the measurement
    that would settle it go into the reason. Under the same two conditions, a partly identified effect that was not
    selected is listed as *not excluded* when some of its non-identified parameters act in a DOF holding at least
    ``locate.GAP_SHARE`` of the located gap (``Located.gap_dofs``, ``EffectCheck.acting_in``): the part the channels
    identify does not explain the gap, and the part that might cannot be tested (without a DVL, a surge added mass
    acts on the pitch and heave forces through the Munk moment and the reconstructed surge speed). Nothing changes
    when the confirmed effects explain the gap: a candidate dropped beside them is then redundant, not
    unconfirmable, and nothing is left for an untested part to explain.

    Returns
    -------
    Stacks
        With the unconfirmed and the not-excluded effects added to its identifiability.
    """
    left = gap_left(where, elim)
    if left is None:
        return stacks
    ident = stacks.identifiability
    steps = {s.effect: s for s in sel.steps}
    found = {n: (f"selection dBIC {steps[n].delta_bic:.0f} on the fit runs, holdout likelihood ratio "
                 f"{t.holdout_lr:.0f} when dropped")
             for n, t in elim.dropped.items()
             if n in steps and n not in ident.names and t.passed_equation_error and ident.unconfirmable(n)}
    gap = where.located.gap_dofs()
    acting = {n: ident.effects[n].acting_in(gap) for n in sel.delta_bic
              if n not in elim.kept and n not in found and n not in ident.names and ident.unconfirmable(n)}
    spare = {n: f"{left}, where its {', '.join(a)} act" for n, a in acting.items() if a}
    if log:
        for n, ev in found.items():
            log(f"  listed, not confirmable: {n} ({ev}; its replay lacks "
                f"{', '.join(ident.effects[n].not_identified)}, which these channels cannot identify)")
        for n in spare:
            log(f"  listed, not excluded: {n} (its {', '.join(acting[n])}, which these channels cannot identify, act "
                f"where the unexplained gap lies)")
    return replace(stacks, identifiability=ident.with_unconfirmed(found).with_not_excluded(spare))


def gap_left(where: Where, elim: Elimination) -> str | None:
    """What the confirmed effects leave of the holdout gap (share, times the noise floor, and the DOFs holding it), or
    None when there is no gap or they explain it: the nominal replay is at most ``REPLAY_ABOVE_FLOOR`` above its
    noise floor, or they leave at most ``UNEXPLAINED_LARGE`` of the gap and a replay at most ``REPLAY_ABOVE_FLOOR``
    above that floor (:func:`remaining_to_floor`)."""
    before = where.before.value
    if not before > 0 or not where.located.replay_to_floor() > REPLAY_ABOVE_FLOOR:
        return None
    left_to_floor = remaining_to_floor(where, elim.after.gap)
    if not (elim.after.gap.value / before > UNEXPLAINED_LARGE or left_to_floor > REPLAY_ABOVE_FLOOR):
        return None
    return (f"the confirmed effects leave {elim.after.gap.value / before:.0%} of the holdout gap unexplained "
            f"({left_to_floor:.0f} x the noise floor), "
            + ", ".join(f"{share:.0%} of it in {fx.DOF[i]}" for i, share in where.located.gap_dofs().items()))


@dataclass(frozen=True)
class FreedPart:
    """A listed, partly identified effect with its non-identified amplitude parameters fitted too (on the velocities
    the smoother reconstructs): the fit-run and holdout attributors with it, and its fit beside the confirmed set."""

    name: str
    fit: Attributor
    holdout: Attributor
    beside: Fit  # the confirmed set and the freed effect, on ``fit``


def freed_parts(stacks: Stacks, elim: Elimination, catalogue) -> list:
    """:class:`FreedPart` of each listed, partly identified effect (amplitude parameters not identified; forms held
    as the search holds them) whose untested part the runs support: beside the confirmed set, freeing it lowers the
    fit-run BIC by more than ``BIC_STRONG`` and raises the holdout equation-error likelihood by a ratio above
    ``HOLDOUT_CHI2`` (the forward-selection test)."""
    att, att_h, ident = stacks.fit, stacks.holdout, stacks.identifiability
    terms = [(n, elim.combination.fit.shapes[n]) for n in elim.kept]
    out = []
    for h in [h for h in ident.names if h not in elim.kept and ident.unconfirmable(h)]:
        chk = ident.effects[h]
        if all(c.identified for c in chk.params):
            continue  # only a form is held: nothing to free
        freed = identifiability.Restricted(catalogue[h], (), {k: f.kept for k, f in chk.forms.items()})
        fa, fa_h = att.with_effect(h, freed), att_h.with_effect(h, freed)
        held, free = att.best_shape(h, terms, refine=False), fa.best_shape(h, terms, refine=False)
        lr = att_h.n_eff * (holdout_loglik(att_h, held) - holdout_loglik(fa_h, free))
        if passes_forward_test(fa.bic(free) - att.bic(held), lr):
            out.append(FreedPart(h, fa, fa_h, free))
    return out


def _supported(att: Attributor, att_h: Attributor, base: Fit, name) -> tuple:
    """(fit, BIC change, holdout likelihood ratio) of ``name`` added to ``base`` (a fit on ``att``; ``att_h``: the
    holdout's attributor with the same catalogue)."""
    with_ = att.best_shape(name, [(n, base.shapes[n]) for n in base.names], refine=False)
    return with_, att.bic(with_) - att.bic(base), holdout_lr(att_h, base, with_)


def hinging_on_untested(parts, elim: Elimination, ident: Identifiability, left: str) -> dict:
    """Identified effects, not significant and not listed, whose support hinges on the untested part of a listed,
    partly identified effect (``parts``, :func:`freed_parts`): beside the significant set and that effect with its
    untested part fitted too, the effect passes the forward-selection test (BIC lower by more than ``BIC_STRONG``,
    holdout likelihood ratio above ``HOLDOUT_CHI2``). Without a DVL a buoyancy offset can cancel, in the mean heave
    force, a cross-coupled heave drag ``u|u|`` of the unmeasured surge speed: alone it is not selected, beside the
    drag it is.

    Returns
    -------
    dict
        Name -> :class:`~udrobot_ctrl.gap.identifiability.Hinged` (the strongest such part for each).
    """
    listed = set(ident.names)
    testable = [m for m, chk in ident.effects.items() if chk.identified and m not in elim.kept and m not in listed]
    out = {}
    for part in parts:
        for m in testable:
            _, d_bic, lr = _supported(part.fit, part.holdout, part.beside, m)
            if passes_forward_test(d_bic, lr) and (m not in out or d_bic < out[m].delta_bic):
                out[m] = identifiability.Hinged(part.name, float(d_bic), float(lr), left)
    return out


def _replaces(fa: Attributor, fa_h: Attributor, replacement: Fit, member, current: float) -> tuple | None:
    """(BIC of ``replacement`` minus ``current``, the member's BIC change added back) when ``replacement`` (a fit on
    ``fa`` without ``member``) has a fit-run BIC below ``current`` (the confirmed set's) and ``member`` added back
    fails the forward-selection test; None otherwise."""
    if not fa.bic(replacement) < current:
        return None
    _, d_m, lr_m = _supported(fa, fa_h, replacement, member)
    return None if passes_forward_test(d_m, lr_m) else (float(fa.bic(replacement) - current), float(d_m))


def stand_ins(parts, elim: Elimination, att: Attributor, ident: Identifiability, catalogue, left: str) -> dict:
    """Confirmed members that may stand in for the untested part of a listed, partly identified effect, alone or
    together with one of their own look-alikes (``Effect.mimics``, in the form the search holds or in the form the
    channels cannot test): with the member replaced by that effect, untested part fitted too (``parts``,
    :func:`freed_parts`), and (when alone it does not) the look-alike, the fit-run BIC is lower than the confirmed
    set's, and the member added back fails the forward-selection test. Without a DVL an added-mass error's Munk
    moments hinge on the unmeasured surge and sway speeds; a dead band on the thrusters takes up the yaw moment a
    surge added mass leaves, and the effect with its surge and sway parts fitted takes it back (the dead band then
    adds nothing). What a heave added-mass error leaves in heave and yaw, with a linear damping or a drag on the
    vehicle's speed, an inflow loss on the hover thrust takes up better than the damping alone.

    Returns
    -------
    dict
        Member -> :class:`~udrobot_ctrl.gap.identifiability.StandIn`.
    """
    shapes = elim.combination.fit.shapes
    current = att.bic(elim.combination.fit)
    out = {}
    for m in elim.kept:
        rest = [(n, shapes[n]) for n in elim.kept if n != m]
        for part in parts:
            alone = part.fit.best_shape(part.name, rest, refine=False)
            if (by := _replaces(part.fit, part.holdout, alone, m, current)) is not None:
                out[m] = identifiability.StandIn(part.name, "", *by, None)
                break
            for x in catalogue[m].mimics:
                chk = ident.effects.get(x)
                if x in elim.kept or x == part.name or chk is None or not chk.identified:
                    continue
                untested = {f"{k} = {f.other:g}": identifiability.Restricted(catalogue[x], (), {k: f.other})
                            for k, f in chk.forms.items()}
                forms = [("", part.fit, part.holdout)] + [
                    (label, part.fit.with_effect(x, eff), part.holdout.with_effect(x, eff))
                    for label, eff in untested.items()]
                for form, fa, fa_h in forms:
                    alt, d_x, lr_x = _supported(fa, fa_h, alone, x)
                    if (by := _replaces(fa, fa_h, alt, m, current)) is not None:
                        out[m] = identifiability.StandIn(
                            part.name, x, *by, identifiability.Hinged(part.name, float(d_x), float(lr_x), left), form)
                        break
                if m in out:
                    break
            if m in out:
                break
    return out


def set_aside_stand_ins(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, log=None, prior=None):
    """Step 3d, while a gap is left (:func:`gap_left`): confirmed members that may stand in for the untested part of a
    partly identified effect are set aside (:func:`stand_ins`), and effects whose support hinges on such a part are
    listed (:func:`hinging_on_untested`); both as unidentifiable, with the measurement that would test that part.
    ``prior`` (member -> ``StandIn``): the stand-ins of the first reconstruction pass, which stay set aside when the
    second confirms them (it reconstructed the velocities with their force).

    Returns
    -------
    elim : Elimination
        Without the stand-ins (refitted and replayed when there are any).
    stacks : Stacks
        With the stand-ins, the effects they may stand in with and the hinged effects listed.
    """
    left = gap_left(where, elim)
    found = {m: s for m, s in (prior or {}).items() if m in elim.kept}
    if (left is None or not reconstructed(inp)) and not found:
        return elim, stacks
    ident = stacks.identifiability
    parts = freed_parts(stacks, elim, inp.catalogue) if left is not None else []
    found.update(stand_ins(parts, elim, stacks.fit, ident, inp.catalogue, left) if parts else {})
    if found:
        rest = [k for k in elim.kept if k not in found]
        combo = finalize(stacks.fit, rest, inp.names)
        after = (_replayer(inp, stacks, where.before.scored)(combo.fit, combo.members) if rest else
                 Replay((), where.before, where.nominal_sims[len(inp.fit):]))
        elim = replace(elim, kept=tuple(rest), combination=combo, after=after)
        left = gap_left(where, elim) or left
        parts = freed_parts(stacks, elim, inp.catalogue) if left is not None else []
    ident = ident.with_stand_in(found)
    partners = {s.partner: s.partner_support for s in found.values() if s.partner and s.partner not in ident.names}
    ident = ident.with_hinged(partners)
    hinged = hinging_on_untested(parts, elim, ident, left) if parts else {}
    if log:
        for m, s in found.items():
            log(f"  set aside: {m} (with {s.on}'s parameters these channels cannot identify fitted"
                + (f" and {s.partner}" if s.partner else "") + (f" with {s.partner_form}" if s.partner_form else "")
                + ", "
                f"BIC {s.delta_bic:+.0f} against the confirmed set; {m} added back: dBIC {s.member_delta_bic:.0f}; "
                f"it may stand in for them)")
        for n, h in {**partners, **hinged}.items():
            log(f"  listed, not excluded: {n} (beside {h.on} with its parameters these channels cannot identify "
                f"fitted as well: dBIC {h.delta_bic:.0f}, holdout LR {h.holdout_lr:.0f}; not selected without them)")
    return elim, replace(stacks, identifiability=ident.with_hinged(hinged))


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


def effect_verdicts(inp: Inputs, stacks: Stacks, sel: Selection, elim: Elimination, shrink: Mapping,
                    at_bound: Mapping | None = None, singles: Mapping | None = None,
                    held: Mapping | None = None) -> list:
    """Step 4, report: one :class:`EffectVerdict` per tested effect, the significant ones first (by shrink), then
    the confirmed effects set aside at a bound (``at_bound``: name -> :class:`AtBound`), then the candidates the
    holdout dropped, then the rest. ``singles`` (name -> single-effect holdout Replay) gives the windows each
    effect's replay alone diverged in; ``held`` (name -> :class:`HeldAtNominal`) the significant effects named with
    some amplitudes held at nominal."""
    kept, dropped, combo = elim.kept, elim.dropped, elim.combination
    at_bound = dict(at_bound or {})
    held = dict(held or {})
    shrink = dict(shrink.items())  # every effect's (an OnDemand replays the missing ones together)
    diverged = {n: singles[n].gap.n_diverged for n in inp.names} if singles else {}
    steps = {s.effect: s for s in sel.steps}
    order = sorted(kept, key=lambda n: -shrink[n]) + sorted(
        [n for n in inp.names if n not in kept], key=lambda n: (n not in at_bound, n not in dropped, -shrink[n]))
    out = []
    for n in order:
        significant = n in kept
        note = None
        if n in held and significant:
            note = held[n].reason()
        elif n in at_bound:
            note = at_bound[n].reason()
        elif n in dropped:
            origin = ("a forward-selection candidate" if n in steps and steps[n].accepted else
                      "a candidate of the fit-run replay check")
            note = (origin + ", dropped by the backward check on the holdout: "
                    + dropped[n].reason() + ("; listed under unidentifiable: the replay lacks its parameters "
                                             "these channels cannot identify"
                                             if n in stacks.identifiability.unconfirmed else "; not significant"))
        elif n in stacks.identifiability.not_excluded:
            note = f"not selected; listed under unidentifiable, not excluded: {stacks.identifiability.not_excluded[n]}"
        elif n in stacks.identifiability.stand_in:
            note = ("confirmed on the holdout, but "
                    + stacks.identifiability.reason(n).split(": it may stand in")[0]
                    + "; listed under unidentifiable, not significant")
        elif n in stacks.identifiability.hinged:
            note = ("not selected; listed under unidentifiable, "
                    + stacks.identifiability.reason(n).split(": whether it acts")[0])
        elif n in stacks.identifiability.form_alike:
            test = elim.last_test(n)
            note = (("confirmed on the holdout, but " if test is not None and test.passed else "")
                    + stacks.identifiability.reason(n).split(", so the runs")[0]
                    + "; listed under unidentifiable, not significant")
        elif n in stacks.identifiability.ambiguous:
            test = elim.last_test(n)
            note = (("confirmed on the holdout, but " if test is not None and test.passed else
                     "the look-alike of an effect confirmed on the holdout: ")
                    + stacks.identifiability.reason(n).split("; ")[0]
                    + "; listed under unidentifiable, not significant")
        ev = Evidence(sel.delta_bic[n], steps.get(n), elim.last_test(n), note)
        alts = tuple((a, fx.discriminating_manoeuvre(n, a)) for a in combo.indistinguishable.get(n, ())) \
            if significant else ()
        shown = combo.fit.params[n] if significant else (at_bound[n].fitted if n in at_bound
                                                         else sel.singles[n].params[n])
        end = top_end(shown, stacks.fit.s.eta[:, :3], _top_end_binds(stacks, n, combo, at_bound, sel)) \
            if n == TETHER else None
        out.append(EffectVerdict(
            name=n, significant=significant, params=shown if significant else {}, shrink=shrink[n],
            evidence=ev, meaning=inp.catalogue[n].meaning, fitted_params_if_added=None if significant else shown,
            indistinguishable_from=alts,
            wall=_wall_entry(combo.fit.params[n], stacks.fit.s, inp.p) if significant and n == "wall_effect"
            else None, not_identified=stacks.identifiability.entry(n).get("not_identified"),
            at_bound=at_bound[n].params if n in at_bound else None,
            at_bound_reason=at_bound[n].reason() if n in at_bound else None,
            replay_diverged_windows=diverged.get(n, 0),
            held_at_nominal=held[n].params if n in held and significant else None,
            top_end=end.to_json() if end is not None else None))
    return out


#: the verdict names, with why they are not significant, the effects outside the significant set that alone shrink the
#: holdout gap by more than this fraction of gap_before (at most ``NOT_NAMED_MAX`` of them), so that it never reads
#: as if nothing helped while the ranked table shows an effect that explains most of the gap
NOT_NAMED_SHRINK = 0.1
NOT_NAMED_MAX = 3


def not_named_reason(v: EffectVerdict) -> str:
    """Why an effect that is not significant was not named, in a few words (for the verdict line)."""
    if v.at_bound:
        return "its fit ends at the edge of its range"
    if "listed under unidentifiable" in (v.evidence.note or ""):  # set aside, not confirmable, not excluded
        return "listed under unidentifiable"
    if v.evidence.backward is not None:
        return "the holdout check dropped it"
    step = v.evidence.selection
    if step is None:
        return "the fit runs' equation error did not select it"
    return (f"forward selection did not accept it (dBIC {step.delta_bic:.0f}, holdout LR {step.holdout_lr:.1f}: the "
            f"equation error on the fit runs or the holdout does not support it)")


def verdict_line(kept, n_tested, before: GapScore, unexplained, at_bound=None, verdicts=()) -> str:
    """The report's one-line verdict (also the console's last word on significance).

    ``at_bound``: the confirmed effects set aside at the edge of their range (named with that reason);
    ``verdicts`` (:class:`EffectVerdict`): the effects not significant that alone shrink the holdout gap by more than
    ``NOT_NAMED_SHRINK`` are named too, with why they are not significant.
    """
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
    if at_bound:
        line += ("; at the edge of its range, so not named (a parameter at its bound is evidence of a missing term, "
                 "not a finding): " + ", ".join(at_bound))
    helpful = [v for v in verdicts if not v.significant and v.name not in (at_bound or {})
               and v.shrink is not None and np.isfinite(v.shrink) and v.shrink > NOT_NAMED_SHRINK]
    helpful = sorted(helpful, key=lambda v: -v.shrink)[:NOT_NAMED_MAX]
    if helpful and before.scored:
        line += "; alone " + "; ".join(f"{v.name} shrinks the holdout gap by {100 * v.shrink:.0f}% but is not "
                                       f"significant: {not_named_reason(v)}" for v in helpful)
    return line


def _method(window_s) -> dict:
    return {
        "gap": f"NRMSE of multiple-shooting replays ({window_s:g} s windows from the measured state, logged "
               f"commands held), RMS over the scored channels; channel scale = std of the measurement",
        "location": "channels ranked by their share of the excess of NRMSE^2 over the channel's noise floor "
                    "(the nominal replay re-measured with each channel's noise and replayed from noisy starts)",
        "fit": "equation error on residual generalised forces from Savitzky-Golay velocities, "
               "per-DOF noise variances estimated from the data",
        "significance": f"forward selection: BIC (N_eff = N / tau_int) drop > {BIC_STRONG:g} on the fit runs "
                        f"and a holdout equation-error likelihood ratio > {HOLDOUT_CHI2:g}; then backward "
                        f"elimination on the holdout: every significant effect, dropped from the final set (the "
                        f"rest refitted), raises the fit-run BIC, lowers the holdout equation-error likelihood by "
                        f"a ratio > "
                        f"{HOLDOUT_CHI2:g} (N_eff = N / tau_int) and raises the holdout replay gap by more than "
                        f"{100 * REPLAY_MATERIAL:g}% of gap_before (below {100 * REPLAY_LARGE:g}%: consistently "
                        f"over the windows, one-sided p < {REPLAY_P:g} and more than half of them worse), and alone it "
                        f"shrinks the holdout replay "
                        f"gap by more than {100 * REPLAY_MATERIAL:g}% (or, interacting with a partner, dropping it "
                        f"worsens at least {100 * CONSISTENT_WINDOWS:g}% of the windows, or raises the gap by more "
                        f"than {100 * REPLAY_LARGE:g}% with a window-by-window p < {INTERACTING_P:g}); the weakest "
                        f"failing one "
                        f"is dropped and the rest refitted until all pass, then each dropped effect is re-admitted "
                        f"once if, added back, every member passes",
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


def balance_of(inp: Inputs, where: Where, stacks: Stacks, elim: Elimination) -> SteadyBalance:
    """The report's ``steady_balance`` (:mod:`udrobot_ctrl.gap.balance`): the fit and holdout runs' steady flight
    with the nominal residuals of step 1 and the significant effects' force."""
    hooks = fitted_hooks(inp.catalogue, inp.p, stacks.actuation, elim.combination.fit, elim.kept) if elim.kept else ()
    n_fit = len(inp.fit)
    return steady_balance(inp.fit, inp.holdout, where.residuals[:n_fit], where.residuals[n_fit:], hooks, elim.kept)


def report_json(inp: Inputs, where: Where, stacks: Stacks, sel: Selection, elim: Elimination, verdicts, verdict,
                elapsed_s, support: ReplaySupport | None = None) -> dict:
    """The ``udrobot-diagnosis/1`` report (docs/formats/diagnosis.md) of the diagnosis' steps (not yet rounded)."""
    before, after = where.before, elim.after.gap
    return {
        "format": FORMAT,
        "model": inp.label,
        "fit_runs": [pr.name for pr in inp.fit],
        "holdout_runs": [pr.name for pr in inp.holdout],
        "gap_before": before.to_json(),
        "location": [x.to_json() for x in where.located.locations],
        "effects": [v.to_json() for v in verdicts],
        "unidentifiable": ranked_like(stacks.identifiability.report(), verdicts),
        "sensors": identifiability.sensors(inp.runs),
        "gap_after": after.to_json() | {"scored": before.scored},
        "unexplained": (after.value / before.value) if before.value > 0 else float("nan"),
        "remaining": [r.to_json() for r in remaining_gap(after, where.located.floor,
                                                          closed_loop_shares(inp.holdout))],
        "steady_balance": balance_of(inp, where, stacks, elim).to_json(),
        "heading_coverage": (hc.to_json() if (hc := headings_and_currents(inp, stacks, sel)) is not None else None),
        "parts": (pt.to_json() if (pt := named_parts(stacks.holdout, elim.combination.fit,
                                                     [v.name for v in verdicts if v.significant])) else None),
        "verdict": verdict,
        "location_detail": where.located.detail_json(),
        "noise": {"tau_int_samples": sel.tau_int, "n_eff": sel.n_eff, "n_samples": stacks.fit.N,
                  "sigma_residual_per_dof": dict(zip(fx.DOF, elim.combination.noise_sigma))},
        "method": _method(inp.window_s) | {"split": inp.notes[0]},
        "selection_steps": [asdict(s) for s in sel.steps],
        "replay_support": support.to_json() if support is not None else None,
        "backward_elimination": [r.to_json() for r in elim.rounds],
        "notes": inp.notes,
        "elapsed_s": elapsed_s,
    }


def _where_line(x) -> str:
    """One located channel for the console: its share of the excess, and its replay NRMSE against the floor when
    the channel is logged (a DOF ranked by its residual force may have no logged velocity channel)."""
    replay = (f"; replay NRMSE {_num(x.nrmse, '.3g')}, floor {_num(x.floor, '.3g')}"
              if x.nrmse is not None and math.isfinite(x.nrmse) else "; channel not logged: ranked by its force")
    return f"{x.channel} ({100 * x.share:.0f}% of the excess over the noise floor{replay})"


@dataclass(frozen=True)
class Pass:
    """One pass of locate -> attribute -> shrink and confirm over prepared runs."""

    where: Where
    stacks: Stacks
    sel: Selection
    shrink: Mapping  # name -> shrink of the effect alone (OnDemand)
    elim: Elimination  # the significant set (ambiguous effects and effects at a bound set aside)
    confirmed: Elimination  # what the holdout confirmed, before the ambiguous effects were set aside
    at_bound: Mapping = field(default_factory=dict)  # name -> AtBound: confirmed, set aside at the edge of its range
    singles: Mapping = field(default_factory=dict)  # name -> its single-effect holdout Replay (OnDemand)
    support: ReplaySupport | None = None  # step 2b: the fit-run replay check of the selected set
    held: Mapping = field(default_factory=dict)  # name -> HeldAtNominal: named with amplitudes held at nominal


def pass_disagreements(first: Elimination, second: Pass, skip=()) -> dict:
    """Effects the two reconstruction passes judge differently: the first (``first``: velocities smoothed with the
    nominal plant) confirmed it on the holdout; the ``second`` (smoothed with the confirmed effects' force) selected
    it again and its replay still does better with it (dropping it raises the holdout gap), but not enough to
    confirm it, and it neither lists it nor sets it aside at a bound. Where the second pass contradicts the first
    (not selected, or the replay as good or better without it) the second, better reconstruction stands and nothing
    is listed. Returns name -> :class:`~udrobot_ctrl.gap.identifiability.PassDisagreement`; ``skip``: names left
    out (those the first pass set aside at a bound)."""
    listed = second.stacks.identifiability
    dropped = second.elim.dropped
    out = {}
    for n in first.kept:
        t1, t2 = first.last_test(n), dropped.get(n)
        if (t1 is None or t2 is None or not t2.gap_contribution > 0 or n in listed.names or n in second.at_bound
                or n in skip):
            continue
        out[n] = identifiability.PassDisagreement(
            f"dropping it raised the holdout replay gap by {100 * t1.gap_contribution:.1f}% of gap_before, "
            f"p {t1.replay_p:.2g}", f"the holdout check dropped it: {t2.reason()}")
    return out


def diagnosis_pass(inp: Inputs, say, t0, prior_ambiguous=None, prior_forms=None, prior_stand_ins=None) -> Pass:
    """Steps 1-3 of :func:`diagnose` on ``inp``'s prepared runs (``prior_ambiguous``, ``prior_forms``,
    ``prior_stand_ins``: the effects the first reconstruction pass set aside, see :func:`set_aside_ambiguous` and
    :func:`set_aside_stand_ins`)."""
    # the nominal replays and their noise floor in a worker while the fits run (the console story keeps its order)
    locating = Background(lambda: locate_gap(inp))
    stacks = build_stacks(inp)
    # the effects the runs cannot identify are searched in a helper process, beside the others' fits (stopped below)
    stacks.fit.delegate(stacks.identifiability.names)
    try:
        return _diagnosis_steps(inp, say, t0, locating, stacks, prior_ambiguous, prior_forms, prior_stand_ins)
    finally:
        stacks.fit.delegate(())


def _diagnosis_steps(inp: Inputs, say, t0, locating: Background, stacks: Stacks, prior_ambiguous, prior_forms,
                     prior_stand_ins) -> Pass:
    """:func:`diagnosis_pass` once the stacks are built (``locating``: the pending :func:`locate_gap`)."""
    lines = []  # said once the gap is located (the console story keeps its order)
    unidentifiable = stacks.identifiability.names
    if unidentifiable:
        lines.append(f"not identifiable from the observed channels ({', '.join(stacks.identifiability.observed_dofs())}"
                     f"): {', '.join(unidentifiable)} (never significant; see the report's unidentifiable list)")
    for n, chk in stacks.identifiability.effects.items():
        if chk.actuators is not None:
            lines.append(f"{n}: {chk.actuators.describe()}")
        for k, form in chk.forms.items():
            lines.append(f"{n}: searched with {k} = {form.kept:g} only (at {form.other:g} it hinges on a velocity the "
                         f"channels do not measure; see its not_identified entry)")
    sel = attribute(stacks, inp.names, log=lines.append)
    where = locating.result()
    sel, support = replay_supported(inp, stacks, sel, where, log=lines.append)
    say("where: " + (", ".join(_where_line(x) for x in where.located.locations) or "no channel above its noise floor"))
    for line in lines:
        say(line)
    say(f"candidates (forward selection on the fit runs, {len(inp.names) - len(unidentifiable)} identifiable "
        f"effects tested): {', '.join(sel.proposed) or 'none'} ({time.perf_counter() - t0:.1f} s)")

    singles = shrink_each(inp, stacks, sel, where.before)
    b = where.before.value

    def shrinks(names):
        singles.fill(names)
        return {n: (1 - singles[n].gap.value / b) if b > 0 else 0.0 for n in names}
    shrink = OnDemand(inp.names, shrinks)
    confirmed = confirm(inp, stacks, sel, where, singles, log=say)
    elim, stacks = set_aside_ambiguous(inp, stacks, where, confirmed, log=say, prior=prior_ambiguous, shrink=shrink,
                                       prior_forms=prior_forms)
    stacks = set_aside_unconfirmed(stacks, sel, where, elim, log=say)
    elim, stacks = set_aside_stand_ins(inp, stacks, where, elim, log=say, prior=prior_stand_ins)
    elim, at_bound, held, stacks = set_aside_at_bound(inp, stacks, where, elim, log=say)
    elim, held, stacks = confirm_components(inp, stacks, where, elim, held, log=say)
    return Pass(where, stacks, sel, shrink, elim, confirmed, at_bound, singles, support, held)


@dataclass(frozen=True)
class AtBound:
    """A confirmed effect whose joint fit ended on the edge of the catalogue's range for some parameter."""

    params: dict  # parameter -> (value, bound) (:meth:`~udrobot_ctrl.gap.attribute.Attributor.at_bounds`)
    fitted: dict  # the effect's parameters in that fit

    def reason(self) -> str:
        """Why the effect is not significant (the report's ``at_bound_reason``)."""
        where = ", ".join(f"{k} = {v:.4g} at its bound {b:.4g}" for k, (v, b) in self.params.items())
        return (f"confirmed on the holdout, but its fit ends at the edge of the catalogue's range ({where}): a "
                f"parameter at its bound is evidence of a missing term, not a finding (the effect stands in for "
                f"something the catalogue lacks, or the truth lies beyond the physical range searched); not "
                f"significant and not written to a corrected model")


@dataclass(frozen=True)
class HeldAtNominal:
    """Amplitudes of a named per-DOF effect (:attr:`~udrobot_ctrl.gap.effects.Effect.per_dof`) held at nominal while
    the rest of the effect stands: their joint fit ended on their bound (:func:`hold_at_nominal`), or the holdout
    does not confirm them on their own (:func:`confirm_components`)."""

    params: dict  # parameter -> (fitted value, its bound where the fit ended on it, else None)
    test: MemberTest  # the effect's holdout check in the set, refitted with them held
    components: dict = field(default_factory=dict)  # parameter -> MemberTest of holding it alone (the unconfirmed)

    def held(self, more: dict, test: MemberTest, components=None) -> HeldAtNominal:
        """These and ``more`` held, ``test`` the effect's check with all of them held."""
        return HeldAtNominal({**self.params, **more}, test, {**self.components, **(components or {})})

    def reason(self) -> str:
        """The report's note on the effect."""
        why = []
        for k, (v, b) in self.params.items():
            if b is not None:
                why.append(f"{k} (its fit ended at its bound {b:.4g}: evidence of a missing term in its DOF, not a "
                           f"finding)")
            else:
                why.append(f"{k} (fitted {v:.4g}, not confirmed on the holdout on its own: "
                           f"{self.components[k].reason()})")
        return (f"held at nominal: {'; '.join(why)}; the rest of the effect, refitted without them, is confirmed on "
                f"the holdout (dropping it raises the holdout replay gap by {100 * self.test.gap_contribution:.1f}% "
                f"of gap_before, holdout equation-error likelihood ratio {self.test.holdout_lr:.1f}); the held "
                f"parameters stay nominal in the corrected model")


def _frozen(eff: fx.Effect, params) -> identifiability.Restricted:
    """``eff`` with its amplitudes ``params`` frozen at zero (held at nominal) beside any restriction it has
    (:class:`~udrobot_ctrl.gap.identifiability.Restricted`)."""
    return (eff.freezing(params) if isinstance(eff, identifiability.Restricted)
            else identifiability.Restricted(eff, tuple(params)))


def _holding(stacks: Stacks, name, params) -> Stacks:
    """``stacks`` with effect ``name``'s amplitudes ``params`` held at nominal (:func:`_frozen`) in both attributors."""
    held = _frozen(stacks.fit.cat[name], params)
    return replace(stacks, fit=stacks.fit.with_effect(name, held), holdout=stacks.holdout.with_effect(name, held))


def _free_amplitudes(stacks: Stacks, elim: Elimination, name) -> list:
    """The amplitudes of member ``name`` fitted non-zero and not frozen."""
    eff = stacks.fit.cat[name]
    params = elim.combination.fit.params[name]
    frozen = eff.frozen if isinstance(eff, identifiability.Restricted) else ()
    names = stacks.fit.design(name, elim.combination.fit.shapes[name]).names
    return [a for a in names if a not in frozen and params.get(a, 0.0) != 0.0]


def _effect_test(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, name) -> MemberTest:
    """The member ``name``'s holdout check in ``elim``'s set (:func:`~udrobot_ctrl.gap.confirm.check_members`)."""
    return check_members(stacks.fit, stacks.holdout, elim.combination, elim.after, where.before,
                         _replayer(inp, stacks, where.before.scored), inp.window_s, inp.holdout, names=(name,))[0]


def _refinalized(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination) -> Elimination:
    """``elim`` with its set fitted again on ``stacks`` and replayed on the holdout."""
    combo = finalize(stacks.fit, elim.kept, inp.names)
    return replace(elim, combination=combo,
                   after=_replayer(inp, stacks, where.before.scored)(combo.fit, combo.members))


def confirm_components(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, held: dict, log=None):
    """Step 3f: each amplitude of a significant per-DOF effect (:attr:`~udrobot_ctrl.gap.effects.Effect.per_dof`)
    with more than one fitted, checked on the holdout on its own: the set refitted with it held at nominal (the
    other amplitudes free), replayed, and compared with the set as it is by the test that drops a member
    (:func:`~udrobot_ctrl.gap.confirm.member_test`: fit-run BIC, holdout equation-error likelihood ratio, holdout
    replay). The holdout confirms a member as a whole; without this a wrong component rides along with a right one
    (a pitch drag scale of -0.83 beside the heave drag error of a 6-thruster dive whose truth has none). The
    amplitudes that fail are held at nominal together (each acts in its own DOF), the set refitted, and the check
    repeated on the rest until every one left passes.

    Returns
    -------
    elim : Elimination
        The set refitted and replayed with the held amplitudes (unchanged when none).
    held : dict
        Name -> :class:`HeldAtNominal`, ``held`` with these added.
    stacks : Stacks
        With the held forms.
    """
    held = dict(held)
    for n in elim.kept:
        if not stacks.fit.cat[n].per_dof:
            continue
        while len(free := _free_amplitudes(stacks, elim, n)) > 1:
            # each amplitude held alone, on the fit runs only (the holdout scores the fit's parameters as they are)
            fits = {a: refit(stacks.fit.with_effect(n, _frozen(stacks.fit.cat[n], [a])), elim.kept,
                             elim.combination.fit.shapes) for a in free}
            replays = _replayer(inp, stacks, where.before.scored).many([(f, elim.kept) for f in fits.values()])
            tests = {a: member_test(stacks.fit, stacks.holdout, elim.combination.fit, elim.after, a, fits[a], r,
                                    where.before, inp.window_s, inp.holdout) for a, r in zip(free, replays)}
            failing = [a for a in free if not tests[a].passed]
            if log:
                log(f"  component check: {n}: " + ", ".join(
                    f"{a} {100 * tests[a].gap_contribution:+.1f}% ({'confirmed' if tests[a].passed else 'fails'})"
                    for a in free))
            if not failing or len(failing) == len(free):  # none to hold, or none would be left to name
                break
            more = {a: (elim.combination.fit.params[n][a], None) for a in failing}
            stacks = _holding(stacks, n, failing)
            elim = _refinalized(inp, stacks, where, elim)
            test = _effect_test(inp, stacks, where, elim, n)
            failed = {a: tests[a] for a in failing}
            held[n] = held[n].held(more, test, failed) if n in held else HeldAtNominal(more, test, failed)
            if log:
                log(f"  held at nominal: {', '.join(failing)} of {n} (not confirmed on the holdout on their own); "
                    f"the rest refitted: " + ", ".join(f"{a} = {elim.combination.fit.params[n][a]:.4g}"
                                                       for a in free if a not in failing))
    return elim, held, stacks


def hold_at_nominal(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, name, bound: dict, log=None):
    """Step 3e, first: the confirmed per-DOF effect ``name`` (:attr:`~udrobot_ctrl.gap.effects.Effect.per_dof`: a
    damping or added-mass scale per DOF) whose amplitudes ``bound`` (parameter -> (value, bound)) ended on their
    bound, refitted with them held at nominal (frozen at zero: :class:`~udrobot_ctrl.gap.identifiability.Restricted`)
    beside the set's other members, and checked on the holdout as any member is
    (:func:`~udrobot_ctrl.gap.confirm.check_members`): a heave drag error need not be thrown away because the pitch
    scale beside it ran to its bound. Only when at most half of its fitted amplitudes are at a bound: when most of an
    effect's DOFs run to their bounds, the effect as a whole stands in for something the catalogue lacks (on a
    BlueROV2 surface log, 4 of 6 added-mass scales at their bounds beside surge and sway scales of +190 % and +160 %).

    Returns
    -------
    (Stacks, Elimination, MemberTest) or None
        The stacks with the held form of the effect, the set refitted and replayed with it, and its test; None when
        ``bound`` holds a shape parameter, when fewer of the effect's other amplitudes were fitted, or the refitted
        effect fails the holdout check.
    """
    amplitudes = stacks.fit.design(name, elim.combination.fit.shapes[name]).names
    rest = [a for a in _free_amplitudes(stacks, elim, name) if a not in bound]
    if not (stacks.fit.cat[name].per_dof and set(bound) <= set(amplitudes) and len(bound) <= len(rest)):
        return None
    st = _holding(stacks, name, bound)
    trial = _refinalized(inp, st, where, elim)
    test = _effect_test(inp, st, where, trial, name)
    if log:
        log(f"  held at nominal: {', '.join(bound)} of {name} (its fit ended at its bound); refitted without it: "
            + (f"confirmed ({', '.join(f'{a} = {trial.combination.fit.params[name][a]:.4g}' for a in rest)})"
               if test.passed else f"fails ({test.reason()})"))
    if not test.passed:
        return None
    return st, trial, test


def _top_end_binds(stacks: Stacks, n, combo, at_bound, sel) -> bool:
    """Whether the tether fit shown for ``n`` wants its top end deeper than the search's limit (read by
    :func:`~udrobot_ctrl.gap.top_end.top_end`): the anchor depth among its parameters at a bound
    (:meth:`~udrobot_ctrl.gap.attribute.Attributor.at_bounds`, which counts that bound only where it binds) for the
    confirmed set's fit or the single fit; for an effect set aside at a bound, as recorded there."""
    depth = TETHER_ANCHOR[2]
    if n in at_bound:
        return depth in at_bound[n].params
    fit = combo.fit if n in combo.members else sel.singles.get(n)
    return fit is not None and depth in stacks.fit.at_bounds(fit, n)


def set_aside_at_bound(inp: Inputs, stacks: Stacks, where: Where, elim: Elimination, log=None):
    """Step 3e: a confirmed effect whose joint fit ends on a bound of its search
    (:meth:`~udrobot_ctrl.gap.attribute.Attributor.at_bounds`: a dead band at 35 % of the command range, an added
    mass at -90 %) is not significant: a parameter at its bound is evidence of a missing term, not a finding. A
    per-DOF effect whose parameters at a bound are some of its amplitudes is first refitted with those held at
    nominal (:func:`hold_at_nominal`), and kept when the rest is confirmed on the holdout; else it is removed from
    the set, the rest refitted and replayed, until no member ends on a bound.

    Returns
    -------
    elim : Elimination
        Without the effects at a bound (unchanged when there are none).
    at_bound : dict
        Name -> :class:`AtBound`, in the order they were set aside.
    held : dict
        Name -> :class:`HeldAtNominal`: the members kept with some amplitudes held at nominal.
    stacks : Stacks
        With the held form of those members (the same stacks when none).
    """
    found, held = {}, {}
    while elim.kept:
        hits = {n: b for n in elim.kept if (b := stacks.fit.at_bounds(elim.combination.fit, n))}
        if not hits:
            break
        kept_held = None
        for n, b in hits.items():
            kept_held = hold_at_nominal(inp, stacks, where, elim, n, b, log=log)
            if kept_held is not None:
                stacks, elim, test = kept_held
                held[n] = held[n].held(b, test) if n in held else HeldAtNominal(dict(b), test)
                break
        if kept_held is not None:  # the set was refitted: check its bounds again
            continue
        for n, b in hits.items():
            found[n] = AtBound(b, dict(elim.combination.fit.params[n]))
            held.pop(n, None)
            if log:
                log(f"  set aside: {n} (its fit ends at the edge of its range: "
                    + ", ".join(f"{k} = {v:.4g}" for k, (v, _) in b.items())
                    + "; a parameter at its bound is evidence of a missing term, not a finding)")
        rest = [k for k in elim.kept if k not in hits]
        combo = finalize(stacks.fit, rest, inp.names)
        after = (_replayer(inp, stacks, where.before.scored)(combo.fit, combo.members) if rest else
                 Replay((), where.before, where.nominal_sims[len(inp.fit):]))
        elim = replace(elim, kept=tuple(rest), combination=combo, after=after)
    return elim, found, held, stacks


@dataclass(frozen=True)
class Diagnosis:
    """The result of :func:`diagnose`: the ``udrobot-diagnosis/1`` report and what its figures need.

    Unpacks as ``report, context = diagnose(...)`` (the form before this result had a name).

    Parameters
    ----------
    report : dict
        The report, JSON-ready (docs/formats/diagnosis.md): what the CLI writes with ``--json``.
    context : DiagnosisContext
        The prepared runs and replays the figures are drawn from (:func:`udrobot_ctrl.gap.plots.write_plots`).
    """

    report: dict
    context: DiagnosisContext

    def __iter__(self):
        return iter((self.report, self.context))

    @property
    def significant(self) -> tuple:
        """Names of the significant effects, most explanatory first."""
        return tuple(e["name"] for e in self.report["effects"] if e["significant"])

    @property
    def unexplained(self) -> float:
        """``gap_after.value / gap_before.value`` on the holdout runs (nan when the gap is undefined)."""
        v = self.report.get("unexplained")
        return float("nan") if v is None else float(v)

    def to_json(self) -> str:
        """The report as the JSON text ``--json`` writes."""
        return json.dumps(self.report, indent=2) + "\n"

    def summary(self) -> str:
        """The human-readable summary the CLI prints (:func:`summary`)."""
        return summary(self.report)

    def write(self, path, protect=()) -> None:
        """Write the report to ``path`` atomically, never over a file in ``protect`` (:func:`write_report`)."""
        write_report(self.report, path, protect=protect)

    def plot(self, directory, protect=()) -> list:
        """Write the residual and overlay figures into ``directory``; returns their paths
        (:func:`udrobot_ctrl.gap.plots.write_plots`)."""
        return write_plots(self.context, self.report, directory, protect=protect)


def diagnose(model, runs, holdout=None, window_s=8.0, effects=None, log=None, model_label=None, selection=False):
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
    selection : bool
        Also compute the one-criterion selection table on the fit runs (:mod:`udrobot_ctrl.gap.decide`) and report
        it as ``selection`` beside the verdict (experimental: it does not decide; several times the run time).

    Returns
    -------
    Diagnosis
        The ``udrobot-diagnosis/1`` report and what its figures need (unpacks as ``report, context``).

    Notes
    -----
    BLAS runs on one thread throughout (:func:`~udrobot_ctrl.parallel.one_blas_thread`): the work is spread over
    worker processes instead, and the report does not depend on how many there are.
    """
    with one_blas_thread():
        return Diagnosis(*_diagnose(model, runs, holdout, window_s, effects, log, model_label, selection))


def _diagnose(model, runs, holdout, window_s, effects, log, model_label, selection=False):
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

    res = diagnosis_pass(inp, say, t0)
    shadow = table_decision(inp, res.stacks, res.where, log=say) if selection else None
    if shadow is not None:
        say(f"selection table (not the verdict): best {shadow.best.members}, named {shadow.named}, "
            f"inclusion {dict((k, round(v, 3)) for k, v in shadow.inclusion.items() if v > 0.01)} "
            f"({time.perf_counter() - t0:.1f} s)")
    # the force the holdout confirmed improves the reconstruction whichever effect it is named as (an ambiguous
    # effect is set aside from the verdict, not from the plant that smooths the velocities)
    if reconstructed(inp) and res.confirmed.kept:
        first, nominal, first_at_bound = res.confirmed, inp, res.at_bound
        say(f"reconstruction, pass 2: the unlogged velocities smoothed again with the force of "
            f"{', '.join(first.kept)} added to the nominal plant; the diagnosis repeated on them")
        inp = reconstruct_with(inp, res.stacks.actuation, first.combination.fit, first.kept)
        pass1 = res.stacks.identifiability
        set_aside = {k: pass1.ambiguous[k] for k in first.kept if k not in res.elim.kept and k in pass1.ambiguous}
        set_forms, set_stand = dict(pass1.form_alike), dict(pass1.stand_in)
        res = diagnosis_pass(inp, say, t0, prior_ambiguous=set_aside, prior_forms=set_forms,
                             prior_stand_ins=set_stand)
        # what pass 1 set aside stays listed: pass 2 smoothed with its force, so its residual is gone from there
        listed = res.stacks.identifiability
        left = {k: v for k, v in set_aside.items() if k not in listed.ambiguous}
        left_forms = {k: a for k, a in set_forms.items() if k not in listed.names and k not in res.elim.kept}
        left_stand = {k: a for k, a in set_stand.items() if k not in listed.names and k not in res.elim.kept}
        if left or left_forms or left_stand:
            say(f"  still set aside from pass 1: {', '.join([*left, *left_forms, *left_stand])} (the runs cannot say "
                f"which of them and their look-alikes acts)")
            res = replace(res, stacks=replace(res.stacks, identifiability=listed.with_ambiguous(left)
                                              .with_form_alike(left_forms).with_stand_in(left_stand)))
        disagree = pass_disagreements(first, res, skip=first_at_bound)
        if disagree:
            say(f"  listed, the two reconstruction passes disagree: {', '.join(disagree)} (confirmed on the holdout "
                f"in pass 1, not in pass 2)")
            res = replace(res, stacks=replace(res.stacks, identifiability=res.stacks.identifiability
                                              .with_pass_disagreement(disagree)))
        inp = replace(inp, notes=inp.notes + [
            f"reconstruction: the unlogged velocities were smoothed twice, first with the nominal plant (confirmed "
            f"on the holdout then: {', '.join(first.kept)}), then with those effects' force added (significant: "
            f"{', '.join(res.elim.kept) or 'none'}); the report is that of the second pass"])
        if res.elim.kept:  # gap_after as `simulate --windows` replays the corrected model: reconstructed with it
            final = reconstruct_with(nominal, res.stacks.actuation, res.elim.combination.fit, res.elim.kept, "holdout")
            res = replace(res, elim=replace(res.elim, after=_replayer(final, res.stacks, res.where.before.scored)(
                res.elim.combination.fit, res.elim.kept)))
    where, stacks, sel, elim, shrink = res.where, res.stacks, res.sel, res.elim, res.shrink
    after = elim.after.gap
    unexplained = (after.value / where.before.value) if where.before.value > 0 else float("nan")
    verdicts = effect_verdicts(inp, stacks, sel, elim, shrink, res.at_bound, res.singles, held=res.held)
    verdict = verdict_line(elim.kept, len(inp.names), where.before, unexplained, at_bound=res.at_bound,
                           verdicts=verdicts)
    after_sims = elim.after.sims if elim.kept else where.nominal_sims[len(inp.fit):]
    domain = replay_domain(inp, where.nominal_sims, after_sims if elim.kept else None)
    verdict += domain_caveat(domain)
    say(f"{verdict} ({time.perf_counter() - t0:.1f} s)")

    location = [x.to_json() for x in where.located.locations]
    inp = replace(inp, notes=inp.notes + _not_diagnosed_notes(skipped))
    report = report_json(inp, where, stacks, sel, elim, verdicts, verdict, time.perf_counter() - t0,
                         support=res.support)
    report.update(_not_diagnosed_fields(skipped))
    report["replay_domain"] = domain
    if shadow is not None:
        report["selection"] = shadow.to_json()
    ctx = DiagnosisContext(inp.runs, len(inp.fit), where.nominal_sims, after_sims, where.residuals, location)
    return _clean(report), ctx


def table_decision(inp: Inputs, stacks: Stacks, where: Where, log=None) -> decide.Decision:
    """The one decision (:mod:`udrobot_ctrl.gap.decide`) on the fit runs only: every identifiable effect searched,
    each set scored by the fit runs' output-error BIC of its replays."""
    nf = len(inp.fit)
    nominal = where.nominal_sims[:nf]
    channels = gap(inp.fit, nominal).scored
    replay = _replayer(inp, stacks, channels, runs=inp.fit).many
    names = [n for n in inp.names if n not in stacks.identifiability.names]
    return decide.decision(decide.search(stacks.fit, replay, inp.fit, channels, nominal, names, log=log))


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
        back = e["evidence"].get("backward_elimination")
        tag = "SIGNIFICANT" if e["significant"] else ("AT BOUND" if e.get("at_bound_reason") else
                                                      "dropped" if back else "-")
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
        if e.get("held_at_nominal"):
            extra += "; held at nominal: " + ", ".join(e["held_at_nominal"])
        lines.append(f"  {e['name']:<26s} {tag:<11s} shrink {_num(e['shrink'], '+.2f')}  "
                     f"dBIC {_num(e['evidence']['delta_bic'], '.0f')}{extra}")
        if e["significant"]:
            lines.append("      params " + ", ".join(f"{k}={_num(v, '.4g')}" for k, v in e["params"].items()))
            if (report.get("parts") or {}).get("holdout_params", {}).get(e["name"]):
                lines.append("      fitted on the holdout runs apart: " + ", ".join(
                    f"{k}={_num(v, '.4g')}" for k, v in report["parts"]["holdout_params"][e["name"]].items()))
            if e.get("held_at_nominal"):
                lines.append("      " + e["evidence"].get("note", ""))
        elif e.get("at_bound_reason"):
            lines.append("      " + e["at_bound_reason"])
            lines.append("      fitted " + ", ".join(f"{k}={_num(v, '.4g')}"
                                                     for k, v in (e.get("fitted_params_if_added") or {}).items()))
        elif back:
            lines.append("      " + e["evidence"].get("note", "dropped on the holdout"))
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
