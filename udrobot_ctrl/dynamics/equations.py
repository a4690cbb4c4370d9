"""The 6-DOF equations of motion, written once for every backend.

    eta_dot = J(eta) nu                                                  (Fossen 2021, eq. 2.40)
    M nu_dot + C(nu) nu + D_L nu + D_n(nu) nu + g(eta) = tau             (Fossen 2021, eq. 6.42)

with M = M_RB + M_A, C(nu) nu from Kirchhoff's equations for the symmetric M (eqs. 3.46, 6.43),
D_n(nu)_ij = Q_ij |nu_j| and g(eta) the restoring forces of a submerged vehicle (eq. 4.6).
State ``x = (x, y, z, phi, theta, psi, u, v, w, p, q, r)``: NED position (m), ZYX Euler angles (rad),
body velocities (m/s, rad/s). Wrench ``tau`` in N and N m about the body origin CO.

:func:`equations` builds the functions for one backend from the same source text: they use only
``+ - * /``, ``abs``, element access ``a[i]`` / ``M[i, j]`` and the ``sin``, ``cos``, ``tan`` they are given,
and return tuples of components. So

* ``equations(np.sin, np.cos, np.tan)`` evaluates on floats or on arrays of any batch shape (the
  numpy plant, :mod:`udrobot_ctrl.dynamics.plant`);
* ``equations(ca.sin, ca.cos, ca.tan)`` builds casadi expressions, with the parameters either numbers
  or symbols (:mod:`udrobot_ctrl.dynamics.plant_casadi`, linearisation, MPC, EKF, batched rollouts);
* ``equations(np.sin, np.cos, np.tan, jit=numba.njit(cache=True))`` compiles to machine code (the
  RK4 kernels of :mod:`udrobot_ctrl.dynamics.sim_kernels`).

Adding a term to the dynamics is one edit here and one test (the backends are held equal in
``tests/udrobot_ctrl/dynamics/test_plant.py``).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


def _no_jit(f):
    return f


@dataclass(frozen=True)
class Equations:
    """The equations of motion of one backend (see :func:`equations`); every function returns a tuple.

    Attributes
    ----------
    rotation : (phi, theta, psi) -> 9 components of R(Theta), body to NED, row-major.
    kinematics : (eta, nu) -> 6 components of eta_dot = J(eta) nu (m/s, rad/s); singular at theta = +-pi/2.
    coriolis : (M, nu) -> 6 components of C(nu) nu for a symmetric inertia M (N, N m).
    damping : (D_L, Q, nu) -> 6 components of D_L nu + D_n(nu) nu (N, N m).
    restoring : (phi, theta, W, B, r_g, r_b) -> 6 components of g(eta) (N, N m).
    generalized_forces : (x, M, D_L, Q, W, B, r_g, r_b) -> 6 components of C nu + D nu + g.
    state_derivative : (x, tau, M, M_inv, D_L, Q, W, B, r_g, r_b) -> 12 components of x_dot.
    """

    rotation: Callable
    kinematics: Callable
    coriolis: Callable
    damping: Callable
    restoring: Callable
    generalized_forces: Callable
    state_derivative: Callable


def equations(sin, cos, tan, jit=_no_jit) -> Equations:
    """The equations of motion built with the given ``sin``, ``cos``, ``tan`` (and compiled with ``jit``).

    Parameters
    ----------
    sin, cos, tan : callable
        Elementary functions of the backend (``numpy``'s, ``casadi``'s).
    jit : callable, optional
        Decorator applied to every function (``numba.njit(cache=True)`` for compiled kernels).

    Returns
    -------
    Equations
        Functions of components: vectors are anything indexable by position (a 1-D array, a casadi
        column, or an array whose *first* axis is the component and the others a batch), matrices
        anything indexable by ``M[i, j]`` (a (6, 6) array, a casadi matrix, or (6, 6, ...) per-vehicle).
    """

    @jit
    def rotation(phi, theta, psi):
        cf, sf = cos(phi), sin(phi)
        ct, st = cos(theta), sin(theta)
        cp, sp = cos(psi), sin(psi)
        return (cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st,
                sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf,
                -st, ct * sf, ct * cf)

    @jit
    def kinematics(eta, nu):
        R = rotation(eta[3], eta[4], eta[5])
        u, v, w, p, q, r = nu[0], nu[1], nu[2], nu[3], nu[4], nu[5]
        sf, cf = sin(eta[3]), cos(eta[3])
        ct, tt = cos(eta[4]), tan(eta[4])
        return (R[0] * u + R[1] * v + R[2] * w,
                R[3] * u + R[4] * v + R[5] * w,
                R[6] * u + R[7] * v + R[8] * w,
                p + sf * tt * q + cf * tt * r,
                cf * q - sf * r,
                sf / ct * q + cf / ct * r)

    @jit
    def row_times(M, i, v):
        acc = M[i, 0] * v[0]
        for j in range(1, 6):
            acc = acc + M[i, j] * v[j]
        return acc

    @jit
    def coriolis(M, nu):
        # Kirchhoff: with a = M11 v + M12 w and b = M21 v + M22 w, C(nu) nu = [w x a ; v x a + w x b]
        a0, a1, a2 = row_times(M, 0, nu), row_times(M, 1, nu), row_times(M, 2, nu)
        b0, b1, b2 = row_times(M, 3, nu), row_times(M, 4, nu), row_times(M, 5, nu)
        u, v, w, p, q, r = nu[0], nu[1], nu[2], nu[3], nu[4], nu[5]
        return (q * a2 - r * a1,
                r * a0 - p * a2,
                p * a1 - q * a0,
                v * a2 - w * a1 + q * b2 - r * b1,
                w * a0 - u * a2 + r * b0 - p * b2,
                u * a1 - v * a0 + p * b1 - q * b0)

    @jit
    def damping_row(D_L, Q, i, nu):
        acc = D_L[i, 0] * nu[0] + Q[i, 0] * abs(nu[0]) * nu[0]
        for j in range(1, 6):
            acc = acc + D_L[i, j] * nu[j] + Q[i, j] * abs(nu[j]) * nu[j]
        return acc

    @jit
    def damping(D_L, Q, nu):
        return (damping_row(D_L, Q, 0, nu), damping_row(D_L, Q, 1, nu), damping_row(D_L, Q, 2, nu),
                damping_row(D_L, Q, 3, nu), damping_row(D_L, Q, 4, nu), damping_row(D_L, Q, 5, nu))

    @jit
    def restoring(phi, theta, W, B, r_g, r_b):
        sf, cf = sin(phi), cos(phi)
        st, ct = sin(theta), cos(theta)
        dw = W - B
        mx = r_g[0] * W - r_b[0] * B
        my = r_g[1] * W - r_b[1] * B
        mz = r_g[2] * W - r_b[2] * B
        return (dw * st,
                -dw * ct * sf,
                -dw * ct * cf,
                -my * ct * cf + mz * ct * sf,
                mz * st + mx * ct * cf,
                -mx * ct * sf - my * st)

    @jit
    def generalized_forces(x, M, D_L, Q, W, B, r_g, r_b):
        nu = x[6:12]
        c = coriolis(M, nu)
        d = damping(D_L, Q, nu)
        g = restoring(x[3], x[4], W, B, r_g, r_b)
        return (c[0] + d[0] + g[0], c[1] + d[1] + g[1], c[2] + d[2] + g[2],
                c[3] + d[3] + g[3], c[4] + d[4] + g[4], c[5] + d[5] + g[5])

    @jit
    def state_derivative(x, tau, M, M_inv, D_L, Q, W, B, r_g, r_b):
        F = generalized_forces(x, M, D_L, Q, W, B, r_g, r_b)
        rhs = (tau[0] - F[0], tau[1] - F[1], tau[2] - F[2], tau[3] - F[3], tau[4] - F[4], tau[5] - F[5])
        k = kinematics(x[0:6], x[6:12])
        return (k[0], k[1], k[2], k[3], k[4], k[5],
                row_times(M_inv, 0, rhs), row_times(M_inv, 1, rhs), row_times(M_inv, 2, rhs),
                row_times(M_inv, 3, rhs), row_times(M_inv, 4, rhs), row_times(M_inv, 5, rhs))

    return Equations(rotation=rotation, kinematics=kinematics, coriolis=coriolis, damping=damping,
                     restoring=restoring, generalized_forces=generalized_forces, state_derivative=state_derivative)
