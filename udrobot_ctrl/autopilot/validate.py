"""The emulated controllers against a real ArduSub dataflash log: PID terms (PIDR/PIDP/PIDY/PIDA) and RCOU.

What is compared, on the log's own inputs (the logged targets ``Tar`` and measurements ``Act`` of each PID,
linearly interpolated onto the autopilot's loop ticks, ``ANG.Dt`` or ``1 / SCHED_LOOP_RATE``):

* **P** sample by sample: ``kP * Err`` at the log instants. For the rate loops (FLTE = 0) the error at a log
  instant is ``Tar - Act`` at that instant, so the emulated P there is exact whatever happened between samples;
  for PIDA the error is low-passed at FLTE = 20 Hz (time constant 8 ms, memory ~40 ms) of an accelerometer signal
  that the 10 Hz log does not resolve, so its emulated P carries the filter's view of the unlogged 200 Hz noise.
* **I**: the integrator integrates the error between log samples, which the log does not hold. Two figures:
  ``i_step`` -- one-step prediction, from the logged I at sample k to k+1 over the interpolated error (what a
  10 Hz log can check: the gain, IMAX and the integrator rule); ``i_free`` -- the emulated integrator run
  freely from the first logged value (it drifts by the integral of the unresolved error; shown, not a test).
* **D**: ``kD`` times the FLTD-filtered (30 Hz for roll/pitch) derivative of the error, a signal of 5-30 Hz
  content sampled at 10 Hz: the sample values alias and cannot be reproduced from 10 Hz inputs (``d``: its NRMSE
  is near or above 1 by construction). What the log does fix is the D term's *integral*: over a window much
  longer than the filter, ``integral(D dt) = kD * change of the error`` (the filter has unit DC gain), so
  ``d_window`` compares 1 s integrals of the logged and emulated D.
* **angle layer** (``rate_targets``): ATT's DesRoll/DesPitch/DesYaw are the *shaped* target attitude and the
  body attitude is ATT's Roll/Pitch/Yaw, so ``attitude_controller_run_quat`` (thrust/heading error, sqrt
  controller with ``ATC_ANG_*_P``, the feed-forward of the target's rate -- taken from a spline derivative of the
  logged targets) must give RATE's RDes/PDes/YDes at each sample.
* **the whole autopilot** (:func:`replay_autopilot`): :class:`~udrobot_ctrl.autopilot.ardusub.ArduSubAutopilot`
  stepped at the loop tick on the logged states (ATT attitude, PID ``Act`` rates, PSCD depth / velocity,
  PIDA ``Act`` acceleration), the logged modes, the logged shaped targets (ATT Des*, PSCD TPD/DVD/DAD plus
  PSOT's VOT/AOT terrain offsets) and the
  pilot's RCIN, its integrators started from the log's; its mixer inputs against RATE's ROut/POut/YOut/AOut and
  its PWM against RCOU. The loop between samples runs on interpolated inputs, so the D terms and the integrators
  drift from the real ones (see I and D above): the rate loops' outputs stay within a few per cent.
* **RCOU** per motor channel (us): ``mixer`` -- the logged mixer inputs (RATE ROut/POut/YOut/AOut) through
  :func:`~udrobot_ctrl.autopilot.motors.motor_pwm`, the check of the output side alone; ``emulated`` -- the
  emulated roll/pitch/yaw (P + one-step I + D + FF), throttle (``hover - PIDA``, the motors' 2 Hz filter) and
  forward/lateral (GUIDED: PSCN/PSCE target accelerations -> ``accel_to_lean_angles`` ->
  ``translate_pos_control_rp`` with ``ANGLE_MAX``; other modes: the pilot's RCIN). Forward and lateral are not
  logged: for ``mixer`` they are fitted per sample by least squares through the frame's factors (the residual of
  the four known inputs, :func:`~udrobot_ctrl.autopilot.motors.fit_horizontal_inputs`), and ``forward_lateral``
  reports how well GUIDED's own horizontal path reproduces those fitted values. ``MOT_i_DIRECTION`` is not logged
  either: it is fitted (:func:`~udrobot_ctrl.autopilot.motors.fit_directions`).

Gains: (a) ArduSub's defaults (:mod:`.params`); (b) fitted from the logged terms where the parameters are
missing (:func:`fit_pid_gains`: ``kP`` by least squares of P on Err; ``kI`` from the integrator's increments over
1 s windows against the integral of a cubic spline through the 10 Hz Err; ``kD`` from the logged D against the
spline's derivative at the log instants. The spline matters: a trapezoid of 10 Hz samples under-integrates
2-3 Hz content by up to 30 % (``x / tan x``, ``x = pi f / 10 Hz``) and biases kI up and kD down. The filter
cut-offs cannot be identified below the 5 Hz Nyquist frequency and keep their defaults).

NRMSE here is ``RMSE(emulated - logged) / std(logged)``: 0 is exact, 1 is no better than the logged mean.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline

from udrobot_ctrl.ardusub.modes import Mode, PilotInput, Targets, norm_input
from udrobot_ctrl.ardusub.params import RC_MAP, ArduSubParameters, PIDGains, usable_log_params
from udrobot_ctrl.autopilot.ardusub import SUPPORTED_MODES, ArduSubAutopilot, VehicleState
from udrobot_ctrl.autopilot.attitude import AttitudeController, euler_rate_to_ang_vel, quat_from_euler
from udrobot_ctrl.autopilot.motors import (
    MotorParameters,
    fit_directions,
    fit_horizontal_inputs,
    frame,
    from_pwm,
    motor_pwm,
    throttle_bidirectional,
)
from udrobot_ctrl.autopilot.pid import ACPID, integrator_after, lowpass_alpha
from udrobot_ctrl.io.mavlink import iter_dataflash

GRAVITY = 9.80665  # m/s^2, GRAVITY_MSS
AXES = ("PIDR", "PIDP", "PIDY", "PIDA")
LOG_MESSAGES = frozenset({"PIDR", "PIDP", "PIDY", "PIDA", "RATE", "RCOU", "RCIN", "MODE", "ANG", "PSCD", "PSCN",
                          "PSCE", "PSOT", "ATT", "CTUN", "PARM"})
#: modes in which the depth (PIDA) loop runs: ALT_HOLD, AUTO, GUIDED, CIRCLE, SURFACE, POSHOLD, SURFTRAK
DEPTH_MODES = (2, 3, 4, 7, 9, 16, 21)


@dataclass(frozen=True)
class DataflashLog:
    """The messages of a dataflash log that the checks need, as arrays on the ``TimeUS`` clock.

    Attributes
    ----------
    path : str
    messages : dict
        Message name -> field -> ndarray; ``t`` is the time (s since boot).
    params : dict
        ``PARM`` name -> last value (ArduSub units).
    modes : tuple of (float, int)
        (time s, mode number) of each MODE record.
    loop_dt : float
        The main loop's tick (s): median ``ANG.Dt``, else ``1 / SCHED_LOOP_RATE``, else 1/400.
    param_problems : tuple of ParameterProblem
        ``PARM`` records ArduSub cannot hold (:func:`~udrobot_ctrl.ardusub.params.parameter_problems`: a damaged
        ``SCHED_LOOP_RATE`` of 1e5, a NaN gain): left out of ``params``, so ArduSub's defaults stand in for them.
    """

    path: str
    messages: dict
    params: dict
    modes: tuple
    loop_dt: float
    param_problems: tuple = ()

    def __getitem__(self, name: str) -> dict:
        if name not in self.messages:
            raise KeyError(f"{self.path}: no {name} messages in the log")
        return self.messages[name]

    def mode_at(self, t) -> np.ndarray:
        """ArduSub mode number at times ``t`` (s); -1 before the first MODE record."""
        t = np.asarray(t, float)
        if not self.modes:
            return np.full(t.shape, -1)
        times = np.array([m[0] for m in self.modes])
        numbers = np.array([m[1] for m in self.modes])
        idx = np.searchsorted(times, t, side="right") - 1
        return np.where(idx >= 0, numbers[np.clip(idx, 0, None)], -1)


def read_log(path) -> DataflashLog:
    """Read the messages in :data:`LOG_MESSAGES` from an ArduSub ``.bin`` (read only; nothing is copied).

    Parameters
    ----------
    path : str or Path
        Dataflash log.
    """
    fields: dict = {}
    params: dict = {}
    modes = []
    for _, _, name, values in iter_dataflash(path, wanted=LOG_MESSAGES):
        if name == "PARM":
            params[values["Name"]] = values["Value"]
            continue
        if name == "MODE":
            modes.append((values["TimeUS"] * 1e-6, int(values["ModeNum"])))
        store = fields.setdefault(name, {})
        for key, value in values.items():
            store.setdefault(key, []).append(value)
    messages = {}
    for name, store in fields.items():
        arrays = {k: np.asarray(v) for k, v in store.items() if not isinstance(v[0], str)}
        arrays["t"] = arrays["TimeUS"] * 1e-6
        messages[name] = arrays
    params, problems = usable_log_params(params)  # the one check of logged parameters (autopilot.params)
    if "ANG" in messages and "Dt" in messages["ANG"]:
        loop_dt = float(np.median(messages["ANG"]["Dt"]))
    elif "SCHED_LOOP_RATE" in params:
        loop_dt = 1.0 / float(params["SCHED_LOOP_RATE"])
    else:
        loop_dt = 1.0 / 400.0
    return DataflashLog(str(path), messages, params, tuple(modes), loop_dt, tuple(problems))


def nrmse(emulated, logged, mask=None) -> float:
    """``RMSE(emulated - logged) / std(logged)`` over finite (and ``mask``-ed) samples; nan if std is 0."""
    e, x = np.asarray(emulated, float), np.asarray(logged, float)
    ok = np.isfinite(e) & np.isfinite(x)
    if mask is not None:
        ok &= np.asarray(mask, bool)
    if ok.sum() < 2:
        return math.nan
    s = float(np.std(x[ok]))
    rmse = float(np.sqrt(np.mean((e[ok] - x[ok]) ** 2)))
    return rmse / s if s > 0 else (0.0 if rmse == 0 else math.nan)


# ------------------------------------------------------------------------------------------------ fitting


@dataclass(frozen=True)
class FittedPID:
    """Gains of one PID fitted from its logged terms (the loop's SI units, as the log records them).

    Attributes
    ----------
    axis : str
        PIDR, PIDP, PIDY or PIDA.
    p, i, d : float
        Fitted kP (output per unit error), kI (per unit error-second), kD (per unit error rate).
    p_nrmse : float
        NRMSE of ``p * Err`` against the logged P (0: the P term is exactly proportional).
    i_corr, d_corr : float
        Correlation of the regressions (integrator increments vs error integrals over ``window`` s; D vs the
        error's spline derivative): how well the 10 Hz log constrains kI and kD.
    window : float
        Window length (s) of the I and D fits.
    n : int
        Samples used.
    """

    axis: str
    p: float
    i: float
    d: float
    p_nrmse: float
    i_corr: float
    d_corr: float
    window: float
    n: int

    def gains(self, base: PIDGains) -> PIDGains:
        """``base`` with the fitted P, I and D (filters, IMAX and FF kept)."""
        return replace(base, p=self.p, i=self.i, d=self.d)


def _ls(y, x) -> tuple:
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    den = float(np.dot(x, x))
    if den == 0.0:
        return 0.0, math.nan
    k = float(np.dot(x, y)) / den
    corr = float(np.corrcoef(x, y)[0, 1]) if np.std(x) > 0 and np.std(y) > 0 else math.nan
    return k, corr


def fit_pid_gains(log: DataflashLog, axis: str, window: float = 1.0, mask=None) -> FittedPID:
    """Fit kP, kI, kD of ``axis`` from its logged Err, P, I and D (see the module notes for the method).

    Parameters
    ----------
    log : DataflashLog
    axis : str
        PIDR, PIDP, PIDY or PIDA.
    window : float
        Window (s) of the I and D fits.
    mask : array of bool, optional
        Samples to use (e.g. the depth-holding modes for PIDA).
    """
    m = log[axis]
    t, err, p, i, d = m["t"], m["Err"], m["P"], m["I"], m["D"]
    use = np.ones(t.shape, bool) if mask is None else np.asarray(mask, bool)
    kp, _ = _ls(p[use], err[use])
    p_nrmse = nrmse(kp * err, p, use)
    dt = np.diff(t)
    w = max(1, int(round(window / float(np.median(dt)))))
    spline = CubicSpline(t, err)
    integ = np.concatenate([[0.0], np.cumsum([spline.integrate(a, b) for a, b in zip(t[:-1], t[1:])])])
    ok = use[w:] & use[:-w]
    # windows in which the integrator sat at a limit are left out (IMAX is not known: |I| within 1 % of its max)
    imax_seen = float(np.max(np.abs(i))) if len(i) else 0.0
    free = (np.abs(i[w:]) < 0.99 * imax_seen) & (np.abs(i[:-w]) < 0.99 * imax_seen) if imax_seen > 0 else ok
    ki, i_corr = _ls((i[w:] - i[:-w])[ok & free], (integ[w:] - integ[:-w])[ok & free])
    kd, d_corr = _ls(d[use], spline(t, 1)[use])
    return FittedPID(axis, kp, ki, kd, p_nrmse, i_corr, d_corr, w * float(np.median(dt)), int(use.sum()))


@dataclass(frozen=True)
class FittedDepth:
    """``PSC_POSZ_P`` and ``PSC_VELZ_P`` fitted from PSCD (and PSOT's offsets) in the depth-holding modes.

    ``TVD = POSZ_P (TPD - PD) + DVD + VOT`` and ``TAD = VELZ_P (TVD - VD) + DAD + AOT`` (``update_z_controller``;
    VOT/AOT are the terrain-following offsets of ArduPilot 4.6+, zero without PSOT). The velocity error is
    low-passed at FLTE (5 Hz) inside the PID, so VELZ_P is fitted within a few per cent.

    Attributes
    ----------
    pos_p, vel_p : float
        Fitted gains (1/s).
    pos_corr, vel_corr : float
        Correlations of the two regressions.
    n : int
        Samples used.
    """

    pos_p: float
    vel_p: float
    pos_corr: float
    vel_corr: float
    n: int


def _offsets(log: DataflashLog, t) -> tuple:
    """PSOT's velocity and acceleration offsets (VOT, AOT; m/s, m/s^2, down) at ``t``; zeros without PSOT."""
    if "PSOT" not in log.messages:
        return np.zeros(len(t)), np.zeros(len(t))
    po = log["PSOT"]
    return np.interp(t, po["t"], po["VOT"], left=0.0), np.interp(t, po["t"], po["AOT"], left=0.0)


def fit_depth_gains(log: DataflashLog) -> FittedDepth:
    """Fit ``PSC_POSZ_P`` and ``PSC_VELZ_P`` from the logged depth targets (see :class:`FittedDepth`)."""
    ps = log["PSCD"]
    use = np.isin(log.mode_at(ps["t"]), DEPTH_MODES)
    vot, aot = _offsets(log, ps["t"])
    kp, cp = _ls((ps["TVD"] - ps["DVD"] - vot)[use], (ps["TPD"] - ps["PD"])[use])
    kv, cv = _ls((ps["TAD"] - ps["DAD"] - aot)[use], (ps["TVD"] - ps["VD"])[use])
    return FittedDepth(kp, kv, cp, cv, int(use.sum()))


def fitted_parameters(log: DataflashLog, window: float = 1.0) -> ArduSubParameters:
    """The log's parameters, with the rate PIDs' and the depth loop's gains replaced by those fitted from its
    PID and PSC logs (:func:`fit_pid_gains`, :func:`fit_depth_gains`); filters and limits keep their defaults."""
    base = ArduSubParameters.from_log_params(log.params, loop_rate_hz=1.0 / log.loop_dt)
    depth_mask = np.isin(log.mode_at(log["PIDA"]["t"]), DEPTH_MODES)
    f = {ax: fit_pid_gains(log, ax, window, depth_mask if ax == "PIDA" else None) for ax in AXES}
    att = replace(base.attitude, rate_roll=f["PIDR"].gains(base.attitude.rate_roll),
                  rate_pitch=f["PIDP"].gains(base.attitude.rate_pitch),
                  rate_yaw=f["PIDY"].gains(base.attitude.rate_yaw))
    depth = replace(base.depth, accel=f["PIDA"].gains(base.depth.accel))
    if "PSCD" in log.messages:
        fd = fit_depth_gains(log)
        depth = replace(depth, pos_p=fd.pos_p, vel=replace(depth.vel, p=fd.vel_p))
    return replace(base, attitude=att, depth=depth)


# --------------------------------------------------------------------------------------------- emulation


@dataclass(frozen=True)
class EmulatedTerms:
    """An axis's PID emulated on the log's targets and measurements, sampled at the log instants.

    Attributes
    ----------
    t : ndarray
        Log instants (s).
    p, d, i_step, i_free : ndarray
        Emulated P, D, one-step I (from the logged I at the previous sample) and free-running I.
    d_window_logged, d_window_emulated : ndarray
        Integrals of the logged (trapezoid of the 10 Hz samples) and emulated (every tick) D over ``window`` s.
    """

    t: np.ndarray
    p: np.ndarray
    d: np.ndarray
    i_step: np.ndarray
    i_free: np.ndarray
    d_window_logged: np.ndarray
    d_window_emulated: np.ndarray


def emulate_pid(log: DataflashLog, axis: str, gains: PIDGains, window: float = 1.0,
                interpolation: str = "cubic") -> EmulatedTerms:
    """Run :class:`~udrobot_ctrl.autopilot.pid.ACPID` at the loop tick on the interpolated logged Tar and Act.

    ``interpolation``: ``cubic`` (a spline through the 10 Hz samples: exact at the samples, smooth between, so
    the derivative and integral between samples follow the signal's slow content) or ``linear``. The logged Tar is
    already the FLTT-filtered target (``_pid_info.target``), so FLTT is not applied again.
    """
    m = log[axis]
    t, tar, act, i_log, d_log = m["t"], m["Tar"], m["Act"], m["I"], m["D"]
    dt = log.loop_dt
    g = replace(gains, filt_t_hz=0.0)
    pid = ACPID(g)
    n = len(t)
    p_out, d_out, i_free, i_step = (np.full(n, np.nan) for _ in range(4))
    d_int = np.zeros(n)
    pid.update_all(float(tar[0]), float(act[0]), dt)
    pid.set_integrator(float(i_log[0]))
    p_out[0], d_out[0], i_free[0], i_step[0] = pid.terms.p, pid.terms.d, pid.integrator, i_log[0]
    ticks = np.maximum(1, np.round(np.diff(t) / dt).astype(int))
    tick_t = np.concatenate([t[k] + (t[k + 1] - t[k]) * np.arange(1, ticks[k] + 1) / ticks[k]
                             for k in range(n - 1)])
    if interpolation == "cubic":
        tar_i, act_i = CubicSpline(t, tar)(tick_t), CubicSpline(t, act)(tick_t)
    else:
        tar_i, act_i = np.interp(tick_t, t, tar), np.interp(tick_t, t, act)
    j = 0
    for k in range(n - 1):
        h = (t[k + 1] - t[k]) / ticks[k]
        errors = []
        acc = 0.0
        for _ in range(ticks[k]):
            pid.update_all(float(tar_i[j]), float(act_i[j]), h)
            errors.append(pid.terms.error)
            acc += pid.terms.d * h
            j += 1
        d_int[k + 1] = d_int[k] + acc
        p_out[k + 1], d_out[k + 1], i_free[k + 1] = pid.terms.p, pid.terms.d, pid.integrator
        i_step[k + 1] = integrator_after(g, float(i_log[k]), errors, h)
    w = max(1, int(round(window / float(np.median(np.diff(t))))))
    d_cum_log = np.concatenate([[0.0], np.cumsum(0.5 * (d_log[1:] + d_log[:-1]) * np.diff(t))])
    return EmulatedTerms(t, p_out, d_out, i_step, i_free, d_cum_log[w:] - d_cum_log[:-w], d_int[w:] - d_int[:-w])


# ----------------------------------------------------------------------------------------- angle layer


def emulate_rate_targets(log: DataflashLog, params: ArduSubParameters) -> tuple:
    """The angle layer's rate demand (N, 3; rad/s) at the ATT instants, and the logged one (RATE, rad/s).

    Uses :meth:`~udrobot_ctrl.autopilot.attitude.AttitudeController.input_target` with ATT's shaped target,
    its spline-derivative feed-forward and ATT's body attitude (module notes).
    """
    att, rate = log["ATT"], log["RATE"]
    t = att["t"]

    def unwrap(deg):
        return np.degrees(np.unwrap(np.radians(deg)))

    des = np.radians(np.stack([att["DesRoll"], att["DesPitch"], unwrap(att["DesYaw"])], axis=1))
    body = np.radians(np.stack([att["Roll"], att["Pitch"], unwrap(att["Yaw"])], axis=1))
    des_rate = CubicSpline(t, des)(t, 1)
    ctl = AttitudeController(params.attitude)
    out = np.empty((len(t), 3))
    for k in range(len(t)):
        ff = euler_rate_to_ang_vel(tuple(des[k, :2]), des_rate[k])
        out[k] = ctl.input_target(quat_from_euler(*des[k]), ff, quat_from_euler(*body[k]), (0.0, 0.0, 0.0),
                                  log.loop_dt)
    logged = np.radians(np.stack([np.interp(t, rate["t"], rate[c]) for c in ("RDes", "PDes", "YDes")], axis=1))
    return out, logged


# ---------------------------------------------------------------------------------------- mixer outputs


def guided_horizontal_inputs(log: DataflashLog, t, angle_max: float) -> np.ndarray:
    """GUIDED's forward/lateral (N, 2) from the logged NE target accelerations (``AC_PosControl::
    accel_to_lean_angles`` then ArduSub's ``translate_pos_control_rp``: lean angle / ``ANGLE_MAX``)."""
    n, e, att = log["PSCN"], log["PSCE"], log["ATT"]
    a_n = np.interp(t, n["t"], n["TAN"])
    a_e = np.interp(t, e["t"], e["TAE"])
    yaw = np.radians(np.interp(t, att["t"], np.unwrap(np.radians(att["Yaw"])) * 180 / np.pi))
    a_fwd = a_n * np.cos(yaw) + a_e * np.sin(yaw)
    a_right = -a_n * np.sin(yaw) + a_e * np.cos(yaw)
    pitch = np.arctan(-a_fwd / GRAVITY)
    roll = np.arctan(a_right * np.cos(pitch) / GRAVITY)
    return np.stack([np.clip(-pitch / angle_max, -1, 1), np.clip(roll / angle_max, -1, 1)], axis=1)


# ------------------------------------------------------------------------------------------------ results


@dataclass(frozen=True)
class TermNRMSE:
    """NRMSE of one axis's emulated terms against the log (module notes for what each can show at 10 Hz)."""

    axis: str
    p: float
    p_from_err: float
    i_step: float
    i_free: float
    d: float
    d_window: float
    n: int


@dataclass(frozen=True)
class EmulationCheck:
    """The emulated controllers against a log, for one set of gains.

    Attributes
    ----------
    label : str
        ``default`` or ``fitted``.
    gains : dict
        Axis -> the :class:`PIDGains` used (SI).
    terms : dict
        Axis -> :class:`TermNRMSE`.
    rcou_mixer : tuple of float
        Per motor channel, NRMSE of ``motor_pwm`` of the logged mixer inputs against RCOU.
    rcou_emulated : tuple of float
        Per motor channel, NRMSE with the emulated roll/pitch/yaw/throttle.
    throttle : float
        NRMSE of the emulated throttle (hover - PIDA, 2 Hz motors filter) against RATE.AOut.
    forward_lateral : tuple of float
        NRMSE of GUIDED's forward and lateral (from PSCN/PSCE) against the per-sample fitted ones.
    directions : tuple of int
        The fitted ``MOT_i_DIRECTION``.
    rate_targets : tuple of float
        NRMSE of the angle layer's rate demand against RATE RDes, PDes, YDes.
    fitted : dict
        Axis -> :class:`FittedPID` (always computed, used when ``label == "fitted"``).
    loop_dt : float
        The tick used (s).
    """

    label: str
    gains: dict
    terms: dict
    rcou_mixer: tuple
    rcou_emulated: tuple
    throttle: float
    forward_lateral: tuple
    directions: tuple
    rate_targets: tuple
    fitted: dict = field(repr=False)
    loop_dt: float = 0.0025

    def summary(self) -> str:
        """A short table for the bench and the report."""
        lines = [f"gains: {self.label} (loop {1 / self.loop_dt:.0f} Hz)",
                 "axis   P      P(Err)  I step  I free  D      D 1s-int"]
        for ax, r in self.terms.items():
            lines.append(f"{ax}   {r.p:.3g}  {r.p_from_err:.3g}  {r.i_step:.3g}  {r.i_free:.3g}  {r.d:.3g}  "
                         f"{r.d_window:.3g}")
        lines.append("angle layer (rate demand vs RATE R/P/YDes) NRMSE: "
                     + " ".join(f"{x:.3g}" for x in self.rate_targets))
        lines.append("RCOU NRMSE mixer only:  " + " ".join(f"{x:.3f}" for x in self.rcou_mixer))
        lines.append("RCOU NRMSE emulated:    " + " ".join(f"{x:.3f}" for x in self.rcou_emulated))
        lines.append(f"throttle (AOut) NRMSE {self.throttle:.3f}; GUIDED forward/lateral NRMSE "
                     f"{self.forward_lateral[0]:.3f}/{self.forward_lateral[1]:.3f}; directions {self.directions}")
        return "\n".join(lines)


def default_gains(params: ArduSubParameters | None = None) -> dict:
    """Axis -> ArduSub's (or ``params``') PID gains, SI."""
    p = params if params is not None else ArduSubParameters.defaults()
    return {"PIDR": p.attitude.rate_roll, "PIDP": p.attitude.rate_pitch, "PIDY": p.attitude.rate_yaw,
            "PIDA": replace(p.depth.accel, imax=max(p.depth.accel.imax, p.depth.throttle_hover))}


def check_log(log: DataflashLog | str | Path, gains: str = "default", frame_name: str = "VECTORED_6DOF",
              window: float = 1.0) -> EmulationCheck:
    """Compare the emulated PID terms and motor outputs with the log (module notes).

    Parameters
    ----------
    log : DataflashLog or path
        An ArduSub dataflash log (``.BIN``) with PID, RATE and RCOU records, or its path.
    gains : {"default", "fitted"}
        ArduSub's defaults (parameters the log lacks) or gains fitted from the logged terms.
    frame_name : str
        ArduSub frame of the vehicle (the Seattle dive: 8 motors, VECTORED_6DOF).
    window : float
        Window (s) of the I/D fits and of the D-integral comparison.

    Returns
    -------
    EmulationCheck
        NRMSE (dimensionless) of each emulated PID term and of the motor outputs against the log.
    """
    log = log if isinstance(log, DataflashLog) else read_log(log)
    params = ArduSubParameters.from_log_params(log.params, loop_rate_hz=1.0 / log.loop_dt)
    base = default_gains(params)
    depth_mask = np.isin(log.mode_at(log["PIDA"]["t"]), DEPTH_MODES)
    fitted = {ax: fit_pid_gains(log, ax, window, depth_mask if ax == "PIDA" else None) for ax in AXES}
    if gains == "default":
        used = base
    elif gains == "fitted":
        used = {ax: fitted[ax].gains(base[ax]) for ax in AXES}
    else:
        raise ValueError(f"gains must be 'default' or 'fitted', got {gains!r}")
    terms, emulated = {}, {}
    for ax in AXES:
        m = log[ax]
        em = emulate_pid(log, ax, used[ax], window)
        emulated[ax] = em
        mask = depth_mask if ax == "PIDA" else None
        w = len(m["t"]) - len(em.d_window_logged)
        wmask = None if mask is None else (mask[w:] & mask[:-w])
        terms[ax] = TermNRMSE(ax, nrmse(em.p, m["P"], mask), nrmse(used[ax].p * m["Err"], m["P"], mask),
                              nrmse(em.i_step, m["I"], mask), nrmse(em.i_free, m["I"], mask),
                              nrmse(em.d, m["D"], mask), nrmse(em.d_window_emulated, em.d_window_logged, wmask),
                              int(len(m["t"]) if mask is None else mask.sum()))
    # ---- motor outputs
    fr = frame(frame_name)
    rate, rcou = log["RATE"], log["RCOU"]
    t = rcou["t"]
    pwm = np.stack([rcou[f"C{k + 1}"] for k in range(fr.n_motors)], axis=1).astype(float)
    logged_in = np.stack([np.interp(t, rate["t"], rate[c]) for c in ("ROut", "POut", "YOut")]
                         + [throttle_bidirectional(np.interp(t, rate["t"], rate["AOut"]))], axis=1)
    mparams = MotorParameters.from_log_params(log.params, fr.n_motors)
    dirs = fit_directions(fr, logged_in, pwm, mparams).directions
    mparams = replace(mparams, directions=dirs)
    # int16 truncation toward 1500 us: the continuous command lay in [pwm, pwm + 1) above 1500, (pwm - 1, pwm] below
    thrust = from_pwm(pwm + 0.5 * np.sign(pwm - 1500.0), mparams)
    fl = fit_horizontal_inputs(fr, logged_in, thrust)
    pred_mixer = motor_pwm(fr, np.concatenate([logged_in, fl], axis=1), mparams)
    rcou_mixer = tuple(nrmse(pred_mixer[:, k], pwm[:, k]) for k in range(fr.n_motors))
    # emulated roll/pitch/yaw: P + one-step I + D + FF on the emulated terms
    rpy = []
    for ax in ("PIDR", "PIDP", "PIDY"):
        em, m = emulated[ax], log[ax]
        out = em.p + em.i_step + em.d + used[ax].ff * m["Tar"]
        rpy.append(np.interp(t, em.t, out))
    # emulated throttle: ThI = hover - (P + I + D) in the depth modes, CTUN.ThI otherwise; 2 Hz motors filter
    ctun, pida = log["CTUN"], emulated["PIDA"]
    hover = params.depth.throttle_hover
    thi_em = hover - (pida.p + pida.i_step + pida.d)
    thi_log = np.interp(pida.t, ctun["t"], ctun["ThI"])
    thi = np.where(depth_mask, thi_em, thi_log)
    thi[~np.isfinite(thi)] = thi_log[~np.isfinite(thi)]
    tho = _throttle_filter(pida.t, thi, log.loop_dt, params.depth.throttle_cutoff_hz,
                           float(np.interp(pida.t[0], rate["t"], rate["AOut"])))
    throttle_nrmse = nrmse(tho, np.interp(pida.t, rate["t"], rate["AOut"]))
    emu_in = np.stack(rpy + [throttle_bidirectional(np.interp(t, pida.t, tho))], axis=1)
    # emulated forward/lateral: GUIDED's horizontal path, the pilot's sticks (RCIN, norm_input) in the other modes
    guided = log.mode_at(t) == 4
    fl_emu = _pilot_horizontal(log, t, params)
    fwd_lat = (math.nan, math.nan)
    if "PSCN" in log.messages and guided.any():
        gh = guided_horizontal_inputs(log, t, params.pilot.angle_max)
        fwd_lat = (nrmse(gh[:, 0], fl[:, 0], guided), nrmse(gh[:, 1], fl[:, 1], guided))
        fl_emu[guided] = gh[guided]
    pred_emu = motor_pwm(fr, np.concatenate([emu_in, fl_emu], axis=1), mparams)
    rcou_emulated = tuple(nrmse(pred_emu[:, k], pwm[:, k]) for k in range(fr.n_motors))
    rate_em, rate_log = emulate_rate_targets(log, params)
    rate_targets = tuple(nrmse(rate_em[:, j], rate_log[:, j]) for j in range(3))
    return EmulationCheck(gains, used, terms, rcou_mixer, rcou_emulated, throttle_nrmse, fwd_lat, dirs,
                          rate_targets, fitted, log.loop_dt)


@dataclass(frozen=True)
class ReplayCheck:
    """:class:`ArduSubAutopilot` on a log's states and targets, against the log's mixer inputs and RCOU.

    Attributes
    ----------
    inputs : tuple of float
        NRMSE of roll, pitch, yaw, throttle against RATE ROut, POut, YOut, AOut.
    rcou : tuple of float
        NRMSE per motor channel, the emulated mixer inputs (forward/lateral as :func:`check_log`'s emulated
        ones) through ``motor_pwm`` with the fitted directions.
    rcou_rmse : tuple of float
        The same as RMSE (us).
    start, end : float
        Replayed span (s, log time).
    seconds_per_second : float
        Wall time per replayed second.
    """

    inputs: tuple
    rcou: tuple
    rcou_rmse: tuple
    start: float
    end: float
    seconds_per_second: float


def replay_autopilot(log: DataflashLog | str | Path, params: ArduSubParameters | None = None,
                     start: float | None = None, end: float | None = None, directions: tuple | None = None,
                     frame_name: str = "VECTORED_6DOF") -> ReplayCheck:
    """Step :class:`~udrobot_ctrl.autopilot.ardusub.ArduSubAutopilot` through a log (module notes).

    Parameters
    ----------
    log : DataflashLog or path
        An ArduSub dataflash log (``.BIN``) with attitude, RATE and RCOU records, or its path.
    params : ArduSubParameters, optional
        Defaults to the log's parameters with ArduSub's defaults for the missing ones.
    start, end : float, optional
        Log time span (s); from the first MODE record to the end by default.
    directions : tuple of int, optional
        ``MOT_i_DIRECTION``; fitted from RCOU (:func:`~udrobot_ctrl.autopilot.motors.fit_directions`) if None.
    frame_name : str
        ArduSub frame of the vehicle (``VECTORED_6DOF``: the BlueROV2 Heavy).

    Returns
    -------
    ReplayCheck
        NRMSE (dimensionless) of the emulated mixer inputs and motor outputs against the log, and the RMSE in us.
    """
    log = log if isinstance(log, DataflashLog) else read_log(log)
    params = params if params is not None else ArduSubParameters.from_log_params(
        log.params, loop_rate_hz=1.0 / log.loop_dt)
    att, rate, pscd = log["ATT"], log["RATE"], log["PSCD"]
    start = start if start is not None else (log.modes[0][0] if log.modes else float(att["t"][0]))
    end = end if end is not None else float(min(att["t"][-1], rate["t"][-1], pscd["t"][-1]))
    dt = log.loop_dt
    ticks = np.arange(start, end, dt)

    def unwrap(deg):
        return np.unwrap(np.radians(deg))

    body = np.stack([np.interp(ticks, att["t"], f) for f in (np.radians(att["Roll"]), np.radians(att["Pitch"]),
                                                             unwrap(att["Yaw"]))], axis=1)
    des_t = np.stack([np.radians(att["DesRoll"]), np.radians(att["DesPitch"]), unwrap(att["DesYaw"])], axis=1)
    des_spline = CubicSpline(att["t"], des_t)
    des, des_rate = des_spline(ticks), des_spline(ticks, 1)
    gyro = np.stack([np.interp(ticks, log[ax]["t"], log[ax]["Act"]) for ax in ("PIDR", "PIDP", "PIDY")], axis=1)
    depth = np.interp(ticks, pscd["t"], pscd["PD"])
    vel = np.interp(ticks, pscd["t"], pscd["VD"])
    acc = np.interp(ticks, log["PIDA"]["t"], log["PIDA"]["Act"])
    tgt = {k: np.interp(ticks, pscd["t"], pscd[k]) for k in ("TPD", "DVD", "DAD")}
    vot, aot = _offsets(log, ticks)  # terrain-following offsets (4.6+) join the feed-forward
    modes = log.mode_at(ticks)
    rc = log["RCIN"] if "RCIN" in log.messages else None
    pwm_in = (np.stack([np.interp(ticks, rc["t"], rc[f"C{k}"].astype(float)) for k in range(1, 9)], axis=1)
              if rc is not None else np.full((len(ticks), 8), 1500.0))
    fl_guided = guided_horizontal_inputs(log, ticks, params.pilot.angle_max) if "PSCN" in log.messages else None
    ap = ArduSubAutopilot(params)
    k0 = int(np.searchsorted(log["PIDR"]["t"], start))
    ap.set_integrators(*(float(log[ax]["I"][k0]) for ax in ("PIDR", "PIDP", "PIDY")),
                       accel_down=float(log["PIDA"]["I"][k0]))
    out = np.empty((len(ticks), 6))
    t_wall = time.perf_counter()
    for j in range(len(ticks)):
        mode = int(modes[j])
        mode = mode if mode in [int(m) for m in SUPPORTED_MODES] else int(Mode.SURFTRAK)
        state = VehicleState(*body[j], rates=tuple(gyro[j]), depth=depth[j], vel_down=vel[j], accel_down=acc[j])
        fwd, lat = (fl_guided[j] if fl_guided is not None else (0.0, 0.0))
        targets = Targets(roll=des[j, 0], pitch=des[j, 1], yaw=des[j, 2], roll_rate=des_rate[j, 0],
                          pitch_rate=des_rate[j, 1], yaw_rate=des_rate[j, 2], shaped=True, depth=tgt["TPD"][j],
                          vel_down=tgt["DVD"][j] + vot[j], accel_down=tgt["DAD"][j] + aot[j], forward=fwd,
                          lateral=lat)
        u = ap.step(dt, state, PilotInput(tuple(pwm_in[j])), mode, targets)
        out[j] = u.as_array(bidirectional=False)
    wall = time.perf_counter() - t_wall
    # the tick's outputs are those the motors wrote in that tick: sample the tick at or just before each log time
    rt = rate["t"]
    sel = (rt >= ticks[0] + 1.0) & (rt <= ticks[-1])  # 1 s for the filters to settle
    idx = np.clip(np.searchsorted(ticks, rt[sel], side="right") - 1, 0, len(ticks) - 1)
    inputs = tuple(nrmse(out[idx, j], rate[c][sel]) for j, c in enumerate(("ROut", "POut", "YOut", "AOut")))
    rcou = log["RCOU"]
    fr = frame(frame_name)
    pwm = np.stack([rcou[f"C{k + 1}"] for k in range(fr.n_motors)], axis=1).astype(float)
    mparams = MotorParameters.from_log_params(log.params, fr.n_motors)
    if directions is None:
        known = np.stack([np.interp(rcou["t"], rt, rate[c]) for c in ("ROut", "POut", "YOut")]
                         + [throttle_bidirectional(np.interp(rcou["t"], rt, rate["AOut"]))], axis=1)
        directions = fit_directions(fr, known, pwm, mparams).directions
    mparams = replace(mparams, directions=tuple(directions))
    csel = (rcou["t"] >= ticks[0] + 1.0) & (rcou["t"] <= ticks[-1])
    cidx = np.clip(np.searchsorted(ticks, rcou["t"][csel], side="right") - 1, 0, len(ticks) - 1)
    u_mix = out[cidx].copy()
    u_mix[:, 3] = throttle_bidirectional(u_mix[:, 3])
    pred = motor_pwm(fr, u_mix, mparams)
    rcou_nrmse = tuple(nrmse(pred[:, k], pwm[csel, k]) for k in range(fr.n_motors))
    rcou_rmse = tuple(float(np.sqrt(np.mean((pred[:, k] - pwm[csel, k]) ** 2))) for k in range(fr.n_motors))
    return ReplayCheck(inputs, rcou_nrmse, rcou_rmse, float(ticks[0]), float(ticks[-1]),
                       wall / max(end - start, 1e-9))


def _pilot_horizontal(log: DataflashLog, t, params: ArduSubParameters) -> np.ndarray:
    """Forward and lateral (N, 2) from the logged RC inputs (``norm_input`` of RCIN C5, C6), 0 without RCIN."""
    out = np.zeros((len(t), 2))
    if "RCIN" not in log.messages:
        return out
    rc = log["RCIN"]
    for j, name in enumerate(("forward", "lateral")):
        pwm = np.interp(t, rc["t"], rc[f"C{RC_MAP[name]}"].astype(float))
        out[:, j] = [norm_input(x, params.pilot.channels[name]) for x in pwm]
    return out


def _throttle_filter(t, throttle_in, dt: float, cutoff_hz: float, start: float) -> np.ndarray:
    """The motors' throttle low-pass run at the loop tick on ``throttle_in`` interpolated between samples."""
    out = np.empty(len(t))
    y = start
    out[0] = y
    for k in range(len(t) - 1):
        span = t[k + 1] - t[k]
        ticks = max(1, int(round(span / dt)))
        a = lowpass_alpha(span / ticks, cutoff_hz)
        for j in range(1, ticks + 1):
            # the throttle set by the mode at tick j is filtered at the next motors output: interpolate
            y += a * ((throttle_in[k] + j / ticks * (throttle_in[k + 1] - throttle_in[k])) - y)
        out[k + 1] = y
    return out


__all__ = ["DataflashLog", "EmulatedTerms", "EmulationCheck", "FittedDepth", "FittedPID", "ReplayCheck", "TermNRMSE",
           "check_log", "default_gains", "emulate_pid", "emulate_rate_targets", "fit_depth_gains",
           "fit_pid_gains", "fitted_parameters",
           "guided_horizontal_inputs", "nrmse", "read_log", "replay_autopilot"]
