"""Sensor and thruster faults: injection for closed-loop tests, detection and reporting.

Injection (what a test or a study does to the loop)
---------------------------------------------------
* :class:`SensorSpike`: one channel reads ``value`` at the samples within ``[t, t + duration]``.
* :class:`FrozenSensor`: from ``t`` on, one channel repeats its last value (a hung driver, a stuck ADC).
* :class:`DeadThruster`: from ``t`` on, one thruster produces no thrust whatever it is commanded.
* :class:`StuckThruster`: from ``t`` on, one thruster produces a constant ``thrust_N``.

Detection (what runs on the vehicle; :class:`FaultMonitor` bundles them with the EKF's own reports)
----------------------------------------------------------------------------------------------------
* Frozen sensor (:class:`FrozenChannelDetector`): a live channel's samples scatter at least by the sensor
  noise, so over a window of ``n`` samples ``(n - 1) s^2 / sigma^2`` is at least chi-square(n - 1)
  distributed (motion only adds variance). The channel is declared frozen when this statistic falls below
  ``chi2.ppf(p_false, n - 1)``; it is declared alive again when it exceeds it. Latency: ``n - 1`` sample
  periods after the value stops changing (10 samples: 0.45 s for the 20 Hz depth sensor, 1.8 s for the
  5 Hz DVL). A sensor whose quantisation step is comparable to its noise needs a larger window.
* Innovation gating of the EKF (:mod:`udrobot_ctrl.control.ekf`): spikes are gated out and counted per channel;
  a channel rejected for longer than the EKF's ``reject_timeout_s`` is reported (``kind`` ``"rejected
  channel"``).
* Thruster fault (:class:`ThrusterFaultDetector`): commanded thrust against the motion the sensors see.
  Every ``stride_s`` a window of ``window_s`` starts from the EKF estimate ``x0`` (covariance ``P0``). Along
  the window the design model is simulated with the commanded thrusts, and its sensitivities are
  propagated with the RK4 Jacobians ``A_k``, ``B_k``: ``Phi`` (to the initial state), ``G_i`` (to a constant
  thrust of thruster ``i``) and ``C_i`` (the contribution of thruster ``i``'s commands). With ``e`` the
  residuals of the raw measurements (channel noise ``R``) against that simulation:

  - H0 (healthy): ``e = Phi dx0 + v``, ``dx0 ~ N(0, P0)``;
  - H_i (thruster ``i`` delivers a constant ``a_i`` instead of its commands; dead: ``a_i = 0``):
    ``e + C_i = Phi dx0 + G_i a_i + v``.

  The generalised likelihood ratio ``lambda_i = J0 - J_i`` (drop of the weighted least-squares cost) is
  chi-square(1) under H0. Thruster ``i`` is reported when ``lambda_i > chi2.isf(p_false, 1)``, it explains
  the data better than every other thruster by the same margin (isolation), and the estimated thrust
  differs from the mean command by at least ``min_fault_N``; ``|a_i| <= dead_band_N`` reads as dead, else
  stuck at ``a_i``. Samples with a normalised residual above ``outlier_sigma`` under the best fit (spikes)
  and channels flagged frozen are left out. Latency: one window after the commands first differ from the
  faulty thrust by ``min_fault_N`` (+ up to one stride). A thruster that is commanded what it delivers
  (a dead thruster commanded ~0 N) cannot be told from a healthy one: physics, not a detector limit.
  Assumptions: the design model matches the vehicle (drag or buoyancy errors of a few newtons look like
  a thruster offset; ``min_fault_N`` 2 N keeps them below the alarm for the bundled models), constant
  fault over a window.

Per step (issue 38) the frozen-sensor test is one numba kernel over all channels
(:func:`udrobot_ctrl.control.fastpath.frozen_statistics`) and the open thruster windows advance together: the
corrected thrust written into the input buffer of the compiled linearisation mapped over the window slots
(:func:`udrobot_ctrl.control.fastpath.window_inputs`), one in-place call of it (the slots' states live in its
input buffer, nothing is copied), and one kernel for the sensitivities, residuals and the count of finished
windows (:func:`udrobot_ctrl.control.fastpath.advance_windows`); windows open by one kernel too
(:func:`udrobot_ctrl.control.fastpath.open_window`). ~30-35 us a step (the mapped RK4 Jacobians ~14 us of it)
against ~60 us with the per-step numpy glue and ~0.6 ms before; the GLR evaluation of a finished window (every
``stride_s``) ~0.5-1 ms.

All events are :class:`FaultEvent` (time of detection, kind, which sensor or thruster, estimated value).
:class:`EstimatorLoop` closes the loop plant -> sensors (+ sensor faults) -> EKF -> controller -> thrusters
(+ thruster faults) for :func:`udrobot_ctrl.dynamics.sim.simulate`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from udrobot_ctrl.control.ekf import UDrobotEKF
from udrobot_ctrl.control.fastpath import (
    CompiledFunction,
    advance_windows,
    frozen_statistics,
    open_window,
    window_inputs,
)
from udrobot_ctrl.control.mpc import linearization_function
from udrobot_ctrl.control.sensors import (
    ANGLE_CHANNELS,
    CHANNEL_STATE,
    CHANNELS,
    SensorConfig,
    SensorSampler,
    channel_index,
)
from udrobot_ctrl.dynamics.plant import PlantParameters, wrap_angle

FROZEN = "frozen sensor"
RECOVERED = "sensor alive again"
REJECTED = "rejected channel"
DEAD = "dead thruster"
STUCK = "stuck thruster"


# ----------------------------------------------------------------------------- injection
@dataclass(frozen=True)
class SensorSpike:
    """Channel ``channel`` reads ``value`` (its unit) at every sample in ``[t, t + duration]`` s."""

    channel: str
    t: float
    value: float
    duration: float = 0.0

    def apply(self, t, z):
        i = channel_index(self.channel)
        if self.t <= t <= self.t + self.duration + 1e-9 and np.isfinite(z[i]):
            z[i] = self.value
        return z


@dataclass
class FrozenSensor:
    """From ``t`` (s) on, channel ``channel`` repeats the last value it produced before ``t``."""

    channel: str
    t: float
    _held: float = field(default=np.nan, repr=False)

    def apply(self, t, z):
        i = channel_index(self.channel)
        if t < self.t:
            if np.isfinite(z[i]):
                self._held = z[i]
        elif np.isfinite(z[i]) and np.isfinite(self._held):
            z[i] = self._held
        return z


@dataclass(frozen=True)
class DeadThruster:
    """From ``t`` (s) on, thruster ``thruster`` (0-based) produces 0 N."""

    thruster: int
    t: float

    def apply(self, t, f):
        if t >= self.t:
            f[self.thruster] = 0.0
        return f


@dataclass(frozen=True)
class StuckThruster:
    """From ``t`` (s) on, thruster ``thruster`` (0-based) produces ``thrust_N`` whatever it is commanded."""

    thruster: int
    t: float
    thrust_N: float

    def apply(self, t, f):
        if t >= self.t:
            f[self.thruster] = self.thrust_N
        return f


# ----------------------------------------------------------------------------- events
@dataclass(frozen=True)
class FaultEvent:
    """A detected fault.

    Attributes
    ----------
    t : float
        Detection time, s.
    kind : str
        :data:`FROZEN`, :data:`RECOVERED`, :data:`REJECTED`, :data:`DEAD` or :data:`STUCK`.
    source : str
        Channel name or ``"thruster <i>"`` (0-based, the model's thruster order).
    index : int
        Channel or thruster index.
    value : float
        Frozen value (channel unit), innovation of a rejected channel, or estimated thrust of a faulty
        thruster (N).
    detail : str
        Human-readable evidence (statistic, threshold, window).
    t_onset : float
        Estimated fault onset, s (thruster faults; NaN otherwise).
    """

    t: float
    kind: str
    source: str
    index: int
    value: float
    detail: str
    t_onset: float = float("nan")


# ----------------------------------------------------------------------------- frozen sensor
class FrozenChannelDetector:
    """Per-channel variance test against the sensor noise (see the module docstring).

    Parameters
    ----------
    sigmas : (13,) array_like
        Channel noise standard deviations (``SensorConfig.sigmas()``).
    window : int
        Samples per test (10).
    p_false : float
        Probability of declaring a live channel frozen at one test (1e-6, assumed: < 1 false alarm per
        channel in 14 h at 20 Hz).
    """

    def __init__(self, sigmas, window=10, p_false=1e-6):
        self.sigmas = np.asarray(sigmas, float)
        if window < 3:
            raise ValueError(f"frozen-sensor window must be >= 3 samples, got {window}")
        self.window, self.p_false = int(window), float(p_false)
        self.threshold = float(chi2.ppf(self.p_false, self.window - 1))
        self._buf = np.zeros((len(CHANNELS), self.window))  # ring buffer per channel
        self._count = np.zeros(len(CHANNELS), np.int64)  # samples seen per channel
        self._stats = np.zeros(len(CHANNELS))
        self._change = np.zeros(len(CHANNELS), bool)
        self.frozen = np.zeros(len(CHANNELS), bool)

    def step(self, t, z_row) -> list:
        """Add one row of samples (NaN = absent); returns the new :class:`FaultEvent` s."""
        events = []
        z_row = np.asarray(z_row, float)
        if not frozen_statistics(self._buf, self._count, z_row, self.sigmas, ANGLE_CHANNELS, self.frozen,
                                 self.threshold, self._stats, self._change):
            return events
        for i in np.flatnonzero(self._change):
            stat = float(self._stats[i])
            if not self.frozen[i]:
                self.frozen[i] = True
                events.append(FaultEvent(t, FROZEN, CHANNELS[i], int(i), float(z_row[i]),
                                         f"(n-1) s^2/sigma^2 = {stat:.3g} < chi2.ppf({self.p_false:g}, "
                                         f"{self.window - 1}) = {self.threshold:.3g} over {self.window} samples"))
            else:
                self.frozen[i] = False
                events.append(FaultEvent(t, RECOVERED, CHANNELS[i], int(i), float(z_row[i]),
                                         f"(n-1) s^2/sigma^2 = {stat:.3g} back above {self.threshold:.3g}"))
        return events


# ----------------------------------------------------------------------------- thruster faults
class _Window:
    """One finished detection window: simulated state and, per step k = 0..n, the sensitivities Phi_k, G_k, C_k.

    Attributes
    ----------
    t0 : float
        Start time, s.
    x0, P0 : ndarray
        EKF estimate (12,) and covariance (12, 12) at the start.
    Phi, G, C : ndarray
        (n+1, 12, 12), (n+1, 12, nu), (n+1, 12, nu).
    f : ndarray
        (n, nu) thrust used in the simulation per step, N.
    rows : list
        (step k, channel, state, residual, measured value) per used sample, in time then channel order.
    """

    def __init__(self, t0, x0, P0, Phi, G, C, f, rows):
        self.t0, self.x0, self.P0 = t0, np.array(x0, float), np.array(P0, float)
        self.Phi, self.G, self.C, self.f, self.rows = Phi, G, C, f, rows

    @property
    def steps(self):
        return len(self.f)


class _WindowBank:
    """The open windows of :class:`ThrusterFaultDetector`, propagated together: one call of the mapped,
    compiled linearisation for all of them and batched products (the per-window Python loop cost ~0.1 ms each).

    Slot arrays: state ``x`` (W, 12); histories ``Phi`` (W, n+1, 12, 12), ``G``, ``C`` (W, n+1, 12, nu),
    thrusts ``F`` (W, n, nu); residuals ``E`` and measured values ``Z`` (W, n+1, 13), NaN where no sample.
    """

    def __init__(self, lin_map, n_slots, n, nu):
        self.lin_map, self.W, self.n, self.nu = lin_map, n_slots, n, nu
        self.active = np.zeros(n_slots, bool)
        self.order = np.zeros(n_slots, np.int64)  # creation counter: windows finish oldest first
        self.k = np.zeros(n_slots, np.int64)
        self.t0 = np.zeros(n_slots)
        self.x0 = np.zeros((n_slots, 12))
        self.P0 = np.zeros((n_slots, 12, 12))
        # the mapped linearisation's buffers, in their memory order (column-major (12, W) is row-major (W, 12)):
        # the states are propagated in its input buffer and it is evaluated in place, nothing is copied
        xb, fb = lin_map.input_buffers
        xnb, ab, bb = lin_map.output_buffers
        self.x, self.fc_slots = xb.reshape(n_slots, 12), fb.reshape(n_slots, nu)
        self._xn, self._At, self._Bt = xnb.reshape(n_slots, 12), ab.reshape(12 * n_slots, 12), bb.reshape(-1, 12)
        self.fc = np.zeros(nu)
        self.Phi = np.zeros((n_slots, n + 1, 12, 12))
        self.G = np.zeros((n_slots, n + 1, 12, nu))
        self.C = np.zeros((n_slots, n + 1, 12, nu))
        self.F = np.zeros((n_slots, n, nu))
        self.E = np.full((n_slots, n + 1, len(CHANNELS)), np.nan)
        self.Z = np.full((n_slots, n + 1, len(CHANNELS)), np.nan)
        self._created = np.zeros(1, np.int64)

    def clear(self):
        self.active[:] = False

    def open(self, t, x_est, P_est) -> int:
        """Open a window at ``t`` from the estimate (a window is evaluated and closed before the next one opens, so
        ``ceil(window / stride)`` slots suffice; were none free, the oldest would be dropped). Returns the slot, or
        -1 when the estimate is not finite."""
        return open_window(self.active, self.order, self._created, self.k, self.t0, self.x0, self.P0, self.x,
                           self.Phi, self.G, self.C, self.E, self.Z, float(t), np.asarray(x_est, float),
                           np.asarray(P_est, float))

    def advance(self, z_row, exclude, n_steps) -> int:
        """One step of every open window with the thrust in :attr:`fc` (and :attr:`fc_slots`); residuals of the
        finite, not excluded channels of ``z_row``. Returns the number of windows that reached ``n_steps``."""
        if not self.active.any():
            return 0
        self.lin_map()  # on the buffers: x (propagated in place) and fc_slots
        return advance_windows(self.active, self.k, self._At, self._Bt, self._xn, self.fc, z_row, exclude,
                               CHANNEL_STATE, ANGLE_CHANNELS, n_steps, self.x, self.Phi, self.G, self.C, self.F,
                               self.E, self.Z)

    def window(self, w) -> _Window:
        """Slot ``w`` as a :class:`_Window` (closes the slot)."""
        self.active[w] = False
        n = int(self.k[w])
        steps, chans = np.nonzero(np.isfinite(self.E[w, :n + 1]))
        rows = [(int(k), int(c), int(CHANNEL_STATE[c]), float(self.E[w, k, c]), float(self.Z[w, k, c]))
                for k, c in zip(steps, chans)]
        return _Window(float(self.t0[w]), self.x0[w], self.P0[w], self.Phi[w, :n + 1].copy(),
                       self.G[w, :n + 1].copy(), self.C[w, :n + 1].copy(), self.F[w, :n].copy(), rows)


class ThrusterFaultDetector:
    """Commanded thrust vs observed motion, per thruster (GLR over sliding windows; module docstring).

    Hypothesis of thruster ``i`` failing at step ``k0`` of a window: from then on it delivers a constant
    ``a`` (dead: ``a = 0``, stuck: ``a != 0``) instead of its commands. The onset is searched over the first
    window but a fault is declared only from a window whose best onset lies in its first half (so at least
    half a window of data fixes ``a``; a later window sees the onset early), Bonferroni threshold
    ``chi2.isf(p_false / (steps / 2), 1)``. H_i is not nested in H0 when the commands vary, so the test
    is conservative (a varying command that the thruster follows makes ``lambda_i`` negative). An
    estimated thrust outside the thruster's limits (by more than 3 standard errors + 1 N) is no thruster
    fault and is not reported. After a detection the thruster's estimated thrust replaces its command in
    the simulation (:meth:`correct`; :class:`EstimatorLoop` also gives it to the EKF), so a second fault
    can be isolated.

    Parameters
    ----------
    params : PlantParameters
        Design model (the EKF's).
    dt : float
        Step between calls, s (the EKF/controller period).
    sigmas : (13,) array_like
        Channel noise standard deviations.
    window_s, stride_s : float
        Window length and spacing, s (1.0 and 0.25; assumed: long enough to average 5 DVL pings, short
        enough to react within ~1 s).
    p_false : float
        False-alarm probability per window evaluation (1e-6, assumed: ~1 false alarm in 3 days at 4
        windows/s on a matched model).
    min_fault_N : float
        Smallest reported mean thrust error, N (2 N assumed: above thrust-curve and drag-model errors).
    dead_band_N : float
        A thruster delivering at most this is "dead", N (1 N assumed: a T200 barely turns below ~1 N).
    outlier_sigma : float
        Samples with a larger normalised residual under the best fit are left out (spikes); 6.
    max_cost : float
        The best explanation must fit: weighted cost per sample at most this (5, assumed; a correct
        single-thruster explanation leaves 1.3-2.3 on the bundled model, the excess being linearisation
        error; a vehicle spinning out of control or two simultaneous faults leave tens to hundreds, and no
        thruster is then named).
    compile : bool
        gcc-compile the Jacobian function (cached).
    """

    def __init__(self, params: PlantParameters, dt, sigmas, window_s=1.0, stride_s=0.25, p_false=1e-6,
                 min_fault_N=2.0, dead_band_N=1.0, outlier_sigma=6.0, max_cost=5.0, compile=True):
        self.params = params
        self.dt = float(dt)
        self.nu = params.T.shape[1]
        self.w = 1.0 / np.asarray(sigmas, float) ** 2
        self.window_steps = max(4, int(round(window_s / dt)))
        self.stride_steps = max(1, int(round(stride_s / dt)))
        self.p_false = float(p_false)
        self.n_onsets = self.window_steps // 2
        self.threshold = float(chi2.isf(self.p_false / self.n_onsets, 1))
        self.margin = float(chi2.isf(self.p_false, 1))
        self.min_fault_N, self.dead_band_N = float(min_fault_N), float(dead_band_N)
        self.outlier_sigma, self.max_cost = float(outlier_sigma), float(max_cost)
        lin = linearization_function(params, self.dt)
        self.lin = CompiledFunction(lin, params, self.dt, compile=compile)
        n_slots = -(-self.window_steps // self.stride_steps)  # open windows never exceed ceil(window / stride)
        self._bank = _WindowBank(CompiledFunction(lin.map(n_slots), params, self.dt, "map", n_slots, compile=compile),
                                 n_slots, self.window_steps, self.nu)
        self._k = 0
        self._no_exclusion = np.zeros(len(CHANNELS), bool)
        self.gain = np.ones(self.nu)  # thruster models: produced = gain * command + offset (gain 0 if faulty)
        self.offset = np.zeros(self.nu)
        self.reported = np.zeros(self.nu, bool)
        self.last_statistics = np.full(self.nu, np.nan)

    def correct(self, f_cmd) -> np.ndarray:
        """Thrust the thrusters produce for the command ``f_cmd`` (N), with the detected faults applied."""
        f = self.gain * np.asarray(f_cmd, float) + self.offset
        return np.minimum(np.maximum(f, self.params.f_min), self.params.f_max)  # np.clip, without its overhead

    def step(self, t, f_cmd, z_row, x_est, P_est, exclude=None) -> list:
        """One period: ``f_cmd`` (N) was commanded over the last ``dt``; ``z_row`` (13,) sampled at ``t`` (s);
        ``x_est``, ``P_est`` the estimate at ``t``; ``exclude`` (13,) bool channels to ignore.

        Returns the new :class:`FaultEvent` s.
        """
        events = []
        bank = self._bank
        if window_inputs(np.asarray(f_cmd, float), self.gain, self.offset, self.params.f_min, self.params.f_max,
                         bank.fc, bank.fc_slots):
            z_row = np.asarray(z_row, float)
            excl = self._no_exclusion if exclude is None else np.asarray(exclude, bool)
            if bank.advance(z_row, excl, self.window_steps):
                w = np.flatnonzero(bank.active)
                done = w[bank.k[w] >= self.window_steps]
                for slot in done[np.argsort(bank.order[done])]:
                    ev = self._evaluate(t, bank.window(slot))
                    if ev is not None:
                        events.append(ev)
                        bank.clear()  # restart with the faulty thruster's identified model
                        break
        else:  # a non-finite command: the windows cannot be simulated
            bank.clear()
        if self._k % self.stride_steps == 0:
            bank.open(t, x_est, P_est)  # not when the estimate is not finite
        self._k += 1
        return events

    # -- evaluation --------------------------------------------------------------------------------
    @staticmethod
    def _fit(Hs, es, prior):
        """Least squares on whitened rows ``Hs`` (m, p), targets ``es`` plus the prior rows on dx0.

        Returns (cost, parameters, covariance of the parameters)."""
        p = Hs.shape[1]
        A = np.vstack([Hs, np.column_stack([prior, np.zeros((12, p - 12))])])
        b = np.concatenate([es, np.zeros(12)])
        theta, *_ = np.linalg.lstsq(A, b, rcond=1e-12)
        r = b - A @ theta
        return float(r @ r), theta, np.linalg.pinv(A.T @ A, rcond=1e-12)

    def _glr(self, Phi, e, w, Pinv, G, C):
        """Costs of all candidate explanations at once (Schur complement on the nuisance ``dx0``).

        For target ``y_j = e + C_j`` and column ``G_j``: ``J_j = J(y_j) - (G_j' W r_j)^2 / (G_j' W s_j)`` with
        ``r_j``, ``s_j`` the residuals of ``y_j``, ``G_j`` after the prior-regularised fit of ``Phi dx0``.
        Returns ``lambda_j = J0(e) - J_j``, the thrust estimates ``a_j``, their variances and the ``dx0`` fits
        (12, n_candidates); ``self._j0`` keeps ``J0(e)``.
        """
        M = np.linalg.inv(Phi.T @ (Phi * w[:, None]) + Pinv)
        Y = e[:, None] + C
        PWY, PWG, PWe = Phi.T @ (w[:, None] * Y), Phi.T @ (w[:, None] * G), Phi.T @ (w * e)
        MY, MG = M @ PWY, M @ PWG
        jy = np.einsum("m,mj,mj->j", w, Y, Y) - np.einsum("kj,kj->j", PWY, MY)
        cross = np.einsum("m,mj,mj->j", w, G, Y) - np.einsum("kj,kj->j", PWG, MY)
        gg = np.einsum("m,mj,mj->j", w, G, G) - np.einsum("kj,kj->j", PWG, MG)
        gg = np.where(gg > 1e-12, gg, np.inf)
        a = cross / gg
        self._j0 = float(e @ (w * e) - PWe @ M @ PWe)
        lam = self._j0 - (jy - cross * a)
        return lam, a, 1.0 / gg, MY - MG * a

    def _refine(self, win, i, k0, a, keep, prior, iterations=2):
        """Gauss-Newton on ``a``: re-simulate the window with thruster ``i`` at ``a`` from step ``k0`` and refit
        (the first fit linearises along the commanded trajectory, where quadratic drag is smaller, which biases
        ``a`` towards the command)."""
        rows = [r for r, kept in zip(win.rows, keep) if kept]
        k = np.array([r[0] for r in rows])
        chans = np.array([r[1] for r in rows])
        st = np.array([r[2] for r in rows])
        z = np.array([r[4] for r in rows])
        sw = np.sqrt(self.w[chans])
        ang = ANGLE_CHANNELS[chans]
        for _ in range(iterations):
            x = win.x0.copy()
            X, Phi, Gi = [x], [np.eye(12)], [np.zeros(12)]
            for step, fk in enumerate(win.f):
                f = fk.copy()
                if step >= k0:
                    f[i] = a
                xn, A, B = self.lin(x, f)
                x = xn.copy()
                X.append(x)
                Phi.append(A @ Phi[-1])
                Gi.append(A @ Gi[-1] + (B[:, i] if step >= k0 else 0.0))
            X, Phi, Gi = np.array(X), np.array(Phi), np.array(Gi)
            e = z - X[k, st]
            e[ang] = wrap_angle(e[ang])
            _, theta, _ = self._fit(np.column_stack([Phi[k, st], Gi[k, st]]) * sw[:, None], e * sw, prior)
            if not np.isfinite(theta[12]):
                break
            a += float(theta[12])
        return a

    def _evaluate(self, t, win: _Window):
        if len(win.rows) < 13:
            return None
        k = np.array([r[0] for r in win.rows])
        chans = np.array([r[1] for r in win.rows])
        st = np.array([r[2] for r in win.rows])
        e = np.array([r[3] for r in win.rows])
        sw = np.sqrt(self.w[chans])
        Phi = np.asarray(win.Phi)  # (n+1, 12, 12)
        G, C = np.asarray(win.G), np.asarray(win.C)  # (n+1, 12, nu)
        F = np.asarray(win.f)  # (n, nu)
        Prow, Grow, Crow = Phi[k, st], G[k, st], C[k, st]  # (m, 12), (m, nu), (m, nu)
        P0 = 0.5 * (win.P0 + win.P0.T) + 1e-12 * np.eye(12)
        prior = np.linalg.cholesky(np.linalg.inv(P0)).T  # prior' prior = P0^-1
        n = win.steps
        no = n - 1  # onsets searched over the whole window, declared only in its first half
        Phi_inv = np.linalg.inv(Phi[:no])
        vG = Phi_inv @ G[:no]  # (no, 12, nu): the initial-state offset equivalent to G at the onset
        vC = Phi_inv @ C[:no]
        Pinv = prior.T @ prior
        after = (k[:, None] > np.arange(no)[None, :]).astype(float)  # (m, no): row after onset k0
        # candidate columns for every (thruster i, onset k0): sensitivity g and command contribution c (m, nu, no)
        # Prow @ v for every onset as one BLAS product: (m, 12) @ (12, no * nu) -> (m, nu, no)
        pv = (Prow @ np.concatenate([vG, vC], axis=2).transpose(1, 0, 2).reshape(12, -1)).reshape(len(k), no, 2, -1)
        Gc = (Grow[:, :, None] - pv[:, :, 0].transpose(0, 2, 1)) * after[:, None, :]
        Cc = (Crow[:, :, None] - pv[:, :, 1].transpose(0, 2, 1)) * after[:, None, :]
        keep = np.ones(len(e), bool)
        for _ in range(2):  # second pass without the outliers of the best explanation (spikes)
            lam, a_all, var_all, theta0 = self._glr(Prow[keep], e[keep], sw[keep] ** 2, Pinv,
                                                    Gc[keep].reshape(int(keep.sum()), -1),
                                                    Cc[keep].reshape(int(keep.sum()), -1))
            j = int(np.argmax(lam))
            i, k0 = divmod(j, no)
            r = (e + Cc[:, i, k0] - Prow @ theta0[:, j] - Gc[:, i, k0] * a_all[j]) * sw
            new_keep = keep & (np.abs(r) <= self.outlier_sigma)
            if np.array_equal(new_keep, keep) or new_keep.sum() < 13:
                break
            keep = new_keep
        lam_i = lam.reshape(self.nu, no)
        best_k0 = np.argmax(lam_i, axis=1)
        lam_best = lam_i[np.arange(self.nu), best_k0]
        self.last_statistics = lam_best.copy()
        order = np.argsort(lam_best)[::-1]
        i, second = int(order[0]), (lam_best[order[1]] if self.nu > 1 else -np.inf)
        k0 = int(best_k0[i])
        j = i * no + k0
        a, sd = float(a_all[j]), float(np.sqrt(max(var_all[j], 0.0)))
        j0 = float(self._j0)
        cmd = F[k0:, i]
        err = float(np.mean(np.abs(a - cmd)))
        slack = 3 * sd + 1.0
        plausible = self.params.f_min[i] - slack <= a <= self.params.f_max[i] + slack
        j_best = float(j0 - lam_best[i])
        m = int(keep.sum())
        if (self.reported[i] or lam_best[i] <= self.threshold or lam_best[i] - second <= self.margin
                or err < self.min_fault_N or not plausible or k0 > self.n_onsets or j_best > self.max_cost * m):
            return None
        a = self._refine(win, i, k0, a, keep, prior)
        kind = DEAD if abs(a) <= max(self.dead_band_N, 3 * sd) else STUCK
        self.gain[i], self.offset[i] = 0.0, (0.0 if kind == DEAD else a)
        self.reported[i] = True
        t_onset = win.t0 + k0 * self.dt
        return FaultEvent(t, kind, f"thruster {i}", i, a,
                          f"onset ~{t_onset:.2f} s; produces {a:.2f} +- {sd:.2f} N against a mean command of "
                          f"{np.mean(cmd):.2f} N; GLR {lam_best[i]:.3g} > {self.threshold:.3g}, next thruster "
                          f"{second:.3g}; cost/sample {j_best / m:.3g}",
                          t_onset=t_onset)


# ----------------------------------------------------------------------------- monitor and loop
@dataclass(frozen=True)
class FaultReport:
    """Everything detected over a run: ``events`` (time order) and the EKF's per-channel gating statistics."""

    events: tuple
    channels: tuple

    def of_kind(self, kind: str) -> list:
        """Events of one kind."""
        return [e for e in self.events if e.kind == kind]

    def first(self, kind: str, source: str):
        """First event of ``kind`` from ``source`` (channel name or ``"thruster <i>"``), or None."""
        return next((e for e in self.events if e.kind == kind and e.source == source), None)


class FaultMonitor:
    """Frozen-sensor and thruster-fault detection next to an EKF; frozen channels are taken out of the EKF
    (and put back when they come alive), EKF channel re-initialisations are collected as events.

    Parameters
    ----------
    ekf : UDrobotEKF
    frozen_window : int
        Samples of the frozen-sensor test.
    **thruster_options
        Passed to :class:`ThrusterFaultDetector` (``window_s``, ``min_fault_N``, ...).
    """

    def __init__(self, ekf: UDrobotEKF, frozen_window=10, compile=True, **thruster_options):
        self.ekf = ekf
        self.frozen = FrozenChannelDetector(ekf.sigmas, window=frozen_window)
        self.thrusters = ThrusterFaultDetector(ekf.params, ekf.dt, ekf.sigmas, compile=compile, **thruster_options)
        self.events: list[FaultEvent] = []
        self._seen_channel_faults = 0

    def step(self, t, z_row, f_applied) -> list:
        """After ``ekf.step(f_applied, z_row)``: run the detectors; returns the new events."""
        new = self.frozen.step(t, z_row)
        for ev in new:
            (self.ekf.exclude_channel if ev.kind == FROZEN else self.ekf.include_channel)(ev.source)
        for cf in self.ekf.channel_faults[self._seen_channel_faults:]:
            new.append(FaultEvent(cf.t, REJECTED, cf.channel, CHANNELS.index(cf.channel), cf.innovation,
                                  f"rejected at every sample since t = {cf.since:.2f} s ({cf.rejections} samples); "
                                  f"{cf.action}"))
        self._seen_channel_faults = len(self.ekf.channel_faults)
        new += self.thrusters.step(t, f_applied, z_row, self.ekf.x, self.ekf.P, exclude=self.frozen.frozen)
        self.events += new
        return new

    def report(self) -> FaultReport:
        return FaultReport(events=tuple(sorted(self.events, key=lambda e: e.t)), channels=self.ekf.channel_stats())


class EstimatorLoop:
    """Closed loop through the sensors and the EKF: ``loop(t, x_true) -> thrusts actually produced``.

    At every call: sample the sensors at the true state (``SensorSampler``), apply the sensor faults, step
    the EKF with the previous command (corrected for the thruster faults detected so far), run the fault
    monitor, ask ``controller(t, x_estimate)`` for the
    command and apply the thruster faults to it. Pass the loop as the controller of
    :func:`udrobot_ctrl.dynamics.sim.simulate` with ``control_dt = ekf.dt``; the recorded ``u`` of the
    simulation is then the thrust produced, ``commands`` the thrust commanded.

    Parameters
    ----------
    controller : callable
        ``controller(t, x) -> (n,)`` thrusts, N.
    ekf : UDrobotEKF
    sensors : SensorConfig, optional
        Sensor noise of the simulated sensors (default the EKF's).
    sensor_faults, thruster_faults : sequence
        Injected faults (:class:`SensorSpike`, :class:`FrozenSensor`; :class:`DeadThruster`,
        :class:`StuckThruster`).
    seed : int
        Sensor-noise seed.
    monitor : bool
        Run a :class:`FaultMonitor`.
    reconfigure : bool
        On a dead or stuck thruster, tell the controller (``controller.set_thruster_limits(i, a, a)``, e.g.
        :meth:`udrobot_ctrl.control.mpc.LinearMPC.set_thruster_limits`) so that its model matches the vehicle.
    """

    def __init__(self, controller, ekf: UDrobotEKF, sensors: SensorConfig | None = None, sensor_faults=(),
                 thruster_faults=(), seed=0, monitor=True, reconfigure=True, **monitor_options):
        self.controller, self.ekf = controller, ekf
        self.sampler = SensorSampler(sensors or ekf.sensors, seed=seed)
        self.sensor_faults, self.thruster_faults = list(sensor_faults), list(thruster_faults)
        self.monitor = FaultMonitor(ekf, **monitor_options) if monitor else None
        self.reconfigure = reconfigure
        self._f = None
        self.t, self.estimates, self.commands, self.measurements = [], [], [], []

    def __call__(self, t, x):
        t = float(t)
        z = self.sampler(t, x)
        for fault in self.sensor_faults:
            z = fault.apply(t, z)
        if self._f is None:
            self.ekf.reset(self.ekf.x0)
            self.ekf.t = t
            self.ekf.update(z)
        else:
            f_model = self._f if self.monitor is None else self.monitor.thrusters.correct(self._f)
            self.ekf.step(f_model, z, t=t)
            if self.monitor is not None:
                for ev in self.monitor.step(t, z, self._f):
                    if ev.kind in (DEAD, STUCK):
                        self.ekf.reopen_gates()  # the rejections came from the model without the fault
                    if self.reconfigure and ev.kind in (DEAD, STUCK) and hasattr(self.controller,
                                                                                "set_thruster_limits"):
                        a = 0.0 if ev.kind == DEAD else ev.value
                        self.controller.set_thruster_limits(ev.index, a, a)
        f_cmd = np.asarray(self.controller(t, self.ekf.x.copy()), float)
        self._f = f_cmd.copy()
        f = f_cmd.copy()
        for fault in self.thruster_faults:
            f = fault.apply(t, f)
        self.t.append(t)
        self.estimates.append(self.ekf.x.copy())
        self.commands.append(f_cmd)
        self.measurements.append(z)
        return f

    def report(self) -> FaultReport:
        """Faults detected so far (empty without a monitor)."""
        if self.monitor is None:
            return FaultReport(events=(), channels=self.ekf.channel_stats())
        return self.monitor.report()
