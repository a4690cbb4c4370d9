"""Actuation check: does the logged thruster command push the vehicle the way the logged motion went?

From a run's ``pwm_i`` (or ``thrust_i``) columns and its ``voltage``, the body wrench the vehicle model's
thrusters produce is computed with the project's one PWM -> thrust path (:func:`udrobot_ctrl.dynamics.thrusters.
pwm_to_thrust`, the model's T200 curve at the logged voltage) and thruster matrix
(:func:`udrobot_ctrl.dynamics.plant.thrust_to_wrench`). Per degree of freedom the measured acceleration is then
regressed on that wrench component, both band-passed (default 0.05-0.5 Hz: the band removes buoyancy, currents
and sensor offsets below and the thrusters' lag, the 2 Hz telemetry hold and vibration above), with the DOF's own
velocity and its square (linear and quadratic damping) and, for roll and pitch, its angle (restoring moment) as
further regressors::

    a_k = gain * tau_k + b * nu_k + c * |nu_k| nu_k [+ d * angle_k] + e

``gain`` should be about the model's 1 / (m + added mass), i.e. 1 / M[k, k] of :func:`~udrobot_ctrl.dynamics.plant.
plant_parameters`, and must be positive; a negative gain that the data determine (|t| >= 3 with the effective
number of samples 2 f_high T of the band) means the command pushes the other way: a reversed thruster direction,
motor order or sign convention. The accelerations: surge/sway/heave from d/dt of u, v, w when the run has them
(else heave from the second derivative of the depth z, else the accelerometer corrected for gravity:
u' = ax - g sin(theta), v' = ay + g cos(theta) sin(phi), w' = az + g cos(theta) cos(phi)); roll/pitch/yaw from
d/dt of p, q, r.

A single reversed thruster does not in general reverse a DOF: with the redundant vectored frames the others that
serve the DOF outweigh it (one of the four verticals reversed halves the heave gain and adds cross-talk). The
per-thruster check (:attr:`ActuationCheck.thrusters`) fits one gain per thruster over all measured DOFs at once;
it can name the reversed one when the thrusters were driven independently (a motor test), and says
"not identifiable" when the log's commands are tied together by the mixer.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import butter, sosfiltfilt

from udrobot_ctrl.constants import DOF_NAMES
from udrobot_ctrl.dynamics.plant import PlantParameters, plant_parameters, thrust_to_wrench
from udrobot_ctrl.dynamics.thrusters import load_curve, pwm_to_thrust
from udrobot_ctrl.io.runlog import Run
from udrobot_ctrl.vehicle import Vehicle

VERDICTS = ("agrees", "reversed", "not excited", "inconclusive", "not measured")
T_SIGNIFICANT = 3.0  # |t| of the gain for a verdict of agrees / reversed
MIN_OWN_VARIANCE = 0.02  # share of a thruster's command the others cannot reproduce, for a per-thruster verdict
GRAVITY = 9.81  # m/s^2, for the accelerometer's gravity correction (the IMU's own constant is GRAVITY_MSS 9.80665)


@dataclass(frozen=True)
class DofCheck:
    """Result of one degree of freedom.

    Attributes
    ----------
    dof : str
        ``X Y Z K M N``.
    source : str
        Where the acceleration came from (``"d u/dt"``, ``"d2 z/dt2"``, ``"accelerometer"``...), "" if not measured.
    excitation : float
        Standard deviation of the band-passed wrench component, N or N m.
    correlation : float
        Partial correlation of the band-passed acceleration with the wrench component, given the other regressors.
    gain : float
        Fitted acceleration per wrench, 1/kg or 1/(kg m^2).
    gain_model : float
        The model's 1 / M[k, k] (rigid body + added mass), same unit.
    t_stat : float
        gain / its standard error (effective samples).
    verdict : str
        One of :data:`VERDICTS`.
    """

    dof: str
    source: str
    excitation: float
    correlation: float
    gain: float
    gain_model: float
    t_stat: float
    verdict: str

    @property
    def gain_ratio(self) -> float:
        """Fitted over model gain (1 = the model's mass and thrust; 0.5 = half the expected acceleration)."""
        return self.gain / self.gain_model if self.gain_model else float("nan")


@dataclass(frozen=True)
class ThrusterCheck:
    """One thruster's fitted thrust scale over all measured DOFs (+1 = as the model; -1 = reversed).

    Attributes
    ----------
    index : int
        Thruster number, 1-based (ArduSub motor number).
    scale : float
        Fitted multiplier of the thruster's modelled force, dimensionless.
    t_stat : float
        scale / its standard error.
    verdict : str
        ``agrees``, ``reversed``, ``inconclusive`` or ``not identifiable`` (its command is a combination of the
        others' in this log).
    """

    index: int
    scale: float
    t_stat: float
    verdict: str


@dataclass(frozen=True)
class ActuationCheck:
    """Result of :func:`actuation_check`.

    Attributes
    ----------
    vehicle : str
        Model name.
    dofs : tuple of DofCheck
        X Y Z K M N in order.
    thrusters : tuple of ThrusterCheck
        Per-thruster direction check.
    band_hz : tuple of float
        (low, high) band-pass corners, Hz.
    n_effective : float
        Effective number of independent samples, 2 f_high T.
    t : (n,) ndarray
        Times of the wrench samples, s.
    wrench : (n, 6) ndarray
        Body wrench of the logged commands through the model, N and N m.
    notes : tuple of str
        What was read, assumed and skipped.
    """

    vehicle: str
    dofs: tuple
    thrusters: tuple
    band_hz: tuple
    n_effective: float
    t: np.ndarray = field(repr=False)
    wrench: np.ndarray = field(repr=False)
    notes: tuple = ()

    def dof(self, name: str) -> DofCheck:
        """The result of one DOF by name (``X``...``N``)."""
        for d in self.dofs:
            if d.dof == name:
                return d
        raise KeyError(f"no DOF {name!r}; DOFs are {DOF_NAMES}")

    def table(self) -> str:
        """The per-DOF and per-thruster results as a text table."""
        rows = [f"{'DOF':3s} {'acceleration from':28s} {'excitation':>11s} {'corr':>6s} {'gain':>9s} "
                f"{'model':>9s} {'ratio':>6s} {'t':>7s}  verdict"]
        for d in self.dofs:
            rows.append(f"{d.dof:3s} {d.source or '-':28s} {d.excitation:11.3g} {d.correlation:6.2f} {d.gain:9.3g} "
                        f"{d.gain_model:9.3g} {d.gain_ratio:6.2f} {d.t_stat:7.1f}  {d.verdict}")
        if self.thrusters:
            rows.append("thruster scale (t): " + ", ".join(f"T{c.index} {c.scale:+.2f} ({c.t_stat:+.1f}) {c.verdict}"
                                                           for c in self.thrusters))
        return "\n".join(rows)


# ----------------------------------------------------------------------------- signals
def _uniform(run: Run) -> tuple:
    """(t, fs, resampler) on a uniform grid of the run's median step (the converters already write one)."""
    t = np.asarray(run.t, float)
    dt = run.dt_median
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"{run.path or 'run'}: needs at least two samples with increasing t")
    steps = np.diff(t)
    if np.allclose(steps, dt, rtol=1e-3, atol=1e-9):
        return t, 1.0 / dt, (lambda y: np.asarray(y, float))
    grid = np.arange(t[0], t[-1] + 0.5 * dt, dt)

    def resample(y):
        y = np.asarray(y, float)
        ok = np.isfinite(y)
        out = np.interp(grid, t[ok], y[ok]) if ok.sum() >= 2 else np.full(grid.size, np.nan)
        # keep gaps as gaps: a grid point far from any finite sample is nan
        if ok.sum() >= 2:
            near = np.interp(grid, t, ok.astype(float)) > 0.5
            out[~near] = np.nan
        return out
    return grid, 1.0 / dt, resample


