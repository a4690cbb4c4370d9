"""Which catalogue effects the runs' observed channels can identify: one test over every effect's regressors.

The equation-error fit scores only the *observed* DOFs (a sensor measures the velocity or its integral, see
:data:`udrobot_ctrl.gap.data.OBSERVING`); the velocities of the other DOFs are *reconstructed* by the model-based
smoother (:mod:`udrobot_ctrl.gap.smoother`) with a posterior standard deviation. For each parameter of an effect
(each amplitude column of its design ``A`` and, for shape-only forms such as a lag or a current, the shape term
``b0``), evaluated on the fit stack at a few shapes of its grid:

* **share**: the part of the regressor's energy, each DOF normalised by its noise (``M_ii`` times the smoother's
  posterior std of the unmodelled acceleration, :func:`noise_scale`), that lies in observed DOFs. Below
  :data:`SHARE_MIN` the parameter acts mostly where nothing is measured.
* **sensitivity**: the relative change of the regressor in the observed DOFs when the reconstructed states are
  moved by one posterior standard deviation (each reconstructed velocity in turn, and the dead-reckoned
  position by the integral of the horizontal velocity's std): a coherent offset, the way a reconstruction
  errs. Above :data:`SENSITIVITY_MAX` the regressor hinges on a state no sensor pins down, so a fit would
  identify the reconstruction, not the effect.
* a regressor that is zero on the data (e.g. a wall effect with no known distance to any surface) identifies
  nothing.

A parameter is identified when its regressor is non-zero, its share is at least ``SHARE_MIN`` and its
sensitivity at most ``SENSITIVITY_MAX``. An effect with no identified parameter is *unidentifiable*: it is
listed with the reason and the measurement that would fix it, excluded from selection and never significant.
An effect identified in part stays testable with its non-identified amplitude parameters frozen at zero
(:meth:`Identifiability.restrict`). With every DOF observed and nothing reconstructed, the only possible
finding is a vanishing regressor.

A *per-actuator* effect (``Effect.per_actuator``: a thruster map, a lag, an inflow loss) has parameters shared by
every actuator, so it is judged on what the observed DOFs see of it: when the whole leaves a parameter unidentified,
the actuators are grouped by the observed DOFs their force acts on and each group's part is checked alone. If some
groups identify it and the others, acting on other observed DOFs, identify nothing (without a DVL, the surge
thrusters' inflow loss lies mostly in the unobserved surge and its yaw moment hinges on the reconstructed surge speed,
while the vertical thrusters' acts on the observed heave and roll), the effect is identified and fitted on the part of
the groups that identify it (:class:`ActuatorCheck`, :meth:`Identifiability.restrict`); its replay still applies the
fitted parameters to every actuator. An effect none of whose groups identifies anything keeps the whole's verdict.

A *form* parameter (``Effect.physical_ends``: each end of its range is a physical form, e.g. a quadratic damping
error on each axis' speed or on the vehicle's speed) is checked at each end: when the effect is identified in
one form and not in the other (the speed-norm drag of heave hinges on the surge speed, which a stock vehicle does
not measure), the search keeps the identified form only, and the report lists the form parameter as not
identified with the reason.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import DesignStore
from udrobot_ctrl.gap.data import OBSERVING, VEL
from udrobot_ctrl.gap.smoother import SmootherSettings

#: a parameter with less than a quarter of its noise-normalised regressor energy in observed DOFs is not identified:
#: the observed part is then a side effect of what it does where nothing is measured (a thruster parameter shared by
#: horizontal and vertical thrusters is judged on the thrusters whose part the observed DOFs see: :func:`_by_actuator`)
SHARE_MIN = 0.25
#: a regressor that changes by more than 30 % (RMS, observed DOFs) when a reconstructed state moves by its
#: reconstruction error hinges on that reconstruction: its fitted amplitude would be off by as much
SENSITIVITY_MAX = 0.3
#: energy below this fraction of the largest column energy of all effects is "zero on the data"
VANISH = 1e-12
N_SHAPES = 3  # grid shapes probed per effect: first, middle, last
#: a parameter acts in a DOF that holds at least this share of its noise-normalised regressor energy (its RMS there is
#: then at least 14 % of its overall RMS: a heave added mass whose energy lies mostly in the Munk moments still acts
#: on the heave force)
ACTS_SHARE = 0.02

#: what measures each DOF's velocity (for the reason): DOF groups -> (what is missing, how to fix it)
MISSING = {
    "horizontal": ("horizontal velocity is not observed: no DVL or positioning in these runs",
                   "log u, v (DVL) or x, y (USBL)"),
    "heave": ("heave velocity is not observed: no DVL and no depth in these runs", "log w (DVL) or z (depth)"),
    "roll": ("roll rate is not observed", "log p (gyro) or phi (attitude)"),
    "pitch": ("pitch rate is not observed", "log q (gyro) or theta (attitude)"),
    "yaw": ("yaw rate is not observed", "log r (gyro) or psi (heading)"),
    "position": ("the horizontal position is not observed (only dead-reckoned)", "log x, y (USBL)"),
    # an attitude DOF a sensor observes but the equation error leaves out (gap.data.without_stabilised)
    "stabilised": ("the autopilot stabilised the attitude and its outputs are logged slower than its loop, so "
                   "the moment it applied between samples is not in the log (equation error without that DOF)",
                   "log the motor outputs faster than the attitude loop's time constant 1 / ATC_ANG_*_P "
                   "(dataflash RCOU at 10 Hz, or a faster SERVO_OUTPUT_RAW stream), or fly a stretch in MANUAL"),
}
DOF_GROUP = ("horizontal", "horizontal", "heave", "roll", "pitch", "yaw")
#: a DOF observed through an integral only (depth for heave, x/y for the horizontal) still has its velocity
#: reconstructed by the smoother: a regressor that hinges on that reconstruction gets this cause, not "not observed"
VELOCITY_SENSOR = {"horizontal": "u, v (DVL)", "heave": "w (DVL)", "roll": "p (gyro)", "pitch": "q (gyro)",
                   "yaw": "r (gyro)"}
RECONSTRUCTED = {g: f"{g} (reconstructed)" for g in VELOCITY_SENSOR}
MISSING.update({RECONSTRUCTED[g]: (f"its force in the observed DOFs hinges on the {g} velocity, which the smoother "
                                   f"reconstructs from its integral with too large an error", f"log {v} directly")
                for g, v in VELOCITY_SENSOR.items()})
#: the DOF groups (keys of :data:`MISSING`) a logged column would observe (:data:`udrobot_ctrl.gap.data.OBSERVING`;
#: x, y also the position)
COLUMN_GROUPS = {c: (DOF_GROUP[i],) + (("position",) if c in ("x", "y") else ()) for i, cols in OBSERVING.items()
                 for c in cols}
#: structured reason codes of an ``unidentifiable`` entry's ``missing`` list (:meth:`Identifiability.missing`)
NOT_OBSERVED, UNAIDED_ESTIMATE, RECONSTRUCTED_CODE, STABILISED, NOT_EXCITED = (
    "not_observed", "unaided_estimate", "reconstructed", "stabilised", "not_excited")


def describe_missing(item: dict) -> str:
    """One ``missing`` item (:meth:`Identifiability.missing`) as a sentence, for the console."""
    code = item["code"]
    if code == UNAIDED_ESTIMATE:
        return (f"{item['column']} is logged but is an estimate without aiding ({item['source']}: {item['why']}), so "
                f"it is not counted as observed")
    if code == NOT_OBSERVED:
        return f"{item['dofs']}: {MISSING[item['dofs']][0]}"
    if code == RECONSTRUCTED_CODE:
        return MISSING[RECONSTRUCTED[item['dofs']]][0]
    if code == STABILISED:
        return MISSING["stabilised"][0]
    return "its regressors are zero on these runs (nothing it acts on is present)"


@dataclass
class ParameterCheck:
    """Identifiability of one parameter (an amplitude column, or an effect's shape term).

    Attributes
    ----------
    name : str
    share : float
        Noise-normalised regressor energy in observed DOFs / total (0-1).
    sensitivity : float
        Largest relative RMS change of the regressor in observed DOFs under a one-std move of a reconstructed
        state.
    identified : bool
    causes : tuple of str
        Keys of :data:`MISSING` (or ``"vanishes"``) that make it non-identified.
    """

    name: str
    share: float
    sensitivity: float
    identified: bool
    causes: tuple = ()
    #: share of its noise-normalised regressor energy in each DOF (X Y Z K M N; empty when it vanishes)
    dof_share: tuple = ()


@dataclass(frozen=True)
class FormCheck:
    """A form parameter held at one end of its range: the channels identify fewer of the effect's parameters at the
    other end.

    Attributes
    ----------
    kept : float
        The end the search keeps.
    other : float
        The end it does not search.
    causes : tuple of str
        Keys of :data:`MISSING` for the parameters the other end loses.
    dof_share : tuple of float
        Per DOF (X Y Z K M N), the largest share of noise-normalised regressor energy there of the parameters the
        other end loses (where the untested form would act).
    """

    kept: float
    other: float
    causes: tuple = ()
    dof_share: tuple = ()


@dataclass(frozen=True)
class ActuatorCheck:
    """A per-actuator effect (:attr:`udrobot_ctrl.gap.effects.Effect.per_actuator`) judged on the part of it that the
    observed DOFs see: its parameters are shared by every actuator, and the fit reads only the groups of actuators
    (by the observed DOFs they act on) whose part identifies them.

    Attributes
    ----------
    kept : tuple of int
        The actuators (indices) whose part the fit reads.
    left : tuple of int
        The active actuators whose part identifies nothing (it acts where nothing is measured, or hinges on a
        reconstructed state); the fitted parameters still act on them in a replay.
    causes : tuple of str
        Keys of :data:`MISSING` that make the ``left`` actuators' parts non-identified.
    """

    kept: tuple
    left: tuple
    causes: tuple = ()

    def describe(self) -> str:
        """One line for the console: which actuators the fit reads, and why not the others."""
        why = "; ".join(MISSING[k][0] for k in self.causes if k in MISSING)
        return (f"fitted on actuators {', '.join(f'T{j + 1}' for j in self.kept)} only (the part of "
                f"{', '.join(f'T{j + 1}' for j in self.left)} is not identified: {why or 'it vanishes'}); the fitted "
                f"parameters act on every actuator in the replays")


@dataclass(frozen=True)
class FormAlike:
    """An effect whose fit another matches as well when one of the two is held in the form the channels cannot test.

    Attributes
    ----------
    rival : str
        The other effect.
    form : str
        The form parameter the channels cannot test (of the rival when ``held_by_rival``, else of this effect).
    other : float
        Its untested end.
    delta_bic : float
        Fit-run BIC change when the confirmed effect is swapped for the one in its untested form.
    held_by_rival : bool
        Whether the untested form is the rival's (this effect was confirmed) or this effect's own.
    """

    rival: str
    form: str
    other: float
    delta_bic: float
    held_by_rival: bool = True


@dataclass(frozen=True)
class Hinged:
    """An identified effect whose support hinges on the untested part of a partly identified one.

    Attributes
    ----------
    on : str
        The partly identified effect.
    delta_bic : float
        Fit-run BIC change when the effect is added beside the significant set and ``on`` with its non-identified
        parameters fitted too.
    holdout_lr : float
        Holdout equation-error likelihood ratio of that addition, parameters frozen.
    gap : str
        The unexplained gap it might account for.
    """

    on: str
    delta_bic: float
    holdout_lr: float
    gap: str


@dataclass(frozen=True)
class StandIn:
    """A confirmed effect that may stand in for the untested part of a partly identified one, alone or with a
    look-alike.

    Attributes
    ----------
    on : str
        The partly identified effect.
    partner : str
        The confirmed effect's look-alike fitted beside ``on`` (empty: ``on`` alone takes the effect's place).
    delta_bic : float
        Fit-run BIC of the set with the effect replaced by ``on`` (untested part fitted) and ``partner``, minus that
        of the confirmed set.
    member_delta_bic : float
        Fit-run BIC change when the effect is added back beside them.
    partner_support : Hinged or None
        The partner's own support beside ``on`` (it is listed with it); None without a partner.
    partner_form : str
        The partner's form when it is one the channels cannot test (e.g. ``"norm_weight = 1"``), else empty.
    """

    on: str
    partner: str
    delta_bic: float
    member_delta_bic: float
    partner_support: Hinged | None
    partner_form: str = ""


@dataclass
class EffectCheck:
    """Identifiability of one effect: its parameters' checks, and whether any is identified."""

    name: str
    params: list = field(default_factory=list)
    excited_by: str = "manoeuvres in which it acts"  # what the runs lack when its regressors vanish
    #: form parameter -> :class:`FormCheck` (the search keeps the identified form)
    forms: dict = field(default_factory=dict)
    #: a per-actuator effect the observed DOFs see through some actuators only: :class:`ActuatorCheck` (else None)
    actuators: ActuatorCheck | None = None

    @property
    def identified(self) -> bool:
        return any(c.identified for c in self.params)

    @property
    def not_identified(self) -> list:
        """Amplitude parameters not identified, then the form parameters kept at one end."""
        return [c.name for c in self.params if not c.identified] + list(self.forms)

    @property
    def causes(self) -> list:
        """Keys of :data:`MISSING` (or ``"vanishes"``) of the parameters not identified and the forms held, once
        each, in order."""
        out = []
        for c in [c for c in self.params if not c.identified] + list(self.forms.values()):
            out += [k for k in c.causes if k not in out]
        return out

    def acting_in(self, dofs, min_share: float = ACTS_SHARE) -> list:
        """The parameters the channels do not identify, and the forms held at one end, that act in any of the DOF
        indices ``dofs`` (hold at least ``min_share`` of their noise-normalised regressor energy there; a held form:
        the parameters its other end loses)."""
        held = [(c.name, c.dof_share) for c in self.params if not c.identified]
        held += [(f"{k} form", f.dof_share) for k, f in self.forms.items()]
        return [n for n, share in held if len(share) == 6 and any(share[i] >= min_share for i in dofs)]

    def reason(self) -> str:
        """Why parameters are not identified, with the measurement that would fix it."""
        causes = self.causes
        forms = "".join(f"{k} kept at {f.kept:g} (the form at {f.other:g} is not identified); "
                        for k, f in self.forms.items())
        if "vanishes" in causes:
            return (forms + f"its regressors are zero on these runs: nothing it acts on is present; it needs "
                            f"{self.excited_by}")
        return forms + "; ".join(f"{MISSING[k][0]}; {MISSING[k][1]}" for k in causes)


