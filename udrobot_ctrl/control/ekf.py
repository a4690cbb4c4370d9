"""Extended Kalman filter for UDrobot: the nonlinear plant as process model, UDrobot's sensors as measurements.

* Process model: one RK4 step of the casadi plant (:func:`udrobot_ctrl.dynamics.plant_casadi.rk4_step_function`)
  with the applied thrusts held over ``dt``; its Jacobian ``F = dx_next/dx`` comes from the same generated
  casadi function (gcc-compiled and cached when possible). The filter is filterpy's
  :class:`~filterpy.kalman.ExtendedKalmanFilter` with ``predict_x`` overridden by the RK4 step.
* Process noise: unmodelled forces and moments (tether, waves, model error) as piecewise-constant white
  noise through the inverse mass matrix, ``Q_nu = dt^2 M^-1 diag(sigma_tau^2) M^-T``, plus a small
  random walk on the pose (assumed magnitudes on :class:`ProcessNoise`).
* Measurements: the channels of :mod:`udrobot_ctrl.control.sensors` (pressure depth, IMU attitude and rates, DVL
  body velocity, optional USBL position). Each step uses whichever channels are present (NaN = absent):
  H (rows of the identity) and R (diagonal) are built per availability pattern and cached; angle
  residuals are wrapped to [-pi, pi).
* Consistency: the normalised innovation squared ``NIS = y' S^-1 y`` of every update; the sum over
  blocks of ``nis_window`` steps is compared with the two-sided chi-square bounds (``alpha``) for the
  total measurement dimension -> ``consistent`` / ``inconsistent``. Divergence: ``divergence_blocks``
  consecutive blocks above the ``1 - divergence_alpha`` quantile, or a non-finite state/covariance.
  The safe fallback then re-initialises the measured states from the latest measurement, keeps the
  others and resets P to P0 (``stats['resets']``); the filter never raises inside the loop.
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import casadi as ca
import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from udrobot_ctrl.control.sensors import ANGLE_CHANNELS, CHANNEL_STATE, CHANNELS, SensorConfig, SensorStream
from udrobot_ctrl.dynamics.plant import PlantParameters, plant_parameters

STATE_NAMES = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
#: default initial standard deviations (m, rad, m/s, rad/s; assumed: start at a known spot, roughly level)
DEFAULT_P0_SIGMA = np.array([0.5, 0.5, 0.1, 0.05, 0.05, 0.2, 0.1, 0.1, 0.1, 0.05, 0.05, 0.05])


@dataclass(frozen=True)
class ProcessNoise:
    """Assumed process-noise magnitudes.

    Attributes
    ----------
    force_sigma : float
        N, unmodelled force per axis held over one filter step (tether drag, waves, drag-model error);
        assumed 1 N (~3 % of a T200's thrust).
    moment_sigma : float
        N m, unmodelled moment per axis held over one step; assumed 0.05 N m (0.3 N at ~0.15 m lever arm).
    pose_sigma : float
        m or rad per step, random walk on the pose (kinematic model error); assumed 1e-3.
    """

    force_sigma: float = 1.0
    moment_sigma: float = 0.05
    pose_sigma: float = 1e-3


def process_noise_covariance(p: PlantParameters, dt: float, noise: ProcessNoise | None = None) -> np.ndarray:
    """Discrete process noise Q (12, 12) for one step of ``dt`` s (see the module docstring)."""
    noise = noise or ProcessNoise()
    S = np.diag([noise.force_sigma ** 2] * 3 + [noise.moment_sigma ** 2] * 3)
    Q = np.zeros((12, 12))
    Q[6:, 6:] = dt ** 2 * p.M_inv @ S @ p.M_inv.T
    Q[:6, :6] = noise.pose_sigma ** 2 * np.eye(6)
    return 0.5 * (Q + Q.T)


def step_jacobian_function(p: PlantParameters, dt: float, compile: bool = True) -> ca.Function:
    """``(x, f) -> (x_next, F)``: RK4 plant step (thrust inputs) and state Jacobian (compiled when gcc is there)."""
    from udrobot_ctrl.control.mpc import maybe_compiled
    from udrobot_ctrl.dynamics.plant_casadi import rk4_step_function

    step = rk4_step_function(p, dt, "thrust")
    x = ca.SX.sym("x", 12)
    f = ca.SX.sym("f", p.T.shape[1])
    xn = step(x, f)
    fun = ca.Function("ekf_step", [x, f], [xn, ca.densify(ca.jacobian(xn, x))], ["x", "f"], ["x_next", "F"])
    return maybe_compiled(fun, p, dt, "ekf", compile=compile)


class _PlantEKF(ExtendedKalmanFilter):
    """filterpy EKF whose state prediction is the RK4 step of the nonlinear plant."""

    def __init__(self, step, nu):
        super().__init__(dim_x=12, dim_z=len(CHANNELS), dim_u=nu)
        self._step = step
        self.x = np.zeros(12)

    def predict_x(self, u=0):
        xn, F = self._step(self.x, u)
        self.F = F.full()
        self.x = xn.full().ravel()


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


@dataclass
class EKFResult:
    """Filter output over a stream: estimates ``x`` (n, 12), standard deviations ``sigma`` (n, 12),
    ``nis`` (n,) (NaN without measurements), measurement dimension ``dof`` (n,), ``status`` per step."""

    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    nis: np.ndarray
    dof: np.ndarray
    status: list
    resets: int

    def nis_mean(self) -> float:
        """Mean NIS over updated steps (to compare with the mean measurement dimension)."""
        ok = self.dof > 0
        return float(np.mean(self.nis[ok])) if ok.any() else float("nan")

    def nis_normalised(self) -> float:
        """Mean of NIS / dof (1 for a consistent filter)."""
        ok = self.dof > 0
        return float(np.mean(self.nis[ok] / self.dof[ok])) if ok.any() else float("nan")

    def rmse(self, truth, states=STATE_NAMES) -> dict:
        """Root-mean-square error per named state against the true states (n, 12); angles wrapped."""
        truth = np.asarray(truth, float)
        out = {}
        for s in states:
            i = STATE_NAMES.index(s)
            e = self.x[:, i] - truth[:, i]
            if i in (3, 4, 5):
                e = _wrap(e)
            out[s] = float(np.sqrt(np.mean(e ** 2)))
        return out


class UDrobotEKF:
    """EKF on the nonlinear plant of ``vehicle`` (design/filter model) with UDrobot's sensors.

    Parameters
    ----------
    vehicle : Vehicle or PlantParameters
        Filter model.
    dt : float
        Filter step, s (the sensor stream's sample time).
    sensors : SensorConfig, optional
        Measurement noise (R = diag(sigma^2)) for the channels.
    x0 : (12,) array_like, optional
        Initial estimate (default at rest at the origin).
    P0 : (12,) sigmas or (12, 12) covariance, optional
    noise : ProcessNoise or (12, 12) array, optional
        Process noise magnitudes or a ready Q.
    nis_window : int
        Steps per NIS block.
    alpha : float
        Two-sided significance of the consistency bounds (0.05 -> 95 %).
    divergence_alpha : float
        Upper-tail significance of the divergence test (1e-3).
    divergence_blocks : int
        Consecutive blocks above the divergence bound before the filter re-initialises.
    compile : bool
        gcc-compile the generated step/Jacobian function (cached; falls back to casadi's VM).
    """

    def __init__(self, vehicle, dt=0.05, sensors: SensorConfig | None = None, x0=None, P0=None, noise=None,
                 nis_window=20, alpha=0.05, divergence_alpha=1e-3, divergence_blocks=2, compile=True):
        self.params = vehicle if isinstance(vehicle, PlantParameters) else plant_parameters(vehicle)
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.dt = float(dt)
        self.sensors = sensors or SensorConfig()
        self.sigmas = self.sensors.sigmas()
        nu = self.params.T.shape[1]
        self.kf = _PlantEKF(step_jacobian_function(self.params, self.dt, compile), nu)
        if noise is None or isinstance(noise, ProcessNoise):
            self.kf.Q = process_noise_covariance(self.params, self.dt, noise or ProcessNoise())
        else:
            self.kf.Q = np.asarray(noise, float).reshape(12, 12)
        P0 = DEFAULT_P0_SIGMA if P0 is None else np.asarray(P0, float)
        self.P0 = np.diag(P0 ** 2) if P0.ndim == 1 else P0.reshape(12, 12)
        self.x0 = np.zeros(12) if x0 is None else np.asarray(x0, float).reshape(12)
        self.nis_window, self.alpha = int(nis_window), float(alpha)
        self.divergence_alpha, self.divergence_blocks = float(divergence_alpha), int(divergence_blocks)
        self._cache: dict[bytes, tuple] = {}
        self._bounds: dict[int, tuple] = {}
        self.reset()

    # -- state --------------------------------------------------------------------------------------
    def reset(self, x0=None):
        """Restart from ``x0`` (default the constructor's) with covariance P0 and cleared statistics."""
        self.kf.x = (self.x0 if x0 is None else np.asarray(x0, float).reshape(12)).copy()
        self.kf.P = self.P0.copy()
        self._block_nis, self._block_dof, self._block_n = 0.0, 0, 0
        self._high_blocks = 0
        self._last_z = None
        self.nis, self.dof = np.nan, 0
        self.last_status = "ok"
        self.stats = {"steps": 0, "resets": 0, "divergences": 0, "inconsistent_blocks": 0, "blocks": 0,
                      "status": "ok", "step_time_s": np.nan, "nis_block_mean": np.nan}
        self.step_times: deque = deque(maxlen=100000)

    @property
    def x(self) -> np.ndarray:
        """Current estimate (12,)."""
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        """Current covariance (12, 12)."""
        return self.kf.P

    # -- measurement model ----------------------------------------------------------------------------
    def _model(self, mask):
        key = mask.tobytes()
        m = self._cache.get(key)
        if m is None:
            idx = CHANNEL_STATE[mask]
            H = np.zeros((len(idx), 12))
            H[np.arange(len(idx)), idx] = 1.0
            R = np.diag(self.sigmas[mask] ** 2)
            ang = ANGLE_CHANNELS[mask]

            def residual(z, hx, ang=ang):
                d = z - hx
                d[ang] = _wrap(d[ang])
                return d

            m = (H, R, (lambda x, H=H: H), (lambda x, idx=idx: x[idx]), residual, len(idx))
            self._cache[key] = m
        return m

    def _chi2_bounds(self, dof):
        b = self._bounds.get(dof)
        if b is None:
            b = (chi2.ppf(self.alpha / 2, dof), chi2.ppf(1 - self.alpha / 2, dof), chi2.ppf(1 - self.divergence_alpha,
                                                                                             dof))
            self._bounds[dof] = b
        return b

    # -- filter steps ---------------------------------------------------------------------------------
    def predict(self, thrust):
        """Propagate the estimate through the plant with the applied thrusts (N) over ``dt``."""
        f = np.clip(np.asarray(thrust, float), self.params.f_min, self.params.f_max)
        self.kf.predict(f)
        self.kf.x[5] = _wrap(self.kf.x[5])

    def update(self, z_row):
        """Update with one row of channel values (13,), NaN where absent; returns the NIS (NaN if none)."""
        z_row = np.asarray(z_row, float)
        mask = np.isfinite(z_row)
        if not mask.any():
            self.nis, self.dof = np.nan, 0
            return np.nan
        H, R, hjac, hx, residual, m = self._model(mask)
        z = z_row[mask]
        self._last_z = (mask, z)
        kf = self.kf
        kf.update(z, hjac, hx, R=R, residual=residual)
        kf.x[5] = _wrap(kf.x[5])
        y = kf.y
        self.nis = float(y @ kf.SI @ y)
        self.dof = m
        return self.nis

    def step(self, thrust, z_row):
        """Predict with ``thrust`` then update with ``z_row``; never raises. Returns the estimate (12,)."""
        t0 = time.perf_counter()
        try:
            self.predict(thrust)
            self.update(z_row)
            status = self._check()
        except Exception as exc:  # noqa: BLE001 - a filter in the loop must not throw
            status = self._reinitialise(f"{type(exc).__name__}: {exc}")
        self.stats["steps"] += 1
        self.stats["status"] = self.last_status = status
        dtc = time.perf_counter() - t0
        self.stats["step_time_s"] = dtc
        self.step_times.append(dtc)
        return self.kf.x

    def _check(self):
        kf = self.kf
        if not (np.all(np.isfinite(kf.x)) and np.all(np.isfinite(kf.P))):
            return self._reinitialise("non-finite state or covariance")
        status = self.last_status if not self.last_status.startswith("diverged") else "ok"
        if self.dof:
            self._block_nis += self.nis
            self._block_dof += self.dof
            self._block_n += 1
        if self._block_n >= self.nis_window:
            lo, hi, div = self._chi2_bounds(self._block_dof)
            s = self._block_nis
            self.stats["blocks"] += 1
            self.stats["nis_block_mean"] = s / self._block_n
            self._block_nis, self._block_dof, self._block_n = 0.0, 0, 0
            self._high_blocks = self._high_blocks + 1 if s > div else 0
            if self._high_blocks >= self.divergence_blocks:
                self._high_blocks = 0
                return self._reinitialise(f"NIS {s:.3g} above the {1 - self.divergence_alpha:.4g} chi-square bound "
                                          f"{div:.3g} for {self.divergence_blocks} blocks")
            if s < lo or s > hi:
                self.stats["inconsistent_blocks"] += 1
                status = f"inconsistent (block NIS {s:.3g} outside [{lo:.3g}, {hi:.3g}])"
            else:
                status = "ok"
        return status

    def _reinitialise(self, reason):
        """Safe fallback: measured states from the latest measurement, others kept (or zero if non-finite), P = P0."""
        self.stats["divergences"] += 1
        self.stats["resets"] += 1
        x = np.where(np.isfinite(self.kf.x), self.kf.x, 0.0)
        if self._last_z is not None:
            mask, z = self._last_z
            x[CHANNEL_STATE[mask]] = z
        self.kf.x = x
        self.kf.P = self.P0.copy()
        self._block_nis, self._block_dof, self._block_n = 0.0, 0, 0
        return f"diverged: reinitialised ({reason})"

    # -- batch ----------------------------------------------------------------------------------------
    def run(self, stream: SensorStream, thrusts) -> EKFResult:
        """Filter a whole stream; ``thrusts`` (n-1, k) or (n, k) are the commands applied after each sample.

        The first sample only updates the initial estimate; sample k is predicted with ``thrusts[k-1]``.
        """
        thrusts = np.asarray(thrusts, float)
        n = len(stream.t)
        if thrusts.ndim != 2 or len(thrusts) < n - 1:
            raise ValueError(f"thrusts must be ({n - 1}, k) for a stream of {n} samples, got {thrusts.shape}")
        xs, sd, nis, dof, status = np.empty((n, 12)), np.empty((n, 12)), np.full(n, np.nan), np.zeros(n, int), []
        for k in range(n):
            if k == 0:
                self.update(stream.values[0])
                self.last_status = "ok"
            else:
                self.step(thrusts[k - 1], stream.values[k])
            xs[k] = self.kf.x
            sd[k] = np.sqrt(np.clip(np.diag(self.kf.P), 0.0, None))
            nis[k], dof[k] = self.nis, self.dof
            status.append(self.last_status)
        return EKFResult(t=np.asarray(stream.t), x=xs, sigma=sd, nis=nis, dof=dof, status=status,
                         resets=self.stats["resets"])


def ekf_on_trajectory(filter_model, t, x, u, dt=0.05, sensors: SensorConfig | None = None, seed=0, **ekf_options):
    """Run the EKF designed on ``filter_model`` on sensors simulated from a true trajectory (e.g. plant B's).

    Parameters
    ----------
    filter_model : Vehicle, PlantParameters or model name
    t : (n,) array_like
        Times of the true states, s (uniform; resampled to the filter step ``dt``, which must be a multiple).
    x : (n, 12) array_like
        True states.
    u : (n - 1, k) array_like
        Thrusts applied over each interval (N), e.g. ``SimResult.u``.
    sensors, seed
        Sensor configuration and noise seed (:func:`udrobot_ctrl.control.sensors.measure`).
    **ekf_options
        Passed to :class:`UDrobotEKF`.

    Returns
    -------
    dict
        ``{"rmse": {state: value for every state}, "nis_mean": mean NIS, "nis_per_dof": mean NIS/dof,
        "dof_mean": mean measurement dimension, "resets": count, "result": EKFResult, "truth": (m, 12)}``.
    """
    from udrobot_ctrl.control.sensors import measure

    t, x, u = np.asarray(t, float), np.asarray(x, float), np.asarray(u, float)
    if len(t) < 2 or x.shape != (len(t), 12) or len(u) < len(t) - 1:
        raise ValueError(f"need t (n,), x (n, 12), u (n-1, k); got {t.shape}, {x.shape}, {u.shape}")
    step = (t[-1] - t[0]) / (len(t) - 1)
    every = int(round(dt / step))
    if every < 1 or abs(every * step - dt) > 1e-9 * max(dt, 1.0):
        raise ValueError(f"filter step dt = {dt} s is not a multiple of the trajectory step {step:.6g} s")
    if not isinstance(filter_model, (PlantParameters,)) and not hasattr(filter_model, "added_mass"):
        from udrobot_ctrl.vehicle import load_model

        filter_model = load_model(filter_model)
    sel = np.arange(0, len(t), every)
    ts, xs = t[sel], x[sel]
    us = u[sel[:-1]]  # ZOH commands at the filter's sample times (commands held over the controller period)
    sensors = sensors or SensorConfig()
    stream = measure(ts, xs, sensors, seed=seed)
    ekf_options.setdefault("x0", xs[0])
    ekf = UDrobotEKF(filter_model, dt, sensors=sensors, **ekf_options)
    res = ekf.run(stream, us)
    ok = res.dof > 0
    return {"rmse": res.rmse(xs), "nis_mean": res.nis_mean(), "nis_per_dof": res.nis_normalised(),
            "dof_mean": float(np.mean(res.dof[ok])) if ok.any() else float("nan"), "resets": res.resets,
            "result": res, "truth": xs}
