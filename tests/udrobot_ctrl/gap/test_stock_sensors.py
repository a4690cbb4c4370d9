"""Diagnosis with the sensors of a stock small ROV: depth, attitude, gyro rates, accelerometer, thrusts (no DVL,
no positioning). Every withheld effect must be named correctly or listed as unidentifiable, never a wrong one.

Lean runs (3 x 60 s at 20 Hz, one seed); bench/blind_score.py --sensors stock runs every catalogue effect (and pairs).
"""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.gap.effects import EFFECT_NAMES
from udrobot_ctrl.gap.report import diagnose

from .truth import generate, random_magnitudes


def _stock(effects, seed=2):
    rng = np.random.default_rng(seed + 100)
    truth = {n: random_magnitudes(n, rng) for n in effects}
    runs = generate(truth, n_runs=3, duration=60.0, rate=20.0, seed=seed, sensors="stock")
    report, _ = diagnose("pendulum:chin", runs)
    return report


def _outcome(report, name):
    """'named' (the truth effect, alone, or a look-alike listing it), 'unidentifiable' (listed, nothing
    significant) or a description of what went wrong."""
    sig = [e for e in report["effects"] if e["significant"]]
    unid = {u["name"] for u in report["unidentifiable"]}
    if len(sig) == 1 and (sig[0]["name"] == name
                          or name in [a["name"] for a in sig[0].get("indistinguishable_from", [])]):
        return "named"
    if not sig and name in unid:
        return "unidentifiable"
    return f"wrong: significant {[e['name'] for e in sig]}, unidentifiable {sorted(unid)}"


@pytest.fixture(scope="module")
def no_effect():
    return _stock([])


@pytest.mark.slow
def test_runs_without_any_velocity_are_diagnosed(no_effect):
    report = no_effect
    assert sorted(e["name"] for e in report["effects"]) == sorted(EFFECT_NAMES)
    assert [e["name"] for e in report["effects"] if e["significant"]] == []
    sensors = report["sensors"]
    assert {"ax", "ay", "az", "z", "p"} <= set(sensors["logged"]) and "u" not in sensors["logged"]
    assert sensors["velocities"]["u"].startswith("reconstructed") and sensors["velocities"]["w"].startswith("observed")
    assert sensors["scored_dofs"] == ["Z", "K", "M", "N"]
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert "water_current" in listed and "DVL" in listed["water_current"]
    # with no gap above the floor, what the equation error selects on reconstructed velocities is not listed
    assert not [n for n, why in listed.items() if "selects it" in why], listed
    for e in report["effects"]:  # unidentifiable effects are still reported, never significant
        if e["name"] in listed:
            assert not e["significant"]
    assert any("reconstructed by the model-based smoother" in n for n in report["notes"])


# heave/roll/pitch/yaw effects stay identifiable from depth + IMU; a tether, whose drag needs the unobserved
# horizontal velocity, is listed as unidentifiable, and the heave-side effects that would mimic its vertical
# footprint (a thrust loss on the vertical thrusters) are set aside as ambiguous instead of named
# (bench/blind_score.py --sensors stock runs every catalogue effect; bench/diagnose_sweep.py --sweep stock runs this
# test's lag and buoyancy cases too: both are named in the suite's stock diagnoses of a pair,
# test_stock_forward_selection_picks_by_a_joint_fit_of_the_shapes, and of a buoyancy offset,
# test_reconstruction_pass.test_stock_corrected_model_replay_reproduces_gap_after)
@pytest.mark.slow
@pytest.mark.parametrize("name,expected", [("tether_drag", "unidentifiable")])
def test_stock_effect_named_or_listed(name, expected):
    report = _stock([name])
    assert _outcome(report, name) == expected, (name, _outcome(report, name))


def _bench_case(names, draw=0):
    """A stock case of bench/blind_score.py: its seed and truth magnitudes, five 60 s runs at 50 Hz (3 fit, 2
    holdout)."""
    seed = 1000 * draw + sum(EFFECT_NAMES.index(n) + 1 for n in names) * 7
    rng = np.random.default_rng(seed)
    truth = {n: random_magnitudes(n, rng) for n in names}
    runs = generate(truth, n_runs=5, duration=60.0, rate=50.0, seed=seed, sensors="stock")
    report, _ = diagnose("pendulum:chin", runs[:3], runs[3:])
    return report