def _band(y, fs, band, order=2):
    """Zero-phase band-pass of y (nan bridged by linear interpolation for the filter; returned nan there)."""
    y = np.asarray(y, float)
    ok = np.isfinite(y)
    if ok.sum() < 10:
        return np.full_like(y, np.nan)
    idx = np.arange(y.size)
    filled = np.interp(idx, idx[ok], y[ok])
    lo, hi = band
    hi = min(hi, 0.45 * fs)
    sos = butter(order, [lo, hi], btype="bandpass", fs=fs, output="sos")
    out = sosfiltfilt(sos, filled)
    out[~ok] = np.nan
    return out


def _damping(nu, fs, band) -> list:
    """Band-passed linear and quadratic damping regressors nu and |nu| nu of one velocity."""
    nu = np.asarray(nu, float)
    return [_band(nu, fs, band), _band(np.abs(nu) * nu, fs, band)]


def _finite_fraction(y) -> float:
    y = np.asarray(y, float)
    return float(np.isfinite(y).mean()) if y.size else 0.0


def _commands_to_wrench(run: Run, p: PlantParameters, curve_name: str, notes: list):
    """Thrust (n, k) N and body wrench (n, 6) of the run's inputs through the model."""
    u = np.asarray(run.inputs, float)
    if run.input_kind == "tau":
        notes.append("inputs: tau_* columns used as the wrench (no thruster model involved)")
        return None, u
    k = p.T.shape[1]
    if u.shape[1] != k:
        raise ValueError(f"{run.path or 'run'}: {u.shape[1]} {run.input_kind}_i columns but the model "
                         f"{p.name!r} has {k} thrusters (columns follow the model's thruster order)")
    if run.input_kind == "pwm":
        volts = run.channels.get("voltage")
        v0 = p.supply_voltage
        if volts is None or not np.isfinite(volts).any():
            v = np.full(run.n, v0)
            notes.append(f"voltage: not in the run; the model's {v0:g} V used for the {curve_name} curve")
        else:
            v = np.where(np.isfinite(volts), volts, np.nanmedian(volts))
            notes.append(f"voltage: the run's column (median {np.nanmedian(volts):.2f} V) used for the "
                         f"{curve_name} curve")
        f = pwm_to_thrust(u, v[:, None], load_curve(curve_name))
    elif run.input_kind == "thrust":
        f = u
    else:
        raise ValueError(f"{run.path or 'run'}: unknown input kind {run.input_kind!r}")
    return f, thrust_to_wrench(f, p)


