"""A short depth-and-heading mission (at a cruise speed) with batch-capable LQR, PID and linear MPC.

This is the sensitivity package's *fast path*: the controller is a constant gain, so one chunk of
perturbed vehicles is simulated at once (:mod:`udrobot_ctrl.sensitivity.batch`). Metrics are
computed for all vehicles of the batch with the same definitions as :mod:`udrobot_ctrl.control.metrics` where
that module exists (IAE, overshoot, settling time, thrust energy, saturation) plus the maximum speed.

LQR design: the plant (casadi twin) is linearised at the cruise point (surge speed ``surge_mps``, level,
at rest otherwise) with the trim thrust that balances the design model's drag and net buoyancy there
(feed-forward); the design uses the states z, phi, psi, u, w, p, r for any thruster layout (sway and pitch
are left to damping and restoring: passive on UDrobot, coupled to surge on the BlueROV2, actuated but not
tracked by this mission on the BlueROV2 Heavy). Control law
``f = f_trim - K (x_r - x_ref_r)`` with the heading error wrapped to [-pi, pi], clipped by the thrusters.
There is no integral action, so a plant whose surge drag differs from the design model's settles at a
different speed: that is how a wrong C_D / K_Q shows in closed loop. At hover (``surge_mps = 0``)
the quadratic damping has zero slope and the design sees only K_L and the added mass.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.dynamics.plant import plant_parameters

CONTROLLED = (2, 3, 5, 6, 8, 9, 11)  # z phi psi u w p r: the tracked channels and the DOFs every layout acts on
STATE_LABELS = ("x", "y", "z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")


def design_states(T) -> tuple:
    """State indices of the design: :data:`CONTROLLED` (heading third), then pitch (theta, q) when a thruster
    makes a pitch moment and sway (v) when one makes a sway force (BlueROV2, Heavy: a controller that ignored
    them would tip the vehicle with its vertical-thrust combinations). UDrobot: exactly :data:`CONTROLLED`."""
    T = np.asarray(T, float)
    scale = max(1.0, float(np.abs(T).max()))
    extra = ((4, 10) if np.any(np.abs(T[4]) > 1e-9 * scale) else ()) + ((7,) if np.any(np.abs(T[1]) > 1e-9 * scale)
                                                                         else ())
    return CONTROLLED + extra


@dataclass(frozen=True)
class DepthHeadingMission:
    """Steps to ``depth_m`` (m, NED z positive down) and ``heading_rad`` while cruising at ``surge_mps``.

    Attributes
    ----------
    depth_m, heading_rad, surge_mps : float
        References (m, rad, m/s); the vehicle starts at the surface origin at the cruise speed.
    t_final, dt : float
        Duration and integration / control step (s). dt 0.02-0.05 keeps sweeps cheap; RK4 is stable
        for the LQR closed loop up to ~0.1 s (fastest pole ~ -20 rad/s).
    settle_band : float
        Settling band as a fraction of the step (2 %).
    """

    depth_m: float = 1.0
    heading_rad: float = np.pi / 2
    surge_mps: float = 0.5
    t_final: float = 20.0
    dt: float = 0.04
    settle_band: float = 0.02

    def x0(self) -> np.ndarray:
        """Initial state: at the surface origin, level, cruising at ``surge_mps``."""
        x = np.zeros(12)
        x[6] = self.surge_mps
        return x

    def operating_point(self) -> np.ndarray:
        """Linearisation point: level, heading 0, surge speed ``surge_mps``."""
        return self.x0()

    def reference(self) -> np.ndarray:
        ref = np.zeros(12)
        ref[2], ref[5], ref[6] = self.depth_m, self.heading_rad, self.surge_mps
        return ref


@dataclass(frozen=True)
class LQRWeights:
    """Bryson weights: maximum acceptable deviation per controlled state and thrust (assumed values)."""

    z: float = 0.1
    phi: float = 0.1
    psi: float = 0.1
    u: float = 0.2
    w: float = 0.2
    p: float = 0.5
    r: float = 0.5
    thrust_N: float = 10.0
    theta: float = 0.2  # rad, only for layouts that act on pitch (design_states)
    v: float = 0.3  # m/s, only for layouts that act on sway
    q: float = 0.5  # rad/s, only for layouts that act on pitch

    def q_matrix(self, states) -> np.ndarray:
        """Bryson state weight diag(1 / dx_max^2) for the design ``states`` (indices into the 12-state)."""
        return np.diag(1.0 / np.array([getattr(self, STATE_LABELS[i]) for i in states], float) ** 2)


def trim_thrust(p, x_op) -> np.ndarray:
    """Thrusts (N) whose wrench balances damping, Coriolis and restoring forces at ``x_op`` (least squares)."""
    from udrobot_ctrl.dynamics.plant import generalized_forces

    return np.linalg.lstsq(p.T, generalized_forces(np.asarray(x_op, float), p), rcond=None)[0]


def linearise(p, x_op):
    """(A, B, f_trim): continuous linearisation of the thrust-input plant at ``x_op`` (casadi, exact)."""
    import casadi as ca

    from udrobot_ctrl.dynamics.plant_casadi import dynamics_function

    f = dynamics_function(p, "thrust")
    x = ca.SX.sym("x", 12)
    u = ca.SX.sym("u", p.T.shape[1])
    jac = ca.Function("op_jacobians", [x, u], [ca.jacobian(f(x, u), x), ca.jacobian(f(x, u), u)])
    trim = trim_thrust(p, x_op)
    A, B = jac(np.asarray(x_op, float), trim)
    return np.array(A), np.array(B), trim


def lqr_gain(vehicle, weights: LQRWeights = LQRWeights(), mission: DepthHeadingMission | None = None):
    """LQR gain K (n_thr x k) on :func:`design_states` and the trim thrust at the mission's cruise point."""
    import control

    p = plant_parameters(vehicle)
    x_op = (mission or DepthHeadingMission()).operating_point()
    A, B, trim = linearise(p, x_op)
    idx = list(design_states(p.T))
    Ar, Br = A[np.ix_(idx, idx)], B[idx]
    w = weights
    Q = w.q_matrix(idx)
    R = np.eye(Br.shape[1]) / w.thrust_N**2
    K, _, _ = control.lqr(Ar, Br, Q, R)
    return np.asarray(K), trim


