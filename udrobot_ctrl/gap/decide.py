"""The diagnosis' one decision: a likelihood of the fit runs under each candidate model, a table of every set the
search visits, model weights and each effect's inclusion probability.

Criterion (the prediction-error method in its output-error form, Ljung 1999 ch. 7; a grey-box model selection
table as MATLAB's ``nlgreyest`` or a statistics package reports it):

* A candidate is the nominal plant plus a set of catalogue effects, with the effects' parameters fitted on the fit
  runs (the equation-error fit of :mod:`udrobot_ctrl.gap.attribute`).
* Its fit runs are replayed window by window from the logged start state with the logged commands
  (:mod:`udrobot_ctrl.gap.shrink`, the same replays ``gap_before``/``gap_after`` and ``simulate --windows`` use),
  and each channel c the runs log (velocities, rates, depth, attitude, the accelerometer where its bias is known)
  gives an output error ``e_c``. Each channel has its own Gaussian noise of unknown variance; maximised over the
  variances, the log-likelihood is

      ln L = -1/2 sum_c N_eff,c (ln(2 pi SSE_c / N_c) + 1),      N_eff,c = N_c / tau_c

  with ``tau_c`` the integrated autocorrelation time of the channel's output error (:func:`channel_taus`, of the
  best model found: the residual of the model the table prefers is the data's own measure of its whiteness).
* ``BIC = -2 ln L + k ln(sum_c N_eff,c)``, ``k`` the set's fitted parameters.
* The search (:func:`search`): forward from the nominal plant, each step scoring every remaining effect added to the
  current set and taking the best while it lowers the BIC, with a backward step after each addition (a member whose
  removal lowers the BIC goes); then every swap of one member of the best set for an effect outside it. Every set
  visited is a row of the table, scored the same way.
* Weights ``w_i = exp(-(BIC_i - BIC_min)/2) / sum_j ...`` (Kass & Raftery 1995: the BIC approximates the log
  marginal likelihood); an effect's inclusion probability is the summed weight of the sets that contain it.
* An effect is named when it belongs to the best set, its inclusion probability is at least :data:`P_NAMED` and no
  parameter of it ends on a bound of its physical range (a parameter pinned at a bound means the catalogue form is
  wrong: reported, not named). Look-alikes: the effects outside the best set whose swap for a member keeps at least
  ``(1 - P_NAMED) / P_NAMED`` of the best set's weight (a BIC within ``2 ln(P_NAMED / (1 - P_NAMED))``): the data
  cannot split their weight, so they are reported together ("X or Y") with the manoeuvre that would separate them.

The holdout runs take no part here: they only score the chosen model (``gap_before``, ``gap_after``, ``shrink``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from udrobot_ctrl.gap.attribute import Attributor, Fit, refit, tau_int
from udrobot_ctrl.gap.shrink import WINDOW, errors, window_counts

#: the inclusion probability at or above which an effect of the best set is named (a probability: odds of 19 to 1)
P_NAMED = 0.95
#: a set within this BIC of the best keeps at least (1 - P_NAMED) / P_NAMED of its weight (2 ln 19 = 5.89)
LOOKALIKE_BIC = 2.0 * math.log(P_NAMED / (1.0 - P_NAMED))
#: the most effects a set holds (the search stops there)
MAX_EFFECTS = 4
CRITERION = ("BIC of the fit runs' output-error likelihood: multiple-shooting replays of the fit runs, a Gaussian "
             "of unknown variance per logged channel (profiled), N_eff = N / tau_int per channel")

#: reason codes of an effect of the best set that is not named (the report's ``not_named``)
AT_BOUND = "at_bound"
INCLUSION_LOW = "inclusion_low"


@dataclass(frozen=True)
class ChannelSums:
    """Sums of squared output error per channel over the fit runs' replays.

    Attributes
    ----------
    sse : dict
        Channel -> sum of squared errors (channel units squared).
    n : dict
        Channel -> samples scored.
    diverged : int
        Replay windows that diverged (their samples scored at the error cap).
    """

    sse: dict
    n: dict
    diverged: int = 0


def channel_sums(preps, sims, channels) -> ChannelSums:
    """:class:`ChannelSums` of the replays ``sims`` (one per prepared run in ``preps``) on ``channels``."""
    sse, n = dict.fromkeys(channels, 0.0), dict.fromkeys(channels, 0)
    diverged = 0
    for prep, sim in zip(preps, sims):
        diverged += window_counts(sim)[1]
        for c, e in errors(prep, sim).items():
            if c in sse:
                ok = np.isfinite(e)
                sse[c] += float(np.sum(e[ok] ** 2))
                n[c] += int(ok.sum())
    return ChannelSums(sse, n, diverged)


def channel_taus(preps, sims, channels) -> dict:
    """Channel -> the variance inflation of its output error over replay windows (samples per independent
    sample, at least 1): the spread of the windows' mean squared errors against what independent Gaussian errors of
    one variance would give,

        phi_c = mean_w[(m_w - s2)^2 n_w] / (2 s2^2),   m_w = SSE_w / n_w,  s2 = SSE / N,

    (under independent errors ``var(m_w) = 2 s2^2 / n_w``, so phi = 1). It counts both the samples' correlation
    within a window (an initial-state error carried through it, a slow systematic error) and errors that differ from
    window to window, so the likelihood's effective samples ``N_c / phi_c`` do not count a smooth systematic error
    as thousands of independent observations. Windows are the replay's own (:data:`~udrobot_ctrl.gap.shrink.WINDOW`
    column); with fewer than 3 windows of 20 samples the integrated autocorrelation time of the error is used."""
    per = {c: [] for c in channels}
    series = {c: [] for c in channels}
    for prep, sim in zip(preps, sims):
        win = np.abs(sim[:, WINDOW]) if sim.shape[1] > WINDOW else np.full(sim.shape[0], np.nan)
        for c, e in errors(prep, sim).items():
            if c not in per:
                continue
            ok = np.isfinite(e) & np.isfinite(win)
            if ok.sum() > 20:
                series[c].append(e[ok])
            for w in np.unique(win[ok]):
                ew = e[ok & (win == w)]
                if ew.size >= 20:
                    per[c].append((float(np.sum(ew ** 2)), ew.size))
    out = {}
    for c in channels:
        blocks = per[c]
        if len(blocks) >= 3:
            sse = np.array([b[0] for b in blocks])
            n = np.array([b[1] for b in blocks], float)
            s2 = sse.sum() / n.sum()
            out[c] = float(max(1.0, np.mean((sse / n - s2) ** 2 * n) / (2 * s2 ** 2))) if s2 > 0 else 1.0
        else:
            out[c] = float(np.median([tau_int(x) for x in series[c]])) if series[c] else 1.0
    return out


def log_likelihood(sums: ChannelSums, taus: dict) -> tuple:
    """(ln L, N_eff) of :class:`ChannelSums` with the channels' autocorrelation times ``taus`` (module docstring)."""
    ll, n_eff = 0.0, 0.0
    for c, sse in sums.sse.items():
        n = sums.n[c]
        if n == 0:
            continue
        ne = n / max(taus.get(c, 1.0), 1.0)
        ll -= 0.5 * ne * (math.log(2 * math.pi * max(sse / n, 1e-300)) + 1.0)
        n_eff += ne
    return ll, n_eff