def _accelerations(run: Run, resample, fs, band, notes):
    """Per DOF: (source, band-passed acceleration, [band-passed regressors]) or None when not measured."""
    ch = {name: resample(run.channel(name)) for name in
          ("z", "phi", "theta", "u", "v", "w", "p", "q", "r", "ax", "ay", "az")}
    g = GRAVITY

    def d(y):
        return np.gradient(_band(y, fs, band), 1.0 / fs)

    def has(name):
        return _finite_fraction(ch[name]) > 0.5

    phi = ch["phi"] if has("phi") else np.zeros_like(ch["z"])
    theta = ch["theta"] if has("theta") else np.zeros_like(ch["z"])
    out = {}
    spec = {"X": ("u", "ax", lambda: ch["ax"] - g * np.sin(theta)),
            "Y": ("v", "ay", lambda: ch["ay"] + g * np.cos(theta) * np.sin(phi)),
            "Z": ("w", "az", lambda: ch["az"] + g * np.cos(theta) * np.cos(phi))}
    for dof, (vel, acc, specific) in spec.items():
        if has(vel):
            out[dof] = (f"d {vel}/dt", d(ch[vel]), _damping(ch[vel], fs, band))
        elif dof == "Z" and has("z"):
            zdot = np.gradient(_band(ch["z"], fs, band), 1.0 / fs)
            zdot_raw = np.gradient(ch["z"], 1.0 / fs)
            out[dof] = ("d2 z/dt2 (depth)", np.gradient(zdot, 1.0 / fs), [zdot, _band(np.abs(zdot_raw) * zdot_raw,
                                                                                       fs, band)])
        elif has(acc):
            out[dof] = (f"accelerometer {acc}", _band(specific(), fs, band), [])
        else:
            out[dof] = None
    for dof, rate, angle in (("K", "p", "phi"), ("M", "q", "theta"), ("N", "r", None)):
        if has(rate):
            regs = _damping(ch[rate], fs, band)
            if angle and has(angle):
                regs.append(_band(ch[angle], fs, band))
            out[dof] = (f"d {rate}/dt", d(ch[rate]), regs)
        else:
            out[dof] = None
    missing = [k for k, v in out.items() if v is None]
    if missing:
        notes.append(f"not measured: {', '.join(missing)} (no velocity, rate, depth or accelerometer column)")
    return out


