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
* ``model`` may also be a list of N models (or :func:`stack_parameters` of them): N vehicles with their
  own mass, damping and restoring parameters (Monte Carlo over coefficients) sharing one thruster layout.
* ``record_every`` (default 1) keeps every k-th state only (t, x, u, tau, saturated at those steps),
  to bound memory for long batches.
* ``on_divergence``: ``"raise"`` (default) raises ``FloatingPointError`` when a state becomes non-finite;
  ``"freeze"`` (batches) sets a diverged vehicle's state to NaN from then on and carries on with the others
  (its controller then receives NaN rows).
* ``parallel``: threaded RK4 kernel over vehicles (default: for 16 or more); False in worker processes.

Speed: ``method='rk4'`` runs a numba kernel (compiled once, cached on disk in ``__pycache__``; pure
parameters are runtime arrays, so no per-model compilation). Without a controller or disturbance the
whole horizon is one kernel call; a controller costs one kernel call plus the controller per control
step. ``method='rk4_numpy'`` is the plain-numpy RK4 (same numbers; used with ``disturbance`` and when
numba is unavailable) and ``method='solve_ivp'`` (RK45, rtol 1e-9) the reference.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.integrate import solve_ivp

from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics import integrators, plant_casadi
from udrobot_ctrl.dynamics.plant import (
    PlantParameters,
    compiled_kernels,
    delivered_wrench,
    plant_parameters,
    require_nominal,
    state_derivative,
    thrust_to_wrench,
)


