"""Where a fitted tether's top end lies against the surface (udrobot_ctrl/gap/top_end.py)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.gap.effects import FAR_ANCHOR_M, TOP_END_DEPTH_MAX_M, catalogue
from udrobot_ctrl.gap.top_end import READINGS, SURFACE_TOLERANCE_M, top_end


def _track(depth=12.5, n=400):
    """A transect 20 m long at ``depth`` (m), heading north."""
    x = np.linspace(0.0, 20.0, n)
    return np.c_[x, np.zeros(n), np.full(n, depth)]


def _anchor(n, e, d):
    return {"anchor_north_m": n, "anchor_east_m": e, "anchor_down_m": d, "k_quadratic_N_s2_per_m2": 10.0}


def test_a_top_end_on_the_deck_is_at_the_surface():
    end = top_end(_anchor(-5.0, 3.0, -0.5), _track(depth=1.2))
    assert end.reading == READINGS[0] and not end.far
    assert end.vehicle_depth_m == pytest.approx(1.2) and end.elevation_deg > 0


def test_the_shared_sea_dives_tether_fit_ends_near_the_vehicles_depth_not_at_the_surface():
    """The sea dive's tether fit (dropped by the holdout check) put its top end 11.8 m down, the vehicle at 12-14 m:
    a free-form force, and the text says what the log lacks."""
    end = top_end(_anchor(-5.3, -2.9, 11.84), _track(depth=12.9))
    assert end.reading == READINGS[1] and "missing: where the tether was paid out from" in end.text
    assert "below the vehicle" not in end.text
    deeper = top_end(_anchor(-5.3, -2.9, 15.0), _track(depth=12.9))
    assert deeper.reading == READINGS[1] and "below the vehicle" in deeper.text


def test_a_top_end_pinned_at_the_searchs_depth_limit_is_read_below_the_surface():
    """The search stops a top end at SURFACE_TOLERANCE_M down: a fit that ends there wants it under water (the sea
    dive's tether fit, once bounded)."""
    assert top_end(_anchor(0, 0, SURFACE_TOLERANCE_M - 0.05), _track()).reading == READINGS[0]
    pinned = top_end(_anchor(7.0, 0, SURFACE_TOLERANCE_M), _track())
    assert pinned.reading == READINGS[1] and "pinned at 1.0 m down" in pinned.text
    assert top_end(_anchor(0, 0, SURFACE_TOLERANCE_M + 0.5), _track()).reading == READINGS[1]


def test_a_top_end_at_the_limit_where_the_surface_fits_as_well_is_at_the_surface():
    """A fit that drifts to the 1 m limit because the runs cannot place the top end within that metre (it would not
    go on deeper, clearly better: the limit does not bind) is a tether at the surface, not a free-form force."""
    flat = top_end(_anchor(7.0, 0, SURFACE_TOLERANCE_M), _track(), limit_binds=False)
    assert flat.reading == READINGS[0] and "would not go clearly better deeper" in flat.text, flat.text
    deeper = top_end(_anchor(7.0, 0, 3.0), _track(), limit_binds=False)  # beyond the limit: below whatever binds
    assert deeper.reading == READINGS[1]


def test_far_top_ends_are_cable_directions_read_by_their_elevation():
    el = np.radians(45.0)  # from the track's median point (10, 0, 12.5)
    up = top_end(_anchor(10.0 + FAR_ANCHOR_M * np.cos(el), 0.0, 12.5 - FAR_ANCHOR_M * np.sin(el)), _track())
    assert up.far and up.reading == READINGS[2] and up.elevation_deg == pytest.approx(45.0, abs=0.5)
    down = top_end(_anchor(10.0, 0.0, 12.5 + FAR_ANCHOR_M), _track())
    assert down.far and down.reading == READINGS[3] and down.elevation_deg == pytest.approx(-90.0, abs=0.5)


def test_fits_without_an_anchor_or_runs_without_a_position_give_no_reading():
    assert top_end({"k_quadratic_N_s2_per_m2": 1.0}, _track()) is None
    assert top_end(_anchor(0, 0, 0), np.full((10, 3), np.nan)) is None


def test_the_tether_search_keeps_its_top_end_within_the_reach_of_the_surface():
    """Grid and refinement bounds: no top end deeper than TOP_END_DEPTH_MAX_M, however deep the vehicle flies."""
    stack = SimpleNamespace(eta=np.c_[_track(depth=40.0), np.zeros((400, 3))], p=SimpleNamespace(size_m=0.25))
    grid, bounds = catalogue()["tether_drag"].search_space(stack)
    assert bounds[2][1] == TOP_END_DEPTH_MAX_M == SURFACE_TOLERANCE_M
    assert all(g[2] <= TOP_END_DEPTH_MAX_M for g in grid)