def _fit(y, X, n_eff):
    """Least squares of y on columns X (first = the wrench); (gain, t, partial correlation)."""
    ok = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
    y, X = y[ok], X[ok]
    if y.size < 10:
        return np.nan, np.nan, np.nan
    X = np.column_stack([X, np.ones(y.size)])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    resid = y - X @ coef
    # residual variance per sample; the standard error is inflated by n / n_eff (samples are not independent)
    sigma2 = float(resid @ resid) / max(y.size - X.shape[1], 1)
    cov = np.linalg.pinv(X.T @ X) * sigma2 * (y.size / max(n_eff - X.shape[1], 1.0))
    se = float(np.sqrt(max(cov[0, 0], 0.0)))
    # partial correlation of y and the wrench given the other regressors
    others = X[:, 1:]
    ry = y - others @ np.linalg.lstsq(others, y, rcond=None)[0]
    rx = X[:, 0] - others @ np.linalg.lstsq(others, X[:, 0], rcond=None)[0]
    den = np.sqrt((ry @ ry) * (rx @ rx))
    corr = float(ry @ rx / den) if den > 0 else np.nan
    return float(coef[0]), float(coef[0] / se) if se > 0 else np.nan, corr


def actuation_check(run: Run, vehicle: Vehicle, band_hz: tuple = (0.05, 0.5), min_excitation: float = 0.01,
                    t_significant: float = T_SIGNIFICANT) -> ActuationCheck:
    """Check per DOF (and per thruster) that the logged commands push the way the logged motion went.

    Parameters
    ----------
    run : Run
        A ``udrobot-run/1`` run with ``pwm_i`` or ``thrust_i`` inputs in the model's thruster order (``pwm_i`` as
        the converters write it: a reversed motor's PWM already mirrored when the log held ``MOT_i_DIRECTION``).
    vehicle : Vehicle
        The model whose thrusters, curve and mass are used.
    band_hz : (float, float)
        Band-pass corners, Hz (the upper one is capped at 0.45 x the sample rate).
    min_excitation : float
        A DOF is "not excited" when the band-passed wrench's standard deviation is below this fraction of the
        DOF's capacity (sum over thrusters of |T_ki| x its larger limit).
    t_significant : float
        |t| of the gain needed for "agrees" / "reversed".

    Returns
    -------
    ActuationCheck
    """
    if run.n < 20:
        raise ValueError(f"{run.path or 'run'}: {run.n} samples; the actuation check needs at least 20")
    lo, hi = (float(b) for b in band_hz)
    if not 0 < lo < hi:
        raise ValueError(f"band_hz must be 0 < low < high, got {band_hz}")
    notes: list = []
    p = plant_parameters(vehicle)
    curve_name = str((vehicle.extras or {}).get("thruster_model", "t200"))
    f, tau = _commands_to_wrench(run, p, curve_name, notes)
    u = np.asarray(run.inputs, float)
    if np.all(np.nanmax(u, axis=0) == np.nanmin(u, axis=0)):
        notes.append(f"inputs: every {run.input_kind}_i column is constant ({', '.join(f'{v:g}' for v in u[0])}"
                     f"{' us: disarmed or idle' if run.input_kind == 'pwm' else ''}); nothing to check")
    t, fs, resample = _uniform(run)
    if t.size != run.n:
        notes.append(f"time base: resampled to a uniform {1 / fs:.3f} s grid")
    tau = np.column_stack([resample(tau[:, k]) for k in range(6)])
    band = (lo, min(hi, 0.45 * fs))
    duration = float(t[-1] - t[0])
    n_eff = max(2.0 * band[1] * duration, 1.0)
    acc = _accelerations(run, resample, fs, band, notes)
    tau_bp = np.column_stack([_band(tau[:, k], fs, band) for k in range(6)])
    f_ref = np.asarray(p.f_ref, float)
    capacity = np.abs(p.T) @ f_ref
    dofs = []
    for k, name in enumerate(DOF_NAMES):
        g_model = 1.0 / float(p.M[k, k])
        exc = float(np.nanstd(tau_bp[:, k]))
        entry = acc.get(name)
        if entry is None:
            dofs.append(DofCheck(name, "", exc, np.nan, np.nan, g_model, np.nan, "not measured"))
            continue
        source, a, regs = entry
        if not capacity[k] > 0 or exc < min_excitation * capacity[k]:
            dofs.append(DofCheck(name, source, exc, np.nan, np.nan, g_model, np.nan, "not excited"))
            continue
        gain, tstat, corr = _fit(a, np.column_stack([tau_bp[:, k]] + regs), n_eff)
        if np.isfinite(tstat) and abs(tstat) >= t_significant:
            verdict = "agrees" if gain > 0 else "reversed"
        else:
            verdict = "inconclusive"
        dofs.append(DofCheck(name, source, exc, corr, gain, g_model, tstat, verdict))
    # the per-thruster fit uses the DOFs that are measured and excited (an unexcited DOF's block is noise)
    used = {d.dof: acc[d.dof] for d in dofs if d.verdict not in ("not measured", "not excited")}
    thrusters = () if f is None else _thruster_check(f, resample, fs, band, p, used, n_eff, t_significant)
    return ActuationCheck(vehicle.name, tuple(dofs), thrusters, band, n_eff, t, tau, tuple(notes))


