"""Spring free-decay test (Cely 2019 sec. 3.2, eqs. 6-9).

The scale model hangs from a spring of stiffness K and oscillates along one body axis:

    (m + m') y'' + c y' + 1/2 rho C_D A |y'| y' + K y = 0                         (eq. 6)

with m the model's mass, m' its added mass, c the linear damping (the spring/rig's mechanical
damping plus any linear fluid damping), A the projected area the drag coefficient C_D refers to.

Graphical (paper) method
------------------------
From two successive same-sign peaks: damped period T_d, logarithmic decrement delta,
zeta = delta / sqrt(4 pi^2 + delta^2), omega_n = 2 pi / (T_d sqrt(1 - zeta^2)) and (eq. 7)
m' = K / omega_n^2 - m, C_m = m' / (rho V). The damping ratio splits as zeta = zeta_s + zeta_f
(eq. 8); zeta_s = c_s / (2 (m + m') omega_n) from the rig's mechanical damping c_s (option,
default 0: all damping attributed to the fluid). The fluid part gives C_D by equivalent
linearisation of the quadratic drag over one cycle of amplitude X (energy balance):

    zeta_f = 2 rho C_D A X / (3 pi (m + m'))

Eq. 9 of the paper, zeta_f = rho D^2 / (4 pi (m + m')) (8/3) C_D A/D = 2 rho D A C_D / (3 pi (m + m')),
is the same expression written for a 2-D section per unit length (projected area D x 1 m, with the
paper's "A" the launch amplitude). We use the model's projected area ``area`` (m^2) and, for X, the
geometric mean of the two peak amplitudes of the decrement (the mean amplitude of that cycle; the
paper uses the launch amplitude, which over-weights the first half cycle).

Output-error method (default)
-----------------------------
Eq. 6 divided by m + m' is fitted to the whole trace (see :mod:`identification.decay`), estimating
omega_n^2, c/(m+m'), (1/2 rho C_D A)/(m+m'), the release position and speed and the rest offset;
the physical coefficients follow with delta-method 95 % intervals from the HAC covariance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from identification import decay
from identification.decay import Launch, LaunchError

COUNTS_PER_MM = 2.45  # LX-EP-40 encoder, Cely 2019 sec. 3.2.1 (measured)
NU_WATER = 1.0e-6  # m^2/s, kinematic viscosity of fresh water near 20 C (assumed)


@dataclass(frozen=True)
class SpringRig:
    """Spring free-decay rig and model (SI units).

    Attributes
    ----------
    mass : float
        Model mass m, kg (Table 2: 0.97).
    volume : float
        Model displaced volume V, m^3 (Table 2: 344,868 mm^3 = 3.44868e-4).
    stiffness : float
        Spring constant K, N/m (63.6).
    area : float
        Projected area A that C_D refers to, m^2.
    rho : float
        Water density, kg/m^3.
    mechanical_damping : float
        Linear damping c_s of the rig itself (measured in air), N s/m; subtracted to get K_L.
    dimension : float or None
        Characteristic length for the Reynolds number, m (default sqrt(area)).
    counts_per_mm : float
        Encoder resolution for ``counts`` logs.
    """

    mass: float
    volume: float
    stiffness: float
    area: float
    rho: float = 1000.0
    mechanical_damping: float = 0.0
    dimension: float | None = None
    counts_per_mm: float = COUNTS_PER_MM

    def __post_init__(self):
        for name in ("mass", "volume", "stiffness", "area", "rho"):
            v = getattr(self, name)
            if v is None or not np.isfinite(v) or v <= 0:
                raise ValueError(f"spring rig: {name} must be a positive number in SI units, got {v!r}")

    @property
    def length_scale(self) -> float:
        return float(self.dimension or math.sqrt(self.area))


def added_mass_from_frequency(omega_n, stiffness, mass):
    """Eq. 7 solved for the added mass: m' = K / omega_n^2 - m (kg)."""
    return stiffness / np.asarray(omega_n, float) ** 2 - mass


def mass_coefficient(added_mass, rho, volume):
    """C_m = m' / (rho V) (dimensionless)."""
    return np.asarray(added_mass, float) / (rho * volume)