@dataclass(frozen=True)
class Candidate:
    """One set of effects with its fit on the fit runs and its replays' output-error sums."""

    members: tuple
    fit: Fit
    sums: ChannelSums
    sims: list = field(repr=False, compare=False, default=None)

    @property
    def k(self) -> int:
        """Parameters fitted (amplitudes and free shape parameters)."""
        return int(self.fit.k) if self.members else 0

    def bic(self, taus: dict) -> float:
        """The criterion (module docstring) with the channels' autocorrelation times ``taus``."""
        ll, n_eff = log_likelihood(self.sums, taus)
        return -2.0 * ll + self.k * math.log(max(n_eff, 1.0))


@dataclass(frozen=True)
class Row:
    """One row of the selection table.

    Attributes
    ----------
    effects : tuple of str
        The set (sorted).
    k : int
        Parameters fitted.
    loglik : float
        Output-error log-likelihood of the fit runs.
    bic : float
        The criterion.
    delta_bic : float
        BIC minus the nominal model's (negative: better).
    weight : float
        Model weight (the rows' weights sum to 1).
    diverged_windows : int
        Fit-run replay windows that diverged.
    """

    effects: tuple
    k: int
    loglik: float
    bic: float
    delta_bic: float
    weight: float
    diverged_windows: int
    rms: dict = field(default_factory=dict)  # channel -> RMS output error on the fit runs (channel units)
    params: dict = field(default_factory=dict)  # effect -> its fitted parameters in this set

    def to_json(self) -> dict:
        """The report's ``selection.candidates`` entry."""
        return {"effects": list(self.effects), "k": self.k, "loglik": self.loglik, "score": self.bic,
                "delta_bic": self.delta_bic, "weight": self.weight, "diverged_windows": self.diverged_windows,
                "rms_error": self.rms, "params": self.params}


