"""Many perturbed vehicles simulated at once: the fast path of sensitivity sweeps.

:mod:`udrobot_ctrl.dynamics.plant` is batch-aware over states but holds one set of matrices; a sensitivity chunk
needs one vehicle per sample. :class:`BatchPlant` stacks M, M^-1, D_L and Q over vehicles ``(N, 6, 6)``
(restoring terms and thrusters must be shared: the studies perturb hydrodynamic coefficients only) and
:func:`simulate_batch` integrates all of them in one vectorised RK4 loop with the same ZOH controller
convention as :func:`udrobot_ctrl.dynamics.sim.simulate`. A test holds it equal to the single-vehicle plant.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.dynamics.plant import kinematics, plant_parameters, restoring_forces
from udrobot_ctrl.dynamics.sim import SimResult


@dataclass(frozen=True)
class BatchPlant:
    """Stacked plant arrays of N vehicles (SI units, see :class:`udrobot_ctrl.dynamics.plant.PlantParameters`)."""

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

    @property
    def size(self) -> int:
        return self.M.shape[0]


def batch_plant(vehicles) -> BatchPlant:
    """Stack the plant parameters of ``vehicles`` (a sequence of Vehicle or PlantParameters).

    Raises
    ------
    ValueError
        If the vehicles differ in weight, buoyancy, CG/CB or thrusters (not batchable).
    """
    ps = [v if hasattr(v, "M_inv") else plant_parameters(v) for v in vehicles]
    if not ps:
        raise ValueError("batch_plant needs at least one vehicle")
    p0 = ps[0]
    for k, p in enumerate(ps[1:], start=1):
        for name in ("weight", "buoyancy", "r_g", "r_b", "T", "f_min", "f_max"):
            if not np.allclose(getattr(p, name), getattr(p0, name)):
                raise ValueError(f"vehicle {k} differs from vehicle 0 in {name}; only hydrodynamic coefficients "
                                 "may vary within a batch")
    return BatchPlant(
        M=np.stack([p.M for p in ps]), M_inv=np.stack([p.M_inv for p in ps]), D_L=np.stack([p.D_L for p in ps]),
        Q=np.stack([p.Q for p in ps]), weight=p0.weight, buoyancy=p0.buoyancy, r_g=p0.r_g, r_b=p0.r_b, T=p0.T,
        f_min=p0.f_min, f_max=p0.f_max)


def _matvec(A, v):
    return np.einsum("nij,nj->ni", A, v)


def state_derivative(x, tau, bp: BatchPlant):
    """x_dot (N, 12) for states x (N, 12) and wrenches tau (N, 6) (N, N m), one vehicle per row."""
    nu = x[:, 6:]
    h = _matvec(bp.M, nu)
    v, w, a, b = nu[:, :3], nu[:, 3:], h[:, :3], h[:, 3:]
    cor = np.concatenate([np.cross(w, a), np.cross(v, a) + np.cross(w, b)], axis=-1)
    forces = (cor + _matvec(bp.D_L, nu) + _matvec(bp.Q, np.abs(nu) * nu)
              + restoring_forces(x[:, :6], bp.weight, bp.buoyancy, bp.r_g, bp.r_b))
    nu_dot = _matvec(bp.M_inv, tau - forces)
    return np.concatenate([kinematics(x[:, :6], nu), nu_dot], axis=-1)


def rk4_step(bp: BatchPlant, x, tau, dt):
    k1 = state_derivative(x, tau, bp)
    k2 = state_derivative(x + dt / 2 * k1, tau, bp)
    k3 = state_derivative(x + dt / 2 * k2, tau, bp)
    k4 = state_derivative(x + dt * k3, tau, bp)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def simulate_batch(bp: BatchPlant, x0, t_final: float, controller, dt: float = 0.02,
                   control_dt: float | None = None) -> SimResult:
    """Closed-loop RK4 simulation of the N vehicles of ``bp``.

    Parameters
    ----------
    x0 : (12,) or (N, 12) array_like
        Initial state(s).
    controller : callable
        ``controller(t, x (N, 12)) -> thrusts (N, n)`` in N; clipped to the thruster limits (ZOH over
        ``control_dt``, default ``dt``).

    Returns
    -------
    SimResult
        ``x`` (n+1, N, 12), ``u`` (n, N, n_thr) commanded, ``tau`` (n, N, 6) applied, ``saturated`` (n, N).
        A vehicle whose state becomes non-finite is frozen (NaN) without stopping the others.
    """
    if dt <= 0 or t_final <= 0:
        raise ValueError(f"dt and t_final must be > 0 (got dt={dt}, t_final={t_final})")
    N = bp.size
    x = np.broadcast_to(np.asarray(x0, float), (N, 12)).copy()
    n = int(round(t_final / dt))
    hold = max(1, int(round((control_dt or dt) / dt)))
    t = np.arange(n + 1) * dt
    xs = np.empty((n + 1, N, 12))
    xs[0] = x
    nthr = bp.T.shape[1]
    us = np.empty((n, N, nthr))
    taus = np.empty((n, N, 6))
    sats = np.empty((n, N), bool)
    u = np.zeros((N, nthr))
    for k in range(n):
        if k % hold == 0:
            u = np.asarray(controller(t[k], x), float).reshape(N, nthr)
        f = np.clip(u, bp.f_min, bp.f_max)
        sats[k] = np.any((u < bp.f_min - 1e-9) | (u > bp.f_max + 1e-9), axis=-1)  # as sim.simulate
        tau = f @ bp.T.T
        x = rk4_step(bp, x, tau, dt)
        bad = ~np.all(np.isfinite(x), axis=-1)
        if bad.any():
            x[bad] = np.nan
        xs[k + 1] = x
        us[k] = u
        taus[k] = tau
    return SimResult(t=t, x=xs, u=us, tau=taus, saturated=sats)
