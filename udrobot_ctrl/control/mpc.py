"""Model predictive control of UDrobot's thrusters: linear MPC (condensed active set or OSQP) and nonlinear MPC
(RTI-SQP or ipopt).

Both controllers are callables ``ctrl(t, x) -> f`` returning the four thrusts (N) for the plant state
``x = [x y z phi theta psi u v w p q r]`` (NED position m, ZYX Euler angles rad, body velocities m/s, rad/s),
so they plug into :func:`udrobot_ctrl.dynamics.sim.simulate` like any other controller.

Formulation (shared by both)
----------------------------
Prediction model: the casadi plant (:mod:`udrobot_ctrl.dynamics.plant_casadi`) with thrusts as inputs, one RK4 step
of ``dt`` per interval (zero-order hold). Cost over the horizon ``N``::

    sum_k (x_k - r_k)' Q (x_k - r_k) + (f_k - f_trim)' R (f_k - f_trim)  +  (x_N - r_N)' Q_N (x_N - r_N)

with ``r_k = reference(t + k dt)`` (preview of the mission), the heading reference unwrapped to within
pi of the current heading (so a 350 deg -> 10 deg change turns 20 deg, not 340 deg), and ``f_trim`` the
thrust that holds the reference surge speed level against the design model's drag and net buoyancy.
Constraints: ``f_min <= f_k <= f_max`` per thruster (asymmetric forward/reverse limits of the model),
optional hard state bounds (``state_bounds={"z": (0.0, 5.0)}``) on ``x_1 .. x_N``.

QP structure: *sparse* (states and inputs are both decision variables, dynamics are equality
constraints). Chosen over the condensed form because (i) the Hessian P is then constant (block diagonal
Q, R), so only the dynamics blocks of the constraint matrix change when the model is re-linearised and
OSQP can update them in place (``update(Ax=...)``) keeping the sparsity pattern; (ii) the KKT matrix stays
sparse (nnz grows linearly in N, not quadratically) and no matrix powers of A are formed, which matters
for the weakly damped roll/pitch modes; (iii) the same structure serves the nonlinear RTI, whose
Jacobians differ from stage to stage. The surge/sway positions x, y do not enter the dynamics; unless
they carry a weight or a bound they are dropped from the QP (10 states instead of 12).

Linear MPC (:class:`LinearMPC`): at every call the prediction model is re-linearised around the current
state and the previous command (affine term kept, so the model is exact at the operating point),
``x_{k+1} = A x_k + B f_k + c``, the QP is updated and warm-started from the shifted previous solution.
Two backends of the same class solve the same QP (``solver=``): ``dense`` (default) solves it exactly by an
active-set method warm-started from the shifted working set, each iteration one Riccati recursion over the
horizon with the thrusts of the working set fixed at their limits (no condensing; with state bounds the QP is
condensed to the thrusts and solved by DAQP; :class:`udrobot_ctrl.control.fastpath.CondensedMPCQP`); ``osqp``
is the sparse QP above on OSQP, the reference, and the dense backend's fallback when its solve fails (counted
in ``stats['fast_fallbacks']``). The linearisation is called through its compiled C code on preallocated
buffers (:class:`udrobot_ctrl.control.fastpath.CompiledFunction`), and a piecewise-constant mission's preview
is a table lookup (a numba kernel). Per call (N = 20, bench/control.py, 2 cores): ~55 us dense for the
UDrobot (4 thrusters), ~75 us for bluerov2-heavy (8 thrusters), against ~0.5-0.6 ms on OSQP.

Nonlinear MPC (:class:`NonlinearMPC`): multiple shooting. ``method='rti'`` (default, the fast path) is a
real-time-iteration SQP: the shooting nodes of the previous solution are shifted, the QP data of every stage
(the RK4 step linearised at the node, ``[A_k | B_k | c_k]`` on the reduced states) come from one compiled
casadi function (``map`` over the horizon) evaluated in place on preallocated buffers, and the Gauss-Newton
QP (exact Hessian for this least-squares cost) is solved by the same two backends (``solver=``): ``dense``
(default, the Riccati active set with a model per stage, warm-started from the shifted working set; OSQP
when state bounds are given or as the fallback) or ``osqp``. Per call ~0.13-0.16 ms dense against ~0.65 ms on
OSQP, the same closed-loop IAE (within 1e-6); ``sqp_iterations`` > 1 iterates to convergence.
``method='ipopt'`` solves the full NLP with ipopt (the correctness reference, ~10x slower).

Failure handling: a non-finite or implausible state (outside :data:`STATE_LIMITS`, e.g. the 1e44 m of an
estimator that swallowed a sensor spike), a solver exception, non-finite QP data, an infeasible or unsolved
QP/NLP never raises in the loop; the controller applies the next move of the previous plan (shifted
solution) while one is left, else the trim thrust (hover/cruise trim, clipped), and records it in
``last_status`` and ``stats['fallbacks']`` (a ``RuntimeWarning`` is issued on the first fallback and then
every 100th). Commands are always clipped to the thrust limits.

Recovery: an implausible state is rejected *before* it reaches the solver (OSQP silently keeps its old data
when an update fails validation, and would "solve" the stale problem). After any failed solve the
solver state is reset (:meth:`SparseMPCQP.reset_solver`: primal/dual iterates zeroed, ADMM step ``rho``
back to its setting) and the shifted trajectories are dropped, so the next call with a sane state solves
from a cold start: without this, OSQP's iterates and adapted ``rho`` from a poisoned solve made every
later solve hit the iteration limit (``stats['solver_resets']`` counts the resets).
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import casadi as ca
import numpy as np
import scipy.sparse as sp

from udrobot_ctrl.constants import STATE_INDEX, STATE_NAMES
from udrobot_ctrl.control.fastpath import CompiledFunction, CondensedMPCQP, preview_table
from udrobot_ctrl.dynamics.fastsim import compile_function, parameter_hash
from udrobot_ctrl.dynamics.plant import PlantParameters, generalized_forces, plant_parameters, wrap_angle
from udrobot_ctrl.dynamics.plant_casadi import rk4_step_function

_ALIASES = {"depth": "z", "heading": "psi", "surge": "u", "yaw": "psi", "roll": "phi", "pitch": "theta"}
PSI = 5

#: Default state weights (Bryson's rule, 1 / acceptable error^2; assumed, tuned on the nominal models):
#: depth 0.1 m, heading 0.1 rad, surge 0.1 m/s, roll 0.1 rad, pitch 0.3 rad (passive DOF, little
#: authority), heave speed 0.5 m/s, angular rates 0.5 rad/s; x, y, v unweighted.
DEFAULT_STATE_WEIGHTS = {"z": 100.0, "psi": 100.0, "u": 100.0, "phi": 100.0, "theta": 10.0,
                         "w": 4.0, "p": 4.0, "q": 4.0, "r": 4.0}
#: Default thrust weight: 1 / (20 N)^2 (Bryson's rule, about half the T200 forward limit; assumed).
DEFAULT_THRUST_WEIGHT = 1.0 / 20.0 ** 2

_OK_STATUSES = ("solved", "solved inaccurate")

#: Plausible envelope of a state handed to the MPC (assumed; anything outside is an estimator or wiring fault,
#: not a vehicle state): |x|, |y|, |z| <= 1e4 m (any ROV work area), |phi|, |theta| <= pi (Euler angles are
#: wrapped), |psi| <= 1e3 rad (unwrapped headings are allowed), |u|, |v|, |w| <= 20 m/s (10x a BlueROV2-class
#: top speed), |p|, |q|, |r| <= 50 rad/s.
STATE_LIMITS = np.array([1e4, 1e4, 1e4, np.pi, np.pi, 1e3, 20.0, 20.0, 20.0, 50.0, 50.0, 50.0])
#: Largest magnitude accepted in QP data (OSQP treats |values| >= 1e30 as infinite; 1e20 keeps a margin).
_QP_DATA_LIMIT = 1e20



def _state_from_reference(r) -> np.ndarray:
    """(12,) state reference from a dict of named states or a (12,) array (missing names are 0)."""
    if isinstance(r, dict):
        out = np.zeros(12)
        for k, v in r.items():
            name = _ALIASES.get(k, k)
            if name not in STATE_INDEX:
                raise ValueError(f"reference key {k!r} is not a state; expected one of {', '.join(STATE_NAMES)}")
            out[STATE_INDEX[name]] = float(v)
        return out
    arr = np.asarray(r, dtype=float).reshape(-1)
    if arr.shape != (12,):
        raise ValueError(f"reference must be a dict of named states or a (12,) state vector, got shape {arr.shape}")
    return arr


def reference_function(reference):
    """Normalise a reference to a function ``t -> (12,)`` state reference.

    Parameters
    ----------
    reference : callable, dict, array_like or object with a ``reference(t)`` method
        ``reference(t)`` returning a dict (keys ``z``, ``psi``, ``u`` ... in m, rad, m/s; aliases
        ``depth``, ``heading``, ``surge``) or a (12,) state; or a constant dict / (12,) array.
    """
    if callable(reference):
        return lambda t: _state_from_reference(reference(t))
    if hasattr(reference, "reference") and callable(reference.reference):
        return lambda t: _state_from_reference(reference.reference(t))
    const = _state_from_reference(reference)
    return lambda t: const


def _weights(W, n, default, names=None):
    """(n, n) weight matrix from None, a scalar, a (n,) diagonal, a (n, n) matrix or a dict of names."""
    if W is None:
        W = default
    if isinstance(W, dict):
        base = np.zeros(n)
        if default is not None and isinstance(default, dict):
            for k, v in default.items():
                base[STATE_INDEX[k]] = v
        for k, v in W.items():
            name = _ALIASES.get(k, k)
            if names is None or name not in names:
                raise ValueError(f"weight key {k!r} is not a state name ({', '.join(STATE_NAMES)})")
            base[names.index(name)] = float(v)
        return np.diag(base)
    W = np.asarray(W, dtype=float)
    if W.ndim == 0:
        return float(W) * np.eye(n)
    if W.shape == (n,):
        return np.diag(W)
    if W.shape == (n, n):
        return 0.5 * (W + W.T)
    raise ValueError(f"weight must be a scalar, ({n},), ({n}, {n}) or a dict, got shape {W.shape}")


def implausible_state(x) -> str | None:
    """Why ``x`` cannot be a vehicle state (wrong shape, non-finite, outside :data:`STATE_LIMITS`), or None."""
    x = np.asarray(x, dtype=float).reshape(-1)
    if x.shape != (12,):
        return f"malformed state (shape {x.shape}, expected (12,))"
    bad = ~np.isfinite(x)
    if bad.any():
        return f"non-finite state ({', '.join(STATE_NAMES[i] for i in np.flatnonzero(bad))})"
    out = np.abs(x) > STATE_LIMITS
    if out.any():
        i = int(np.flatnonzero(out)[0])
        return f"implausible state ({STATE_NAMES[i]} = {x[i]:.3g}, limit +-{STATE_LIMITS[i]:.3g})"
    return None


def trim_thrust(p: PlantParameters, x_ref) -> np.ndarray:
    """Thrusts (N) holding the level state ``x_ref`` (surge speed, others at rest) in least squares.

    Balances drag, Coriolis and net buoyancy (``tau = C nu + D nu + g``) through the thruster matrix; the
    unactuated components (sway, pitch) are left to the passive dynamics. Clipped to the thrust limits.
    """
    x = np.zeros(12)
    x[6] = x_ref[6]
    tau = generalized_forces(x, p)
    f = np.linalg.lstsq(p.T, tau, rcond=None)[0]
    return np.clip(f, p.f_min, p.f_max)


def linearization_function(p: PlantParameters, dt: float, name: str = "lin") -> ca.Function:
    """casadi Function ``(x[12], f[n]) -> (x_next, A = dx_next/dx, B = dx_next/df)`` of one RK4 step (dense)."""
    F = rk4_step_function(p, dt, "thrust")
    x = ca.SX.sym("x", 12)
    u = ca.SX.sym("f", p.T.shape[1])
    xn = F(x, u)
    A = ca.densify(ca.jacobian(xn, x))
    B = ca.densify(ca.jacobian(xn, u))
    return ca.Function(name, [x, u], [xn, A, B], ["x", "f"], ["x_next", "A", "B"])


def affine_model_function(p: PlantParameters, dt: float, idx, name: str = "affine") -> ca.Function:
    """casadi Function ``(x[12], f[n]) -> [A_r | B_r | c_r]`` (nx, nx + n + 1) on the states ``idx``.

    ``x_next[idx] ~ A_r x[idx] + B_r f + c_r``, exact at (x, f): one output so Python converts one array.
    Valid only when the dropped states do not enter the dynamics (x, y).
    """
    lin = linearization_function(p, dt)
    x = ca.SX.sym("x", 12)
    u = ca.SX.sym("f", p.T.shape[1])
    xn, A, B = lin(x, u)
    idx = [int(i) for i in idx]
    A_r, B_r = A[idx, idx], B[idx, :]
    c = xn[idx] - A_r @ x[idx] - B_r @ u
    return ca.Function(name, [x, u], [ca.horzcat(A_r, B_r, c)], ["x", "f"], ["ABc"])


#: gcc budget for compiling the generated Jacobian functions (s); on timeout casadi's VM is used (2x slower).
COMPILE_TIMEOUT_S = 30.0


def maybe_compiled(fun: ca.Function, p: PlantParameters, *key, compile: bool = True) -> ca.Function:
    """gcc-compiled copy of ``fun`` (cached on disk by
    :func:`udrobot_ctrl.dynamics.fastsim.compile_function`) or ``fun``."""
    if not compile:
        return fun

    try:
        out = compile_function(fun, parameter_hash(p, fun.name(), *key), timeout=COMPILE_TIMEOUT_S)
    except (OSError, RuntimeError):  # cache folder unusable, casadi codegen/load failed: compiling is optional
        out = None
    return fun if out is None else out


@dataclass(frozen=True)
class OSQPSettings:
    """OSQP options for the MPC QPs (tuned in bench/control.py: first move within 0.1 N of the exact optimum).

    ``eps_abs`` / ``eps_rel`` are OSQP's residual tolerances (on the scaled QP, see :class:`SparseMPCQP`),
    ``polishing`` runs the active-set refinement that makes the solution exact when the active set is right
    (+0.15 ms: one more factorisation), ``rho`` the initial ADMM step (0.01 took ~20 iterations warm-started
    against ~30 for OSQP's 0.1 on the standard mission).
    """

    eps_abs: float = 1e-4
    eps_rel: float = 1e-4
    rho: float = 0.01
    polishing: bool = False
    max_iter: int = 4000
    check_termination: int = 10
    warm_starting: bool = True
    adaptive_rho: bool = True
    time_limit: float = 0.0

    def as_dict(self) -> dict:
        d = {"eps_abs": self.eps_abs, "eps_rel": self.eps_rel, "rho": self.rho, "polishing": self.polishing,
             "max_iter": self.max_iter, "check_termination": self.check_termination,
             "warm_starting": self.warm_starting, "adaptive_rho": self.adaptive_rho, "verbose": False}
        if self.time_limit > 0:
            d["time_limit"] = self.time_limit
        return d


class SparseMPCQP:
    """The sparse tracking QP of horizon N over reduced states ``idx`` (see the module docstring).

    Variables ``z = [x_0 .. x_N, f_0 .. f_{N-1}]``. Constraint rows: ``x_0 = x(t)``;
    ``x_{k+1} - A_k x_k - B_k f_k = c_k``; ``f_min <= f_k <= f_max``; optional bounds on ``x_1 .. x_N``.
    Dynamics blocks are stored dense so that any Jacobian fits the fixed sparsity pattern.
    """

    def __init__(self, nx, nu, N, Q, QN, R, f_min, f_max, state_bounds=None, settings=None):
        import osqp

        # Variable scaling z = D z~ with unit cost curvature (x~_i = sqrt(Q_ii) x_i, f~_j = sqrt(R_jj) f_j) and
        # rows scaled so that every constant entry stays 1: OSQP's residual tolerances then mean the same
        # thing for a thrust (N) as for a heading (rad); without it, eps_rel 1e-4 allowed ~4 N first-move errors.
        qd, rd = np.diag(Q).copy(), np.diag(R).copy()
        sx = np.where(qd > 0, 1.0 / np.sqrt(np.where(qd > 0, qd, 1.0)), 1.0)
        su = np.where(rd > 0, 1.0 / np.sqrt(np.where(rd > 0, rd, 1.0)), 1.0)
        self.sx, self.su = sx, su
        self.D = np.concatenate([np.tile(sx, N + 1), np.tile(su, N)])

        self.nx, self.nu, self.N = nx, nu, N
        self.Q, self.QN, self.R = Q, QN, R
        nX, nU = (N + 1) * nx, N * nu
        self.n = nX + nU
        P = sp.block_diag([sp.kron(sp.eye(N), Q), QN, sp.kron(sp.eye(N), R)], format="csc")
        Dm = sp.diags(self.D)
        self.P = sp.triu(Dm @ P @ Dm, format="csc")
        rows, cols, src = [], [], []
        const = []

        def add_const(r, c, v):
            rows.append(r)
            cols.append(c)
            src.append(len(const))
            const.append(v)

        for i in range(nx):
            add_const(i, i, 1.0)
        for k in range(N):
            for i in range(nx):
                add_const(nx * (k + 1) + i, nx * (k + 1) + i, 1.0)
        self._nconst_dyn = len(const)
        bidx = []  # state-bound rows: (state position, lower, upper)
        for j, (lo, hi) in (state_bounds or {}).items():
            bidx.append((j, lo, hi))
        row = nx * (N + 1)
        for k in range(N):
            for j in range(nu):
                add_const(row + k * nu + j, nX + k * nu + j, 1.0)
        row += N * nu
        for k in range(1, N + 1):
            for (j, _, _) in bidx:
                add_const(row, k * nx + j, 1.0)
                row += 1
        self.m = row
        n_const = len(const)
        nA, nB = nx * nx, nx * nu
        for k in range(N):  # -A_k at (rows of x_{k+1}, cols of x_k), row-major flat index of A_k
            for i in range(nx):
                for j in range(nx):
                    rows.append(nx * (k + 1) + i)
                    cols.append(nx * k + j)
                    src.append(n_const + k * nA + i * nx + j)
        for k in range(N):
            for i in range(nx):
                for j in range(nu):
                    rows.append(nx * (k + 1) + i)
                    cols.append(nX + k * nu + j)
                    src.append(n_const + N * nA + k * nB + i * nu + j)
        src = np.asarray(src)
        Acsc = sp.csc_matrix((src + 1.0, (rows, cols)), shape=(self.m, self.n))
        Acsc.sort_indices()
        self._perm = np.rint(Acsc.data).astype(int) - 1
        # row scaling E: 1 / scale of the variable each row is "about" (x_0, x_{k+1}, f_k, bounded x_k)
        E = np.empty(self.m)
        E[:nx * (N + 1)] = 1.0 / np.tile(sx, N + 1)
        E[nx * (N + 1):nx * (N + 1) + N * nu] = 1.0 / np.tile(su, N)
        bj = np.array([b[0] for b in bidx], int)
        if bidx:
            E[nx * (N + 1) + N * nu:] = 1.0 / np.tile(sx[bj], N)
        self.E = E
        col_of = np.repeat(np.arange(self.n), np.diff(Acsc.indptr))
        self._entry_scale = E[Acsc.indices] * self.D[col_of]
        self._values = np.zeros(n_const + N * (nA + nB))
        self._values[:n_const] = const
        self._n_const = n_const
        self.l = np.zeros(self.m)
        self.u = np.zeros(self.m)
        r0 = nx * (N + 1)
        self.l[r0:r0 + N * nu] = np.tile(f_min, N)
        self.u[r0:r0 + N * nu] = np.tile(f_max, N)
        r1 = r0 + N * nu
        if bidx:
            lo = np.array([b[1] for b in bidx], float)
            hi = np.array([b[2] for b in bidx], float)
            self.l[r1:] = np.tile(lo, N)
            self.u[r1:] = np.tile(hi, N)
        self.settings = settings or OSQPSettings()
        self.solver = osqp.OSQP()
        # Set up with a placeholder dynamics (identity) so the first factorisation is valid.
        Acsc.data = self.set_dynamics(np.tile(np.eye(nx), (N, 1, 1)), np.zeros((N, nx, nu)))
        self.solver.setup(self.P, np.zeros(self.n), Acsc, self.l * self.E, self.u * self.E,
                          **self.settings.as_dict())
        self.q = np.zeros(self.n)

    def set_dynamics(self, A, B):
        """Fill the dynamics blocks from A (N, nx, nx) or (nx, nx) and B (N, nx, nu) or (nx, nu)."""
        N, nA = self.N, self.nx * self.nx
        c0 = self._n_const
        self._values[c0:c0 + N * nA] = -np.broadcast_to(A, (N, self.nx, self.nx)).reshape(-1)
        self._values[c0 + N * nA:] = -np.broadcast_to(B, (N, self.nx, self.nu)).reshape(-1)
        return self._values[self._perm] * self._entry_scale

    def update(self, A, B, c, x0, xref, uref):
        """Update the QP data: dynamics (A, B, affine c (N, nx)), initial state, references (N+1, nx), (N, nu).

        Raises
        ------
        FloatingPointError
            If any of the data is non-finite or larger than 1e20 in magnitude; the solver is then left
            untouched (OSQP would reject the update and silently keep solving its previous data).
        """
        nx, N = self.nx, self.N
        for name, a in (("A", A), ("B", B), ("c", c), ("x0", x0), ("reference", xref), ("trim thrust", uref)):
            a = np.asarray(a, float)
            if not np.all(np.abs(a) < _QP_DATA_LIMIT):  # False for NaN too
                raise FloatingPointError(f"QP data {name} is non-finite or larger than {_QP_DATA_LIMIT:.0e}")
        Ax = self.set_dynamics(A, B)
        self.l[:nx] = x0
        self.u[:nx] = x0
        cc = np.broadcast_to(c, (N, nx)).reshape(-1)
        self.l[nx:nx * (N + 1)] = cc
        self.u[nx:nx * (N + 1)] = cc
        q = self.q
        q[:N * nx] = -(xref[:N] @ self.Q).reshape(-1)
        q[N * nx:(N + 1) * nx] = -(xref[N] @ self.QN)
        q[(N + 1) * nx:] = -(uref @ self.R).reshape(-1)
        self.solver.update(q=q * self.D, l=self.l * self.E, u=self.u * self.E, Ax=Ax)

    def split(self, z):
        """(X (N+1, nx), U (N, nu)) from the stacked primal vector."""
        nX = (self.N + 1) * self.nx
        return z[:nX].reshape(self.N + 1, self.nx), z[nX:].reshape(self.N, self.nu)

    def stack(self, X, U):
        return np.concatenate([np.asarray(X).reshape(-1), np.asarray(U).reshape(-1)])

    def set_thrust_bounds(self, j, lo, hi):
        """Bounds of thruster ``j`` (N) at every stage (e.g. ``lo == hi`` for a thruster stuck at that thrust)."""
        r0 = self.nx * (self.N + 1)
        rows = r0 + np.arange(self.N) * self.nu + int(j)
        self.l[rows], self.u[rows] = float(lo), float(hi)

    def reset_solver(self):
        """Forget the solver's iterates after a failure: zero primal/dual warm start, ``rho`` back to its setting."""
        self.solver.warm_start(x=np.zeros(self.n), y=np.zeros(self.m))
        self.solver.update_settings(rho=self.settings.rho)

    def solve(self, warm=None):
        """Solve; returns (status string, primal z or None, OSQP info)."""
        if warm is not None:
            self.solver.warm_start(x=warm / self.D)
        res = self.solver.solve(raise_error=False)
        status = res.info.status
        z = res.x * self.D if status in _OK_STATUSES and np.all(np.isfinite(res.x)) else None
        return status, z, res.info


class _MPCBase:
    """Reference handling, weights, trim, fallback and statistics shared by the two MPCs."""

    def __init__(self, vehicle, reference, dt, horizon, Q, R, terminal_weight, state_bounds, settings, compile):
        self.params = vehicle if isinstance(vehicle, PlantParameters) else plant_parameters(vehicle)
        p = self.params
        if not (dt > 0 and int(horizon) >= 1):
            raise ValueError(f"dt must be > 0 and horizon >= 1 (got dt={dt}, horizon={horizon})")
        if np.any(p.f_min >= p.f_max):
            raise ValueError("thrust limits of the model are empty (f_min >= f_max)")
        self.dt, self.N, self.nu = float(dt), int(horizon), p.T.shape[1]
        self.reference = reference_function(reference)
        # vectorised references (e.g. missions.Mission.reference_array: channel -> (n,) arrays) save ~0.1 ms/call
        self._reference_array = getattr(reference, "reference_array", None)
        self._table = self._reference_table(reference)
        self._trim_rows = None
        self._preview = self.dt * np.arange(self.N + 1)  # s, the horizon's sample times after t
        Qf = _weights(Q, 12, DEFAULT_STATE_WEIGHTS, list(STATE_NAMES))
        self.R = _weights(DEFAULT_THRUST_WEIGHT if R is None else R, self.nu, None)
        bounds = {}
        for k, (lo, hi) in (state_bounds or {}).items():
            name = _ALIASES.get(k, k)
            if name not in STATE_INDEX:
                raise ValueError(f"state_bounds key {k!r} is not a state name ({', '.join(STATE_NAMES)})")
            bounds[STATE_INDEX[name]] = (float(lo), float(hi))
        keep_xy = np.any(Qf[:2] != 0) or np.any(Qf[:, :2] != 0) or 0 in bounds or 1 in bounds
        self.idx = np.arange(12) if keep_xy else np.arange(2, 12)
        self._psi_col = int(np.flatnonzero(self.idx == PSI)[0])
        pos = {int(s): i for i, s in enumerate(self.idx)}
        self.Q = Qf[np.ix_(self.idx, self.idx)]
        self.QN = float(terminal_weight) * self.Q
        self.state_bounds = {pos[s]: b for s, b in bounds.items()}
        self.settings = settings or OSQPSettings()
        self.lin = maybe_compiled(linearization_function(p, self.dt), p, self.dt, compile=compile)
        self._trim_cache: dict[float, np.ndarray] = {}
        self.f_min, self.f_max = np.asarray(p.f_min, float), np.asarray(p.f_max, float)
        self._plan = None  # (U (N, nu)) of the last successful solve
        self._plan_age = 0
        self.last_command = None
        self.last_status = "not run"
        self.stats = {"solves": 0, "fallbacks": 0, "solver_resets": 0, "status": "not run",
                      "solve_time_s": np.nan, "call_time_s": np.nan, "iterations": 0}
        self.call_times: list[float] = []  # wall time of every call (linearisation + QP update + solve), s
        self.solve_times: list[float] = []  # solver-reported time of every call (OSQP solve / ipopt total), s

    # -- references ---------------------------------------------------------------------------------
    def _reference_table(self, reference):
        """(breakpoint times (m,), state references (m + 1, 12)) of a piecewise-constant, right-continuous
        reference with a ``reference_array`` and ``steps`` carrying their times ``.t`` (a
        :class:`udrobot_ctrl.control.missions.Mission`), or None. Row k holds the reference from the k-th
        breakpoint on (row 0 before the first), evaluated by ``reference_array`` itself, so a lookup
        (``searchsorted``) returns exactly what ``reference_array`` would, in ~2 us instead of ~30 us."""
        steps = getattr(reference, "steps", None)
        if self._reference_array is None or steps is None:
            return None
        try:
            times = np.unique(np.array([float(s.t) for s in steps], float))
            at = np.concatenate([[-np.inf], times])
            rows = np.zeros((len(at), 12))
            for k, v in self._reference_array(at).items():
                rows[:, STATE_INDEX[_ALIASES.get(k, k)]] = v
        except (AttributeError, KeyError, TypeError, ValueError):
            return None
        return times, rows

    def references(self, t, x):
        """State references (N+1, nx) over the horizon (heading unwrapped near x) and trim thrusts (N, nu)."""
        if self._table is not None:
            times, rows = self._table
            if self._trim_rows is None:
                self._trim_rows = np.ascontiguousarray([self.trim(rk[6]) for rk in rows], dtype=float)
                self._rows_idx = np.ascontiguousarray(rows[:, self.idx])
                self._table_times = np.ascontiguousarray(times, dtype=float)
            psi = float(x[PSI])
            r = np.empty((self.N + 1, len(self.idx)))
            ft = np.empty((self.N, self.nu))
            preview_table(self._table_times, self._rows_idx, self._trim_rows, float(t), self._preview,
                          psi if math.isfinite(psi) else 0.0, self._psi_col, r, ft)
            return r, ft
        ts = t + self.dt * np.arange(self.N + 1)
        r = None
        if self._reference_array is not None:
            try:
                r = np.zeros((self.N + 1, 12))
                for k, v in self._reference_array(ts).items():
                    r[:, STATE_INDEX[_ALIASES.get(k, k)]] = v
            except (KeyError, TypeError, ValueError):
                self._reference_array, r = None, None
        if r is None:
            r = np.array([self.reference(tk) for tk in ts])
        psi = x[PSI] if np.isfinite(x[PSI]) else 0.0
        r[:, PSI] = psi + wrap_angle(r[:, PSI] - psi)
        ftrim = np.array([self.trim(rk[6]) for rk in r[:-1]]) if np.any(r[:-1, 6] != r[0, 6]) \
            else np.tile(self.trim(r[0, 6]), (self.N, 1))
        return r[:, self.idx], ftrim

    def trim(self, surge):
        """Trim thrusts (N) at surge speed ``surge`` (m/s), cached."""
        f = self._trim_cache.get(surge)
        if f is None:
            x = np.zeros(12)
            x[6] = surge
            f = self._trim_cache[surge] = np.clip(trim_thrust(self.params, x), self.f_min, self.f_max)
        return f

    # -- fallback -----------------------------------------------------------------------------------
    def _fallback(self, t, x, reason):
        self.stats["fallbacks"] += 1
        n = self.stats["fallbacks"]
        if self._plan is not None and self._plan_age + 1 < len(self._plan):
            self._plan_age += 1
            f = self._plan[self._plan_age]
            kind = "shifted previous solution"
        else:
            try:
                f = self.trim(float(self.reference(t)[6]))
                kind = "trim thrust"
            except Exception as exc:  # noqa: BLE001 - a broken reference must not stop the loop; reported below
                f = np.zeros(self.nu)
                kind = f"zero thrust; trim failed: {type(exc).__name__}: {exc}"
        self.last_status = f"fallback ({kind}): {reason}"
        if n == 1 or n % 100 == 0:
            warnings.warn(f"{type(self).__name__} at t = {t:.3f} s: {self.last_status} (fallback #{n})",
                          RuntimeWarning, stacklevel=3)
        return np.clip(np.nan_to_num(f), self.f_min, self.f_max)

    def _finish(self, t0, f, status, info_time=np.nan, iters=0):
        self.stats["status"] = self.last_status = status
        self.stats["solve_time_s"] = info_time
        self.stats["iterations"] = iters
        self.solve_times.append(info_time)
        dtc = time.perf_counter() - t0
        self.stats["call_time_s"] = dtc
        self.call_times.append(dtc)
        self.last_command = f
        return f

    def reset(self):
        """Forget the warm start, the previous plan and the QP solver's iterates: a design flown again (compare
        flies one design on every plant) starts like a fresh one."""
        self._plan = None
        self._plan_age = 0
        self.last_command = None
        self._forget_solver_iterates()

    def _forget_solver_iterates(self):
        """Reset the iterates / working sets of every QP backend this controller holds."""
        for qp in (getattr(self, "qp", None), getattr(self, "dense", None)):
            if qp is not None:
                qp.reset_solver()

    def set_thruster_limits(self, j, lo, hi):
        """Reconfigure after a thruster fault: thruster ``j`` (0-based) can only produce ``[lo, hi]`` N from now on
        (a dead thruster: ``0, 0``; stuck at ``a``: ``a, a``). The prediction model then matches the vehicle, so
        the other thrusters take over what the faulty one no longer does. Applies to the next call."""
        j = int(j)
        if not 0 <= j < self.nu or not lo <= hi:
            raise ValueError(f"thruster index must be in [0, {self.nu}) and lo <= hi; got {j}, [{lo}, {hi}]")
        self.f_min, self.f_max = self.f_min.copy(), self.f_max.copy()
        self.f_min[j], self.f_max[j] = float(lo), float(hi)
        qp = getattr(self, "qp", None)
        if qp is not None:
            qp.set_thrust_bounds(j, lo, hi)
        dense = getattr(self, "dense", None)
        if dense is not None:
            dense.set_thrust_bounds(j, lo, hi)
        if getattr(self, "_lbx", None) is not None:
            n0 = 12 * (self.N + 1)
            self._lbx[n0 + j::self.nu], self._ubx[n0 + j::self.nu] = float(lo), float(hi)
        self._trim_cache.clear()
        self._trim_rows = None
        self._plan = None
        self.last_command = None
        for name in ("_z", "_X", "_U"):  # warm starts that assume the old limits
            if hasattr(self, name):
                setattr(self, name, None)
        self._forget_solver_state()

    def _forget_solver_state(self):
        """After a failed solve: drop the shifted trajectories and reset the QP solver's iterates (the plan of
        the last good solve is kept for the fallback)."""
        self.stats["solver_resets"] += 1
        self._forget_solver_iterates()


#: QP backends of :class:`LinearMPC`.
LINEAR_MPC_SOLVERS = ("dense", "osqp")


class LinearMPC(_MPCBase):
    """Linear MPC re-linearised at every call (see the module docstring).

    Parameters
    ----------
    vehicle : Vehicle or PlantParameters
        Design model.
    reference : callable or dict or (12,) array
        ``reference(t)`` -> dict with ``z`` (m), ``psi`` (rad), ``u`` (m/s) (other states 0) or (12,) state.
    dt : float
        Prediction / control step, s (the controller should be called every ``dt``).
    horizon : int
        Number of prediction steps N.
    Q, R : optional
        State weights (scalar, (12,), (12, 12) or dict of state names merged into the defaults) and
        thrust weights (scalar, (n,), (n, n)); defaults :data:`DEFAULT_STATE_WEIGHTS` and
        :data:`DEFAULT_THRUST_WEIGHT`.
    terminal_weight : float
        Q_N = terminal_weight * Q.
    state_bounds : dict, optional
        Hard bounds on predicted states, e.g. ``{"z": (0.0, 10.0)}`` (m).
    settings : OSQPSettings, optional
        Of the OSQP solver (the ``osqp`` backend, and the ``dense`` backend's fallback).
    relinearize : bool
        Re-linearise at every call (default) or keep the model of the first call.
    compile : bool
        Call the linearisation through its gcc-compiled C code (cached; else casadi's VM).
    solver : {'dense', 'osqp'}
        ``dense`` (default): the same QP condensed to the thrusts (states eliminated,
        :class:`udrobot_ctrl.control.fastpath.CondensedMPCQP`), solved exactly by an active-set method
        warm-started from the shifted previous working set (DAQP when ``state_bounds`` add general
        constraints); a failed or infeasible solve is handed to OSQP on the sparse QP (counted in
        ``stats['fast_fallbacks']``, its reason in ``stats['fast_failure']``). ``osqp``: the sparse QP on
        OSQP only (the reference).
    """

    def __init__(self, vehicle, reference, dt=0.05, horizon=20, Q=None, R=None, terminal_weight=10.0,
                 state_bounds=None, settings=None, relinearize=True, compile=True, solver="dense"):
        super().__init__(vehicle, reference, dt, horizon, Q, R, terminal_weight, state_bounds, settings, compile)
        if solver not in LINEAR_MPC_SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(LINEAR_MPC_SOLVERS)}, got {solver!r}")
        self.solver = solver
        self.relinearize = relinearize
        self.affine = CompiledFunction(affine_model_function(self.params, self.dt, self.idx), self.params, self.dt,
                                       tuple(int(i) for i in self.idx), compile=compile)
        self.qp = SparseMPCQP(len(self.idx), self.nu, self.N, self.Q, self.QN, self.R, self.f_min, self.f_max,
                              self.state_bounds, self.settings)
        self.dense = CondensedMPCQP(len(self.idx), self.nu, self.N, self.Q, self.QN, self.R, self.f_min,
                                    self.f_max, self.state_bounds) if solver == "dense" else None
        self.stats.update(fast_fallbacks=0, fast_failure="")
        self._z = None
        self._model = None

    def linear_model(self, x, f):
        """Reduced (A, B, c) with x_next ~ A x + B f + c, exact at (x, f)."""
        M = self._affine(x, f)
        nx = len(self.idx)
        return M[:, :nx], M[:, nx:nx + self.nu], M[:, -1]

    def _affine(self, x, f):
        """``[A | B | c]`` (nx, nx + nu + 1), a copy (the compiled function's buffer is reused)."""
        return self._affine_transposed(x, f)[0].T

    def _affine_transposed(self, x, f):
        """``[A | B | c]'`` as (1, nx + nu + 1, nx), C-contiguous: the memory order of the compiled function's
        column-major output (one copy, no transposition)."""
        self.affine(x, f)
        nx = len(self.idx)
        return self.affine.output_buffers[0].reshape(1, nx + self.nu + 1, nx).copy()

    def _operating_point(self, t, x):
        xr, ftrim = self.references(t, x)
        f_op = self.last_command if self.last_command is not None else ftrim[0]
        if self._model is None or self.relinearize:
            self._model_T = self._affine_transposed(x, f_op)
            self._model = self._model_T[0].T  # (nx, nx + nu + 1) view
        return xr, ftrim

    def _update_sparse(self, x, xr, ftrim):
        nx = len(self.idx)
        M = self._model
        self.qp.update(M[:, :nx], M[:, nx:nx + self.nu], M[:, -1], x[self.idx], xr, ftrim)

    def build_qp(self, t, x):
        """Update the QP of the configured backend for state x at time t (used by the controller and by the
        bench's exact reference); returns the references (N+1, nx) and trim thrusts (N, nu)."""
        xr, ftrim = self._operating_point(t, x)
        if self.dense is not None:
            self.dense.update_transposed(self._model_T, x[self.idx], xr, ftrim)
        else:
            self._update_sparse(x, xr, ftrim)
        return xr, ftrim

    def __call__(self, t, x):
        t0 = time.perf_counter()
        x = np.asarray(x, dtype=float).reshape(-1)
        self.stats["solves"] += 1
        if x.shape != (12,) or not np.all(np.abs(x) <= STATE_LIMITS):
            bad = implausible_state(x)
            if bad is not None:  # rejected before it reaches the solver: nothing to recover from afterwards
                return self._finish(t0, self._fallback(t, np.zeros(12), bad), self.last_status)
        try:
            xr, ftrim = self.build_qp(t, x)
            if self.dense is not None:
                sol = self.dense.solve()
                if sol.U is not None:
                    self._z = None
                    self._plan, self._plan_age = sol.U, 0
                    f = np.minimum(np.maximum(sol.U[0], self.f_min), self.f_max)  # np.clip without its overhead
                    return self._finish(t0, f, "solved", sol.solve_time, sol.iterations)
                self.stats["fast_fallbacks"] += 1
                self.stats["fast_failure"] = f"t = {t:.3f} s: {sol.status}"
                self._update_sparse(x, xr, ftrim)
            warm = None
            if self._z is not None:
                X, U = self.qp.split(self._z)
                warm = self.qp.stack(np.vstack([X[1:], X[-1:]]), np.vstack([U[1:], U[-1:]]))
            status, z, info = self.qp.solve(warm)
        except Exception as exc:  # noqa: BLE001 - never throw in the loop: falls back, reported in last_status
            self._z = None
            self._forget_solver_state()
            return self._finish(t0, self._fallback(t, x, f"{type(exc).__name__}: {exc}"), self.last_status)
        if z is None:
            self._z = None
            self._forget_solver_state()
            return self._finish(t0, self._fallback(t, x, f"OSQP status {status!r}"), self.last_status,
                                info.solve_time, info.iter)
        self._z = z
        _, U = self.qp.split(z)
        self._plan, self._plan_age = U.copy(), 0
        f = np.clip(U[0], self.f_min, self.f_max)
        if self.dense is not None:
            status = f"{status} (OSQP fallback: {self.stats['fast_failure']})"
        return self._finish(t0, f, status, info.solve_time, info.iter)