@dataclass(frozen=True)
class NotNamed:
    """Why a member of the best set is not named: a reason code (:data:`AT_BOUND`, :data:`INCLUSION_LOW`) and its
    fields."""

    code: str
    inclusion_probability: float
    params_at_bound: dict = field(default_factory=dict)  # parameter -> (value, bound)
    rivals: tuple = ()  # effects whose swap for it keeps the data from splitting their weight

    def to_json(self) -> dict:
        out = {"code": self.code, "inclusion_probability": self.inclusion_probability}
        if self.params_at_bound:
            out["at_bound"] = {k: {"value": v, "bound": b} for k, (v, b) in self.params_at_bound.items()}
        if self.rivals:
            out["rivals"] = list(self.rivals)
        return out


@dataclass(frozen=True)
class Decision:
    """The table and what it names (module docstring).

    Attributes
    ----------
    rows : tuple of Row
        Every set visited, best first.
    best : Candidate
        The set of lowest BIC.
    named : tuple of str
        Members of the best set named (inclusion probability >= P_NAMED, no parameter at a bound).
    inclusion : dict
        Effect -> inclusion probability (every effect searched; 0 for those in no visited set).
    not_named : dict
        Member of the best set -> :class:`NotNamed`.
    lookalikes : dict
        Member of the best set -> effects outside it whose swap for it lies within ``LOOKALIKE_BIC``.
    taus : dict
        Channel -> tau_int of the best set's output error (samples).
    channels : tuple of str
        Channels in the likelihood.
    n_eff : float
        Effective samples of the likelihood (sum over channels).
    singles : dict
        Effect -> its single-effect :class:`Candidate`.
    """

    rows: tuple
    best: Candidate
    named: tuple
    inclusion: dict
    not_named: dict
    lookalikes: dict
    taus: dict
    channels: tuple
    n_eff: float
    singles: dict

    def to_json(self) -> dict:
        """The report's ``selection`` object."""
        return {"criterion": CRITERION, "p_named": P_NAMED, "lookalike_delta_bic": LOOKALIKE_BIC,
                "channels": list(self.channels), "tau_int_samples": self.taus, "n_eff": self.n_eff,
                "best": list(self.best.members), "named": list(self.named),
                "inclusion_probability": self.inclusion,
                "not_named": {k: v.to_json() for k, v in self.not_named.items()},
                "lookalikes": {k: list(v) for k, v in self.lookalikes.items()},
                "candidates": [r.to_json() for r in self.rows]}