def damping_ratio_from_decrement(delta):
    """zeta from the logarithmic decrement over one full period."""
    delta = np.asarray(delta, float)
    return delta / np.sqrt(4 * np.pi ** 2 + delta ** 2)


def drag_coefficient_from_fluid_damping(zeta_f, total_mass, rho, area, amplitude):
    """C_D from zeta_f = 2 rho C_D A X / (3 pi (m + m')) (eq. 9 in 3-D form, see module docstring)."""
    return 3 * np.pi * np.asarray(total_mass, float) * np.asarray(zeta_f, float) / (2 * rho * area * amplitude)


def drag_coefficient_paper_eq9(zeta_f, total_mass, rho, dimension, amplitude):
    """C_D from the paper's eq. 9 literally (2-D section: projected area D per metre of length)."""
    return drag_coefficient_from_fluid_damping(zeta_f, total_mass, rho, dimension * 1.0, amplitude)


def read_spring_launch(path, counts_per_mm=COUNTS_PER_MM) -> Launch:
    """Read a ``t,y`` (m) or ``t,counts`` (encoder counts) launch CSV.

    Parameters
    ----------
    path : str or Path
        The CSV (t in s).
    counts_per_mm : float
        Encoder counts per mm of a ``counts`` file (default 2.45: the LX-EP-40 encoder, Cely 2019 sec. 3.2.1).

    Returns
    -------
    Launch
        Times (s), displacement (m) and the sensor's quantisation step (m).
    """
    cols, label = decay.read_columns(path, {"y": ("t", "y"), "counts": ("t", "counts")})
    if label == "counts":
        x = cols["counts"] / counts_per_mm * 1e-3
        res = 1e-3 / counts_per_mm
    else:
        x = cols["y"]
        res = decay.estimate_resolution(x)
    return Launch(str(path), cols["t"], x, res)


def _graphical(launch: Launch, rig: SpringRig, start, ext, noise=0.0):
    """The paper's peak method; standard errors from the amplitude noise and the peak-timing resolution.

    Uncertainty model (first order): each turning-point amplitude carries the sensor noise and
    quantisation, sigma_x = sqrt(noise^2 + q^2 / 12); each turning-point time is known to one sample
    interval (uniform, dt / sqrt(12)), so the mean period over n half cycles has
    sigma_T = 2 sqrt(2) (dt / sqrt(12)) / n. Both are propagated by the delta method.
    """
    xs = np.abs(ext.x)
    # the release instant is known only to a few samples: period and decrement from the turning
    # points after it when there are enough of them (two consecutive same-sign peaks, Fig. 7)
    i0 = 1 if ext.count >= 4 else 0
    n_half = ext.count - 1 - i0
    td = 2 * float(ext.t[-1] - ext.t[i0]) / n_half
    if not xs[i0 + 2] < xs[i0]:
        raise LaunchError(launch.path, f"amplitude does not decay between the first peaks ({xs[0]:.4g} -> {xs[2]:.4g})")

    def physical(q):
        td_, x0, x2 = q
        delta_ = math.log(x0 / x2)
        zeta_ = float(damping_ratio_from_decrement(delta_))
        wn_ = 2 * math.pi / td_ / math.sqrt(1 - zeta_ ** 2)
        ma_ = float(added_mass_from_frequency(wn_, rig.stiffness, rig.mass))
        M_ = rig.mass + ma_
        zeta_f_ = zeta_ - rig.mechanical_damping / (2 * M_ * wn_)
        cd_ = float(drag_coefficient_from_fluid_damping(zeta_f_, M_, rig.rho, rig.area, math.sqrt(x0 * x2)))
        return np.array([wn_, zeta_, zeta_f_, ma_, float(mass_coefficient(ma_, rig.rho, rig.volume)), cd_,
                         0.5 * rig.rho * cd_ * rig.area, delta_])

    dt = float(np.median(np.diff(launch.t)))
    sx = math.sqrt(noise ** 2 + launch.resolution ** 2 / 12)
    st = 2 * math.sqrt(2) * (dt / math.sqrt(12)) / n_half
    q = np.array([td, xs[i0], xs[i0 + 2]])
    val, cov = decay.propagate(physical, q, np.diag([st ** 2, sx ** 2, sx ** 2]))
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    keys = ("omega_n", "zeta", "zeta_f", "added_mass_kg", "Cm", "CD", "KQ", "log_decrement")
    out = {"damped_period": td}
    for k, v, e in zip(keys, val, se):
        out[k] = float(v)
        if k in ("omega_n", "added_mass_kg", "Cm", "CD", "KQ", "zeta"):
            out[k + "_se"] = float(e)
            out[k + "_ci95"] = [float(v - 1.96 * e), float(v + 1.96 * e)]
    return out