class NonlinearMPC(_MPCBase):
    """Nonlinear MPC by multiple shooting on the RK4-discretised casadi plant.

    Parameters
    ----------
    vehicle : Vehicle or PlantParameters
        Design model.
    reference : callable or dict or (12,) array
        ``reference(t)`` -> dict with ``z`` (m), ``psi`` (rad), ``u`` (m/s) (other states 0) or (12,) state.
    dt : float
        Prediction / control step, s (the controller should be called every ``dt``).
    horizon : int
        Number of prediction steps N.
    Q, R : optional
        State and thrust weights, as for :class:`LinearMPC`.
    terminal_weight : float
        Q_N = terminal_weight * Q.
    state_bounds : dict, optional
        Hard bounds on predicted states, e.g. ``{"z": (0.0, 10.0)}`` (m).
    settings : OSQPSettings, optional
        Of the OSQP solver.
    compile : bool
        Call the casadi functions through their gcc-compiled C code (cached; else casadi's VM).
    method : {'rti', 'ipopt'}
        ``rti``: real-time-iteration SQP (Gauss-Newton QP, its data by one compiled casadi function mapped over
        the horizon); ``ipopt``: full NLP with ipopt (reference).
    solver : {'dense', 'osqp'}
        QP backend of the RTI path. ``dense`` (default): the Gauss-Newton QP (one affine model per stage, thrust
        limits) solved exactly by the Riccati active set of
        :class:`udrobot_ctrl.control.fastpath.CondensedMPCQP`, warm-started from the shifted working set; a failed
        solve is handed to OSQP (``stats['fast_fallbacks']``). ``osqp``: the sparse QP on OSQP, the reference
        (also used whenever ``state_bounds`` are given).
    sqp_iterations : int
        SQP iterations per call on the RTI path (1 = RTI).
    ipopt_options : dict, optional
        Extra ipopt options (e.g. ``{"max_iter": 100}``).
    """

    def __init__(self, vehicle, reference, dt=0.05, horizon=20, Q=None, R=None, terminal_weight=10.0,
                 state_bounds=None, settings=None, method="rti", sqp_iterations=1, ipopt_options=None,
                 compile=True, solver="dense"):
        super().__init__(vehicle, reference, dt, horizon, Q, R, terminal_weight, state_bounds, settings, compile)
        if method not in ("rti", "ipopt"):
            raise ValueError(f"method must be 'rti' or 'ipopt', got {method!r}")
        if solver not in LINEAR_MPC_SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(LINEAR_MPC_SOLVERS)}, got {solver!r}")
        self.method = method
        self.solver = solver
        self.sqp_iterations = max(1, int(sqp_iterations))
        self._X = None  # full 12-state shooting nodes (N+1, 12)
        self._U = None
        self.dense = None
        self.stats.update(fast_fallbacks=0, fast_failure="")
        if method == "rti":
            # the QP data of every stage, [A_k | B_k | c_k] on the reduced states, by one compiled function
            self.rti_model = CompiledFunction(
                affine_model_function(self.params, self.dt, self.idx).map(self.N), self.params, self.dt,
                tuple(int(i) for i in self.idx), "map", self.N, compile=compile)
            self.qp = SparseMPCQP(len(self.idx), self.nu, self.N, self.Q, self.QN, self.R, self.f_min, self.f_max,
                                  self.state_bounds, self.settings)
            if solver == "dense" and not self.state_bounds:
                self.dense = CondensedMPCQP(len(self.idx), self.nu, self.N, self.Q, self.QN, self.R, self.f_min,
                                            self.f_max)
        else:
            self._build_nlp(ipopt_options or {})

    # -- ipopt path -----------------------------------------------------------------------------------
    def _build_nlp(self, ipopt_options):
        N, nu = self.N, self.nu
        F = rk4_step_function(self.params, self.dt, "thrust")
        X = ca.MX.sym("X", 12, N + 1)
        U = ca.MX.sym("U", nu, N)
        P = ca.MX.sym("P", 12 + 12 * (N + 1) + nu * N)
        x0 = P[:12]
        Xr = ca.reshape(P[12:12 + 12 * (N + 1)], 12, N + 1)
        Ur = ca.reshape(P[12 + 12 * (N + 1):], nu, N)
        Qf = np.zeros((12, 12))
        Qf[np.ix_(self.idx, self.idx)] = self.Q
        Q, R = ca.DM(Qf), ca.DM(self.R)
        QNf = np.zeros((12, 12))
        QNf[np.ix_(self.idx, self.idx)] = self.QN
        QN = ca.DM(QNf)
        Xn = F.map(N)(X[:, :N], U)
        g = [X[:, 0] - x0, ca.reshape(X[:, 1:] - Xn, -1, 1)]
        J = 0
        for k in range(N):
            e = X[:, k] - Xr[:, k]
            du = U[:, k] - Ur[:, k]
            J += ca.dot(e, Q @ e) + ca.dot(du, R @ du)
        e = X[:, N] - Xr[:, N]
        J += ca.dot(e, QN @ e)
        w = ca.vertcat(ca.reshape(X, -1, 1), ca.reshape(U, -1, 1))
        nlp = {"x": w, "f": J, "g": ca.vertcat(*g), "p": P}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 200,
                "ipopt.tol": 1e-8, "error_on_fail": False}
        opts.update({f"ipopt.{k}" if not k.startswith("ipopt.") else k: v for k, v in ipopt_options.items()})
        self.nlp = ca.nlpsol("nmpc", "ipopt", nlp, opts)
        lbx = np.full((12 * (N + 1) + nu * N,), -np.inf)
        ubx = np.full_like(lbx, np.inf)
        lbx[12 * (N + 1):] = np.tile(self.f_min, N)
        ubx[12 * (N + 1):] = np.tile(self.f_max, N)
        for j, (lo, hi) in self.state_bounds.items():
            s = self.idx[j]
            lbx[12 + s:12 * (N + 1):12] = lo
            ubx[12 + s:12 * (N + 1):12] = hi
        self._lbx, self._ubx = lbx, ubx
        self._ng = 12 * (N + 1)

    def _solve_ipopt(self, t, x):
        N, nu = self.N, self.nu
        xr_red, ftrim = self.references(t, x)
        Xr = np.zeros((N + 1, 12))
        Xr[:, self.idx] = xr_red
        if self._X is None:
            X0, U0 = np.tile(x, (N + 1, 1)), ftrim.copy()
        else:
            X0 = np.vstack([self._X[1:], self._X[-1:]])
            U0 = np.vstack([self._U[1:], self._U[-1:]])
            X0[:, PSI] += 2 * np.pi * np.round((x[PSI] - X0[0, PSI]) / (2 * np.pi))
            X0[0] = x
        w0 = np.concatenate([X0.reshape(-1), U0.reshape(-1)])
        par = np.concatenate([x, Xr.reshape(-1), ftrim.reshape(-1)])
        sol = self.nlp(x0=w0, p=par, lbx=self._lbx, ubx=self._ubx, lbg=0.0, ubg=0.0)
        st = self.nlp.stats()
        status = st.get("return_status", "unknown")
        w = sol["x"].full().ravel()
        if not st.get("success", False) or not np.all(np.isfinite(w)):
            return status, None, None, st.get("t_wall_total", np.nan), st.get("iter_count", 0)
        X = w[:12 * (N + 1)].reshape(N + 1, 12)
        U = w[12 * (N + 1):].reshape(N, nu)
        return status, X, U, st.get("t_wall_total", np.nan), st.get("iter_count", 0)

    # -- RTI path -------------------------------------------------------------------------------------
    def _solve_rti(self, t, x):
        N, idx = self.N, self.idx
        xr, ftrim = self.references(t, x)
        if self._X is None:  # initial guess: hold the state, trim thrust (simulated forward below)
            U = ftrim.copy()
            X = np.empty((N + 1, 12))
            X[0] = x
            for k in range(N):
                X[k + 1] = self.lin(X[k], U[k])[0].full().ravel()
        else:
            X = np.vstack([self._X[1:], self._X[-1:]])
            U = np.vstack([self._U[1:], self._U[-1:]])
            X[:, PSI] += 2 * np.pi * np.round((x[PSI] - X[0, PSI]) / (2 * np.pi))  # heading crossed +-pi
        X[0] = x
        status, info_t, iters = "not solved", 0.0, 0
        nx, nu = len(idx), self.nu
        xb, ub = self.rti_model.input_buffers
        x0 = x[idx]
        for it in range(self.sqp_iterations):
            xb.reshape(N, 12)[:] = X[:N]  # column-major (12, N) inputs: the nodes as rows
            ub.reshape(N, nu)[:] = U
            self.rti_model()
            MT = self.rti_model.output_buffers[0].reshape(N, nx + nu + 1, nx)  # MT[k] = [A_k | B_k | c_k]'
            if self.dense is not None:
                self.dense.update_transposed(MT, x0, xr, ftrim)
                sol = self.dense.solve(shift=it == 0)
                info_t += sol.solve_time
                iters += sol.iterations
                if sol.U is not None:
                    status, U = "solved", sol.U
                    X = self._full_states(x, self.dense.states, U)
                    continue
                self.stats["fast_fallbacks"] += 1
                self.stats["fast_failure"] = f"t = {t:.3f} s: {sol.status}"
            A, B = MT[:, :nx].transpose(0, 2, 1), MT[:, nx:nx + nu].transpose(0, 2, 1)
            self.qp.update(A, B, MT[:, nx + nu], x0, xr, ftrim)
            status, z, info = self.qp.solve(self.qp.stack(X[:, idx], U))
            info_t += info.solve_time
            iters += info.iter
            if z is None:
                return status, None, None, info_t, iters
            Xs, U = self.qp.split(z)
            X = self._full_states(x, Xs, U)
            if self.dense is not None:
                status = f"{status} (OSQP fallback: {self.stats['fast_failure']})"
        return status, X, U, info_t, iters

    def _full_states(self, x, Xs, U):
        """12-state nodes from reduced QP states (x, y integrated by the kinematics when dropped)."""
        if len(self.idx) == 12:
            return Xs.copy()
        X = np.empty((self.N + 1, 12))
        X[:, 2:] = Xs
        X[0, :2] = x[:2]
        c, s = np.cos(Xs[:-1, 3]), np.sin(Xs[:-1, 3])  # planar approximation for the unweighted x, y
        vx = c * Xs[:-1, 4] - s * Xs[:-1, 5]
        vy = s * Xs[:-1, 4] + c * Xs[:-1, 5]
        X[1:, 0] = x[0] + np.cumsum(vx) * self.dt
        X[1:, 1] = x[1] + np.cumsum(vy) * self.dt
        return X

    def __call__(self, t, x):
        t0 = time.perf_counter()
        x = np.asarray(x, dtype=float).reshape(-1)
        self.stats["solves"] += 1
        bad = implausible_state(x)
        if bad is not None:  # rejected before it reaches the solver
            return self._finish(t0, self._fallback(t, np.zeros(12), bad), self.last_status)
        try:
            solve = self._solve_rti if self.method == "rti" else self._solve_ipopt
            status, X, U, st, iters = solve(t, x)
        except Exception as exc:  # noqa: BLE001 - never throw in the loop: falls back, reported in last_status
            self._X = self._U = None
            self._forget_solver_state()
            return self._finish(t0, self._fallback(t, x, f"{type(exc).__name__}: {exc}"), self.last_status)
        if X is None:
            self._X = self._U = None
            self._forget_solver_state()
            return self._finish(t0, self._fallback(t, x, f"solver status {status!r}"), self.last_status, st, iters)
        self._X, self._U = X, U
        self._plan, self._plan_age = U.copy(), 0
        return self._finish(t0, np.clip(U[0], self.f_min, self.f_max), str(status), st, iters)

    def reset(self):
        super().reset()
        self._X = self._U = None
