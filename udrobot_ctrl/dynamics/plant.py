"""6-DOF Fossen plant, numpy implementation (vectorised over leading batch axes).

    eta_dot = J(eta) nu                                   (Fossen 2021, eq. 2.40)
    (M_RB + M_A) nu_dot + C_RB(nu) nu + C_A(nu) nu + D_L nu + D_n(nu) nu + g(eta) = tau

State order ``x y z phi theta psi u v w p q r`` (NED position, ZYX Euler angles, body velocities).
The casadi twin is :mod:`udrobot_ctrl.dynamics.plant_casadi`; a test holds both equal to 1e-9.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.vehicle import Vehicle

#: V, thruster supply assumed when a vehicle states none (UDrobot: Cely 2019 sec. 3.1 nominal 12 V).
DEFAULT_SUPPLY_VOLTAGE = 12.0


class SingularMassMatrixError(ValueError):
    """The total mass matrix M_RB + M_A is not symmetric positive definite."""


def skew(a):
    """Skew-symmetric matrix S(a) with S(a) b = a x b (works on (..., 3))."""
    a = np.asarray(a, dtype=float)
    z = np.zeros_like(a[..., 0])
    return np.stack([
        np.stack([z, -a[..., 2], a[..., 1]], -1),
        np.stack([a[..., 2], z, -a[..., 0]], -1),
        np.stack([-a[..., 1], a[..., 0], z], -1),
    ], -2)


def rigid_body_mass(mass, inertia_cg, r_g):
    """M_RB about CO (Fossen 2021 eq. 3.44): [[m I, -m S(r_g)], [m S(r_g), I_g - m S(r_g)^2]].

    Parameters
    ----------
    mass : float
        kg.
    inertia_cg : (3, 3) array_like
        Inertia about the CG, kg m^2.
    r_g : (3,) array_like
        CG position relative to CO, m.
    """
    S = skew(r_g)
    M = np.zeros((6, 6))
    M[:3, :3] = mass * np.eye(3)
    M[:3, 3:] = -mass * S
    M[3:, :3] = mass * S
    M[3:, 3:] = np.asarray(inertia_cg, float) - mass * S @ S
    return M


def coriolis_centripetal(M, nu):
    """C(nu) nu for a symmetric 6x6 inertia M, from Kirchhoff's equations (Fossen 2021 eqs. 3.46, 6.43).

    With a = M11 v + M12 w and b = M21 v + M22 w: C(nu) nu = [w x a ; v x a + w x b].
    Valid for M_RB, M_A and their sum. ``nu`` has shape (..., 6); returns N, N m.
    """
    nu = np.asarray(nu, dtype=float)
    h = nu @ M.T
    v, w = nu[..., :3], nu[..., 3:]
    a, b = h[..., :3], h[..., 3:]
    return np.concatenate([np.cross(w, a), np.cross(v, a) + np.cross(w, b)], axis=-1)


def restoring_forces(eta, weight, buoyancy, r_g, r_b):
    """g(eta) for a submerged vehicle (Fossen 2021 eq. 4.6), N and N m.

    Parameters
    ----------
    eta : (..., 6) array_like
        Position (m) and ZYX Euler angles (rad); only phi and theta enter.
    weight, buoyancy : float
        W and B, N.
    r_g, r_b : (3,) array_like
        CG and CB relative to CO, m.
    """
    eta = np.asarray(eta, dtype=float)
    W, B = weight, buoyancy
    xg, yg, zg = r_g
    xb, yb, zb = r_b
    sphi, cphi = np.sin(eta[..., 3]), np.cos(eta[..., 3])
    sth, cth = np.sin(eta[..., 4]), np.cos(eta[..., 4])
    return np.stack([
        (W - B) * sth,
        -(W - B) * cth * sphi,
        -(W - B) * cth * cphi,
        -(yg * W - yb * B) * cth * cphi + (zg * W - zb * B) * cth * sphi,
        (zg * W - zb * B) * sth + (xg * W - xb * B) * cth * cphi,
        -(xg * W - xb * B) * cth * sphi - (yg * W - yb * B) * sth,
    ], axis=-1)


def rotation_zyx(phi, theta, psi):
    """Body-to-NED rotation R(Theta) for ZYX Euler angles (rad); broadcasts, returns (..., 3, 3)."""
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    cp, sp = np.cos(psi), np.sin(psi)
    return np.stack([
        np.stack([cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st], -1),
        np.stack([sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf], -1),
        np.stack([-st, ct * sf, ct * cf], -1),
    ], -2)


def kinematics(eta, nu):
    """eta_dot = J(eta) nu (Fossen 2021 eq. 2.40); singular at theta = +-pi/2.

    Returns (..., 6): NED velocity (m/s) and Euler-angle rates (rad/s).
    """
    eta = np.asarray(eta, dtype=float)
    nu = np.asarray(nu, dtype=float)
    phi, theta, psi = eta[..., 3], eta[..., 4], eta[..., 5]
    R = rotation_zyx(phi, theta, psi)
    pos_dot = np.einsum("...ij,...j->...i", R, nu[..., :3])
    p, q, r = nu[..., 3], nu[..., 4], nu[..., 5]
    sf, cf = np.sin(phi), np.cos(phi)
    ct, tt = np.cos(theta), np.tan(theta)
    ang_dot = np.stack([p + sf * tt * q + cf * tt * r, cf * q - sf * r, sf / ct * q + cf / ct * r], -1)
    return np.concatenate([pos_dot, ang_dot], axis=-1)


def thruster_matrix(thrusters):
    """Thruster configuration matrix T (6 x n): tau = T f, columns [d_i ; r_i x d_i]."""
    cols = []
    for t in thrusters:
        d = np.asarray(t.direction, float)
        d = d / np.linalg.norm(d)
        cols.append(np.concatenate([d, np.cross(np.asarray(t.position, float), d)]))
    return np.array(cols).T if cols else np.zeros((6, 0))


def thrust_limits(thrusters):
    """Per-thruster limits (lower, upper) in N: [-max_reverse_N, max_forward_N]."""
    lo = np.array([-t.max_reverse_N for t in thrusters], float)
    hi = np.array([t.max_forward_N for t in thrusters], float)
    return lo, hi


@dataclass(frozen=True)
class PlantParameters:
    """Precomputed numeric arrays of a vehicle for fast evaluation."""

    M: np.ndarray
    M_inv: np.ndarray
    D_L: np.ndarray
    Q: np.ndarray
    weight: float
    buoyancy: float
    r_g: np.ndarray
    r_b: np.ndarray
    T: np.ndarray
    f_min: np.ndarray
    f_max: np.ndarray
    name: str = ""
    M_A: np.ndarray | None = None
    supply_voltage: float = DEFAULT_SUPPLY_VOLTAGE  # V, thruster supply for pwm -> thrust (the vehicle's own)


def plant_parameters(vehicle: Vehicle) -> PlantParameters:
    """Assemble M = M_RB + M_A and the other arrays; checks M is symmetric positive definite.

    Raises
    ------
    SingularMassMatrixError
        If M is not symmetric or not positive definite (naming the model).
    """
    M = rigid_body_mass(vehicle.mass, vehicle.inertia_cg, vehicle.r_g) + np.asarray(vehicle.added_mass, float)
    if not np.allclose(M, M.T, atol=1e-9 * max(1.0, np.abs(M).max())):
        raise SingularMassMatrixError(f"model {vehicle.name!r}: M_RB + M_A is not symmetric")
    eig = np.linalg.eigvalsh(0.5 * (M + M.T))
    if eig.min() <= 1e-9 * eig.max():
        raise SingularMassMatrixError(
            f"model {vehicle.name!r}: M_RB + M_A is not positive definite (smallest eigenvalue {eig.min():.3g})"
        )
    lo, hi = thrust_limits(vehicle.thrusters)
    return PlantParameters(
        M=M, M_inv=np.linalg.inv(M), D_L=np.asarray(vehicle.linear_damping, float),
        Q=np.asarray(vehicle.quadratic_damping, float), weight=vehicle.weight, buoyancy=vehicle.buoyancy,
        r_g=np.asarray(vehicle.r_g, float), r_b=np.asarray(vehicle.r_b, float),
        T=thruster_matrix(vehicle.thrusters), f_min=lo, f_max=hi, name=vehicle.name,
        M_A=np.asarray(vehicle.added_mass, float),
        supply_voltage=float((vehicle.extras or {}).get("voltage", DEFAULT_SUPPLY_VOLTAGE)),
    )


def generalized_forces(x, p: PlantParameters):
    """Sum of C(nu) nu + D(nu) nu + g(eta) for state x (..., 12); N, N m."""
    x = np.asarray(x, dtype=float)
    nu = x[..., 6:]
    return (coriolis_centripetal(p.M, nu) + nu @ p.D_L.T + (np.abs(nu) * nu) @ p.Q.T
            + restoring_forces(x[..., :6], p.weight, p.buoyancy, p.r_g, p.r_b))


def state_derivative(x, tau, p: PlantParameters):
    """x_dot = f(x, tau) for state (..., 12) and body wrench tau (..., 6) in N, N m."""
    x = np.asarray(x, dtype=float)
    nu_dot = (np.asarray(tau, float) - generalized_forces(x, p)) @ p.M_inv.T
    return np.concatenate([kinematics(x[..., :6], x[..., 6:]), nu_dot], axis=-1)


def thrust_to_wrench(f, p: PlantParameters, clip=True):
    """Body wrench tau = T sat(f) (N, N m) from thrusts f (..., n) in N; clipped to each thruster's limits."""
    f = np.asarray(f, dtype=float)
    if clip:
        f = np.clip(f, p.f_min, p.f_max)
    return f @ p.T.T
