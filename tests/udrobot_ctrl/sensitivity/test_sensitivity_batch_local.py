"""Batched missions equal single runs; local FD derivatives match an analytic case."""
from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.control.missions import Mission, ReferenceStep, make_controller, run_mission, run_mission_batch
from udrobot_ctrl.sensitivity.evaluators import TerminalSurgeSpeed
from udrobot_ctrl.sensitivity.local import local_sensitivity
from udrobot_ctrl.sensitivity.parameters import apply_sample, default_space

SHORT = Mission("batch-test", 6.0, initial={"z": 0.5, "psi": 0.0, "u": 0.0},
                steps=(ReferenceStep("z", 0.5, 1.5), ReferenceStep("psi", 2.0, np.pi / 2),
                       ReferenceStep("u", 3.0, 0.5)))


@pytest.mark.parametrize("kind", ["lqr", "pid"])
def test_batched_mission_equals_each_vehicle_flown_alone(kind):
    # the vectorised laws and the stacked plant give every vehicle the trajectory of its own run
    space = default_space("pendulum:chin")
    rng = np.random.default_rng(3)
    lo, hi = space.bounds.T
    vehicles = [apply_sample(space, x) for x in lo + rng.random((4, len(space))) * (hi - lo)]
    ctrls = [make_controller(kind, v, SHORT) for v in vehicles]  # redesigned on each: per-vehicle gains
    res = run_mission_batch(ctrls, vehicles, SHORT, dt=0.01, control_dt=0.05)
    for i, v in enumerate(vehicles):
        alone = run_mission(make_controller(kind, v, SHORT), v, SHORT, dt=0.01, control_dt=0.05)
        np.testing.assert_allclose(res.x[:, i], alone.x, rtol=0, atol=1e-10)
        np.testing.assert_allclose(res.u[:, i], alone.u, rtol=0, atol=1e-8)


def test_local_derivative_of_terminal_surge_speed_matches_analytic():
    # Pure-surge case: neutral buoyancy and CG at CO, so no heave drift and no pitch coupling;
    # the steady state then solves F = K_L u + K_Q u^2 exactly.
    space = default_space("pendulum:chin", rotational=False).subset(["surge.KL", "surge.KQ", "sway.KQ"])
    v = space.vehicle
    space = replace(space, vehicle=v.with_changes(buoyancy=v.weight, r_g=np.zeros(3)))
    F = 20.0
    res = local_sensitivity(TerminalSurgeSpeed(space, F, t_final=12.0), space, executor=None, progress=False)
    KL, KQ = space.nominal[0], space.nominal[1]
    u = (-KL + np.sqrt(KL**2 + 4 * KQ * F)) / (2 * KQ)
    assert res.base["u_terminal"] == pytest.approx(u, rel=1e-8)
    denom = KL + 2 * KQ * u  # implicit differentiation of F = K_L u + K_Q u^2
    d = res.derivative["u_terminal"]
    assert d[0] == pytest.approx(-u / denom, rel=1e-5)
    assert d[1] == pytest.approx(-u**2 / denom, rel=1e-5)
    assert abs(d[2]) < 1e-9  # sway damping does not act in pure surge
    assert res.reliable("u_terminal")[:2].all()
    # elasticity: a 1 % larger K_Q slows the vehicle by about 0.49 % (quadratic-dominated drag)
    assert res.elasticity["u_terminal"][1] == pytest.approx(-KQ * u**2 / denom / u, rel=1e-5)
