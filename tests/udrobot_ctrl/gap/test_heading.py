"""What the runs' headings let a diagnosis say of a steady current (udrobot_ctrl/gap/heading.py)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.gap.heading import ONE_HEADING_STD_DEG, READINGS, REVERSED_DEG, heading_coverage, headings


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
