"""Compiled closed-loop batches of the gain-scheduled LQR, and the mission metrics of a whole batch.

The Sobol / Morris / Monte Carlo studies of ``compare``'s LQR fly thousands of vehicles through one mission.
:func:`udrobot_ctrl.control.missions.run_mission_batch` does it with one numba RK4 call per control step
(5 RK4 steps) and the vectorised law (:class:`~udrobot_ctrl.control.lqr.BatchScheduledLQR` in a
:class:`~udrobot_ctrl.control.missions.SafeBatch`) in numpy between them; per 256-vehicle task that Python loop
and the per-vehicle :func:`~udrobot_ctrl.control.metrics.mission_metrics` cost as much as the RK4 itself
(issue 38). Here

* :func:`fly_lqr_batch` flies the whole mission of every vehicle in one compiled call: the scheduled-LQR law
  of :class:`~udrobot_ctrl.control.lqr.BatchScheduledLQR` with :class:`~udrobot_ctrl.control.missions.SafeBatch`'s
  fallback and clipping, the clipped thrust allocation ``tau = T sat(f)`` and the RK4 steps of
  :func:`udrobot_ctrl.dynamics.sim_kernels.rk4_step` (the compiled RK4 step of ``integrate_rk4``, its derivative
  compiled from :mod:`udrobot_ctrl.dynamics.equations`: the one definition of the plant), called from compiled code,
  so that the step carries no Python call or reference-counting overhead. A vehicle that diverges is frozen at NaN
  (``on_divergence="freeze"``) and then commanded its trim, as in the numpy loop. The trajectories equal
  ``run_mission_batch``'s up to rounding (the law's dot products are summed in another order than numpy's
  ``einsum`` and BLAS; the RK4 steps are ``integrate_rk4``'s own).
* :func:`batch_metrics` computes :func:`udrobot_ctrl.sensitivity.evaluators.flat_metrics` of every vehicle of the
  batch at once, with the same numpy operations on a vehicle axis (tested equal).
"""
from __future__ import annotations

from udrobot_ctrl.caches import configure_numba_cache

configure_numba_cache()  # before the decorators below choose their cache folder

import numba  # noqa: E402
import numpy as np  # noqa: E402

from udrobot_ctrl.control.linearize import REDUCED_INDEX  # noqa: E402
from udrobot_ctrl.control.lqr import PSI_R, BatchScheduledLQR  # noqa: E402
from udrobot_ctrl.control.metrics import at_thrust_limit, thrust_power  # noqa: E402
from udrobot_ctrl.control.missions import CHANNEL_INDEX, CHANNELS  # noqa: E402
from udrobot_ctrl.dynamics.plant import wrap_angle  # noqa: E402
from udrobot_ctrl.dynamics.sim import _kernel_arrays, require_nominal  # noqa: E402
from udrobot_ctrl.dynamics.sim_kernels import rk4_step  # noqa: E402

#: assumed threshold: beyond |theta| = 45 deg a mission is counted as having lost (passive) pitch control; the one
#: definition, used by :mod:`udrobot_ctrl.sensitivity.evaluators` too
LOST_PITCH_DEG = 45.0


@numba.njit(cache=True)
def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi  # plant.wrap_angle