# without a DVL, a quadratic damping error acts on the heave and yaw drag only as far as the channels see, and a
# CG-CB offset in free pitch oscillations is matched by a pitch added-mass error; a cross-coupled damping acts
# mostly through the unmeasured surge speed (its heave force u|u|): the equation error selects it and the replay
# cannot confirm it (since 913af22; before, a deadband's fit took its place and it was listed as the deadband's
# look-alike). Either way every truth effect not named is listed with the measurement or manoeuvre that settles it
@pytest.mark.slow
@pytest.mark.parametrize("names", [("quadratic_damping_error", "cg_cb_offset"),
                                   pytest.param(("cross_coupled_damping",), marks=pytest.mark.extended)])
def test_stock_look_alikes_are_listed_not_guessed(names):
    report = _bench_case(names)
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig <= set(names), (sig, sorted(listed))
    assert all(n in sig or n in listed for n in names), (sig, sorted(listed))
    assert all("to tell it from" in listed[n] or "log " in listed[n] for n in names if n not in sig), listed
    ambiguous = [r for r in listed.values() if "the runs cannot say which acts" in r]
    assert all("to tell it from" in r or "log " in r for r in ambiguous), ambiguous
    ranked = [e["name"] for e in report["effects"]]  # the list opens with what explains most of the holdout gap
    assert list(listed) == sorted(listed, key=ranked.index), (list(listed), ranked)


# a heave/yaw added-mass error whose surge part (and, through the Munk moment, its heave part) needs the surge speed:
# the equation error on Z, K, M, N selects it and the replay without those parameters cannot confirm it, or (since
# 913af22, whose refinement fits a lag's two shape parameters better) a thruster lag matches it on those channels;
# either way the report says so, with what would settle it, instead of dropping it silently or naming the lag
@pytest.mark.slow
def test_stock_effect_the_replay_cannot_confirm_is_listed_with_its_evidence():
    report = _bench_case(("added_mass_error",))
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig <= {"added_mass_error"}, sig
    if "added_mass_error" not in sig:
        why = listed["added_mass_error"]
        unconfirmed = ("the equation error on the observed DOFs (Z, K, M, N) selects it" in why
                       and "scale_Xdu" in why and "log u, v (DVL)" in why)
        look_alike = "is matched as well by" in why and "to tell it from" in why
        assert unconfirmed or look_alike, why


@pytest.mark.extended
# the truth's quadratic drag acts on the speed norm, a form whose heave drag grows with the unmeasured surge speed:
# the search keeps the per-axis form, and an inflow loss on the vertical thrusters took up the rest (+2.5 % of the gap
# when dropped, p 0.002: it passed every holdout test). Swapped for the drag in the untested form, the fit is as good,
# so the inflow loss is listed with that reason instead of named
@pytest.mark.slow
def test_stock_look_alike_of_a_form_the_channels_cannot_test_is_listed_not_named():
    report = _bench_case(("quadratic_damping_error",), draw=2)
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig <= {"quadratic_damping_error"} and ("quadratic_damping_error" in sig
                                                   or "quadratic_damping_error" in listed), (sig, sorted(listed))
    form_alikes = [why for why in listed.values()
                   if "its fit is matched as well by quadratic_damping_error with norm_weight = 1" in why]
    assert form_alikes, f"no effect set aside for the untested speed-norm form: {sorted(listed)}"
    assert all("log u, v (DVL)" in why for why in form_alikes), form_alikes


@pytest.mark.extended
# a lag explains 62 % of the holdout gap, and what it leaves is still ~36 x the noise floor: the added-mass error,
# whose heave part needs the heave acceleration the depth channel gives only through a reconstruction, may explain
# it and cannot be tested; it is listed, not dropped silently because most of the gap was explained
@pytest.mark.slow
def test_stock_effect_beside_a_confirmed_one_is_listed_when_a_gap_above_the_floor_is_left():
    report = _bench_case(("thruster_lag", "added_mass_error"))
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig <= {"thruster_lag", "added_mass_error"}, sig
    assert "thruster_lag" in sig, (sig, sorted(listed))
    assert "added_mass_error" in sig or "added_mass_error" in listed, (sig, sorted(listed))
    if "added_mass_error" in listed:  # not excluded (the gap left, against the floor) or not confirmable (evidence)
        why = listed["added_mass_error"]
        assert "x the noise floor" in why or "the equation error on the observed DOFs" in why, why


