"""The thruster templates' shape exponents are recovered by the equation-error fit (search grid and refinement)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import curve_fit

from udrobot_ctrl.dynamics import effects as pfx
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.thrusters import read_t200_csv
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import Attributor
from udrobot_ctrl.vehicle import load_model

from .truth import Truth

P = plant_parameters(load_model("pendulum:chin"))
DT = 0.02  # s, a 50 Hz log
#: equation-error residual noise per DOF (assumed: N and N m, of the order of a smoothed 50 Hz fit's residual)
SIGMA = 2.0
DOFS = np.array([True, False, True, True, False, True])  # X Z K N: the DOFs UDrobot actuates


def _commands(n=3000, seed=0):
    """Thrust commands held for 1 s each, uniform in the normalised command (u^1.5 times each direction's capacity):
    both signs, small and large, like a closed-loop pool run's."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, (n // 50 + 1, 4)), 50, axis=0)[:n]
    return np.where(u >= 0, P.f_max, -P.f_min) * np.sign(u) * np.abs(u) ** 1.5


def _stack(f):
    """A stack of one run whose derivative filter is the identity (the residual is given, not smoothed)."""
    n = f.shape[0]
    run = {"f": f, "dt": DT, "idx": np.arange(n), "rows": np.arange(n), "smooth": lambda y, held=False: y}
    z = np.zeros((n, 6))
    return fx.Stack(nu=z, nu_dot=z, eta=z, f=f, B=P.T, inflow=P.T, f_ref=P.f_ref, surfaces={},
                    runs=[run], p=P, M_A=P.M_A)


def _crb(b0, theta, step=1e-6):
    """Cramer-Rao standard deviations of the shape ``theta`` for a residual b0(theta) + white noise SIGMA on the
    scored DOFs: sigma^2 (J^T J)^-1, J by backward differences (they stay inside an exponent's range [1, 2])."""
    theta = np.asarray(theta, float)
    J = np.stack([(b0(theta) - b0(theta - step * e)) / step for e in np.eye(theta.size)], 1)
    return SIGMA * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))


@pytest.mark.parametrize("k", [2.0, 1.6])
def test_lag_template_recovers_the_rotor_speed_lag(k):
    """Equation-error data of a rotor-speed lag (k = 2, thrust ~ n|n|) or one in between: the Lag template's grid
    and refinement recover T and k within 4 Cramer-Rao standard deviations (the estimate of a well-posed
    least-squares fit is within 4 sigma but for 6e-5 of draws) plus the refinement's tolerance (1e-3)."""
    f = _commands()
    T = 0.4  # s, between the grid's nodes (0.3, 0.45)

    def b0(theta):
        return ((pfx.first_order_lag(f, DT, theta[0], thrust_exponent=theta[1]) - f) @ P.T.T)[:, DOFS].ravel()

    r = (pfx.first_order_lag(f, DT, T, thrust_exponent=k) - f) @ P.T.T
    r = r + SIGMA * np.random.default_rng(1).standard_normal(r.shape)
    fit = Attributor(_stack(f), r, DOFS, fx.catalogue()).best_shape("thruster_lag")
    T_fit, k_fit = fit.shapes["thruster_lag"]
    sd = _crb(b0, (T, k))
    assert abs(T_fit - T) <= 4 * sd[0] + 1e-3
    assert abs(k_fit - k) <= 4 * sd[1] + 1e-3
    assert fit.params["thruster_lag"] == {"T_lag_s": T_fit, "thrust_exponent": k_fit}  # as a model file names them


def _deadband_residual(f, w, p, c):
    effect = (pfx.PlantEffect("thruster_deadband", {"width_fraction": w, "shift": c, "command_exponent": p}),)
    f_act = np.stack(pfx.static_thrust(pfx.NUMPY, list(f.T), effect, P.f_ref, P.capacities), -1)
    return (f_act - f) @ P.T.T


def test_deadband_design_is_the_plant_map():
    """b0 + A shift of the template is what the plant's deadband does to the wrench, for any exponent."""
    f = _commands(600)
    for w, p, c in ((0.1, 1.0, 1.0), (0.25, 2.0, 0.6), (0.3, 1.4, 0.2)):
        d = fx.catalogue()["thruster_deadband"].design(_stack(f), (w, p))
        assert d.names == ("shift",)
        np.testing.assert_allclose(d.b0 + d.A[..., 0] * c, _deadband_residual(f, w, p, c), rtol=1e-12, atol=1e-9)