class BatchLQR:
    """``controller(t, x (N, 12)) -> thrusts (N, n)``; ``K`` (n, k) shared or (N, n, k) per vehicle on the
    design ``states`` (k indices, :func:`design_states`), ``trim`` (n,) shared or (N, n) per vehicle."""

    def __init__(self, K, trim, mission: DepthHeadingMission, states=CONTROLLED):
        self.K, self.trim = np.asarray(K, float), np.asarray(trim, float)
        self.idx = list(states)
        if self.K.shape[-1] != len(self.idx):
            raise ValueError(f"gain has {self.K.shape[-1]} columns for {len(self.idx)} design states")
        self.ref = mission.reference()[self.idx]

    def __call__(self, t, x):
        x = np.atleast_2d(x)
        e = x[:, self.idx] - self.ref
        e[:, 2] = (e[:, 2] + np.pi) % (2 * np.pi) - np.pi  # heading error wrapped
        if self.K.ndim == 3:
            return self.trim - np.einsum("nij,nj->ni", self.K, e)
        return self.trim - e @ self.K.T


def _settling_time(t, err, band):
    """Last time |err| leaves the band, interpolated between samples (continuous in the parameters).

    Returns (time, settled): an unsettled response returns t[-1] and False (censored).
    """
    out = np.zeros(err.shape[1])
    settled = np.ones(err.shape[1], bool)
    a = np.abs(err) - band  # > 0 outside the band
    for j in range(err.shape[1]):
        col = a[:, j]
        if not np.all(np.isfinite(col)):
            out[j], settled[j] = np.nan, False
            continue
        outside = np.nonzero(col > 0)[0]
        if outside.size == 0:
            out[j] = t[0]
        elif outside[-1] == len(t) - 1:
            out[j], settled[j] = t[-1], False
        else:
            k = outside[-1]
            frac = col[k] / (col[k] - col[k + 1])
            out[j] = t[k] + frac * (t[k + 1] - t[k])
    return out, settled


LOST_PITCH_DEG = 45.0  # assumed threshold: beyond it the mission is considered failed
T200_DISK_AREA = np.pi * 0.038**2  # m^2; assumed: 76 mm T200 propeller diameter (Blue Robotics datasheet)


