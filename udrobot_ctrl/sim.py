"""Simulation: fixed-step RK4 (default) and scipy ``solve_ivp``, open or closed loop, single or batch.

Public API (other modules rely on it):

``simulate(model, x0, t_final, controller=None, inputs=None, dt=0.01, input_kind="thrust",
method="rk4", control_dt=None, disturbance=None) -> SimResult``

* ``controller(t, x) -> u`` is any callable (an LQR, a PID, an MPC object with ``__call__``);
  it is sampled every ``control_dt`` (default ``dt``) and held (zero-order hold).
* ``inputs`` is an alternative open-loop input: an array (n_steps, k) held per step, or a
  callable ``inputs(t) -> u``.
* ``input_kind``: ``thrust`` (u = the n thruster forces, N, clipped to each thruster's
  forward/reverse limit) or ``tau`` (u = body wrench, N and N m, unclipped).
* ``disturbance(t, x) -> (6,)`` adds an external generalised force (N, N m), e.g. tether drag.
* ``x0`` of shape (12,) simulates one vehicle; (N, 12) simulates N vehicles at once (the
  controller then receives and returns batches).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.plant import PlantParameters, plant_parameters, state_derivative, thrust_to_wrench
from udrobot_ctrl.vehicle import load_model


@dataclass
class SimResult:
    """Simulated trajectory. ``t`` (n+1,), ``x`` (n+1, [N,] 12), ``u`` (n, [N,] k) commanded input,
    ``tau`` (n, [N,] 6) applied wrench (after thruster saturation), ``saturated`` (n, [N,]) bool."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    tau: np.ndarray
    saturated: np.ndarray


def as_parameters(model) -> PlantParameters:
    """PlantParameters from a model name, file, Vehicle or PlantParameters."""
    if isinstance(model, PlantParameters):
        return model
    return plant_parameters(load_model(model))


def _wrench(u, p, input_kind):
    if input_kind == "thrust":
        return thrust_to_wrench(u, p, clip=True), np.any((u < p.f_min - 1e-9) | (u > p.f_max + 1e-9), axis=-1)
    if input_kind == "tau":
        return np.asarray(u, float), np.zeros(np.shape(u)[:-1], bool)
    raise ValueError(f"input_kind must be 'thrust' or 'tau', got {input_kind!r}")


def rk4_step(p: PlantParameters, x, tau, dt, disturbance=None, t=0.0):
    """One classical RK4 step of the plant with the wrench ``tau`` held over ``dt`` seconds."""
    def f(tt, xx):
        tot = tau if disturbance is None else tau + disturbance(tt, xx)
        return state_derivative(xx, tot, p)

    k1 = f(t, x)
    k2 = f(t + dt / 2, x + dt / 2 * k1)
    k3 = f(t + dt / 2, x + dt / 2 * k2)
    k4 = f(t + dt, x + dt * k3)
    return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def simulate(model, x0, t_final, controller=None, inputs=None, dt=0.01, input_kind="thrust",
             method="rk4", control_dt=None, disturbance=None) -> SimResult:
    """Simulate the plant; see the module docstring. Times in s, states in SI units."""
    p = as_parameters(model)
    if dt <= 0 or t_final <= 0:
        raise ValueError(f"dt and t_final must be > 0 (got dt={dt}, t_final={t_final})")
    n = int(round(t_final / dt))
    x = np.array(x0, dtype=float)
    if x.shape[-1] != 12:
        raise ValueError(f"x0 must have 12 states (x y z phi theta psi u v w p q r), got shape {x.shape}")
    hold = max(1, int(round((control_dt or dt) / dt)))
    t = np.arange(n + 1) * dt
    xs = np.empty((n + 1,) + x.shape)
    xs[0] = x
    us, taus, sats = [], [], []
    u = None
    for k in range(n):
        if controller is not None:
            if k % hold == 0:
                u = np.asarray(controller(t[k], x), dtype=float)
        elif inputs is not None:
            u = np.asarray(inputs(t[k]) if callable(inputs) else inputs[min(k, len(inputs) - 1)], float)
        else:
            u = np.zeros(x.shape[:-1] + ((p.T.shape[1],) if input_kind == "thrust" else (6,)))
        tau, sat = _wrench(u, p, input_kind)
        if method == "rk4":
            x = rk4_step(p, x, tau, dt, disturbance, t[k])
        elif method == "solve_ivp":
            from scipy.integrate import solve_ivp

            def rhs(tt, xx, tau=tau, shape=x.shape):
                xx = xx.reshape(shape)
                tot = tau if disturbance is None else tau + disturbance(tt, xx)
                return state_derivative(xx, tot, p).ravel()

            sol = solve_ivp(rhs, (t[k], t[k + 1]), x.ravel(), rtol=1e-9, atol=1e-11)
            x = sol.y[:, -1].reshape(x.shape)
        else:
            raise ValueError(f"method must be 'rk4' or 'solve_ivp', got {method!r}")
        if not np.all(np.isfinite(x)):
            raise FloatingPointError(f"simulation of {p.name!r} diverged at t = {t[k + 1]:.3f} s")
        xs[k + 1] = x
        us.append(u)
        taus.append(tau)
        sats.append(sat)
    return SimResult(t=t, x=xs, u=np.array(us), tau=np.array(taus), saturated=np.array(sats))