def test_deadband_template_at_p2_is_the_truth_generators_pwm_deadband():
    """The truth generator's deadband (tests/udrobot_ctrl/gap/truth.py: a deadband delta of the PWM-like command,
    each direction's command normalised by its capacity, thrust ~ command^2 rescaled to full thrust at full
    command) is the plant's deadband at p = 2, shift 1, in both directions."""
    delta = 0.22
    truth = Truth(effects={"thruster_deadband": {"delta": delta}})
    assert np.all(truth.fmax != truth.frev)  # an asymmetric thruster: the reverse normalisation matters
    fc = np.linspace(-1.0, 1.0, 201)[:, None] * np.where(np.linspace(-1.0, 1.0, 201)[:, None] >= 0, truth.fmax,
                                                          truth.frev)
    true, _ = truth.thrust(fc, np.zeros_like(fc), np.zeros((fc.shape[0], 12)), DT)
    effect = (pfx.PlantEffect("thruster_deadband", {"width_fraction": delta, "shift": 1.0, "command_exponent": 2.0}),)
    ours = np.stack(pfx.static_thrust(pfx.NUMPY, list(fc.T), effect, P.f_ref, P.capacities), -1)
    np.testing.assert_allclose(ours, true, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("w, p, c", [(0.25, 2.0, 1.0), (0.15, 1.5, 0.7)])
def test_deadband_template_recovers_the_command_domain_deadband(w, p, c):
    """Equation-error data of a command-domain deadband: grid and refinement recover the width and exponent, and
    the least-squares shift, within 4 Cramer-Rao standard deviations plus the refinement's tolerance (1e-3)."""
    f = _commands()
    r = _deadband_residual(f, w, p, c) + SIGMA * np.random.default_rng(2).standard_normal((f.shape[0], 6))
    fit = Attributor(_stack(f), r, DOFS, fx.catalogue()).best_shape("thruster_deadband")
    got = fit.params["thruster_deadband"]

    def b0(theta):
        return _deadband_residual(f, theta[0], theta[1], theta[2])[:, DOFS].ravel()
    sd = _crb(b0, (w, p, c))
    assert abs(got["width_fraction"] - w) <= 4 * sd[0] + 1e-3
    assert abs(got["command_exponent"] - p) <= 4 * sd[1] + 1e-3
    assert abs(got["shift"] - c) <= 4 * sd[2] + 1e-3


T200 = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "t200" / "t200_performance_tidy.csv"


def _power_law_beyond_deadband(offset_us, thrust_N, span_us=150.0):
    """(d, p) of |thrust| = a (offset - d)^p fitted over the measured nonzero thrust up to ``span_us`` of PWM offset."""
    keep = (offset_us > 0) & (thrust_N > 0) & (offset_us <= span_us)
    o, t = offset_us[keep], thrust_N[keep]
    (_, d, p), _ = curve_fit(lambda x, a, d, p: a * np.clip(x - d, 0.0, None) ** p, o, t, p0=(1e-3, 20.0, 2.0),
                             maxfev=20000)
    return d, p


@pytest.mark.skipif(not T200.exists(), reason="../shared/data/t200 not available")
def test_t200_deadband_and_thrust_exponent_lie_inside_the_templates_range():
    """Blue Robotics' T200 bollard data (10-20 V, both directions; ../shared/data/t200/PROVENANCE.md): beyond the
    ESC's deadband (fitted: 20-27 us of the +-400 us PWM range) the thrust grows as the offset^p with p = 1.1-1.6
    near it -- inside the command exponent's range [1, 2] and the width's bound 0.35."""
    volts, pwm, thrust = read_t200_csv(T200)
    (_, w_hi), (p_lo, p_hi) = fx.catalogue()["thruster_deadband"].shape_bounds
    exponents = []
    for v in np.unique(volts):
        for sign in (1.0, -1.0):
            at = volts == v
            d, p = _power_law_beyond_deadband(sign * (pwm[at] - 1500.0), sign * thrust[at])
            assert 15.0 < d < 30.0 and d / 400.0 < w_hi, (v, sign, d)
            exponents.append(p)
    assert p_lo <= min(exponents) and max(exponents) <= p_hi, exponents
    assert max(exponents) < 1.8  # not the square law often assumed: the data pick the exponent, not the template