def mission_metrics(res, mission: DepthHeadingMission, f_min, f_max, rho: float = 1000.0) -> dict:
    """Closed-loop metrics of a batch simulation (every entry is an (N,) array).

    * ``iae_depth`` (m s), ``iae_heading`` (rad s): integral of |error| (rectangle rule on the RK4 grid);
    * ``overshoot_depth``, ``overshoot_heading`` (%): peak beyond the reference, % of the step;
    * ``settling_depth``, ``settling_heading`` (s): last exit from the +-2 % band, interpolated between
      steps (``t_final`` when not settled; ``unsettled`` counts such responses, 0-2 per vehicle);
    * ``iae_speed`` (m): integral of |u - surge_mps|; ``speed_error`` (m/s): final u - surge_mps;
    * ``energy`` (J): *estimated* electrical energy of the applied thrusts with the T-200 power fit of
      :func:`udrobot_ctrl.control.metrics.thrust_power` (same definition as the missions' ``energy_J``); when that
      module is absent, the ideal actuator-disk energy sum_i |f_i|^1.5 / sqrt(2 rho A_disk) (a lower bound);
    * ``thrust_effort`` (N^2 s): integral of sum_i f_i^2;
    * ``saturation`` (-): fraction of control steps with a thruster saturated;
    * ``max_speed`` (m/s): maximum body-frame translational speed;
    * ``max_pitch`` (deg): maximum |theta| (pitch is passive: the Munk moment can destabilise it);
    * ``lost_control`` (0/1): 1 when |theta| exceeded ``LOST_PITCH_DEG`` or the state diverged, a
      failure indicator whose Sobol indices say which coefficients drive the failure.
    """
    t = res.t
    x = res.x
    dt = np.diff(t)[:, None]
    e_z = x[:, :, 2] - mission.depth_m
    e_psi = (x[:, :, 5] - mission.heading_rad + np.pi) % (2 * np.pi) - np.pi
    iae_z = np.sum(np.abs(e_z[1:]) * dt, axis=0)
    iae_psi = np.sum(np.abs(e_psi[1:]) * dt, axis=0)
    e_u = x[:, :, 6] - mission.surge_mps
    over_z = np.max(e_z * np.sign(mission.depth_m), axis=0) / abs(mission.depth_m) * 100.0
    over_psi = np.max(e_psi * np.sign(mission.heading_rad), axis=0) / abs(mission.heading_rad) * 100.0
    ts_z, ok_z = _settling_time(t, e_z, mission.settle_band * abs(mission.depth_m))
    ts_psi, ok_psi = _settling_time(t, e_psi, mission.settle_band * abs(mission.heading_rad))
    f = np.clip(res.u, f_min, f_max)
    try:
        from udrobot_ctrl.control.metrics import thrust_power

        power = np.sum(thrust_power(f), axis=-1)
    except ImportError:
        power = np.sum(np.abs(f) ** 1.5, axis=-1) / np.sqrt(2 * rho * T200_DISK_AREA)
    speed = np.linalg.norm(x[:, :, 6:9], axis=-1)
    max_pitch = np.degrees(np.max(np.abs(x[:, :, 4]), axis=0))
    diverged = ~np.all(np.isfinite(x[-1]), axis=-1)
    return {
        "iae_depth": iae_z, "iae_heading": iae_psi, "iae_speed": np.sum(np.abs(e_u[1:]) * dt, axis=0),
        "speed_error": e_u[-1],
        "overshoot_depth": np.maximum(over_z, 0.0), "overshoot_heading": np.maximum(over_psi, 0.0),
        "settling_depth": ts_z, "settling_heading": ts_psi,
        "energy": np.sum(power * dt, axis=0),
        "thrust_effort": np.sum(np.sum(f**2, axis=-1) * dt, axis=0),
        "saturation": np.mean(res.saturated, axis=0),
        "max_speed": np.max(speed, axis=0),
        "max_pitch": max_pitch,
        "lost_control": ((max_pitch > LOST_PITCH_DEG) | diverged).astype(float),
        "unsettled": (~ok_z).astype(float) + (~ok_psi).astype(float),
    }


# ----------------------------------------------------------------------------- batched PID (fast path)
@dataclass(frozen=True)
class PIDTuning:
    """Closed-loop natural frequencies (rad/s) of the PID loops, critically damped (assumed values).

    Gains follow from the design model's inertia m (rigid + added) and linear damping d on each axis:
    ``Kp = m wn^2``, ``Kd = 2 m wn - d``, ``Ki = Kp wn / ki_ratio``; the surge loop is a PI with
    ``Kp = 2 m wn - d``, ``Ki = m wn^2``.
    """

    depth: float = 1.5
    heading: float = 5.0
    roll: float = 3.0
    surge: float = 1.0
    ki_ratio: float = 8.0
    integral_limit_N: float = 20.0