def _thruster_check(f, resample, fs, band, p, acc, n_eff, t_significant):
    """Fit one scale per thruster: M a_k = sum_i s_i T_ki f_i + per-DOF damping/restoring terms, all DOFs stacked."""
    k_thr = f.shape[1]
    f_bp = np.column_stack([_band(resample(f[:, i]), fs, band) for i in range(k_thr)])
    blocks_y, blocks_x, blocks_extra = [], [], []
    measured = [(k, acc[name]) for k, name in enumerate(DOF_NAMES) if acc.get(name) is not None]
    if not measured:
        return tuple(ThrusterCheck(i + 1, np.nan, np.nan, "not identifiable") for i in range(k_thr))
    n_extra = sum(len(e[2]) + 1 for _, e in measured)
    col = 0
    for k, (_source, a, regs) in measured:
        y = float(p.M[k, k]) * a
        X = f_bp * p.T[k]  # (n, k_thr): thruster i's force in DOF k
        scale = np.nanstd(y)
        if not scale > 0:
            continue
        extra = np.zeros((y.size, n_extra))
        for j, r in enumerate(regs + [np.ones(y.size)]):
            extra[:, col + j] = r
        col += len(regs) + 1
        blocks_y.append(y / scale)
        blocks_x.append(X / scale)
        blocks_extra.append(extra / scale)
    if not blocks_y:
        return ()
    y = np.concatenate(blocks_y)
    X = np.column_stack([np.concatenate(blocks_x), np.concatenate(blocks_extra)])
    ok = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
    y, X = y[ok], X[ok]
    keep = np.any(X != 0, axis=0)
    Xk = X[:, keep]
    coef = np.full(X.shape[1], np.nan)
    c, *_ = np.linalg.lstsq(Xk, y, rcond=None)
    coef[keep] = c
    resid = y - Xk @ c
    n_blocks = len(blocks_y)
    n_eff_total = n_eff * n_blocks
    sigma2 = float(resid @ resid) / max(y.size - Xk.shape[1], 1) * (y.size / max(n_eff_total - Xk.shape[1], 1.0))
    cov = np.linalg.pinv(Xk.T @ Xk) * sigma2
    se = np.full(X.shape[1], np.nan)
    se[keep] = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # identifiability: the share of thruster i's column that the other columns (thrusters and terms) cannot
    # reproduce; a command tied to the others by the mixer has (almost) none
    own = np.zeros(k_thr)
    for i in range(k_thr):
        if keep[i]:
            others = np.delete(X, i, axis=1)[:, np.delete(keep, i)]
            r = X[:, i] - others @ np.linalg.lstsq(others, X[:, i], rcond=None)[0]
            own[i] = float(r @ r) / float(X[:, i] @ X[:, i])
    out = []
    for i in range(k_thr):
        if not keep[i] or own[i] < MIN_OWN_VARIANCE:
            out.append(ThrusterCheck(i + 1, float(coef[i]), np.nan, "not identifiable"))
            continue
        t = coef[i] / se[i] if se[i] > 0 else np.nan
        if np.isfinite(t) and abs(t) >= t_significant:
            verdict = "agrees" if coef[i] > 0 else "reversed"
        else:
            verdict = "inconclusive"
        out.append(ThrusterCheck(i + 1, float(coef[i]), float(t), verdict))
    return tuple(out)