@dataclass(frozen=True)
class PassDisagreement:
    """An effect the two reconstruction passes of a stock-sensor diagnosis judge differently.

    Attributes
    ----------
    first : str
        Its holdout evidence in the first pass (velocities reconstructed with the nominal plant), where it was
        confirmed.
    second : str
        What the second pass (velocities reconstructed with the first pass' confirmed effects) did with it.
    """

    first: str
    second: str


@dataclass
class Identifiability:
    """Per-effect identifiability on a fit stack (see the module docstring)."""

    effects: dict
    observed: np.ndarray
    reconstructed: np.ndarray
    #: effects the channels identify alone, but whose fit another effect matches as well on the observed DOFs (name
    #: -> those look-alikes): the data cannot say which of them acts (:meth:`with_ambiguous`)
    ambiguous: dict = field(default_factory=dict)
    #: partly identified effects that the equation error on the observed DOFs selects but the holdout replay, which
    #: needs their non-identified parameters, cannot confirm (name -> its evidence; :meth:`with_unconfirmed`)
    unconfirmed: dict = field(default_factory=dict)
    #: partly identified effects whose non-identified parameters act where an unexplained gap lies: the part the
    #: channels identify was not selected, the rest cannot be tested (name -> the gap and those parameters;
    #: :meth:`with_not_excluded`)
    not_excluded: dict = field(default_factory=dict)
    #: effects whose fit another matches as well when one of the two is held in the form these channels cannot test
    #: (a confirmed effect swapped for it, BIC within ``BIC_STRONG``): name -> :class:`FormAlike`;
    #: :meth:`with_form_alike`
    form_alike: dict = field(default_factory=dict)
    #: effects the channels identify, not significant, whose support hinges on the untested part of a partly
    #: identified effect (name -> :class:`Hinged`; :meth:`with_hinged`)
    hinged: dict = field(default_factory=dict)
    #: confirmed effects that may stand in for the untested part of a partly identified effect with one of their
    #: look-alikes (name -> :class:`StandIn`; :meth:`with_stand_in`)
    stand_in: dict = field(default_factory=dict)
    #: confirmed effects whose identifiable look-alikes were swapped in and replayed on the holdout (name -> tuple of
    #: :class:`udrobot_ctrl.gap.confirm.Separation`): those it did not separate are named in the reason with both
    #: scores; those it did are look-alikes no more (:meth:`with_separations`)
    separations: dict = field(default_factory=dict)
    #: effects the holdout confirmed on velocities the smoother reconstructed with the nominal plant, and dropped once
    #: they were reconstructed with the confirmed effects' force (name -> :class:`PassDisagreement`;
    #: :meth:`with_pass_disagreement`)
    pass_disagreement: dict = field(default_factory=dict)
    #: columns some fit run logs but its sidecar marks estimated-unaided (column ->
    #: :class:`udrobot_ctrl.io.runlog.ChannelSource`; ``Prepared.unaided``): named in the reasons' ``missing``
    unaided: dict = field(default_factory=dict)

    def observed_dofs(self) -> list:
        """Names of the observed (scored) DOFs."""
        return [d for d, ok in zip(fx.DOF, self.observed) if ok]

    @property
    def names(self) -> list:
        """Names of the unidentifiable effects (the ambiguous and the unconfirmed ones included)."""
        return [n for n, e in self.effects.items()
                if not e.identified or n in self.ambiguous or n in self.unconfirmed or n in self.not_excluded
                or n in self.form_alike or n in self.hinged or n in self.stand_in or n in self.pass_disagreement]

    def with_ambiguous(self, ambiguous: dict) -> Identifiability:
        """A copy that also lists ``ambiguous`` (name -> look-alikes) as unidentifiable, and with each of them its
        identifiable look-alikes (the relation is symmetric: the runs cannot say which of them acts; an unidentifiable
        look-alike is listed already, with its own reason)."""
        amb = dict(self.ambiguous)
        for k, alts in ambiguous.items():
            if not alts:
                continue
            amb[k] = tuple(dict.fromkeys(amb.get(k, ()) + tuple(alts)))
            for a in alts:
                if self.effects[a].identified:
                    amb[a] = tuple(dict.fromkeys(amb.get(a, ()) + (k,)))
        return replace(self, ambiguous=amb)

    def unconfirmable(self, name) -> bool:
        """Whether ``name`` is identified in part only because of what the runs do not measure (a parameter or a
        form not identified for a missing or reconstructed channel, not because its regressor vanishes)."""
        e = self.effects.get(name)
        return e is not None and e.identified and bool(set(e.causes) - {"vanishes"})

    def with_unconfirmed(self, unconfirmed: dict) -> Identifiability:
        """A copy that also lists ``unconfirmed`` (name -> its equation-error evidence) as unidentifiable."""
        return replace(self, unconfirmed={**self.unconfirmed, **unconfirmed})

    def with_not_excluded(self, not_excluded: dict) -> Identifiability:
        """A copy that also lists ``not_excluded`` (name -> the unexplained gap and its non-identified parameters that
        act there) as unidentifiable."""
        return replace(self, not_excluded={**self.not_excluded, **not_excluded})

    def with_form_alike(self, form_alike: dict) -> Identifiability:
        """A copy that also lists ``form_alike`` (name -> :class:`FormAlike`) as unidentifiable."""
        return replace(self, form_alike={**self.form_alike, **form_alike})

    def with_stand_in(self, stand_in: dict) -> Identifiability:
        """A copy that also lists ``stand_in`` (name -> :class:`StandIn`) as unidentifiable."""
        return replace(self, stand_in={**self.stand_in, **stand_in})

    def with_separations(self, separations: dict) -> Identifiability:
        """A copy that also holds ``separations`` (name -> tuple of holdout look-alike swaps, for the reasons)."""
        return replace(self, separations={**self.separations, **separations})

    def with_pass_disagreement(self, disagreement: dict) -> Identifiability:
        """A copy that also lists ``disagreement`` (name -> :class:`PassDisagreement`) as unidentifiable."""
        return replace(self, pass_disagreement={**self.pass_disagreement, **disagreement})

    def with_hinged(self, hinged: dict) -> Identifiability:
        """A copy that also lists ``hinged`` (name -> :class:`Hinged`) as unidentifiable."""
        return replace(self, hinged={**self.hinged, **hinged})

    def reason(self, name) -> str:
        """Why ``name`` is unidentifiable, with the measurement (or the manoeuvre) that would fix it."""
        if name in self.stand_in and name not in self.ambiguous:
            st = self.stand_in[name]
            part = self.effects[st.on]
            return (f"with it replaced by {st.on}, its {', '.join(part.not_identified)} fitted as well (on the "
                    f"velocities the smoother reconstructs)" + (f", and {st.partner}" if st.partner else "")
                    + (f" with {st.partner_form} (a form these channels cannot test)" if st.partner_form else "")
                    + f", the fit runs' BIC changes by "
                    f"{st.delta_bic:+.0f} against the confirmed set, and it adds nothing beside them (dBIC "
                    f"{st.member_delta_bic:+.0f}): it may stand in for what these channels cannot test of {st.on}, so "
                    f"the runs cannot say which acts; " + part.reason()
                    + (f"; to tell it from {st.partner}: {fx.discriminating_manoeuvre(name, st.partner)}"
                       if st.partner else ""))
        if name in self.hinged and name not in self.ambiguous:
            h = self.hinged[name]
            part = self.effects[h.on]
            return (f"not excluded: {h.gap}; beside {h.on} with its {', '.join(part.not_identified)} fitted as well "
                    f"(on the velocities the smoother reconstructs), it lowers the fit runs' BIC by {-h.delta_bic:.0f} "
                    f"(holdout likelihood ratio {h.holdout_lr:.0f}), and without them it is not selected: whether it "
                    f"acts hinges on what these channels cannot test of {h.on}: " + part.reason())
        if name in self.form_alike and name not in self.ambiguous:
            a = self.form_alike[name]
            held = a.rival if a.held_by_rival else name
            line = (f"on the observed DOFs ({', '.join(self.observed_dofs())}) its fit is matched as well by "
                    f"{a.rival} with {a.form} = {a.other:g}" if a.held_by_rival else
                    f"on the observed DOFs ({', '.join(self.observed_dofs())}), with {a.form} = {a.other:g}, its fit "
                    f"matches that of {a.rival} as well")
            return (line + f" (BIC {a.delta_bic:+.0f} when swapped), a form of {held} these channels cannot test, so "
                    f"the runs cannot say which acts; " + self.effects[held].reason())
        if name in self.unconfirmed and name not in self.ambiguous:
            e = self.effects[name]
            return (f"the equation error on the observed DOFs ({', '.join(self.observed_dofs())}) selects it "
                    f"({self.unconfirmed[name]}), but the holdout replay cannot confirm it with the parameters these "
                    f"channels identify ({', '.join(e.not_identified)} not identified, so not in the replay): "
                    + e.reason())
        if name in self.pass_disagreement and name not in self.ambiguous:
            d = self.pass_disagreement[name]
            recon = [c for c, r in zip(VEL, self.reconstructed) if r]
            return (f"the holdout confirmed it on the unlogged velocities ({', '.join(recon)}) as the smoother "
                    f"reconstructed them with the nominal plant ({d.first}), but not once they were reconstructed with "
                    f"the confirmed effects' force ({d.second}): whether it acts hinges on how those velocities are "
                    f"reconstructed, so the runs cannot say; log {', '.join(recon)} (a DVL) to replay it on measured "
                    f"velocities")
        if name in self.not_excluded and name not in self.ambiguous:
            e = self.effects[name]
            return (f"not excluded: {self.not_excluded[name]}; the part of it these channels identify does not "
                    f"explain that gap, and the rest cannot be tested: " + e.reason())
        if name not in self.ambiguous:
            return self.effects[name].reason()
        alts = self.ambiguous[name]
        hidden = [a for a in alts if not self.effects[a].identified]
        line = (f"on the observed DOFs ({', '.join(self.observed_dofs())}) its fit, or alone the holdout replay, is "
                f"matched as well by {', '.join(alts)}")
        if hidden:
            line += f" ({', '.join(hidden)}: not identifiable from these channels)"
        scores = self._holdout_scores(name, [a for a in alts if a not in hidden])
        if scores:
            line += f" (not separated on the holdout: {scores})"
        fixes = [self.effects[hidden[0]].reason()] if hidden else []
        fixes += [f"to tell it from {a}: {fx.discriminating_manoeuvre(name, a)}" for a in alts if a not in hidden]
        return line + ", so the runs cannot say which acts; " + "; ".join(fixes)

    def _holdout_scores(self, name, alts) -> str:
        """The holdout scores of ``name``'s look-alike swaps with ``alts`` (either effect the confirmed member)."""
        out = []
        for a in alts:
            sp = next((s for s in self.separations.get(name, ()) if s.rival == a), None) or \
                next((s for s in self.separations.get(a, ()) if s.rival == name), None)
            if sp is not None:
                out.append(sp.describe() + {"equal": ": equal", "rival better": f": better with {sp.rival}",
                                            "separated": ""}[sp.verdict])
        return "; ".join(out)

    def report(self) -> list:
        """The report's ``unidentifiable`` list: ``[{"name", "reason", "missing"}]`` (``missing``: :meth:`missing`,
        present when not empty)."""
        out = []
        for n in self.names:
            entry = {"name": n, "reason": self.reason(n)}
            missing = self.missing(n)
            if missing:
                entry["missing"] = missing
            out.append(entry)
        return out

    def _referred(self, name) -> list:
        """``name`` and the effects whose reason its reason carries (:meth:`reason`)."""
        out = [name]
        if name in self.stand_in:
            out.append(self.stand_in[name].on)
        if name in self.hinged:
            out.append(self.hinged[name].on)
        if name in self.form_alike:
            a = self.form_alike[name]
            out.append(a.rival if a.held_by_rival else name)
        out += [a for a in self.ambiguous.get(name, ()) if not self.effects[a].identified][:1]
        return [n for n in dict.fromkeys(out) if n in self.effects]

    def missing(self, name) -> list:
        """What the runs lack for ``name`` as structured codes, once each: ``{"code": "not_observed", "dofs": group}``
        (no sensor of the DOF group's velocity or its integral), ``{"code": "unaided_estimate", "column", "source",
        "why"}`` (a column of that group was logged but its sidecar marks it estimated-unaided: dead reckoning, not
        counted as observed), ``{"code": "reconstructed", "dofs"}``, ``{"code": "stabilised"}``,
        ``{"code": "not_excited"}``. Rendered as sentences by :func:`describe_missing` (the console only)."""
        out = []
        for n in self._referred(name):
            for cause in self.effects[n].causes:
                if cause == "vanishes":
                    item = [{"code": NOT_EXCITED}]
                elif cause == "stabilised":
                    item = [{"code": STABILISED}]
                elif cause in RECONSTRUCTED.values():
                    item = [{"code": RECONSTRUCTED_CODE, "dofs": cause.split(" (")[0]}]
                else:
                    item = [{"code": NOT_OBSERVED, "dofs": cause}]
                    item += [{"code": UNAIDED_ESTIMATE, "column": c, "source": s.source, "why": s.aiding}
                             for c, s in self.unaided.items() if cause in COLUMN_GROUPS.get(c, ())]
                out += [i for i in item if i not in out]
        return out

    def entry(self, name) -> dict:
        """Extra fields of an effect's report entry: the parameters not identified (partial effects only)."""
        e = self.effects.get(name)
        if (e is None or not e.identified or not e.not_identified or name in self.ambiguous
                or name in self.unconfirmed or name in self.not_excluded or name in self.form_alike
                or name in self.hinged or name in self.stand_in or name in self.pass_disagreement):
            return {}
        return {"not_identified": {"params": e.not_identified, "reason": e.reason()}}

    def restrict(self, catalogue: dict) -> dict:
        """The catalogue with each partly identified effect's non-identified amplitude parameters frozen at 0."""
        out = {}
        for n, eff in catalogue.items():
            chk = self.effects.get(n)
            frozen = tuple(c.name for c in chk.params if not c.identified) if chk is not None and chk.identified \
                else ()
            forms = {k: f.kept for k, f in chk.forms.items()} if chk is not None and chk.identified else {}
            kept = chk.actuators.kept if chk is not None and chk.identified and chk.actuators is not None else None
            out[n] = Restricted(eff, frozen, forms, kept) if frozen or forms or kept is not None else eff
        return out


