"""Extended Kalman filter for UDrobot: the nonlinear plant as process model, UDrobot's sensors as measurements.

* Process model: one RK4 step of the casadi plant (:func:`udrobot_ctrl.dynamics.plant_casadi.rk4_step_function`)
  with the applied thrusts held over ``dt``; its Jacobian ``F = dx_next/dx`` comes from the same generated
  casadi function (gcc-compiled and cached when possible). The prediction is filterpy's
  :class:`~filterpy.kalman.ExtendedKalmanFilter` with ``predict_x`` overridden by the RK4 step; the update
  is done here (gated, Joseph form like filterpy's) and leaves ``kf.y``, ``kf.S``, ``kf.SI``, ``kf.K`` set.
  The default per-step path (``fast=True``, issue 38: ~25 us a step against ~150 us) calls the same compiled
  function directly on preallocated buffers and does an update whose every channel passes the gate in one numba
  kernel (:func:`udrobot_ctrl.control.fastpath.ekf_update_all`); ``fast=False`` is the reference path above
  (the two agree to ~1e-15, tests/udrobot_ctrl/control/test_fastpath.py).
* Process noise: unmodelled forces and moments (tether, waves, model error) as piecewise-constant white
  noise through the inverse mass matrix, ``Q_nu = dt^2 M^-1 diag(sigma_tau^2) M^-T``, plus a small
  random walk on the pose (assumed magnitudes on :class:`ProcessNoise`).
* Measurements: the channels of :mod:`udrobot_ctrl.control.sensors` (pressure depth, IMU attitude and rates, DVL
  body velocity, optional USBL position). Each step uses whichever channels are present (NaN = absent):
  H (rows of the identity) and R (diagonal) are built per availability pattern and cached; angle
  residuals are wrapped to [-pi, pi).
* Innovation gating: before each update the innovation ``y`` of every sensor (depth, attitude, gyro, DVL,
  USBL: :data:`udrobot_ctrl.control.sensors.SENSORS`) is tested, ``NIS_s = y_s' S_ss^-1 y_s`` against the
  chi-square quantile ``chi2.ppf(1 - gate_probability, dof_s)`` (``dof_s`` = the sensor's present channels;
  ``gate_probability`` 1e-4 = the chance of rejecting a correct sample of a consistent filter). A rejected
  sensor drops its channel with the largest normalised innovation ``|y_i| / sqrt(S_ii)`` until the rest passes,
  so one spiked DVL axis does not discard the other two. Rejections are counted per channel
  (:meth:`UDrobotEKF.channel_stats`, :class:`ChannelStats`). A channel rejected at every sample for longer
  than ``reject_timeout_s`` (and at least ``reject_min_samples`` samples) is reported (:class:`ChannelFault`:
  a failed or frozen sensor, or a real jump the model cannot follow) and re-initialised: its state is
  decorrelated and given the variance ``R + y^2``, and the sample is accepted, so the filter never locks a
  correct sensor out forever. :meth:`UDrobotEKF.exclude_channel` takes a channel out (e.g. a frozen sensor
  found by :mod:`udrobot_ctrl.control.faults`) until :meth:`UDrobotEKF.include_channel`.
* Consistency: the normalised innovation squared ``NIS = y' S^-1 y`` of every update (accepted channels);
  the sum over blocks of ``nis_window`` steps is compared with the two-sided chi-square bounds (``alpha``)
  for the total measurement dimension -> ``consistent`` / ``inconsistent``; a gated-out channel enters
  the block with its 1-dof gate value (so persistent rejection still reads as divergence, a lone spike
  does not). Divergence: ``divergence_blocks`` consecutive blocks above the ``1 - divergence_alpha``
  quantile, or a non-finite state/covariance. The safe fallback then re-initialises the measured states
  from the latest accepted measurement (the latest one for a channel rejected for ``reject_min_samples``
  samples or more), keeps the others and resets P to P0 (``stats['resets']``); the filter never raises
  inside the loop.
"""
from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass

import casadi as ca
import numpy as np
from filterpy.kalman import ExtendedKalmanFilter
from scipy.stats import chi2

from udrobot_ctrl.constants import STATE_NAMES
from udrobot_ctrl.control.fastpath import CompiledFunction, ekf_update_all
from udrobot_ctrl.control.mpc import maybe_compiled
from udrobot_ctrl.control.sensors import (
    ANGLE_CHANNELS,
    CHANNEL_STATE,
    CHANNELS,
    SENSORS,
    SensorConfig,
    SensorStream,
    channel_index,
    measure,
)
from udrobot_ctrl.dynamics.plant import PlantParameters, plant_parameters, wrap_angle
from udrobot_ctrl.dynamics.plant_casadi import rk4_step_function
from udrobot_ctrl.vehicle import load_model

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


