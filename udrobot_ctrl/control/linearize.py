"""Linearisation of the thruster-input plant at operating points, and an honest controllability report.

Operating points (:func:`operating_points`): hover at a depth (trim thrust balancing the net buoyancy,
least squares through the thruster matrix) and steady level surge at 0.25 and 0.5 m/s and at the
highest speed the thrusters reach (:func:`max_surge_speed`: the largest surge force the thrusters can
produce with the other actuated wrench components held at trim, found by a linear program over the box
limits, balanced against the model's surge drag ``X(u) = K_L u + K_Q u|u|`` by root finding).

:func:`linearize` differentiates the casadi plant (:func:`udrobot_ctrl.dynamics.plant_casadi.dynamics_function`
with ``inputs='thrust'``) exactly at the trim ``(x0, u0)`` and returns a python-control ``StateSpace``
(inputs: the thrusts T1..Tn in N; states: ``x y z phi theta psi u v w p q r``; outputs selectable).

The layout is data (any number of thrusters, the vehicle's own thruster matrix). Structure of UDrobot's
layout (two surge thrusters at y = +-0.15 m, two vertical at y = +-0.15 m, all
in the z = 0 plane): the thruster matrix has rank 4 (surge X, heave Z, roll K, yaw N); sway Y and pitch M
have zero rows. In the linear model:

* x, y are pure integrators (no force depends on position); y is reachable only at speed (via
  psi: y_dot ~ u0 psi), x through u. Position is not tracked by the mission, so the design state is the
  *reduced* ``[z, phi, theta, psi, u, v, w, p, q, r]`` (:data:`REDUCED_STATES`); z and psi are
  integrators too (no hydrostatic depth or heading stiffness) but directly actuated.
* pitch and sway are reached only through inertial coupling (the CG lies ``z_g`` below the origin, so
  M_RB couples surge-pitch and sway-roll) and, at speed, the Munk/Coriolis terms: controllable in the
  rank sense but weakly. :func:`controllability_report` therefore uses the Kalman decomposition with a
  relative tolerance, lists every mode with its PBH controllability margin, and checks that the modes
  outside the (numerically) controllable subspace are stable.
* at hover the Morison-form models have no linear damping: the quadratic drag has zero slope at rest,
  so the passive sway mode sits at s = 0 and pitch is an undamped pendulum (s = +-j w): *marginally*
  stable in the linearisation (the quadratic drag damps them in the nonlinear plant).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from udrobot_ctrl.constants import STATE_INDEX, STATE_NAMES
from udrobot_ctrl.dynamics.plant import PlantParameters, generalized_forces
from udrobot_ctrl.dynamics.plant_casadi import dynamics_function

#: Design state (position x, y dropped: not tracked, pure integrators).
REDUCED_STATES = ("z", "phi", "theta", "psi", "u", "v", "w", "p", "q", "r")
REDUCED_INDEX = tuple(STATE_INDEX[n] for n in REDUCED_STATES)
#: Surge speeds (m/s) of the standard operating points besides hover and the maximum speed.
SURGE_POINTS = (0.25, 0.5)


@dataclass(frozen=True)
class OperatingPoint:
    """A trim: state ``x0`` (12,) and thrusts ``u0`` (n,) with f(x0, u0) ~ 0.

    Attributes
    ----------
    name : str
        e.g. ``hover``, ``surge 0.50 m/s``, ``surge max 1.28 m/s``.
    surge : float
        Surge speed u of the trim, m/s (the scheduling variable).
    x0 : ndarray
        Trim state (level, heading 0, at ``depth``), SI units.
    u0 : ndarray
        Trim thrusts, N (least squares through the thruster matrix).
    residual : ndarray
        The 6 body accelerations left at the trim (m/s^2, rad/s^2): zero for an exact equilibrium;
        non-zero if the thrusters cannot balance a component (e.g. a pitch moment).
    """

    name: str
    surge: float
    x0: np.ndarray
    u0: np.ndarray
    residual: np.ndarray = field(default_factory=lambda: np.zeros(6))

    @property
    def is_equilibrium(self) -> bool:
        return bool(np.all(np.abs(self.residual) < 1e-9))


def _level_state(surge: float, depth: float) -> np.ndarray:
    x = np.zeros(12)
    x[2], x[6] = depth, surge
    return x


def trim_at(p: PlantParameters, surge: float = 0.0, depth: float = 1.0, name: str | None = None) -> OperatingPoint:
    """Trim for level flight at ``surge`` m/s and ``depth`` m: thrusts u0 = T^+ (C nu + D nu + g) (N).

    Parameters
    ----------
    p : PlantParameters
        The plant.
    surge : float
        Surge speed u of the trim, m/s.
    depth : float
        Depth of the trim, m (positive down).
    name : str, optional
        Label of the point (default ``hover`` or ``surge 0.50 m/s``).

    Returns
    -------
    OperatingPoint
        The trim state, the least-squares thrusts (N) and the accelerations they leave (m/s^2, rad/s^2).
    """
    x0 = _level_state(float(surge), float(depth))
    need = generalized_forces(x0, p)
    u0 = np.linalg.lstsq(p.T, need, rcond=None)[0]
    residual = p.M_inv @ (p.T @ u0 - need)
    label = name or ("hover" if surge == 0 else f"surge {surge:.2f} m/s")
    return OperatingPoint(label, float(surge), x0, u0, residual)


def hover_trim(p: PlantParameters, depth: float = 1.0) -> OperatingPoint:
    """Hover at ``depth`` m: the vertical thrusters hold the net buoyancy B - W (N).

    Parameters
    ----------
    p : PlantParameters
        The plant.
    depth : float
        Depth, m (positive down).

    Returns
    -------
    OperatingPoint
        :func:`trim_at` with zero surge, named ``hover``.
    """
    return trim_at(p, 0.0, depth, "hover")


def held_rows(T, tol: float = 1e-9) -> list:
    """Wrench rows (1..5) held at trim while surging: those the thrusters set independently of surge.

    A row is held when it is non-zero and not a combination of the surge row and the rows already held.
    A row that is such a combination (BlueROV2: the horizontals sit below CO, so the pitch row is
    0.0725 X - 0.0025 Z) cannot be held without holding surge too: its moment is left to the restoring forces.
    """
    T = np.asarray(T, float)
    scale = max(1.0, float(np.abs(T).max()))
    rows: list = []
    for j in range(1, 6):
        if not np.any(np.abs(T[j]) > tol * scale):
            continue
        base = T[[0] + rows]
        r0 = np.linalg.matrix_rank(base, tol * scale)
        if np.linalg.matrix_rank(np.vstack([base, T[j]]), tol * scale) > r0:
            rows.append(j)
    return rows


def max_surge_force(p: PlantParameters, depth: float = 1.0) -> float:
    """Largest steady surge force (N) the thrusters give with the other wrench rows held at the hover trim.

    Linear program: max (T f)_X s.t. (T f)_j = hover trim wrench_j for the rows of :func:`held_rows`
    (UDrobot: heave, roll, yaw; BlueROV2 Heavy: all five), f_min <= f <= f_max.

    Raises
    ------
    ValueError
        If the LP is infeasible (the thrusters cannot hold the hover trim).
    """
    from scipy.optimize import linprog

    T = p.T
    trim = T @ hover_trim(p, depth).u0
    rows = held_rows(T)
    res = linprog(-T[0], A_eq=T[rows] if rows else None, b_eq=trim[rows] if rows else None,
                  bounds=list(zip(p.f_min, p.f_max)), method="highs")
    if not res.success:
        raise ValueError(f"model {p.name!r}: no thrust holds the hover trim while surging ({res.message})")
    return float(-res.fun)


def max_surge_speed(p: PlantParameters, depth: float = 1.0) -> float:
    """Highest steady level surge speed (m/s): surge drag X(u) of the model = :func:`max_surge_force`.

    Solved by bracketing and Brent's method on the plant's own surge force ``generalized_forces(x)[0]``
    (K_L u + K_Q u|u| for the Chin/Morison forms).
    """
    from scipy.optimize import brentq

    X = max_surge_force(p, depth)

    def excess(u):
        return generalized_forces(_level_state(u, depth), p)[0] - X

    hi = 0.5
    while excess(hi) < 0:
        hi *= 2
        if hi > 100:
            raise ValueError(f"model {p.name!r}: surge drag never reaches the thrust limit {X:.1f} N")
    return float(brentq(excess, 0.0, hi, xtol=1e-10))


def operating_points(p: PlantParameters, depth: float = 1.0, speeds=SURGE_POINTS) -> list:
    """Hover, steady surge at ``speeds`` (m/s) and at :func:`max_surge_speed` (sorted by speed)."""
    vmax = max_surge_speed(p, depth)
    pts = [hover_trim(p, depth)] + [trim_at(p, s, depth) for s in speeds if 0 < s < vmax]
    pts.append(trim_at(p, vmax, depth, f"surge max {vmax:.2f} m/s"))
    return pts


# ----------------------------------------------------------------------------- Jacobians
_JAC_CACHE: dict = {}


def jacobian_function(p: PlantParameters):
    """casadi Function (x, u) -> (f, df/dx, df/du) of the thruster-input plant (cached per parameters)."""
    import casadi as ca

    key = id(p)
    hit = _JAC_CACHE.get(key)
    if hit is not None and hit[0] is p:
        return hit[1]
    f = dynamics_function(p, inputs="thrust")
    x = ca.SX.sym("x", 12)
    u = ca.SX.sym("u", p.T.shape[1])
    fx = f(x, u)
    fun = ca.Function("plant_jacobians", [x, u], [fx, ca.jacobian(fx, x), ca.jacobian(fx, u)])
    _JAC_CACHE[key] = (p, fun)
    return fun


def jacobians(p: PlantParameters, x0, u0):
    """(f(x0,u0), A, B): state derivative (12,) and the exact Jacobians (12x12, 12xn) at (x0, u0)."""
    f, A, B = jacobian_function(p)(np.asarray(x0, float), np.asarray(u0, float))
    return np.array(f).ravel(), np.array(A), np.array(B)


@dataclass
class LinearModel:
    """A linearisation: python-control ``sys`` (continuous), the trim and the raw matrices.

    Attributes
    ----------
    point : OperatingPoint
        The trim linearised about.
    sys : control.StateSpace
        Continuous-time model from the thrust deviations (N) to the chosen outputs (SI units).
    A : (12, 12) ndarray
        State Jacobian d f / d x, SI units / s.
    B : (12, n) ndarray
        Input Jacobian d f / d u per newton of thrust.
    f0 : (12,) ndarray
        State derivative at the trim (zero for an equilibrium), SI units / s.
    """

    point: OperatingPoint
    sys: object
    A: np.ndarray
    B: np.ndarray
    f0: np.ndarray  # state derivative at the trim (zero for an equilibrium), SI units / s

    def reduced(self, states=REDUCED_STATES):
        """(A_r, B_r) on a subset of states (default :data:`REDUCED_STATES`)."""
        idx = [STATE_INDEX[s] for s in states]
        return self.A[np.ix_(idx, idx)], self.B[idx]


def linearize(p: PlantParameters, point: OperatingPoint, outputs=STATE_NAMES) -> LinearModel:
    """Linearise the plant at ``point``: ``dx/dt = A dx + B du``, ``y = C dx`` (python-control StateSpace).

    Parameters
    ----------
    p : PlantParameters
        The plant.
    point : OperatingPoint
        The trim (:func:`trim_at`, :func:`hover_trim`).
    outputs : sequence of str
        State names measured (default all 12 states, C = I); e.g. ``("z", "phi", "theta", "psi", "u", "v",
        "w", "p", "q", "r")`` for pressure depth + IMU + DVL.

    Returns
    -------
    LinearModel
        A, B (from casadi's exact Jacobians), the python-control system and the trim.
    """
    import control

    f0, A, B = jacobians(p, point.x0, point.u0)
    bad = [o for o in outputs if o not in STATE_INDEX]
    if bad:
        raise ValueError(f"outputs {bad} are not state names ({', '.join(STATE_NAMES)})")
    C = np.zeros((len(outputs), 12))
    for i, o in enumerate(outputs):
        C[i, STATE_INDEX[o]] = 1.0
    n = B.shape[1]
    sys = control.ss(A, B, C, np.zeros((len(outputs), n)), states=list(STATE_NAMES),
                     inputs=[f"T{i + 1}" for i in range(n)], outputs=list(outputs),
                     name=f"{p.name} {point.name}".replace(".", "_"))
    return LinearModel(point, sys, A, B, f0)


# ----------------------------------------------------------------------------- structure
def controllable_subspace(A, B, rtol: float = 1e-7) -> np.ndarray:
    """Orthonormal basis V (n x r) of the controllable subspace (Krylov iteration with re-orthogonalisation).

    Directions whose component falls below ``rtol`` times the largest are treated as not controllable.
    """
    A, B = np.asarray(A, float), np.asarray(B, float)
    n = A.shape[0]
    scale = max(np.linalg.norm(B), 1e-300)

    def orth_new(V, W):
        if V.shape[1]:
            W = W - V @ (V.T @ W)
            W = W - V @ (V.T @ W)
        U, s, _ = np.linalg.svd(W, full_matrices=False)
        return U[:, s > rtol * scale]

    V = orth_new(np.zeros((n, 0)), B)
    new = V
    while new.shape[1] and V.shape[1] < n:
        anorm = max(np.linalg.norm(A, 2), 1e-300)
        new = orth_new(V, A @ new / anorm * scale)
        V = np.hstack([V, new])
    return V


@dataclass
class StructureReport:
    """Controllability / observability of one linear model, and the stability of what is left.

    Attributes
    ----------
    states : tuple of str
        The state subset analysed.
    eigenvalues : ndarray
        Open-loop eigenvalues of A on that subset, 1/s.
    pbh_margin : ndarray
        Per eigenvalue, smallest singular value of [A - lambda I, B] divided by ||[A, B]||: 0 =
        uncontrollable mode, small = weakly controllable.
    controllable_rank : int
        Dimension of the controllable subspace (relative tolerance ``rtol``).
    uncontrollable_eigenvalues : ndarray
        Eigenvalues of A restricted to the orthogonal complement of the controllable subspace.
    stabilizable : bool
        All uncontrollable eigenvalues have real part < 0 (marginal ones at Re = 0 are *not* counted as
        stabilizable; see ``marginal``).
    marginal : bool
        Some uncontrollable eigenvalue sits on the imaginary axis (|Re| <= 1e-9).
    observable_rank : int or None
        Rank of the observability matrix for the outputs given (None when no outputs).
    dominant_states : dict
        Eigenvalue (str) -> the two states with the largest (scaled) eigenvector components.
    """

    states: tuple
    eigenvalues: np.ndarray
    pbh_margin: np.ndarray
    controllable_rank: int
    uncontrollable_eigenvalues: np.ndarray
    stabilizable: bool
    marginal: bool
    observable_rank: int | None
    dominant_states: dict

    def summary(self) -> str:
        obs = "" if self.observable_rank is None else f"; observable rank {self.observable_rank}"
        lines = [f"states {', '.join(self.states)} ({len(self.states)}); controllable subspace dimension "
                 f"{self.controllable_rank}{obs}"]
        for lam, m in zip(self.eigenvalues, self.pbh_margin):
            key = _fmt(lam)
            lines.append(f"  mode {key:>20}  PBH margin {m:8.2e}  ({', '.join(self.dominant_states[key])})")
        unc = ", ".join(_fmt(lam) for lam in self.uncontrollable_eigenvalues) or "none"
        verdict = "stable" if self.stabilizable else ("MARGINAL" if self.marginal else "UNSTABLE")
        lines.append(f"  uncontrollable modes: {unc} -> {verdict}")
        return "\n".join(lines)


def _fmt(lam) -> str:
    return f"{lam.real:+.4f}{lam.imag:+.4f}j"


def structure_report(A, B, C=None, states=STATE_NAMES, rtol: float = 1e-7) -> StructureReport:
    """Kalman-decomposition report of (A, B[, C]) (see :class:`StructureReport`)."""
    A, B = np.asarray(A, float), np.asarray(B, float)
    n = A.shape[0]
    lam, vec = np.linalg.eig(A)
    AB = np.hstack([A, B])
    norm = max(np.linalg.norm(AB, 2), 1e-300)
    margin = np.array([np.linalg.svd(np.hstack([A - li * np.eye(n), B]), compute_uv=False)[-1] / norm for li in lam])
    V = controllable_subspace(A, B, rtol)
    r = V.shape[1]
    if r < n:
        U, _, _ = np.linalg.svd(V, full_matrices=True)
        W = U[:, r:]
        unc = np.linalg.eigvals(W.T @ A @ W)
    else:
        unc = np.zeros(0, complex)
    marginal = bool(np.any(np.abs(unc.real) <= 1e-9))
    stabilizable = bool(np.all(unc.real < -1e-9))
    obs = None
    if C is not None:
        C = np.asarray(C, float)
        O = np.vstack([C @ np.linalg.matrix_power(A, k) for k in range(n)])
        obs = int(np.linalg.matrix_rank(O, tol=1e-9 * max(np.linalg.norm(O), 1.0)))
    dom = {}
    for li, v in zip(lam, vec.T):
        order = np.argsort(-np.abs(v))[:2]
        dom[_fmt(li)] = tuple(states[k] for k in order)
    return StructureReport(tuple(states), lam, margin, r, unc, stabilizable, marginal, obs, dom)


def passive_modes(lin: LinearModel, passive=("v", "theta", "q")) -> dict:
    """Eigenvalues (1/s) of the modes dominated by the passive DOFs (sway, pitch) with thrusts held at trim.

    Returns ``{"eigenvalues": [...], "stable": bool, "marginal": bool}`` for the reduced state.
    """
    Ar, _ = lin.reduced()
    lam, vec = np.linalg.eig(Ar)
    idx = [REDUCED_STATES.index(s) for s in passive]
    sel = [i for i in range(len(lam)) if np.argmax(np.abs(vec[:, i])) in idx]
    ev = lam[sel]
    return {"eigenvalues": ev, "stable": bool(np.all(ev.real < -1e-9)),
            "marginal": bool(np.any(np.abs(ev.real) <= 1e-9))}
