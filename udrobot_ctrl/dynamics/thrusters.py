"""Blue Robotics T-200 thrusters: PWM <-> thrust curve, limits, controllability and thrust allocation.

Thruster curve
--------------
Fitted to Blue Robotics' bollard measurements (T200 Public Performance Data, 10-20 V, September 2019,
``../shared/data/t200/``; one thruster, Basic ESC R3). The coefficients live in ``models/t200.toml``
(with the data file's sha256, the fit residuals and provenance); this module only evaluates them, so
nothing here needs the data. :func:`fit_t200` / ``python -m udrobot_ctrl.dynamics.thrusters --data CSV --out TOML``
regenerates the file from the data.

Per measured supply voltage V_j in {10, 12, 14, 16, 18, 20} V and per direction (forward pwm > 1500,
reverse pwm < 1500) the thrust magnitude is a quartic without constant term::

    |T| = sum_k c_k x^k,   x = (|pwm - 1500| - d0) / 100   for |pwm - 1500| > d0,   T = 0 otherwise,

pinned to the direction's measured maximum at 1900 / 1100 us. The curve is continuous and strictly
monotone outside the zero band |pwm - 1500| <= d0 (where the propeller does not turn; Blue Robotics
zeroed every point under 300 RPM and the fit uses only the non-zero points). Between measured voltages
the thrust is interpolated linearly in V; outside 10-20 V it is scaled from the nearest end by the power
law T_max ~ V^a fitted to the data (a ~ 1.20 forward, ~ 1.13 reverse).

Limits: at 12 V the curve gives 36.4 N forward and 28.6 N reverse, the measured values. The UDrobot
paper (Cely 2019 sec. 3.1) quotes "12 V, 34.3 N" (3.5 kgf) without a source or a direction; it is 94 %
of the measured 12 V maximum and gives no reverse value, so it is **not used**: the measured,
direction-dependent Blue Robotics figures are.

The data are bollard thrust (zero inflow): nothing says how thrust falls with advance speed, so
this model ignores it (an optimistic assumption at speed). Longer tethers/cables sag the voltage.

Allocation
----------
:func:`thrust_allocation_pinv` (unconstrained minimum-norm least squares) and :class:`ThrustAllocator`
(box-constrained weighted least squares solved with OSQP, warm-started, never raises).
"""
from __future__ import annotations

import argparse
import hashlib
from dataclasses import dataclass, field
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
import tomllib

from udrobot_ctrl.constants import DOF_NAMES
from udrobot_files.inputs import read_regular
from udrobot_files.output import atomic_write

PWM_NEUTRAL = 1500.0
PWM_MIN = 1100.0
PWM_MAX = 1900.0
PWM_SCALE = 100.0  # us; x = (|pwm - 1500| - d0) / PWM_SCALE
DEFAULT_VOLTAGE = 12.0  # V, Cely 2019 sec. 3.1 nominal supply


# ----------------------------------------------------------------------------- curve
@dataclass(frozen=True)
class ThrusterCurve:
    """Fitted PWM -> thrust curve of one thruster type over supply voltage.

    Attributes
    ----------
    voltages : (m,) ndarray
        Supply voltages of the fitted curves, V, increasing.
    fwd_d0, rev_d0 : (m,) ndarray
        Half-width of the zero band per voltage, us, forward and reverse.
    fwd_coeffs, rev_coeffs : (m, deg) ndarray
        Coefficients c_1..c_deg of |T| (N) in x = (|pwm-1500| - d0)/100.
    fwd_exponent, rev_exponent : float
        Power-law voltage exponents (dimensionless) used outside ``voltages``.
    pwm_min, pwm_max : float
        ESC command range, us.
    name : str
        Curve name (``t200``).
    provenance : dict
        Source, fit and residual notes from the TOML.
    """

    voltages: np.ndarray
    fwd_d0: np.ndarray
    rev_d0: np.ndarray
    fwd_coeffs: np.ndarray
    rev_coeffs: np.ndarray
    fwd_exponent: float
    rev_exponent: float
    pwm_min: float = PWM_MIN
    pwm_max: float = PWM_MAX
    name: str = "t200"
    provenance: dict = field(default_factory=dict)