class Restricted(fx.Effect):
    """A catalogue effect with some amplitude parameters frozen at zero (their columns removed from the design), some
    form parameters kept at one end of their range (``forms``: name -> value) and, for a per-actuator effect, its
    design read from the actuators ``actuators`` only (indices; None: all). Its replay (:meth:`hooks`) is the inner
    effect's: the fitted parameters act on every actuator."""

    def __init__(self, inner: fx.Effect, frozen, forms=None, actuators=None):
        super().__init__(inner.name, inner.meaning, inner.shape_names, inner.shape_grid, inner.shape_bounds,
                         inner.refine, inner.mimics, inner.excited_by, inner.physical_ends,
                         inner.physical_amplitudes, inner.tolerance_ends, inner.nested)
        self.inner = inner
        self.reads_delivered, self.maps_command = inner.reads_delivered, inner.maps_command
        self.frozen = tuple(frozen)
        self.forms = dict(forms or {})
        self.per_actuator, self.per_dof = inner.per_actuator, inner.per_dof
        self.actuators = None if actuators is None else tuple(actuators)

    def freezing(self, names) -> Restricted:
        """The same restriction with the amplitudes ``names`` frozen at zero too."""
        return Restricted(self.inner, self.frozen + tuple(n for n in names if n not in self.frozen), self.forms,
                          self.actuators)

    def design(self, s, shape):
        if self.actuators is not None:
            s = s.only_actuators(self.actuators)
        b0, A, names, lo, hi = self.inner.design(s, shape)
        keep = np.array([nm not in self.frozen for nm in names], float)
        return b0, A * keep, names, lo, hi

    def search_space(self, s):
        grid, bounds = self.inner.search_space(s)
        if not self.forms:
            return grid, bounds
        at = {self.shape_names.index(k): v for k, v in self.forms.items()}
        kept = [tuple(at.get(i, x) for i, x in enumerate(shape)) for shape in grid]
        grid = tuple(dict.fromkeys(kept))  # the grid's shapes in the kept form, once each
        bounds = tuple((at[i], at[i]) if i in at else b for i, b in enumerate(bounds))
        return grid, bounds

    def refine_step(self, s, x0):
        return self.inner.refine_step(s, x0)

    def default_form(self, s):
        return self.inner.default_form(s)

    def command_filter(self, shape):
        return self.inner.command_filter(shape)

    def change_filter(self, shape):
        return self.inner.change_filter(shape)

    def hooks(self, params, p, actuation):
        return self.inner.hooks(params, p, actuation)


