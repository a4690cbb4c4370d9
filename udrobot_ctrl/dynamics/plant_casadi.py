"""6-DOF Fossen plant as casadi expressions: the equations of :mod:`udrobot_ctrl.dynamics.equations`
built with casadi's elementary functions, from the same :class:`~udrobot_ctrl.dynamics.plant.PlantParameters`
as the numpy plant. Used for linearisation (exact Jacobians), MPC, EKF Jacobians and compiled rollouts.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from udrobot_ctrl.dynamics import effects as fx
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


def effect_forces(x, p: PlantParameters):
    """Symbolic generalised force of the model's force effects (twin of :func:`plant.effect_forces`)."""
    eta, nu = x[0:6], x[6:12]
    total = ca.DM.zeros(6)
    nu_r = fx.relative_velocity(fx.CASADI, eta, nu, p.effects)
    if nu_r is not nu:
        M_A, D_L, Q = _dm(p.M_A), _dm(p.D_L), _dm(p.Q)
        total = (ca.vertcat(*EQUATIONS.damping(D_L, Q, nu)) + ca.vertcat(*EQUATIONS.coriolis(M_A, nu))
                 - ca.vertcat(*EQUATIONS.damping(D_L, Q, nu_r)) - ca.vertcat(*EQUATIONS.coriolis(M_A, nu_r)))
    ext = fx.external_force(fx.CASADI, eta, nu, p.effects)
    return total if ext is None else total + ca.vertcat(*ext)


def generalized_forces(x, p: PlantParameters):
    """Symbolic C(nu) nu + D_L nu + D_n(nu) nu + g(eta), minus the force effects of the model."""
    M, _, D_L, Q, W, B, r_g, r_b = parameter_arguments(p)
    F = ca.vertcat(*EQUATIONS.generalized_forces(x, M, D_L, Q, W, B, r_g, r_b))
    return F - effect_forces(x, p) if p.effects else F


def state_derivative(x, tau, p: PlantParameters):
    """Symbolic x_dot = f(x, tau)."""
    if not p.effects:
        return ca.vertcat(*EQUATIONS.state_derivative(x, tau, *parameter_arguments(p)))
    rhs = tau - generalized_forces(x, p)
    dM = fx.added_mass_increment(fx.CASADI, x[0:6], x[6:12], p.effects)
    nu_dot = _dm(p.M_inv) @ rhs if dM is None else ca.solve(_dm(p.M) + ca.vertcat(*[ca.horzcat(*r) for r in dM]), rhs)
    return ca.vertcat(ca.vertcat(*EQUATIONS.kinematics(x[0:6], x[6:12])), nu_dot)


def delivered_wrench(x, f, p: PlantParameters, static_maps: bool = True):
    """Symbolic body wrench of commanded, clipped thrusts ``f`` after the model's thrust effects (static maps unless
    ``static_maps`` is False, then inflow loss); twin of ``plant.delivered_wrench(x, static_thrust(f))``."""
    fe = fx.thrust_effects(p.effects)
    comps = [f[i] for i in range(f.shape[0])]
    if static_maps:
        comps = fx.static_thrust(fx.CASADI, comps, fe, p.f_ref, p.capacities)
    comps = fx.inflow_loss(fx.CASADI, comps, x[6:12], fe, p.T, p.f_ref)
    return _dm(p.T) @ ca.vertcat(*comps)


def require_static(p: PlantParameters, tool: str) -> None:
    """Refuse a model whose effects ``tool`` cannot represent (a thruster lag needs actuator states)."""
    if fx.lag_time_constant(p.effects) is not None:
        raise ValueError(f"model {p.name!r} has a thruster_lag effect: {tool} works on the static plant (no "
                         f"actuator states) and does not represent it; remove the effect or simulate instead")


def dynamics_function(p: PlantParameters, inputs: str = "tau", name: str = "f",
                      actuators: str = "command") -> ca.Function:
    """casadi Function f(x[12], u) -> x_dot[12].

    Parameters
    ----------
    inputs : {'tau', 'thrust'}
        ``tau``: u is the body wrench (6). ``thrust``: u is the n thruster forces (N), mapped by the
        thruster matrix without saturation (limits belong in the controller's constraints), after the model's
        thrust effects.
    actuators : {'command', 'delivered'}
        ``command``: u is the commanded thrust, the static thrust maps act inside (a thruster lag is refused);
        ``delivered``: u is the thrust after the static maps and the lag (a simulator holding the lag's state),
        only the state-dependent inflow loss acts inside.

    Raises
    ------
    ValueError
        If the model has a thruster lag and ``actuators='command'``, or thrust effects with ``inputs='tau'``.
    """
    if actuators not in ("command", "delivered"):
        raise ValueError(f"actuators must be 'command' or 'delivered', got {actuators!r}")
    if actuators == "command":
        require_static(p, "the casadi plant")
    x = ca.SX.sym("x", 12)
    if inputs == "tau":
        if fx.thrust_effects(p.effects):
            raise ValueError(f"model {p.name!r} has thrust effects "
                             f"({', '.join(e.name for e in fx.thrust_effects(p.effects))}): they act on each "
                             f"thruster's force, so the plant takes thrusts (inputs='thrust'), not a wrench")
        u = ca.SX.sym("tau", 6)
        tau = u
    elif inputs == "thrust":
        u = ca.SX.sym("f", p.T.shape[1])
        tau = delivered_wrench(x, u, p, static_maps=actuators == "command") if p.effects else _dm(p.T) @ u
    else:
        raise ValueError(f"inputs must be 'tau' or 'thrust', got {inputs!r}")
    return ca.Function(name, [x, u], [state_derivative(x, tau, p)], ["x", "u"], ["xdot"])


def rk4_step_function(p: PlantParameters, dt: float, inputs: str = "tau", name: str = "F",
                      actuators: str = "command") -> ca.Function:
    """One RK4 step x_next = F(x, u) with zero-order hold on u over ``dt`` seconds (``actuators``: see
    :func:`dynamics_function`)."""
    f = dynamics_function(p, inputs, actuators=actuators)
    x = ca.SX.sym("x", 12)
    u = ca.SX.sym("u", f.size1_in(1))
    x_next = integrators.rk4_step(lambda _t, xx: f(xx, u), 0.0, x, dt)
    return ca.Function(name, [x, u], [x_next], ["x", "u"], ["x_next"])
