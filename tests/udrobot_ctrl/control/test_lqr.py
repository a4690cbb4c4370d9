"""LQR: Bryson weights, continuous vs discrete design, closed loop on the nonlinear plant."""
import numpy as np
import pytest

from udrobot_ctrl.control.linearize import REDUCED_STATES, hover_trim
from udrobot_ctrl.control.lqr import BrysonWeights, ScheduledLQR, design_lqr
from udrobot_ctrl.control.metrics import mission_metrics
from udrobot_ctrl.control.missions import make_controller, run_mission, standard_mission
from udrobot_ctrl.dynamics.sim import as_parameters


def test_bryson_weights_and_stable_designs():
    p = as_parameters("cfd:chin")
    Q, R = BrysonWeights().matrices(p)
    assert Q[0, 0] == pytest.approx(1 / 0.1**2) and R[0, 0] == pytest.approx(1 / 28.61**2)
    with pytest.raises(ValueError, match="not a design state"):
        BrysonWeights({"x": 1.0}).matrices(p)
    cont = design_lqr(p, hover_trim(p))
    assert np.all(cont.closed_loop_poles.real < 0)
    disc = design_lqr(p, hover_trim(p), dt=0.05)
    assert np.all(np.abs(disc.closed_loop_poles) < 1)
    assert cont.K.shape == (4, len(REDUCED_STATES))


def test_gain_schedule_interpolates():
    p = as_parameters("cfd:chin")
    ctrl = ScheduledLQR.design(p, lambda t: {"z": 1.0, "psi": 0.0, "u": 0.0}, dt=0.05)
    assert ctrl.speeds[0] == 0.0 and ctrl.speeds[-1] > 1.0
    k_mid = ctrl.gain(0.375)
    assert np.allclose(k_mid, 0.5 * (ctrl.gains[1] + ctrl.gains[2]))
    assert np.allclose(ctrl.gain(10.0), ctrl.gains[-1])


@pytest.mark.parametrize("design,plant", [("cfd:chin", "cfd:chin"), ("cfd:chin", "free_decay:morison")])
def test_closed_loop_settles_depth_step_and_keeps_passive_dofs_bounded(design, plant):
    mission = standard_mission(quick=True)
    ctrl = make_controller("lqr", design, mission)
    res = run_mission(ctrl, plant, mission)
    p = as_parameters(plant)
    m = mission_metrics(res, mission, p.f_min, p.f_max)
    assert m["settling_s"] is not None and m["settling_s"] < 4.0  # depth step, 2 % band
    assert m["overshoot"] < 10.0
    assert abs(m["final_error"]["z"]) < 0.02 and abs(m["final_error"]["psi"]) < np.radians(2)
    assert m["max_pitch_deg"] < 30.0 and m["max_roll_deg"] < 10.0 and m["max_sway_mps"] < 0.3
    assert np.all(res.u <= p.f_max + 1e-9) and np.all(res.u >= p.f_min - 1e-9)
    assert res.controller.fallbacks == 0
