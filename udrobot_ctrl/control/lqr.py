"""LQR for UDrobot: Bryson's-rule weights, design on the reduced state, gain scheduling on surge speed.

Design (:func:`design_lqr`): the plant is linearised at an operating point
(:func:`udrobot_ctrl.control.linearize.linearize`), reduced to the design state
``[z, phi, theta, psi, u, v, w, p, q, r]`` (position x, y dropped: not tracked, pure integrators) and
checked with :func:`udrobot_ctrl.control.linearize.structure_report` (every mode controllable in the rank sense;
sway and pitch only weakly, through inertial coupling). The gain comes from ``control.lqr`` (continuous)
or, when a sampling period is given, ``control.dlqr(..., method='scipy')`` on the zero-order-hold
discretisation. Bryson's rule (:class:`BrysonWeights`): ``Q = diag(1 / dx_max^2)``,
``R = diag(1 / f_max^2)`` with ``dx_max`` the largest acceptable deviation per state (assumed values,
below) and ``f_max`` each thruster's smaller (reverse) limit. Weakly controllable passive states (v,
theta, q) carry small weights: they are kept in the design so that the Riccati equation sees them (the
Morison models' hover linearisation has them on the imaginary axis), but the controller does not lean on
the weak coupling (which made the gains model-sensitive: see :func:`_default_deviation`).

Control law (:class:`ScheduledLQR`)::

    f = f_trim(u_ref) - K(u) [x_r - x_ref_r],   heading error wrapped to [-pi, pi),

clipped to each thruster's forward / reverse limit; ``K(u)`` interpolated linearly in the measured surge
speed u between the operating points (hover, 0.25, 0.5 m/s, the maximum speed), ``f_trim`` the exact trim
at the reference speed. No integral action: a plant whose drag differs from the design model's settles
at a slightly different speed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from udrobot_ctrl.control.linearize import (
    REDUCED_INDEX,
    REDUCED_STATES,
    LinearModel,
    linearize,
    operating_points,
    structure_report,
    trim_at,
)
from udrobot_ctrl.dynamics.plant import PlantParameters, wrap_angle

PSI_R = REDUCED_STATES.index("psi")


def _default_deviation():
    # assumed: depth 0.1 m, heading/roll 0.1 rad, surge 0.1 m/s, heave 0.3 m/s, roll/yaw rates 0.5 rad/s.
    # Passive pitch/sway (theta, q, v) get 3 rad, 3 rad/s, 3 m/s: "leave them to damping and BG". Measured on the
    # quick mission: with 0.3 rad / 0.5 rad/s / 0.5 m/s the gains lean on the weak inertial coupling and an LQR
    # designed on cfd:chin flown on free_decay:morison loses pitch (90 deg); with 3 it stays within 12 deg.
    return {"z": 0.1, "phi": 0.1, "theta": 3.0, "psi": 0.1, "u": 0.1, "v": 3.0, "w": 0.3, "p": 0.5, "q": 3.0,
            "r": 0.5}


@dataclass(frozen=True)
class BrysonWeights:
    """Bryson's rule: largest acceptable deviation per design state and thrust per thruster.

    Attributes
    ----------
    max_deviation : dict
        State name -> deviation (m, rad, m/s, rad/s); missing states use the defaults (assumed values).
    max_thrust : float or None
        Acceptable thrust per thruster, N; None = each thruster's smaller limit (28.6 N reverse for T-200 at 12 V).
    """

    max_deviation: dict = field(default_factory=_default_deviation)
    max_thrust: float | None = None

    def matrices(self, p: PlantParameters):
        """(Q, R) for the reduced state and the thrusters."""
        dev = _default_deviation()
        for k, v in self.max_deviation.items():
            if k not in dev:
                raise ValueError(f"max_deviation key {k!r} is not a design state ({', '.join(REDUCED_STATES)})")
            if not v > 0:
                raise ValueError(f"max_deviation[{k!r}] must be > 0, got {v}")
            dev[k] = float(v)
        Q = np.diag([1.0 / dev[s] ** 2 for s in REDUCED_STATES])
        fmax = (np.minimum(p.f_max, -p.f_min) if self.max_thrust is None
                else np.full(p.T.shape[1], float(self.max_thrust)))
        return Q, np.diag(1.0 / fmax**2)


@dataclass
class LQRDesign:
    """One LQR design at an operating point: gain K (n x 10) on the reduced state, closed-loop poles.

    Attributes
    ----------
    lin : LinearModel
        The linearisation designed on.
    K : (n, 10) ndarray
        State-feedback gain from the reduced state deviation (SI units) to the thrust deviations, N.
    closed_loop_poles : ndarray
        Eigenvalues of the closed loop: in 1/s for a continuous design, in the z-plane (dimensionless) for a
        discrete one (``dt`` set).
    report : StructureReport
        Controllability of the reduced (A, B).
    dt : float, optional
        Sampling period of a discrete design, s; None for a continuous one.
    """

    lin: LinearModel
    K: np.ndarray
    closed_loop_poles: np.ndarray
    report: object  # StructureReport of the reduced (A, B)
    dt: float | None = None


def design_lqr(p: PlantParameters, point, weights: BrysonWeights | None = None, Q=None, R=None,
               dt: float | None = None) -> LQRDesign:
    """LQR gain at ``point`` on the reduced state.

    Parameters
    ----------
    p : PlantParameters
        The design model.
    point : OperatingPoint
        The trim to linearise about.
    weights : BrysonWeights, optional
        Bryson's-rule weights (default values when None); ``Q`` (10x10) / ``R`` (n x n) override them.
    Q : (10, 10) array_like, optional
        State weight on the reduced state (overrides ``weights``).
    R : (n, n) array_like, optional
        Thrust weight, 1/N^2 (overrides ``weights``).
    dt : float, optional
        Sampling period, s: discrete design with ``control.dlqr(method='scipy')`` on the ZOH model.

    Returns
    -------
    LQRDesign
        The gain, the closed-loop poles and the linearisation.

    Raises
    ------
    ValueError
        If the reduced model is not stabilizable (an uncontrollable mode with Re >= 0).
    """
    import control

    lin = linearize(p, point)
    Ar, Br = lin.reduced()
    rep = structure_report(Ar, Br, states=REDUCED_STATES)
    if not rep.stabilizable and rep.uncontrollable_eigenvalues.size:
        raise ValueError(f"model {p.name!r} at {point.name}: not stabilizable\n{rep.summary()}")
    Qb, Rb = (weights or BrysonWeights()).matrices(p)
    Q = Qb if Q is None else np.asarray(Q, float)
    R = Rb if R is None else np.asarray(R, float)
    if dt is None:
        K, _, poles = control.lqr(Ar, Br, Q, R)
    else:
        sysd = control.c2d(control.ss(Ar, Br, np.eye(len(Ar)), 0), dt, method="zoh")
        K, _, poles = control.dlqr(sysd.A, sysd.B, Q, R, method="scipy")
    return LQRDesign(lin, np.asarray(K), np.asarray(poles), rep, dt)



class ScheduledLQR:
    """Gain-scheduled LQR tracking depth, heading and surge speed: ``controller(t, x) -> thrusts`` (N).

    Parameters
    ----------
    params : PlantParameters
        The design model.
    designs : list of LQRDesign
        One per operating point, sorted by surge speed.
    reference : callable
        ``reference(t) -> {"z": m, "psi": rad, "u": m/s}``.
    """

    def __init__(self, params: PlantParameters, designs, reference):
        self.params = params
        self.designs = sorted(designs, key=lambda d: d.lin.point.surge)
        self.speeds = np.array([d.lin.point.surge for d in self.designs])
        self.gains = np.stack([d.K for d in self.designs])
        self.reference = reference
        self._trims: dict = {}
        self.f_min, self.f_max = np.asarray(params.f_min, float), np.asarray(params.f_max, float)
        self.depth = float(self.designs[0].lin.point.x0[2])

    @classmethod
    def design(cls, params: PlantParameters, reference, weights: BrysonWeights | None = None, depth: float = 1.0,
               dt: float | None = None, Q=None, R=None) -> ScheduledLQR:
        """Design at every operating point of :func:`udrobot_ctrl.control.linearize.operating_points`."""
        pts = operating_points(params, depth)
        return cls(params, [design_lqr(params, pt, weights, Q, R, dt) for pt in pts], reference)

    def gain(self, surge: float) -> np.ndarray:
        """K (n x 10) interpolated linearly in surge speed (m/s), held at the ends."""
        s = float(np.clip(surge, self.speeds[0], self.speeds[-1]))
        k = int(np.clip(np.searchsorted(self.speeds, s) - 1, 0, len(self.speeds) - 2)) if len(self.speeds) > 1 else 0
        if len(self.speeds) == 1:
            return self.gains[0]
        a = (s - self.speeds[k]) / (self.speeds[k + 1] - self.speeds[k])
        return (1 - a) * self.gains[k] + a * self.gains[k + 1]

    def trim(self, surge: float) -> np.ndarray:
        """Trim thrusts (N) at the reference surge speed (exact least squares, cached)."""
        key = round(float(surge), 6)
        f = self._trims.get(key)
        if f is None:
            f = self._trims[key] = trim_at(self.params, key, self.depth).u0
        return f

    def __call__(self, t, x):
        x = np.asarray(x, float)
        ref = self.reference(t)
        xr = np.zeros(12)
        xr[2], xr[5], xr[6] = ref["z"], ref["psi"], ref["u"]
        e = (x - xr)[list(REDUCED_INDEX)]
        e[PSI_R] = wrap_angle(e[PSI_R])
        u = x[6] if np.isfinite(x[6]) else ref["u"]
        f = self.trim(ref["u"]) - self.gain(u) @ e
        if not np.all(np.isfinite(f)):
            f = self.trim(ref["u"])  # safe fallback on a non-finite state
        return np.clip(f, self.f_min, self.f_max)


class BatchScheduledLQR:
    """N :class:`ScheduledLQR` controllers flown at once: ``controller(t, x (N, 12)) -> thrusts (N, n)``.

    The law of each vehicle is exactly its controller's (gain interpolated in its own measured surge
    speed between its own operating points, trim of its own design model at the reference speed, the
    trim as fallback on a non-finite state, clipped), evaluated for all vehicles with array operations.
    Vehicles whose controllers have fewer operating points are padded with copies of their last gain
    at speeds above their range, which the clipping of the surge speed never reaches.

    Parameters
    ----------
    controllers : sequence of ScheduledLQR
        One per vehicle (the same object may repeat: a design shared by several plants); they must
        share the reference callable and the thruster limits.
    """

    def __init__(self, controllers):
        ctrls = list(controllers)
        if not ctrls:
            raise ValueError("BatchScheduledLQR needs at least one controller")
        first = ctrls[0]
        for i, c in enumerate(ctrls):
            if not isinstance(c, ScheduledLQR):
                raise TypeError(f"controller {i} is a {type(c).__name__}, not a ScheduledLQR")
            if c.reference != first.reference:
                raise ValueError(f"controller {i} follows another reference than controller 0")
            if not (np.array_equal(c.f_min, first.f_min) and np.array_equal(c.f_max, first.f_max)):
                raise ValueError(f"controller {i} has other thrust limits than controller 0")
        self.controllers = ctrls
        self.reference = first.reference
        self.f_min, self.f_max = first.f_min, first.f_max
        n_pts = max(len(c.speeds) for c in ctrls) + 1  # >= 2 columns, room for one padding point
        self.speeds = np.empty((len(ctrls), n_pts))
        self.gains = np.empty((len(ctrls), n_pts) + first.gains.shape[1:])
        self.top = np.empty(len(ctrls))
        for i, c in enumerate(ctrls):
            k = len(c.speeds)
            self.speeds[i, :k], self.gains[i, :k] = c.speeds, c.gains
            self.speeds[i, k:] = c.speeds[-1] + 1.0 + np.arange(n_pts - k)
            self.gains[i, k:] = c.gains[-1]
            self.top[i] = c.speeds[-1]
        self._trims: dict = {}

    def __len__(self) -> int:
        return len(self.controllers)

    def trim(self, surge: float) -> np.ndarray:
        """(N, n) trim thrusts of every design model at the reference surge speed (N)."""
        key = round(float(surge), 6)
        f = self._trims.get(key)
        if f is None:
            per_object = {}
            f = self._trims[key] = np.stack([per_object.setdefault(id(c), c.trim(key)) for c in self.controllers])
        return f

    def gain(self, surge) -> np.ndarray:
        """(N, n, 10) gains interpolated in each vehicle's surge speed (m/s, (N,)), held at the ends."""
        s = np.clip(np.asarray(surge, float), self.speeds[:, 0], self.top)
        k = np.clip(np.sum(self.speeds < s[:, None], axis=1) - 1, 0, self.speeds.shape[1] - 2)
        rows = np.arange(len(s))
        lo, hi = self.speeds[rows, k], self.speeds[rows, k + 1]
        a = ((s - lo) / (hi - lo))[:, None, None]
        return (1 - a) * self.gains[rows, k] + a * self.gains[rows, k + 1]

    def __call__(self, t, x):
        x = np.asarray(x, float).reshape(len(self), 12)
        ref = self.reference(t)
        xr = np.zeros(12)
        xr[2], xr[5], xr[6] = ref["z"], ref["psi"], ref["u"]
        e = (x - xr)[:, list(REDUCED_INDEX)]
        e[:, PSI_R] = wrap_angle(e[:, PSI_R])
        u = np.where(np.isfinite(x[:, 6]), x[:, 6], ref["u"])
        trim = self.trim(ref["u"])
        f = trim - np.einsum("nij,nj->ni", self.gain(u), e)
        bad = ~np.all(np.isfinite(f), axis=1)
        f[bad] = trim[bad]  # safe fallback on a non-finite state, as ScheduledLQR
        return np.clip(f, self.f_min, self.f_max)
