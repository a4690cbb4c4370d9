"""Replays of fitted effect sets (udrobot_ctrl/gap/sets.py): the cache of one diagnosis's recent replays."""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap import sets
from udrobot_ctrl.gap.attribute import Fit
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.effects import Actuation
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import load_model


def _prepared_run(n=1200, dt=0.05, seed=1):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    ch = {c: 0.2 * np.sin(0.3 * t + k) + rng.normal(0, 0.01, n)
          for k, c in enumerate(("u", "v", "w", "p", "q", "r", "z", "phi", "theta", "psi"))}
    run = Run(path="r.csv", t=t, channels=ch, input_kind="thrust", inputs=np.zeros((n, 4)), extra={}, metadata={})
    return prepare(run, plant_parameters(load_model("pendulum:chin")), "r.csv")



def test_a_set_replayed_again_is_the_same_replay_and_equals_a_fresh_one():
    """A ReplayCache keeps one diagnosis's recent replays: the same set with the same parameters on the same runs
    is not integrated again, and what it returns is what the integration gives; without a cache nothing is kept."""
    prep = _prepared_run()
    p = plant_parameters(load_model("pendulum:chin"))
    cat = fx.catalogue()
    act = Actuation(prep.B, prep.inflow, prep.f_ref, np.asarray(p.M_A, float))
    fit = Fit(("buoyancy_offset",), {"buoyancy_offset": ()}, {"buoyancy_offset": {"dB_N": 1.5}}, np.ones(1), 1, 0.0)
    other = Fit(("buoyancy_offset",), {"buoyancy_offset": ()}, {"buoyancy_offset": {"dB_N": -1.0}}, np.ones(1), 1,
                0.0)
    scored = ["w", "z"]
    cache = sets.ReplayCache()
    first = sets.replay_sets([prep], p, [(fit, ("buoyancy_offset",)), (None, ())], cat, act, 6.0, scored, cache)
    again = sets.replay_sets([prep], p, [(other, ("buoyancy_offset",)), (fit, ("buoyancy_offset",))], cat, act,
                                6.0, scored, cache)
    assert again[1] is first[0] and len(cache) == 3
    assert again[0].gap.value != first[0].gap.value  # other parameters: replayed
    fresh = sets.replay_sets([prep], p, [(fit, ("buoyancy_offset",))], cat, act, 6.0, scored)[0]  # no cache
    assert fresh is not first[0] and fresh.gap == first[0].gap
    np.testing.assert_array_equal(fresh.sims[0], first[0].sims[0])
    # another run (another object) is replayed, whatever its contents; another cache keeps nothing of this one
    prep2 = _prepared_run()
    assert sets.replay_sets([prep2], p, [(fit, ("buoyancy_offset",))], cat, act, 6.0, scored, cache)[0] \
        is not first[0]
    assert sets.replay_sets([prep], p, [(fit, ("buoyancy_offset",))], cat, act, 6.0, scored,
                               sets.ReplayCache())[0] is not first[0]
    small = sets.ReplayCache(kept=1)  # the oldest replay goes beyond ``kept``
    a = sets.replay_sets([prep], p, [(fit, ("buoyancy_offset",))], cat, act, 6.0, scored, small)[0]
    sets.replay_sets([prep], p, [(other, ("buoyancy_offset",))], cat, act, 6.0, scored, small)
    assert len(small) == 1
    assert sets.replay_sets([prep], p, [(fit, ("buoyancy_offset",))], cat, act, 6.0, scored, small)[0] is not a
