"""Confirm the candidates on the holdout runs: backward elimination from the forward-selected set.

Forward selection (:func:`udrobot_ctrl.gap.attribute.forward_select`) proposes effects that lower the fit-run BIC
and the holdout equation error one at a time; an effect added early can become redundant once later ones are in
(a thruster lag proposed with a deadband, an added-mass and a damping error that only shared its residual). So the
final set is checked member by member: each member, dropped from the set (the others refitted on the fit runs,
their shapes too: two templates that split one effect's force when fitted jointly, the one left must get its share
back before the removal is scored), must leave the fit runs' BIC higher (the fit runs still prefer the set with it:
forward selection admitted it given the effects before it, and a later effect can take its share) and must make
the holdout worse on both scores:

* **equation error** (significance): the holdout likelihood ratio of the set against the set without it,
  parameters frozen from the fit runs, exceeds chi^2_1(0.99) = ``HOLDOUT_CHI2`` (N_eff = N / tau_int of the
  holdout stack);
* **replay** (materiality): the multiple-shooting replay gap of the holdout runs rises by more than
  ``REPLAY_MATERIAL`` (2 %) of gap_before, and a rise below ``REPLAY_LARGE`` (10 %) must not be a coin flip over
  the holdout windows (one-sided p < ``REPLAY_P`` = 0.1, signed-rank and t tests, and more than half of the windows
  worse: a t-test can pass on one or two windows that rise a lot while most improve). A template-mismatch correction
  (a damping term fitted alongside a lag of another form, an added-mass error next to a deadband) can be
  statistically significant in equation error and even lower the gap by a few percent on average, yet it trades
  error between manoeuvres: better in a few windows, worse in most. A large rise is material however it is spread:
  a holdout run gives only ten or twenty windows and an effect may act in a few of them (a tether at speed).

Each member must also explain part of the gap **on its own**: the holdout replay with it alone (its single-effect
fit) must shrink the gap by more than ``REPLAY_MATERIAL``. An effect that helps only alongside another (a damping
term that bends a lag template towards a lag of another form, a cross-coupled damping whose own shrink is
negative) compensates for that other effect's template, it is not a second effect. The exception is an effect
that **interacts** with a partner: an added-mass error next to a CG-CB offset, a current next to an inflow loss;
alone, its single fit is biased by the partner it lacks and the replay can get worse, yet in the set dropping it
worsens the replay in every holdout window (at least ``CONSISTENT_WINDOWS`` of them), or raises the gap by more
than ``REPLAY_LARGE`` with a window-by-window p below ``INTERACTING_P`` (10 x stricter than the materiality test).
Its parameters from the set's joint fit do not help alone either: the effects interact in the replay (a tether
beside a quadratic-damping error, shrink -0.015 alone with its joint-fit parameters, +12.5 % of the gap when
dropped). A compensator does not pass: it trades error between windows, or its consistent rise is small (a
template correction).

The member that fails is dropped (one that does not help alone first, then the one with the weakest replay
evidence), the rest are refitted jointly (their shapes re-optimised,
:func:`udrobot_ctrl.gap.attribute.finalize`) and the check repeats until every member passes. Then each dropped
effect is tried back once, if the set has changed since it was dropped: added to the confirmed set, refitted and
checked again by the same elimination, which may drop a member it displaces. It is **re-admitted** when it
survives and the holdout replay gap is lower than with the set without it. An effect dropped while a look-alike
took its share (a quadratic damping error next to a tether that is kept for want of it) gets its second chance.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy import stats

from udrobot_ctrl.gap.attribute import HOLDOUT_CHI2, Attributor, Combination, Fit, finalize, holdout_lr, refit
from udrobot_ctrl.gap.effects import Actuation
from udrobot_ctrl.gap.shrink import GapScore, errors, gap, simulate_windows_sets, window_starts
from udrobot_ctrl.parallel import fork_map, shares, workers

REPLAY_MATERIAL = 0.02  # fraction of gap_before
REPLAY_P = 0.1  # one-sided p of the per-window rise (signed-rank and t, Bonferroni) below REPLAY_LARGE
REPLAY_LARGE = 0.10  # fraction of gap_before: a rise this large is material without the test over windows
CONSISTENT_WINDOWS = 0.95  # fraction of holdout windows whose replay error rises when an interacting effect is dropped
#: ... or the gap rises by more than REPLAY_LARGE with a one-sided window-by-window p (``replay_p``) below this:
#: a partner carries a large share consistently; a compensator's rise is a coin flip over the windows or small.
#: In the blind bench the true partners that fail alone come at 0.0076 and below, the false look-alikes with a
#: rise above 10 % at 0.044 and above.
INTERACTING_P = 1e-2


@dataclass(frozen=True)
class Replay:
    """Holdout multiple-shooting replay of the nominal model plus some fitted effects."""

    members: tuple
    gap: GapScore
    sims: list  # (n, 16) per holdout run: state, specific force and window column (shrink.simulate_windows)


@dataclass(frozen=True)
class Replayer:
    """Holdout replays of fitted effect sets: ``replayer(fit, members)`` gives one :class:`Replay`,
    ``replayer.many([(fit, members), ...])`` several, integrated together (:func:`replay_sets`)."""

    many: Callable  # sequence of (fit, members) -> list of Replay, in order

    def __call__(self, fit, members) -> Replay:
        return self.many([(fit, members)])[0]


def fitted_hooks(catalogue, p, actuation: Actuation, fit: Fit | None, members) -> list:
    """Replay hooks (:class:`udrobot_ctrl.gap.effects.Hooks`) of ``members`` with their parameters in ``fit``."""
    return [catalogue[n].hooks(fit.params[n], p, actuation) for n in members]


def replay(preps, p, fit: Fit | None, members, catalogue, actuation: Actuation, window_s, scored) -> Replay:
    """Replay the holdout runs with ``members`` of ``fit`` added to the nominal plant (no member: nominal).

    Parameters
    ----------
    preps : list of Prepared
        Holdout runs.
    p : PlantParameters
        Nominal plant.
    fit : Fit or None
        Fitted parameters of the members.
    members : sequence of str
    catalogue : dict
        Name -> Effect.
    actuation : Actuation
    window_s : float
        Multiple-shooting window, s.
    scored : list of str
        Channels scored (those of the nominal gap).
    """
    return replay_sets(preps, p, [(fit, members)], catalogue, actuation, window_s, scored)[0]


#: the most recent replays a :class:`ReplayCache` keeps: the diagnosis replays some sets again (a member's rest in the
#: backward check is its single fit, the set left after a drop the rest just replayed, the empty set)
REPLAYS_KEPT = 32


class ReplayCache:
    """The most recent replays of one diagnosis (:func:`replay_sets`), at most ``kept``: a set replayed again on the
    same runs with the same parameters is the same :class:`Replay`. Owned by what runs the diagnosis (its
    :class:`~udrobot_ctrl.gap.report.Stacks`), so that it and the runs it holds go with it; keys name the runs, the
    plant, the catalogue and the actuation by identity, and the cache holds those objects so that their ids stay
    theirs.

    Parameters
    ----------
    kept : int
        The oldest replays are dropped beyond this many.
    """

    def __init__(self, kept=REPLAYS_KEPT):
        self.kept = int(kept)
        self._items = OrderedDict()  # key -> (the key's objects, Replay)

    def __len__(self) -> int:
        return len(self._items)

    def get(self, key):
        """The Replay kept under ``key`` (now the most recent), or None."""
        if key not in self._items:
            return None
        self._items.move_to_end(key)
        return self._items[key][1]

    def put(self, key, objs, replay: Replay) -> None:
        """Keep ``replay`` under ``key`` with the objects its key names (the oldest dropped beyond ``kept``)."""
        self._items[key] = (objs, replay)
        self._items.move_to_end(key)
        while len(self._items) > self.kept:
            self._items.popitem(last=False)


def _replay_key(preps, p, fit, members, catalogue, actuation, window_s, scored):
    """The key of one replay: what it is computed from (the objects by identity, the members' parameters by value)
    and those objects."""
    objs = (tuple(preps), p, catalogue, actuation)
    params = tuple((n, tuple(sorted(fit.params[n].items()))) for n in members) if members else ()
    return (tuple(map(id, objs[0])), *map(id, objs[1:]), float(window_s), tuple(scored), tuple(members), params), objs


def replay_sets(preps, p, sets, catalogue, actuation: Actuation, window_s, scored, cache: ReplayCache | None = None
                ) -> list:
    """:func:`replay` of several sets at once: ``sets`` is a sequence of (fit, members); one :class:`Replay` each, in
    order, integrated together (:func:`udrobot_ctrl.gap.shrink.simulate_windows_sets`). With a ``cache``, a set it
    keeps (the same runs, the same parameters) is not replayed again: the same Replay."""
    if cache is None:
        return _replay_sets(preps, p, sets, catalogue, actuation, window_s, scored)
    keys = [_replay_key(preps, p, fit, members, catalogue, actuation, window_s, scored) for fit, members in sets]
    out = [cache.get(k) for k, _ in keys]
    todo = [i for i, r in enumerate(out) if r is None]
    if todo:
        for i, r in zip(todo, _replay_sets(preps, p, [sets[i] for i in todo], catalogue, actuation, window_s,
                                           scored)):
            out[i] = r
            cache.put(*keys[i], r)
    for k, _ in keys:  # every set asked for is now among the most recent, as it was asked
        cache.get(k)
    return out


def _replay_sets(preps, p, sets, catalogue, actuation: Actuation, window_s, scored) -> list:
    """:func:`replay_sets` computed."""
    hook_sets = [fitted_hooks(catalogue, p, actuation, fit, members) for fit, members in sets]
    # one piece of work per run and share of the sets, spread over the cores (a set's replay is its own either way)
    pieces = [(r, part) for r in range(len(preps)) for part in shares(len(sets), workers())]
    done = fork_map(lambda rp: simulate_windows_sets(preps[rp[0]], p, [hook_sets[v] for v in rp[1]], window_s),
                    pieces)
    per_run = [[None] * len(sets) for _ in preps]
    for (r, part), sims in zip(pieces, done):
        for v, sim in zip(part, sims):
            per_run[r][v] = sim
    out = []
    for v, (_, members) in enumerate(sets):
        sims = [run_sims[v] for run_sims in per_run]
        out.append(Replay(tuple(members), gap(preps, sims, scored), sims))
    return out


def window_energy(preps, sims, score: GapScore, window_s, weights=None) -> np.ndarray:
    """Each window's part of the squared gap: sum over the scored channels c of SE_c,window / (N_c scale_c^2 C),
    windows of all runs concatenated, so that they sum to ``score.value ** 2`` (N_c: the channel's scored samples,
    C: the number of scored channels). With ``weights`` (channel -> weight, summing to 1), each channel's part is
    weighted by its weight instead of 1 / C (:func:`change_weights`: a member's rise is tested where it acts)."""
    chans = score.scored
    se = {c: [] for c in chans}
    count = dict.fromkeys(chans, 0)
    for prep, sim in zip(preps, sims):
        starts, w = window_starts(prep, window_s)
        err = errors(prep, sim)
        for c in chans:
            e = err.get(c, np.full(prep.n, np.nan))
            ok = np.isfinite(e)
            count[c] += int(ok.sum())
            e2 = np.where(ok, e, 0.0) ** 2 / score.scale[c] ** 2
            se[c].append(np.array([e2[s: s + w].sum() for s in starts]))
    if not chans:
        return np.zeros(0)
    weight = weights or dict.fromkeys(chans, 1.0 / len(chans))
    return sum(weight.get(c, 0.0) * np.concatenate(se[c]) / max(count[c], 1) for c in chans)


def change_weights(preps, with_: Replay, without: Replay) -> dict | None:
    """Channel weights for the window test of a member: where its replay changes, against the error there.

    Each scored channel's squared difference between the holdout replays with the member (``with_``) and without it
    (``without``), over its scored samples and gap scale squared, divided by the channel's squared NRMSE with it (a
    matched filter: the change the member makes, whitened by the error it is measured against); normalised to sum
    to 1. None (every channel alike) when the replays agree. The replay, not the force, says where a member acts (a
    tether's sway force turns into roll and yaw motion); the error level keeps a channel the member barely moves
    but whose error is large and noisy (a pitch rate at its floor) from swamping the windows' differences. The
    weights use no measurement beyond the windows' initial states and the gap's per-channel level.
    """
    scored = with_.gap.scored
    se, count = dict.fromkeys(scored, 0.0), dict.fromkeys(scored, 0)
    for prep, a, b in zip(preps, with_.sims, without.sims):
        ea, eb = errors(prep, a), errors(prep, b)
        for c in scored:
            if c in ea and c in eb:
                d = ea[c] - eb[c]
                ok = np.isfinite(d)
                se[c] += float(np.sum(d[ok] ** 2))
                count[c] += int(ok.sum())
    level = {c: max(with_.gap.per_channel.get(c, 0.0) ** 2, 1e-12) for c in scored}
    energy = {c: se[c] / max(count[c], 1) / with_.gap.scale[c] ** 2 / level[c] for c in scored}
    total = sum(energy.values())
    if not np.isfinite(total) or total <= 0:
        return None
    return {c: v / total for c, v in energy.items()}


def window_changes(without: np.ndarray, with_: np.ndarray) -> np.ndarray:
    """Per-window differences ``without - with_`` of the windows that change (finite, non-zero)."""
    d = np.asarray(without, float) - np.asarray(with_, float)
    return d[np.isfinite(d) & (d != 0)]


def rise_fraction(without: np.ndarray, with_: np.ndarray) -> float:
    """Fraction of the windows (those that change) whose error is larger ``without`` than ``with_``."""
    d = window_changes(without, with_)
    return float(np.mean(d > 0)) if d.size else 0.0


def sign_p(without: np.ndarray, with_: np.ndarray) -> float:
    """One-sided sign-test p that as many windows (of those that change) would be worse ``without`` by chance (1.0
    when none change)."""
    d = window_changes(without, with_)
    if not d.size:
        return 1.0
    return float(stats.binomtest(int(np.sum(d > 0)), int(d.size), 0.5, alternative="greater").pvalue)


#: below this many windows with tied changes, the signed-rank p is exact: every one of the 2^n sign patterns (as
#: ``scipy.stats.wilcoxon``'s default, which then runs its permutation test)
EXACT_TIED_MAX = 13


def signed_rank_greater(d: np.ndarray):
    """One-sided Wilcoxon signed-rank test that the non-zero differences ``d`` are positive: (W+, p).

    ``scipy.stats.wilcoxon(d, alternative="greater")``'s result, computed directly where it is slow: with tied
    |d| and at most :data:`EXACT_TIED_MAX` of them, scipy enumerates the 2^n sign patterns in a permutation test
    that evaluates its statistic one pattern at a time (0.2 s per call); here the 2^n null statistics are one
    matrix product (the same exact null distribution and the same relative tolerance on ties with the observed W+).
    """
    d = np.asarray(d, float)
    r = stats.rankdata(np.abs(d))
    if d.size > EXACT_TIED_MAX or np.unique(r).size == r.size:  # scipy's exact or normal test: fast already
        w = stats.wilcoxon(d, alternative="greater")
        return float(w.statistic), float(w.pvalue)
    w_plus = float(r[d > 0].sum())
    signs = (np.arange(2 ** d.size)[:, None] >> np.arange(d.size)) & 1  # every pattern of positive differences
    null = signs @ r
    eps = np.finfo(float).eps * 100 * abs(w_plus)
    return w_plus, float(np.count_nonzero(null >= w_plus - eps) / null.size)


def paired_rise(without: np.ndarray, with_: np.ndarray):
    """One-sided paired tests that ``without`` exceeds ``with_`` window by window: (W+, p).

    Two tests, as the per-window differences are heavy-tailed: the Wilcoxon signed-rank test (ranks: many windows
    of consistent rise) and the paired t-test (a large rise concentrated in the windows where the effect acts);
    p is the smaller of the two one-sided p-values, Bonferroni-corrected (x 2).
    """
    d = window_changes(without, with_)
    if d.size < 2:
        return 0.0, 1.0
    w, p_w = signed_rank_greater(d)
    sd = float(np.std(d, ddof=1))
    p_t = float(stats.t.sf(d.mean() / (sd / np.sqrt(d.size)), d.size - 1)) if sd > 0 else float(d.mean() <= 0)
    return w, min(1.0, 2.0 * min(p_w, p_t))


@dataclass(frozen=True)
class Alone:
    """The holdout replay with one effect alone (its single-effect fit) against the nominal replay."""

    shrink: float  # 1 - gap with it alone / gap_before
    w: float  # Wilcoxon signed-rank statistic W+ (nominal against alone)
    p: float
    diverged: int = 0  # holdout windows its replay diverged in, beyond those the nominal replay diverged in

    @property
    def passed(self) -> bool:
        """It shrinks the gap by more than ``REPLAY_MATERIAL``, and its replay diverges in no window the nominal
        replay holds (a replay that blows up cannot be scored on the windows that survive)."""
        return self.shrink > REPLAY_MATERIAL and self.diverged <= 0

    def reason(self) -> str:
        if self.diverged > 0:
            return (f"on its own its holdout replay diverges in {self.diverged} window"
                    f"{'s' if self.diverged > 1 else ''} (shrink {self.shrink:+.3g}, the diverged samples scored at "
                    f"the error cap)")
        return (f"on its own it does not shrink the holdout gap by more than {100 * REPLAY_MATERIAL:g}% "
                f"(shrink {self.shrink:+.3f})")


def alone_tests(preps, nominal: Replay, singles: dict, window_s) -> dict:
    """Name -> :class:`Alone` from the nominal holdout replay and each effect's single-effect replay."""
    e0 = window_energy(preps, nominal.sims, nominal.gap, window_s)
    out = {}
    for n, r in singles.items():
        t, pval = paired_rise(e0, window_energy(preps, r.sims, r.gap, window_s))
        b = nominal.gap.value
        out[n] = Alone((1 - r.gap.value / b) if b > 0 else 0.0, t, pval,
                       max(r.gap.n_diverged - nominal.gap.n_diverged, 0))
    return out


@dataclass(frozen=True)
class MemberTest:
    """What dropping one member from the set does on the holdout runs, and what it does alone."""

    name: str
    holdout_lr: float  # equation-error likelihood ratio of the set against the set without it
    gap_contribution: float  # rise of the holdout gap when dropped, fraction of gap_before
    replay_w: float  # Wilcoxon signed-rank statistic W+ of the per-window rise (without - with)
    replay_p: float  # one-sided p of the rise over windows (signed-rank and t, Bonferroni)
    alone: Alone | None = None  # the effect alone against the nominal model (None: not checked)
    windows_worse: float = float("nan")  # fraction of holdout windows whose replay error rises when it is dropped
    fit_delta_bic: float = float("nan")  # fit-run BIC of the set minus that of the set without it (nan: unchecked)
    windows_p: float = float("nan")  # one-sided sign-test p of that many windows worse (nan: unchecked)
    set_diverged: int = 0  # holdout windows in which the replay of the whole set (with it) diverges

    @property
    def passed_equation_error(self) -> bool:
        return self.holdout_lr > HOLDOUT_CHI2

    @property
    def passed_fit(self) -> bool:
        """The fit runs still prefer the set with it: ``fit_delta_bic`` negative, or nan (unchecked)."""
        return not self.fit_delta_bic >= 0

    @property
    def passed_replay(self) -> bool:
        """The rise is material: above ``REPLAY_MATERIAL``, and below ``REPLAY_LARGE`` consistent over the windows
        (one-sided p < ``REPLAY_P`` and more than half of them worse; nan: unchecked)."""
        consistent = self.replay_p < REPLAY_P and not self.windows_worse <= 0.5
        return self.gap_contribution > REPLAY_MATERIAL and (consistent or self.gap_contribution > REPLAY_LARGE)

    @property
    def interacting(self) -> bool:
        """Dropping it worsens the replay in (nearly) every holdout window (at least ``CONSISTENT_WINDOWS`` of them),
        or raises the gap by more than ``REPLAY_LARGE`` with ``replay_p`` < ``INTERACTING_P``: needed in the set
        whatever it does alone."""
        return self.windows_worse >= CONSISTENT_WINDOWS or (self.replay_p < INTERACTING_P
                                                            and self.gap_contribution > REPLAY_LARGE)

    @property
    def passed_alone(self) -> bool:
        """Alone it shrinks the gap (or it interacts with a partner); an effect whose replay alone diverges in a
        window fails whatever it does in the set."""
        return self.alone is None or (self.alone.diverged <= 0 and (self.alone.passed or self.interacting))

    @property
    def passed(self) -> bool:
        return self.passed_fit and self.passed_equation_error and self.passed_replay and self.passed_alone

    def reason(self) -> str:
        """Why the member fails (empty when it passes)."""
        why = []
        if not self.passed_fit:
            why.append(f"the fit runs do not prefer the set with it (BIC {self.fit_delta_bic:+.1f} against the set "
                       f"without it)")
        if not self.passed_equation_error:
            why.append(f"holdout equation-error likelihood ratio {self.holdout_lr:.1f} <= {HOLDOUT_CHI2:g}")
        if self.gap_contribution <= REPLAY_MATERIAL and self.set_diverged:
            why.append(f"the set with it diverges in {self.set_diverged} holdout window"
                       f"{'s' if self.set_diverged > 1 else ''}, so its replay gap says nothing of this member")
        elif self.gap_contribution <= REPLAY_MATERIAL:
            why.append(f"dropping it changes the holdout replay gap by {100 * self.gap_contribution:+.1f}% of "
                       f"gap_before (<= {100 * REPLAY_MATERIAL:g}%)")
        elif not self.passed_replay:
            why.append(f"dropping it raises the holdout replay gap by {100 * self.gap_contribution:+.1f}% of "
                       f"gap_before, but not consistently over the windows (p {self.replay_p:.2g}, "
                       f"{100 * self.windows_worse:.0f}% of them worse; below {100 * REPLAY_LARGE:g}% it needs "
                       f"p < {REPLAY_P:g} and more than half of them worse)")
        if not self.passed_alone:
            why.append(self.alone.reason())
        return "; ".join(why)

    def to_json(self) -> dict:
        out = {"fit_delta_bic": self.fit_delta_bic, "holdout_lr": self.holdout_lr,
               "holdout_gap_contribution": self.gap_contribution,
               "replay_w": self.replay_w, "replay_p": self.replay_p, "windows_worse": self.windows_worse,
               "windows_p": self.windows_p, "passed": self.passed}
        if self.alone is not None:
            out |= {"alone_shrink": self.alone.shrink, "alone_w": self.alone.w, "alone_p": self.alone.p}
            if self.alone.diverged:
                out["alone_diverged_windows"] = self.alone.diverged
        return out


@dataclass(frozen=True)
class EliminationRound:
    """One pass of the backward check over the current set."""

    members: tuple
    tests: tuple  # MemberTest per member
    dropped: str | None
    readmitted: str | None = None  # the effect this round re-admitted (its tests are those of the new set)

    def to_json(self) -> dict:
        out = {"members": list(self.members), "tests": {t.name: t.to_json() for t in self.tests},
               "dropped": self.dropped}
        if self.readmitted:
            out["readmitted"] = self.readmitted
        if self.dropped:
            out["reason"] = next(t.reason() for t in self.tests if t.name == self.dropped)
        return out


@dataclass(frozen=True)
class Elimination:
    """Outcome of the backward check: the confirmed set, its joint fit and holdout replay, and the rounds."""

    kept: tuple
    combination: Combination
    after: Replay
    rounds: tuple  # EliminationRound

    @property
    def dropped(self) -> dict:
        """Name -> the test that last dropped it (effects re-admitted and kept are not listed)."""
        return {r.dropped: next(t for t in r.tests if t.name == r.dropped) for r in self.rounds
                if r.dropped and r.dropped not in self.kept}

    def last_test(self, name) -> MemberTest | None:
        """The member's test in the last round it took part in."""
        for r in reversed(self.rounds):
            for t in r.tests:
                if t.name == name:
                    return t
        return None


@dataclass(frozen=True)
class Separation:
    """The holdout replay of a confirmed set against the same set with one member swapped for a look-alike (both
    fitted on the fit runs): whether the runs tell the two apart.

    The swap is judged as a dropped member is (:attr:`MemberTest.passed_replay`): the runs separate the member from
    its look-alike when the swapped set's holdout gap is higher by more than ``REPLAY_MATERIAL`` of gap_before and,
    below ``REPLAY_LARGE``, consistently over the windows (one-sided p < ``REPLAY_P``, more than half of them worse).
    Otherwise the two fits score equally on the holdout and the runs cannot say which acts.

    Attributes
    ----------
    member, rival : str
        The confirmed member and its look-alike.
    gap_member, gap_rival : float
        Holdout replay gap (NRMSE) of the confirmed set and of the swapped set.
    rise : float
        ``(gap_rival - gap_member) / gap_before``.
    p : float
        One-sided window-by-window p of the rise (:func:`paired_rise`).
    windows_worse : float
        Fraction of the holdout windows (that change) worse with the rival.
    """

    member: str
    rival: str
    gap_member: float
    gap_rival: float
    rise: float
    p: float
    windows_worse: float

    @property
    def separated(self) -> bool:
        """The swapped set is materially and consistently worse on the holdout (see the class docstring)."""
        consistent = self.p < REPLAY_P and self.windows_worse > 0.5
        return self.rise > REPLAY_MATERIAL and (consistent or self.rise > REPLAY_LARGE)

    @property
    def verdict(self) -> str:
        """``"separated"`` (the member scores materially better), ``"rival better"`` (the swapped set's gap is lower
        by more than ``REPLAY_LARGE`` of gap_before) or ``"equal"``."""
        if self.separated:
            return "separated"
        return "rival better" if -self.rise > REPLAY_LARGE else "equal"

    def describe(self) -> str:
        """The two holdout scores, for the report's reasons and the console."""
        return (f"holdout gap {self.gap_member:.4g} with {self.member}, {self.gap_rival:.4g} with {self.rival} in its "
                f"place ({100 * self.rise:+.1f}% of gap_before, p {self.p:.2g}, {100 * self.windows_worse:.0f}% of "
                f"the windows worse)")


def separations(att: Attributor, members, pairs, full: Replay, before: GapScore, replayer: Replayer, window_s,
                preps, shapes=None) -> list:
    """:class:`Separation` of each (member, rival) in ``pairs``: the set ``members`` with the member swapped for the
    rival, refitted on the fit runs (shapes too) and replayed on the holdout against ``full`` (the set's replay).

    Parameters
    ----------
    att : Attributor
        Fit-run stack.
    members : sequence of str
        The confirmed set.
    pairs : sequence of (str, str)
        (member, rival); the rival is not in ``members``.
    full : Replay
        Holdout replay of the confirmed set.
    before : GapScore
        The nominal holdout gap (``gap_before``).
    replayer : Replayer
    window_s : float
        Replay window, s.
    preps : list of Prepared
        Holdout runs.
    shapes : dict, optional
        Name -> shape seeding the refit (the confirmed set's).
    """
    if not pairs:
        return []
    sets = [tuple(r if m == k else m for m in members) for k, r in pairs]
    fits = [refit(att, s, shapes) for s in sets]
    replays = replayer.many(list(zip(fits, sets)))
    e_full = window_energy(preps, full.sims, full.gap, window_s)
    out = []
    for (k, r), rep in zip(pairs, replays):
        e_swap = window_energy(preps, rep.sims, rep.gap, window_s)
        _, pval = paired_rise(e_swap, e_full)
        rise = (rep.gap.value - full.gap.value) / before.value if before.value > 0 else 0.0
        out.append(Separation(k, r, float(full.gap.value), float(rep.gap.value), float(rise), float(pval),
                              rise_fraction(e_swap, e_full)))
    return out


def check_members(att: Attributor, att_h: Attributor, combo: Combination, full: Replay, before: GapScore,
                  replay_rest, window_s, preps, alone=None, names=None) -> tuple:
    """:class:`MemberTest` of every member of ``combo`` (see the module docstring), or of the members ``names``.

    ``replay_rest`` (:class:`Replayer`) replays the holdout with the rest of the set, every member's rest at once;
    ``alone`` maps names to their :class:`Alone` check.
    """
    alone = alone or {}
    tested = combo.members if names is None else tuple(names)
    rests = [[m for m in combo.members if m != n] for n in tested]
    fits = [refit(att, rest, combo.fit.shapes) for rest in rests]  # amplitudes and shapes refitted without it
    replays = replay_rest.many(list(zip(fits, rests)))
    return tuple(member_test(att, att_h, combo.fit, full, n, fit_rest, r_rest, before, window_s, preps, alone.get(n))
                 for n, fit_rest, r_rest in zip(tested, fits, replays))


def member_test(att: Attributor, att_h: Attributor, fit: Fit, full: Replay, name, fit_rest: Fit, r_rest: Replay,
                before: GapScore, window_s, preps, alone: Alone | None = None) -> MemberTest:
    """The :class:`MemberTest` of ``name``: the set's fit ``fit`` and holdout replay ``full`` against ``fit_rest``
    and its replay ``r_rest``, the set without it (a member dropped, or a member's amplitude held at nominal:
    :func:`udrobot_ctrl.gap.report.confirm_components`)."""
    weights = change_weights(preps, full, r_rest)
    e_full = window_energy(preps, full.sims, full.gap, window_s, weights)
    e_rest = window_energy(preps, r_rest.sims, r_rest.gap, window_s, weights)
    t, pval = paired_rise(e_rest, e_full)
    contrib = (r_rest.gap.value - full.gap.value) / before.value if before.value > 0 else 0.0
    return MemberTest(name, holdout_lr(att_h, fit_rest, fit), float(contrib), t, pval, alone,
                      rise_fraction(e_rest, e_full), float(att.bic(fit) - att.bic(fit_rest)), sign_p(e_rest, e_full),
                      int(full.gap.n_diverged))


def backward_eliminate(att: Attributor, att_h: Attributor, candidates: Combination, names, before: GapScore,
                       replay_fit, window_s, preps, alone=None, log=None) -> Elimination:
    """Drop members of ``candidates`` that do not make the holdout worse when removed, until all pass; then try
    each dropped effect back once the set has changed (re-admission, see the module docstring).

    Parameters
    ----------
    att, att_h : Attributor
        Fit-run and holdout stacks (``att_h.n_eff`` set from the noise floor).
    candidates : Combination
        The forward-selected set and its joint fit.
    names : sequence of str
        Effects tested (for the refitted set's look-alikes).
    before : GapScore
        Nominal holdout gap.
    replay_fit : Replayer
        Holdout replay with members of a fit added.
    window_s : float
    preps : list of Prepared
        Holdout runs.
    alone : dict, optional
        Name -> :class:`Alone` (each effect alone against the nominal replay); unchecked when absent.
    log : callable, optional
    """
    rounds = []
    combo, full = _eliminate(att, att_h, candidates, replay_fit(candidates.fit, candidates.members), names, before,
                             replay_fit, window_s, preps, alone, rounds, log)
    while (back := _readmit(att, att_h, combo, full, names, before, replay_fit, window_s, preps, alone, rounds,
                            log)) is not None:
        combo, full, trial_rounds = back
        rounds.extend(trial_rounds)
        if log:
            log(f"  holdout re-check: {trial_rounds[0].readmitted} re-admitted; confirmed: {', '.join(combo.members)}")
    if len(rounds) > 1:
        combo = finalize(att, combo.members, names, final=combo.fit)
    return Elimination(kept=combo.members, combination=combo, after=full, rounds=tuple(rounds))


def _eliminate(att, att_h, combo, full, names, before, replay_fit, window_s, preps, alone, rounds, log):
    """Drop failing members one per round (refitting the rest) until every member passes; appends the rounds.
    Returns the final (combination, replay)."""
    while combo.members:
        tests = check_members(att, att_h, combo, full, before, replay_fit, window_s, preps, alone)
        failing = [t for t in tests if not t.passed]
        worst = min(failing, key=lambda t: (t.passed_alone and t.passed_fit, t.passed_replay, t.gap_contribution,
                                            t.holdout_lr)) if failing else None
        rounds.append(EliminationRound(combo.members, tests, worst.name if worst else None))
        if log:
            for t in tests:
                verdict = "dropped: " + t.reason() if worst and t.name == worst.name else (
                    "kept" if t.passed else "fails (" + t.reason() + "); weaker ones first")
                rise = (f"the set diverges in {t.set_diverged} holdout windows" if t.set_diverged else
                        f"replay gap {100 * t.gap_contribution:+.1f}%")
                log(f"  holdout check {len(rounds)}: {t.name}: LR {t.holdout_lr:.1f}, {rise} (p {t.replay_p:.2g}, "
                    f"{100 * t.windows_worse:.0f}% of windows worse) -> {verdict}")
        if worst is None:
            break
        # refit what remains (its parameters were shared with the dropped effect); look-alikes once at the end
        combo = finalize(att, [m for m in combo.members if m != worst.name], names, lookalikes=False)
        full = replay_fit(combo.fit, combo.members)
    return combo, full


def _readmit(att, att_h, combo, full, names, before, replay_fit, window_s, preps, alone, rounds, log=None):
    """Try each dropped effect (not yet re-admitted) back in ``combo``: added, refitted and checked again by the
    elimination (which may now drop a member the effect displaces). The effect is re-admitted when it survives and
    the resulting set lowers the holdout replay gap of ``full``; of several, the one that lowers it most. An effect
    is tried back only when the set has changed since it was dropped (its partners then are not exactly the members
    now).

    Returns
    -------
    (combination, replay, rounds) or None
        The new confirmed set, its replay and the elimination rounds of the trial (the first one marked
        ``readmitted``).
    """
    last_drop = {r.dropped: frozenset(r.members) - {r.dropped} for r in rounds if r.dropped}
    readmitted = {r.readmitted for r in rounds if r.readmitted}
    best = None
    for n in sorted(set(last_drop) - set(combo.members) - readmitted):
        if last_drop[n] == frozenset(combo.members):
            continue
        trial = finalize(att, combo.members + (n,), names, lookalikes=False)
        trial_rounds = []
        got, got_full = _eliminate(att, att_h, trial, replay_fit(trial.fit, trial.members), names, before,
                                   replay_fit, window_s, preps, alone, trial_rounds, None)
        gain = (full.gap.value - got_full.gap.value) / before.value if before.value > 0 else 0.0
        survives = n in got.members and gain > 0
        if log:
            log(f"  holdout re-check: {n} back with {', '.join(combo.members) or 'nothing'} -> "
                + _trial_outcome(n, got.members, trial_rounds, gain))
        if survives and (best is None or gain > best[0]):
            trial_rounds[0] = replace(trial_rounds[0], readmitted=n)
            best = (gain, got, got_full, trial_rounds)
    return None if best is None else best[1:]


def _trial_outcome(n, members, trial_rounds, gain) -> str:
    """One console phrase on a re-admission trial of ``n``."""
    if n not in members:
        return "dropped again: " + next(t.reason() for r in trial_rounds if r.dropped == n for t in r.tests
                                        if t.name == n)
    gone = [r.dropped for r in trial_rounds if r.dropped]
    if gain <= 0:
        return f"the holdout gap would not be lower ({100 * gain:+.1f}% of gap_before)"
    return (f"kept with {', '.join(m for m in members if m != n) or 'nothing'}"
            + (f" (dropped: {', '.join(gone)})" if gone else "")
            + f"; holdout gap {100 * gain:.1f}% of gap_before lower")
