"""6-DOF Fossen plant, casadi symbolic twin of :mod:`udrobot_ctrl.dynamics.plant`.

Written independently from the numpy version (explicit component formulas rather than numpy
broadcasting) from the same :class:`~udrobot_ctrl.dynamics.plant.PlantParameters`; a test holds the two
equal to 1e-9. Used for linearisation (exact Jacobians), MPC and EKF Jacobians.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from udrobot_ctrl.dynamics.plant import PlantParameters


def _cross(a, b):
    return ca.vertcat(a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _dm(a):
    return ca.DM(np.asarray(a, dtype=float))


def kinematics(eta, nu):
    """Symbolic eta_dot = J(eta) nu (ZYX Euler angles)."""
    phi, theta, psi = eta[3], eta[4], eta[5]
    cf, sf, ct, st, cp, sp = ca.cos(phi), ca.sin(phi), ca.cos(theta), ca.sin(theta), ca.cos(psi), ca.sin(psi)
    R = ca.vertcat(
        ca.horzcat(cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st),
        ca.horzcat(sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf),
        ca.horzcat(-st, ct * sf, ct * cf),
    )
    p, q, r = nu[3], nu[4], nu[5]
    ang = ca.vertcat(p + sf * st / ct * q + cf * st / ct * r, cf * q - sf * r, sf / ct * q + cf / ct * r)
    return ca.vertcat(R @ nu[:3], ang)


def restoring_forces(eta, p: PlantParameters):
    """Symbolic g(eta) (Fossen 2021 eq. 4.6)."""
    W, B = p.weight, p.buoyancy
    xg, yg, zg = (float(v) for v in p.r_g)
    xb, yb, zb = (float(v) for v in p.r_b)
    phi, theta = eta[3], eta[4]
    sf, cf, st, ct = ca.sin(phi), ca.cos(phi), ca.sin(theta), ca.cos(theta)
    return ca.vertcat(
        (W - B) * st, -(W - B) * ct * sf, -(W - B) * ct * cf,
        -(yg * W - yb * B) * ct * cf + (zg * W - zb * B) * ct * sf,
        (zg * W - zb * B) * st + (xg * W - xb * B) * ct * cf,
        -(xg * W - xb * B) * ct * sf - (yg * W - yb * B) * st,
    )


def generalized_forces(x, p: PlantParameters):
    """Symbolic C(nu) nu + D_L nu + D_n(nu) nu + g(eta)."""
    nu = x[6:12]
    h = _dm(p.M) @ nu
    v, w, a, b = nu[:3], nu[3:], h[:3], h[3:]
    cor = ca.vertcat(_cross(w, a), _cross(v, a) + _cross(w, b))
    damp = _dm(p.D_L) @ nu + _dm(p.Q) @ (ca.fabs(nu) * nu)
    return cor + damp + restoring_forces(x[:6], p)


def state_derivative(x, tau, p: PlantParameters):
    """Symbolic x_dot = f(x, tau)."""
    nu_dot = ca.solve(_dm(p.M), tau - generalized_forces(x, p))
    return ca.vertcat(kinematics(x[:6], x[6:12]), nu_dot)


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
    k1 = f(x, u)
    k2 = f(x + dt / 2 * k1, u)
    k3 = f(x + dt / 2 * k2, u)
    k4 = f(x + dt * k3, u)
    return ca.Function(name, [x, u], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)], ["x", "u"], ["x_next"])
