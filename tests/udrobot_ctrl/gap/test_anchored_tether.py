"""A tether tied to a fixed point on the pool deck, the vehicle looping around the pool (issue 13.2).

The truth cable (:func:`.truth.anchored_tether`) is straight from the deck to the vehicle, its normal drag integrated
along 20 nodes with each node's velocity and growing with the cable's length (taut); the template integrates over
three points and chooses between a drag per metre of the straight line (``cable_taut`` 1) and a lumped one (a slack
cable of fixed paid-out length, 0). As the vehicle loops, the cable's direction sweeps through more than 120 degrees: a
template with a fixed direction could not follow it, and the diagnoser named a thrust inflow loss or a damping
error instead. Each case: three 60 s runs at 20 Hz (two fit, one holdout), one seed; about 40 s each on one core
(generation ~20 s, diagnosis ~20 s).
"""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.effects import TETHER_ANCHOR
from udrobot_ctrl.gap.report import corrected_model, diagnose

from .truth import anchored_tether, generate, random_magnitudes

#: the fitted anchor within 1 m of the deck point horizontally and 0.8 m vertically: the vehicle passes within
#: 1-2 m of it and goes 8-9 m away; the lumped template of earlier stops traded the truth's length-dependent drag
#: for an anchor displaced by 0.1-0.7 m (seeds 2 and 3)
ANCHOR_TOLERANCE_M = (1.0, 0.8)


def _case(effects, seed, **tether):
    rng = np.random.default_rng(seed + 100)
    truth = {n: anchored_tether(rng) | tether if n == "tether_drag" else random_magnitudes(n, rng) for n in effects}
    runs = generate(truth, n_runs=3, duration=60.0, rate=20.0, seed=seed, path="loop")
    report, _ = diagnose("pendulum:chin", runs)
    return truth, runs, report


def _significant(report):
    return {e["name"]: e for e in report["effects"] if e["significant"]}


@pytest.fixture(scope="module")
def alone():
    return _case(["tether_drag"], seed=2)


@pytest.fixture(scope="module")
def with_inflow_loss():
    return _case(["tether_drag", "thrust_inflow_loss"], seed=2)


@pytest.mark.slow
def test_the_loop_path_swings_the_cable_around(alone):
    """The case is what it claims: the bearing from the vehicle to the anchor turns through > 120 deg in each run."""
    truth, runs, _ = alone
    a = truth["tether_drag"]["anchor"]
    for run in runs:
        x, y = run.channels["x"], run.channels["y"]
        assert np.degrees(np.ptp(np.unwrap(np.arctan2(a[1] - y, a[0] - x)))) > 120.0


@pytest.mark.slow
def test_anchored_tether_is_named_alone_and_shrinks_the_gap(alone):
    truth, _, report = alone
    sig = _significant(report)
    assert set(sig) == {"tether_drag"}, {e["name"]: (e["significant"], e["shrink"]) for e in report["effects"]}
    assert sig["tether_drag"]["shrink"] >= 0.5


@pytest.mark.slow
def test_the_fitted_anchor_is_the_deck_point(alone):
    truth, _, report = alone
    q = _significant(report)["tether_drag"]["params"]
    fitted = np.array([q[k] for k in TETHER_ANCHOR])
    true = np.asarray(truth["tether_drag"]["anchor"], float)
    assert np.hypot(*(fitted[:2] - true[:2])) < ANCHOR_TOLERANCE_M[0], (fitted, true)
    assert abs(fitted[2] - true[2]) < ANCHOR_TOLERANCE_M[1], (fitted, true)
    assert q["walk_fraction"] < 0.5, q  # a deck point: the top end stands still
    assert q["cable_taut"] > 0.5, q  # the truth's drag grows with the straight-line length
    assert _significant(report)["tether_drag"]["top_end"]["reading"] == "at the surface"


@pytest.mark.slow
def test_the_corrected_model_carries_the_anchor(alone):
    _, runs, report = alone
    v, not_placed = corrected_model("pendulum:chin", report, runs)
    assert not_placed == {}
    (tether,) = [e for e in v.effects if e.name == "tether_drag"]
    assert dict(tether.params) == _significant(report)["tether_drag"]["params"]
    assert set(TETHER_ANCHOR) <= set(tether.params) and "cable_azimuth_rad" not in tether.params


@pytest.mark.slow
def test_anchored_tether_and_inflow_loss_are_both_named_and_nothing_else(with_inflow_loss):
    _, _, report = with_inflow_loss
    sig = _significant(report)
    assert set(sig) == {"tether_drag", "thrust_inflow_loss"}, \
        {e["name"]: (e["significant"], e["shrink"]) for e in report["effects"]}


@pytest.fixture(scope="module")
def walking():
    """A handler walking along the pool edge (the wall line y = 0) ``back`` m behind the vehicle, legs along and
    across the pool (:func:`.truth.random_magnitudes`)."""
    rng = np.random.default_rng(7)
    truth = {"tether_drag": random_magnitudes("tether_drag", rng)}
    runs = generate(truth, n_runs=3, duration=60.0, rate=20.0, seed=7)
    report, _ = diagnose("pendulum:chin", runs)
    return truth, runs, report


@pytest.mark.slow
def test_a_handler_walking_the_tether_along_the_pool_edge_is_found_walking(walking):
    """The fitted top end walks along the edge (north, or south: the same line) with the vehicle, behind it by the
    truth's distance within 1.5 m, on the edge's line within 1 m, in the taut form (the truth's drag grows with the
    straight-line length), and the tether is named alone."""
    truth, _, report = walking
    sig = _significant(report)
    assert set(sig) == {"tether_drag"}, {e["name"]: (e["significant"], e["shrink"]) for e in report["effects"]}
    q = sig["tether_drag"]["params"]
    assert q["walk_fraction"] > 0.5, q
    assert q["cable_taut"] > 0.5, q
    chi = q["walk_azimuth_rad"]
    d = np.array([np.cos(chi), np.sin(chi)])
    assert abs(d[0]) > np.cos(0.3), q  # along north-south, the edge's line
    top = np.array([q["anchor_north_m"], q["anchor_east_m"]])
    assert abs(top @ d * np.sign(d[0]) + truth["tether_drag"]["back"]) < 1.5, (q, truth)
    assert abs(top @ np.array([-d[1], d[0]])) < 1.0, q  # the edge line y = 0


@pytest.mark.slow
def test_a_slack_cable_from_the_deck_is_found_slack():
    """The same deck anchor with 12 m of cable paid out whatever the distance (the vehicle goes 1-9 m from the
    deck): the drag no longer grows with the straight-line length, and the search picks the lumped (slack) form,
    named alone, anchored near the deck point. The form is chosen by the data, not by a default."""
    truth, _, report = _case(["tether_drag"], seed=2, slack_length=12.0)
    sig = _significant(report)
    assert set(sig) == {"tether_drag"}, {e["name"]: (e["significant"], e["shrink"]) for e in report["effects"]}
    q = sig["tether_drag"]["params"]
    assert q["cable_taut"] < 0.5, q
    fitted = np.array([q[k] for k in TETHER_ANCHOR])
    assert np.hypot(*(fitted[:2] - np.asarray(truth["tether_drag"]["anchor"][:2]))) < ANCHOR_TOLERANCE_M[0], q