def curve_from_dict(doc: dict, source: str = "<dict>") -> ThrusterCurve:
    """Parse the ``udrobot-thruster/1`` document of a thruster curve (see ``models/t200.toml``)."""
    try:
        rows = sorted(doc["curve"], key=lambda c: float(c["voltage"]))
        volts = np.array([float(c["voltage"]) for c in rows])
        fwd_d0 = np.array([float(c["forward"]["d0"]) for c in rows])
        rev_d0 = np.array([float(c["reverse"]["d0"]) for c in rows])
        fwd = np.array([[float(v) for v in c["forward"]["coeffs"]] for c in rows])
        rev = np.array([[float(v) for v in c["reverse"]["coeffs"]] for c in rows])
        ve = doc["voltage_extrapolation"]
        curve = ThrusterCurve(volts, fwd_d0, rev_d0, fwd, rev, float(ve["forward_exponent"]),
                              float(ve["reverse_exponent"]), float(doc.get("pwm_min", PWM_MIN)),
                              float(doc.get("pwm_max", PWM_MAX)), str(doc.get("name", "t200")),
                              dict(doc.get("provenance", {})))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{source}: malformed thruster curve ({exc!r}); expected [[curve]] tables with voltage, "
                         "forward/reverse {d0, coeffs} and [voltage_extrapolation]") from exc
    if volts.size == 0 or np.any(np.diff(volts) <= 0):
        raise ValueError(f"{source}: [[curve]] voltages must be distinct, got {volts.tolist()}")
    return curve


#: the largest thruster-curve file read, bytes (assumed: the shipped models/t200.toml is 4.7 kB for four
#: voltages; 256 kB holds a curve of hundreds of voltages and stops an endless or huge file at once)
MAX_CURVE_BYTES = 256 * 1024


def shipped_curve_name(name: str) -> bool:
    """True if ``name`` is a plain name (no folder, no ``..``, no suffix) of a curve shipped in
    ``udrobot_ctrl.models`` (``t200``)."""
    if not isinstance(name, str) or not name or name.startswith(".") or any(c in name for c in "/\\\0"):
        return False
    return resources.files("udrobot_ctrl.models").joinpath(f"{name}.toml").is_file()


@cache
def load_curve(name_or_path: str = "t200") -> ThrusterCurve:
    """The shipped curve ``t200`` (``models/t200.toml``) or a curve TOML path.

    A plain name is looked up only among the shipped curves (never joined into a path that leaves the package);
    a path is read only if it is a regular file of at most :data:`MAX_CURVE_BYTES` (never a pipe or a device).
    A model file's reference is resolved first (:func:`udrobot_ctrl.vehicle.resolve_curve`: inside the package
    or next to the model only).

    Parameters
    ----------
    name_or_path : str or Path
        ``t200`` or the path of a ``udrobot-thruster/1`` TOML.

    Returns
    -------
    ThrusterCurve
        The fitted PWM -> thrust curve.
    """
    if shipped_curve_name(name_or_path):
        res = resources.files("udrobot_ctrl.models").joinpath(f"{name_or_path}.toml")
        return curve_from_dict(tomllib.loads(res.read_text()), f"models/{name_or_path}.toml")
    path = Path(name_or_path)
    if path.suffix.lower() != ".toml":
        raise FileNotFoundError(f"thruster curve {name_or_path!r} is not shipped in udrobot_ctrl.models (shipped: "
                                f"t200) and is not a .toml file")
    data = read_regular(path, MAX_CURVE_BYTES, "thruster curve")
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"thruster curve {path}: not a UTF-8 TOML file ({exc})") from None
    return curve_from_dict(doc, str(path))


def _poly_mag(dpwm_abs, d0, coeffs):
    """|T| (N) for |pwm-1500| = dpwm_abs (us) with zero band d0 (us) and coefficients c_1.. (broadcast)."""
    coeffs = np.asarray(coeffs, float)
    x = np.maximum(np.asarray(dpwm_abs, float) - d0, 0.0) / PWM_SCALE
    out = np.zeros(np.broadcast_shapes(np.shape(x), np.shape(coeffs[..., 0])))
    for k in range(coeffs.shape[-1] - 1, -1, -1):  # Horner, no constant term
        out = (out + coeffs[..., k]) * x
    return out