# the truth's inflow loss (K_T falling with the advance ratio, a J^2 term included: a drag on the thruster axis) with
# a rotor-speed lag: forward selection fitted the lag alone first, and with its time constant held (0.59 s) a heave
# quadratic-damping error complemented it better than the inflow loss and was named. Each step now picks among its
# best candidates by a joint fit of every shape (lag 0.47 s beside the inflow loss, against 0.51 s beside the
# damping) and, the velocities being reconstructed, adds the pick with the lag's time constant fitted again: both
# effects are named, and the damping never is
@pytest.mark.slow
def test_stock_forward_selection_picks_by_a_joint_fit_of_the_shapes():
    report = _bench_case(("thrust_inflow_loss", "thruster_lag"))
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig == {"thrust_inflow_loss", "thruster_lag"}, (sig, sorted(listed))
    steps = [s["effect"] for s in report["selection_steps"] if s["accepted"]]
    assert steps[:2] == ["thruster_lag", "thrust_inflow_loss"], steps
    lag = next(e for e in report["effects"] if e["name"] == "thruster_lag")
    assert 0.3 < lag["params"]["T_lag_s"] < 0.7, lag["params"]  # the truth's rotor time constant: 0.47 s


# a dead band (truth 0.27 of the reference thrust, a command-domain form) and a linear damping: the first pass smooths
# the velocities with the nominal plant, and the dead band, fitted first, takes width 0.35 and exponent 1.59; held
# there, the second step's pick (an inflow loss) raised the fit-run BIC by 9.7, selection stopped and the damping was
# missed. Added with the shapes refitted (0.30, 2.0: BIC -83), the next step selects the damping (BIC -41); the holdout
# confirms it and drops the inflow loss; the damping is then set aside with its tether look-alike, which these channels
# cannot test
@pytest.mark.slow
def test_stock_second_effect_is_added_with_the_first_ones_shape_fitted_again():
    report = _bench_case(("thruster_deadband", "linear_damping"))
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    dead = next(e for e in report["effects"] if e["name"] == "thruster_deadband")
    assert sig <= {"thruster_deadband", "linear_damping"}, (sig, sorted(listed))
    # the dead band is confirmed on the holdout; its width ends at the 0.35 top of its range (exponent 1.59 where the
    # truth's is 2), and a parameter at its bound is evidence of a missing term, not a finding: it is named only when
    # its fit ends inside the range, else listed with that reason (issue 37)
    assert "thruster_deadband" in sig or dead.get("at_bound_reason"), (sig, dead)
    if dead.get("at_bound_reason"):
        assert dead["at_bound"]["width_fraction"]["bound"] == pytest.approx(0.35)
    assert "linear_damping" in sig or "linear_damping" in listed, (sig, sorted(listed))
    # selected and confirmed on the holdout in the first pass, then set aside with its look-alike: listed with the
    # reason that names it (the second pass's selection_steps, reported, start from the dead band's force alone)
    if "linear_damping" in listed:
        assert "matched as well by" in listed["linear_damping"], listed["linear_damping"]


# a cross-coupled heave drag c u|u| of the unmeasured surge speed whose mean (+1.7 N) cancels a buoyancy offset of
# -1.8 N: alone the offset does not lower the BIC, beside the drag fitted on the reconstructed surge speed it does
# (by ~200); neither can be named, and the offset is listed with that reason instead of missed
@pytest.mark.slow
def test_stock_effect_hinging_on_an_untested_part_is_listed_not_missed():
    report = _bench_case(("cross_coupled_damping", "buoyancy_offset"))
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig <= {"cross_coupled_damping", "buoyancy_offset"}, (sig, sorted(listed))
    assert "cross_coupled_damping" in listed, sorted(listed)
    if "buoyancy_offset" not in sig:
        why = listed.get("buoyancy_offset", "")
        assert "beside cross_coupled_damping" in why and "log u, v (DVL)" in why, (why, sorted(listed))


@pytest.mark.extended
# a quadratic drag on the speed norm and a heave/yaw added-mass error: neither can be fitted whole without a DVL, and
# an inflow loss on the hover thrust took up what they leave (confirmed on the holdout, 58 % of the gap left). With
# the added mass's untested part fitted and the drag in its untested form, the inflow loss adds nothing: it is
# listed as their possible stand-in, not named
@pytest.mark.slow
def test_stock_stand_in_for_untested_parts_is_listed_not_named():
    report = _bench_case(("quadratic_damping_error", "added_mass_error"))
    sig = {e["name"] for e in report["effects"] if e["significant"]}
    listed = {u["name"]: u["reason"] for u in report["unidentifiable"]}
    assert sig <= {"quadratic_damping_error", "added_mass_error"}, (sig, sorted(listed))
    assert all(n in sig or n in listed for n in ("quadratic_damping_error", "added_mass_error")), sorted(listed)
    assert "may stand in for what these channels cannot test" in listed.get("thrust_inflow_loss", ""), sorted(listed)