def _output_error(launch: Launch, rig: SpringRig, start, ext, linear=True):
    fit = decay.fit_decay(launch.t, launch.x, start, ext, sine=False, linear=linear, quadratic=True)
    names = fit.names
    p = np.array([fit.params[n] for n in names])
    K, m, rho, A, V = rig.stiffness, rig.mass, rig.rho, rig.area, rig.volume

    def physical(q):
        d = dict(zip(names, q))
        M = K / d["a0"]
        c = d.get("aL", 0.0) * M
        kq = d["aQ"] * M
        wn = math.sqrt(d["a0"])
        return np.array([M - m, (M - m) / (rho * V), 2 * kq / (rho * A), kq, c - rig.mechanical_damping,
                         wn, (c + 0.0) / (2 * M * wn)])

    val, cov = decay.propagate(physical, p, fit.cov)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    dof = fit.t.size - len(names)
    keys = ("added_mass_kg", "Cm", "CD", "KQ", "KL", "omega_n", "zeta_linear")
    out = {}
    for k, v, s in zip(keys, val, se):
        out[k] = float(v)
        out[k + "_se"] = float(s)
        out[k + "_ci95"] = decay.ci95(v, s, dof)
    if not linear:
        for k in ("KL", "KL_se", "KL_ci95"):
            out.pop(k)
    out.update({"rms_residual": fit.rms, "hac_lag": fit.lag, "nfev": fit.nfev})
    return out, fit


def identify_launch(launch: Launch, rig: SpringRig, method="output-error", keep_fit=False) -> dict:
    """Identify one spring launch; raises :class:`LaunchError` on bad data.

    Physically impossible results (negative added mass, damping or drag, :func:`decay.physical_check`) are listed
    in ``impossible`` (reasons); :func:`identification.identify.identify_files` then reports the launch as not ok.

    Returns
    -------
    dict
        ``amplitude`` (m, launch amplitude from rest), ``v_max`` (m/s), ``Re``, ``omega_n``
        (rad/s), ``Cm``, ``added_mass_kg``, ``CD``, ``KQ`` (N s^2/m^2), ``KL`` (N s/m, output-error
        only) and, for the output-error fit, ``*_se`` / ``*_ci95``.
    """
    start, ext, noise = decay.prepare(launch)
    res = {"amplitude": decay.launch_amplitude(launch.x, start, ext), "n_peaks": ext.count, "noise": noise}
    g = _graphical(launch, rig, start, ext, noise)
    fit = None
    if method == "graphical":
        res.update(g)
    elif method == "output-error":
        oe, fit = _output_error(launch, rig, start, ext)
        res.update(oe)
        res["graphical"] = {k: g[k] for k in ("Cm", "CD", "omega_n", "zeta")}
    else:
        raise ValueError(f"unknown fit method {method!r} (expected output-error or graphical)")
    wn = res["omega_n"]
    res["v_max"] = decay.peak_speed(launch.t, launch.x, start, g["damped_period"]) if fit is None \
        else float(np.max(np.abs(np.gradient(fit.model, fit.t))))
    res["v_max_linear"] = res["amplitude"] * wn
    res["Re"] = res["v_max"] * rig.length_scale / NU_WATER
    check = decay.physical_check(res)
    res["impossible"], res["doubtful"] = list(check.impossible), list(check.doubtful)
    if keep_fit:
        res["_fit"] = fit
        res["_graph"] = (launch, start, ext, g)
    return res