def _magnitude_at_voltage(dpwm_abs, voltage, d0s, coeffs, volts, exponent):
    """Interpolate |T| linearly in voltage between the fitted curves; power law outside."""
    v = np.asarray(voltage, float)
    vc = np.clip(v, volts[0], volts[-1])
    if volts.size == 1:
        mag = _poly_mag(dpwm_abs, d0s[0], coeffs[0])
    else:
        j = np.clip(np.searchsorted(volts, vc, side="right") - 1, 0, volts.size - 2)
        w = (vc - volts[j]) / (volts[j + 1] - volts[j])
        lo = _poly_mag(dpwm_abs, d0s[j], coeffs[j])
        hi = _poly_mag(dpwm_abs, d0s[j + 1], coeffs[j + 1])
        mag = (1.0 - w) * lo + w * hi
    return mag * (np.maximum(v, 1e-9) / vc) ** exponent


def _check_voltage(voltage):
    v = np.asarray(voltage, float)
    if np.any(~np.isfinite(v)) or np.any(v <= 0):
        raise ValueError(f"supply voltage must be finite and > 0 V, got {voltage}")
    return v


def pwm_to_thrust(pwm, voltage=DEFAULT_VOLTAGE, curve: ThrusterCurve | None = None):
    """Bollard thrust (N, + forward) of a T-200 for an ESC command ``pwm`` (us) at supply ``voltage`` (V).

    Commands outside [1100, 1900] us are clipped to the range; NaN commands give NaN.
    ``pwm`` and ``voltage`` broadcast.

    Parameters
    ----------
    pwm : float or array_like
        ESC command, us.
    voltage : float or array_like
        Supply voltage, V (default 12 V, Cely 2019 sec. 3.1).
    curve : ThrusterCurve, optional
        The thruster's curve (default the shipped T-200, :func:`load_curve`).

    Returns
    -------
    float or ndarray
        Thrust, N (positive forward), the broadcast shape of ``pwm`` and ``voltage``.
    """
    c = curve or load_curve()
    v = _check_voltage(voltage)
    pwm = np.clip(np.asarray(pwm, float), c.pwm_min, c.pwm_max)
    d = pwm - PWM_NEUTRAL
    fwd = _magnitude_at_voltage(np.abs(d), v, c.fwd_d0, c.fwd_coeffs, c.voltages, c.fwd_exponent)
    rev = _magnitude_at_voltage(np.abs(d), v, c.rev_d0, c.rev_coeffs, c.voltages, c.rev_exponent)
    out = np.where(d > 0, fwd, np.where(d < 0, -rev, np.where(np.isnan(d), np.nan, 0.0)))
    return out if out.ndim else float(out)


def _band_half_width(v, volts, d0s):
    """Zero-band half-width (us) of the voltage-interpolated curve: the smaller bracketing d0 between nodes."""
    vc = min(max(v, volts[0]), volts[-1])
    j = int(np.searchsorted(volts, vc, side="right") - 1)
    if j >= volts.size - 1 or vc == volts[j]:
        return float(d0s[min(j, volts.size - 1)])
    return float(min(d0s[j], d0s[j + 1]))


def zero_band(voltage=DEFAULT_VOLTAGE, curve: ThrusterCurve | None = None):
    """(low, high) PWM (us) of the zero band at ``voltage`` (V): commands in it give no thrust."""
    c = curve or load_curve()
    v = float(_check_voltage(voltage))
    return (PWM_NEUTRAL - _band_half_width(v, c.voltages, c.rev_d0),
            PWM_NEUTRAL + _band_half_width(v, c.voltages, c.fwd_d0))


def thrust_limits(voltage=DEFAULT_VOLTAGE, curve: ThrusterCurve | None = None):
    """(max_forward_N, max_reverse_N) of one thruster at ``voltage`` (V), both positive (N)."""
    c = curve or load_curve()
    return (float(pwm_to_thrust(c.pwm_max, voltage, c)), float(-pwm_to_thrust(c.pwm_min, voltage, c)))


