"""Designs kept by content (DesignStore): an effect's declared reads are all its design reads, and a design is
shared only between stacks whose read arrays hold the same values."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import Attributor, DesignStore, build_stack
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.identifiability import assess
from udrobot_ctrl.vehicle import load_model

from .stock_sim import STOCK, simulate

P = plant_parameters(load_model("pendulum:chin"))
RUN_ARRAYS = ("f", "eta", "nu", "nu_dot")


@pytest.fixture(scope="module")
def stock():
    runs = [simulate(duration=30.0, seed=seed, sensors=STOCK)[0] for seed in (21, 22)]
    return runs, [prepare(r, P) for r in runs]


def _moved(s: fx.Stack, what: str) -> fx.Stack:
    """``s`` with the run array ``what`` (and its stacked rows) changed: 10 % larger plus an offset of 0.05 in its
    units (so that a zero stays no zero)."""
    def move(a):
        return 1.1 * a + 0.05
    runs = []
    for r in s.runs:
        new = dict(r, **{what: move(r[what])})
        if what in ("eta", "nu"):
            new["x"] = np.concatenate([new["eta"], new["nu"]], axis=1)
        runs.append(new)
    stacked = {"f": "f", "eta": "eta", "nu": "nu", "nu_dot": "nu_dot"}[what]
    return replace(s, runs=runs, **{stacked: move(getattr(s, stacked))})


def _shape(eff: fx.Effect, s: fx.Stack) -> tuple:
    grid = list(eff.search_space(s)[0])
    return tuple(grid[len(grid) // 2])


@pytest.mark.parametrize("name", [n for n, e in fx.catalogue().items() if e.reads is not None])
def test_a_design_reads_no_run_array_beyond_its_declared_reads(stock, name):
    """Moving every run array an effect does not declare leaves its design bit for bit the same (a design that read
    one would change: a store would hand out another state's regressors); moving a declared one changes its key."""
    _, preps = stock
    s, _, _ = build_stack(preps, P, P.M_A)
    eff = fx.catalogue()[name]
    shape = _shape(eff, s)
    d0 = eff.design(s, shape)
    for what in RUN_ARRAYS:
        moved = _moved(s, what)
        if what in eff.reads:
            assert fx.content_key(moved, eff.reads) != fx.content_key(s, eff.reads)
            continue
        d = eff.design(moved, shape)
        for got, want in zip(d[:2], d0[:2]):
            np.testing.assert_array_equal(got, want, err_msg=f"{name} reads {what}")
        assert fx.content_key(moved, eff.reads) == fx.content_key(s, eff.reads)


def test_attributors_sharing_a_store_compute_a_design_once_per_content(stock):
    """Two stacks of the same runs prepared twice share their command-only designs (the same arrays), and fit as a
    stack with a store of its own does; a stack whose commands differ gets its own design."""
    runs, preps = stock
    store = DesignStore()
    again = [prepare(r, P) for r in runs]
    (s1, r1, d1), (s2, r2, d2) = build_stack(preps, P, P.M_A), build_stack(again, P, P.M_A)
    cat = fx.catalogue()  # a key names the effect: the attributors of one diagnosis share its catalogue
    a1, a2 = Attributor(s1, r1, d1, cat, store=store), Attributor(s2, r2, d2, cat, store=store)
    alone = Attributor(s2, r2, d2, cat)
    shape = (0.2, 1.5)
    assert a2.design("thruster_lag", shape).b0 is a1.design("thruster_lag", shape).b0
    f1, f2 = a2.fit([("thruster_lag", shape)]), alone.fit([("thruster_lag", shape)])
    assert np.array_equal(f1.rss, f2.rss) and f1.params == f2.params
    louder = [replace(pr, f=1.5 * pr.f) for pr in preps]
    s3, r3, d3 = build_stack(louder, P, P.M_A)
    a3 = Attributor(s3, r3, d3, cat, store=store)
    b3 = a3.design("thruster_lag", shape).b0
    assert b3 is not a1.design("thruster_lag", shape).b0
    np.testing.assert_allclose(b3, 1.5 * a1.design("thruster_lag", shape).b0, rtol=1e-9, atol=1e-9)


def test_an_assessment_with_a_store_is_the_one_without(stock):
    """The identifiability checks read the same designs from a store as they compute: the same verdicts, shares and
    sensitivities."""
    _, preps = stock
    s, r, dofs = build_stack(preps, P, P.M_A)
    cat = fx.catalogue()
    plain, stored = assess(s, r, dofs, preps, cat, store=None), assess(s, r, dofs, preps, cat, store=DesignStore())
    for name in cat:
        assert plain.effects[name] == stored.effects[name], name
