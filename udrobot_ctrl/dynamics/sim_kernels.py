"""numba kernels of :mod:`udrobot_ctrl.dynamics.sim`: fixed-step RK4 of the 6-DOF plant for N vehicles.

Same equations as :func:`udrobot_ctrl.dynamics.plant.state_derivative` written out per component (a test holds
them equal to the numpy plant to ~1e-15). Parameters are runtime arrays with a leading vehicle axis of
length 1 (shared) or N, so one compilation serves every model; it is cached on disk (``cache=True``) in a
private per-user folder (:func:`udrobot_ctrl.caches.configure_numba_cache`: ``$NUMBA_CACHE_DIR`` if set, else
``~/.cache/udrobot_ctrl/numba``, never the source tree), so only the very first use pays the compile.
"""
from udrobot_ctrl.caches import configure_numba_cache

configure_numba_cache()  # before the decorators below choose their cache folder

import numba  # noqa: E402
import numpy as np  # noqa: E402


@numba.njit(cache=True)
def deriv(x, tau, M, Minv, DL, Q, W, B, rg, rb, out, h, nu_dot_rhs):
    """out = x_dot (12) for state x and wrench tau; h, nu_dot_rhs are (6,) scratch buffers."""
    phi, th, psi = x[3], x[4], x[5]
    sf, cf = np.sin(phi), np.cos(phi)
    st, ct = np.sin(th), np.cos(th)
    sp, cp = np.sin(psi), np.cos(psi)
    u, v, w, p, q, r = x[6], x[7], x[8], x[9], x[10], x[11]
    out[0] = cp * ct * u + (-sp * cf + cp * st * sf) * v + (sp * sf + cp * cf * st) * w
    out[1] = sp * ct * u + (cp * cf + sf * st * sp) * v + (-cp * sf + st * sp * cf) * w
    out[2] = -st * u + ct * sf * v + ct * cf * w
    tt = st / ct
    out[3] = p + sf * tt * q + cf * tt * r
    out[4] = cf * q - sf * r
    out[5] = sf / ct * q + cf / ct * r
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += M[i, j] * x[6 + j]
        h[i] = acc
    # C(nu) nu = [w x a ; v x a + w x b], a = h[:3], b = h[3:]
    nu_dot_rhs[0] = q * h[2] - r * h[1]
    nu_dot_rhs[1] = r * h[0] - p * h[2]
    nu_dot_rhs[2] = p * h[1] - q * h[0]
    nu_dot_rhs[3] = v * h[2] - w * h[1] + q * h[5] - r * h[4]
    nu_dot_rhs[4] = w * h[0] - u * h[2] + r * h[3] - p * h[5]
    nu_dot_rhs[5] = u * h[1] - v * h[0] + p * h[4] - q * h[3]
    dw = W - B
    mx = rg[0] * W - rb[0] * B
    my = rg[1] * W - rb[1] * B
    mz = rg[2] * W - rb[2] * B
    nu_dot_rhs[0] += dw * st
    nu_dot_rhs[1] += -dw * ct * sf
    nu_dot_rhs[2] += -dw * ct * cf
    nu_dot_rhs[3] += -my * ct * cf + mz * ct * sf
    nu_dot_rhs[4] += mz * st + mx * ct * cf
    nu_dot_rhs[5] += -mx * ct * sf - my * st
    for i in range(6):
        acc = nu_dot_rhs[i]
        for j in range(6):
            vj = x[6 + j]
            acc += DL[i, j] * vj + Q[i, j] * abs(vj) * vj
        h[i] = tau[i] - acc
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += Minv[i, j] * h[j]
        out[6 + i] = acc

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
    h = np.empty(6)
    rhs = np.empty(6)
    for k in range(nsteps):
        tau = taus[k // tau_every, ti]
        deriv(x, tau, Mi, Minvi, DLi, Qi, Wi, Bi, rgi, rbi, k1, h, rhs)
        for j in range(12):
            xt[j] = x[j] + 0.5 * dt * k1[j]
        deriv(xt, tau, Mi, Minvi, DLi, Qi, Wi, Bi, rgi, rbi, k2, h, rhs)
        for j in range(12):
            xt[j] = x[j] + 0.5 * dt * k2[j]
        deriv(xt, tau, Mi, Minvi, DLi, Qi, Wi, Bi, rgi, rbi, k3, h, rhs)
        for j in range(12):
            xt[j] = x[j] + dt * k3[j]
        deriv(xt, tau, Mi, Minvi, DLi, Qi, Wi, Bi, rgi, rbi, k4, h, rhs)
        finite = True
        for j in range(12):
            x[j] = x[j] + dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
            if not np.isfinite(x[j]):
                finite = False
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
    h = np.empty(6)
    rhs = np.empty(6)
    out[0] = x
    for k in range(t.shape[0] - 1):
        span = t[k + 1] - t[k]
        m = max(1, int(np.ceil(span / max_step - 1e-9)))
        dt = span / m
        tau = taus[k]
        for _ in range(m):
            deriv(x, tau, M, Minv, DL, Q, W, B, rg, rb, k1, h, rhs)
            for j in range(12):
                xt[j] = x[j] + 0.5 * dt * k1[j]
            deriv(xt, tau, M, Minv, DL, Q, W, B, rg, rb, k2, h, rhs)
            for j in range(12):
                xt[j] = x[j] + 0.5 * dt * k2[j]
            deriv(xt, tau, M, Minv, DL, Q, W, B, rg, rb, k3, h, rhs)
            for j in range(12):
                xt[j] = x[j] + dt * k3[j]
            deriv(xt, tau, M, Minv, DL, Q, W, B, rg, rb, k4, h, rhs)
            for j in range(12):
                x[j] = x[j] + dt / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        out[k + 1] = x
        for j in range(12):
            if not np.isfinite(x[j]):
                return k
    return -1