def thrust_to_pwm(thrust, voltage=DEFAULT_VOLTAGE, curve: ThrusterCurve | None = None, iterations: int = 48):
    """ESC command (us) producing ``thrust`` (N, + forward) at ``voltage`` (V): the inverse of :func:`pwm_to_thrust`.

    Monotone: zero thrust returns exactly 1500 us (inside the zero band); any non-zero thrust maps outside
    the band; thrust beyond the limits saturates at 1900 / 1100 us. NaN gives NaN. Solved by bisection on
    the monotone curve (``iterations`` halvings of a 400 us bracket, i.e. ~1e-12 us).

    Parameters
    ----------
    thrust : float or array_like
        Wanted thrust, N (positive forward).
    voltage : float or array_like
        Supply voltage, V (default 12 V).
    curve : ThrusterCurve, optional
        The thruster's curve (default the shipped T-200).
    iterations : int
        Bisection halvings.

    Returns
    -------
    float or ndarray
        ESC command, us, in [1100, 1900].
    """
    c = curve or load_curve()
    v = _check_voltage(voltage)
    f = np.asarray(thrust, float)
    shape = np.broadcast_shapes(f.shape, v.shape)
    f = np.broadcast_to(f, shape)
    v = np.broadcast_to(v, shape)
    lo = np.zeros(shape)
    hi = np.full(shape, max(c.pwm_max - PWM_NEUTRAL, PWM_NEUTRAL - c.pwm_min))
    mag = np.abs(f)
    pos = f > 0
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        m = np.where(pos, _magnitude_at_voltage(mid, v, c.fwd_d0, c.fwd_coeffs, c.voltages, c.fwd_exponent),
                     _magnitude_at_voltage(mid, v, c.rev_d0, c.rev_coeffs, c.voltages, c.rev_exponent))
        below = m < mag
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    out = np.where(f > 0, np.minimum(PWM_NEUTRAL + hi, c.pwm_max),
                   np.where(f < 0, np.maximum(PWM_NEUTRAL - hi, c.pwm_min), PWM_NEUTRAL))
    out = np.where(np.isnan(f), np.nan, out)
    return out if out.ndim else float(out)


# ----------------------------------------------------------------------------- fitting (needs the data)
def _fit_direction(dabs, thrust_abs, degree, d_end, limit):
    """Fit d0 and c_1..c_deg with the curve pinned to ``limit`` (N) at |pwm-1500| = ``d_end`` (us)."""
    from scipy.optimize import least_squares

    def coeffs_of(p):
        head = np.asarray(p[1:], float)
        x_end = (d_end - p[0]) / PWM_SCALE
        rest = limit - sum(c * x_end ** (k + 1) for k, c in enumerate(head))
        return np.r_[head, rest / x_end ** degree]

    def residual(p):
        return _poly_mag(dabs, p[0], coeffs_of(p)) - thrust_abs

    p0 = np.r_[30.0, np.full(degree - 1, 0.5)]
    sol = least_squares(residual, p0, bounds=([0.0] + [-np.inf] * (degree - 1), [80.0] + [np.inf] * (degree - 1)),
                        x_scale=np.r_[10.0, np.ones(degree - 1)])
    c = coeffs_of(sol.x)
    grid = np.linspace(sol.x[0], d_end, 801)
    if np.any(np.diff(_poly_mag(grid, sol.x[0], c)) <= 0):
        raise ValueError(f"fitted curve is not monotone (degree {degree}, limit {limit:.2f} N); try another degree")
    r = sol.fun
    return float(sol.x[0]), [float(v) for v in c], float(np.sqrt(np.mean(r ** 2))), float(np.abs(r).max())


def read_t200_csv(path):
    """Columns voltage_V, pwm_us, thrust_N of Blue Robotics' tidy T200 table (``t200_performance_tidy.csv``)."""
    path = Path(path)
    data = np.genfromtxt(path, delimiter=",", names=True)
    for col in ("voltage_V", "pwm_us", "thrust_N"):
        if col not in (data.dtype.names or ()):
            raise ValueError(f"{path}: missing column {col!r} (expected the tidy T200 table)")
    return data["voltage_V"], data["pwm_us"], data["thrust_N"]


