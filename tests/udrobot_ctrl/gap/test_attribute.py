"""Fits that end on the edge of the catalogue's range are flagged (Attributor.at_bounds)."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import Attributor, build_stack, filter_forces
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.identifiability import Restricted
from udrobot_ctrl.vehicle import load_model

from .stock_sim import STATE, simulate

P = plant_parameters(load_model("pendulum:chin"))


@pytest.fixture(scope="module")
def attributor():
    preps = [prepare(simulate(duration=30.0, seed=3, sensors=STATE)[0], P)]
    st, r, dofs = build_stack(preps, P, P.M_A)
    return Attributor(st, r, dofs, fx.catalogue())


def test_a_lag_at_the_top_of_its_range_is_flagged_and_one_inside_is_not(attributor):
    (lo, hi), (k_lo, k_hi) = fx.catalogue()["thruster_lag"].shape_bounds
    at_top = attributor.fit([("thruster_lag", (hi, 1.5))])
    assert attributor.at_bounds(at_top, "thruster_lag") == {"T_lag_s": (hi, hi)}
    # a thrust exponent of 1 or 2 is a physical form (a lag of the thrust, of the rotor speed), not a search limit
    for k in (k_lo, k_hi):
        inside = attributor.fit([("thruster_lag", (0.3, k))])
        assert attributor.at_bounds(inside, "thruster_lag") == {}


def test_an_amplitude_fitted_to_zero_on_a_zero_bound_is_not_flagged(attributor):
    # a fitted zero on a one-sided bound (k >= 0) means "absent", not a fit pushed against the physical range
    fit = attributor.fit([("thrust_inflow_loss", ())])
    flagged = attributor.at_bounds(fit, "thrust_inflow_loss")
    assert all(v[1] != 0.0 for v in flagged.values())


def test_a_damping_well_inside_a_wide_one_sided_range_is_not_flagged(attributor):
    # linear damping may add from -D_L (no damping left) up to 1e4: a value of a few N s/m is inside, however wide
    # the range is; one at -D_L is at its physical end
    fit = attributor.fit([("linear_damping", ())])
    d = attributor.design("linear_damping", ())
    inside = {n: 2.0 for n in d.names}
    fit_inside = type(fit)(**{**fit.__dict__, "params": {"linear_damping": inside}})
    assert attributor.at_bounds(fit_inside, "linear_damping") == {}
    at_end = {n: float(lo) for n, lo in zip(d.names, d.lower)}
    fit_end = type(fit)(**{**fit.__dict__, "params": {"linear_damping": at_end}})
    assert set(attributor.at_bounds(fit_end, "linear_damping")) == {n for n, lo in zip(d.names, d.lower) if lo != 0}


def test_bic_counts_only_the_shape_parameters_the_search_moves(attributor):
    """A form held at one end (stock runs keep the per-axis quadratic drag) is not a fitted parameter."""
    cat = fx.catalogue()
    held = Attributor(attributor.s, attributor.r, attributor.dofs,
                      {**cat, "quadratic_damping_error": Restricted(cat["quadratic_damping_error"], (),
                                                                    {"norm_weight": 0.0})})
    assert attributor.free_shapes("quadratic_damping_error") == 1 and held.free_shapes("quadratic_damping_error") == 0
    assert attributor.free_shapes("thruster_lag") == 2 and attributor.free_shapes("buoyancy_offset") == 0
    free = attributor.fit([("quadratic_damping_error", (0.0,))])
    fixed = held.fit([("quadratic_damping_error", (0.0,))])
    assert free.k == fixed.k + 1 and free.rss == pytest.approx(fixed.rss)


def test_filtering_only_the_stacked_rows_gives_the_full_filter_there():
    """The stack filters forces only at its (decimated) rows: the same sums as the full-rate filter, bit for bit,
    nan at the ends and next to a nan sample."""
    run, _ = simulate(duration=10.0, rate=50.0, seed=5)
    prep = prepare(run, P)
    y = np.random.default_rng(0).normal(size=(prep.n, 6, 2))
    y[200, 3] = np.nan
    at = np.r_[0, 1, np.arange(2, prep.n, 5), prep.n - 1]
    for held in (False, True):
        full = filter_forces(prep, y, held)
        part = filter_forces(prep, y, held, at=at)
        np.testing.assert_array_equal(part, full[at])
        assert np.isnan(part[0]).all() and np.isnan(part[-1]).all()
        assert np.isnan(full[200, 3]).all() and np.isfinite(full[200, 2]).all()
