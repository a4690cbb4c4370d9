"""numba kernels of :mod:`udrobot_ctrl.dynamics.sim`: fixed-step RK4 of the 6-DOF plant for N vehicles.

The derivative is the one of :mod:`udrobot_ctrl.dynamics.equations`, compiled by numba (a test holds
the kernels equal to the numpy plant to ~1e-15). Parameters are runtime arrays with a leading vehicle axis of
length 1 (shared) or N, so one compilation serves every model; it is cached on disk (``cache=True``) in a
private per-user folder (:func:`udrobot_ctrl.caches.configure_numba_cache`: ``$NUMBA_CACHE_DIR`` if set, else
``~/.cache/udrobot_ctrl/numba``, never the source tree), so only the very first use pays the compile.
"""
from udrobot_ctrl.caches import configure_numba_cache

configure_numba_cache()  # before the decorators below choose their cache folder

import numba  # noqa: E402
import numpy as np  # noqa: E402

from udrobot_ctrl.dynamics.equations import equations  # noqa: E402

# inlined at the numba IR level: no call (and no reference counting of the shared parameter arrays, which made
# threads contend in the parallel batch kernel) per term of the equations
_EQ = equations(np.sin, np.cos, np.tan, jit=numba.njit(cache=True, inline="always"))
_state_derivative = _EQ.state_derivative
_generalized_forces = _EQ.generalized_forces
_kinematics = _EQ.kinematics


@numba.njit(cache=True)
def deriv(x, tau, M, Minv, DL, Q, W, B, rg, rb, out):
    """out = x_dot (12) for state x and wrench tau (:mod:`udrobot_ctrl.dynamics.equations`)."""
    d = _state_derivative(x, tau, M, Minv, DL, Q, W, B, rg, rb)
    for i in range(12):
        out[i] = d[i]


@numba.njit(cache=True)
def rk4_step(x, tau, dt, M, Minv, DL, Q, W, B, rg, rb, xt, k1, k2, k3, k4):
    """One classical RK4 step of ``dt`` s in place on ``x`` (12,); xt, k1..k4 are (12,) scratch buffers.

    The compiled twin of :func:`udrobot_ctrl.dynamics.integrators.rk4_step`. Returns False if x became non-finite.
    """
    deriv(x, tau, M, Minv, DL, Q, W, B, rg, rb, k1)
    for j in range(12):
        xt[j] = x[j] + 0.5 * dt * k1[j]
    deriv(xt, tau, M, Minv, DL, Q, W, B, rg, rb, k2)
    for j in range(12):
        xt[j] = x[j] + 0.5 * dt * k2[j]
    deriv(xt, tau, M, Minv, DL, Q, W, B, rg, rb, k3)
    for j in range(12):
        xt[j] = x[j] + dt * k3[j]
    deriv(xt, tau, M, Minv, DL, Q, W, B, rg, rb, k4)
    finite = True
    for j in range(12):
        x[j] = x[j] + dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        if not np.isfinite(x[j]):
            finite = False
    return finite


@numba.njit(cache=True)
def vehicle(i, x0, taus, tau_every, nsteps, dt, rec_every, M, Minv, DL, Q, W, B, rg, rb, out):
    """RK4 of vehicle i; returns -1, or the step index at which its state became non-finite."""
    pi = i if M.shape[0] > 1 else 0
    ti = i if taus.shape[1] > 1 else 0
    Mi, Minvi, DLi, Qi = M[pi], Minv[pi], DL[pi], Q[pi]
    Wi, Bi, rgi, rbi = W[pi], B[pi], rg[pi], rb[pi]
    x = x0[i].copy()
    xt = np.empty(12)
    k1 = np.empty(12)
    k2 = np.empty(12)
    k3 = np.empty(12)
    k4 = np.empty(12)
    for k in range(nsteps):
        tau = taus[k // tau_every, ti]
        finite = rk4_step(x, tau, dt, Mi, Minvi, DLi, Qi, Wi, Bi, rgi, rbi, xt, k1, k2, k3, k4)
        if (k + 1) % rec_every == 0:
            out[(k + 1) // rec_every, i] = x
        if not finite:
            return k
    return -1

@numba.njit(cache=True)
def run_serial(x0, taus, tau_every, nsteps, dt, rec_every, M, Minv, DL, Q, W, B, rg, rb, out, status):
    for i in range(x0.shape[0]):
        status[i] = vehicle(i, x0, taus, tau_every, nsteps, dt, rec_every, M, Minv, DL, Q, W, B, rg, rb, out)

@numba.njit(cache=True, parallel=True)
def run_parallel(x0, taus, tau_every, nsteps, dt, rec_every, M, Minv, DL, Q, W, B, rg, rb, out, status):
    for i in numba.prange(x0.shape[0]):
        status[i] = vehicle(np.int64(i), x0, taus, tau_every, nsteps, dt, rec_every, M, Minv, DL, Q, W, B, rg, rb, out)

@numba.njit(cache=True)
def replay_intervals(x0, taus, t, max_step, M, Minv, DL, Q, W, B, rg, rb, out):
    """RK4 over each logged interval [t_k, t_k+1) with taus[k] held, in ceil(h / max_step) equal sub-steps.

    Single vehicle: M, Minv, DL, Q (6, 6), W, B floats, rg, rb (3,). ``out[0] = x0``, ``out[k + 1]`` = state at
    t[k + 1]. Returns -1, or the interval index k at whose end the state became non-finite.
    """
    x = x0.copy()
    xt = np.empty(12)
    k1 = np.empty(12)
    k2 = np.empty(12)
    k3 = np.empty(12)
    k4 = np.empty(12)
    out[0] = x
    for k in range(t.shape[0] - 1):
        span = t[k + 1] - t[k]
        m = max(1, int(np.ceil(span / max_step - 1e-9)))
        dt = span / m
        tau = taus[k]
        for _ in range(m):
            rk4_step(x, tau, dt, M, Minv, DL, Q, W, B, rg, rb, xt, k1, k2, k3, k4)
        out[k + 1] = x
        for j in range(12):
            if not np.isfinite(x[j]):
                return k
    return -1


@numba.njit(cache=True)
def generalized_forces_rows(x, M, DL, Q, W, B, rg, rb, out):
    """out[i] = C(nu) nu + D(nu) nu + g(eta) (N, N m) of state x[i] (N, 12), one vehicle's parameters.

    The compiled twin of :func:`udrobot_ctrl.dynamics.plant.generalized_forces` for a batch of states.
    """
    for i in range(x.shape[0]):
        F = _generalized_forces(x[i], M, DL, Q, W, B, rg, rb)
        for j in range(6):
            out[i, j] = F[j]


@numba.njit(cache=True)
def kinematics_rows(eta, nu, out):
    """out[i] = J(eta[i]) nu[i] for (N, 6) poses and velocities: the compiled twin of ``plant.kinematics``."""
    for i in range(eta.shape[0]):
        k = _kinematics(eta[i], nu[i])
        for j in range(6):
            out[i, j] = k[j]