def fit_t200(csv_path, degree: int = 4) -> dict:
    """Fit the curve of this module to Blue Robotics' tidy T200 CSV; returns the ``udrobot-thruster/1`` document.

    Points exactly zero (Blue Robotics' "< 300 RPM" zeroing) are excluded from each direction's fit; each
    direction is pinned to its measured maximum |thrust| (mean of 5 repeats at full throttle).
    """
    csv_path = Path(csv_path)
    V, pwm, T = read_t200_csv(csv_path)
    rows, all_rms = [], []
    for volt in np.unique(V):
        row = {"voltage": float(volt)}
        for key, sign in (("forward", 1.0), ("reverse", -1.0)):
            m = (V == volt) & (np.sign(pwm - PWM_NEUTRAL) == sign) & (T != 0)
            end = PWM_MAX if sign > 0 else PWM_MIN
            limit = float(np.abs(T[m]).max())  # the table's maximum (12 V reverse peaks at 1104 us)
            d0, coeffs, rms, worst = _fit_direction(np.abs(pwm[m] - PWM_NEUTRAL), np.abs(T[m]), degree,
                                                    abs(end - PWM_NEUTRAL), limit)
            zeros = pwm[(V == volt) & (T == 0)]
            row[key] = {"d0": round(d0, 4), "coeffs": [float(f"{c:.10g}") for c in coeffs],
                        "rms_N": round(rms, 4), "max_abs_N": round(worst, 4), "limit_N": round(limit, 4),
                        "data_zero_band_us": [float(zeros.min()), float(zeros.max())], "n_points": int(m.sum())}
            all_rms.append(rms)
        rows.append(row)
    volts = np.array([r["voltage"] for r in rows])
    exps = {}
    for key in ("forward", "reverse"):
        lim = np.array([r[key]["limit_N"] for r in rows])
        exps[key] = float(np.polyfit(np.log(volts), np.log(lim), 1)[0])
    sha = hashlib.sha256(csv_path.read_bytes()).hexdigest()
    return {
        "format": "udrobot-thruster/1",
        "name": "t200",
        "pwm_min": PWM_MIN,
        "pwm_max": PWM_MAX,
        "pwm_neutral": PWM_NEUTRAL,
        "form": (f"|T| = sum_k coeffs[k-1] * x^k (k = 1..{degree}), x = (|pwm - 1500| - d0) / 100 for "
                 "|pwm - 1500| > d0, else 0 (zero band); T > 0 for pwm > 1500 (forward), T < 0 below; "
                 "linear in voltage between [[curve]] entries, power law V^exponent outside"),
        "provenance": {
            "source": "measured: Blue Robotics T200 Public Performance Data 10-20 V, September 2019 (bollard "
                      "thrust, Basic ESC R3, 1 m 18 AWG cable); tidy CSV ../shared/data/t200/"
                      "t200_performance_tidy.csv, see its PROVENANCE.md",
            "data_sha256": sha,
            "fit": f"least squares per voltage and direction of d0 and {degree} coefficients on the non-zero points "
                   "(points under 300 RPM were zeroed by Blue Robotics and are excluded), pinned to the measured "
                   "maximum |thrust| at 1900 / 1100 us; udrobot_ctrl.dynamics.thrusters.fit_t200",
            "residual": f"mean rms over voltages and directions {np.mean(all_rms):.3f} N, worst point "
                        f"{max(max(r['forward']['max_abs_N'], r['reverse']['max_abs_N']) for r in rows):.3f} N "
                        "(per curve: rms_N, max_abs_N)",
            "paper_34_3N": "not used: Cely 2019 sec. 3.1 quotes '12 V, 34.3 N' (3.5 kgf) without source or "
                           "direction; it is 94 % of the measured 12 V forward maximum (36.4 N) and gives no "
                           "reverse value. The measured direction-dependent Blue Robotics limits are used.",
            "speed_effect": "assumed none: bollard data only; thrust loss with advance speed is not modelled",
        },
        "voltage_extrapolation": {
            "forward_exponent": round(exps["forward"], 4), "reverse_exponent": round(exps["reverse"], 4),
            "provenance": "derived: log-log least squares of the measured maximum thrust over 10-20 V",
        },
        "curve": rows,
    }


def write_curve_toml(doc: dict, path, protect=()) -> None:
    """Write a thruster-curve document as TOML (atomically)."""
    import tomli_w

    path = Path(path)
    header = ("# T-200 PWM -> thrust curve (udrobot-thruster/1), generated by\n"
              "#   python -m udrobot_ctrl.dynamics.thrusters --data ../shared/data/t200/t200_performance_tidy.csv "
              "--out models/t200.toml\n# Fitted coefficients only: the measured data are not copied here.\n")
    atomic_write(path, header + tomli_w.dumps(doc), protect=protect)