def pid_gains(vehicle, tuning: PIDTuning = PIDTuning()) -> dict:
    """PID gains per loop (depth on Z, heading on N, roll on K, surge on X) from the design model."""
    p = plant_parameters(vehicle)
    m = np.diag(p.M)
    d = np.diag(p.D_L)
    out = {}
    for name, dof, wn in (("depth", 2, tuning.depth), ("heading", 5, tuning.heading), ("roll", 3, tuning.roll)):
        kp = m[dof] * wn**2
        out[name] = (kp, max(2 * m[dof] * wn - d[dof], 0.0), kp * wn / tuning.ki_ratio)
    out["surge"] = (max(2 * m[0] * tuning.surge - d[0], 0.0), 0.0, m[0] * tuning.surge**2)
    return out


class BatchPID:
    """Decoupled PID loops + exact thrust allocation, vectorised over vehicles (stateful integrators).

    ``gains`` values are (kp, kd, ki) scalars or (N,) arrays (per-vehicle redesign); ``trim`` (n,) or
    (N, n) is the feed-forward thrust of the design model at the cruise point, as for the LQR.
    """

    LOOPS = ("surge", "depth", "roll", "heading")  # wrench rows X, Z, K, N
    ROWS = (0, 2, 3, 5)
    INTEGRATE_BAND = np.array([np.inf, 0.25, np.inf, 0.35])  # m/s, m, rad, rad (assumed)

    def __init__(self, gains: dict, trim, T, mission: DepthHeadingMission, integral_limit_N: float = 20.0):
        self.g = {k: tuple(np.asarray(v, float) for v in gains[k]) for k in self.LOOPS}
        self.trim = np.asarray(trim, float)
        self.alloc = np.linalg.inv(np.asarray(T, float)[list(self.ROWS)])  # (n, 4) for UDrobot's 4 thrusters
        self.mission = mission
        self.limit = integral_limit_N
        self.integ = None
        self.t_last = None

    def __call__(self, t, x):
        x = np.atleast_2d(x)
        m = self.mission
        err = np.stack([
            x[:, 6] - m.surge_mps,
            x[:, 2] - m.depth_m,
            x[:, 3],
            (x[:, 5] - m.heading_rad + np.pi) % (2 * np.pi) - np.pi,
        ], axis=-1)
        rate = np.stack([np.zeros(len(x)), x[:, 8], x[:, 9], x[:, 11]], axis=-1)  # derivative on measurement
        if self.integ is None or self.integ.shape != err.shape:
            self.integ = np.zeros_like(err)
        dt = 0.0 if self.t_last is None else t - self.t_last
        self.t_last = t
        kp = np.stack([self.g[k][0] * np.ones(len(x)) for k in self.LOOPS], -1)
        kd = np.stack([self.g[k][1] * np.ones(len(x)) for k in self.LOOPS], -1)
        ki = np.stack([self.g[k][2] * np.ones(len(x)) for k in self.LOOPS], -1)
        near = np.abs(err) < self.INTEGRATE_BAND  # conditional integration: no wind-up during large steps
        self.integ = self.integ + np.where(near, err, 0.0) * dt
        with np.errstate(divide="ignore", invalid="ignore"):
            cap = np.where(ki > 0, self.limit / ki, 0.0)
        self.integ = np.clip(self.integ, -cap, cap)  # anti-windup: integral force <= limit
        wrench = -(kp * err + kd * rate + ki * self.integ)
        return self.trim + wrench @ self.alloc.T


# ----------------------------------------------------------------------------- batched linear MPC (fast path)
@dataclass(frozen=True)
class MPCSettings:
    """Linear MPC on the LQR's reduced model: sample time ``Ts`` (s), horizon ``horizon`` steps, the
    LQR weights (:class:`LQRWeights`) as stage cost and the discrete Riccati solution as terminal cost;
    thrust limits are hard constraints. Each solve starts from the unconstrained optimum clipped to the
    limits (exact when no limit is active) and runs ``iterations`` of FISTA (accelerated projected
    gradient) to resolve active limits; the QP is ill-conditioned (cond(H) ~ 3e4), so with active limits
    the plan is near-optimal rather than exact (assumed values)."""

    Ts: float = 0.1
    horizon: int = 20
    iterations: int = 60


