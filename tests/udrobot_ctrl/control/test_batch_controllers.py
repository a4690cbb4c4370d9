"""Batch control laws give every vehicle exactly its own controller's command, call after call."""
import numpy as np
import pytest

from udrobot_ctrl.control.lqr import BatchScheduledLQR
from udrobot_ctrl.control.missions import (
    ControllerBatch,
    SafeBatch,
    batch_controller,
    make_controller,
    standard_mission,
)
from udrobot_ctrl.control.pid import BatchPID, PIDController
from udrobot_ctrl.dynamics.sim import as_parameters
from udrobot_ctrl.sensitivity.parameters import apply_sample, default_space

MISSION = standard_mission(quick=True)


def _vehicles(n, seed=0):
    space = default_space("pendulum:chin")
    lo, hi = space.bounds.T
    X = lo + np.random.default_rng(seed).random((n, len(space))) * (hi - lo)
    return [as_parameters(apply_sample(space, x)) for x in X]


def _states(rng, n):
    x = rng.normal(size=(n, 12)) * np.array([1, 1, 0.5, 0.2, 0.2, 1.5, 0.4, 0.2, 0.2, 0.3, 0.3, 0.5])
    x[:, 2] += 1.0
    return x


@pytest.mark.parametrize("anti_windup", ["back-calculation", "conditional", "none"])
def test_batch_pid_matches_each_pid_over_a_sequence_of_calls(anti_windup):
    ps = _vehicles(5)
    single = [PIDController.design(p, MISSION.reference, dt=0.05, anti_windup=anti_windup) for p in ps]
    batch = BatchPID([PIDController.design(p, MISSION.reference, dt=0.05, anti_windup=anti_windup) for p in ps])
    rng = np.random.default_rng(1)
    for k in range(40):  # integrators, setpoint filters and saturation evolve per vehicle
        t = 0.05 * k * 10  # crosses the mission's reference changes
        x = _states(rng, len(ps))
        if k == 7:
            x[2, 4] = np.nan  # a non-finite state: trim command, that vehicle's state untouched
        got = batch(t, x)
        want = np.stack([c(t, xi) for c, xi in zip(single, x)])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch.integral, [[c.integral[n] for n in c.loops] for c in single], atol=1e-9)


def test_batch_lqr_matches_each_scheduled_lqr_and_shares_a_repeated_design():
    ps = _vehicles(4, seed=2)
    ctrls = [make_controller("lqr", p, MISSION) for p in ps]
    batch = BatchScheduledLQR(ctrls + [ctrls[0]])
    rng = np.random.default_rng(3)
    for t in (0.0, 5.0, 12.0, 20.0):
        x = _states(rng, 5)
        x[:, 6] = rng.uniform(-0.2, 1.5, 5)  # surge speeds below, inside and above the scheduling range
        x[1, 6] = np.nan
        got = batch(t, x)
        want = np.stack([c(t, xi) for c, xi in zip(ctrls + [ctrls[0]], x)])
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def test_batch_controller_vectorises_gain_laws_and_wraps_others_per_vehicle():
    ps = _vehicles(2)
    f_min, f_max = ps[0].f_min, ps[0].f_max
    assert isinstance(batch_controller([make_controller("lqr", p, MISSION) for p in ps], f_min, f_max), SafeBatch)
    assert isinstance(batch_controller([make_controller("pid", p, MISSION) for p in ps], f_min, f_max), SafeBatch)

    def broken(t, x):
        raise RuntimeError("solver failed")

    wrap = batch_controller([lambda t, x: np.full(len(f_min), 5.0), broken], f_min, f_max)
    assert isinstance(wrap, ControllerBatch)
    with pytest.warns(RuntimeWarning, match="solver failed"):
        u = wrap(0.0, np.zeros((2, 12)))
    np.testing.assert_allclose(u, [np.clip(np.full(len(f_min), 5.0), f_min, f_max), np.zeros(len(f_min))])
    assert list(wrap.fallbacks) == [0, 1]
