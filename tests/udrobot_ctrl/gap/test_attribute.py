"""The equation-error Attributor: fits at the edge of the catalogue's range are flagged (at_bounds), the stack's
filtering, and effects composed in the plant's order (an inflow loss on the lagged thrust)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import (
    FILTER_COLUMNS,
    ArrayCache,
    Attributor,
    bounded_normal_solve,
    build_stack,
    filter_forces,
)
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.identifiability import Restricted
from udrobot_ctrl.gap.shrink import delivered_commands, effect_wrench
from udrobot_ctrl.parallel import JOBS_ENV, can_fork, workers
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


def test_an_attributor_with_one_effect_replaced_fits_it_in_the_new_form_and_the_rest_as_before(attributor):
    """The look-alike test of an untested form swaps one catalogue entry (the quadratic drag held on the speed norm)
    and keeps the cached designs of the others: their fits are unchanged, the swapped effect is fitted in its new
    form, and the original attributor still fits the old one."""
    cat = fx.catalogue()
    quad = attributor.fit([("quadratic_damping_error", (0.0,)), ("buoyancy_offset", ())])  # fills the caches
    norm = attributor.with_effect("quadratic_damping_error", Restricted(cat["quadratic_damping_error"], (),
                                                                        {"norm_weight": 1.0}))
    assert norm.n_eff == attributor.n_eff and norm.free_shapes("quadratic_damping_error") == 0
    assert norm.fit([("buoyancy_offset", ())]).rss == pytest.approx(attributor.fit([("buoyancy_offset", ())]).rss)
    assert norm.cat["quadratic_damping_error"].search_space(norm.s)[0] == ((1.0,),)
    swapped = norm.best_shape("quadratic_damping_error", [("buoyancy_offset", ())], refine=False)
    direct = attributor.fit([("quadratic_damping_error", (1.0,)), ("buoyancy_offset", ())])
    assert swapped.rss == pytest.approx(direct.rss, rel=1e-9)
    assert attributor.fit([("quadratic_damping_error", (0.0,)), ("buoyancy_offset", ())]).rss == pytest.approx(
        quad.rss)


def test_filtering_only_the_stacked_rows_gives_the_full_filter_there():
    """The stack filters forces only at its (decimated) rows: the same sums as the full-rate filter, bit for bit,
    nan at the ends and next to a nan sample."""
    run, _ = simulate(duration=10.0, rate=50.0, seed=5)
    prep = prepare(run, P)
    y = np.random.default_rng(0).normal(size=(prep.n, 6, 2))
    y[200, 3] = np.nan
    y[:, 4, 1] = 0.0  # a regressor that is zero throughout (a moment the force has none of): skipped, still zero
    at = np.r_[0, 1, np.arange(2, prep.n, 5), prep.n - 1]
    for held in (False, True):
        full = filter_forces(prep, y, held)
        part = filter_forces(prep, y, held, at=at)
        np.testing.assert_array_equal(part, full[at])
        assert np.isnan(part[0]).all() and np.isnan(part[-1]).all()
        assert np.isnan(full[200, 3]).all() and np.isfinite(full[200, 2]).all()
        inner = (at >= 40) & (at < prep.n - 40)
        assert np.all(part[inner, 4, 1] == 0.0) and np.all(part[inner, 4, 0] != 0.0)
    live = np.random.default_rng(1).normal(size=(prep.n, 6, 2))  # every regressor live (a tether's anchors)
    for held in (False, True):
        np.testing.assert_array_equal(filter_forces(prep, live, held, at=at), filter_forces(prep, live, held)[at])
    wide = np.random.default_rng(2).normal(size=(prep.n, 6, 50))  # columns filtered in blocks, some zero throughout
    wide[:, :, ::7] = 0.0
    assert wide[0].size > FILTER_COLUMNS
    for held in (False, True):
        np.testing.assert_array_equal(filter_forces(prep, wide, held, at=at), filter_forces(prep, wide, held)[at])


def test_an_inflow_loss_behind_a_lag_is_fitted_on_the_lagged_thrust():
    """The plant applies an inflow loss to the thrust the lag delivers; the equation-error fit of the pair must do the
    same. On a residual made by the plant's own lag (rotor-speed form, 0.45 s) and inflow loss, the pair's fit
    recovers both inflow coefficients within 1 % (0.6 % measured; the residual is noise-free, the rest is the
    derivative filter) and explains the residual; the inflow regressor on the commanded thrust (the two effects
    added, not composed) leaves a misfit over a hundred times larger (a thousand measured)."""
    run, _ = simulate(duration=40.0, rate=50.0, seed=4, sensors=STATE)
    prep = prepare(run, P)
    st, _, dofs = build_stack([prep], P, P.M_A)
    cat = fx.catalogue()
    truth = {"thruster_lag": {"T_lag_s": 0.45, "thrust_exponent": 2.0},
             "thrust_inflow_loss": {"k1_per_mps": 0.25, "k2_per_mps": 0.15}}
    act = fx.Actuation(prep.B, prep.inflow, prep.f_ref, P.M_A)
    hooks = [cat[n].hooks(q, P, act) for n, q in truth.items()]
    lagged = (delivered_commands(prep, hooks) - prep.f) @ prep.B.T  # a held command: filtered as the lag's design
    r = st.full(lambda _: lagged, held=True) + st.full(lambda _: effect_wrench(prep, hooks) - lagged)
    att = Attributor(st, r, dofs, cat)
    lag = ("thruster_lag", (0.45, 2.0))
    fit = att.fit([lag, ("thrust_inflow_loss", ())])
    for k in ("k1_per_mps", "k2_per_mps"):
        assert fit.params["thrust_inflow_loss"][k] == pytest.approx(truth["thrust_inflow_loss"][k], rel=0.01)
    assert att.upstream("thrust_inflow_loss", [lag, ("thrust_inflow_loss", ())]) == (lag,)
    assert att.upstream("thruster_lag", [lag, ("thrust_inflow_loss", ())]) == ()
    added = att.design("thrust_inflow_loss", ())  # the commanded thrust: the two effects summed, not composed
    lag_b0 = att.design(*lag).b0
    a, *_ = np.linalg.lstsq(added.A[:, dofs].reshape(-1, 2), (r - lag_b0)[:, dofs].ravel(), rcond=None)
    misfit_added = np.sum(((r - lag_b0)[:, dofs] - np.einsum("nik,k->ni", added.A[:, dofs], a)) ** 2)
    assert np.sum(fit.rss) < 0.01 * misfit_added
    assert np.sum(fit.rss) < 1e-3 * np.sum(r[:, dofs] ** 2)


@pytest.mark.parametrize("k", [1.0, 2.0])
def test_a_deadband_before_a_lag_is_fitted_with_its_thrust_change_lagged(k):
    """The plant lags the thrust after the deadband (ESC, then rotor). The pair's fit passes the deadband's thrust
    change through the lag (its small-signal form): on a residual made by the plant's own deadband (PWM form, 12 %
    wide) and lag, the deadband's amplitude is recovered within 0.5 % for a lag of the thrust (k = 1: the composition
    is exact; 1e-6 measured) and within 5 % for a lag of the rotor speed (k = 2: linearised; 2 % measured), and the
    composed fit leaves under a fifth of the misfit of the deadband taken as acting on the unlagged command (1/80
    and 1/17 measured)."""
    run, _ = simulate(duration=40.0, rate=50.0, seed=6, sensors=STATE)
    prep = prepare(run, P)
    st, _, dofs = build_stack([prep], P, P.M_A)
    cat = fx.catalogue()
    db = ("thruster_deadband", (0.12, 2.0))
    lag = ("thruster_lag", (0.4, k))
    truth = {"thruster_deadband": {"width_fraction": 0.12, "command_exponent": 2.0, "shift": 0.6},
             "thruster_lag": {"T_lag_s": 0.4, "thrust_exponent": k}}
    act = fx.Actuation(prep.B, prep.inflow, prep.f_ref, P.M_A)
    hooks = [cat[n].hooks(q, P, act) for n, q in truth.items()]
    r = st.full(lambda _: (delivered_commands(prep, hooks) - prep.f) @ prep.B.T, held=True)
    att = Attributor(st, r, dofs, cat)
    fit = att.fit([db, lag])
    assert att.upstream("thruster_deadband", [db, lag]) == (lag,)
    assert fit.params["thruster_deadband"]["shift"] == pytest.approx(0.6, rel=0.005 if k == 1.0 else 0.05)
    plain = att.design(*db)  # the deadband's change unlagged: the two effects summed
    y = (r - att.design(*lag).b0 - plain.b0)[:, dofs]
    a, *_ = np.linalg.lstsq(plain.A[:, dofs].reshape(-1, 1), y.ravel(), rcond=None)
    assert np.sum(fit.rss) < 0.2 * np.sum((y - plain.A[:, dofs, 0] * a[0]) ** 2)


def test_the_design_cache_drops_the_least_recently_used_arrays_beyond_its_byte_budget():
    cache = ArrayCache(max_bytes=3 * 800)
    for k in range(3):
        cache[k] = np.zeros(100)  # 800 bytes each
    _ = cache[0]  # used again: the oldest is now 1
    cache[3] = (np.zeros(100), "names")  # a tuple holding one array
    assert 1 not in cache and all(k in cache for k in (0, 2, 3)) and cache.nbytes == 3 * 800
    cache[4] = np.zeros(150)  # 1200 bytes: the two least recently used (2, then 0) go
    assert len(cache) == 2 and 4 in cache and 3 in cache and cache.nbytes == 2000
    kept = cache.without(lambda key: key == 3)
    assert 3 not in kept and 4 in kept and 3 in cache and kept.nbytes == 1200


def test_an_attributor_holds_its_designs_regressors_and_cross_products_under_one_budget(attributor):
    """The three caches of a fit share one byte budget: a small one is never exceeded, and the fits are the same."""
    budget = 200_000
    small = Attributor(attributor.s, attributor.r, attributor.dofs, attributor.cat, cache_bytes=budget)
    terms = [("thruster_lag", (T, 2.0)) for T in (0.1, 0.2, 0.3, 0.45)]
    for t in terms:
        fits = small.fit([t, ("linear_damping", ())]), attributor.fit([t, ("linear_damping", ())])
        assert 0 < small._cache.nbytes <= budget
        np.testing.assert_allclose(fits[0].rss, fits[1].rss, rtol=1e-9)


@pytest.mark.parametrize("bounds", [(-10.0, 10.0), (0.0, 10.0), (-10.0, -0.2)])
def test_the_bounded_normal_equations_solve_is_bounded_least_squares(bounds):
    """Inside the bounds, the unconstrained solution; with a bound active, what bounded-variable least squares on
    the same problem gives (the minimiser of a strictly convex problem is unique)."""
    rng = np.random.default_rng(11)
    A = rng.normal(size=(60, 4))
    y = A @ np.array([0.5, -0.3, 1.2, 0.05]) + 0.01 * rng.normal(size=60)
    lo, hi = np.full(4, bounds[0]), np.full(4, bounds[1])
    z = bounded_normal_solve(A.T @ A, A.T @ y, lo, hi)
    ref = lsq_linear(A, y, bounds=(lo, hi), method="bvls").x
    np.testing.assert_allclose(z, ref, rtol=1e-7, atol=1e-9)
    assert np.all(z >= lo) and np.all(z <= hi)


@pytest.mark.parametrize("fixed, name, restrict", [
    ([("buoyancy_offset", ())], "tether_drag", False),  # many anchors; k >= 0 binds for some of them
    ([("thruster_lag", (0.3, 1.5))], "thruster_deadband", False),  # its design sees the fixed lag
    ([("thrust_inflow_loss", ())], "thruster_lag", False),  # the fixed term's design changes with each lag
    ([("linear_damping", ())], "tether_drag", True),  # stock DOFs: the surge and sway columns are inactive
])
def test_a_grid_solved_together_gives_each_fits_own_likelihood(attributor, fixed, name, restrict):
    """The grid search solves its fits as one batch (Attributor.losses): each shape's log-likelihood is what its own
    fit gives, whether its amplitudes sit inside their bounds or on them, whether the fixed terms' designs change with
    the searched shape (a lag ahead of an inflow loss) or not, and with columns that act only where nothing is
    scored."""
    att = attributor
    if restrict:
        dofs = np.array([False, False, True, True, True, True])
        att = Attributor(attributor.s, attributor.r, dofs, fx.catalogue())
    grid = list(att.cat[name].search_space(att.s)[0])
    shapes = grid[:: max(1, len(grid) // 40)]
    together = att.losses(fixed, name, shapes, chunk=16)
    alone = np.array([att.fit(list(fixed) + [(name, sh)]).loglik_n for sh in shapes])
    np.testing.assert_allclose(together, alone, rtol=1e-10, atol=1e-10)
    assert np.ptp(alone) > 1e-6  # the shapes do differ
    if name == "tether_drag" and not restrict:
        on_bound = [att.fit(list(fixed) + [(name, sh)]).params[name]["k_quadratic_N_s2_per_m2"] == 0.0
                    for sh in shapes]
        assert any(on_bound) and not all(on_bound)


def test_a_fit_is_the_weighted_least_squares_solution(attributor):
    """One re-weighting (weights from the residual's RMS per DOF), amplitudes inside their bounds: the fit's
    amplitudes are numpy's least squares on the weighted, stacked scored DOFs."""
    terms = [("buoyancy_offset", ()), ("linear_damping", ())]
    fit = attributor.fit(terms, iters=1)
    d = attributor.dofs
    A = np.concatenate([attributor.design(n, sh).A for n, sh in terms], axis=2)[:, d]  # (n, nd, k)
    y = attributor.r[:, d] - sum(attributor.design(n, sh).b0 for n, sh in terms)[:, d]
    w = 1.0 / (np.sqrt(np.mean(attributor.r[:, d] ** 2, axis=0)) + 1e-12)
    on = np.einsum("nik,nik->k", A, A) > 0
    ref = np.zeros(A.shape[2])
    ref[on] = np.linalg.lstsq((A[:, :, on] * w[None, :, None]).reshape(-1, on.sum()), (y * w).ravel(),
                              rcond=None)[0]
    lo = np.concatenate([attributor.design(n, sh).lower for n, sh in terms])
    hi = np.concatenate([attributor.design(n, sh).upper for n, sh in terms])
    assert np.all((ref >= lo) & (ref <= hi))  # interior: the bounds do not act
    np.testing.assert_allclose(fit.a, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


def test_searches_delegated_to_a_helper_equal_those_made_here(attributor, monkeypatch):
    """A delegated effect's searches (Attributor.delegate: a forked helper keeping its designs) give the fits the
    caller's own searches give, started ahead (request) or asked for at once, alone or beside fixed terms."""
    monkeypatch.setenv(JOBS_ENV, "2")
    here = Attributor(attributor.s, attributor.r, attributor.dofs, fx.catalogue())
    there = Attributor(attributor.s, attributor.r, attributor.dofs, fx.catalogue())
    there.delegate(["tether_drag", "thruster_lag"])
    try:
        assert there.delegates("tether_drag") == can_fork() and not there.delegates("buoyancy_offset")
        calls = [("tether_drag", (), False), ("thruster_lag", [("buoyancy_offset", ())], True),
                 ("tether_drag", [("linear_damping", ())], False)]
        for name, fixed, refine in calls[:2]:
            there.request(name, fixed, refine=refine)
        for name, fixed, refine in calls:
            a, b = here.best_shape(name, fixed, refine=refine), there.best_shape(name, fixed, refine=refine)
            assert a.shapes == b.shapes and a.names == b.names
            np.testing.assert_allclose(b.loglik_n, a.loglik_n, rtol=1e-12)
            np.testing.assert_allclose(b.a, a.a, rtol=1e-9, atol=1e-12 * np.abs(a.a).max())
    finally:
        there.delegate(())
    assert workers() == 2 or not can_fork()  # the helper's core is back


def test_an_amplitude_held_at_nominal_is_fitted_at_zero_and_the_others_as_alone(attributor):
    """A per-DOF amplitude held at nominal (report.hold_at_nominal, report.confirm_components: frozen by
    ``Restricted.freezing``) is inactive in the fit, exactly 0, one parameter fewer; each DOF's amplitude reads its
    own regressor, so holding one leaves the others' estimates where a fit without it puts them; holding more
    keeps the earlier ones held."""
    cat = fx.catalogue()
    quad = cat["quadratic_damping_error"]
    assert quad.per_dof and cat["linear_damping"].per_dof and not cat["cg_cb_offset"].per_dof
    free = attributor.fit([("quadratic_damping_error", (0.0,))])
    active = [n for n, v in free.params["quadratic_damping_error"].items() if n.startswith("scale_") and v != 0.0]
    assert len(active) >= 2, free.params
    one = Restricted(quad, (active[0],))
    held = attributor.with_effect("quadratic_damping_error", one).fit([("quadratic_damping_error", (0.0,))])
    assert held.params["quadratic_damping_error"][active[0]] == 0.0 and held.k == free.k - 1
    for n in active[1:]:  # the per-DOF regressors are orthogonal across DOFs: the others' values are unchanged
        assert held.params["quadratic_damping_error"][n] == pytest.approx(free.params["quadratic_damping_error"][n],
                                                                          rel=1e-6, abs=1e-9)
    both = one.freezing(active[:2])
    assert both.frozen == tuple(active[:2]) and both.per_dof and both.inner is quad
    d = attributor.with_effect("quadratic_damping_error", both).design("quadratic_damping_error", (0.0,))
    assert not np.any(d.A[..., [d.names.index(n) for n in active[:2]]])
    assert all(np.any(d.A[..., d.names.index(n)]) for n in active[2:])
