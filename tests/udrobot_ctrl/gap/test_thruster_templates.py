"""The thruster templates' shape exponents are recovered by the equation-error fit (search grid and refinement)."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics import effects as pfx
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.gap import effects as fx
from udrobot_ctrl.gap.attribute import Attributor
from udrobot_ctrl.vehicle import load_model

P = plant_parameters(load_model("pendulum:chin"))
DT = 0.02  # s, a 50 Hz log
F_REF = 30.0  # N, the thrusters' capacity
#: equation-error residual noise per DOF (assumed: N and N m, of the order of a smoothed 50 Hz fit's residual)
SIGMA = 2.0
DOFS = np.array([True, False, True, True, False, True])  # X Z K N: the DOFs UDrobot actuates


def _commands(n=3000, seed=0):
    """Thrust commands held for 1 s each, uniform in the normalised command (u^1.5 f_ref): both signs, small and
    large, like a closed-loop pool run's."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, (n // 50 + 1, 4)), 50, axis=0)[:n]
    return F_REF * np.sign(u) * np.abs(u) ** 1.5


def _stack(f):
    """A stack of one run whose derivative filter is the identity (the residual is given, not smoothed)."""
    n = f.shape[0]
    run = {"f": f, "dt": DT, "idx": np.arange(n), "rows": np.arange(n), "smooth": lambda y, held=False: y}
    z = np.zeros((n, 6))
    return fx.Stack(nu=z, nu_dot=z, eta=z, f=f, B=P.T, inflow=P.T, f_ref=np.full(f.shape[1], F_REF), surfaces={},
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