@numba.njit(cache=True)
def _fly(x0, refs, trim_id, trims, speeds, gains, top, f_min, f_max, T, hold, nsteps, dt, red, psi_r,
         M, Minv, DL, Q, W, B, rg, rb, xs, us, status, fallbacks):
    """Every vehicle through the whole mission (see :func:`fly_lqr_batch`); fills xs (12, N, n + 1: one
    contiguous block per state component), us (N, control steps, k), status, fallbacks."""
    n_veh = x0.shape[0]
    n_thr = f_min.shape[0]
    n_red = red.shape[0]
    n_pts = speeds.shape[1]
    xt = np.empty(12)
    k1 = np.empty(12)
    k2 = np.empty(12)
    k3 = np.empty(12)
    k4 = np.empty(12)
    e = np.empty(n_red)
    f = np.empty(n_thr)
    last = np.empty(n_thr)
    tau = np.empty(6)
    for i in range(n_veh):
        pv = i if M.shape[0] > 1 else 0
        Mi, Minvi, DLi, Qi = M[pv], Minv[pv], DL[pv], Q[pv]
        Wi, Bi, rgi, rbi = W[pv], B[pv], rg[pv], rb[pv]
        x = x0[i].copy()
        for j in range(12):
            xs[j, i, 0] = x[j]
        status[i] = -1
        fallbacks[i] = 0
        for j in range(n_thr):
            last[j] = 0.0
        for c in range(refs.shape[0]):
            k0 = c * hold
            if k0 >= nsteps:
                break
            z_ref, psi_ref, u_ref = refs[c, 0], refs[c, 1], refs[c, 2]
            trim = trims[trim_id[c], i]
            # BatchScheduledLQR: e = x_r - x_ref_r (heading wrapped), K(u) interpolated in the measured surge
            for j in range(n_red):
                e[j] = x[red[j]]
            e[0] = x[2] - z_ref  # red = (z, phi, theta, psi, u, v, w, p, q, r)
            e[3] = x[5] - psi_ref
            e[4] = x[6] - u_ref
            e[psi_r] = _wrap(e[psi_r])
            s = x[6] if np.isfinite(x[6]) else u_ref
            s = min(max(s, speeds[i, 0]), top[i])
            kk = 0
            for m in range(n_pts):
                if speeds[i, m] < s:
                    kk += 1
            kk = min(max(kk - 1, 0), n_pts - 2)
            lo, hi = speeds[i, kk], speeds[i, kk + 1]
            a = (s - lo) / (hi - lo)
            good = True
            for r in range(n_thr):
                acc = 0.0
                for j in range(n_red):
                    acc += ((1 - a) * gains[i, kk, r, j] + a * gains[i, kk + 1, r, j]) * e[j]
                f[r] = trim[r] - acc
                if not np.isfinite(f[r]):
                    good = False
            if not good:
                for r in range(n_thr):
                    f[r] = trim[r]  # safe fallback on a non-finite state
            good = True
            for r in range(n_thr):
                f[r] = min(max(f[r], f_min[r]), f_max[r])
                if not np.isfinite(f[r]):
                    good = False
            # SafeBatch: a non-finite command is replaced by the last good one and counted
            if good:
                for r in range(n_thr):
                    last[r] = f[r]
            else:
                fallbacks[i] += 1
            # thrust_to_wrench: tau = T clip(f)
            for q in range(6):
                acc = 0.0
                for r in range(n_thr):
                    acc += min(max(last[r], f_min[r]), f_max[r]) * T[q, r]
                tau[q] = acc
            for r in range(n_thr):
                us[i, c, r] = last[r]
            for k in range(k0, min(k0 + hold, nsteps)):
                if status[i] >= 0:
                    for j in range(12):
                        xs[j, i, k + 1] = np.nan
                    continue
                finite = rk4_step(x, tau, dt, Mi, Minvi, DLi, Qi, Wi, Bi, rgi, rbi, xt, k1, k2, k3, k4)
                if finite:
                    for j in range(12):
                        xs[j, i, k + 1] = x[j]
                else:  # frozen: NaN from the first non-finite state on, the trim commanded from then on
                    status[i] = k
                    for j in range(12):
                        x[j] = np.nan
                        xs[j, i, k + 1] = np.nan