def _step_jacobian(p: PlantParameters, dt: float) -> ca.Function:
    step = rk4_step_function(p, dt, "thrust")
    x = ca.SX.sym("x", 12)
    f = ca.SX.sym("f", p.T.shape[1])
    xn = step(x, f)
    return ca.Function("ekf_step", [x, f], [xn, ca.densify(ca.jacobian(xn, x))], ["x", "f"], ["x_next", "F"])


def step_jacobian_function(p: PlantParameters, dt: float, compile: bool = True) -> ca.Function:
    """``(x, f) -> (x_next, F)``: RK4 plant step (thrust inputs) and state Jacobian (compiled when gcc is there)."""
    return maybe_compiled(_step_jacobian(p, dt), p, dt, "ekf", compile=compile)


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



@dataclass(frozen=True)
class ChannelStats:
    """Innovation-gating statistics of one channel over a filter run.

    Attributes
    ----------
    channel : str
        Channel name (:data:`udrobot_ctrl.control.sensors.CHANNELS`).
    samples : int
        Samples presented to the filter (present and not excluded).
    rejected : int
        Samples rejected by the innovation gate.
    reinitialisations : int
        Times the channel was re-initialised after ``reject_timeout_s`` of continuous rejection.
    longest_rejection_s : float
        Longest run of consecutive rejections, s (time from its first to its last rejected sample).
    """

    channel: str
    samples: int
    rejected: int
    reinitialisations: int
    longest_rejection_s: float

    @property
    def rejection_rate(self) -> float:
        """Rejected / presented samples (NaN without samples)."""
        return self.rejected / self.samples if self.samples else float("nan")


@dataclass(frozen=True)
class ChannelFault:
    """A channel rejected at every sample for longer than the filter's ``reject_timeout_s``.

    Attributes
    ----------
    t : float
        Time of the report (the sample that was then accepted with inflated covariance), s.
    channel : str
    since : float
        Time of the first rejected sample of the run, s.
    rejections : int
        Consecutive rejected samples before the report.
    innovation : float
        Measurement minus prediction at the report, in the channel's unit (m, rad, m/s, rad/s).
    action : str
        What the filter did.
    """

    t: float
    channel: str
    since: float
    rejections: int
    innovation: float
    action: str = "re-initialised: state decorrelated, variance R + y^2, sample accepted"


