"""Only the failures expected at a place are turned into a status or a fallback; a bug surfaces as a bug."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from udrobot_ctrl.control import compare, mpc, pid
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.vehicle import load_model


def _raiser(exc):
    def fail(*args, **kwargs):
        raise exc
    return fail


def test_a_failed_design_is_a_row_but_a_bug_propagates(monkeypatch):
    monkeypatch.setattr(compare, "make_controller", _raiser(ValueError("not stabilizable")))
    rows, _ = compare.run_design("lqr", "pendulum:chin", ["pendulum:chin", "cfd:chin"], True, False)
    assert [r["status"] for r in rows] == ["design failed: ValueError: not stabilizable"] * 2
    assert all(r[k] is None for r in rows for k in compare.RESULT_KEYS[3:])
    monkeypatch.setattr(compare, "make_controller", _raiser(KeyError("selected")))
    with pytest.raises(KeyError, match="selected"):
        compare.run_design("lqr", "pendulum:chin", ["pendulum:chin"], True, False)


def test_a_diverged_flight_is_a_row_but_a_bug_propagates(monkeypatch):
    mission = compare.standard_mission(True)
    monkeypatch.setattr(compare, "run_mission", _raiser(FloatingPointError("state not finite")))
    row, res = compare._fly(object(), "lqr", "pendulum:chin", "cfd:chin", mission)
    assert res is None and row["status"] == "diverged: state not finite"
    monkeypatch.setattr(compare, "run_mission", _raiser(TypeError("unexpected keyword")))
    with pytest.raises(TypeError):
        compare._fly(object(), "lqr", "pendulum:chin", "cfd:chin", mission)


def test_pid_allocation_falls_back_only_when_osqp_rejects_the_problem(monkeypatch):
    p = plant_parameters(load_model("pendulum:chin"))
    monkeypatch.setattr(pid.ThrustAllocator, "from_parameters", _raiser(ValueError("P not positive semidefinite")))
    run, how = pid._allocator(p, "osqp")
    tau = np.array([5.0, 0.0, -3.0, 0.0, 0.0, 0.2])
    assert how == "clipped pseudo-inverse"
    assert np.allclose(run(tau), np.clip(np.linalg.pinv(p.T) @ tau, p.f_min, p.f_max))
    monkeypatch.setattr(pid.ThrustAllocator, "from_parameters", _raiser(AttributeError("T")))
    with pytest.raises(AttributeError):
        pid._allocator(p, "osqp")


def test_compilation_failure_keeps_the_interpreted_function_but_a_bug_propagates(monkeypatch):
    p = plant_parameters(load_model("pendulum:chin"))
    x = ca.SX.sym("x")
    fun = ca.Function("square", [x], [x * x])
    monkeypatch.setattr(mpc, "compile_function", _raiser(OSError("cache folder not writable")))
    assert mpc.maybe_compiled(fun, p) is fun
    monkeypatch.setattr(mpc, "compile_function", _raiser(NameError("gen")))
    with pytest.raises(NameError):
        mpc.maybe_compiled(fun, p)