# ----------------------------------------------------------------------------- controllability
@dataclass(frozen=True)
class Controllability:
    """Which degrees of freedom a thruster layout can act on.

    Attributes
    ----------
    rank : int
        Rank of the 6 x n thruster matrix T (number of independently controllable wrench directions).
    actuated : tuple of str
        DOFs whose unit wrench lies in the range of T (can be commanded alone, e.g. pure surge).
    coupled : tuple of str
        DOFs T acts on only together with others (non-zero row, unit wrench not in range(T)).
    passive : tuple of str
        DOFs with a zero row in T: left to damping and restoring forces (passive stability).
    """

    rank: int
    actuated: tuple
    coupled: tuple
    passive: tuple

    def summary(self) -> str:
        return (f"rank(T) = {self.rank}; actuated: {', '.join(self.actuated) or 'none'}; "
                f"coupled: {', '.join(self.coupled) or 'none'}; passive: {', '.join(self.passive) or 'none'}")


def actuated_dofs(T, tol: float = 1e-9) -> Controllability:
    """Controllability of each DOF (X Y Z K M N) by the thruster matrix ``T`` (6 x n, tau = T f)."""
    T = np.asarray(T, float)
    if T.ndim != 2 or T.shape[0] != 6:
        raise ValueError(f"thruster matrix must be 6 x n, got shape {T.shape}")
    scale = max(1.0, float(np.abs(T).max())) if T.size else 1.0
    rank = int(np.linalg.matrix_rank(T, tol * scale)) if T.size else 0
    pinv = np.linalg.pinv(T) if T.size else np.zeros((0, 6))
    act, cpl, pas = [], [], []
    for i, name in enumerate(DOF_NAMES):
        if T.size == 0 or np.all(np.abs(T[i]) <= tol * scale):
            pas.append(name)
            continue
        e = np.zeros(6)
        e[i] = 1.0
        (act if np.linalg.norm(T @ (pinv @ e) - e) <= 1e-6 else cpl).append(name)
    return Controllability(rank, tuple(act), tuple(cpl), tuple(pas))


# ----------------------------------------------------------------------------- allocation
def thrust_allocation_pinv(T, tau):
    """Unconstrained minimum-norm thrusts f = T^+ tau (N) for a wrench ``tau`` (..., 6) (N, N m)."""
    return np.asarray(tau, float) @ np.linalg.pinv(np.asarray(T, float)).T


@dataclass
class AllocationResult:
    """Outcome of one allocation.

    Attributes
    ----------
    f : (n,) ndarray
        Thrusts, N, within each thruster's limits.
    unachieved : (6,) ndarray
        tau - T f, N and N m: the part of the requested wrench that could not be produced.
    ok : bool
        True if OSQP solved the problem; False when a fallback was used (see ``status``).
    status : str
        Solver status or the reason for the fallback.
    """

    f: np.ndarray
    unachieved: np.ndarray
    ok: bool
    status: str