@dataclass
class EKFResult:
    """Filter output over a stream (:meth:`UDrobotEKF.run`).

    Attributes
    ----------
    t : (n,) ndarray
        Sample times, s.
    x : (n, 12) ndarray
        State estimates, SI units (m, rad, m/s, rad/s).
    sigma : (n, 12) ndarray
        Their standard deviations, same units.
    nis : (n,) ndarray
        Normalised innovation squared of the accepted measurements (dimensionless; NaN without any).
    dof : (n,) ndarray
        Dimension of the accepted measurement per step (a count).
    status : list of str
        Per step: ``ok``, or why the filter was flagged (an inconsistent NIS block) or re-initialised (printed
        text).
    resets : int
        Times the filter was re-initialised after a divergence.
    rejected : (n, 13) ndarray of bool, optional
        Samples refused by the innovation gate, per measurement channel.
    channels : tuple of ChannelStats
        The per-channel gating statistics.
    channel_faults : tuple of ChannelFault
        The channels re-initialised after continuous rejection.
    """

    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray
    nis: np.ndarray
    dof: np.ndarray
    status: list
    resets: int
    rejected: np.ndarray | None = None
    channels: tuple = ()
    channel_faults: tuple = ()

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
                e = wrap_angle(e)
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
        Initial uncertainty (SI units of the states).
    noise : ProcessNoise or (12, 12) array, optional
        Process noise magnitudes or a ready Q.
    nis_window : int
        Steps per NIS block.
    alpha : float
        Two-sided significance of the consistency bounds (0.05 -> 95 %).
    divergence_alpha : float
        Upper-tail significance of the divergence test (a probability, 1e-3).
    divergence_blocks : int
        Consecutive blocks above the divergence bound before the filter re-initialises.
    compile : bool
        gcc-compile the generated step/Jacobian function (cached; falls back to casadi's VM).
    gate_probability : float
        Probability that the innovation gate rejects a correct sample of one sensor (chi-square upper tail,
        dof = the sensor's present channels); 1e-4 (assumed: ~1 false rejection per sensor in 8 min at
        20 Hz). 0 disables gating.
    reject_timeout_s : float
        s. A channel rejected at every sample for longer than this (2 s, assumed: longer than the frozen-
        sensor window of :mod:`udrobot_ctrl.control.faults` and than any credible spike burst) is reported and
        re-initialised.
    reject_min_samples : int
        ... and for at least this many samples (3: a 1 Hz USBL needs 3 s).
    fast : bool
        Per-step fast path (default): the RK4 step and its Jacobian called through their compiled C code on
        preallocated buffers (:class:`udrobot_ctrl.control.fastpath.CompiledFunction`, the same generated
        function), the covariance propagated here, and an update whose every channel passes the gate done by
        one numba kernel (:func:`udrobot_ctrl.control.fastpath.ekf_update_all`); per-sensor gating and
        re-initialisation stay in Python. False: filterpy's predict and the numpy update (the reference; the
        two agree to rounding, ~1e-15).
    """

    def __init__(self, vehicle, dt=0.05, sensors: SensorConfig | None = None, x0=None, P0=None, noise=None,
                 nis_window=20, alpha=0.05, divergence_alpha=1e-3, divergence_blocks=2, compile=True,
                 gate_probability=1e-4, reject_timeout_s=2.0, reject_min_samples=3, fast=True):
        self.params = vehicle if isinstance(vehicle, PlantParameters) else plant_parameters(vehicle)
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.dt = float(dt)
        self.sensors = sensors or SensorConfig()
        self.sigmas = self.sensors.sigmas()
        nu = self.params.T.shape[1]
        self.fast = bool(fast)
        if self.fast:
            self._step = CompiledFunction(_step_jacobian(self.params, self.dt), self.params, self.dt, "ekf",
                                          compile=compile)
            self.kf = _PlantEKF(None, nu)
        else:
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
        if not 0 <= gate_probability < 1:
            raise ValueError(f"gate_probability must be in [0, 1), got {gate_probability}")
        if not reject_timeout_s > 0:
            raise ValueError(f"reject_timeout_s must be > 0 s, got {reject_timeout_s}")
        self.gate_probability = float(gate_probability)
        self.reject_timeout_s, self.reject_min_samples = float(reject_timeout_s), int(reject_min_samples)
        self._r = self.sigmas ** 2
        self._sensor_of = np.empty(len(CHANNELS), int)
        for g, (_, chans) in enumerate(SENSORS):
            self._sensor_of[list(chans)] = g
        self._gates: dict[int, float] = {}
        self._bounds: dict[int, tuple] = {}
        self._layouts: dict[bytes, tuple] = {}
        self.channel_enabled = np.ones(len(CHANNELS), bool)
        self.reset()

    # -- state --------------------------------------------------------------------------------------
    def reset(self, x0=None):
        """Restart from ``x0`` (default the constructor's) with covariance P0 and cleared statistics."""
        self.kf.x = (self.x0 if x0 is None else np.asarray(x0, float).reshape(12)).copy()
        self.kf.P = self.P0.copy()
        self._block_nis, self._block_dof, self._block_n = 0.0, 0, 0
        self._high_blocks = 0
        self.nis, self.dof = np.nan, 0
        self.t = 0.0
        self.last_status = "ok"
        self.stats = {"steps": 0, "resets": 0, "divergences": 0, "inconsistent_blocks": 0, "blocks": 0,
                      "status": "ok", "step_time_s": np.nan, "nis_block_mean": np.nan, "rejected": 0,
                      "channel_reinitialisations": 0}
        self.step_times: deque = deque(maxlen=100000)
        nc = len(CHANNELS)
        self._last_value = np.full(nc, np.nan)  # latest sample per channel
        self._last_accepted = np.full(nc, np.nan)  # latest accepted sample per channel
        self._n_samples = np.zeros(nc, int)
        self._n_rejected = np.zeros(nc, int)
        self._n_reinit = np.zeros(nc, int)
        self._run = np.zeros(nc, int)  # consecutive rejections
        self._run_since = np.full(nc, np.nan)
        self._longest = np.zeros(nc)
        self.rejected_now = np.zeros(nc, bool)
        self._reopen = np.zeros(nc, bool)
        self._gated_nis, self._gated_dof = 0.0, 0  # gated-out contribution of the last update to the NIS block
        self._contribution = np.zeros(nc)  # per channel, of the last update
        self.channel_faults: list[ChannelFault] = []

    @property
    def x(self) -> np.ndarray:
        """Current estimate (12,)."""
        return self.kf.x

    @property
    def P(self) -> np.ndarray:
        """Current covariance (12, 12)."""
        return self.kf.P

    # -- channels -----------------------------------------------------------------------------------
    def exclude_channel(self, name: str):
        """Stop using channel ``name`` (e.g. a sensor found frozen) until :meth:`include_channel`."""
        self.channel_enabled[channel_index(name)] = False

    def include_channel(self, name: str):
        """Use channel ``name`` again (its rejection run restarts)."""
        i = channel_index(name)
        self.channel_enabled[i] = True
        self._run[i], self._run_since[i] = 0, np.nan

    def reopen_gates(self):
        """After a change of the process model (e.g. a thruster fault found and accounted for): every channel
        in a rejection run is re-initialised at its next sample instead of waiting for ``reject_timeout_s``
        (the model that rejected it was wrong)."""
        self._reopen |= self._run > 0

    def channel_stats(self) -> tuple:
        """:class:`ChannelStats` of every channel since the last :meth:`reset`."""
        return tuple(ChannelStats(c, int(self._n_samples[i]), int(self._n_rejected[i]), int(self._n_reinit[i]),
                                  float(self._longest[i])) for i, c in enumerate(CHANNELS))

    def _chi2_bounds(self, dof):
        b = self._bounds.get(dof)
        if b is None:
            b = self._bounds[dof] = (chi2.ppf(self.alpha / 2, dof), chi2.ppf(1 - self.alpha / 2, dof),
                                     chi2.ppf(1 - self.divergence_alpha, dof))
        return b

    def _gate(self, dof):
        g = self._gates.get(dof)
        if g is None:
            g = self._gates[dof] = float(chi2.isf(self.gate_probability, dof)) if self.gate_probability > 0 \
                else np.inf
        return g

    # -- filter steps ---------------------------------------------------------------------------------
    def predict(self, thrust):
        """Propagate the estimate through the plant with the applied thrusts (N) over ``dt``."""
        f = np.clip(np.asarray(thrust, float), self.params.f_min, self.params.f_max)
        kf = self.kf
        if self.fast:  # filterpy's predict without its prior copies: x = F(x, f), P = F P F' + Q
            xn, F = self._step(kf.x, f)
            kf.F = F.copy()
            kf.x = xn.copy()
            kf.P = kf.F @ kf.P @ kf.F.T + kf.Q
        else:
            kf.predict(f)
        kf.x[5] = wrap_angle(kf.x[5])

    def _layout(self, present):
        """Per availability pattern (cached): channels, states, angle mask, R diagonal, H, sensor blocks by size."""
        key = present.tobytes()
        lay = self._layouts.get(key)
        if lay is None:
            ch = np.flatnonzero(present)
            st = CHANNEL_STATE[ch]
            H = np.zeros((ch.size, 12))
            H[np.arange(ch.size), st] = 1.0
            sensor = self._sensor_of[ch]
            blocks: dict[int, list] = {}
            for g in np.unique(sensor):
                pos = np.flatnonzero(sensor == g)
                blocks.setdefault(pos.size, []).append(pos)
            blocks = {k: np.array(v) for k, v in blocks.items()}  # size -> (n_sensors, size) positions
            lay = self._layouts[key] = (ch, st, ANGLE_CHANNELS[ch], self._r[ch], H, blocks)
        return lay

    def update(self, z_row):
        """Gate and update with one row of channel values (13,), NaN where absent (see the module docstring).

        Returns the NIS of the accepted channels (NaN if none); ``rejected_now`` (13,) marks the gated-out ones.
        """
        z_row = np.asarray(z_row, float)
        present = np.isfinite(z_row) & self.channel_enabled
        self.rejected_now = np.zeros(len(CHANNELS), bool)
        self._gated_nis, self._gated_dof = 0.0, 0
        if not present.any():
            self.nis, self.dof = np.nan, 0
            return np.nan
        kf = self.kf
        ch, st, ang, r, H, blocks = self._layout(present)
        if self.fast:
            gate = self._gate(min(blocks)) if self.gate_probability > 0 else np.inf
            ok, nis, y, S, SI, K = ekf_update_all(kf.x, kf.P, z_row, ch, st, ang, r, gate, self._last_value,
                                                  self._last_accepted, self._n_samples, self._run, self._run_since)
            if ok:
                kf.y, kf.S, kf.SI, kf.K = y, S, SI, K
                self.nis, self.dof = float(nis), int(ch.size)
                return self.nis
        y = z_row[ch] - kf.x[st]
        if ang.any():
            y[ang] = wrap_angle(y[ang])
        S = kf.P[st[:, None], st] + np.diag(r)
        self._last_value[ch] = z_row[ch]
        self._n_samples[ch] += 1
        SI = np.linalg.inv(S)
        # a sensor's NIS never exceeds the joint NIS (marginal Mahalanobis distance <= joint): when the joint one
        # is below the smallest gate, every sensor passes and the per-sensor test is skipped
        if self.gate_probability <= 0 or float(y @ SI @ y) <= self._gate(min(blocks)):
            accept = np.ones(ch.size, bool)
        else:
            accept = self._gate_sensors(ch, y, S, blocks)
        if accept.all():
            self._run[ch] = 0
            self._run_since[ch] = np.nan
            sa, ya, Sa, Ha, ra = st, y, S, H, r
        else:
            forced = self._reinitialise_stale(ch, y, accept)
            if forced.any():  # P changed for the forced channels: innovation covariance again
                S = kf.P[st[:, None], st] + np.diag(r)
            a = np.flatnonzero(accept)
            self.rejected_now[ch[~accept]] = True
            if a.size == 0:
                self.nis, self.dof = np.nan, 0
                return np.nan
            sa, ya, Sa, Ha, ra = st[a], y[a], S[a[:, None], a], H[a], r[a]
            SI = np.linalg.inv(Sa)
        self._last_accepted[ch[accept]] = z_row[ch[accept]]
        K = kf.P[:, sa] @ SI
        I_KH = np.eye(12) - K @ Ha
        P = I_KH @ kf.P @ I_KH.T + (K * ra) @ K.T  # Joseph form, as filterpy
        kf.P = 0.5 * (P + P.T)
        kf.x = kf.x + K @ ya
        kf.x[5] = wrap_angle(kf.x[5])
        kf.y, kf.S, kf.SI, kf.K = ya, Sa, SI, K
        self.nis = float(ya @ SI @ ya)
        self.dof = int(ya.size)
        return self.nis

    def _gate_sensors(self, ch, y, S, blocks):
        """Accept mask over the present channels ``ch``: per sensor NIS gate (batched over the sensors of one
        size), then, for a rejected sensor, its worst channel is dropped until the rest passes."""
        accept = np.ones(ch.size, bool)
        if self.gate_probability <= 0:
            return accept
        failed = []
        for size, pos in blocks.items():  # pos (n_sensors, size)
            yb = y[pos]
            Sb = S[pos[:, :, None], pos[:, None, :]]
            nis = np.einsum("ki,ki->k", yb, np.linalg.solve(Sb, yb[..., None])[..., 0])
            failed += [pos[j] for j in np.flatnonzero(nis > self._gate(size))]
        for pos in failed:
            while pos.size:
                yg = y[pos]
                Sg = S[pos[:, None], pos]
                nis = float(yg @ np.linalg.solve(Sg, yg))
                if nis <= self._gate(pos.size):
                    break
                worst = int(np.argmax(yg ** 2 / np.diag(Sg)))
                accept[pos[worst]] = False
                contribution = min(yg[worst] ** 2 / Sg[worst, worst], self._gate(1))
                self._gated_nis += contribution
                self._gated_dof += 1
                self._contribution[ch[pos[worst]]] = contribution
                pos = np.delete(pos, worst)
        return accept

    def _reinitialise_stale(self, ch, y, accept):
        """Count rejection runs; a channel rejected for longer than the timeout is reported and re-initialised
        (state decorrelated, variance R + y^2) and accepted. Returns the mask of such channels over ``ch``."""
        forced = np.zeros(ch.size, bool)
        rej = ~accept
        ok = ch[accept]
        self._run[ok], self._run_since[ok] = 0, np.nan
        if not rej.any():
            return forced
        bad = ch[rej]
        self._n_rejected[bad] += 1
        self.stats["rejected"] += int(bad.size)
        new = np.isnan(self._run_since[bad])
        self._run_since[bad[new]] = self.t
        self._run[bad] += 1
        self._longest[bad] = np.maximum(self._longest[bad], self.t - self._run_since[bad])
        for j in np.flatnonzero(rej):
            i = ch[j]
            timeout = self._run[i] >= self.reject_min_samples and self.t - self._run_since[i] >= self.reject_timeout_s
            if timeout or self._reopen[i]:
                self._reopen[i] = False
                s = CHANNEL_STATE[i]
                P = self.kf.P
                var = self._r[i] + y[j] ** 2
                P[s, :] = 0.0
                P[:, s] = 0.0
                P[s, s] = var
                self.channel_faults.append(ChannelFault(
                    t=self.t, channel=CHANNELS[i], since=float(self._run_since[i]), rejections=int(self._run[i]),
                    innovation=float(y[j]), action=ChannelFault.action if timeout else
                    "re-initialised after a process-model change (reopen_gates): variance R + y^2, sample accepted"))
                self._n_reinit[i] += 1
                self.stats["channel_reinitialisations"] += 1
                self._n_rejected[i] -= 1
                self.stats["rejected"] -= 1
                self._run[i], self._run_since[i] = 0, np.nan
                accept[j] = True
                forced[j] = True
                # the forced channel no longer counts as gated out in the NIS block
                self._gated_nis = max(0.0, self._gated_nis - self._contribution[i])
                self._gated_dof = max(0, self._gated_dof - 1)
        return forced

    def step(self, thrust, z_row, t=None):
        """Predict with ``thrust`` then update with ``z_row`` taken at time ``t`` (s; default the previous
        time + dt); never raises. Returns the estimate (12,)."""
        t0 = time.perf_counter()
        self.t = self.t + self.dt if t is None else float(t)
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
        # one sum first (finite values summing to inf only trigger the exact test)
        if not math.isfinite(float(kf.x.sum()) + float(kf.P.sum())) and not (
                np.all(np.isfinite(kf.x)) and np.all(np.isfinite(kf.P))):
            return self._reinitialise("non-finite state or covariance")
        status = self.last_status if not self.last_status.startswith("diverged") else "ok"
        if self.dof or self._gated_dof:
            self._block_nis += (self.nis if self.dof else 0.0) + self._gated_nis
            self._block_dof += self.dof + self._gated_dof
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
        z = np.where(self._run >= self.reject_min_samples, self._last_value, self._last_accepted)
        z = np.where(np.isfinite(z), z, self._last_value)
        have = np.isfinite(z) & self.channel_enabled
        x[CHANNEL_STATE[have]] = z[have]
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
        rejected = np.zeros((n, len(CHANNELS)), bool)
        ts = np.asarray(stream.t, float)
        for k in range(n):
            if k == 0:
                self.t = float(ts[0])
                self.update(stream.values[0])
                self.last_status = "ok"
            else:
                self.step(thrusts[k - 1], stream.values[k], t=ts[k])
            xs[k] = self.kf.x
            sd[k] = np.sqrt(np.clip(np.diag(self.kf.P), 0.0, None))
            nis[k], dof[k] = self.nis, self.dof
            rejected[k] = self.rejected_now
            status.append(self.last_status)
        return EKFResult(t=ts, x=xs, sigma=sd, nis=nis, dof=dof, status=status, resets=self.stats["resets"],
                         rejected=rejected, channels=self.channel_stats(), channel_faults=tuple(self.channel_faults))


def ekf_on_trajectory(filter_model, t, x, u, dt=0.05, sensors: SensorConfig | None = None, seed=0, **ekf_options):
    """Run the EKF designed on ``filter_model`` on sensors simulated from a true trajectory (e.g. plant B's).

    Parameters
    ----------
    filter_model : Vehicle, PlantParameters or model name
        The model the filter is designed on.
    t : (n,) array_like
        Times of the true states, s (uniform; resampled to the filter step ``dt``, which must be a multiple).
    x : (n, 12) array_like
        True states.
    u : (n - 1, k) array_like
        Thrusts applied over each interval (N), e.g. ``SimResult.u``.
    dt : float
        Filter step, s (a multiple of the trajectory's step).
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
    t, x, u = np.asarray(t, float), np.asarray(x, float), np.asarray(u, float)
    if len(t) < 2 or x.shape != (len(t), 12) or len(u) < len(t) - 1:
        raise ValueError(f"need t (n,), x (n, 12), u (n-1, k); got {t.shape}, {x.shape}, {u.shape}")
    step = (t[-1] - t[0]) / (len(t) - 1)
    every = int(round(dt / step))
    if every < 1 or abs(every * step - dt) > 1e-9 * max(dt, 1.0):
        raise ValueError(f"filter step dt = {dt} s is not a multiple of the trajectory step {step:.6g} s")
    if not isinstance(filter_model, (PlantParameters,)) and not hasattr(filter_model, "added_mass"):
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
