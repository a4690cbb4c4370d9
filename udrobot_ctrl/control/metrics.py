"""Closed-loop metrics of a mission: IAE, overshoot, settling time, thrust energy, time in saturation.

Definitions (``e = y - r`` per tracked channel, heading error wrapped to [-pi, pi)):

* ``iae_<c>`` — integral of |e| dt over the whole mission (m s, rad s, m); ``iae`` — the weighted total
  ``sum_c iae_c / s_c`` with ``s_c`` the channel's largest step in the mission (1 m, pi/2 rad, 0.5 m/s for
  the standard mission), so each channel counts as "seconds of one full step's error"; unit s.
* ``overshoot_<c>`` — per step event (see :meth:`udrobot_ctrl.control.missions.Mission.events`): largest
  excursion beyond the new reference, in the direction of the step, within the event's window, % of the
  step size (0 if none). For several events of one channel (surge transit and stop) the largest is kept.
* ``settling_<c>_s`` — time from the step until the error last leaves the band ``settle_band * |step|``
  (2 %) within the event's window, interpolated between samples; ``None`` if it is still outside at the
  window end (not settled). For several events of one channel the largest is kept (``None`` wins).
* ``overshoot``, ``settling_s`` — the headline figures are the *depth step*'s (``overshoot_z``,
  ``settling_z_s``).
* ``energy_J`` — *estimated* electrical energy of the four T-200s: integral of sum_i P(f_i) dt with the
  power-law fit P = c |f|^a of Blue Robotics' bollard data at 12 V (``../shared/data/t200``, 201 PWM
  steps; forward c = 0.909 W/N^a, a = 1.493, RMS 2.7 W; reverse c = 1.087, a = 1.555, RMS 2.3 W; points
  with |f| < 0.5 N excluded). Bollard (zero advance speed), one ESC per thruster, idle draw ignored
  (measured <= 0.6 W): an estimate, not a measurement. :func:`fit_t200_power` refits it from the CSV.
* ``saturation_s`` — time during which at least one thruster's command is at (within 0.5 % of the range)
  or beyond its forward or reverse limit, s.
* ``max_roll_deg``, ``max_pitch_deg``, ``max_sway_mps`` — peaks of the DOFs that are passive or weakly
  actuated (the thrusters cannot hold pitch or sway on UDrobot).
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.control.missions import CHANNEL_INDEX, CHANNELS, Mission
from udrobot_ctrl.dynamics.plant import wrap_angle

#: T-200 electrical power vs thrust at 12 V, P = c |f|^a (W, f in N): fitted by :func:`fit_t200_power` to
#: Blue Robotics' T200 Public Performance Data (September 2019), 12 V sheet (estimated, bollard conditions).
T200_POWER_12V = {"forward": (0.9092, 1.4932), "reverse": (1.0874, 1.5547)}
SATURATION_TOL = 0.005  # fraction of the thrust range counted as "at the limit"


def thrust_power(f, fit=T200_POWER_12V):
    """Estimated electrical power (W) of thrusters producing thrusts ``f`` (N, any shape), elementwise."""
    f = np.asarray(f, float)
    cf, af = fit["forward"]
    cr, ar = fit["reverse"]
    a = np.abs(f)
    return np.where(f >= 0, cf * a**af, cr * a**ar)


def fit_t200_power(csv_path, voltage: float = 12.0, min_thrust_N: float = 0.5) -> dict:
    """Fit P = c |f|^a per direction (log-log least squares) to the tidy T-200 CSV at one voltage.

    Returns ``{"forward": (c, a), "reverse": (c, a), "rms_W": {...}}``.

    Raises
    ------
    ValueError
        If the file lacks the columns ``voltage_V``, ``thrust_N``, ``power_W`` or has no row at ``voltage``.
    """
    import csv

    with open(csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    need = {"voltage_V", "thrust_N", "power_W"}
    if not rows or not need <= set(rows[0]):
        raise ValueError(f"{csv_path}: expected columns {sorted(need)}")
    sel = [r for r in rows if abs(float(r["voltage_V"]) - voltage) < 1e-9]
    if not sel:
        raise ValueError(f"{csv_path}: no rows at voltage_V = {voltage}")
    f = np.array([float(r["thrust_N"]) for r in sel])
    P = np.array([float(r["power_W"]) for r in sel])
    out, rms = {}, {}
    for name, sgn in (("forward", 1.0), ("reverse", -1.0)):
        m = (np.sign(f) == sgn) & (np.abs(f) > min_thrust_N) & (P > 0)
        a, logc = np.polyfit(np.log(np.abs(f[m])), np.log(P[m]), 1)
        out[name] = (float(np.exp(logc)), float(a))
        rms[name] = float(np.sqrt(np.mean((np.exp(logc) * np.abs(f[m]) ** a - P[m]) ** 2)))
    out["rms_W"] = rms
    return out


def tracking_errors(t, x, mission: Mission) -> dict:
    """Channel -> (n,) error y - r over the samples ``t`` (heading wrapped)."""
    ref = mission.reference_array(t)
    err = {c: x[:, CHANNEL_INDEX[c]] - ref[c] for c in CHANNELS}
    err["psi"] = wrap_angle(err["psi"])
    return err


def step_response(t, y, t_step, t_end, before, target, band_fraction=0.02):
    """Overshoot (%) and settling time (s, or None) of one step from ``before`` to ``target`` at ``t_step``.

    ``y`` is the response (for heading, already unwrapped near the target), scored on ``t_step <= t <= t_end``.
    """
    size = target - before
    m = (t >= t_step - 1e-12) & (t <= t_end + 1e-12)
    tt, yy = t[m], y[m]
    if abs(size) < 1e-12 or tt.size < 2:
        return 0.0, 0.0
    if not np.all(np.isfinite(yy)):
        return float("nan"), None
    over = max(0.0, float(np.max((yy - target) * np.sign(size))) / abs(size) * 100.0)
    a = np.abs(yy - target) - band_fraction * abs(size)
    outside = np.flatnonzero(a > 0)
    if outside.size == 0:
        return over, 0.0
    k = outside[-1]
    if k == tt.size - 1:
        return over, None
    frac = a[k] / (a[k] - a[k + 1])
    return over, float(tt[k] + frac * (tt[k + 1] - tt[k]) - t_step)


def integral_abs_error(t, e) -> float:
    """IAE: the integral of |e| dt over the samples ``t`` (s), trapezoid rule (error unit times s)."""
    t, e = np.asarray(t, float), np.abs(np.asarray(e, float))
    return float(np.sum(0.5 * (e[1:] + e[:-1]) * np.diff(t)))


def at_thrust_limit(u, f_min, f_max) -> np.ndarray:
    """Per sample: at least one thruster command ``u`` (..., k) is within :data:`SATURATION_TOL` of the thrust range
    of its forward or reverse limit ``f_max`` / ``f_min`` (N), or beyond (the ``saturation_s`` definition)."""
    u, f_min, f_max = np.asarray(u, float), np.asarray(f_min, float), np.asarray(f_max, float)
    tol = SATURATION_TOL * (f_max - f_min)
    return np.any((u >= f_max - tol) | (u <= f_min + tol), axis=-1)


def _worst(values):
    if any(v is None for v in values):
        return None
    return max(values) if values else 0.0


def mission_metrics(res, mission: Mission, f_min, f_max) -> dict:
    """Metrics of one simulated mission (see the module docstring for every definition).

    Parameters
    ----------
    res : SimResult
        ``t`` (n+1,), ``x`` (n+1, 12), ``u`` (n, k) commanded thrusts (N).
    mission : Mission
        The flown mission.
    f_min, f_max : (k,) array_like
        Thrust limits of the *plant*, N.

    Returns
    -------
    dict
        ``iae`` (s), ``iae_z`` (m s), ``iae_psi`` (rad s), ``iae_u`` (m), ``overshoot`` (%), ``settling_s``
        (s or None), ``overshoot_<c>``, ``settling_<c>_s``, ``energy_J`` (J), ``saturation_s`` (s),
        ``max_roll_deg``, ``max_pitch_deg``, ``max_sway_mps``, ``final_error`` (dict per channel).
    """
    t, x = np.asarray(res.t, float), np.asarray(res.x, float)
    u = np.asarray(res.u, float)
    f_min, f_max = np.asarray(f_min, float), np.asarray(f_max, float)
    dt = np.diff(t)
    err = tracking_errors(t, x, mission)
    out = {}
    total = 0.0
    for c in CHANNELS:
        iae = integral_abs_error(t, err[c])
        out[f"iae_{c}"] = iae
        total += iae / mission.step_scale(c)
    out["iae"] = total
    overs, settles = {c: [] for c in CHANNELS}, {c: [] for c in CHANNELS}
    for step, before, t_end in mission.events():
        y = x[:, CHANNEL_INDEX[step.channel]]
        if step.channel == "psi":
            y = step.value + wrap_angle(y - step.value)
        o, s = step_response(t, y, step.t, t_end, before, step.value, mission.settle_band)
        overs[step.channel].append(o)
        settles[step.channel].append(s)
    for c in CHANNELS:
        out[f"overshoot_{c}"] = max(overs[c]) if overs[c] else 0.0
        out[f"settling_{c}_s"] = _worst(settles[c])
    out["overshoot"] = out["overshoot_z"]
    out["settling_s"] = out["settling_z_s"]
    f = np.clip(u, f_min, f_max)
    out["energy_J"] = float(np.sum(np.sum(thrust_power(f), axis=-1) * dt[: len(f)]))
    sat = at_thrust_limit(u, f_min, f_max)
    out["saturation_s"] = float(np.sum(dt[: len(sat)] * sat))
    out["max_roll_deg"] = float(np.degrees(np.max(np.abs(x[:, 3]))))
    out["max_pitch_deg"] = float(np.degrees(np.max(np.abs(x[:, 4]))))
    out["max_sway_mps"] = float(np.max(np.abs(x[:, 7])))
    out["final_error"] = {c: float(err[c][-1]) for c in CHANNELS}
    return out