class Search:
    """The table's search over effect sets on the fit runs (module docstring).

    Parameters
    ----------
    att : Attributor
        The fit runs' equation-error stack (fits the parameters of each set).
    replay : callable
        ``replay([(fit, members), ...]) -> [Replay, ...]`` on the fit runs (sims per fit run).
    preps : list of Prepared
        The fit runs.
    channels : sequence of str
        Channels in the likelihood.
    nominal_sims : list
        The nominal model's replays of the fit runs.
    names : sequence of str
        Effects searched (the identifiable ones).
    log : callable, optional
        Receives one line per step.
    """

    def __init__(self, att: Attributor, replay, preps, channels, nominal_sims, names, log=None):
        self.att, self.replay, self.preps = att, replay, preps
        self.channels, self.names, self.log = tuple(channels), tuple(names), log or (lambda s: None)
        nominal = Candidate((), att.fit([]), channel_sums(preps, nominal_sims, self.channels), nominal_sims)
        self.visited = {(): nominal}
        self.taus = channel_taus(preps, nominal_sims, self.channels)
        self.singles = {}

    def bic(self, key) -> float:
        """The criterion of the visited set ``key``."""
        return self.visited[key].bic(self.taus)

    def score(self, fits) -> list:
        """Replay the sets ``fits`` ((members, Fit) pairs) not yet visited, together; their keys, in order."""
        keys = [tuple(sorted(m)) for m, _ in fits]
        todo = [(k, f, m) for k, (m, f) in zip(keys, fits) if k not in self.visited]
        todo = list({k: (k, f, m) for k, f, m in todo}.values())
        if todo:
            for (k, f, m), rep in zip(todo, self.replay([(f, tuple(m)) for _, f, m in todo])):
                self.visited[k] = Candidate(tuple(m), f, channel_sums(self.preps, rep.sims, self.channels), rep.sims)
        return keys

    def _added(self, current: Candidate, n) -> Fit:
        """The fit of ``current``'s members plus ``n``, the members' shapes held (``n``'s seeded by its single)."""
        fixed = [(m, current.fit.shapes[m]) for m in current.members]
        seeds = (self.singles[n].fit.shapes[n],) if n in self.singles else ()
        return self.att.best_shape(n, fixed, refine=not fixed, seeds=seeds)

    def forward(self, start=()) -> tuple:
        """Forward steps with a backward step after each addition, from the visited set ``start``; the key of the
        set it stops at."""
        cur = tuple(start)
        while len(cur) < MAX_EFFECTS:
            rest = [n for n in self.names if n not in cur]
            if not rest:
                break
            current = self.visited[cur]
            keys = self.score([((*current.members, n), self._added(current, n)) for n in rest])
            if not cur:
                self.singles.update({n: self.visited[k] for n, k in zip(rest, keys)})
            best = min(keys, key=self.bic)
            if not self.bic(best) < self.bic(cur):
                self.log(f"  search: no effect added to {{{', '.join(cur) or 'nominal'}}} lowers the BIC "
                         f"(best {', '.join(best)}: {self.bic(best) - self.bic(cur):+.1f})")
                break
            members = self.visited[best].members
            if any(self.att.free_shapes(m) for m in members) and len(members) > 1:  # every shape fitted again
                joint = refit(self.att, members, self.visited[best].fit.shapes)
                if self.att.bic(joint) < self.att.bic(self.visited[best].fit):
                    del self.visited[best]
                    self.score([(members, joint)])
            self.log(f"  search: + {best[-1] if len(best) == 1 else next(n for n in best if n not in cur)} -> "
                     f"{{{', '.join(best)}}} dBIC {self.bic(best) - self.bic(()):+.1f}")
            cur = best
            cur = self.backward(cur)
        return cur

    def backward(self, cur) -> tuple:
        """Drop the member whose removal lowers the BIC most, while one does; the key left."""
        while len(cur) > 1:
            current = self.visited[cur]
            subsets = [tuple(m for m in current.members if m != d) for d in current.members]
            keys = self.score([(s, self.att.fit([(m, current.fit.shapes[m]) for m in s])) for s in subsets])
            best = min(keys, key=self.bic)
            if not self.bic(best) < self.bic(cur):
                break
            self.log(f"  search: - {next(n for n in cur if n not in best)} -> {{{', '.join(best)}}} "
                     f"dBIC {self.bic(best) - self.bic(()):+.1f}")
            cur = best
        return cur

    def swaps(self, cur) -> None:
        """Score every swap of one member of the set ``cur`` for an effect outside it."""
        best = self.visited[cur]
        fits = []
        for m in best.members:
            others = tuple(x for x in best.members if x != m)
            base = self.visited.get(tuple(sorted(others)))
            if base is None:
                base = Candidate(others, self.att.fit([(x, best.fit.shapes[x]) for x in others]), ChannelSums({}, {}))
            for n in self.names:
                if n not in best.members:
                    fits.append(((*others, n), self._added(base, n)))
        self.score(fits)

    def best_key(self) -> tuple:
        return min(self.visited, key=self.bic)

    def retau(self) -> bool:
        """Set the channels' autocorrelation times from the best set's output error; True when that changed the
        best set."""
        before = self.best_key()
        best = self.visited[before]
        self.taus = channel_taus(self.preps, best.sims, self.channels)
        return self.best_key() != before