def fly_lqr_batch(controllers, plant, mission, dt: float, control_dt: float):
    """Fly N :class:`~udrobot_ctrl.control.lqr.ScheduledLQR` controllers on N stacked plants through ``mission``.

    What :func:`udrobot_ctrl.control.missions.run_mission_batch` does for scheduled LQRs (safe batch wrapper,
    ``on_divergence="freeze"``, serial), in one compiled call.

    Parameters
    ----------
    controllers : sequence of ScheduledLQR
        One per vehicle (the same object may repeat).
    plant : PlantParameters
        Stacked parameters of the N plants (:func:`~udrobot_ctrl.dynamics.sim.stack_parameters`).
    mission : Mission
    dt, control_dt : float
        RK4 step and controller period, s.

    Returns
    -------
    t : (n + 1,) ndarray
    x : (N, n + 1, 12) ndarray
        States (NaN from a diverged vehicle's first non-finite state on); a view of a (12, N, n + 1) array, so
        each component ``x[..., j]`` is contiguous.
    u : (N, m, k) ndarray
        Commanded thrusts (after the safe wrapper's clipping), N, one row per control step: held ``hold`` RK4
        steps each (``m = ceil(n / hold)``).
    hold : int
        RK4 steps per control step.
    diverged : (N,) ndarray of int
        -1, or the index of the first non-finite state.
    fallbacks : (N,) ndarray of int
        Substitutions of the safe wrapper per vehicle.
    """
    require_nominal(plant, "the compiled LQR batch")
    law = BatchScheduledLQR(controllers)
    n_veh = len(law)
    x0 = np.ascontiguousarray(np.broadcast_to(np.asarray(mission.x0(), float), (n_veh, 12)))
    if tuple(REDUCED_INDEX[:5]) != (2, 3, 4, 5, 6) or PSI_R != 3:
        raise RuntimeError("the compiled LQR law expects the reduced state (z, phi, theta, psi, u, ...)")
    n = int(round(mission.t_final / dt))
    hold = max(1, int(round((control_dt or dt) / dt)))
    t_all = np.arange(n + 1) * dt
    n_ctrl = -(-n // hold)
    refs = np.empty((n_ctrl, 3))
    trim_keys, trim_id, trims = {}, np.empty(n_ctrl, np.int64), []
    for c in range(n_ctrl):
        ref = law.reference(t_all[c * hold])
        refs[c] = ref["z"], ref["psi"], ref["u"]
        key = round(float(ref["u"]), 6)
        if key not in trim_keys:
            trim_keys[key] = len(trims)
            trims.append(law.trim(ref["u"]))
        trim_id[c] = trim_keys[key]
    arrays = _kernel_arrays(plant)
    if arrays[0].shape[0] not in (1, n_veh):
        raise ValueError(f"stacked parameters hold {arrays[0].shape[0]} vehicles for {n_veh} controllers")
    xs = np.empty((12, n_veh, n + 1))
    us = np.empty((n_veh, n_ctrl, law.f_min.shape[0]))
    status = np.empty(n_veh, np.int64)
    fallbacks = np.empty(n_veh, np.int64)
    _fly(x0, refs, trim_id, np.ascontiguousarray(np.stack(trims)), np.ascontiguousarray(law.speeds),
         np.ascontiguousarray(law.gains), np.ascontiguousarray(law.top), np.ascontiguousarray(law.f_min, float),
         np.ascontiguousarray(law.f_max, float), np.ascontiguousarray(plant.T, float), hold, n, float(dt),
         np.asarray(REDUCED_INDEX, np.int64), PSI_R, *arrays, xs, us, status, fallbacks)
    diverged = np.where(status >= 0, status + 1, -1)
    return t_all, np.moveaxis(xs, 0, -1), us, hold, diverged, fallbacks


# ----------------------------------------------------------------------------- metrics of a batch
def _step_response(t, y, t_step, t_end, before, target, band_fraction):
    """:func:`udrobot_ctrl.control.metrics.step_response` of N responses ``y`` (N, n+1): (over, settle, unsettled)."""
    size = target - before
    n_veh = y.shape[0]
    m = (t >= t_step - 1e-12) & (t <= t_end + 1e-12)
    tt, yy = t[m], y[:, m]
    if abs(size) < 1e-12 or tt.size < 2:
        return np.zeros(n_veh), np.zeros(n_veh), np.zeros(n_veh, bool)
    over = np.maximum(0.0, np.max((yy - target) * np.sign(size), axis=1) / abs(size) * 100.0)
    a = np.abs(yy - target) - band_fraction * abs(size)
    outside = a > 0
    any_out = outside.any(axis=1)
    k = tt.size - 1 - np.argmax(outside[:, ::-1], axis=1)  # last sample outside the band
    unsettled = any_out & (k == tt.size - 1)
    kk = np.minimum(k, tt.size - 2)
    rows = np.arange(n_veh)
    a0, a1 = a[rows, kk], a[rows, kk + 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = a0 / (a0 - a1)
        settle = tt[kk] + frac * (tt[kk + 1] - tt[kk]) - t_step
    settle = np.where(any_out, settle, 0.0)
    bad = ~np.all(np.isfinite(yy), axis=1)
    over[bad] = np.nan
    unsettled = unsettled | bad
    return over, settle, unsettled


def _row_sums(a):
    """np.sum of each row as a 1-D array (numpy's pairwise summation of one run, which ``axis=1`` does not repeat)."""
    return np.array([np.sum(r) for r in a], float)


def batch_metrics(t, x, u, mission, f_min, f_max, hold: int = 1) -> dict:
    """:func:`udrobot_ctrl.sensitivity.evaluators.flat_metrics` of N runs at once: ``{metric: (N,)}``.

    ``t`` (n+1,), ``x`` (N, n+1, 12), ``u`` (N, m, k) commanded thrusts (N), each row held ``hold`` steps
    (``m = ceil(n / hold)``; ``hold = 1``: one row per step); ``f_min``, ``f_max`` the plant's thrust limits (N).
    The thrust terms are evaluated once per held row and repeated (the same numbers as per step). The same
    definitions and numpy operations as :func:`~udrobot_ctrl.control.metrics.mission_metrics`, so the same numbers
    (tested); a settling time that is not reached is censored at ``mission.t_final`` and counted in ``unsettled``.
    """
    t, x, u = np.asarray(t, float), np.asarray(x, float), np.asarray(u, float)
    f_min, f_max = np.asarray(f_min, float), np.asarray(f_max, float)
    dt = np.diff(t)
    ref = mission.reference_array(t)
    err = {c: x[:, :, CHANNEL_INDEX[c]] - ref[c] for c in CHANNELS}
    err["psi"] = wrap_angle(err["psi"])
    out = {}
    total = 0.0
    for c in CHANNELS:
        e = np.abs(err[c])
        iae = _row_sums(0.5 * (e[:, 1:] + e[:, :-1]) * dt)
        out[f"iae_{c}"] = iae
        total = total + iae / mission.step_scale(c)
    out["iae"] = total
    overs = {c: [] for c in CHANNELS}
    settles = {c: [] for c in CHANNELS}
    for step, before, t_end in mission.events():
        y = x[:, :, CHANNEL_INDEX[step.channel]]
        if step.channel == "psi":
            y = step.value + wrap_angle(y - step.value)
        o, s, none = _step_response(t, y, step.t, t_end, before, step.value, mission.settle_band)
        overs[step.channel].append(o)
        settles[step.channel].append((s, none))
    unsettled = np.zeros(x.shape[0])
    for c in CHANNELS:
        out[f"overshoot_{c}"] = np.max(overs[c], axis=0) if overs[c] else np.zeros(x.shape[0])
        if settles[c]:
            none = np.any([nn for _, nn in settles[c]], axis=0)
            worst = np.max([s for s, _ in settles[c]], axis=0)
            out[f"settling_{c}_s"] = np.where(none, float(mission.t_final), worst)
            unsettled += none
        else:
            out[f"settling_{c}_s"] = np.zeros(x.shape[0])
    out["overshoot"] = out["overshoot_z"]
    out["settling_s"] = out["settling_z_s"]
    n = dt.shape[0]

    def per_step(a):  # (N, m) per held row -> (N, n) per RK4 step
        return a if hold == 1 else np.repeat(a, hold, axis=1)[:, :n]
    f = np.clip(u, f_min, f_max)
    power = per_step(np.sum(thrust_power(f), axis=-1))
    out["energy_J"] = _row_sums(power * dt[: power.shape[1]])
    sat = per_step(at_thrust_limit(u, f_min, f_max))
    out["saturation_s"] = _row_sums(dt[: sat.shape[1]] * sat)
    out["max_roll_deg"] = np.degrees(np.max(np.abs(x[:, :, 3]), axis=1))
    out["max_pitch_deg"] = np.degrees(np.max(np.abs(x[:, :, 4]), axis=1))
    out["max_sway_mps"] = np.max(np.abs(x[:, :, 7]), axis=1)
    for c in CHANNELS:
        out[f"final_error_{c}"] = err[c][:, -1]
    out["unsettled"] = unsettled
    # np.linalg.norm(x[..., 6:9], axis=-1) sums the three squares in this order; sqrt is monotonic, so the max of
    # the norms is the norm of the largest sum
    speed2 = x[:, :, 6] * x[:, :, 6] + x[:, :, 7] * x[:, :, 7] + x[:, :, 8] * x[:, :, 8]
    out["max_speed"] = np.sqrt(np.max(speed2, axis=1))
    out["lost_control"] = (out["max_pitch_deg"] > LOST_PITCH_DEG).astype(float)
    return {k: np.asarray(v, float) for k, v in out.items()}
