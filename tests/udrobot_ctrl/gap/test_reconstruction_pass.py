"""The second reconstruction pass: stock runs re-smoothed with the effects a diagnosis attributed.

The smoother's process model is the nominal plant; an unmodelled force is carried by its unmodelled acceleration
``d`` instead. Given that force (:func:`udrobot_ctrl.gap.shrink.effect_wrench` of the effect's replay hooks), the
reconstruction no longer needs ``d`` for it.
"""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from udrobot_ctrl.cli.main import main
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap.confirm import MemberTest
from udrobot_ctrl.gap.data import prepare, restoring_gradient
from udrobot_ctrl.gap.effects import Actuation, plant_hooks
from udrobot_ctrl.gap.identifiability import Identifiability
from udrobot_ctrl.gap.report import _lookalike_groups, pass_disagreements, replay_rivals
from udrobot_ctrl.gap.shrink import effect_wrench, prepare_with_effects
from udrobot_ctrl.io.runlog import write_run
from udrobot_ctrl.vehicle import load_model

from .stock_sim import simulate
from .test_corrected_model import REPLAY_TOL
from .truth import generate

P = plant_parameters(load_model("pendulum:chin"))
DB = 2.0  # N, net buoyancy the truth adds (no compressibility: beta = 0, so the plant's dB_N is its exact form)


def _hooks(prep, *effects):
    act = Actuation(prep.B, prep.inflow, prep.f_ref, P.M_A)
    return [plant_hooks(e, P, act) for e in effects]


def test_effect_wrench_is_the_plant_force_along_the_run():
    run, _ = simulate(duration=20.0, rate=20.0, seed=3)
    prep = prepare(run, P, "r")
    assert np.all(effect_wrench(prep, []) == 0.0)
    w = effect_wrench(prep, _hooks(prep, PlantEffect("buoyancy_offset", {"dB_N": DB})))
    # more buoyancy: the restoring force g(eta) falls by dB times its gradient in B
    np.testing.assert_allclose(w, -DB * restoring_gradient(np.nan_to_num(prep.eta), P, "B"), atol=1e-9)
    scale = {f"scale_{d}d{v}": 0.0 for d, v in zip("XYZKMN", "uvwpqr")} | {"scale_Zdw": 0.5}
    w = effect_wrench(prep, _hooks(prep, PlantEffect("added_mass_error", scale)))
    np.testing.assert_allclose(w[:, 2], -0.5 * P.M_A[2, 2] * np.nan_to_num(prep.nu_dot[:, 2]), atol=1e-6)
    # a dead band takes thrust away from small commands only: the wrench is B (f_delivered - f)
    band = _hooks(prep, PlantEffect("thruster_deadband", {"width_fraction": 0.2, "shift": 1.0}))
    w = effect_wrench(prep, band)
    small = np.all(np.abs(prep.f) < 0.2 * prep.f_ref, axis=1)
    np.testing.assert_allclose(w[small], -(prep.f[small] @ prep.B.T), atol=1e-9)


def test_runs_with_logged_velocities_are_not_prepared_again():
    run, _ = simulate(duration=20.0, rate=20.0, seed=3, sensors=("z", "phi", "theta", "psi", "u", "v", "w", "p",
                                                                  "q", "r"))
    prep = prepare(run, P, "r")
    assert prep.smoothed is None
    assert prepare_with_effects(run, P, prep, _hooks(prep, PlantEffect("buoyancy_offset", {"dB_N": DB})), "b") is prep


