"""PID: tuning from the linear model, margins, anti-windup under thrust saturation."""
import numpy as np
import pytest

from udrobot_ctrl.control.metrics import mission_metrics
from udrobot_ctrl.control.missions import Mission, ReferenceStep, make_controller, run_mission, standard_mission
from udrobot_ctrl.control.pid import LOOPS, PIDController, PIDTuning, design_loops, loop_margins
from udrobot_ctrl.dynamics.sim import as_parameters


@pytest.mark.parametrize("name", ["cfd:chin", "pendulum:morison"])
def test_margins_positive(name):
    loops = design_loops(as_parameters(name))
    assert set(loops) == set(LOOPS)
    assert "SIMC" in loops["depth"].method and "pole placement" in loops["roll"].method
    for loop, m in loop_margins(loops).items():
        assert 20.0 < m["phase_margin_deg"] < 180.0, loop
        assert m["gain_margin"] > 2.0, loop
        assert m["gain_margin_lower"] < 0.5, loop  # conditionally stable loops tolerate a large gain reduction


def test_pid_settles_mission():
    mission = standard_mission(quick=False)
    res = run_mission(make_controller("pid", "cfd:chin", mission), "cfd:chin", mission)
    p = as_parameters("cfd:chin")
    m = mission_metrics(res, mission, p.f_min, p.f_max)
    assert m["settling_s"] is not None and m["settling_s"] < 10.0
    assert m["settling_psi_s"] is not None
    assert all(abs(e) < 0.02 for e in m["final_error"].values())


def test_anti_windup_reduces_overshoot_under_saturation():
    # aggressive depth loop (tau_c 0.1 s) on a 3 m step: the vertical thrusters saturate for seconds
    mission = Mission("deep step", 25.0, {"z": 0.5, "psi": 0.0, "u": 0.0}, (ReferenceStep("z", 0.5, 3.5),))
    p = as_parameters("free_decay:morison")
    tuning = PIDTuning(tau_c={"depth": 0.1})
    out = {}
    for aw in ("back-calculation", "conditional", "none"):
        ctrl = PIDController.design(p, mission.reference, dt=0.05, tuning=tuning, anti_windup=aw,
                                    setpoint_filter=0.0)
        res = run_mission(ctrl, p, mission)
        out[aw] = mission_metrics(res, mission, p.f_min, p.f_max)
    assert out["none"]["saturation_s"] > 1.0
    assert out["none"]["overshoot"] > out["back-calculation"]["overshoot"] + 5.0
    assert out["none"]["overshoot"] > out["conditional"]["overshoot"] + 5.0
    assert np.isfinite(out["back-calculation"]["iae"])


def test_bad_anti_windup_name():
    with pytest.raises(ValueError, match="anti_windup"):
        PIDController.design(as_parameters("cfd:chin"), standard_mission().reference, anti_windup="clamp")
