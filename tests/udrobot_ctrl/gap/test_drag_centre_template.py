"""The diagnoser's template of a centre of pressure off the CO: the first-order expansion of the plant's own term,
bounded by the vehicle's size; the replay uses the plant's exact form."""
from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.dynamics.plant import generalized_forces, plant_parameters
from udrobot_ctrl.gap.effects import Actuation, Stack, catalogue, discriminating_manoeuvre
from udrobot_ctrl.vehicle import load_model


def _stack(x, p):
    """A stack whose filter is the identity: the regressor as the plant sees it, sample by sample."""
    n = x.shape[0]
    run = {"eta": x[:, :6], "nu": x[:, 6:], "idx": np.arange(n), "smooth": lambda y, held=False: y}
    return Stack(nu=x[:, 6:], nu_dot=np.zeros((n, 6)), eta=x[:, :6], f=np.zeros((n, p.T.shape[1])), B=p.T,
                 inflow=p.T, f_ref=np.ones(p.T.shape[1]), surfaces={}, runs=[run], p=p, M_A=p.M_A)


def _states(n=300, seed=0):
    rng = np.random.default_rng(seed)
    x = np.zeros((n, 12))
    x[:, 3:6] = rng.uniform(-0.3, 0.3, (n, 3))
    x[:, 6:9] = rng.uniform(-0.4, 0.4, (n, 3))
    x[:, 9:12] = rng.uniform(-0.2, 0.2, (n, 3))
    return x


def _plant_force(model, r, x):
    p0 = plant_parameters(load_model(model))
    corrected = plant_parameters(load_model(model).with_changes(
        effects=(PlantEffect("drag_centre_offset", dict(zip(fx.DRAG_CENTRE, r))),)))
    return generalized_forces(x, p0) - generalized_forces(x, corrected)  # what the effect adds to the plant


@pytest.mark.parametrize("model", ["bluerov2-heavy", "pendulum:chin"])
def test_design_is_the_plants_force_to_first_order_and_the_replay_the_plants_own(model):
    p0 = plant_parameters(load_model(model))
    eff = catalogue()["drag_centre_offset"]
    b0, A, names, lo, hi = eff.design(_stack(_states(), p0), ())
    assert names == fx.DRAG_CENTRE and np.all(b0 == 0)
    np.testing.assert_allclose(hi, p0.size_m)
    np.testing.assert_allclose(lo, -p0.size_m)
    x = _states()
    r = np.array([0.03, -0.02, 0.04])
    err = [np.abs(A @ (k * r) - _plant_force(model, k * r, x)).max() for k in (1.0, 0.5)]
    assert err[1] < 0.3 * err[0]  # the error of the expansion is second order in r
    assert err[0] < 0.1 * np.abs(_plant_force(model, r, x)).max()
    still = x.copy()
    still[:, 9:] = 0.0  # not rotating: the centre moves with the CO, the moment r x F(v) is linear in r, exact
    b0, A, *_ = eff.design(_stack(still, p0), ())
    np.testing.assert_allclose(A @ r, _plant_force(model, r, still), rtol=1e-10, atol=1e-12)
    hooks = eff.hooks(dict(zip(names, r)), p0, Actuation(None, None, None, p0.M_A))
    np.testing.assert_allclose(hooks.force(x, None, {}), _plant_force(model, r, x), rtol=1e-12, atol=1e-12)


def test_least_squares_on_the_design_recovers_a_centre_of_pressure():
    """A centre of pressure a few cm off the CO is recovered from the plant's exact force to a millimetre."""
    p0 = plant_parameters(load_model("bluerov2-heavy"))
    x = _states(600, seed=3)
    r = np.array([-0.02, 0.01, 0.03])
    _, A, *_ = catalogue()["drag_centre_offset"].design(_stack(x, p0), ())
    fit, *_ = np.linalg.lstsq(A.reshape(-1, 3), _plant_force("bluerov2-heavy", r, x).ravel(), rcond=None)
    np.testing.assert_allclose(fit, r, atol=1e-3)


def test_a_model_without_thrusters_is_bounded_by_the_assumed_size():
    p0 = plant_parameters(load_model("bluerov2-heavy"))
    *_, lo, hi = catalogue()["drag_centre_offset"].design(_stack(_states(20), replace(p0, size_m=None)), ())
    np.testing.assert_allclose(hi, fx.ASSUMED_VEHICLE_SIZE_M)


def test_its_look_alikes_name_the_manoeuvre_that_separates_them():
    for other in ("cg_cb_offset", "cross_coupled_damping"):
        text = discriminating_manoeuvre("drag_centre_offset", other)
        assert text == discriminating_manoeuvre(other, "drag_centre_offset") and "regressors of" not in text


@pytest.mark.slow
def test_a_withheld_centre_of_pressure_is_confirmed_and_located():
    """The truth generator's form drag at a centre of pressure (its quadratic drag only, not the template's whole
    drag) is confirmed on the holdout and its centre recovered within 1 mm, when the test is restricted to it
    (``--effects drag_centre_offset``). Against the whole catalogue ``cross_coupled_damping`` is its look-alike
    (its D_Mu, Q_Mu|u| ... hold the centre's moments, with free ratios): the blind bench scores that
    (bench/blind_score.py --only drag_centre_offset --draws 4: 4 of 4 right)."""
    from udrobot_ctrl.gap.report import diagnose

    from .truth import generate

    truth = {"drag_centre_offset": {"r": (-0.011, 0.001, 0.0145)}}
    runs = generate(truth, n_runs=5, duration=60.0, rate=50.0, seed=98)
    report, _ = diagnose("pendulum:chin", runs[:3], runs[3:], window_s=8.0, effects=("drag_centre_offset",),
                         log=lambda line: None)
    (entry,) = report["effects"]
    assert entry["significant"] and not entry.get("at_bound")
    fit = [entry["params"][k] for k in fx.DRAG_CENTRE]
    np.testing.assert_allclose(fit, truth["drag_centre_offset"]["r"], atol=1e-3)
    assert report["unexplained"] < 0.3