def search(att: Attributor, replay, preps, channels, nominal_sims, names, log=None) -> Search:
    """Run the search (:class:`Search`): forward-backward from the nominal plant, the autocorrelation times set from
    the best set and the search resumed from it until the best set holds, then the swaps of the best set."""
    s = Search(att, replay, preps, channels, nominal_sims, names, log=log)
    cur = s.forward(())
    for _ in range(3):
        if not s.retau():
            break
        cur = s.forward(s.best_key())
    s.retau()
    cur = s.best_key()
    if cur:
        s.swaps(cur)
        s.retau()
    return s


def decision(s: Search) -> Decision:
    """The :class:`Decision` of a finished :class:`Search`."""
    keys = sorted(s.visited, key=s.bic)
    bics = np.array([s.bic(k) for k in keys])
    w = np.exp(-0.5 * (bics - bics.min()))
    w = w / w.sum()
    b0 = s.bic(())
    rows = []
    for k, b, wi in zip(keys, bics, w):
        c = s.visited[k]
        ll, _ = log_likelihood(c.sums, s.taus)
        rms = {ch: math.sqrt(c.sums.sse[ch] / c.sums.n[ch]) for ch in s.channels if c.sums.n.get(ch)}
        params = {m: dict(c.fit.params[m]) for m in c.members}
        rows.append(Row(k, c.k, float(ll), float(b), float(b - b0), float(wi), int(c.sums.diverged), rms, params))
    inclusion = {n: float(sum(wi for k, wi in zip(keys, w) if n in k)) for n in s.names}
    best = s.visited[keys[0]]
    lookalikes = {}
    for m in best.members:
        others = [x for x in best.members if x != m]
        rivals = [n for n in s.names if n not in best.members
                  and tuple(sorted([*others, n])) in s.visited
                  and s.bic(tuple(sorted([*others, n]))) - bics[0] < LOOKALIKE_BIC]
        if rivals:
            lookalikes[m] = tuple(sorted(rivals, key=lambda n: s.bic(tuple(sorted([*others, n])))))
    not_named, named = {}, []
    _, n_eff = log_likelihood(best.sums, s.taus)
    for m in best.members:
        bound = s.att.at_bounds(best.fit, m)
        if bound:
            not_named[m] = NotNamed(AT_BOUND, inclusion[m], bound, lookalikes.get(m, ()))
        elif inclusion[m] < P_NAMED:
            not_named[m] = NotNamed(INCLUSION_LOW, inclusion[m], rivals=lookalikes.get(m, ()))
        else:
            named.append(m)
    return Decision(tuple(rows), best, tuple(named), inclusion, not_named, lookalikes, dict(s.taus), s.channels,
                    float(n_eff), dict(s.singles))
