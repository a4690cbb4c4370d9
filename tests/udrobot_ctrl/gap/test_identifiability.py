"""Per-effect identifiability from the observed channels (one mechanism over every effect's regressors)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import Attributor, build_stack
from udrobot_ctrl.gap.data import prepare
from udrobot_ctrl.gap.identifiability import (
    SHARE_MIN,
    ActuatorCheck,
    EffectCheck,
    FormCheck,
    Hinged,
    Identifiability,
    ParameterCheck,
    Restricted,
    StandIn,
    _checks,
    _energies,
    _groups,
    assess,
    noise_scale,
    sensors,
)
from udrobot_ctrl.vehicle import load_model

from . import stock_sim
from .stock_sim import STATE, STOCK, simulate

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


def test_the_probed_designs_are_the_effects_own_and_spare_the_attributor_computing_them(stock):
    _, preps = stock
    st, r, dofs = build_stack(preps, P, P.M_A)
    cat, probed = fx.catalogue(), {}
    assess(st, r, dofs, preps, cat, designs=probed)
    assert {name for name, _ in probed} == set(cat)
    for (name, shape), d in probed.items():
        again = cat[name].design(st, shape)
        for got, want in zip(d[:2], again[:2]):
            np.testing.assert_array_equal(got, want)
    seeded, fresh = Attributor(st, r, dofs, cat), Attributor(st, r, dofs, cat)
    seeded.keep_designs(probed)
    for name in ("thruster_deadband", "buoyancy_offset", "wall_effect"):
        a, b = seeded.best_shape(name, refine=False), fresh.best_shape(name, refine=False)
        assert a.shapes == b.shapes and a.params == b.params and np.array_equal(a.rss, b.rss)


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
    # the untested form acts where the speed-norm drag lost its identification: on the heave force (a heave drag
    # that grows with the unmeasured surge speed), so a gap there does not exclude it
    share = quad.forms["norm_weight"].dof_share
    assert len(share) == 6 and share[2] > 0.5, share
    assert "norm_weight form" in quad.acting_in([2]) and "norm_weight form" not in quad.acting_in([3])
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


def test_full_sensors_identify_everything():
    ident, preps = _assess(STATE)
    assert not any(pr.reconstructed.any() for pr in preps)
    assert ident.names == []
    assert not any(e.forms for e in ident.effects.values())  # every form is searched
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


def test_ambiguity_is_symmetric_and_names_what_would_settle_it():
    """A confirmed effect whose fit a look-alike matches as well is listed with it: an unidentifiable look-alike
    keeps its own reason (the measurement that would identify it), an identifiable one is listed too, with the
    manoeuvre that tells the two apart."""
    ok = ParameterCheck("a", 0.9, 0.0, True)
    hidden = ParameterCheck("k", 0.9, 2.0, False, ("horizontal",))
    ident = Identifiability({n: EffectCheck(n, [hidden if n == "tether_drag" else ok])
                             for n in ("added_mass_error", "cg_cb_offset", "tether_drag", "buoyancy_offset")},
                            np.array([0, 0, 1, 1, 1, 1], bool), np.array([1, 1, 0, 0, 0, 0], bool))
    assert ident.names == ["tether_drag"]
    amb = ident.with_ambiguous({"added_mass_error": ["cg_cb_offset", "tether_drag"]})
    assert set(amb.names) == {"added_mass_error", "cg_cb_offset", "tether_drag"}
    why = amb.reason("added_mass_error")
    assert why.startswith("on the observed DOFs (Z, K, M, N) its fit, or alone the holdout replay, is matched as "
                          "well by cg_cb_offset, tether_drag")
    assert "tether_drag: not identifiable" in why and "DVL" in why
    assert "to tell it from cg_cb_offset: forced pitch and roll steps" in why
    assert "matched as well by added_mass_error" in amb.reason("cg_cb_offset")
    assert amb.reason("tether_drag") == ident.reason("tether_drag")
    assert amb.entry("added_mass_error") == {}  # listed, so no partial-identification entry


def test_an_unconfirmed_partial_effect_is_listed_with_its_evidence_and_the_fix():
    """A candidate the replay could not confirm because its parameters in the unmeasured DOFs were frozen is listed
    with the equation-error evidence and the measurement that would let the replay confirm it; an effect identified in
    part only because a regressor vanishes on the runs is not unconfirmable (nothing would be missing from its
    replay)."""
    ok = ParameterCheck("scale_Zdw", 0.9, 0.1, True)
    surge = ParameterCheck("scale_Xdu", 0.1, 0.0, False, ("horizontal",))
    gone = ParameterCheck("suction", 0.0, 0.0, False, ("vanishes",))
    ident = Identifiability({"added_mass_error": EffectCheck("added_mass_error", [ok, surge]),
                             "wall_effect": EffectCheck("wall_effect", [ok, gone]),
                             "cg_cb_offset": EffectCheck("cg_cb_offset", [ok])},
                            np.array([0, 0, 1, 1, 1, 1], bool), np.array([1, 1, 0, 0, 0, 0], bool))
    assert ident.unconfirmable("added_mass_error")
    assert not ident.unconfirmable("wall_effect") and not ident.unconfirmable("cg_cb_offset")
    listed = ident.with_unconfirmed({"added_mass_error": "selection dBIC -131"})
    assert listed.names == ["added_mass_error"] and ident.names == []
    why = listed.reason("added_mass_error")
    assert why.startswith("the equation error on the observed DOFs (Z, K, M, N) selects it (selection dBIC -131)")
    assert "scale_Xdu not identified" in why and "DVL" in why
    assert listed.entry("added_mass_error") == {}  # listed, so no partial-identification entry


def test_frozen_parameters_act_where_their_regressor_energy_lies(stock):
    """Each parameter's DOF shares are its noise-normalised regressor energy per DOF (summing to 1). Without a DVL a
    linear surge damping acts in surge only, never in the observed yaw; the frozen sway added mass acts where its
    Munk moments put it, in the observed roll and yaw, besides sway."""
    ident, _ = stock
    for e in ident.effects.values():
        for c in e.params:
            if c.dof_share:
                assert sum(c.dof_share) == pytest.approx(1.0, abs=1e-9), (e.name, c)
    lin = ident.effects["linear_damping"]
    assert lin.acting_in([0]) == ["d_Xu"] and lin.acting_in([5]) == []
    am = ident.effects["added_mass_error"]
    assert "scale_Ydv" in am.acting_in([3, 5]), [(c.name, np.round(c.dof_share, 2)) for c in am.params]


def test_a_not_excluded_partial_effect_is_listed_with_the_gap_it_could_explain():
    """An effect not selected whose frozen parameters act where an unexplained gap lies is listed with that gap, the
    parameters and the measurement that would test them; it carries no partial-identification entry then."""
    ok = ParameterCheck("scale_Ndr", 0.9, 0.1, True, (), (0, 0, 0, 0, 0, 1.0))
    heave = ParameterCheck("scale_Zdw", 0.9, 2.0, False, ("horizontal",), (0, 0, 0.03, 0.34, 0.63, 0))
    surge = ParameterCheck("scale_Xdu", 0.1, 0.0, False, ("horizontal",), (0.9, 0, 0, 0, 0.1, 0))
    am = EffectCheck("added_mass_error", [ok, heave, surge])
    assert am.acting_in([2]) == ["scale_Zdw"] and am.acting_in([5]) == []
    assert am.acting_in([4]) == ["scale_Zdw", "scale_Xdu"] and am.acting_in([2], min_share=0.05) == []
    ident = Identifiability({"added_mass_error": am}, np.array([0, 0, 1, 1, 1, 1], bool),
                            np.array([1, 1, 0, 0, 0, 0], bool))
    listed = ident.with_not_excluded({"added_mass_error": "54% of the gap unexplained, 76% of it in Z, where its "
                                                          "scale_Zdw act"})
    assert ident.names == [] and listed.names == ["added_mass_error"]
    why = listed.reason("added_mass_error")
    assert why.startswith("not excluded: 54% of the gap unexplained, 76% of it in Z, where its scale_Zdw act")
    assert "cannot be tested" in why and "DVL" in why
    assert listed.entry("added_mass_error") == {} and ident.entry("added_mass_error") != {}


def _partial_added_mass():
    ok = ParameterCheck("scale_Ndr", 0.9, 0.1, True, (), (0, 0, 0, 0, 0, 1.0))
    heave = ParameterCheck("scale_Zdw", 0.9, 2.0, False, ("horizontal",), (0, 0, 0.03, 0.34, 0.63, 0))
    full = [ParameterCheck("d", 1.0, 0.0, True, (), (0, 0, 1.0, 0, 0, 0))]
    checks = {"added_mass_error": EffectCheck("added_mass_error", [ok, heave]),
              "buoyancy_offset": EffectCheck("buoyancy_offset", full),
              "thrust_inflow_loss": EffectCheck("thrust_inflow_loss", full),
              "linear_damping": EffectCheck("linear_damping", full)}
    return Identifiability(checks, np.array([0, 0, 1, 1, 1, 1], bool), np.array([1, 1, 0, 0, 0, 0], bool))


def test_an_effect_whose_support_hinges_on_an_untested_part_is_listed_with_that_part_and_its_measurement():
    """Listed as not excluded: the gap, the partly identified effect beside which it is supported, the evidence, and
    the measurement that would test that part; no partial-identification entry."""
    ident = _partial_added_mass()
    listed = ident.with_hinged({"buoyancy_offset": Hinged("added_mass_error", -205.3, 219.3, "80% of the gap left")})
    assert ident.names == [] and listed.names == ["buoyancy_offset"]
    why = listed.reason("buoyancy_offset")
    assert why.startswith("not excluded: 80% of the gap left; beside added_mass_error with its scale_Zdw fitted")
    assert "by 205" in why and "ratio 219" in why and "log u, v (DVL)" in why
    assert listed.entry("buoyancy_offset") == {}


def test_a_confirmed_stand_in_for_an_untested_part_is_listed_with_its_partner_and_what_tells_them_apart():
    ident = _partial_added_mass()
    partner = Hinged("added_mass_error", -433.0, 275.8, "83% of the gap left")
    stand = StandIn("added_mass_error", "linear_damping", -662.9, 104.7, partner)
    listed = ident.with_stand_in({"thrust_inflow_loss": stand}).with_hinged({"linear_damping": partner})
    assert listed.names == ["thrust_inflow_loss", "linear_damping"]
    why = listed.reason("thrust_inflow_loss")
    assert "replaced by added_mass_error, its scale_Zdw fitted" in why and "-663" in why and "+105" in why
    assert "log u, v (DVL)" in why and "to tell it from linear_damping: coast-downs" in why
    form = replace(stand, partner_form="norm_weight = 1")
    assert "with norm_weight = 1 (a form these channels cannot test)" in ident.with_stand_in(
        {"thrust_inflow_loss": form}).reason("thrust_inflow_loss")


def test_a_stand_in_without_a_partner_is_listed_with_what_would_test_the_part_it_may_stand_in_for():
    """A thruster effect that the added-mass error takes back alone once its untested part is fitted: the reason gives
    both BICs and the measurement, and names no look-alike (there is none to tell it from)."""
    ident = _partial_added_mass()
    stand = StandIn("added_mass_error", "", -203.5, 11.0, None)
    listed = ident.with_stand_in({"thrust_inflow_loss": stand})
    assert listed.names == ["thrust_inflow_loss"]
    why = listed.reason("thrust_inflow_loss")
    assert why.startswith("with it replaced by added_mass_error, its scale_Zdw fitted as well (on the velocities the "
                          "smoother reconstructs), the fit runs' BIC changes by -204"), why
    assert "(dBIC +11)" in why and "log u, v (DVL)" in why and "to tell it from" not in why


def _vertical_scaled(monkeypatch, scale):
    """Stock runs of :mod:`stock_sim` with the vertical thrusters' commands (T3, T4: heave and roll) scaled by
    ``scale``: at 0.25 the surge thrusters' inflow loss in the unobserved surge dominates the effect's energy, at 0
    no thruster acting on heave or roll is commanded."""
    commands = stock_sim.commands

    def scaled(t, f_max):
        f = commands(t, f_max)
        f[:, 2:] *= scale
        return f
    monkeypatch.setattr(stock_sim, "commands", scaled)
    return _assess(STOCK)


def test_thrusters_are_grouped_by_the_observed_dofs_they_act_on():
    observed = np.array([0, 0, 1, 1, 1, 1], bool)
    assert _groups(P.T, observed, [0, 1, 2, 3]) == {(5,): (0, 1), (2, 3): (2, 3)}
    assert _groups(P.T, observed, [0, 1]) == {(5,): (0, 1)}


def test_a_shared_thruster_parameter_is_judged_on_the_thrusters_the_observed_dofs_see(monkeypatch):
    """Without a DVL an inflow loss of the surge thrusters puts most of its energy in the unobserved surge, and its
    yaw moment hinges on the reconstructed surge speed; that of the vertical thrusters acts on the observed heave
    and roll, through the heave speed that depth pins down. Its parameters are shared by every thruster, so the
    observed DOFs identify them: the effect is identified, fitted on T3 and T4 (the surge thrusters' part, which
    stays in DOFs the vertical thrusters' part does not read, left out), and replayed on all four."""
    ident, preps = _vertical_scaled(monkeypatch, 0.25)
    inflow = ident.effects["thrust_inflow_loss"]
    assert inflow.identified and "thrust_inflow_loss" not in ident.names
    assert inflow.not_identified == [] and ident.entry("thrust_inflow_loss") == {}
    assert inflow.actuators == ActuatorCheck((2, 3), (0, 1), ("horizontal",))
    assert all(c.share == pytest.approx(1.0) for c in inflow.params)
    line = inflow.actuators.describe()
    assert "T3, T4 only" in line and "T1, T2" in line and "horizontal velocity is not observed" in line
    cat = ident.restrict(fx.catalogue())
    st, _, _ = build_stack(preps, P, P.M_A)
    _, A, _, _, _ = cat["thrust_inflow_loss"].design(st, ())
    assert not A[:, [0, 5]].any() and A[:, 2].any()  # no surge thruster in the fit: no surge force, no yaw moment
    _, A_all, _, _, _ = fx.catalogue()["thrust_inflow_loss"].design(st, ())
    assert A_all[:, 0].any() and np.allclose(A[:, 2:5], A_all[:, 2:5])
    # judged whole, the surge thrusters' part dominates its energy: less than SHARE_MIN of it in observed DOFs
    whole = _checks(_energies(fx.catalogue()["thrust_inflow_loss"], st, {}, [()], noise_scale(st, preps),
                              ident.observed), 0.0, ident.observed)
    assert any(c.share < SHARE_MIN for c in whole), whole


def test_a_thruster_effect_acting_only_where_nothing_is_measured_stays_unidentifiable(monkeypatch):
    """With the vertical thrusters never commanded, the inflow loss acts through the surge thrusters only: in the
    unobserved surge, and in yaw through the reconstructed surge speed. It is declined with that reason."""
    ident, _ = _vertical_scaled(monkeypatch, 0.0)
    inflow = ident.effects["thrust_inflow_loss"]
    assert not inflow.identified and inflow.actuators is None
    assert "thrust_inflow_loss" in ident.names
    assert "horizontal velocity is not observed" in ident.reason("thrust_inflow_loss")


def test_a_regressor_vanishing_at_one_form_end_does_not_unsettle_the_form_check(stock):
    """A roll the autopilot holds level (p = 0): the own-axis roll drag |p| p vanishes at norm_weight 0 but not at
    1 (there the rotational speed norm holds q and r). Left in the comparison it would make the two ends'
    identified sets incomparable, the form would be searched whole and the heave scale judged on the unmeasured
    surge speed (issue 37's synthetic 2 Hz dive lost its heave drag error that way): the form stays held at 0."""
    _, preps = stock
    level = []
    for pr in preps:
        nu, nu_dot = pr.nu.copy(), pr.nu_dot.copy()
        nu[:, 3] = nu_dot[:, 3] = 0.0
        level.append(replace(pr, nu=nu, nu_dot=nu_dot, meas={**pr.meas, "p": np.zeros(pr.n)}))
    st, r, dofs = build_stack(level, P, P.M_A)
    quad = assess(st, r, dofs, level, fx.catalogue(), ["quadratic_damping_error"]).effects["quadratic_damping_error"]
    assert set(quad.forms) == {"norm_weight"} and quad.forms["norm_weight"].kept == 0.0
    checks = {c.name: c for c in quad.params}
    assert checks["scale_Zw|w|"].identified
    assert checks["scale_Kp|p|"].causes == ("vanishes",)