@pytest.mark.slow
def test_known_force_leaves_the_unmodelled_acceleration_free_of_it():
    """Stock runs of a vehicle 2 N more buoyant than its model, depth held by the controller: reconstructed with the
    nominal plant, the smoother's heave disturbance d_Z carries that force (dB / M_33 on average); with the buoyancy
    offset given, it no longer does, and the reconstructed heave velocity is no worse."""
    runs = generate({"buoyancy_offset": {"dB0": DB, "beta": 0.0}}, n_runs=1, duration=60.0, rate=20.0, seed=8,
                    sensors="stock")
    run = runs[0]
    nominal = prepare(run, P, "r")
    again = prepare_with_effects(run, P, nominal, _hooks(nominal, PlantEffect("buoyancy_offset", {"dB_N": DB})),
                                 "buoyancy_offset")
    assert any("plus the force of buoyancy_offset" in n for n in again.notes)
    expected = -DB / P.M[2, 2]  # NED: more buoyancy pulls up (negative z)
    d0, d1 = np.mean(nominal.smoothed.d[:, 2]), np.mean(again.smoothed.d[:, 2])
    sd = np.median(nominal.smoothed.sigma_d[:, 2])  # posterior std of d_Z: the scale of what the data pin
    assert abs(d0 - expected) < 0.3 * abs(expected), (d0, expected)
    assert abs(d1) < 0.2 * abs(expected) + sd / 10, (d1, expected, sd)
    true_w = run.extra["true_w"]
    err0 = np.sqrt(np.mean((nominal.nu[:, 2] - true_w) ** 2))
    err1 = np.sqrt(np.mean((again.nu[:, 2] - true_w) ** 2))
    assert err1 <= 1.05 * err0, (err0, err1)


@pytest.mark.slow
def test_stock_corrected_model_replay_reproduces_gap_after(tmp_path, capsys):
    """Stock runs (no DVL) with a withheld buoyancy offset: the diagnosis names it in two reconstruction passes, and
    ``simulate --windows`` with the corrected model -- which reconstructs the holdout run with that model -- gives
    the report's gap_after."""
    runs = generate({"buoyancy_offset": {"dB0": DB, "beta": 0.1}}, n_runs=3, duration=60.0, rate=20.0, seed=9,
                    sensors="stock")
    files = [write_run(tmp_path / r.path, r.t, r.channels, r.input_kind, r.inputs,
                       metadata={k: v for k, v in r.metadata.items() if k != "format"}) for r in runs]
    report_path, model_path = tmp_path / "report.json", tmp_path / "corrected.json"
    assert main(["diagnose", "--model", "pendulum:chin", "--json", str(report_path), "--out-model", str(model_path),
                 "--quiet", *map(str, files)]) == 0
    report = json.loads(report_path.read_text())
    assert [e["name"] for e in report["effects"] if e["significant"]] == ["buoyancy_offset"]
    assert any(n.startswith("reconstruction: the unlogged velocities were smoothed twice") for n in report["notes"])
    out = tmp_path / "gap.json"
    assert main(["simulate", "--model", str(model_path), "--input", str(files[-1]), "--windows", "8",
                 "--json", str(out)]) == 0
    g = json.loads(out.read_text())
    # the smoother sees the 6-decimal parameters of the file: its reconstruction moves by as little as the replay's
    assert g["value"] == pytest.approx(report["gap_after"]["value"], abs=10 * REPLAY_TOL)
    assert g["scored"] == report["gap_after"]["scored"]
    assert report["gap_after"]["value"] < 0.8 * report["gap_before"]["value"]


def test_a_first_pass_lookalike_group_stays_set_aside_whichever_member_the_second_pass_confirms():
    """The first pass set aside a linear damping matched as well by an inflow loss and a quadratic-damping error;
    the second pass, smoothing with the linear damping's force, may confirm the quadratic one instead: every member of
    the group maps to the others (a stock case of the blind score: inflow loss + linear damping, draw 1)."""
    groups = _lookalike_groups({"linear_damping": ("thrust_inflow_loss", "quadratic_damping_error"),
                                "cg_cb_offset": ("added_mass_error", "quadratic_damping_error")})
    assert groups["quadratic_damping_error"] == ("linear_damping", "thrust_inflow_loss", "cg_cb_offset",
                                                 "added_mass_error")
    assert groups["thrust_inflow_loss"] == ("linear_damping", "quadratic_damping_error")
    assert groups["linear_damping"] == ("thrust_inflow_loss", "quadratic_damping_error")
    assert "buoyancy_offset" not in groups and _lookalike_groups({}) == {}


