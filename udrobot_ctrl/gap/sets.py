"""Replays of fitted effect sets: the nominal plant plus some catalogue effects with their fitted parameters,
replayed window by window on prepared runs (:mod:`udrobot_ctrl.gap.shrink`), several sets integrated together,
the most recent kept.

The selection table (:mod:`udrobot_ctrl.gap.decide`) scores the fit runs' replays of every set it visits; the report
replays the chosen model and each effect alone on the holdout runs, which only score.
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from udrobot_ctrl.gap.attribute import Fit
from udrobot_ctrl.gap.effects import Actuation
from udrobot_ctrl.gap.shrink import GapScore, gap, simulate_windows_sets
from udrobot_ctrl.parallel import fork_map, shares, workers


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
