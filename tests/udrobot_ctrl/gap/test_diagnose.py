"""The diagnoser against the truth generator (effects withheld, written in other forms than the templates)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.gap.confirm import CONSISTENT_WINDOWS, REPLAY_MATERIAL
from udrobot_ctrl.gap.effects import EFFECT_NAMES
from udrobot_ctrl.gap.locate import Located
from udrobot_ctrl.gap.report import REPLAY_ABOVE_FLOOR, OnDemand, Where, diagnose, remaining_to_floor
from udrobot_ctrl.gap.shrink import GapScore
from udrobot_ctrl.io.runlog import write

from .truth import generate, random_magnitudes

REPO = Path(__file__).resolve().parents[3]


def _run(effects, seed=2, **kw):
    rng = np.random.default_rng(seed + 100)
    truth = {n: random_magnitudes(n, rng) for n in effects}
    runs = generate(truth, n_runs=3, duration=90.0, rate=20.0, seed=seed, **kw)
    report, _ = diagnose("pendulum:chin", runs)
    return report, truth


def case(*effects, seed=2):
    """The xdist group of the tests that read case ``(effects, seed)`` through :func:`diagnosed`: they run on one
    worker, which diagnoses the case once (tests/conftest.py; the cases are independent, so each has its own group
    rather than the module's)."""
    return pytest.mark.xdist_group(f"test_diagnose:{'+'.join(effects) or 'no_effect'}:{seed}")


@pytest.fixture(scope="module")
def diagnosed():
    """(effects, seed) -> (report, truth), each case diagnosed once per module (several tests read one case: mark
    them with its :func:`case` group)."""
    cache = {}

    def get(effects, seed=2):
        key = (tuple(effects), seed)
        if key not in cache:
            cache[key] = _run(list(effects), seed=seed)
        return cache[key]
    return get


def _by_name(report):
    return {e["name"]: e for e in report["effects"]}


def _verdict_ok(report, name):
    eff = _by_name(report)
    if eff[name]["significant"]:
        return True
    top = [e for e in report["effects"] if e["significant"]]
    return any(name in [a["name"] for a in e.get("indistinguishable_from", [])] for e in top)


@pytest.mark.slow
@case()
def test_no_effect_no_false_alarm(diagnosed):
    report, _ = diagnosed([])
    assert report["format"] == "udrobot-diagnosis/1"
    assert [e["name"] for e in report["effects"] if e["significant"]] == []
    assert sorted(e["name"] for e in report["effects"]) == sorted(EFFECT_NAMES)
    assert report["unexplained"] == pytest.approx(1.0)


#: every catalogue effect alone, at this module's settings (3 x 90 s at 20 Hz, seed 2): the sweep is
#: bench/diagnose_sweep.py's (it prints each case's verdict and shrink); the suite keeps one case per mechanism
SINGLE = ["thrust_inflow_loss", "thruster_deadband", "thruster_asymmetry", "thruster_lag", "tether_drag",
          "water_current", "quadratic_damping_error", "linear_damping", "added_mass_error", "cross_coupled_damping",
          "buoyancy_offset", "cg_cb_offset"]
#: the suite's cases of the sweep: a thruster's dynamics (lag), its command-domain map (dead band; asymmetry, whose
#: only diagnosis in the suite this is) and a static force (buoyancy); lag, dead band and buoyancy are read by other
#: tests below as well (each case diagnosed once). The
#: others are diagnosed elsewhere in the suite in a pair or another draw: inflow loss (test_two_effects_together,
#: test_cli_end_to_end), the dampings (test_quadratic_damping_on_the_speed_..., test_linear_and_quadratic_...), added
#: mass and CG-CB offset (test_an_interacting_pair_...), current (test_a_current_added_after_...), tether
#: (test_anchored_tether.py, test_tether_attachment.py), cross-coupled damping (test_stock_sensors.py)
SUITE_SINGLE = ["thruster_deadband", "thruster_asymmetry", "thruster_lag", "buoyancy_offset"]


@pytest.mark.slow
@pytest.mark.parametrize("name", [pytest.param(n, marks=case(n)) for n in SUITE_SINGLE])
def test_single_effect_named_and_shrinks(name, diagnosed):
    report, truth = diagnosed([name])
    assert _verdict_ok(report, name), (name, truth, [(e["name"], e["significant"]) for e in report["effects"]])
    assert _by_name(report)[name]["shrink"] >= 0.5, (name, _by_name(report)[name])
    assert report["effects"][0]["significant"]


@pytest.mark.slow
@case("buoyancy_offset")
def test_the_steady_balance_shows_the_buoyancy_error_and_the_corrected_model_taking_it_off(diagnosed):
    """The report's ``steady_balance``: with a withheld buoyancy change the thrusters held a steady heave force the
    nominal model does not need (imbalanced beyond 3 standard errors); the corrected model, with the named
    buoyancy offset, needs what was held to within a quarter of that (the truth's foam changes with depth, the
    template is constant)."""
    report, truth = diagnosed(["buoyancy_offset"])
    bal = report["steady_balance"]
    assert bal["effects"] == [e["name"] for e in report["effects"] if e["significant"]]
    off = [b["dofs"]["Z"] for b in bal["bins"] if b["dofs"]["Z"]["imbalanced"]]
    assert off, bal
    for z in off:
        assert abs(z["held"] - z["corrected"]) < 0.25 * abs(z["held"] - z["nominal"]), (z, truth)


@pytest.mark.slow
@pytest.mark.xfail(reason="truth fixture, not diagnoser: with its 2-3x image-law wall suction and no contact, the "
                          "unactuated sway lets the truth vehicle be pulled through the wall (tens of metres, rolling "
                          "over), a chaotic run no model replays; wall_effect is still named first. The physical wall "
                          "case is tests/udrobot_ctrl/gap/test_case_wall_effect.py", strict=False)
@pytest.mark.parametrize("name", ["wall_effect"])
def test_single_effect_hard_cases(name):
    report, truth = _run([name])
    assert _verdict_ok(report, name)
    assert _by_name(report)[name]["shrink"] >= 0.5


@pytest.mark.slow
def test_two_effects_together():
    report, truth = _run(["buoyancy_offset", "thrust_inflow_loss"], seed=5)
    assert _verdict_ok(report, "buoyancy_offset") and _verdict_ok(report, "thrust_inflow_loss")
    assert report["unexplained"] < 0.5


@pytest.mark.slow
def test_an_interacting_pair_is_named_though_one_alone_makes_the_holdout_worse():
    """An added-mass error with a CG-CB offset: fitted alone, the CG-CB offset is biased by the missing added mass and
    its replay is worse than the nominal one; in the pair, dropping it worsens every holdout window. Both are named,
    nothing else."""
    report, truth = _run(["added_mass_error", "cg_cb_offset"])
    assert {e["name"] for e in report["effects"] if e["significant"]} == {"added_mass_error", "cg_cb_offset"}, truth
    last = report["backward_elimination"][-1]["tests"]["cg_cb_offset"]
    assert last["alone_shrink"] < REPLAY_MATERIAL and last["windows_worse"] >= CONSISTENT_WINDOWS, last
    assert report["unexplained"] < 0.3


@pytest.mark.slow
def test_quadratic_damping_on_the_speed_is_recovered_in_its_form():
    """The truth's damping error acts on the speed norm (cross-flow drag), not per axis: the template's form
    ``norm_weight`` ends near 1 and the per-DOF scales are the truth's translational and rotational ones, with no
    cross-coupled damping standing in for the coupling."""
    report, truth = _run(["quadratic_damping_error"], seed=3)
    assert {e["name"] for e in report["effects"] if e["significant"]} == {"quadratic_damping_error"}, truth
    fit = _by_name(report)["quadratic_damping_error"]["params"]
    c = truth["quadratic_damping_error"]
    assert fit["norm_weight"] > 0.9, fit
    for k in ("scale_Xu|u|", "scale_Yv|v|", "scale_Zw|w|"):
        assert fit[k] == pytest.approx(c["s_t"], abs=0.05), (k, fit, c)
    for k in ("scale_Mq|q|", "scale_Nr|r|"):  # roll is barely excited by these manoeuvres
        assert fit[k] == pytest.approx(c["s_r"], abs=0.1), (k, fit, c)


@pytest.mark.slow
def test_linear_and_quadratic_damping_errors_together_are_both_named():
    """A |nu|^1.1 skin-friction term and a speed-norm quadratic error: both named, nothing else; the quadratic
    error in its speed form, so the linear template does not absorb it."""
    report, truth = _run(["linear_damping", "quadratic_damping_error"])
    assert {e["name"] for e in report["effects"] if e["significant"]} == {"linear_damping",
                                                                          "quadratic_damping_error"}, truth
    assert _by_name(report)["quadratic_damping_error"]["params"]["norm_weight"] > 0.8
    assert report["unexplained"] < 0.3


@pytest.mark.extended
@pytest.mark.slow
def test_a_current_added_after_a_quadratic_damping_error_is_confirmed_with_the_dampings_form_fitted_again():
    """bench/blind_score.py's water current + quadratic damping error case (five 60 s runs at 50 Hz, 3 fit, 2
    holdout). The damping, selected first, fits its speed-norm weight alone at 0.835 and, held there, leaves the
    current a holdout replay rise of +3.7 % (p 0.16) when dropped, and the current was missed; added with the
    damping's form refitted (the truth's: the speed norm) the current is confirmed."""
    names = ("water_current", "quadratic_damping_error")
    seed = sum(EFFECT_NAMES.index(n) + 1 for n in names) * 7
    rng = np.random.default_rng(seed)
    truth = {n: random_magnitudes(n, rng) for n in names}
    runs = generate(truth, n_runs=5, duration=60.0, rate=50.0, seed=seed)
    report, _ = diagnose("pendulum:chin", runs[:3], runs[3:], window_s=8.0)
    assert {e["name"] for e in report["effects"] if e["significant"]} == set(names), truth
    assert _by_name(report)["quadratic_damping_error"]["params"]["norm_weight"] > 0.95
    current = report["backward_elimination"][-1]["tests"]["water_current"]
    assert current["holdout_gap_contribution"] > 0.08 and current["replay_p"] < 0.01, current  # held: 0.037, p 0.16


@pytest.mark.slow
@case("periodic_disturbance", seed=3)
def test_effect_outside_catalogue_is_unexplained(diagnosed):
    report, _ = diagnosed(["periodic_disturbance"], seed=3)
    sig = [e for e in report["effects"] if e["significant"]]
    assert not sig or report["unexplained"] > 0.5
    assert report["location"], "the gap is still located"


@pytest.mark.slow
@case()
def test_no_effect_nothing_located(diagnosed):
    """The model matches within noise: no DOF's force balance is above its floor, so no channel is located."""
    report, _ = diagnosed([])
    assert report["location"] == []
    assert report["location_detail"]["ranked_by"] == "force"
    assert all(v["excess_share"] == 0.0 for v in report["location_detail"]["force"].values())


def _significant(report):
    return [e["name"] for e in report["effects"] if e["significant"]]


@pytest.mark.slow
@case("periodic_disturbance", seed=3)
def test_disturbance_in_surge_and_heave_is_located_there_not_in_roll(diagnosed):
    """A periodic surge/heave force: the force balance fails in X and Z; the roll rate, whose replay error is
    large for any model (small spread against its noise), is not where the gap lies."""
    report, _ = diagnosed(["periodic_disturbance"], seed=3)
    located = [loc["channel"] for loc in report["location"]]
    assert located and located[0] in ("u", "w", "z"), report["location"]
    assert {"u", "w"} <= set(located) and not {"p", "phi"} & set(located), located
    force = report["location_detail"]["force"]
    assert force["X"]["ratio"] > 2 and force["Z"]["ratio"] > 2  # well above the noise floor
    assert force["K"]["ratio"] < 1.5  # roll's force balance holds within noise


@pytest.mark.slow
@case("thruster_lag")
def test_lag_alone_names_only_the_lag(diagnosed):
    """Seen before: thruster lag came with deadband, added mass and linear damping. Each extra candidate, dropped
    from the final set, leaves the holdout no worse; the backward check records why it went."""
    report, _ = diagnosed(["thruster_lag"])
    assert _significant(report) == ["thruster_lag"]
    for e in report["effects"]:
        back = e["evidence"].get("backward_elimination")
        if e["significant"]:
            assert back["passed"] and back["holdout_lr"] > 6.63 and back["holdout_gap_contribution"] > 0
        elif back is not None:  # a dropped candidate says why
            assert not back["passed"] and "dropped by the backward check" in e["evidence"]["note"]
    last = report["backward_elimination"][-1]
    assert last["dropped"] is None and last["members"] == ["thruster_lag"]
    assert report["verdict"].startswith(f"significant: 1 of {len(EFFECT_NAMES)} effects tested (thruster_lag)")


@pytest.mark.slow
@case("thruster_deadband")
def test_deadband_alone_comes_without_extra_damping(diagnosed):
    report, _ = diagnosed(["thruster_deadband"])
    assert _significant(report) == ["thruster_deadband"]


@pytest.mark.slow
def test_partial_logs_and_buoyancy_parameter():
    report, truth = _run(["buoyancy_offset"], seed=4, partial=True)
    e = _by_name(report)["buoyancy_offset"]
    assert e["significant"]
    dB_mean = truth["buoyancy_offset"]["dB0"] * (1 - truth["buoyancy_offset"]["beta"] * 1.5)
    assert e["params"]["dB_N"] == pytest.approx(dB_mean, rel=0.35)


@pytest.mark.slow
def test_cli_end_to_end(tmp_path):
    rng = np.random.default_rng(7)
    runs = generate({"thrust_inflow_loss": random_magnitudes("thrust_inflow_loss", rng)}, n_runs=2, duration=60.0,
                    rate=25.0, seed=7)
    paths = []
    for i, r in enumerate(runs):
        paths.append(write(r, tmp_path / f"run{i}.csv"))
    out = tmp_path / "rep.json"
    proc = subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "diagnose", "--model", "pendulum:chin",
                           "--json", str(out), "--holdout", str(paths[1]), "--plot", str(tmp_path / "fig"),
                           "--quiet", str(paths[0])], capture_output=True, text=True, cwd=REPO,
                          env={"MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr
    rep = json.loads(out.read_text())
    assert rep["holdout_runs"] == ["run1.csv"] and rep["fit_runs"] == ["run0.csv"]
    assert {"gap_before", "gap_after", "location", "effects", "unexplained"} <= set(rep)
    assert any((tmp_path / "fig").glob("overlay_*.png"))


@pytest.mark.slow
def test_cli_bad_input(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u\n0,1\n")
    proc = subprocess.run([sys.executable, "-m", "udrobot_ctrl.cli", "diagnose", "--model", "pendulum:chin",
                           "--json", str(tmp_path / "r.json"), str(bad)], capture_output=True, text=True, cwd=REPO)
    assert proc.returncode == 2 and "bad.csv" in proc.stderr


def test_the_gap_left_is_measured_against_the_noise_floor():
    """A nominal replay 250 x its floor (summed NRMSE^2) with 38 % of the holdout gap left is still ~36 x above
    it: a gap to explain, though most of it was; a channel without a floor does not count."""
    located = Located((), {"z": 1.0, "r": 0.5, "u": 9.0}, {"z": 0.063, "r": 0.032}, {}, {}, {})
    before = GapScore(1.0, {"z": 1.0, "r": 0.5, "u": 9.0}, ["z", "r", "u"], {})
    where = Where([], [], located, before)
    after = GapScore(0.38, {"z": 0.38, "r": 0.19, "u": 0.1}, ["z", "r", "u"], {})
    nominal = located.replay_to_floor()
    assert nominal == pytest.approx(1.25 / (0.063 ** 2 + 0.032 ** 2))
    assert remaining_to_floor(where, after) == pytest.approx(nominal * 0.38 ** 2)
    assert remaining_to_floor(where, after) > REPLAY_ABOVE_FLOOR
    explained = GapScore(0.05, {"z": 0.05, "r": 0.02, "u": 9.0}, ["z", "r", "u"], {})
    assert remaining_to_floor(where, explained) < REPLAY_ABOVE_FLOOR  # near the floor: nothing left to explain
    assert np.isnan(remaining_to_floor(Where([], [], Located((), {"u": 1.0}, {}, {}, {}, {}),
                                             GapScore(1.0, {"u": 1.0}, ["u"], {})), after))


def test_replays_on_demand_run_once_per_effect_only_when_read_and_together_when_iterated():
    calls = []

    def replay(names):
        calls.append(tuple(names))
        return {n: len(n) for n in names}
    lazy = OnDemand(("lag", "tether", "current"), replay)
    assert calls == [] and len(lazy) == 3 and list(lazy) == ["lag", "tether", "current"]
    assert lazy["tether"] == 6 and lazy["tether"] == 6 and calls == [("tether",)]
    # iterating the values computes every missing one in one call (the replays are integrated together)
    assert dict(lazy.items()) == {"lag": 3, "tether": 6, "current": 7} and calls == [("tether",), ("lag", "current")]
    assert list(lazy.values()) == [3, 6, 7] and len(calls) == 2
    with pytest.raises(KeyError):
        lazy["wall"]