class ThrustAllocator:
    """Box-constrained thrust allocation with OSQP, warm-started between calls.

    Solves  min_f ||T f - tau||_W^2 + eps ||f||^2  s.t.  -max_reverse_i <= f_i <= max_forward_i.

    Parameters
    ----------
    T : (6, n) array_like
        Thruster matrix.
    f_min, f_max : (n,) array_like
        Thrust limits, N (f_min <= 0 <= f_max normally).
    weights : (6,) array_like, optional
        Diagonal of W (per-DOF importance; forces in 1/N^2, moments in 1/(N m)^2).
    eps : float
        Thrust regulariser, 1/N^2 (a weight), picks the minimum-effort solution among equals.
    """

    def __init__(self, T, f_min, f_max, weights=None, eps: float = 1e-6):
        import osqp
        import scipy.sparse as sp

        self.T = np.asarray(T, float)
        n = self.T.shape[1]
        self.f_min = np.broadcast_to(np.asarray(f_min, float), (n,)).copy()
        self.f_max = np.broadcast_to(np.asarray(f_max, float), (n,)).copy()
        self.W = np.ones(6) if weights is None else np.asarray(weights, float)
        self.eps = float(eps)
        self._bad_limits = bool(np.any(self.f_min > self.f_max) or not np.all(np.isfinite(self.f_min))
                                or not np.all(np.isfinite(self.f_max)))
        self._TW = self.T.T * self.W  # (n, 6) = T^T W
        P = 2.0 * (self._TW @ self.T + self.eps * np.eye(n))
        self._solver = None
        if not self._bad_limits:
            new_api = int(str(getattr(osqp, "__version__", "0")).split(".")[0]) >= 1
            # no polishing: at eps 1e-9 it changes nothing measurable here, and OSQP 1.x prints
            # "Polishing not needed ..." to stdout on every unconstrained solve even with verbose=False
            opts = {"warm_starting": True, "polishing": False} if new_api else {"warm_start": True, "polish": False}
            self._solve_kw = {"raise_error": False} if new_api else {}
            self._solver = osqp.OSQP()
            self._solver.setup(P=sp.triu(sp.csc_matrix(P)).tocsc(), q=np.zeros(n),
                               A=sp.identity(n, format="csc"), l=self.f_min, u=self.f_max, verbose=False,
                               eps_abs=1e-9, eps_rel=1e-9, max_iter=4000, **opts)

    @classmethod
    def from_parameters(cls, p, **kw) -> ThrustAllocator:
        """Allocator for a :class:`~udrobot_ctrl.dynamics.plant.PlantParameters` (its T, f_min, f_max)."""
        return cls(p.T, p.f_min, p.f_max, **kw)

    def _fallback(self, tau, reason):
        lo, hi = np.minimum(self.f_min, self.f_max), np.maximum(self.f_min, self.f_max)
        f = np.clip(thrust_allocation_pinv(self.T, np.nan_to_num(tau)), np.nan_to_num(lo), np.nan_to_num(hi))
        f = np.where(np.isfinite(f), f, 0.0)
        return AllocationResult(f, np.asarray(tau, float) - self.T @ f, False, reason)

    def __call__(self, tau) -> AllocationResult:
        """Allocate the wrench ``tau`` (6,) (N, N m); never raises."""
        n = self.T.shape[1]
        try:
            tau = np.asarray(tau, float).reshape(6)
        except (TypeError, ValueError) as exc:
            return AllocationResult(np.zeros(n), np.full(6, np.nan), False, f"bad tau ({exc}): zero thrust")
        if not np.all(np.isfinite(tau)):
            return AllocationResult(np.zeros(n), tau.copy(), False, "non-finite tau: zero thrust")
        if self._bad_limits:
            return self._fallback(tau, "inconsistent thrust limits (f_min > f_max or non-finite): clipped pinv")
        try:
            self._solver.update(q=-2.0 * self._TW @ tau)
            res = self._solver.solve(**self._solve_kw)
            status = str(res.info.status)
            f = np.asarray(res.x, float)
            if not np.all(np.isfinite(f)) or "solved" not in status.lower() or "inaccurate" in status.lower():
                return self._fallback(tau, f"OSQP status {status!r}: clipped pseudo-inverse used")
        except Exception as exc:  # noqa: BLE001 - an allocator in the loop must never throw
            return self._fallback(tau, f"OSQP failed ({exc}): clipped pseudo-inverse used")
        f = np.clip(f, self.f_min, self.f_max)
        return AllocationResult(f, tau - self.T @ f, True, status)


def _main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m udrobot_ctrl.dynamics.thrusters", description="Refit models/t200.toml")
    ap.add_argument("--data", required=True, help="t200_performance_tidy.csv")
    ap.add_argument("--out", required=True, help="output TOML")
    ap.add_argument("--degree", type=int, default=4)
    args = ap.parse_args(argv)
    doc = fit_t200(args.data, args.degree)
    write_curve_toml(doc, args.out, protect=[args.data])
    for row in doc["curve"]:
        f, r = row["forward"], row["reverse"]
        print(f"{row['voltage']:5.1f} V  fwd d0 {f['d0']:6.2f} us rms {f['rms_N']:.3f} max {f['max_abs_N']:.3f} N "
              f"limit {f['limit_N']:.2f} N | rev d0 {r['d0']:6.2f} us rms {r['rms_N']:.3f} max {r['max_abs_N']:.3f} N "
              f"limit {r['limit_N']:.2f} N")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
