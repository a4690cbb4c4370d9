"""Batched plant equals the single-vehicle plant; local FD derivatives match an analytic case."""
from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics import plant
from udrobot_ctrl.sensitivity.batch import batch_plant, state_derivative
from udrobot_ctrl.sensitivity.evaluators import TerminalSurgeSpeed
from udrobot_ctrl.sensitivity.local import local_sensitivity
from udrobot_ctrl.sensitivity.parameters import apply_sample, default_space


def test_batch_plant_matches_single_vehicle_plant():
    space = default_space("pendulum:chin")
    rng = np.random.default_rng(3)
    lo, hi = space.bounds.T
    X = lo + rng.random((8, len(space))) * (hi - lo)
    vehicles = [apply_sample(space, x) for x in X]
    x = rng.normal(size=(8, 12)) * 0.4
    tau = rng.normal(size=(8, 6)) * 5
    got = state_derivative(x, tau, batch_plant(vehicles))
    ref = np.stack([plant.state_derivative(x[i], tau[i], plant.plant_parameters(v)) for i, v in enumerate(vehicles)])
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


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
