"""Pendulum free-decay test (Cely 2019 sec. 3.3, eqs. 10-16), dimensionally consistent.

Physics used here
-----------------
The scale model (mass m, displaced volume V, buoyancy B = rho V g) sits at distance r (``length``)
from the pivot on a light arm; the IMU measures the arm angle theta from the rest position. The
model moves on a circle with speed v = r theta'. With the hydrodynamic force of the Chin form
F_h = m_a v' + K_L v + K_Q |v| v (Morison form: K_L = 0, K_Q = K_D = 1/2 rho C_D A), moments about
the pivot give

    J theta'' = -R sin(theta) - K_L r^2 theta' - K_Q r^3 |theta'| theta',
    J = (m + m_a) r^2 + I_p,      R = |m g - B| r,

(heavy model hanging below the pivot when m g > B, buoyant model standing above it otherwise;
I_p is the inertia of the arm and pivot, default 0, and the model's own rotational inertia is
neglected: point-mass model, valid for r much larger than the model). Hence

    theta'' = -a1 sin(theta) - aL theta' - a2 |theta'| theta',
    a1 = R / J,   aL = K_L r^2 / J,   a2 = K_Q r^3 / J,

and the identification inverts it:  J = R / a1,  m_a = (J - I_p) / r^2 - m,  C_m = m_a / (rho V),
K_L = aL J / r^2,  K_Q = a2 J / r^3,  C_D = 2 K_Q / (rho A).

Relation to the paper: eq. 12 has the same structure (with r theta'' on the left, i.e. divided by
r), but eq. 13 drops that r from a1, so the paper's eq. 15, m' = (rho V g - m g) / a1 - m, is our
m_a with r = 1 m; eq. 13's a2 = K_D r / (m + m') agrees with ours (K_D r^3 / (M r^2)), but eq. 16,
C_D = 2 a2 / (rho A), omits the factor (m + m') / r, so it is not dimensionless. With r in metres
the two agree only for r = 1 m and m + m' = 1 kg.

Methods
-------
``regression`` (paper): Savitzky-Golay derivatives and linear least squares on the three
regressors. The derivatives use a quintic over a sixth of the period: a cubic's second derivative of
a sinusoid is low by O((w h)^2) (h the half-window; ~1.5-2.5 % with a tenth of the period, which
biases a1 low and C_m high by as much), a quintic's only by O((w h)^4), and its wider window keeps
the noise gain similar (checked on simulated decays with 0.02 and 0.1 deg IMU noise).
``output-error`` (default): the ODE above fitted to the whole trace (:mod:`identification.decay`),
with HAC 95 % intervals propagated by the delta method. Both are run for the Chin and for the Morison form.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from identification import decay
from identification.decay import Launch, LaunchError

NU_WATER = 1.0e-6  # m^2/s (assumed, fresh water near 20 C)
FORMS = ("chin", "morison")
SG_ORDER = 5  # Savitzky-Golay polynomial order (see module docstring)
SG_WINDOW_PERIODS = 6.0  # window = period / 6


@dataclass(frozen=True)
class PendulumRig:
    """Pendulum rig and model (SI units).

    Attributes
    ----------
    mass : float
        Model mass m, kg (Table 3: 0.146).
    volume : float
        Displaced volume V, m^3 (Table 3: 107,597 mm^3 = 1.07597e-4).
    length : float
        Pivot to model centre r, m.
    area : float
        Projected area A for C_D, m^2.
    rho, g : float
        Water density (kg/m^3) and gravity (m/s^2).
    pivot_inertia : float
        Arm and pivot inertia about the pivot, kg m^2 (default 0, assumed negligible).
    dimension : float or None
        Characteristic length for the Reynolds number, m (default sqrt(area)).
    """

    mass: float
    volume: float
    length: float
    area: float
    rho: float = 1000.0
    g: float = 9.81
    pivot_inertia: float = 0.0
    dimension: float | None = None

    def __post_init__(self):
        for name in ("mass", "volume", "length", "area", "rho", "g"):
            v = getattr(self, name)
            if v is None or not np.isfinite(v) or v <= 0:
                raise ValueError(f"pendulum rig: {name} must be a positive number in SI units, got {v!r}")
        if self.restoring_moment <= 1e-3 * self.mass * self.g * self.length:
            raise ValueError(f"pendulum rig: weight {self.mass * self.g:.4g} N and buoyancy "
                             f"{self.rho * self.volume * self.g:.4g} N nearly cancel: no restoring moment")

    @property
    def restoring_moment(self) -> float:
        """R = |m g - rho V g| r, N m per unit sin(theta)."""
        return abs(self.mass - self.rho * self.volume) * self.g * self.length

    @property
    def length_scale(self) -> float:
        return float(self.dimension or math.sqrt(self.area))


def coefficients_from_rates(a1, aL, a2, rig: PendulumRig) -> dict:
    """Physical coefficients from the per-inertia rates (see module docstring)."""
    r = rig.length
    J = rig.restoring_moment / a1
    ma = (J - rig.pivot_inertia) / r ** 2 - rig.mass
    kq = a2 * J / r ** 3
    return {"added_mass_kg": ma, "Cm": ma / (rig.rho * rig.volume), "KL": aL * J / r ** 2, "KQ": kq,
            "CD": 2 * kq / (rig.rho * rig.area), "omega_n": math.sqrt(a1)}


_KEYS = ("added_mass_kg", "Cm", "KL", "KQ", "CD", "omega_n")


def read_pendulum_launch(path) -> Launch:
    """Read a ``t,theta`` (rad) launch CSV.

    Parameters
    ----------
    path : str or Path
        The CSV (t in s, theta in rad).

    Returns
    -------
    Launch
        Times (s), angle (rad) and its estimated quantisation step (rad).
    """
    cols, _ = decay.read_columns(path, {"theta": ("t", "theta")})
    th = cols["theta"]
    if np.max(np.abs(th)) > math.pi:
        raise LaunchError(path, f"|theta| up to {np.max(np.abs(th)):.4g} exceeds pi: theta must be in radians",
                          field="theta")
    return Launch(str(path), cols["t"], th, decay.estimate_resolution(th))


def savgol_derivatives(t, theta, window_s, order=3):
    """Smoothed angle, rate and acceleration by Savitzky-Golay (uniform sampling required)."""
    dt = float(np.median(np.diff(t)))
    if np.max(np.abs(np.diff(t) - dt)) > 0.05 * dt:
        raise ValueError("Savitzky-Golay differentiation needs uniform sampling")
    w = max(int(round(window_s / dt)) | 1, order + 2 + ((order + 2) % 2 == 0))
    if w >= theta.size:
        raise ValueError("record shorter than the smoothing window")
    th = signal.savgol_filter(theta, w, order)
    d1 = signal.savgol_filter(theta, w, order, deriv=1, delta=dt)
    d2 = signal.savgol_filter(theta, w, order, deriv=2, delta=dt)
    return th, d1, d2, w


def regression_fit(launch: Launch, rig: PendulumRig, start, ext, form="chin") -> dict:
    """Paper's method: SG derivatives and linear least squares for (a1, aL, a2)."""
    period = 2 * float(np.mean(np.diff(ext.t)))
    t = launch.t[start:]
    th_raw = launch.x[start:] - ext.offset
    try:
        th, d1, d2, w = savgol_derivatives(t, th_raw, period / SG_WINDOW_PERIODS, order=SG_ORDER)
    except ValueError as exc:
        raise LaunchError(launch.path, f"regression method: {exc}", field="t") from None
    sl = slice(w // 2 + 1, th.size - w // 2)
    cols = [np.sin(th[sl])] + ([d1[sl]] if form == "chin" else []) + [np.abs(d1[sl]) * d1[sl]]
    X = -np.column_stack(cols)
    y = d2[sl]
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    if not coef[0] > 0:
        raise LaunchError(launch.path, f"regression method: restoring rate a1 = {coef[0]:.3g} 1/s^2 is not positive "
                          "(the trace is not a pendulum decay)")
    r = y - X @ coef
    cov, lag = decay.hac_covariance(X, r)
    names = ["a1"] + (["aL"] if form == "chin" else []) + ["a2"]

    def physical(q):
        d = dict(zip(names, q))
        c = coefficients_from_rates(d["a1"], d.get("aL", 0.0), d["a2"], rig)
        return np.array([c[k] for k in _KEYS])

    val, pcov = decay.propagate(physical, coef, cov)
    return _pack(val, pcov, y.size - len(names), form, {"rms_residual": float(np.sqrt(np.mean(r ** 2))),
                                                        "hac_lag": lag, "sg_window": w})


def _pack(val, cov, dof, form, extra):
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    out = {}
    for k, v, s in zip(_KEYS, val, se):
        if form == "morison" and k == "KL":
            continue
        out[k] = float(v)
        out[k + "_se"] = float(s)
        out[k + "_ci95"] = decay.ci95(v, s, dof)
    out.update(extra)
    return out


def output_error_fit(launch: Launch, rig: PendulumRig, start, ext, form="chin"):
    """ODE fit of the whole trace for one damping form; returns (results dict, DecayFit)."""
    fit = decay.fit_decay(launch.t, launch.x, start, ext, sine=True, linear=(form == "chin"), quadratic=True)
    names = fit.names
    p = np.array([fit.params[n] for n in names])

    def physical(q):
        d = dict(zip(names, q))
        c = coefficients_from_rates(d["a0"], d.get("aL", 0.0), d["aQ"], rig)
        return np.array([c[k] for k in _KEYS])

    val, cov = decay.propagate(physical, p, fit.cov)
    return _pack(val, cov, fit.t.size - len(names), form, {"rms_residual": fit.rms, "hac_lag": fit.lag,
                                                             "nfev": fit.nfev}), fit


def identify_launch(launch: Launch, rig: PendulumRig, method="output-error", keep_fit=False) -> dict:
    """Identify one pendulum launch in both forms; raises :class:`LaunchError` on bad data.

    Physically impossible results (negative added mass, damping or drag, :func:`decay.physical_check`) are listed
    in ``impossible`` (reasons); :func:`identification.identify.identify_files` then reports the launch as not ok.

    Returns
    -------
    dict
        ``amplitude`` (rad), ``v_max`` (m/s at the model), ``Re``, the Chin results at top level
        (``Cm``, ``added_mass_kg``, ``KL``, ``KQ`` with ``*_se``/``*_ci95``; ``CD_chin`` = 2 K_Q / (rho A)),
        ``CD`` from the Morison fit (as the paper's Table 10) and all Morison results under ``morison``.
    """
    start, ext, noise = decay.prepare(launch)
    amp = decay.launch_amplitude(launch.x, start, ext)
    res = {"amplitude": amp, "amplitude_deg": math.degrees(amp),
           "n_peaks": ext.count, "noise": noise}
    fits = {}
    for form in FORMS:
        if method == "output-error":
            out, fits[form] = output_error_fit(launch, rig, start, ext, form)
        elif method in ("regression", "graphical"):
            out = regression_fit(launch, rig, start, ext, form)
        else:
            raise ValueError(f"unknown fit method {method!r} (expected output-error or graphical)")
        if form == "chin":
            res.update(out)
        else:
            res["morison"] = out
    # the paper's C_D (Table 10) is the Morison fit's; the Chin fit's K_Q expressed as a C_D is kept as CD_chin
    for suffix in ("", "_se", "_ci95"):
        res["CD_chin" + suffix] = res.pop("CD" + suffix)
        res["CD" + suffix] = res["morison"]["CD" + suffix]
    if res["added_mass_kg"] <= -rig.mass:
        raise LaunchError(launch.path, f"fitted frequency {res['omega_n']:.3g} rad/s implies a negative total mass "
                          "(check --length, --mass, --volume)")
    fit = fits.get("chin")
    if fit is not None:
        rate = np.gradient(fit.model, fit.t)
    else:
        period = 2 * float(np.mean(np.diff(ext.t)))
        rate = savgol_derivatives(launch.t[start:], launch.x[start:], period / SG_WINDOW_PERIODS,
                                  order=SG_ORDER)[1]
    res["v_max"] = float(np.max(np.abs(rate)) * rig.length)
    res["Re"] = res["v_max"] * rig.length_scale / NU_WATER
    check = decay.physical_check(res)
    res["impossible"], res["doubtful"] = list(check.impossible), list(check.doubtful)
    if keep_fit:
        res["_fit"] = fit
        res["_graph"] = (launch, start, ext, None)
    return res
