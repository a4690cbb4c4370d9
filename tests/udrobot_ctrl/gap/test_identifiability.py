"""Per-effect identifiability from the observed channels (one mechanism over every effect's regressors)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import build_stack
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.identifiability import (
    EffectCheck,
    FormCheck,
    ParameterCheck,
    Restricted,
    assess,
    sensors,
)
from udrobot_ctrl.gap.report import build_stacks, prepare_inputs
from udrobot_ctrl.vehicle import load_model

from .stock_sim import STATE, STOCK, simulate
from .truth import generate

P = plant_parameters(load_model("pendulum:chin"))


def _assess(channels, drop_surfaces=False, preps=None):
    if preps is None:
        preps = [prepare(simulate(duration=30.0, seed=seed, sensors=channels)[0], P) for seed in (11, 12)]
    if drop_surfaces:  # as if the sidecar gave no seabed depth
        preps = [replace(pr, surfaces=[]) for pr in preps]
    st, r, dofs = build_stack(preps, P, P.M_A)
    return assess(st, r, dofs, preps, fx.catalogue()), preps


@pytest.fixture(scope="module")
def stock():
    return _assess(STOCK)


def test_stock_sensors_keep_heave_roll_pitch_yaw_effects(stock):
    ident, _ = stock
    for name in ("buoyancy_offset", "cg_cb_offset", "thruster_deadband", "thruster_lag", "wall_effect"):
        assert ident.effects[name].identified, (name, ident.effects[name])
    # the seabed's added mass acts on the (observed) heave acceleration; its suction on the horizontal speed
    wall = ident.effects["wall_effect"]
    assert wall.not_identified == ["suction_N_s2_per_m2"]


def test_stock_sensors_list_horizontal_velocity_effects_with_the_fix(stock):
    ident, _ = stock
    listed = {u["name"]: u["reason"] for u in ident.report()}
    for name in ("water_current", "tether_drag"):
        assert name in listed
        assert "horizontal velocity is not observed" in listed[name] and "DVL" in listed[name]
    assert set(listed) == set(ident.names)
    # per-DOF effects stay testable, with the surge/sway parameters named as not identified
    lin = ident.entry("linear_damping")["not_identified"]
    assert {"d_Xu", "d_Yv"} <= set(lin["params"]) and "d_Zw" not in lin["params"] and "d_Nr" not in lin["params"]


def test_restricted_catalogue_freezes_only_unidentified_columns(stock):
    ident, preps = stock
    cat = ident.restrict(fx.catalogue())
    assert isinstance(cat["linear_damping"], Restricted) and not isinstance(cat["buoyancy_offset"], Restricted)
    st, _, _ = build_stack(preps, P, P.M_A)
    _, A, names, _, _ = cat["linear_damping"].design(st, ())
    col = dict(zip(names, np.moveaxis(A, -1, 0)))
    assert not col["d_Xu"].any() and not col["d_Yv"].any() and col["d_Zw"].any()


def test_stock_sensors_keep_the_quadratic_damping_error_on_each_axis_speed(stock):
    """The speed-norm form puts the unmeasured surge speed into the heave drag: without a DVL the search keeps the
    per-axis form (norm_weight 0), and the report says why."""
    ident, preps = stock
    quad = ident.effects["quadratic_damping_error"]
    assert quad.identified and set(quad.forms) == {"norm_weight"} and quad.forms["norm_weight"].kept == 0.0
    # a thruster map's exponent does not hinge on any reconstructed state: both of its forms stay searched
    assert not ident.effects["thruster_deadband"].forms and not ident.effects["thruster_lag"].forms
    entry = ident.entry("quadratic_damping_error")["not_identified"]
    assert "norm_weight" in entry["params"] and "norm_weight kept at 0" in entry["reason"]
    assert "horizontal velocity is not observed" in entry["reason"]
    st, _, _ = build_stack(preps, P, P.M_A)
    grid, bounds = ident.restrict(fx.catalogue())["quadratic_damping_error"].search_space(st)
    assert grid == ((0.0,),) and bounds == ((0.0, 0.0),)
    # in the kept form the heave, roll, pitch and yaw scales are identified; surge and sway are not
    assert {c.name for c in quad.params if c.identified} == {"scale_Zw|w|", "scale_Kp|p|", "scale_Mq|q|",
                                                               "scale_Nr|r|"}


def test_a_parameter_hinging_on_a_reconstruction_in_some_equations_is_fitted_on_the_others(stock):
    """A heave added-mass scale acts through the heave inertia (pinned by depth and the accelerometer) and through
    the Munk moment in pitch and the roll coupling (which need the surge and sway speeds): without a DVL it is fitted
    on the heave equation alone; the surge and sway scales, which act nowhere robust, stay frozen."""
    ident, preps = stock
    am = ident.effects["added_mass_error"]
    assert am.identified and "scale_Zdw" not in am.not_identified
    assert {"scale_Xdu", "scale_Ydv"} <= set(am.not_identified)
    part = ident.entry("added_mass_error")["fitted_on"]["scale_Zdw"]
    assert part["dofs"] == ["Z"] and "horizontal velocity is not observed" in part["reason"]
    st, _, _ = build_stack(preps, P, P.M_A)
    _, A0, names, _, _ = fx.catalogue()["added_mass_error"].design(st, ())
    _, A, _, _, _ = ident.restrict(fx.catalogue())["added_mass_error"].design(st, ())
    j = names.index("scale_Zdw")
    assert np.any(A0[:, 4, j])  # the Munk moment the fit leaves out
    assert np.array_equal(A[:, 2, j], A0[:, 2, j]) and not np.any(A[:, [0, 1, 3, 4, 5], j])
    # the other columns are untouched
    k = names.index("scale_Ndr")
    assert np.array_equal(A[:, :, k], A0[:, :, k])


@pytest.mark.slow
def test_a_withheld_heave_added_mass_error_is_recovered_from_the_heave_equation_alone():
    """Stock runs (no DVL) of the independent truth plant with 80 % more heave added mass: fitted on the heave
    equation only, the scale comes back within 0.15 (measured 0.78; its Munk moment, left out of the fit, stays in
    the pitch residual, where the other scales take it up)."""
    runs = generate({"added_mass_error": {"sX": 0.0, "sZ": 0.8, "sN": 0.0}}, n_runs=3, duration=60.0, rate=50.0,
                    seed=5, sensors="stock")
    stacks = build_stacks(prepare_inputs("pendulum:chin", runs[:2], runs[2:], None, 8.0))
    fit = stacks.fit.best_shape("added_mass_error").params["added_mass_error"]
    assert fit["scale_Zdw"] == pytest.approx(0.8, abs=0.15)
    assert fit["scale_Xdu"] == 0.0 and fit["scale_Ydv"] == 0.0


def test_full_sensors_identify_everything():
    ident, preps = _assess(STATE)
    assert not any(pr.reconstructed.any() for pr in preps)
    assert ident.names == []
    assert not any(e.forms for e in ident.effects.values())  # every form is searched
    assert not any(e.masks for e in ident.effects.values())  # and every equation used
    rep = sensors(preps)
    assert rep["velocities"]["u"] == "observed" and rep["scored_dofs"] == list(fx.DOF)


def test_vanishing_regressor_is_unidentifiable_with_its_reason(stock):
    ident, preps = _assess(STOCK, drop_surfaces=True, preps=stock[1])
    assert "wall_effect" in ident.names
    reason = {u["name"]: u["reason"] for u in ident.report()}["wall_effect"]
    assert "zero on these runs" in reason and "altitude" in reason
    rep = sensors(preps)
    assert rep["velocities"]["u"].startswith("reconstructed") and rep["velocities"]["w"].startswith("observed")
    assert rep["scored_dofs"] == ["Z", "K", "M", "N"]


def test_a_partly_identified_effect_names_why_its_other_parameters_are_not():
    """Every non-identified parameter comes with its reason, whether it vanishes on the runs or hinges on a
    reconstructed state, with or without a form kept at one end."""
    ok = ParameterCheck("a", 0.9, 0.0, True)
    zero = ParameterCheck("b", float("nan"), float("nan"), False, ("vanishes",))
    hidden = ParameterCheck("c", 0.1, 0.0, False, ("horizontal",))
    assert "regressors are zero" in EffectCheck("e", [ok, zero], "commands of both signs").reason()
    assert "commands of both signs" in EffectCheck("e", [ok, zero], "commands of both signs").reason()
    assert "horizontal velocity is not observed" in EffectCheck("e", [ok, hidden]).reason()
    kept = EffectCheck("e", [ok], forms={"norm_weight": FormCheck(0.0, 1.0, ("horizontal",))})
    assert kept.reason().startswith("norm_weight kept at 0 (the form at 1 is not identified)")
    assert kept.not_identified == ["norm_weight"]