def _shapes(eff: fx.Effect, stack):
    """A few shapes of the effect's search grid on this stack (first, middle, last)."""
    grid = list(eff.search_space(stack)[0])
    if len(grid) <= N_SHAPES:
        return grid
    return [grid[0], grid[len(grid) // 2], grid[-1]]


def _columns(eff, stack, shape, design=None):
    """(n, 6, k) regressors of an effect at ``shape`` and their names: amplitude columns, then the shape term
    (``design``: the effect's design on ``stack`` at ``shape``, when already computed)."""
    b0, A, names, _, _ = eff.design(stack, tuple(shape)) if design is None else design
    A, nm = fx.finite_values(A), list(names)  # no copy of a design the store already made finite
    b0 = fx.finite_values(b0)
    if eff.shape_names and np.any(b0):  # a shape-only form (lag, current, deadband's cut) acts through b0
        nm.append(",".join(eff.shape_names))
        return np.concatenate([A, b0[..., None]], axis=-1), nm
    return A, nm


def reconstruction_error(pr, p) -> np.ndarray:
    """(n, 6) error scale of the reconstructed velocities of a prepared run (m/s, rad/s; 0 where logged).

    The smoother's posterior std, and for a DOF no sensor observes at least the steady offset an unmodelled
    acceleration of the smoother's assumed size would cause, ``sigma_d M_ii / (D_L,ii + 2 Q_ii |nu_i|)``
    (capped at 1 m/s or rad/s): there the velocity is known only through the model, and a model error of that
    size shifts it without any measured trace (at a steady speed the accelerometer reads the same).
    """
    out = np.zeros((pr.n, 6))
    sm = pr.smoothed
    if sm is None:
        return out
    prior = SmootherSettings().sigma_d
    for i in np.flatnonzero(pr.reconstructed):
        err = np.nan_to_num(sm.sigma_nu[:, i])
        if not pr.observed[i]:
            slope = p.D_L[i, i] + 2.0 * p.Q[i, i] * np.abs(pr.nu[:, i])
            err = np.maximum(err, np.minimum(1.0, prior[i] * p.M[i, i] / np.maximum(slope, 1e-9)))
        out[:, i] = err
    return out


def _perturbed(stack, preps, what):
    """A copy of ``stack`` with reconstructed velocity ``what`` (0-5) moved by its :func:`reconstruction_error`, or
    the dead-reckoned position (``what = "xy"``) by the time integral of the horizontal velocity's."""
    runs = []
    for r, pr in zip(stack.runs, preps):
        nu, eta = r["nu"].copy(), r["eta"].copy()
        if pr.smoothed is not None:
            err = reconstruction_error(pr, stack.p)
            if what == "xy":
                drift = np.cumsum(np.hypot(err[:, 0], err[:, 1])) * pr.dt
                eta[:, 0] += drift
                eta[:, 1] += drift
            else:
                nu[:, what] += err[:, what]
        runs.append(dict(r, nu=nu, eta=eta, x=np.concatenate([eta, nu], axis=1)))
    return replace(stack, runs=runs)


def noise_scale(stack, preps) -> np.ndarray:
    """Per-DOF noise of the equation error (N, N m): ``M_ii`` times the median posterior std of the smoother's
    unmodelled acceleration over the runs (how well the data pin that DOF's acceleration), or its prior std when
    no smoother ran. The same definition for every DOF, and independent of the gap itself (a residual's std would
    grow with the very effect under test)."""
    prior = SmootherSettings().sigma_d
    smoothed = [pr.smoothed for pr in preps if pr.smoothed is not None]
    sig = np.array([np.nanmedian(np.concatenate([sm.sigma_d[:, i] for sm in smoothed])) if smoothed else prior[i]
                    for i in range(6)])
    return np.diag(stack.p.M) * np.where(np.isfinite(sig) & (sig > 0), sig, prior)


def assess(stack, r, dofs, preps, catalogue: dict, names=None, designs=None, store: DesignStore | None = None
           ) -> Identifiability:
    """Identifiability of each effect in ``names`` on the fit ``stack`` (see the module docstring).

    Parameters
    ----------
    stack : effects.Stack
        Fit stack (:func:`udrobot_ctrl.gap.attribute.build_stack`).
    r : (n, 6) ndarray
        Its residual.
    dofs : (6,) bool
        Scored (observed) DOFs.
    preps : list of Prepared
        The fit runs, in the stack's order (their ``reconstructed`` DOFs and smoother std).
    catalogue : dict
        Name -> Effect.
    designs : dict, optional
        Receives the design on ``stack`` of each effect at each shape probed, (name, shape) ->
        :class:`~udrobot_ctrl.gap.effects.Design` (a diagnosis hands them to its attributor).
    store : DesignStore, optional
        Where the probes' designs are kept by content (a diagnosis's, shared with its attributors): a design whose
        effect does not read the state a reconstruction move changes is then computed once for the stack and its
        moves. None: every design computed.
    """
    names = list(names or catalogue)
    observed = np.asarray(dofs, bool)
    reconstructed = np.logical_or.reduce([pr.reconstructed for pr in preps])
    sensed = np.logical_and.reduce([pr.observed for pr in preps])
    held = {DOF_GROUP[i] for i in range(3, 6) if sensed[i] and not observed[i]}
    sigma = noise_scale(stack, preps)
    moves = [i for i in range(6) if reconstructed[i]]
    if any(pr.smoothed is not None and not any(c in pr.meas and np.isfinite(pr.meas[c]).any() for c in "xy")
           for pr in preps):
        moves.append("xy")
    stacks = {m: _perturbed(stack, preps, m) for m in moves}
    memo = Probes(designs=designs, store=store)  # each probed shape's energies (the form checks probe some again)
    raw = {n: _energies(catalogue[n], stack, stacks, _shapes(catalogue[n], stack), sigma, observed, memo)
           for n in names}
    top = max([a["all"] for acc in raw.values() for a in acc.values()], default=0.0)
    out = {}
    for n in names:
        eff = catalogue[n]
        forms = _forms(eff, stack, stacks, sigma, observed, top, memo)
        if forms:  # the parameters are judged in the form the search keeps
            kept = Restricted(eff, (), {k: f.kept for k, f in forms.items()})
            raw[n] = _energies(eff, stack, stacks, _shapes(kept, stack), sigma, observed, memo)
        checks = _checks(raw[n], top, observed)
        acts = None
        if eff.per_actuator and not all(c.identified for c in checks):
            shapes = _shapes(Restricted(eff, (), {k: f.kept for k, f in forms.items()}), stack)
            acts, checks = _by_actuator(eff, stack, stacks, shapes, sigma, observed, top, checks, store)
        if not checks:  # no amplitude column and a shape term that is zero at every probed shape
            checks.append(ParameterCheck(",".join(eff.shape_names) or n, float("nan"), float("nan"), False,
                                         ("vanishes",)))
        out[n] = _stabilised_causes(EffectCheck(n, checks, eff.excited_by, forms, acts), held)
    unaided = {c: s for pr in preps for c, s in getattr(pr, "unaided", {}).items()}
    return Identifiability(out, observed, reconstructed, unaided=unaided)


def _stabilised_causes(chk: EffectCheck, held) -> EffectCheck:
    """``chk`` with the cause of the attitude DOF groups in ``held`` (sensed, but left out of the equation error on
    closed-loop runs) named ``"stabilised"`` instead of "not observed"."""
    if not held:
        return chk

    def swap(causes):
        return tuple(dict.fromkeys("stabilised" if c in held else c for c in causes))
    params = [replace(c, causes=swap(c.causes)) for c in chk.params]
    forms = {k: replace(f, causes=swap(f.causes)) for k, f in chk.forms.items()}
    acts = None if chk.actuators is None else replace(chk.actuators, causes=swap(chk.actuators.causes))
    return replace(chk, params=params, forms=forms, actuators=acts)


def _only(stack, stacks, keep):
    """``stack`` and its reconstruction moves ``stacks`` with only the actuators ``keep`` commanded."""
    return stack.only_actuators(keep), {m: st.only_actuators(keep) for m, st in stacks.items()}


def _groups(B, observed, active) -> dict:
    """The ``active`` actuators grouped by the observed DOFs their force acts on (non-zero rows of ``B``): observed DOF
    indices -> actuator indices."""
    out = {}
    for j in active:
        out.setdefault(tuple(int(i) for i in np.flatnonzero(observed & (np.abs(B[:, j]) > 1e-9))), []).append(j)
    return {k: tuple(v) for k, v in out.items()}


def _by_actuator(eff, stack, stacks, shapes, sigma, observed, top, checks, store=None):
    """A per-actuator effect judged on what the observed DOFs see of it: (:class:`ActuatorCheck` or None, the
    parameter checks).

    Its parameters are shared by every actuator, so the observed DOFs identify them when the part of some actuators
    does, however much energy the others put where nothing is measured (an inflow loss of the horizontal thrusters
    in the unobserved surge) or however much their part hinges on a reconstruction (their inflow speed is the
    reconstructed surge speed). The actuators are judged in groups that act on the same observed DOFs (:func:`_groups`;
    within a group their forces add and cancel there, e.g. two surge thrusters' yaw moments), each group's part with
    :func:`_checks`. When some groups identify a parameter and the others none, and the two act on disjoint observed
    DOFs (the part left out of the fit stays in DOFs the kept part does not read, so it cannot bias it), the effect is
    judged, and fitted, on the kept groups' part: the result names them if that identifies more parameters than the
    whole (``checks``). Otherwise the whole stands (None, ``checks``). ``store``: as :func:`_shape_energy`'s.
    """
    active = [j for j in range(stack.f.shape[1]) if np.any(stack.f[:, j])]
    groups = _groups(np.asarray(stack.B, float), observed, active)
    alone = {g: _checks(_energies(eff, *_only(stack, stacks, acts), shapes, sigma, observed, store=store), top,
                        observed)
             for g, acts in groups.items()}
    seen = [g for g in groups if any(c.identified for c in alone[g])]
    unseen = [g for g in groups if g not in seen]
    if not seen or not unseen or set().union(*seen) & set().union(*unseen):
        return None, checks
    kept = tuple(sorted(j for g in seen for j in groups[g]))
    part = _checks(_energies(eff, *_only(stack, stacks, kept), shapes, sigma, observed, store=store), top, observed)
    before, after = ({c.name for c in cs if c.identified} for cs in (checks, part))
    if not before < after:
        return None, checks
    left = tuple(sorted(j for g in unseen for j in groups[g]))
    causes = tuple(dict.fromkeys(k for g in unseen for c in alone[g] for k in c.causes))
    return ActuatorCheck(kept, left, causes), part


class ShapeEnergy(NamedTuple):
    """One shape's part of :func:`_energies`: the parameters' names and, per parameter, its noise-normalised
    regressor energy in the observed DOFs and in all DOFs, per DOF, and under each reconstruction move."""

    names: list
    obs: np.ndarray  # (k,)
    all: np.ndarray  # (k,)
    per_dof: list  # (k,) of (6,)
    dev: dict  # move -> (k,)


@dataclass
class Probes:
    """What one assessment computed on its fit stack, by effect name and shape: each probe's :class:`ShapeEnergy`
    (the form checks probe some shapes again) and, when asked for (``designs`` not None), its design on the fit stack
    (which the attributor's searches would compute again, :meth:`~udrobot_ctrl.gap.attribute.Attributor.keep_designs`).
    """

    energies: dict = field(default_factory=dict)  # (name, shape) -> ShapeEnergy
    designs: dict | None = None  # (name, shape) -> effects.Design
    store: DesignStore | None = None  # the designs by content (:func:`_shape_energy`)


def _design(eff, stack, shape, store=None) -> fx.Design:
    """``eff``'s design on ``stack`` at ``shape``, read from ``store`` when kept there (computed and kept else;
    :class:`~udrobot_ctrl.gap.attribute.DesignStore`: its non-finite entries zeroed, as :func:`_columns` reads it)."""
    if store is None:
        return fx.Design(*eff.design(stack, tuple(shape)))
    return store.design(store.key(eff, stack, shape), lambda: eff.design(stack, tuple(shape)))


def _shape_energy(eff, stack, stacks, shape, sigma, observed, designs=None, store=None) -> ShapeEnergy:
    """:class:`ShapeEnergy` of ``eff`` at one ``shape`` on ``stack`` and its reconstruction moves ``stacks``
    (``designs``: a dict that receives the design on ``stack`` under (name, shape); ``store``: a
    :class:`~udrobot_ctrl.gap.attribute.DesignStore` the designs are read from and kept in, so that a move that leaves
    the arrays the effect reads unchanged costs no design)."""
    d = _design(eff, stack, shape, store)
    if designs is not None:
        designs[(eff.name, tuple(shape))] = d
    A, nm = _columns(eff, stack, shape, d)
    An2 = (A / sigma[None, :, None]) ** 2
    # the moves on the observed DOFs only (the same numbers as moving all six and keeping those)
    A_obs, sigma_obs = A[:, observed], sigma[None, observed, None]
    dev = {}
    for m, st_m in stacks.items():
        d_m = _design(eff, st_m, shape, store)
        if d_m is d or (d_m.A is d.A and d_m.b0 is d.b0):  # a move the effect does not read: no change
            dev[m] = np.zeros(len(nm))
            continue
        Am, _ = _columns(eff, st_m, shape, d_m)
        dev[m] = np.sum(((Am[:, observed] - A_obs) / sigma_obs) ** 2, axis=(0, 1))
    return ShapeEnergy(nm, np.sum(An2[:, observed], axis=(0, 1)), np.sum(An2, axis=(0, 1)),
                       [np.sum(An2[:, :, j], axis=0) for j in range(len(nm))], dev)


def _energies(eff, stack, stacks, shapes, sigma, observed, memo=None, store=None) -> dict:
    """Per parameter of ``eff``, summed over ``shapes``: its noise-normalised regressor energy in the observed DOFs
    (``obs``), in all DOFs (``all``) and per DOF (``per_dof``), and the energy of its change in the observed DOFs
    under each reconstruction move (``dev``: move -> energy).

    ``memo`` (optional :class:`Probes`, for one ``stack``, ``stacks``, ``sigma`` and ``observed``): each shape's
    :class:`ShapeEnergy` kept by effect name and shape, so that the probes of one assessment that meet again (a
    form's end that is a grid shape, the kept form's shapes) are computed once; its ``store`` (or ``store``) keeps
    the designs by content (:func:`_shape_energy`)."""
    acc = {}
    for shape in shapes:
        key = (eff.name, tuple(float(v) for v in shape))
        if memo is not None and key in memo.energies:
            part = memo.energies[key]
        else:
            part = _shape_energy(eff, stack, stacks, shape, sigma, observed, memo.designs if memo else None,
                                 memo.store if memo is not None and memo.store is not None else store)
            if memo is not None:
                memo.energies[key] = part
        for j, pname in enumerate(part.names):
            a = acc.setdefault(pname, {"obs": 0.0, "all": 0.0, "dev": dict.fromkeys(stacks, 0.0),
                                       "per_dof": np.zeros(6)})
            a["obs"] += part.obs[j]
            a["all"] += part.all[j]
            a["per_dof"] += part.per_dof[j]
            for m in stacks:
                a["dev"][m] += part.dev[m][j]
    return acc


def _checks(acc, top, observed) -> list:
    """:class:`ParameterCheck` of each parameter from its :func:`_energies` (``top``: the largest energy of all
    effects, for "zero on the data")."""
    checks = []
    for pname, a in acc.items():
        if a["all"] <= VANISH * max(top, 1e-300):
            checks.append(ParameterCheck(pname, float("nan"), float("nan"), False, ("vanishes",)))
            continue
        share = a["obs"] / a["all"]
        sens = {m: np.sqrt(d / a["obs"]) if a["obs"] > 0 else 0.0 for m, d in a["dev"].items()}
        worst = max(sens.values(), default=0.0)
        causes = []
        if share < SHARE_MIN:
            causes += [DOF_GROUP[i] for i in np.argsort(-a["per_dof"]) if not observed[i]
                       and a["per_dof"][i] > 0.1 * a["all"]]
        causes += ["position" if m == "xy" else DOF_GROUP[m] if not observed[m] else RECONSTRUCTED[DOF_GROUP[m]]
                   for m, v in sens.items() if v > SENSITIVITY_MAX]
        causes = list(dict.fromkeys(causes))
        ok = share >= SHARE_MIN and worst <= SENSITIVITY_MAX
        checks.append(ParameterCheck(pname, float(share), float(worst), ok, () if ok else tuple(causes),
                                     tuple(float(v) for v in a["per_dof"] / a["all"])))
    return checks


def _forms(eff, stack, stacks, sigma, observed, top, memo=None) -> dict:
    """Form parameters of ``eff`` (``physical_ends``) at whose one end the channels identify more of its amplitude
    parameters than at the other (a strict superset), the others failing because their regressor hinges on a
    reconstructed state (sensitivity), not because it acts less in the observed DOFs (share): name ->
    :class:`FormCheck`. A parameter whose regressor vanishes on the data at either end is left out of the
    comparison. Each end is probed with the other shape parameters at the middle of the effect's grid (``memo``: as
    :func:`_energies`'s)."""
    grid, bounds = eff.search_space(stack)
    grid = list(grid)
    if not eff.physical_ends or not grid or not bounds:
        return {}
    middle = list(grid[len(grid) // 2])
    out = {}
    for k in eff.physical_ends:
        i = eff.shape_names.index(k)
        ends = {}
        for end in bounds[i]:
            shape = tuple(middle[:i] + [end] + middle[i + 1:])
            ends[float(end)] = {c.name: c for c in _checks(_energies(eff, stack, stacks, [shape], sigma, observed,
                                                                     memo), top, observed)}
        if len(ends) != 2:
            continue
        (e1, c1), (e2, c2) = ends.items()
        # a parameter whose regressor vanishes at an end (a regulated rate's drag at the own-axis end) tells neither
        # form apart: compared, it would make the two sets incomparable and leave the hinging form searched
        idle = {n for c in (c1, c2) for n, chk in c.items() if "vanishes" in chk.causes}
        ok1 = {n for n, c in c1.items() if c.identified and n not in idle}
        ok2 = {n for n, c in c2.items() if c.identified and n not in idle}
        if ok1 == ok2 or not (ok1 < ok2 or ok2 < ok1):
            continue  # the same parameters in both forms, or neither form better: the search keeps both
        good, bad, lost = (e2, c1, ok2 - ok1) if ok1 < ok2 else (e1, c2, ok1 - ok2)
        if any(n not in bad or not bad[n].share >= SHARE_MIN for n in lost):
            # the other form acts elsewhere (less in the observed DOFs), it does not hinge on a reconstruction; or
            # its checks group the parameters differently (a shape that leaves one of them without a regressor)
            continue
        causes = tuple(dict.fromkeys(x for n in sorted(lost) for x in bad[n].causes))
        shares = [bad[n].dof_share for n in sorted(lost) if len(bad[n].dof_share) == 6]
        out[k] = FormCheck(good, e1 if good == e2 else e2, causes,
                           tuple(float(v) for v in np.max(shares, axis=0)) if shares else ())
    return out


def sensors(preps) -> dict:
    """The report's ``sensors`` field: per velocity channel, ``observed`` (logged, or pinned by a logged
    integral), ``reconstructed`` (by the smoother) or ``absent``; the channels logged in every run; and ``unaided``
    (column -> source) the columns some run logs as estimated-unaided (left out of the rest)."""
    status = {}
    for i, c in enumerate(VEL):
        if all(pr.observed[i] for pr in preps):
            how = "observed" if all(c in pr.meas and np.isfinite(pr.meas[c]).any() for pr in preps) else \
                f"observed through {'/'.join(OBSERVING[i][1:])}, reconstructed by the smoother"
        elif all(pr.reconstructed[i] for pr in preps):
            how = "reconstructed by the smoother (not observed: not scored)"
        else:
            how = "absent"
        status[c] = how
    logged = sorted(set.intersection(*[{c for c, v in pr.meas.items() if np.isfinite(v).any()} for pr in preps]))
    scored = [fx.DOF[i] for i in range(6) if all(pr.dof_ok[i] for pr in preps)]
    out = {"logged": logged, "velocities": status, "scored_dofs": scored}
    unaided = {c: s.source for pr in preps for c, s in getattr(pr, "unaided", {}).items()}
    if unaided:  # logged, but dead reckoning (the sidecar's estimated-unaided): not in "logged", never scored
        out["unaided"] = dict(sorted(unaided.items()))
    return out
