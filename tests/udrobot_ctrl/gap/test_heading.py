"""What the runs' headings let a diagnosis say of a steady current (udrobot_ctrl/gap/heading.py)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.gap.heading import (
    CURRENT,
    CURRENT_CHI2,
    CURRENT_READINGS,
    DIRECTION_SPEED,
    ONE_HEADING_STD_DEG,
    READINGS,
    REVERSED_DEG,
    VERTICAL_CURRENT_MPS,
    heading_coverage,
    headings,
    part_current,
    read_currents,
)
from udrobot_ctrl.gap.parts import SAME_SHARE, Agreement
from udrobot_ctrl.gap.report import attribute, build_stacks, headings_and_currents, prepare_inputs

from .truth import generate


def _run(psi):
    """A prepared run as heading_coverage reads it: its measured heading, rad (nan: not logged)."""
    return SimpleNamespace(meas={"psi": np.asarray(psi, float)})


def _noisy(mean_deg, std_deg, n=2000, seed=0):
    rng = np.random.default_rng(seed)
    return np.radians(mean_deg + std_deg * rng.standard_normal(n))


def test_runs_on_one_heading_say_the_current_is_a_body_fixed_force_and_what_is_missing():
    cov = heading_coverage([_run(_noisy(30, 5, seed=1)), _run(_noisy(32, 5, seed=2))], [_run(_noisy(28, 5, seed=3))])
    assert cov.reading == READINGS[0]
    assert cov.all_std_deg == pytest.approx(5.0, abs=0.5)  # the wrapped normal's spread
    assert cov.fit.mean_deg == pytest.approx(31.0, abs=0.5) and cov.holdout.mean_deg == pytest.approx(28.0, abs=0.5)
    assert "missing: a run on another heading" in cov.text


def test_a_holdout_flown_the_other_way_tests_the_fit_runs_current():
    """The shared sea dive's split: fit part near -136 deg, holdout near 38 deg (174 deg apart)."""
    cov = heading_coverage([_run(_noisy(-136, 25, seed=4))], [_run(_noisy(38, 10, seed=5))])
    assert cov.reading == READINGS[1]
    assert cov.separation_deg == pytest.approx(174.0, abs=2.0) and cov.separation_deg >= REVERSED_DEG
    assert "tests its direction" in cov.text and "missing" not in cov.text


def test_turning_runs_with_a_holdout_on_the_same_mean_heading_vary():
    turns = np.radians(np.linspace(-60, 60, 3000))  # a sweep of +-60 deg: spread ~35 deg
    cov = heading_coverage([_run(turns)], [_run(turns[::-1] + np.radians(10))])
    assert cov.reading == READINGS[2]
    assert cov.all_std_deg > ONE_HEADING_STD_DEG and cov.separation_deg < REVERSED_DEG


def test_headings_across_north_are_averaged_on_the_circle():
    """179 deg and -179 deg are 2 deg apart: one heading near 180, not a mean of 0 and a spread of 179."""
    psi = np.radians(np.r_[np.full(500, 179.0), np.full(500, -179.0)])
    h = headings([psi])
    assert abs(abs(h.mean_deg) - 180.0) < 1e-6 and h.std_deg == pytest.approx(1.0, abs=0.01)
    cov = heading_coverage([_run(psi)], [_run(psi)])
    assert cov.reading == READINGS[0] and cov.separation_deg == pytest.approx(0.0, abs=1e-6)


def test_opposite_headings_have_no_single_heading():
    """Equal time on two opposite headings: mean resultant 0, an infinite circular spread, never 'one heading'."""
    psi = np.r_[np.zeros(100), np.full(100, math.pi)]
    assert headings([psi]).std_deg > 100.0
    assert heading_coverage([_run(psi)], [_run(psi)]).reading != READINGS[0]


def test_runs_without_a_logged_heading_give_no_coverage():
    assert heading_coverage([_run(np.full(50, np.nan))], [_run(_noisy(0, 5))]) is None
    assert heading_coverage([SimpleNamespace(meas={})], [_run(_noisy(0, 5))]) is None
    assert headings([]) is None


def test_a_current_is_given_its_direction_in_the_world_and_off_the_bow():
    c = part_current((0.1, 0.1, -0.02), heading_deg=-90.0)  # flowing north-east, the vehicle heading west
    assert c.speed == pytest.approx(math.hypot(0.1, 0.1)) and c.toward_deg == pytest.approx(45.0)
    assert c.off_bow_deg == pytest.approx(135.0) and c.down == pytest.approx(-0.02)
    slow = part_current((0.5 * DIRECTION_SPEED, 0.0, 0.1), heading_deg=0.0)  # too slow for a direction
    assert math.isnan(slow.toward_deg) and math.isnan(slow.off_bow_deg)