def test_an_effect_that_alone_explains_more_of_the_holdout_than_the_confirmed_set_is_its_rival():
    """Stock blind-bench cases: a linear damping confirmed for a quadratic-damping error on the speed norm explained
    14 % of the holdout gap, an inflow loss alone (unidentifiable there: its fit hinges on the reconstructed surge
    speed) 70 %; a confirmed buoyancy offset with 35 % against a tether's 40 % rivals too. Within 2 % of the set,
    below no shrink, or with nothing confirmed, nothing does."""
    def elim(kept, unexplained):
        return SimpleNamespace(kept=kept, after=SimpleNamespace(gap=SimpleNamespace(value=unexplained)))
    before = SimpleNamespace(value=1.0)
    shrink = {"linear_damping": 0.14, "thrust_inflow_loss": 0.70, "tether_drag": 0.15, "wall_effect": 0.0}
    assert replay_rivals(elim(("linear_damping",), 0.86), before, shrink) == ["thrust_inflow_loss"]
    assert replay_rivals(elim(("buoyancy_offset",), 0.65), before, {"tether_drag": 0.40, "cg_cb": 0.36}) == [
        "tether_drag"]
    # a set that makes the replay worse is measured from no shrink: a small gain alone is no rival
    assert replay_rivals(elim(("cross_coupled_damping",), 2.3), before, {"water_current": -0.08,
                                                                         "tether_drag": 0.01}) == []
    assert replay_rivals(elim((), 1.0), before, shrink) == []


def _member(name, rise, p):
    return MemberTest(name=name, holdout_lr=40.0, gap_contribution=rise, replay_w=0.0, replay_p=p,
                      windows_worse=0.7, fit_delta_bic=-20.0)


def _second_pass(dropped, kept=(), listed=()):
    """A second pass (only what :func:`pass_disagreements` reads): ``dropped`` name -> its last MemberTest."""
    elim = SimpleNamespace(kept=tuple(kept), dropped=dropped)
    return SimpleNamespace(elim=elim, at_bound={}, stacks=SimpleNamespace(
        identifiability=SimpleNamespace(names=list(listed))))


def test_an_effect_the_second_reconstruction_still_prefers_but_cannot_confirm_is_listed_not_dropped():
    """Pass 1 (velocities smoothed with the nominal plant) confirms a dead band and an asymmetry; pass 2 (smoothed
    with their force) keeps the dead band and still replays better with the asymmetry (+3.4 % when dropped) but not
    consistently (p 0.18): the passes disagree, so the asymmetry is listed, with both passes' evidence, instead of
    silently dropped. An effect pass 2 contradicts (its replay is as good without it) is not listed."""
    first = SimpleNamespace(kept=("thruster_deadband", "thruster_asymmetry", "buoyancy_offset"),
                            last_test=lambda n: _member(n, 0.058, 0.009))
    second = _second_pass({"thruster_asymmetry": _member("thruster_asymmetry", 0.034, 0.18),
                           "buoyancy_offset": _member("buoyancy_offset", -0.004, 1.0)}, kept=("thruster_deadband",))
    out = pass_disagreements(first, second)
    assert set(out) == {"thruster_asymmetry"}
    ident = Identifiability(effects={"thruster_asymmetry": SimpleNamespace(identified=True)},
                            observed=np.array([0, 0, 1, 1, 1, 1], bool),
                            reconstructed=np.array([1, 1, 1, 0, 0, 0], bool))
    ident = ident.with_pass_disagreement(out)
    assert ident.names == ["thruster_asymmetry"]
    why = ident.reason("thruster_asymmetry")
    assert "by 5.8%" in why and "+3.4%" in why and "p 0.18" in why and "log u, v, w" in why
    # already listed by the second pass, or set aside at a bound by the first: not listed again
    assert pass_disagreements(first, _second_pass(second.elim.dropped, listed=("thruster_asymmetry",))) == {}
    assert pass_disagreements(first, second, skip=("thruster_asymmetry",)) == {}
