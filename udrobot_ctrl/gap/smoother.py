"""Model-based smoother: what a run did not measure, reconstructed from what it did (forward EKF + backward RTS).

A stock small ROV logs depth, attitude, gyro rates, an accelerometer and its thruster outputs, but no body
velocity (DVL) and no position (USBL). The equation-error diagnosis needs every body velocity and its
derivative; this module reconstructs them with the nominal plant as process model and reports how well each
is known (posterior standard deviation), so that :mod:`udrobot_ctrl.gap.identifiability` can tell which effects
the measured channels can still identify.

State (21, or 19 when neither ``x`` nor ``y`` is logged: the dynamics never depend on them, and an unobserved
position only makes the covariance ill-conditioned; it is then dead-reckoned from the smoothed velocity):

    s = [eta (6), nu (6), d (6), b (3)]

* ``eta, nu``: pose (NED, ZYX Euler) and body velocity; ``nu_dot = f_nominal(eta, nu, tau) + d``, with ``f`` the
  project's casadi twin of the plant (:func:`udrobot_ctrl.dynamics.plant_casadi.state_derivative`) and ``tau`` the
  logged actuator wrench ``B f`` held over each interval (zero-order hold).
* ``d``: the generalised acceleration the nominal model misses (m/s^2, rad/s^2), a first-order Gauss-Markov
  process of time constant ``T_d`` and stationary std ``sigma_d`` (:class:`SmootherSettings`). It lets the
  accelerometer and the depth pull the velocity away from the nominal model, and carries what the model misses.
* ``b``: accelerometer bias (m/s^2, body FRD), a random constant: a calibrated MEMS accelerometer keeps an offset
  of a few 0.01 m/s^2. Where the velocity is observed (depth gives heave), the bias is separated from ``d``
  (the depth's second derivative is unbiased); in an unobserved DOF both are only known through the
  accelerometer, and the reported velocity std says so.

Measurements: whichever of ``x y z phi theta psi u v w p q r ax ay az`` are logged (nan = absent per sample). The
accelerometer model is the specific force at the body origin in body axes (FRD),
``f = v_dot + omega x v - R^T [0, 0, g] + b`` (the run-log format's definition). Noise std per channel is
estimated from the data (:func:`channel_noise`, sample-to-sample MAD) with floors
(:data:`NOISE_FLOOR`); angle innovations are wrapped to [-pi, pi).

The filter runs on a grid decimated to about ``rate_hz`` (the input is averaged over each interval), and the
smoothed trajectory is interpolated back to the run's grid. A non-finite or non-positive covariance stops the
pass with :class:`SmootherError` naming the time; :func:`udrobot_ctrl.gap.data.prepare` then falls back to the
measured channels only.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np
from scipy.interpolate import CubicSpline
from scipy.linalg.lapack import dposv

from udrobot_ctrl.dynamics import plant_casadi as pc
from udrobot_ctrl.dynamics.effects import CASADI
from udrobot_ctrl.dynamics.fastsim import compile_function, parameter_hash
from udrobot_ctrl.dynamics.integrators import rk4_step
from udrobot_ctrl.dynamics.plant import PlantParameters, rotation_zyx
from udrobot_ctrl.gap import smoother_kernels as kernels

CHANNELS = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r", "ax", "ay", "az")
ANGLE_ROWS = (3, 4, 5)
N_STATE = 21
#: floors of the per-channel noise std (m, rad, m/s, rad/s, m/s^2): below a sensor's resolution / quantisation
#: (assumed: 1 cm USBL, 2 mm pressure depth, 0.001 rad AHRS, 2 mm/s DVL, 0.001 rad/s gyro, 0.01 m/s^2 MEMS
#: accelerometer), so that a channel logged with few digits or a simulated noiseless channel is not trusted blindly
NOISE_FLOOR = {"x": 0.01, "y": 0.01, "z": 0.002, "phi": 1e-3, "theta": 1e-3, "psi": 1e-3, "u": 2e-3, "v": 2e-3,
               "w": 2e-3, "p": 1e-3, "q": 1e-3, "r": 1e-3, "ax": 0.01, "ay": 0.01, "az": 0.01}
GRAVITY = 9.81  # m/s^2, the vehicle model's default g (udrobot_ctrl.vehicle.Vehicle.g)


def accelerometer(be, eta, nu, nu_dot, g=GRAVITY) -> tuple:
    """Specific force at the body origin in body axes (FRD), m/s^2, without bias: ``v_dot + omega x v -
    R^T [0, 0, g]`` (the run-log format's accelerometer), from the components of the pose ``eta`` (6), the velocity
    ``nu`` (6) and the linear acceleration ``nu_dot`` (3), with the functions of backend ``be`` (numpy arrays of any
    shape or casadi expressions): the smoother's measurement model and the replay's prediction are this one
    function."""
    phi, th = eta[3], eta[4]
    u, v, w, p, q, r = nu[:6]
    g_body = (-g * be.sin(th), g * be.cos(th) * be.sin(phi), g * be.cos(th) * be.cos(phi))  # R^T [0, 0, g]
    omega_x_v = (q * w - r * v, r * u - p * w, p * v - q * u)
    return tuple(nu_dot[i] + omega_x_v[i] - g_body[i] for i in range(3))


class SmootherError(ValueError):
    """Numerical failure of the smoother (non-finite or indefinite covariance, non-finite state)."""


@dataclass(frozen=True)
class SmootherSettings:
    """Assumed magnitudes of the smoother (none is measured; each is a modelling choice with its reason).

    Attributes
    ----------
    rate_hz : float
        Highest filter rate, Hz: logs up to 50 Hz are filtered at their own rate, faster ones decimated (assumed:
        the vehicle's fastest modes, roll/pitch, are below 2 Hz). Decimating below the log rate is not free: a 50 Hz
        stock-sensor run with no effect, filtered at 25 Hz, left a lag-like heave residual that the diagnoser named
        as a thrust loss and an added-mass error; at 50 Hz it named nothing.
    T_d : float
        Time constant of the unmodelled acceleration d, s (assumed 2 s: the catalogue effects change with the
        manoeuvre, i.e. on the vehicle's velocity time constants of 1-5 s).
    sigma_d_lin, sigma_d_ang : float
        Stationary std of d, m/s^2 and rad/s^2 (assumed 0.3 m/s^2 and 1.0 rad/s^2: a pool-scale unmodelled force
        of ~30 % of a T200's thrust on a 17 kg vehicle, and a moment of ~0.2 N m on 0.2 kg m^2).
    sigma_bias : float
        Prior std of the accelerometer bias, m/s^2 (assumed 0.1: a calibrated MEMS accelerometer).
    bias_walk : float
        Random walk of the bias per sqrt(s), m/s^2 (assumed 1e-4: a constant over a run).
    pose_walk : float
        Random walk on the pose per sqrt(s), m or rad (assumed 1e-3: kinematics are exact, this only conditions P).
    nu_walk : float
        Random walk on the velocity per sqrt(s), m/s or rad/s (assumed 1e-3; d carries the model error).
    g : float
        Gravity, m/s^2.
    """

    rate_hz: float = 50.0
    T_d: float = 2.0
    sigma_d_lin: float = 0.3
    sigma_d_ang: float = 1.0
    sigma_bias: float = 0.1
    bias_walk: float = 1e-4
    pose_walk: float = 1e-3
    nu_walk: float = 1e-3
    g: float = GRAVITY

    @property
    def sigma_d(self) -> np.ndarray:
        """(6,) std of the unmodelled acceleration per DOF: linear (m/s^2) for X Y Z, angular (rad/s^2) for K M N."""
        return np.array([self.sigma_d_lin] * 3 + [self.sigma_d_ang] * 3)


@dataclass
class SmoothedRun:
    """Smoothed trajectory of one run on the run's grid (n samples).

    Attributes
    ----------
    t : (n,) ndarray
        Time, s.
    eta, nu, nu_dot : (n, 6) ndarray
        Pose (m, rad; x, y dead-reckoned from the start when not logged), body velocity (m/s, rad/s) and its
        derivative (m/s^2, rad/s^2) = nominal plant + unmodelled acceleration d.
    d : (n, 6) ndarray
        Unmodelled generalised acceleration (m/s^2, rad/s^2).
    accel_bias : (3,) ndarray
        Accelerometer bias at the end of the run, m/s^2 (nan without accelerometer).
    sigma_eta, sigma_nu, sigma_nu_dot, sigma_d : (n, 6) ndarray
        Posterior std of each (sigma_nu_dot is that of d, the uncertain part of nu_dot).
    channels : tuple of str
        Logged channels the smoother fused.
    noise : dict of str -> float
        Measurement noise std used per channel (estimated from the data, floored).
    rate_hz : float
        Filter rate actually used, Hz.
    """

    t: np.ndarray
    eta: np.ndarray
    nu: np.ndarray
    nu_dot: np.ndarray
    d: np.ndarray
    accel_bias: np.ndarray
    sigma_eta: np.ndarray
    sigma_nu: np.ndarray
    sigma_nu_dot: np.ndarray
    sigma_d: np.ndarray
    channels: tuple
    noise: dict = field(default_factory=dict)
    rate_hz: float = 0.0


def _symbolic_model(p: PlantParameters, s: SmootherSettings):
    """(xdot(x, tau), h(x, tau)) of the augmented state as casadi expressions."""
    x = ca.SX.sym("x", N_STATE)
    tau = ca.SX.sym("tau", 6)
    f12 = pc.state_derivative(x[0:12], tau, p)
    d, b = x[12:18], x[18:21]
    nu_dot = f12[6:12] + d
    xdot = ca.vertcat(f12[0:6], nu_dot, -d / s.T_d, ca.DM.zeros(3))
    acc = ca.vertcat(*accelerometer(CASADI, [x[i] for i in range(6)], [x[6 + i] for i in range(6)],
                                    [nu_dot[i] for i in range(3)], s.g)) + b
    h = ca.vertcat(x[0:12], acc)
    return x, tau, xdot, h


_CACHE: dict = {}
COMPILE_TIMEOUT_S = 60.0  # gcc on the RK4 Jacobian takes ~5 s once; the library is cached on disk afterwards


class _Buffered:
    """Low-overhead evaluation of a casadi Function ``(x, tau) -> (a, B)`` into preallocated numpy arrays (casadi's
    buffer interface: a plain call converts every argument and result, ~10x the cost of the evaluation)."""

    def __init__(self, fun: ca.Function):
        self.fun = fun
        self.x = np.zeros(fun.size1_in(0))
        self.u = np.zeros(fun.size1_in(1))
        self.a = np.zeros(fun.size1_out(0))
        self.B = np.zeros((fun.size1_out(1), fun.size2_out(1)), order="F")
        self._buf, self._eval = fun.buffer()
        self._buf.set_arg(0, memoryview(self.x))
        self._buf.set_arg(1, memoryview(self.u))
        self._buf.set_res(0, memoryview(self.a))
        self._buf.set_res(1, memoryview(self.B.reshape(-1, order="F")))

    def __call__(self, x, u):
        """(a, B) for state x and input u (views of the buffers: copy what must be kept)."""
        self.x[:] = x
        self.u[:] = u
        self._eval()
        return self.a, self.B


def _plant_key(p: PlantParameters, s: SmootherSettings, dt: float) -> tuple:
    return (np.asarray(p.M).tobytes(), np.asarray(p.D_L).tobytes(), np.asarray(p.Q).tobytes(), float(p.weight),
            float(p.buoyancy), np.asarray(p.r_g).tobytes(), np.asarray(p.r_b).tobytes(), s, round(dt, 9))


def _functions(p: PlantParameters, s: SmootherSettings, dt: float, compile: bool = True):
    """(step, meas, deriv), cached per plant, settings and dt: ``step(x, tau) -> (x_next, dx_next/dx)`` (RK4, tau
    held; gcc-compiled when possible, see :func:`udrobot_ctrl.dynamics.fastsim.compile_function`),
    ``meas(x, tau) -> (h, dh/dx)`` (both :class:`_Buffered`) and the casadi Function ``deriv(x, tau) -> x_dot``."""
    key = _plant_key(p, s, dt) + (compile,)
    if key not in _CACHE:
        x, tau, xdot, h = _symbolic_model(p, s)
        f = ca.Function("smoother_f", [x, tau], [xdot])
        xn = rk4_step(lambda _t, xx: f(xx, tau), 0.0, x, dt)
        step = ca.Function("smoother_step", [x, tau], [xn, ca.densify(ca.jacobian(xn, x))])
        meas = ca.Function("smoother_meas", [x, tau], [h, ca.densify(ca.jacobian(h, x))])
        if compile:
            fast = compile_function(step, parameter_hash(p, "smoother", repr(s), round(dt, 9)),
                                    timeout=COMPILE_TIMEOUT_S)
            step = fast if fast is not None else step
        if len(_CACHE) > 16:
            _CACHE.clear()
        _CACHE[key] = (_Buffered(step), _Buffered(meas), f)
    return _CACHE[key]


#: a row lies on the straight line through its neighbours when its second difference is within this share of its
#: two differences (the relative rounding of a linear interpolation on time stamps of up to ~1e9 s at a 0.02 s grid
#: is ~1e-5; two differences of a sampled channel with noise agree that closely with a chance of ~1e-4)
LINE_RELATIVE = 1e-4
#: ... plus this many double-precision rounding units of the channel's largest value, plus twice the decimal step of
#: values written with few decimals (the absolute rounding of the interpolation and of the file)
LINE_ULPS = 64
#: decimals beyond which values are taken as written in full (not rounded to a fixed number of decimals)
DECIMALS_MAX = 12
#: share of a channel's moving rows (not flat) that lie on straight lines above which it is taken as linearly
#: interpolated from a slower stream: a sampled channel with noise has almost none (three noisy samples in line by
#: chance), one interpolated from knots k rows apart about 1 - 2/k (knots between rows break two lines each): 0.2 at
#: 20 Hz on a 50 Hz grid, 0.6 at 10 Hz (assumed threshold, below the 20 Hz streams of a QGC tlog)
INTERPOLATED_SHARE = 0.1
#: ... and at least this many times the share that equal differences would have by chance (the sum of the squared
#: frequencies of the differences' values: a channel quantised to a few steps per sample has equal differences
#: often without any interpolation)
CHANCE_MARGIN = 3.0
#: knots recovered where neighbouring segments meet that are needed to measure the noise on them; fewer (knots
#: under ~3 rows apart leave too few rows on each line): the grid-to-grid estimate, scaled by what interpolation at
#: that interval does to it (:func:`_interpolation_factor`)
MIN_SEGMENTS = 10


@dataclass(frozen=True)
class ChannelNoise:
    """A logged channel's sensor noise, as the data show it.

    Attributes
    ----------
    sigma : float
        Noise std of the channel's own samples, same units as the channel.
    interval : float
        Grid rows between the channel's own samples: 1 for a channel sampled at the grid's rate; k for one logged
        k times slower and linearly interpolated onto the grid (its knots, which may fall between rows).
    """

    sigma: float
    interval: float = 1.0

    @property
    def interpolated(self) -> bool:
        """Whether the channel is interpolated onto the grid from a slower stream."""
        return self.interval > 1.5


def _robust_std(x) -> float:
    """Standard deviation of normal data from the median absolute deviation (robust to outliers), same units."""
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def _mad_noise(d) -> float:
    """Noise std from differences of consecutive samples (robust MAD; the difference of two has variance 2 s^2)."""
    d = d[np.isfinite(d)]
    if d.size < 5:
        return np.nan
    return _robust_std(d) / np.sqrt(2.0)


def _decimal_step(y) -> float:
    """Rounding step of values written with a fixed number of decimals (0 when they are written in full)."""
    v = y[np.isfinite(y)][:4096]
    if v.size == 0:
        return 0.0
    need = np.full(v.size, DECIMALS_MAX + 1)
    for k in range(DECIMALS_MAX + 1):
        x = v * 10.0 ** k
        whole = (np.abs(x) < 1e14) & (np.abs(x - np.round(x)) <= 8 * np.finfo(float).eps * np.maximum(np.abs(x), 1))
        need[whole & (need > DECIMALS_MAX)] = k
    k99 = float(np.percentile(need, 99))
    return 0.0 if k99 > DECIMALS_MAX else 10.0 ** -k99


def _line_segments(y):
    """Maximal runs of rows that lie on the straight line through their neighbours: (first row, last row) pairs and
    the mask of moving rows (neither difference beside them zero) and of those on lines."""
    d = np.diff(y)
    d2 = d[1:] - d[:-1]
    finite = np.isfinite(y)
    big = float(np.max(np.abs(y[finite]))) if finite.any() else 0.0
    atol = 2 * _decimal_step(y) + LINE_ULPS * np.finfo(float).eps * big
    with np.errstate(invalid="ignore"):
        line = np.abs(d2) <= LINE_RELATIVE * (np.abs(d[:-1]) + np.abs(d[1:])) + atol
        flat = (np.abs(d[:-1]) <= atol) & (np.abs(d[1:]) <= atol)
    moving = np.isfinite(d2) & ~flat
    edges = np.diff(np.concatenate(([0], line.astype(np.int8), [0])))
    first, last = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return first + 1, last + 1, moving, line & moving


def _knots(y, first, last):
    """The samples a linearly interpolated channel was drawn through: where neighbouring straight segments meet.

    Segment j (rows ``first[j]..last[j]`` on its line, slope ``d[first[j]]`` per row) and segment j+1 meet at a
    knot between rows ``last[j]`` and ``first[j+1]`` when at most two rows lie between them (one knot: a knot on a
    row breaks one line, one between rows breaks two). Returns (row positions, values, whether the knot follows
    the previous one directly), the positions clipped to those rows (two nearly parallel segments meet anywhere).
    """
    d = np.diff(y)
    slope = d[first]
    b0 = y[first] - slope * first  # y = b0 + slope * row on each segment
    with np.errstate(divide="ignore", invalid="ignore"):
        k = (b0[1:] - b0[:-1]) / (slope[:-1] - slope[1:])
    k = np.clip(np.nan_to_num(k, nan=0.5 * (last[:-1] + first[1:])), last[:-1], first[1:])
    value = b0[:-1] + slope[:-1] * k
    joined = np.flatnonzero(first[1:] - last[:-1] <= 3)
    return k[joined], value[joined], np.concatenate(([False], np.diff(joined) == 1))


@lru_cache(maxsize=64)
def _interpolation_factor(interval: float) -> float:
    """How much the grid-to-grid noise estimate (:func:`_mad_noise` of differences of consecutive rows)
    underestimates the noise of a channel interpolated from knots ``interval`` rows apart: the estimate of unit
    noise drawn at such knots (:func:`noise_draw`, random phase; seeded, 40 000 rows), inverted."""
    e = noise_draw(ChannelNoise(1.0, interval), 40_000, np.random.default_rng(0))
    return 1.0 / _mad_noise(np.diff(e))


def noise_model(y) -> ChannelNoise:
    """Noise of a logged channel on a uniform grid, at the channel's own logging rate.

    A channel logged slower than the grid and linearly interpolated onto it (e.g. a 10 Hz attitude on a 50 Hz
    grid) lies on straight lines between its own samples (knots, which may fall between rows): differences of
    consecutive rows are then a fraction of the noise, and measuring it from them underestimates it by about
    the interval. Such a channel is recognised by the share of its moving rows whose second difference vanishes
    (to the rounding of the values: full double precision, or the decimal step of values written with a fixed
    number of decimals), at least :data:`INTERPOLATED_SHARE` and :data:`CHANCE_MARGIN` times what equal
    differences give by chance (a sampled channel, quantised or not, has almost none; flat stretches are not
    counted). Its knots are recovered where neighbouring segments meet, the interval is their median spacing, and
    the noise is measured on each knot's deviation from the chord of its two neighbours (robust MAD; white noise
    gives it variance s^2 (1 + a^2 + b^2), a + b = 1 the chord's weights): between samples logged slowly the
    motion is large, a steady climb is not noise, and the stamps' jitter is kept. Knots too close to recover
    (under ~3 rows apart: a 20 Hz stream on a 50 Hz grid) give the interval from the share (``2 / (1 - share)``)
    and the noise from the grid-to-grid differences scaled by :func:`_interpolation_factor`.

    Parameters
    ----------
    y : (n,) ndarray
        The channel on the grid (nan where absent), its units; angles unwrapped by the caller if they wrap.

    Returns
    -------
    ChannelNoise
        ``sigma`` nan when fewer than five differences are finite.
    """
    y = np.asarray(y, float)
    raw = _mad_noise(np.diff(y[np.isfinite(y)]))
    sampled = ChannelNoise(raw)
    if y.size < 3:
        return sampled
    first, last, moving, on_line = _line_segments(y)
    d = np.diff(y)
    _, counts = np.unique(d[1:][moving], return_counts=True)
    chance = float(np.sum((counts / max(counts.sum(), 1)) ** 2))
    share = on_line.sum() / max(moving.sum(), 1)
    if first.size < MIN_SEGMENTS or share < max(INTERPOLATED_SHARE, CHANCE_MARGIN * chance):
        return sampled
    k, v, after = _knots(y, first, last)
    step = np.diff(k)[after[1:]]
    mid = np.flatnonzero(after[1:-1] & after[2:]) + 1  # knots with both neighbours directly beside them
    if step.size < MIN_SEGMENTS or mid.size < MIN_SEGMENTS:
        interval = float(2.0 / (1.0 - share))
        return ChannelNoise(raw * _interpolation_factor(round(interval, 1)), interval) if interval > 1.5 else sampled
    if np.median(step) <= 1.5:
        return sampled
    h0, h1 = k[mid] - k[mid - 1], k[mid + 1] - k[mid]
    a, b = h1 / (h0 + h1), h0 / (h0 + h1)
    e = (v[mid] - a * v[mid - 1] - b * v[mid + 1]) / np.sqrt(1.0 + a ** 2 + b ** 2)
    return ChannelNoise(_robust_std(e), float(np.median(step)))


_NOISE_MODELS: dict = {}  # id(y) -> (y, ChannelNoise), see logged_noise_model
#: logged arrays :func:`logged_noise_model` keeps at most (all dropped at once beyond it): a diagnosis's runs times
#: their channels, both reconstruction passes
NOISE_MODELS_KEPT = 64


def logged_noise_model(y: np.ndarray) -> ChannelNoise:
    """:func:`noise_model` of a logged channel ``y`` (an array), kept for the most recent arrays: a diagnosis asks it
    of the same logs for every replay it scores and every noise-floor draw (the entry holds ``y``, so its id is its
    own)."""
    hit = _NOISE_MODELS.get(id(y))
    if hit is not None and hit[0] is y:
        return hit[1]
    out = noise_model(y)
    if len(_NOISE_MODELS) >= NOISE_MODELS_KEPT:
        _NOISE_MODELS.clear()
    _NOISE_MODELS[id(y)] = (y, out)
    return out


def channel_noise(y) -> float:
    """Sensor-noise std of a channel at its own logging rate (:func:`noise_model`), same units."""
    return noise_model(y).sigma


def noise_draw(model: ChannelNoise, n: int, rng) -> np.ndarray:
    """One draw of a channel's noise on ``n`` grid rows: white at the grid rate for a sampled channel; for one
    interpolated onto the grid, white at its knots (random phase) and linearly interpolated between them, as the
    log's own noise is.

    Parameters
    ----------
    model : ChannelNoise
    n : int
        Grid rows.
    rng : numpy.random.Generator

    Returns
    -------
    (n,) ndarray, the channel's units (zeros when ``sigma`` is not finite).
    """
    sigma = model.sigma if np.isfinite(model.sigma) else 0.0
    if not model.interpolated:
        return rng.normal(0.0, sigma, n)
    knots = rng.uniform(-model.interval, 0.0) + model.interval * np.arange(int(np.ceil(n / model.interval)) + 2)
    return np.interp(np.arange(n), knots, rng.normal(0.0, sigma, knots.size))


def measurement_noise(meas: dict, channels, step: int = 1) -> dict:
    """Noise std per channel for a filter that takes every ``step``-th grid row as an independent measurement:
    the noise at the channel's own rate (angles unwrapped, :func:`noise_model`), floored, and inflated by the
    square root of the rows per own sample where the channel is interpolated more finely than the filter's rate
    (the filter would otherwise count one sample's information that many times)."""
    out = {}
    for c in channels:
        y = np.asarray(meas[c], float)
        if c in ("phi", "theta", "psi"):
            ok = np.isfinite(y)
            y = y.copy()
            y[ok] = np.unwrap(y[ok])
        model = noise_model(y)
        sd = model.sigma if np.isfinite(model.sigma) else 0.0
        out[c] = float(max(sd, NOISE_FLOOR[c]) * np.sqrt(max(1.0, model.interval / step)))
    return out


def _block_mean(a, step, n_out):
    """Mean of ``a`` (n, k) over consecutive blocks of ``step`` rows (the last block may be shorter)."""
    starts = np.arange(n_out) * step
    counts = np.diff(np.append(starts, a.shape[0]))
    return np.add.reduceat(a, starts, axis=0) / counts[:, None]


def spd_solve(A, B):
    """X with A X = B for a symmetric positive definite A (a covariance): LAPACK's Cholesky solver called directly
    (``np.linalg.solve``'s checks cost twice the solve at the smoother's sizes, and it runs twice per sample); a
    matrix rounding has left indefinite goes through the general solver.

    Raises
    ------
    numpy.linalg.LinAlgError
        If A is singular.
    """
    _, X, info = dposv(A, B)
    return X if info == 0 else np.linalg.solve(A, B)


def smooth_run(t, meas: dict, tau, p: PlantParameters, settings: SmootherSettings | None = None,
               label: str = "run") -> SmoothedRun:
    """Forward EKF and backward RTS pass over one run (see the module docstring).

    Parameters
    ----------
    t : (n,) ndarray
        Uniform time grid, s.
    meas : dict of str -> (n,) ndarray
        Logged channels on the grid (nan where absent); any of :data:`CHANNELS` are used, others ignored.
    tau : (n, 6) ndarray
        Actuator wrench B f, N and N m, held from each sample to the next.
    p : PlantParameters
        Nominal plant (without run-time effects).
    label : str
        Run name for error messages.

    Returns
    -------
    SmoothedRun

    Raises
    ------
    SmootherError
        If the covariance or the state becomes non-finite (names the time), or nothing is logged to fuse.
    """
    s = settings or SmootherSettings()
    t = np.asarray(t, float)
    n = t.size
    dt_run = float(np.median(np.diff(t)))
    step = max(1, int(round(1.0 / (s.rate_hz * dt_run))))
    dt = step * dt_run
    idx = np.arange(0, n, step)
    m = idx.size
    chans = tuple(c for c in CHANNELS if c in meas and np.isfinite(np.asarray(meas[c], float)).any())
    if not chans:
        raise SmootherError(f"{label}: no channel of {', '.join(CHANNELS)} is logged; nothing to smooth")
    noise = measurement_noise(meas, chans, step)
    rows = np.array([CHANNELS.index(c) for c in chans])
    Z = np.column_stack([np.asarray(meas[c], float)[idx] for c in chans])
    Rdiag = np.array([noise[c] ** 2 for c in chans])
    has_acc = any(c in chans for c in ("ax", "ay", "az"))
    has_xy = "x" in chans or "y" in chans
    keep = np.arange(N_STATE) if has_xy else np.arange(2, N_STATE)
    ns = keep.size
    tau_c = _block_mean(np.nan_to_num(np.asarray(tau, float)), step, m)
    f_step, f_meas, f_deriv = _functions(p, s, dt)

    # initial state: first logged value of each pose/velocity channel; d = 0, b = 0
    x0 = np.zeros(N_STATE)
    for i, c in enumerate(CHANNELS[:12]):
        if c in chans:
            y = np.asarray(meas[c], float)
            x0[i] = y[np.flatnonzero(np.isfinite(y))[0]]
    # assumed initial std (m, rad, m/s, rad/s): wide, so that the first measurements set the state, not the prior
    sig0 = np.array([1.0, 1.0, 0.5, 0.2, 0.2, 0.5, 0.5, 0.5, 0.5, 0.3, 0.3, 0.3]
                    + list(s.sigma_d) + [s.sigma_bias] * 3)
    P = np.diag(sig0[keep] ** 2)
    a = np.exp(-dt / s.T_d)
    qd = s.sigma_d ** 2 * (1 - a ** 2)
    Qfull = np.diag(np.concatenate([np.full(6, s.pose_walk ** 2 * dt), np.full(6, s.nu_walk ** 2 * dt), qd,
                                    np.full(3, s.bias_walk ** 2 * dt)]))
    Q = Qfull[np.ix_(keep, keep)]

    sl = slice(0, N_STATE) if has_xy else slice(2, N_STATE)
    xs_f = np.empty((m, N_STATE))
    xs_p = np.empty((m, N_STATE))
    Ps_f = np.empty((m, ns, ns))
    Fs = np.empty((m, ns, ns))
    x = x0.copy()
    # the predicted covariance of the sample at hand only: the backward pass computes each again from Fs and Ps_f
    # (kernels.predicted_covariance, the same numbers), so a run keeps two (m, ns, ns) arrays, not three
    P_pred = P.copy()
    finite = np.isfinite(Z)
    measured = finite.any(axis=1)
    angle_rows = np.array(ANGLE_ROWS)
    lo = sl.start
    # one compiled call per sample for the update (the innovation of its logged channels) and one for the
    # prediction; the casadi plant is called from here (kernels.forward_update, kernels.forward_predict)
    # (kernels.update_sample, kernels.predict_sample: the per-sample bookkeeping compiled too)
    hk, Hk = f_meas.a, f_meas.B  # its result buffers (filled by each call; an unmeasured sample reads neither)
    for k, (tau_k, meas_k) in enumerate(zip(tau_c, measured.tolist())):
        if meas_k:
            hk, Hk = f_meas(x, tau_k)
        if not kernels.update_sample(k, x, lo, hk, Hk, Z, finite, measured, rows, angle_rows, Rdiag, xs_p, xs_f,
                                     P_pred, Ps_f):
            # rounding left S indefinite: the general solver
            H, y, r_k = kernels.innovation(lo, hk, Hk, Z[k], finite[k], rows, angle_rows, Rdiag)
            PHt = P_pred @ H.T
            K = spd_solve(H @ PHt + np.diag(r_k), PHt.T).T
            x[sl] += K @ y
            Pn = P_pred - K @ PHt.T
            Ps_f[k] = 0.5 * (Pn + Pn.T)
            xs_f[k] = x
        xn, Fk = f_step(x, tau_k)
        if not kernels.predict_sample(k, x, xn, Fk, lo, Fs, Ps_f, Q, P_pred):
            raise SmootherError(f"{label}: the smoother's forward pass diverged at t = {t[idx[k]]:.2f} s "
                                f"(non-finite covariance or state)")
    xs_p = np.vstack([xs_p[1:], x])  # prediction of step k+1 from step k

    # backward RTS pass (compiled; a step whose predicted covariance the compiled Cholesky refuses is solved here by
    # spd_solve, as the forward pass's update)
    xs, Ps = xs_f, Ps_f  # smoothed in place: step k reads its filtered values before it writes them
    k = kernels.rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Q, Fs, sl.start, m - 2)
    Pp = np.empty((ns, ns))
    while k >= 0:
        kernels.predicted_covariance(k, Fs, Ps_f, Q, Pp)
        try:
            C = spd_solve(Pp, Fs[k] @ Ps_f[k]).T
        except np.linalg.LinAlgError as exc:
            raise SmootherError(f"{label}: singular predicted covariance at t = {t[idx[k + 1]]:.2f} s in the RTS "
                                f"pass") from exc
        xs[k, sl] = xs_f[k, sl] + C @ (xs[k + 1, sl] - xs_p[k, sl])
        Ps[k] = Ps_f[k] + C @ (Ps[k + 1] - Pp) @ C.T
        k = kernels.rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Q, Fs, sl.start, k - 1)
    var = np.einsum("kii->ki", Ps)
    if not (np.isfinite(xs).all() and np.isfinite(var).all()) or (var < -1e-9 * (1 + np.abs(var).max())).any():
        raise SmootherError(f"{label}: the smoother's backward pass produced a non-finite or negative covariance")
    sd = np.full((m, N_STATE), np.nan)
    sd[:, keep] = np.sqrt(np.maximum(var, 0.0))

    # nu_dot at the nodes = nominal plant + d (the derivative of the process model), one vectorised call
    nud = np.asarray(f_deriv.map(m)(xs.T, tau_c.T)).T[:, 6:12]

    tc = t[idx]
    eta_c = xs[:, 0:6].copy()
    for j in (3, 4, 5):
        eta_c[:, j] = np.unwrap(eta_c[:, j])

    def interp(y):
        if m < 4:
            return np.array([np.interp(t, tc, col) for col in y.T]).T
        return CubicSpline(tc, y, axis=0, bc_type="natural", extrapolate=True)(t)

    def interp_lin(y):
        return np.array([np.interp(t, tc, col) for col in y.T]).T

    eta = interp(eta_c)
    nu = interp(xs[:, 6:12])
    if not has_xy:  # dead reckoning from the start: x_dot = (R nu)_xy
        R = rotation_zyx(eta[:, 3], eta[:, 4], eta[:, 5])
        v_ned = np.einsum("nij,nj->ni", R, nu[:, :3])
        eta[:, 0:2] = np.concatenate([np.zeros((1, 2)),
                                      np.cumsum(0.5 * (v_ned[1:, :2] + v_ned[:-1, :2]) * np.diff(t)[:, None], 0)])
    return SmoothedRun(t=t, eta=eta, nu=nu, nu_dot=interp_lin(nud), d=interp_lin(xs[:, 12:18]),
                       accel_bias=xs[-1, 18:21] if has_acc else np.full(3, np.nan),
                       sigma_eta=interp_lin(sd[:, 0:6]), sigma_nu=interp_lin(sd[:, 6:12]),
                       sigma_nu_dot=interp_lin(sd[:, 12:18]), sigma_d=interp_lin(sd[:, 12:18]), channels=chans,
                       noise=noise, rate_hz=1.0 / dt)