@dataclass
class SimResult:
    """Simulated trajectory of :func:`simulate` (one vehicle, or N at once: the ``[N,]`` axis).

    Attributes
    ----------
    t : (n+1,) ndarray
        Times, s (every ``record_every``-th step).
    x : (n+1, [N,] 12) ndarray
        States x y z (m, NED) phi theta psi (rad) u v w (m/s, body) p q r (rad/s, body).
    u : (n, [N,] k) ndarray
        Commanded input: thrusts (N) for ``input_kind="thrust"``, the body wrench (N, N m) for ``"tau"``.
    tau : (n, [N,] 6) ndarray
        Applied body wrench X Y Z (N) K M N (N m), after thruster saturation.
    saturated : (n, [N,]) ndarray of bool
        True where a thrust was clipped to its thruster's limit.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    tau: np.ndarray
    saturated: np.ndarray


#: How a model name or file becomes a Vehicle: :func:`udrobot_ctrl.vehicle.load_model`, handed down by
#: :mod:`udrobot_ctrl.vehicle` when it is imported (:func:`set_model_loader`). The vehicle layer sits above this one
#: (it reads model files with this package's effects and thruster curves, docs/architecture.md), so it is not
#: imported here; ``udrobot_ctrl/__init__`` imports it, so the loader is set before any module of the package runs.
_MODEL_LOADER = None


def set_model_loader(load) -> None:
    """Set the function :func:`as_parameters` resolves model names and files with.

    Parameters
    ----------
    load : callable
        Model name, file or Vehicle -> :class:`udrobot_ctrl.vehicle.Vehicle` (:func:`udrobot_ctrl.vehicle.load_model`).

    Returns
    -------
    None
    """
    global _MODEL_LOADER
    _MODEL_LOADER = load


def as_parameters(model) -> PlantParameters:
    """PlantParameters from a model name, file, Vehicle or PlantParameters; a list/tuple gives stacked ones.

    Parameters
    ----------
    model : str, Path, udrobot_ctrl.vehicle.Vehicle, PlantParameters, list or tuple
        A model name or file (read by :func:`udrobot_ctrl.vehicle.load_model`), a vehicle, plant parameters, or
        a sequence of those (stacked, :func:`stack_parameters`).

    Returns
    -------
    PlantParameters
    """
    if isinstance(model, PlantParameters):
        return model
    if isinstance(model, (list, tuple)):
        return stack_parameters(model)
    if _MODEL_LOADER is None:  # not reachable through the package: udrobot_ctrl/__init__ imports the vehicle layer
        raise RuntimeError("no model loader: import udrobot_ctrl.vehicle before resolving a model name")
    return plant_parameters(_MODEL_LOADER(model))


_STACKED = ("M", "M_inv", "D_L", "Q", "weight", "buoyancy", "r_g", "r_b")


def stack_parameters(models) -> PlantParameters:
    """PlantParameters of N vehicles with a leading batch axis on M, M_inv, D_L, Q (N,6,6), weight, buoyancy (N,),
    r_g, r_b (N,3). The thruster matrix and limits must be shared.

    Raises
    ------
    ValueError
        If the list is empty or the vehicles differ in thruster layout or limits.
    """
    ps = [as_parameters(m) for m in models]
    if not ps:
        raise ValueError("stack_parameters needs at least one model")
    p0 = ps[0]
    for p in ps:
        require_nominal(p, "stacked (per-vehicle) parameters")
    for i, p in enumerate(ps[1:], start=1):
        if np.ndim(p.weight) or p.T.shape != p0.T.shape or not (
                np.allclose(p.T, p0.T) and np.allclose(p.f_min, p0.f_min) and np.allclose(p.f_max, p0.f_max)):
            raise ValueError(f"model {i} ({p.name!r}) has a different thruster layout or limits from model 0, or is "
                             "already stacked")
    fields = {k: np.stack([np.asarray(getattr(p, k), float) for p in ps]) for k in _STACKED}
    return replace(p0, name=f"{len(ps)} vehicles ({p0.name}, ...)", M_A=None, **fields)


def is_stacked(p: PlantParameters) -> bool:
    """True if ``p`` holds per-vehicle parameters (from :func:`stack_parameters`)."""
    return np.ndim(p.M) == 3


def vehicle_parameters(p: PlantParameters, i: int) -> PlantParameters:
    """The single-vehicle parameters of vehicle ``i`` of stacked parameters (``p`` itself if not stacked)."""
    if not is_stacked(p):
        return p
    return replace(p, **{k: (float(getattr(p, k)[i]) if k in ("weight", "buoyancy") else getattr(p, k)[i])
                         for k in _STACKED})


def _wrench(u, p, input_kind):
    if input_kind == "thrust":
        if u.shape[-1] != p.T.shape[1]:
            raise ValueError(f"thrust input has {u.shape[-1]} columns, the model has {p.T.shape[1]} thrusters")
        return thrust_to_wrench(u, p, clip=True), np.any((u < p.f_min - 1e-9) | (u > p.f_max + 1e-9), axis=-1)
    if input_kind == "tau":
        return np.asarray(u, float), np.zeros(np.shape(u)[:-1], bool)
    raise ValueError(f"input_kind must be 'thrust' or 'tau', got {input_kind!r}")


class Actuators:
    """The thrust effects of a model between the command and the plant: clip, static maps, lag (held per step of
    ``dt`` s, exact zero-order-hold discretisation), and the state-dependent inflow loss inside each RK4 stage."""

    def __init__(self, p: PlantParameters, dt: float):
        self.p, self.dt = p, float(dt)
        self.maps = fx.thrust_effects(p.effects)
        self.lag = fx.thruster_lag(p.effects)
        self.inflow = any(e.name == "thrust_inflow_loss" for e in self.maps)
        self.f = None

    def delivered(self, u):
        """Thrust after clipping, the static maps and the lag (advanced by one step), N."""
        p = self.p
        f = np.clip(np.asarray(u, float), p.f_min, p.f_max)
        f = np.stack(np.broadcast_arrays(*fx.static_thrust(fx.NUMPY, list(np.moveaxis(f, -1, 0)), self.maps,
                                                           p.f_ref, p.capacities)), axis=-1)
        if self.lag is not None:
            self.f = f if self.f is None else fx.first_order_lag_step(self.f, f, self.dt, self.lag.T_s,
                                                                      self.lag.thrust_exponent)
            f = self.f
        return f

    def step(self, u, disturbance):
        """(wrench of the delivered thrust without inflow loss, stage disturbance adding the inflow loss)."""
        p = self.p
        f = self.delivered(u)
        tau = f @ p.T.T
        if not self.inflow:
            return tau, disturbance

        def stage(tt, xx, f=f, tau=tau):
            extra = delivered_wrench(xx, f, p) - tau
            return extra if disturbance is None else extra + disturbance(tt, xx)
        return tau, stage


def rk4_step(p: PlantParameters, x, tau, dt, disturbance=None, t=0.0):
    """One classical RK4 step of the plant with the wrench ``tau`` held over ``dt`` seconds.

    ``p`` may be stacked parameters (:func:`stack_parameters`), ``x`` then has one vehicle per row.
    """
    def f(tt, xx):
        tot = tau if disturbance is None else tau + disturbance(tt, xx)
        return state_derivative(xx, tot, p)

    return integrators.rk4_step(f, t, x, dt)


# ----------------------------------------------------------------------------- numba kernels
PARALLEL_MIN_VEHICLES = 16  # below this the thread start-up costs more than it saves


def _kernel_arrays(p: PlantParameters):
    """Parameter arrays with a leading (1 or N) vehicle axis, C-contiguous float64."""
    def lead(a, nd):
        a = np.ascontiguousarray(np.asarray(a, float))
        return a if a.ndim == nd + 1 else a[None]
    return (lead(p.M, 2), lead(p.M_inv, 2), lead(p.D_L, 2), lead(p.Q, 2), lead(p.weight, 0),
            lead(p.buoyancy, 0), lead(p.r_g, 1), lead(p.r_b, 1))


def integrate_rk4(p: PlantParameters, x0, taus, dt, nsteps, tau_every=1, record_every=1, out=None, parallel=None):
    """Fixed-step RK4 of N vehicles in compiled code (numba), the wrench held per row of ``taus``.

    Parameters
    ----------
    p : PlantParameters
        Single (shared) or stacked (one per vehicle) parameters.
    x0 : (N, 12) array_like
        Initial states.
    taus : (m, N or 1, 6) array_like
        Wrenches, N and N m; step k uses row ``k // tau_every``.
    dt : float
        Step, s.
    nsteps : int
        Number of RK4 steps.
    record_every : int
        Store every k-th state.
    out : (nsteps // record_every + 1, N, 12) ndarray, optional
        Output buffer (row 0 is set to x0).
    parallel : bool, optional
        Threaded kernel over vehicles; default: when N >= ``PARALLEL_MIN_VEHICLES``. Pass False inside worker
        processes that already use every core (threads there oversubscribe: measured ~10x slower per step on
        a loaded 2-core machine).

    Returns
    -------
    out : ndarray
        Recorded states.
    status : (N,) ndarray of int
        -1 where the vehicle stayed finite, else the step index at which it diverged.
    """
    require_nominal(p, "the compiled RK4 kernel")
    x0 = np.ascontiguousarray(np.asarray(x0, float).reshape(-1, 12))
    n = x0.shape[0]
    taus = np.require(np.asarray(taus, float), requirements=("C", "W"))  # a read-only view: a 2nd numba signature
    if taus.ndim != 3 or taus.shape[2] != 6 or taus.shape[1] not in (1, n):
        raise ValueError(f"taus must be (m, 1 or {n}, 6), got {taus.shape}")
    if (nsteps - 1) // tau_every >= taus.shape[0]:
        raise ValueError(f"{nsteps} steps need {(nsteps - 1) // tau_every + 1} wrench rows, got {taus.shape[0]}")
    arrays = _kernel_arrays(p)
    if arrays[0].shape[0] not in (1, n):
        raise ValueError(f"stacked parameters hold {arrays[0].shape[0]} vehicles but x0 has {n}")
    if out is None:
        out = np.empty((nsteps // record_every + 1, n, 12))
    out[0] = x0
    status = np.empty(n, dtype=np.int64)
    kernels = compiled_kernels()
    serial, threaded = kernels.run_serial, kernels.run_parallel
    run = threaded if (n >= PARALLEL_MIN_VEHICLES if parallel is None else parallel) else serial
    run(x0, taus, int(tau_every), int(nsteps), float(dt), int(record_every), *arrays, out, status)
    return out, status


def integrate_intervals(p: PlantParameters, x0, t, taus, max_step: float, out=None) -> tuple:
    """RK4 of one vehicle over non-uniform sample times, the wrench held on each [t_k, t_k+1) (compiled).

    Each interval is split into ``ceil(h_k / max_step)`` equal sub-steps, so the result does not depend on the
    other intervals. Uses numba when available, else the numpy RK4 (same numbers).

    Parameters
    ----------
    p : PlantParameters
        Single-vehicle parameters.
    x0 : (12,) array_like
    t : (n,) array_like
        Strictly increasing times, s.
    taus : (n, 6) or (n - 1, 6) array_like
        Wrench held on each interval, N and N m.
    max_step : float
        Largest sub-step, s.
    out : (n, 12) ndarray, optional

    Returns
    -------
    out : (n, 12) ndarray
        States at ``t``.
    bad : int
        -1, or the interval index at whose end the state became non-finite.
    """
    if is_stacked(p):
        raise ValueError("integrate_intervals simulates one vehicle; got stacked parameters")
    require_nominal(p, "integrate_intervals (wrench inputs, compiled kernel)")
    t = np.ascontiguousarray(np.asarray(t, float))
    taus = np.ascontiguousarray(np.asarray(taus, float))
    x0 = np.ascontiguousarray(np.asarray(x0, float).reshape(12))
    if out is None:
        out = np.empty((t.shape[0], 12))
    if not max_step > 0:
        raise ValueError(f"max_step must be > 0, got {max_step}")
    if taus.shape[0] < t.shape[0] - 1 or taus.shape[1:] != (6,):
        raise ValueError(f"taus must be ({t.shape[0] - 1} or more, 6), got {taus.shape}")
    M, Minv, DL, Q, W, B, rg, rb = (a[0] for a in _kernel_arrays(p))
    bad = compiled_kernels().replay_intervals(x0, taus, t, float(max_step), M, Minv, DL, Q, float(W), float(B), rg,
                                              rb, out)
    return out, int(bad)


def _divergence(p, status, t0, dt, out=None, record_every=1):
    """Raise for diverged vehicles, or (``out`` given: freeze mode) set their recorded states to NaN from the
    first non-finite one on."""
    bad = np.flatnonzero(status >= 0)
    if out is not None:
        for i in bad:
            out[(int(status[i]) + 1) // record_every:, i] = np.nan
        return
    if bad.size:
        k = int(status[bad].min())
        which = "" if status.size == 1 else f" (vehicles {bad[:10].tolist()})"
        raise FloatingPointError(f"simulation of {p.name!r} diverged at t = {t0 + (k + 1) * dt:.3f} s{which}")


def _input_width(p, input_kind):
    if input_kind == "thrust":
        return p.T.shape[1]
    if input_kind == "tau":
        return 6
    raise ValueError(f"input_kind must be 'thrust' or 'tau', got {input_kind!r}")


def simulate(model, x0, t_final, controller=None, inputs=None, dt=0.01, input_kind="thrust",
             method="rk4", control_dt=None, disturbance=None, record_every=1, on_divergence="raise",
             parallel=None) -> SimResult:
    """Simulate the plant from ``x0`` for ``t_final`` seconds, open loop or under a controller.

    Parameters
    ----------
    model : str, Path, Vehicle, PlantParameters or list
        The plant (a name or file as for :func:`~udrobot_ctrl.vehicle.load_model`); a list of N models
        simulates N vehicles with their own mass, damping and restoring parameters sharing one thruster layout.
    x0 : (12,) or (N, 12) array_like
        Initial state (x y z in m NED, phi theta psi in rad, u v w in m/s, p q r in rad/s); (N, 12) for N
        vehicles at once.
    t_final : float
        Duration, s.
    controller : callable, optional
        ``controller(t, x) -> u`` (an LQR, PID or MPC object), sampled every ``control_dt`` and held.
    inputs : array_like or callable, optional
        Open-loop input instead of a controller: (n_steps, k) rows held per step, or ``inputs(t) -> u``;
        zero if both are None.
    dt : float
        Integration step, s.
    input_kind : {'thrust', 'tau'}
        ``thrust``: u is the n thruster forces, N, clipped to each thruster's limits; ``tau``: u is the body
        wrench, N and N m, unclipped.
    method : {'rk4', 'rk4_numpy', 'solve_ivp'}
        Compiled RK4 kernel, plain-numpy RK4 (same numbers) or scipy's RK45 (rtol 1e-9, the reference).
    control_dt : float, optional
        Controller period, s (default ``dt``).
    disturbance : callable, optional
        ``disturbance(t, x) -> (6,)`` external generalised force added to the wrench, N and N m.
    record_every : int
        Keep every k-th step only (bounds memory for long batches).
    on_divergence : {'raise', 'freeze'}
        On a non-finite state: raise, or (batches) set that vehicle to NaN from then on and carry on.
    parallel : bool, optional
        Threaded RK4 kernel over vehicles (default: for 16 or more).

    Returns
    -------
    SimResult
        Times, states, commanded inputs, applied wrenches and saturation flags.

    Raises
    ------
    ValueError
        Bad arguments (shapes, method, input kind).
    FloatingPointError
        If the state becomes non-finite (names the time and the vehicles) and ``on_divergence`` is ``"raise"``.
    """
    p = as_parameters(model)
    if on_divergence not in ("raise", "freeze"):
        raise ValueError(f"on_divergence must be 'raise' or 'freeze', got {on_divergence!r}")
    freeze = on_divergence == "freeze"
    if not (dt > 0 and t_final > 0):
        raise ValueError(f"dt and t_final must be > 0 (got dt={dt}, t_final={t_final})")
    if method not in ("rk4", "rk4_numpy", "solve_ivp"):
        raise ValueError(f"method must be 'rk4', 'rk4_numpy' or 'solve_ivp', got {method!r}")
    record_every = int(record_every)
    if record_every < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    n = int(round(t_final / dt))
    x = np.array(x0, dtype=float)
    if x.shape[-1] != 12 or x.ndim > 2:
        raise ValueError(f"x0 must have 12 states (x y z phi theta psi u v w p q r), got shape {x.shape}")
    if is_stacked(p):
        if x.ndim == 1:
            x = np.broadcast_to(x, (p.M.shape[0], 12)).copy()
        if x.shape[0] != p.M.shape[0]:
            raise ValueError(f"{p.M.shape[0]} stacked vehicles but x0 has {x.shape[0]} rows")
    k_in = _input_width(p, input_kind)
    hold = max(1, int(round((control_dt or dt) / dt)))
    batch = x.shape[:-1]
    if p.effects and input_kind == "tau" and fx.thrust_effects(p.effects):
        raise ValueError(f"model {p.name!r} has thrust effects ({', '.join(e.name for e in p.effects)}): they act "
                         f"on each thruster's force, so simulate it with thrust inputs, not a commanded wrench")
    # the compiled kernels hold the nominal equations; a model's run-time effects go through the numpy loop
    use_kernel = method == "rk4" and disturbance is None and not p.effects
    if use_kernel and controller is None:
        return _simulate_open_loop(p, x, n, dt, inputs, input_kind, k_in, record_every, freeze, parallel)
    if use_kernel:
        return _simulate_closed_loop(p, x, n, dt, controller, hold, input_kind, record_every, freeze, parallel)
    return _simulate_python(p, x, n, dt, controller, inputs, input_kind, k_in, hold, method, disturbance,
                            record_every, batch, freeze)


def _open_loop_inputs(inputs, n, dt, k_in):
    """(n, k) shared or (n, N, k) per-vehicle input rows from an array, a callable or None (zeros)."""
    if inputs is None:
        return np.zeros((n, k_in))
    if callable(inputs):
        u = np.asarray([np.asarray(inputs(tk), float) for tk in np.arange(n) * dt], float)
    else:
        u = np.asarray(inputs, float)
        if u.ndim == 1:
            u = u[None]
        if len(u) != n:
            u = u[np.minimum(np.arange(n), len(u) - 1)]
    if u.ndim not in (2, 3) or u.shape[-1] != k_in:
        raise ValueError(f"inputs must be (n_steps, {k_in}) or (n_steps, N, {k_in}), got shape {u.shape}")
    return u


def _simulate_open_loop(p, x, n, dt, inputs, input_kind, k_in, record_every, freeze=False, parallel=None):
    batch = x.shape[:-1]
    u = _open_loop_inputs(inputs, n, dt, k_in)
    if u.ndim == 3 and (not batch or u.shape[1] != batch[0]):
        raise ValueError(f"per-vehicle inputs have {u.shape[1]} vehicles, x0 has shape {x.shape}")
    tau_rows, sat_rows = _wrench(u, p, input_kind)
    taus = tau_rows[:, None, :] if tau_rows.ndim == 2 else tau_rows
    xs, status = integrate_rk4(p, x.reshape(-1, 12), taus, dt, n, 1, record_every, parallel=parallel)
    _divergence(p, status, 0.0, dt, xs if freeze else None, record_every)
    m = xs.shape[0] - 1
    sel = np.arange(m) * record_every

    def expand(a, tail):  # (m, [N,] *tail) -> (m, *batch, *tail), a view for shared inputs
        a = a[sel]
        if batch and a.ndim == 1 + len(tail):
            a = np.broadcast_to(a.reshape((m, 1) + tail), (m,) + batch + tail)
        return a

    return SimResult(t=np.arange(m + 1) * dt * record_every, x=xs.reshape((m + 1,) + batch + (12,)),
                     u=expand(u, (k_in,)), tau=expand(tau_rows, (6,)), saturated=expand(sat_rows, ()))


def _simulate_closed_loop(p, x, n, dt, controller, hold, input_kind, record_every, freeze=False, parallel=None):
    batch = x.shape[:-1]
    flat = x.reshape(-1, 12)
    xs = np.empty((n // record_every + 1, flat.shape[0], 12))
    xs[0] = flat
    t_all = np.arange(n + 1) * dt
    n_ctrl = -(-n // hold)
    us, taus, sats = [], [], []
    buf = np.empty((hold + 1, flat.shape[0], 12))
    for c in range(n_ctrl):
        k0 = c * hold
        steps = min(hold, n - k0)
        u = np.asarray(controller(t_all[k0], flat.reshape(batch + (12,))), dtype=float)
        tau, sat = _wrench(u, p, input_kind)
        tau_b = np.broadcast_to(tau, batch + (6,)).reshape(1, -1, 6)
        out, status = integrate_rk4(p, flat, tau_b, dt, steps, hold, 1, out=buf[: steps + 1], parallel=parallel)
        _divergence(p, status, t_all[k0], dt, out if freeze else None)
        for j in range(steps):
            k = k0 + j
            if k % record_every == 0:
                us.append(u)
                taus.append(tau)
                sats.append(sat)
            if (k + 1) % record_every == 0:
                xs[(k + 1) // record_every] = out[j + 1]
        flat = out[steps].copy()
    t = np.arange(xs.shape[0]) * dt * record_every
    return SimResult(t=t, x=xs.reshape((xs.shape[0],) + batch + (12,)), u=np.array(us)[: xs.shape[0] - 1],
                     tau=np.array(taus)[: xs.shape[0] - 1], saturated=np.array(sats)[: xs.shape[0] - 1])


def _simulate_python(p, x, n, dt, controller, inputs, input_kind, k_in, hold, method, disturbance, record_every,
                     batch, freeze=False):
    """Reference loop in numpy (``rk4_numpy``, ``solve_ivp``, or ``rk4`` with a disturbance)."""
    t = np.arange(n + 1) * dt
    xs = [x.copy()]
    us, taus, sats = [], [], []
    u = None
    actuators = Actuators(p, dt) if p.effects and input_kind == "thrust" else None
    # a model with effects: one casadi RK4 step (the same equations, compiled by casadi) per step, unless the
    # numpy reference is asked for or a numpy disturbance must enter the stages
    stepper = None
    if p.effects and method == "rk4" and disturbance is None:
        stepper = plant_casadi.rk4_step_function(p, dt, input_kind, actuators="delivered")
        if batch:
            stepper = stepper.map(int(np.prod(batch)))
    for k in range(n):
        if controller is not None:
            if k % hold == 0:
                u = np.asarray(controller(t[k], x), dtype=float)
        elif inputs is not None:
            u = np.asarray(inputs(t[k]) if callable(inputs) else inputs[min(k, len(inputs) - 1)], float)
        else:
            u = np.zeros(batch + (k_in,))
        tau, sat = _wrench(u, p, input_kind)
        if stepper is not None:
            v = actuators.delivered(u) if actuators is not None else np.asarray(u, float)
            tau = v @ p.T.T if actuators is not None else tau
            v = np.broadcast_to(v, batch + (v.shape[-1],)).reshape(-1, v.shape[-1])
            x = np.asarray(stepper(x.reshape(-1, 12).T, v.T)).T.reshape(x.shape)
        elif method in ("rk4", "rk4_numpy"):
            step_disturbance = disturbance
            if actuators is not None:
                tau, step_disturbance = actuators.step(u, disturbance)
            x = rk4_step(p, x, tau, dt, step_disturbance, t[k])
        else:
            step_disturbance = disturbance
            if actuators is not None:
                tau, step_disturbance = actuators.step(u, disturbance)
            def rhs(tt, xx, tau=tau, shape=x.shape, dist=step_disturbance):
                xx = xx.reshape(shape)
                tot = tau if dist is None else tau + dist(tt, xx)
                return state_derivative(xx, tot, p).ravel()

            sol = solve_ivp(rhs, (t[k], t[k + 1]), x.ravel(), rtol=1e-9, atol=1e-11)
            x = sol.y[:, -1].reshape(x.shape)
        if freeze:
            x = np.where(np.all(np.isfinite(x), axis=-1, keepdims=True), x, np.nan)
        elif not np.all(np.isfinite(x)):
            raise FloatingPointError(f"simulation of {p.name!r} diverged at t = {t[k + 1]:.3f} s")
        if k % record_every == 0:
            us.append(u)
            taus.append(np.broadcast_to(tau, batch + (6,)))
            sats.append(sat)
        if (k + 1) % record_every == 0:
            xs.append(x.copy())
    m = len(xs) - 1
    return SimResult(t=np.arange(m + 1) * dt * record_every, x=np.array(xs), u=np.array(us)[:m],
                     tau=np.array(taus)[:m], saturated=np.array(sats)[:m])