def mpc_matrices(vehicle, mission: DepthHeadingMission, settings: MPCSettings = MPCSettings(),
                 weights: LQRWeights = LQRWeights()) -> dict:
    """Condensed QP of the linear MPC: ``J = dU' H dU + 2 e0' F dU`` (dU = thrust - trim, e0 = state error)."""
    import scipy.linalg as sla

    p = plant_parameters(vehicle)
    A, B, trim = linearise(p, mission.operating_point())
    idx = list(design_states(p.T))
    Ar, Br = A[np.ix_(idx, idx)], B[idx]
    n, m = Br.shape
    M = sla.expm(np.block([[Ar, Br], [np.zeros((m, n + m))]]) * settings.Ts)
    Ad, Bd = M[:n, :n], M[:n, n:]
    w = weights
    Q = w.q_matrix(idx) * settings.Ts
    R = np.eye(m) / w.thrust_N**2 * settings.Ts
    P = sla.solve_discrete_are(Ad, Bd, Q, R)
    N = settings.horizon
    Phi = np.zeros((N * n, n))
    Gam = np.zeros((N * n, N * m))
    Ak = np.eye(n)
    for k in range(N):
        Ak = Ad @ Ak
        Phi[k * n:(k + 1) * n] = Ak
        for j in range(k + 1):
            Gam[k * n:(k + 1) * n, j * m:(j + 1) * m] = np.linalg.matrix_power(Ad, k - j) @ Bd
    Qbar = np.kron(np.eye(N), Q)
    Qbar[-n:, -n:] = P
    H = Gam.T @ Qbar @ Gam + np.kron(np.eye(N), R)
    F = Phi.T @ Qbar @ Gam
    return {"H": H, "F": F, "L": float(np.linalg.eigvalsh(H).max()), "trim": trim, "m": m, "states": tuple(idx)}


class BatchMPC:
    """Box-constrained linear MPC solved for N vehicles at once (FISTA on the condensed QP).

    ``qp`` from :func:`mpc_matrices` (shared), or a list of them (per-vehicle redesign). Called every
    ``Ts`` seconds (use it with ``control_dt = Ts``); never raises: a non-finite plan falls back to the trim.
    """

    def __init__(self, qp, mission: DepthHeadingMission, f_min, f_max, settings: MPCSettings = MPCSettings()):
        qps = qp if isinstance(qp, (list, tuple)) else [qp]
        self.shared = len(qps) == 1
        self.H = np.stack([q["H"] for q in qps])
        self.F = np.stack([q["F"] for q in qps])
        self.step = 1.0 / np.array([q["L"] for q in qps])
        self.Hinv = np.linalg.inv(self.H)
        self.trim = np.stack([q["trim"] for q in qps])
        self.m = qps[0]["m"]
        self.N = settings.horizon
        self.iters = settings.iterations
        self.idx = list(qps[0].get("states", CONTROLLED))
        self.ref = mission.reference()[self.idx]
        self.f_min, self.f_max = np.asarray(f_min, float), np.asarray(f_max, float)
        self.U = None

    def __call__(self, t, x):
        x = np.atleast_2d(x)
        nv = len(x)
        e = x[:, self.idx] - self.ref
        e[:, 2] = (e[:, 2] + np.pi) % (2 * np.pi) - np.pi
        trim = np.broadcast_to(self.trim if not self.shared else self.trim[0], (nv, self.m))
        lo = np.tile(self.f_min, self.N) - np.tile(trim, self.N)
        hi = np.tile(self.f_max, self.N) - np.tile(trim, self.N)
        if self.shared:
            g = e @ self.F[0]
            hv = lambda u: u @ self.H[0]  # noqa: E731 - H symmetric
            step = self.step[0]
        else:
            g = np.einsum("ni,nij->nj", e, self.F)
            hv = lambda u: np.einsum("ni,nij->nj", u, self.H)  # noqa: E731
            step = self.step[:, None]
        # start from the unconstrained optimum clipped to the box: exact whenever no limit is active,
        # and FISTA then only has to resolve the active thrust limits
        U = np.clip(-(g @ self.Hinv[0] if self.shared else np.einsum("ni,nij->nj", g, self.Hinv)), lo, hi)
        Y, tk = U.copy(), 1.0
        for _ in range(self.iters):
            U_new = np.clip(Y - step * (hv(Y) + g), lo, hi)
            tk_new = 0.5 * (1 + np.sqrt(1 + 4 * tk * tk))
            Y = U_new + (tk - 1) / tk_new * (U_new - U)
            U, tk = U_new, tk_new
        bad = ~np.all(np.isfinite(U), axis=1)
        U[bad] = 0.0  # safe fallback: hold the trim thrust
        return trim + U[:, :self.m]
