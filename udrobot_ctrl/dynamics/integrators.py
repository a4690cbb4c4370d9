"""Fixed-step integrators shared by every simulation path (numpy arrays and casadi expressions alike).

The numba kernels of :mod:`udrobot_ctrl.dynamics.sim_kernels` keep a compiled copy of the same RK4 step
(numba cannot call back into Python); a test holds them equal.
"""
from __future__ import annotations


def rk4_step(f, t, x, dt, k1=None):
    """One classical Runge-Kutta step of x' = f(t, x) over ``dt`` seconds.

    Parameters
    ----------
    f : callable
        ``f(t, x) -> x_dot``, on numpy arrays (any batch shape) or casadi expressions.
    t : float
        Time at the start of the step, s.
    x : array_like or casadi expression
        State at ``t``.
    dt : float
        Step, s.
    k1 : array_like or casadi expression, optional
        ``f(t, x)`` when the caller has already evaluated it (it is the first stage).

    Returns
    -------
    Same type as ``x``: the state at ``t + dt``.
    """
    k1 = f(t, x) if k1 is None else k1
    k2 = f(t + dt / 2, x + dt / 2 * k1)
    k3 = f(t + dt / 2, x + dt / 2 * k2)
    k4 = f(t + dt, x + dt * k3)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
