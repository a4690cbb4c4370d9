"""6-DOF Fossen plant as casadi expressions: the equations of :mod:`udrobot_ctrl.dynamics.equations`
built with casadi's elementary functions, from the same :class:`~udrobot_ctrl.dynamics.plant.PlantParameters`
as the numpy plant. Used for linearisation (exact Jacobians), MPC, EKF Jacobians and compiled rollouts.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from udrobot_ctrl.dynamics import integrators
from udrobot_ctrl.dynamics.equations import equations
from udrobot_ctrl.dynamics.plant import PlantParameters

EQUATIONS = equations(ca.sin, ca.cos, ca.tan)


def _dm(a):
    return ca.DM(np.asarray(a, dtype=float))


def kinematics(eta, nu):
    """Symbolic eta_dot = J(eta) nu (ZYX Euler angles)."""
    return ca.vertcat(*EQUATIONS.kinematics(eta, nu))


def restoring_forces(eta, p: PlantParameters):
    """Symbolic g(eta) (Fossen 2021 eq. 4.6)."""
    return ca.vertcat(*EQUATIONS.restoring(eta[3], eta[4], float(p.weight), float(p.buoyancy), _dm(p.r_g), _dm(p.r_b)))


def parameter_arguments(p: PlantParameters) -> tuple:
    """(M, M_inv, D_L, Q, W, B, r_g, r_b) of ``p`` as casadi constants, in the order of the equations."""
    return (_dm(p.M), _dm(p.M_inv), _dm(p.D_L), _dm(p.Q), float(p.weight), float(p.buoyancy), _dm(p.r_g),
            _dm(p.r_b))


def generalized_forces(x, p: PlantParameters):
    """Symbolic C(nu) nu + D_L nu + D_n(nu) nu + g(eta)."""
    M, _, D_L, Q, W, B, r_g, r_b = parameter_arguments(p)
    return ca.vertcat(*EQUATIONS.generalized_forces(x, M, D_L, Q, W, B, r_g, r_b))


def state_derivative(x, tau, p: PlantParameters):
    """Symbolic x_dot = f(x, tau)."""
    return ca.vertcat(*EQUATIONS.state_derivative(x, tau, *parameter_arguments(p)))


def dynamics_function(p: PlantParameters, inputs: str = "tau", name: str = "f") -> ca.Function:
    """casadi Function f(x[12], u) -> x_dot[12].

    Parameters
    ----------
    inputs : {'tau', 'thrust'}
        ``tau``: u is the body wrench (6). ``thrust``: u is the n thruster forces (N), mapped by the
        thruster matrix without saturation (limits belong in the controller's constraints).
    """
    x = ca.SX.sym("x", 12)
    if inputs == "tau":
        u = ca.SX.sym("tau", 6)
        tau = u
    elif inputs == "thrust":
        u = ca.SX.sym("f", p.T.shape[1])
        tau = _dm(p.T) @ u
    else:
        raise ValueError(f"inputs must be 'tau' or 'thrust', got {inputs!r}")
    return ca.Function(name, [x, u], [state_derivative(x, tau, p)], ["x", "u"], ["xdot"])


def rk4_step_function(p: PlantParameters, dt: float, inputs: str = "tau", name: str = "F") -> ca.Function:
    """One RK4 step x_next = F(x, u) with zero-order hold on u over ``dt`` seconds."""
    f = dynamics_function(p, inputs)
    x = ca.SX.sym("x", 12)
    u = ca.SX.sym("u", f.size1_in(1))
    x_next = integrators.rk4_step(lambda _t, xx: f(xx, u), 0.0, x, dt)
    return ca.Function(name, [x, u], [x_next], ["x", "u"], ["x_next"])
