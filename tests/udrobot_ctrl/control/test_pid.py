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


def _linear_depth_step(loop, setpoint_filter):
    """Overshoot (%) and 2 % settling time (s) of the depth loop's linear closed loop for a unit setpoint step.

    Plant ``b / (s (s - a))``, control ``Kp e + Ki/s e - Kd s y`` with ``e`` taken to the setpoint filtered by
    ``1 / (setpoint_filter Kp/Ki s + 1)``: ``Y/R = b (Kp s + Ki) / ((s^3 - a s^2 + b (Kd s^2 + Kp s + Ki))
    (tf s + 1))``.
    """
    from scipy import signal

    a, b = loop.a, loop.b
    tf = setpoint_filter * loop.kp / loop.ki
    num = [b * loop.kp, b * loop.ki]
    den = np.polymul(np.polyadd([1.0, -a, 0.0, 0.0], [b * loop.kd, b * loop.kp, b * loop.ki]), [tf, 1.0])
    t = np.linspace(0.0, 30.0, 30001)
    _, y = signal.step((num, den), T=t)
    outside = np.flatnonzero(np.abs(y - 1.0) > 0.02)
    return 100.0 * max(0.0, y.max() - 1.0), float(t[outside[-1] + 1]) if outside.size else 0.0


@pytest.mark.parametrize("name", ["cfd:chin", "free_decay:morison", "pendulum:chin", "bluerov2-heavy"])
def test_depth_step_settles_within_its_manoeuvre_without_overshoot(name):
    """Issue 42: the shipped PID overshot a depth step by about 20 % and never settled before the next manoeuvre.

    The physics of the loop says why and what fixes it: the integral action's closed-loop zero at -Ki/Kp makes the
    linear loop overshoot by 10-20 % without the setpoint filter that cancels it, and the closed loop settles
    within the depth step's window of the mission. The flown mission (nonlinear plant, thrust limits, delay) agrees.
    """
    from udrobot_ctrl.control.pid import SETPOINT_FILTER

    mission = standard_mission(quick=True)
    step, _, window_end = next(e for e in mission.events() if e[0].channel == "z")
    window = window_end - step.t
    p = as_parameters(name)
    loop = design_loops(p)["depth"]
    overshoot_unfiltered, _ = _linear_depth_step(loop, 0.0)
    overshoot, settling = _linear_depth_step(loop, SETPOINT_FILTER)
    assert overshoot_unfiltered > 10.0  # the zero of the integral action: why a PID step overshoots
    assert overshoot < 1.0 and settling < 0.8 * window, (overshoot, settling, window)
    res = run_mission(make_controller("pid", name, mission), name, mission)
    m = mission_metrics(res, mission, p.f_min, p.f_max)
    assert m["overshoot"] < 5.0, m["overshoot"]
    assert m["settling_s"] is not None and m["settling_s"] < window, (m["settling_s"], window)
    assert m["overshoot_psi"] < 5.0 and m["settling_psi_s"] is not None
    assert m["saturation_s"] == 0.0  # the filtered setpoint keeps the thrusters off their limits