def test_currents_that_keep_their_bearing_off_the_bow_while_the_vehicle_reverses_turn_with_it():
    """The shared sea dive's figures: the fit part's current flows 146 deg off the bow to port, the holdout's 167 deg,
    while the vehicle turned 171 deg; the fit part's current makes the holdout worse than none."""
    fit, hold = part_current((0.0225, 0.0444, -0.085), -151.0), part_current((-0.0240, -0.0296, -0.011), 38.0)
    reading, text, world, body = read_currents(fit, hold, 171.0, Agreement(54.0, -1.41))
    assert reading == CURRENT_READINGS[2] and "body-fixed force" in text
    assert world == pytest.approx(168.0, abs=1.0) and body == pytest.approx(21.0, abs=1.0)
    # the same currents, the vehicle not turned: they disagree in the world and off the bow alike
    assert read_currents(fit, hold, 10.0, Agreement(54.0, -1.41))[0] == CURRENT_READINGS[3]


def test_the_holdouts_support_decides_before_the_directions():
    fit, hold = part_current((0.1, 0.0, 0.0), 0.0), part_current((0.1, 0.01, 0.0), 180.0)
    assert read_currents(fit, hold, 180.0, Agreement(CURRENT_CHI2 - 0.1, 0.9))[0] == CURRENT_READINGS[1]
    one = read_currents(fit, hold, 180.0, Agreement(10 * CURRENT_CHI2, SAME_SHARE))
    assert one[0] == CURRENT_READINGS[0] and one[2] == pytest.approx(5.7, abs=0.1)
    # a current the holdout's own beats by more than half, pointing the same way in the world: not one current,
    # and not a body-fixed force either (it did not keep its bearing off the bow)
    assert read_currents(fit, hold, 180.0, Agreement(10 * CURRENT_CHI2, 0.2))[0] == CURRENT_READINGS[3]


def test_a_share_reached_through_the_vertical_part_with_opposed_directions_is_not_one_current():
    """The Tartan pool log's figures: both parts fit 0.14-0.15 m/s upward, their horizontal currents 129 deg apart
    on one heading; the fit runs' current does 80% of the holdout's own there, through the vertical part."""
    fit, hold = part_current((-0.068, -0.087, -0.140), 25.0), part_current((-0.018, 0.080, -0.152), 12.0)
    reading, text, world, _ = read_currents(fit, hold, 13.0, Agreement(60.0, 0.80))
    assert reading == CURRENT_READINGS[3] and world == pytest.approx(129.0, abs=2.0)
    assert "129 deg apart" in text and "stands in for a heave force" in text
    # the same share with the horizontal parts along one direction: one current, its vertical part still named
    same = part_current((-0.060, -0.080, -0.150), 12.0)
    reading, text, _, _ = read_currents(fit, same, 13.0, Agreement(60.0, 0.80))
    assert reading == CURRENT_READINGS[0] and "stands in for a heave force" in text
    calm = part_current((-0.060, -0.080, 0.5 * VERTICAL_CURRENT_MPS), 12.0)
    assert "heave force" not in read_currents(calm, calm, 0.0, Agreement(60.0, 0.9))[1]


def _split_headings(effects, seed=3):
    """Fit runs flown north, the holdout run the reverse transect (south), with ``effects`` withheld; the report's
    heading_coverage after the fit of the current alone."""
    runs = generate(effects, n_runs=3, duration=60.0, seed=seed, headings=[0.0, 0.0, math.pi])
    inp = prepare_inputs("pendulum:chin", runs, None, None, 8.0)  # the last run held out
    stacks = build_stacks(inp)
    return headings_and_currents(inp, stacks, attribute(stacks, [CURRENT]))


@pytest.mark.slow
def test_a_steady_current_is_found_in_both_parts_and_read_as_one():
    """A 0.12 m/s current toward 034 deg (a 1/7-power profile over the pool depth: 0.09-0.11 m/s where the runs
    fly), fitted on the northbound fit runs and on the southbound holdout apart: the same current twice."""
    hc = _split_headings({"water_current": {"V0": 0.12, "dir": math.radians(34.0)}})
    cur = hc.currents
    assert hc.reading == READINGS[1] and cur.reading == CURRENT_READINGS[0]
    for part in (cur.fit, cur.holdout):
        assert 0.07 < part.speed < 0.13 and part.toward_deg == pytest.approx(34.0, abs=8.0)
        assert abs(part.down) < 0.02  # no vertical current
    assert cur.share > 0.8 and cur.world_angle_deg < 10.0 and cur.body_angle_deg > 150.0


@pytest.mark.slow
def test_a_constant_push_in_the_body_frame_is_no_current():
    """The horizontal thrusters' ESCs trimmed 2 N off neutral: a body-fixed surge force that a current cannot make
    while the vehicle hovers, surges and reverses; neither part fits a current, the holdout supports none."""
    hc = _split_headings({"neutral_offset": {"X": -2.0}})
    assert hc.currents.reading == CURRENT_READINGS[1]
    assert hc.currents.fit.speed < 0.02 and hc.currents.holdout.speed < 0.02
