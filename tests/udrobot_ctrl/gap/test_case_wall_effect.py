"""Seeds 003 / 000 section 5.1: a gap-ratio near-wall/near-seabed effect (not the diagnoser's exponential template)
is attributed to wall_effect, and the distance below which it matters is recovered per surface."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

EXAMPLE = Path(__file__).resolve().parents[3] / "examples" / "wall_effect_case.py"


@pytest.fixture(scope="module")
def wall():
    spec = importlib.util.spec_from_file_location("wall_effect_case", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def result(wall):
    return wall.case(seed=0)


def test_truth_law_is_seed_000_gap_ratio(wall):
    tr = wall.GapRatioTruth()
    x = np.zeros((2, 12))
    x[:, 1] = -5.0  # far from the wall
    x[:, 2] = wall.SEABED - np.array([5.0, 0.085 + 0.35 * 0.169])  # far / heave gap ratio 0.35 over the seabed
    _, dM = tr.surface_terms(x)
    ratio = dM[:, 2, 2] / tr.MA[2, 2]
    assert ratio[0] < 0.01
    assert ratio[1] == pytest.approx(0.40, abs=0.03)  # Cely et al. 2019: 10.64 vs 7.62 kg near the bottom


def test_wall_effect_named_first(result):
    eff = result["wall_effect"]
    assert eff["significant"]
    assert result["report"]["effects"][0]["name"] == "wall_effect"
    assert eff["shrink"] > 0.0
    assert eff["evidence"]["delta_bic"] < -100


def test_distance_below_which_it_matters(result):
    truth, fitted = result["truth_matters_below"], result["fitted_matters_below"]
    assert set(fitted) == {"seabed", "wall 0"}
    assert result["wall_effect"]["planes"] == ["seabed", "wall 0"]  # both act: the physical default is kept
    assert fitted["seabed"]["matters_below_m"] == pytest.approx(truth["seabed"]["matters_below_m"], rel=0.25)
    assert fitted["wall 0"]["matters_below_m"] == pytest.approx(truth["wall 0"]["matters_below_m"], rel=0.35)
    assert result["wall_effect"]["matters_below_m"] == pytest.approx(
        max(v["matters_below_m"] for v in fitted.values()))


def test_corrected_model_holds_the_seabed_and_the_wall_and_replays_gap_after(result, wall):
    """The corrected plant's wall_effect acts on the planes the diagnosis saw (the sidecar's seabed depth and wall),
    so the windowed replay of the holdout passes with it is the report's gap_after, to its 6-decimal rounding."""
    from udrobot_ctrl.dynamics.effects import wall_planes
    from udrobot_ctrl.gap.replay import windowed_gap
    from udrobot_ctrl.gap.report import corrected_model

    report, runs, n_fit = result["report"], result["runs"], result["n_fit"]
    vehicle, not_placed = corrected_model(wall.MODEL, report, runs)
    assert not_placed == {}
    planes = wall_planes(next(e for e in vehicle.effects if e.name == "wall_effect").params)
    assert planes == [((0.0, 0.0, wall.SEABED), (0.0, 0.0, -1.0)), ((0.0, wall.WALL_Y, 0.0), (0.0, -1.0, 0.0))]
    g = windowed_gap(vehicle, runs[n_fit:], 8.0)
    assert g.value == pytest.approx(report["gap_after"]["value"], abs=2e-6)


@pytest.fixture(scope="module")
def seabed_only(wall):
    """The same passes with the flow effect of the seabed only: the sidecar still lists the wall the runs pass along
    (0.36-1 m off), which bumps the hull on contact but changes no flow."""
    return wall.case(seed=0, acting=("seabed",))


def test_a_plane_that_does_not_act_is_left_out(seabed_only, wall):
    """Fitted on the seabed and the wall with shared coefficients, the template would put the seabed's suction and
    added mass on every pass along the wall; the plane subset the fit selects is the seabed alone, its distance is the
    truth's, and the corrected plant holds the seabed only and replays the report's gap_after."""
    from udrobot_ctrl.dynamics.effects import wall_planes
    from udrobot_ctrl.gap.replay import windowed_gap
    from udrobot_ctrl.gap.report import corrected_model

    eff = seabed_only["wall_effect"]
    assert eff["significant"] and seabed_only["report"]["effects"][0]["name"] == "wall_effect"
    assert eff["planes"] == ["seabed"]
    truth, fitted = seabed_only["truth_matters_below"], seabed_only["fitted_matters_below"]
    assert set(truth) == set(fitted) == {"seabed"}
    assert fitted["seabed"]["matters_below_m"] == pytest.approx(truth["seabed"]["matters_below_m"], rel=0.25)
    report, runs, n_fit = seabed_only["report"], seabed_only["runs"], seabed_only["n_fit"]
    vehicle, _ = corrected_model(wall.MODEL, report, runs)
    params = next(e for e in vehicle.effects if e.name == "wall_effect").params
    assert "planes_mask" not in params
    assert wall_planes(params) == [((0.0, 0.0, wall.SEABED), (0.0, 0.0, -1.0))]
    assert windowed_gap(vehicle, runs[n_fit:], 8.0).value == pytest.approx(report["gap_after"]["value"], abs=2e-6)
