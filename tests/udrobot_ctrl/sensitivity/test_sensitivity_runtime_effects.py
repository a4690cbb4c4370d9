"""Sensitivity of a model with run-time effects (a corrected model): flown vehicle by vehicle in numpy."""
import numpy as np
import pytest

from udrobot_ctrl.control.compare import DETAIL_KEYS, RESULT_KEYS, run_design
from udrobot_ctrl.control.missions import standard_mission
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator, TerminalSurgeSpeed, runtime_effects
from udrobot_ctrl.sensitivity.parameters import default_space
from udrobot_ctrl.vehicle import load_model, write_model_file

K_Q = 25.0  # N s^2/m^2, a cable straight up: horizontal drag K_Q |V_h| V_h


@pytest.fixture(scope="module")
def tethered(tmp_path_factory):
    cable = PlantEffect("tether_drag", {"k_quadratic_N_s2_per_m2": K_Q, "k_linear_N_s_per_m": 0.0,
                                        "cable_azimuth_rad": 0.0, "cable_elevation_rad": np.pi / 2})
    v = load_model("cfd:morison")
    path = tmp_path_factory.mktemp("tether") / "tethered.json"
    write_model_file(v.with_changes(effects=(cable,), name="cfd:morison+tether_drag"), path)
    return str(path)


def test_terminal_speed_carries_the_tether(tethered):
    """Open loop, a surge force F settles where F = (Q_uu + k_q) u^2 (morison: no linear damping); the batched
    kernels would drop the cable, the per-vehicle path simulates it."""
    space = default_space(tethered)
    assert runtime_effects(space) == ("tether_drag",)
    ev = TerminalSurgeSpeed(space, thrust_N=20.0, t_final=40.0)
    out = ev(space.nominal[None])
    assert out["error"] == [""]
    q = plant_parameters(space.vehicle).Q[0, 0]
    assert out["u_terminal"][0] == pytest.approx(np.sqrt(20.0 / (q + K_Q)), rel=2e-3)
    assert out["u_terminal"][0] < 0.8 * np.sqrt(20.0 / q)  # the cable matters


@pytest.mark.slow
def test_nominal_sample_of_a_tethered_model_gives_compare_metrics(tethered):
    space = default_space(tethered)
    out = MissionEvaluator(space, "lqr", mission=standard_mission(quick=True))(space.nominal[None])
    rows, _ = run_design("lqr", tethered, [tethered], quick=True, keep_trajectory=False)
    assert out["error"] == [""] and rows[0]["status"] == "ok"
    for k in RESULT_KEYS[3:] + DETAIL_KEYS:
        if rows[0][k] is not None:
            assert out[k][0] == pytest.approx(rows[0][k], rel=1e-9, abs=1e-12), k
