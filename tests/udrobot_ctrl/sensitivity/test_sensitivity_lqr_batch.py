"""The compiled LQR batch and the batch metrics of the sensitivity studies (issue 38) against the numpy path they
replace: ``run_mission_batch`` (one RK4 kernel call per control step, the vectorised law) and ``flat_metrics``
per vehicle; SALib's Sobol analysis against its fast twin."""
from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.control.missions import batch_controller
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import SimResult, simulate, stack_parameters
from udrobot_ctrl.sensitivity.batch import batch_metrics, fly_lqr_batch
from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator, _vehicles, flat_metrics
from udrobot_ctrl.sensitivity.global_ import sobol_first_total, sobol_samples
from udrobot_ctrl.sensitivity.parameters import default_space


@pytest.fixture(scope="module")
def batch():
    space = default_space("cfd:morison")
    X = sobol_samples(space.salib_problem(), 8, seed=1)[:12]
    plants = [plant_parameters(v) for v in _vehicles(space, X)[0]]
    return space, X, stack_parameters(plants)


def _numpy_path(ev, p):
    ctrls = [ev._nominal()] * p.M.shape[0]
    ctrl = batch_controller(ctrls, p.f_min, p.f_max)
    res = simulate(p, ev.mission.x0(), ev.mission.t_final, controller=ctrl, dt=ev.sim_dt, control_dt=ev.control_dt,
                   on_divergence="freeze", parallel=False)
    return ctrls, ctrl, res


def test_compiled_lqr_batch_flies_as_run_mission_batch_and_freezes_a_diverging_vehicle(batch):
    space, _, p = batch
    ev = MissionEvaluator(space, "lqr")
    Minv = p.M_inv.copy()
    Minv[3] *= -30.0  # vehicle 3: an unstable plant that diverges within a few seconds
    p = replace(p, M_inv=Minv)
    ctrls, ctrl, res = _numpy_path(ev, p)
    t, x, u, hold, diverged, fallbacks = fly_lqr_batch(ctrls, p, ev.mission, ev.sim_dt, ev.control_dt)
    xo = np.moveaxis(res.x, 1, 0)
    assert np.array_equal(t, res.t) and x.shape == xo.shape
    assert np.array_equal(np.isnan(x), np.isnan(xo))
    first_nan = np.argmax(~np.all(np.isfinite(res.x[:, 3]), axis=-1))
    assert diverged[3] == first_nan > 0 and np.all(np.delete(diverged, 3) == -1)
    ok = np.delete(np.arange(len(x)), 3)
    # the law sums its dot products in another order than einsum / BLAS: rounding differences only
    np.testing.assert_allclose(x[ok], xo[ok], rtol=0, atol=1e-12)
    u_steps = np.repeat(u, hold, axis=1)[:, : res.u.shape[0]]
    np.testing.assert_allclose(u_steps[ok], np.moveaxis(res.u, 1, 0)[ok], rtol=0, atol=1e-11)
    assert np.array_equal(fallbacks, ctrl.fallbacks)


def test_batch_metrics_equal_flat_metrics_of_each_run(batch):
    space, _, p = batch
    ev = MissionEvaluator(space, "lqr")
    _, _, res = _numpy_path(ev, p)
    met = batch_metrics(res.t, np.moveaxis(res.x, 1, 0), np.moveaxis(res.u, 1, 0), ev.mission, p.f_min, p.f_max)
    for j in range(p.M.shape[0]):
        one = SimResult(t=res.t, x=res.x[:, j], u=res.u[:, j], tau=res.tau[:, j], saturated=res.saturated[:, j])
        ref = flat_metrics(one, ev.mission, p.f_min, p.f_max)
        assert set(met) == set(ref)
        for k, v in ref.items():
            assert met[k][j] == v, (k, j, met[k][j], v)  # the same operations: the same numbers
    # held commands given once per control step: the same numbers
    t, x, u, hold, _, _ = fly_lqr_batch([ev._nominal()] * p.M.shape[0], p, ev.mission, ev.sim_dt, ev.control_dt)
    once = batch_metrics(t, x, u, ev.mission, p.f_min, p.f_max, hold)
    per_step = batch_metrics(t, x, np.repeat(u, hold, axis=1)[:, : len(t) - 1], ev.mission, p.f_min, p.f_max)
    for k in once:
        assert np.array_equal(once[k], per_step[k]), k


def test_evaluator_metrics_equal_the_numpy_path(batch):
    space, X, p = batch
    ev = MissionEvaluator(space, "lqr")
    out = ev(X)
    _, ctrl, res = _numpy_path(ev, p)
    assert out["error"] == [""] * len(X)
    for j in range(len(X)):
        one = SimResult(t=res.t, x=res.x[:, j], u=res.u[:, j], tau=res.tau[:, j], saturated=res.saturated[:, j])
        ref = {**flat_metrics(one, ev.mission, p.f_min, p.f_max), "fallbacks": float(ctrl.fallbacks[j])}
        for k, v in ref.items():
            assert out[k][j] == pytest.approx(v, rel=1e-9, abs=1e-12), (k, j)


def test_sobol_first_total_equals_salib_bit_for_bit():
    from SALib.analyze import sobol as sobol_analyze

    problem = {"num_vars": 3, "names": ["a", "b", "c"], "bounds": [[-np.pi, np.pi]] * 3}
    X = sobol_samples(problem, 64, seed=3)
    Y = np.sin(X[:, 0]) + 7 * np.sin(X[:, 1]) ** 2 + 0.1 * X[:, 2] ** 4 * np.sin(X[:, 0])
    for y in (Y, np.where(X[:, 2] > 0, 1.0, 0.0), X[:, 0] * 0.0 + 2.0):
        with np.errstate(all="ignore"):  # the constant output: SALib divides by its zero deviation
            ref = sobol_analyze.analyze(problem, y, calc_second_order=False, num_resamples=50, conf_level=0.9,
                                        seed=np.random.default_rng(5))
            ours = sobol_first_total(problem, y, 50, 0.9, np.random.default_rng(5))
        for k in ("S1", "S1_conf", "ST", "ST_conf"):
            assert np.array_equal(np.asarray(ref[k]), ours[k], equal_nan=True), k
