"""Per-step fast paths of the controllers and estimators: compiled casadi calls and the condensed MPC QP.

* :class:`CompiledFunction`: a casadi Function (the plant's RK4 step and its Jacobians, generated from
  :mod:`udrobot_ctrl.dynamics.equations` through :mod:`udrobot_ctrl.dynamics.plant_casadi`, so there is one
  model) evaluated through its gcc-compiled C code with :mod:`ctypes` on preallocated numpy buffers. casadi's
  own Python call converts every argument and result (~30-40 us for the MPC's linearisation); the direct call
  costs ~2-3 us for the same C code. Falls back to the casadi Function when gcc is missing.
* :class:`CondensedMPCQP`: the linear MPC's tracking QP with the states eliminated (inputs only, ``N nu``
  variables), built by a numba kernel from the time-invariant affine model ``x_{k+1} = A x_k + B f_k + c``
  and solved exactly by an active-set method warm-started with the working set of the shifted previous
  solution: with thrust limits only (box constraints) a block-principal-pivoting active set (numba, one
  Cholesky of the free variables' Hessian per iteration, usually one iteration warm); with state bounds
  (general constraints) DAQP (Arnström et al., IEEE TAC 2022, a dual active-set solver made for MPC).
  Measured (issue 38, N = 20, 4 thrusters): DAQP's ``update`` with a new Hessian refactorises for ~100 us,
  the box solver ~15 us per iteration, so DAQP is kept for the general constraints only.
* Kernels of the EKF update (:func:`ekf_update_all`) and of the fault monitor (:func:`frozen_statistics`,
  :func:`propagate_windows`): the per-step arithmetic of :mod:`udrobot_ctrl.control.ekf` and
  :mod:`udrobot_ctrl.control.faults` without Python overhead.

Condensing (``G_m = A^m B``, ``Qw_k = Q`` for ``k < N``, ``Q_N`` at ``k = N``)::

    H_ij = sum_{k >= max(i, j)} G_{k-i}' Qw_{k+1} G_{k-j} + R delta_ij     (i, j = 0 .. N-1)
    g_j  = B' lambda_{j+1} - R f_trim_j,   lambda_N = Q_N e_N,  lambda_k = Q e_k + A' lambda_{k+1}

with ``e_k`` the free response (zero inputs) minus the reference. With ``T = [G_0 .. G_{N-1}]' Q [G_0 ..]``
(one BLAS product) the blocks of one diagonal ``d = i - j`` are running sums of ``T[m, m + d]``, so the
Hessian costs one (N nu, nx, N nu) product and N (N + 1) / 2 block additions.
"""
from __future__ import annotations

import ctypes
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from udrobot_ctrl.caches import configure_numba_cache
from udrobot_ctrl.dynamics.fastsim import compile_function, parameter_hash, private_cache_dir, verified_library
from udrobot_ctrl.dynamics.plant import PlantParameters

configure_numba_cache()  # before the decorators below choose their cache folder

import numba  # noqa: E402

try:
    import daqp
except ImportError:  # pragma: no cover - daqp is a dependency; without it state bounds need solver="osqp"
    daqp = None

#: gcc budget for compiling a generated casadi function (s); on timeout casadi's VM is used.
COMPILE_TIMEOUT_S = 30.0
_CASADI_INT = ctypes.c_longlong
#: LLVM fast-math flags of the kernels: reassociation (vectorised reductions) only, so NaN/inf tests stay valid.
_FASTMATH = {"reassoc", "contract"}
#: Largest magnitude accepted in QP data (as the sparse OSQP QP: OSQP treats |values| >= 1e30 as infinite).
QP_DATA_LIMIT = 1e20


class CompiledFunction:
    """A casadi Function called through its compiled C code on preallocated buffers (module docstring).

    Parameters
    ----------
    fun : casadi.Function
        Dense inputs; outputs are densified if needed.
    params : PlantParameters
        Plant the function was built from (part of the cache key).
    *key
        Further cache-key items (time step, horizon, ...), as for :func:`udrobot_ctrl.control.mpc.maybe_compiled`
        (the same key: both share one library).
    compile : bool
        False: always evaluate with casadi (the reference path of the tests).

    Attributes
    ----------
    compiled : bool
        True when the C code is called directly.
    outputs : tuple of ndarray
        Views into the output buffers ((n,) for a column, (n, m) otherwise); overwritten by the next call.
    """

    def __init__(self, fun: ca.Function, params: PlantParameters, *key, compile: bool = True):
        if not all(fun.sparsity_out(i).is_dense() for i in range(fun.n_out())):
            x = [ca.SX.sym(fun.name_in(i), fun.sparsity_in(i)) for i in range(fun.n_in())]
            fun = ca.Function(f"{fun.name()}_dense", x, [ca.densify(o) for o in fun(*x)],
                              fun.name_in(), fun.name_out())
        self.fun = fun
        self.name = fun.name()
        self._in_shapes = [(fun.size1_in(i), fun.size2_in(i)) for i in range(fun.n_in())]
        self._out_shapes = [(fun.size1_out(i), fun.size2_out(i)) for i in range(fun.n_out())]
        self._in = [np.zeros(a * b) for a, b in self._in_shapes]
        self._out = [np.zeros(a * b) for a, b in self._out_shapes]
        self.outputs = tuple(buf if b == 1 else buf.reshape(b, a).T for buf, (a, b) in zip(self._out,
                                                                                          self._out_shapes))
        self.compiled = False
        self._c = None
        if compile:
            self._load(params, key)

    def _load(self, params, key):
        hkey = parameter_hash(params, self.name, *key)
        try:
            if compile_function(self.fun, hkey, timeout=COMPILE_TIMEOUT_S) is None:
                return
            lib_path = private_cache_dir() / f"{self.name}_{hkey}.so"
            if verified_library(lib_path) is not None:
                return
            lib = ctypes.CDLL(str(lib_path))
        except (OSError, RuntimeError):  # cache folder unusable, codegen/load failed: compiling is optional
            return
        sizes = [(_CASADI_INT * 1)() for _ in range(4)]
        work = getattr(lib, f"{self.name}_work")
        work.argtypes = [ctypes.c_void_p] * 4
        work.restype = ctypes.c_int
        if work(*[ctypes.addressof(s) for s in sizes]) != 0:
            return
        n_arg, n_res, n_iw, n_w = (int(s[0]) for s in sizes)
        self._args = (ctypes.c_void_p * max(n_arg, len(self._in)))(*[b.ctypes.data for b in self._in])
        self._res = (ctypes.c_void_p * max(n_res, len(self._out)))(*[b.ctypes.data for b in self._out])
        self._iw = np.zeros(max(n_iw, 1), np.int64)
        self._w = np.zeros(max(n_w, 1))
        fn = getattr(lib, self.name)
        fn.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        fn.restype = ctypes.c_int
        self._lib = lib  # keeps the library loaded
        self._c = fn
        self._c_args = (ctypes.addressof(self._args), ctypes.addressof(self._res), self._iw.ctypes.data,
                        self._w.ctypes.data, 0)
        self.compiled = True

    def __call__(self, *args):
        """Evaluate at ``args`` (array_like, column-major for matrices); returns :attr:`outputs` (views)."""
        for buf, a, (r, c) in zip(self._in, args, self._in_shapes):
            if c == 1:
                buf[:] = a
            else:
                buf.reshape(c, r).T[:] = a
        if self._c is not None:
            if self._c(*self._c_args) != 0:
                raise RuntimeError(f"compiled casadi function {self.name} failed")
        else:
            ins = [buf.reshape(c, r).T for buf, (r, c) in zip(self._in, self._in_shapes)]
            res = self.fun.call(ins)
            for buf, o, (r, c) in zip(self._out, res, self._out_shapes):
                buf.reshape(c, r).T[:] = np.asarray(o.full() if hasattr(o, "full") else o).reshape(r, c)
        return self.outputs


# ----------------------------------------------------------------------------- condensed MPC QP
@numba.njit(cache=True, fastmath=_FASTMATH)
def _condense(M, x0, Xr, Ft, Q, QN, R, Lq, tn_scale, bnd_state, bnd_lo, bnd_hi, Gm, H, g, Ab, ab_lo, ab_hi,
              Xf, limit, full):
    """Fill ``H`` (n, n), ``g`` (n,) and the state-bound rows ``Ab``, ``ab_lo``, ``ab_hi`` of the condensed QP.

    ``H`` is written on and below the diagonal only unless ``full`` (the transposed, strided writes of the
    upper triangle cost as much as the rest of the condensing; the box solver reads the lower triangle).

    ``Lq``: factor with ``Q = Lq' Lq`` (rows of zero weight dropped). ``tn_scale``: Q_N = (1 + tn_scale) Q
    when finite (the terminal term reuses the stage product), else it is formed from ``QN - Q``. Returns False
    (nothing usable) if any data is non-finite or ``>= limit`` in magnitude."""
    N, nu = Ft.shape
    nx = M.shape[0]
    A, B, c = M[:, :nx], M[:, nx:nx + nu], M[:, nx + nu]
    if not (np.all(np.abs(M) < limit) and np.all(np.abs(x0) < limit) and np.all(np.abs(Xr) < limit)
            and np.all(np.abs(Ft) < limit)):
        return False
    # G_m = A^m B, stored as column blocks of Gm (nx, N nu)
    for i in range(nx):
        for j in range(nu):
            Gm[i, j] = B[i, j]
    for m in range(1, N):
        for i in range(nx):
            for j in range(nu):
                s = 0.0
                for k in range(nx):
                    s += A[i, k] * Gm[k, (m - 1) * nu + j]
                Gm[i, m * nu + j] = s
    GL = Lq @ Gm  # Q = Lq' Lq
    T = GL.T @ GL
    scaled = np.isfinite(tn_scale)
    TN = T if scaled else Gm.T @ ((QN - Q) @ Gm)
    tn = tn_scale if scaled else 1.0
    n = N * nu
    acc = np.zeros((nu, nu))
    for d in range(N):
        acc[:] = 0.0
        for i in range(N - 1, d - 1, -1):
            a0 = (N - 1 - i) * nu
            b0 = (N - 1 - i + d) * nu
            for p in range(nu):
                for q in range(nu):
                    acc[p, q] += T[a0 + p, b0 + q]
            j = i - d
            for p in range(nu):
                for q in range(nu):
                    h = acc[p, q] + tn * TN[a0 + p, b0 + q]
                    if d == 0:
                        h += R[p, q]
                    H[i * nu + p, j * nu + q] = h
                    if full or d == 0:
                        H[j * nu + q, i * nu + p] = h
    # free response and gradient
    Xf[0, :] = x0
    for k in range(N):
        for i in range(nx):
            s = c[i]
            for m in range(nx):
                s += A[i, m] * Xf[k, m]
            Xf[k + 1, i] = s
    lam = np.empty(nx)
    tmp = np.empty(nx)
    for i in range(nx):
        s = 0.0
        for m in range(nx):
            s += QN[i, m] * (Xf[N, m] - Xr[N, m])
        lam[i] = s
    for k in range(N, 0, -1):  # g_{k-1} = B' lambda_k - R ft_{k-1}; lambda_{k-1} = Q e_{k-1} + A' lambda_k
        for j in range(nu):
            s = 0.0
            for i in range(nx):
                s += B[i, j] * lam[i]
            for q in range(nu):
                s -= R[j, q] * Ft[k - 1, q]
            g[(k - 1) * nu + j] = s
        if k > 1:
            for i in range(nx):
                s = 0.0
                for m in range(nx):
                    s += A[m, i] * lam[m] + Q[i, m] * (Xf[k - 1, m] - Xr[k - 1, m])
                tmp[i] = s
            lam[:] = tmp
    # state bounds: x_k[s] = Xf[k, s] + sum_{i < k} G_{k-1-i}[s, :] f_i, k = 1 .. N
    nb = bnd_state.shape[0]
    for k in range(1, N + 1):
        for b in range(nb):
            r = (k - 1) * nb + b
            s = bnd_state[b]
            for col in range(n):
                Ab[r, col] = 0.0
            for i in range(k):
                for j in range(nu):
                    Ab[r, i * nu + j] = Gm[s, (k - 1 - i) * nu + j]
            ab_lo[r] = bnd_lo[b] - Xf[k, s]
            ab_hi[r] = bnd_hi[b] - Xf[k, s]
    for i in range(n):  # H is symmetric: its lower triangle
        for j in range(i + 1):
            if not abs(H[i, j]) < limit:
                return False
        if not abs(g[i]) < limit:
            return False
    return True


@numba.njit(cache=True, fastmath=_FASTMATH)
def _cholesky_solve(H, free, nf, rhs, L, y, out):
    """Solve ``H[free, free] out = rhs`` (first ``nf`` entries) by Cholesky into ``L``; False if not positive
    definite."""
    for j in range(nf):
        fj = free[j]
        s = H[fj, fj]
        for p in range(j):
            s -= L[j, p] * L[j, p]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        L[j, j] = d
        inv = 1.0 / d
        for i in range(j + 1, nf):
            s = H[free[i], fj]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            L[i, j] = s * inv
    for i in range(nf):
        s = rhs[i]
        for p in range(i):
            s -= L[i, p] * y[p]
        y[i] = s / L[i, i]
    for i in range(nf - 1, -1, -1):
        s = y[i]
        for p in range(i + 1, nf):
            s -= L[p, i] * out[p]
        out[i] = s / L[i, i]
    return True


@numba.njit(cache=True, fastmath=_FASTMATH)
def _box_qp(H, g, lo, hi, state, u, max_iter):
    """``min 0.5 u' H u + g' u`` s.t. ``lo <= u <= hi`` (H positive definite, read on and below its diagonal)
    by block principal pivoting.

    ``state`` (n,) int8: 0 free, 1 at the upper bound, -1 at the lower bound; on entry the warm-start
    working set, on exit the optimal one. Júdice-Pires block pivoting: every variable violating its KKT
    condition (a free one outside its bounds, a bound one whose gradient pushes it inwards) changes set at
    once; when the number of violations has not decreased for 3 iterations, only the violating variable of
    largest index changes (Murty's rule, finite for positive definite H) until it has. Each iteration solves
    the free variables' equations exactly (Cholesky), so the result is the exact minimiser.
    Returns the number of iterations, or -1 (iteration limit or a numerical failure).
    """
    n = g.size
    free = np.empty(n, np.int64)
    rhs = np.empty(n)
    y = np.empty(n)
    uf = np.empty(n)
    L = np.empty((n, n))
    gscale = 1.0
    for i in range(n):
        gscale = max(gscale, abs(g[i]))
        if lo[i] == hi[i]:
            state[i] = 1  # a fixed variable (a stuck thruster) is never freed
    best, stall = n + 1, 0
    for it in range(max_iter):
        nf = 0
        for i in range(n):
            if state[i] == 0:
                free[nf] = i
                nf += 1
            elif state[i] > 0:
                u[i] = hi[i]
            else:
                u[i] = lo[i]
        for a in range(nf):
            i = free[a]
            s = -g[i]
            for j in range(n):
                if state[j] != 0:
                    s -= (H[i, j] if j <= i else H[j, i]) * u[j]
            rhs[a] = s
        if not _cholesky_solve(H, free, nf, rhs, L, y, uf):
            return -1
        for a in range(nf):
            u[free[a]] = uf[a]
        n_bad, last = 0, -1
        for i in range(n):
            tol = 1e-10 * (1.0 + abs(lo[i]) + abs(hi[i]))
            if state[i] == 0:
                bad = u[i] > hi[i] + tol or u[i] < lo[i] - tol
            elif lo[i] == hi[i]:
                bad = False
            else:
                gr = g[i]
                for j in range(i + 1):
                    gr += H[i, j] * u[j]
                for j in range(i + 1, n):
                    gr += H[j, i] * u[j]
                dtol = 1e-10 * gscale
                bad = gr > dtol if state[i] > 0 else gr < -dtol
            if bad:
                n_bad += 1
                last = i
        if n_bad == 0:
            for i in range(n):
                u[i] = min(max(u[i], lo[i]), hi[i])
            return it + 1
        if n_bad < best:
            best, stall = n_bad, 0
        else:
            stall += 1
        for i in range(n):
            if stall >= 3 and i != last:
                continue
            if state[i] == 0:
                if u[i] > hi[i] + 1e-10 * (1.0 + abs(lo[i]) + abs(hi[i])):
                    state[i] = 1
                elif u[i] < lo[i] - 1e-10 * (1.0 + abs(lo[i]) + abs(hi[i])):
                    state[i] = -1
            elif lo[i] != hi[i]:
                gr = g[i]
                for j in range(i + 1):
                    gr += H[i, j] * u[j]
                for j in range(i + 1, n):
                    gr += H[j, i] * u[j]
                if (gr > 1e-10 * gscale) if state[i] > 0 else (gr < -1e-10 * gscale):
                    state[i] = 0
    return -1


def _factor(W):
    """``L`` (r, n) with ``W = L' L`` for a symmetric positive semi-definite ``W`` (zero-weight directions dropped)."""
    w, V = np.linalg.eigh(0.5 * (W + W.T))
    if np.any(w < -1e-12 * max(1.0, float(np.max(np.abs(w))))):
        raise ValueError("MPC weight matrices must be positive semi-definite")
    keep = w > 1e-14 * max(1.0, float(np.max(np.abs(w))))
    return np.ascontiguousarray((V[:, keep] * np.sqrt(w[keep])).T)


@dataclass(frozen=True)
class DenseSolve:
    """Result of one :meth:`CondensedMPCQP.solve`.

    Attributes
    ----------
    status : str
        ``"solved"`` or why not (DAQP exit flag).
    U : ndarray or None
        Thrust plan (N, nu), N; None when not solved.
    solve_time : float
        DAQP's reported solve time, s.
    iterations : int
        Active-set iterations.
    """

    status: str
    U: np.ndarray | None
    solve_time: float
    iterations: int


_DAQP_FLAGS = {-1: "infeasible", -2: "cycling", -3: "unbounded", -4: "iteration limit", -5: "nonconvex",
               -6: "overdetermined initial active set", 2: "soft optimal"}


class CondensedMPCQP:
    """The tracking QP of :class:`udrobot_ctrl.control.mpc.SparseMPCQP` with the states eliminated, on DAQP.

    Same problem (same weights, thrust limits, optional state bounds on ``x_1 .. x_N``), restricted to the
    time-invariant affine model of the linear MPC; the minimiser is the same (DAQP solves to machine accuracy).

    Parameters
    ----------
    nx, nu, N : int
        Reduced state size, thrusters, horizon.
    Q, QN, R : ndarray
        Stage, terminal and thrust weights ((nx, nx), (nx, nx), (nu, nu); 1/unit^2).
    f_min, f_max : (nu,) ndarray
        Thrust limits, N.
    state_bounds : dict, optional
        Reduced state position -> (lower, upper) bounds (m, rad, m/s, rad/s).
    """

    def __init__(self, nx, nu, N, Q, QN, R, f_min, f_max, state_bounds=None):
        self.nx, self.nu, self.N = int(nx), int(nu), int(N)
        self.n = self.N * self.nu
        self.Q, self.QN, self.R = (np.ascontiguousarray(a, float) for a in (Q, QN, R))
        qd = np.sum(self.Q * self.Q)
        s = float(np.sum(self.QN * self.Q) / qd) if qd > 0 else np.nan
        self._tn_scale = s - 1.0 if np.isfinite(s) and np.allclose(self.QN, s * self.Q, rtol=1e-14, atol=0) \
            else np.nan
        self._Lq = _factor(self.Q)
        sb = state_bounds or {}
        self._bnd_state = np.array(list(sb), np.int64)
        self._bnd_lo = np.array([b[0] for b in sb.values()], float)
        self._bnd_hi = np.array([b[1] for b in sb.values()], float)
        self.m_general = self.N * len(sb)
        if self.m_general and daqp is None:  # pragma: no cover - daqp is a dependency
            raise ImportError("state bounds on the dense MPC backend need the daqp package (pip install daqp)")
        self._Gm = np.zeros((self.nx, self.n))
        self.H = np.zeros((self.n, self.n))
        self.g = np.zeros(self.n)
        self._Ab = np.zeros((self.m_general, self.n))
        self._ab_lo = np.zeros(self.m_general)
        self._ab_hi = np.zeros(self.m_general)
        self._Xf = np.zeros((self.N + 1, self.nx))
        self.lo = np.tile(np.asarray(f_min, float), self.N)
        self.hi = np.tile(np.asarray(f_max, float), self.N)
        self._bu = np.concatenate([self.hi, self._ab_hi])
        self._bl = np.concatenate([self.lo, self._ab_lo])
        self._sense = np.zeros(self.n + self.m_general, np.int32)
        self._state = np.zeros(self.n, np.int8)  # working set: 0 free, 1 upper, -1 lower bound
        self._have_state = False
        self._u = np.zeros(self.n)
        self.max_iter = 4 * self.n
        self._model = None
        self._ready = False

    def set_thrust_bounds(self, j, lo, hi):
        """Bounds of thruster ``j`` (N) at every stage (``lo == hi``: a thruster stuck at that thrust)."""
        self.lo[int(j)::self.nu], self.hi[int(j)::self.nu] = float(lo), float(hi)
        self.reset_solver()

    def reset_solver(self):
        """Forget the warm start (the next solve starts from an empty working set)."""
        self._model = None
        self._have_state = False

    def update(self, ABc, x0, xref, uref):
        """Condense for the model ``x_{k+1} = A x_k + B f_k + c`` (reduced states; ``ABc = [A | B | c]``,
        (nx, nx + nu + 1)), initial state ``x0`` (nx,), references ``xref`` (N+1, nx) and trim thrusts ``uref``
        (N, nu).

        Raises
        ------
        FloatingPointError
            If any of the data is non-finite or larger than :data:`QP_DATA_LIMIT` (nothing is changed).
        """
        ok = _condense(np.ascontiguousarray(ABc, float), np.ascontiguousarray(x0, float),
                       np.ascontiguousarray(xref, float), np.ascontiguousarray(uref, float), self.Q, self.QN, self.R,
                       self._Lq, self._tn_scale, self._bnd_state, self._bnd_lo, self._bnd_hi, self._Gm, self.H,
                       self.g, self._Ab, self._ab_lo, self._ab_hi, self._Xf, QP_DATA_LIMIT, self.m_general > 0)
        if not ok:
            self._ready = False
            raise FloatingPointError(f"QP data is non-finite or larger than {QP_DATA_LIMIT:.0e}")
        self._ready = True

    def solve(self, shift=True) -> DenseSolve:
        """Solve the condensed QP from the working set of the previous solve, shifted by one stage when ``shift``
        (the last stage repeated): the active-set counterpart of OSQP's shifted warm start."""
        if not self._ready:
            return DenseSolve("no data", None, 0.0, 0)
        n, nu = self.n, self.nu
        state = self._state
        if self._have_state and shift:
            state[:n - nu] = state[nu:].copy()
        elif not self._have_state:
            state[:] = 0
        if self.m_general == 0:
            return self._solve_box()
        return self._solve_daqp()

    def _solve_box(self):
        t0 = time.perf_counter()
        it = _box_qp(self.H, self.g, self.lo, self.hi, self._state, self._u, self.max_iter)
        dt = time.perf_counter() - t0
        if it < 0 or not np.all(np.isfinite(self._u)):
            self._have_state = False
            return DenseSolve("active set failed (iteration limit or not positive definite)", None, dt, max(it, 0))
        self._have_state = True
        return DenseSolve("solved", self._u.reshape(self.N, self.nu).copy(), dt, it)

    def _solve_daqp(self):
        n = self.n
        self._bu[:n], self._bl[:n] = self.hi, self.lo
        self._bu[n:], self._bl[n:] = self._ab_hi, self._ab_lo
        sense = self._sense
        sense[:] = 0
        sense[:n][self._state > 0] = 1
        sense[:n][self._state < 0] = 3
        if self._model is None:
            self._model = daqp.Model()
            flag, _ = self._model.setup(self.H, self.g, self._Ab, self._bu, self._bl, sense)
            if flag < 0:
                self._model = None
                return DenseSolve(f"DAQP setup failed (exit flag {flag})", None, 0.0, 0)
        else:
            self._model.update(H=self.H, f=self.g, A=self._Ab, bupper=self._bu, blower=self._bl, sense=sense)
        x, _, flag, info = self._model.solve()
        if flag != 1 or not np.all(np.isfinite(x)):
            self._model = None  # a failed workspace is not reused
            self._have_state = False
            why = _DAQP_FLAGS.get(int(flag), "non-finite solution" if flag == 1 else "failed")
            return DenseSolve(f"DAQP {why} (exit flag {flag})", None, float(info.get("solve_time", 0.0)),
                              int(info.get("iterations", 0)))
        lam = np.asarray(info["lam"])[:n]
        self._state[:] = np.where(lam > 0, 1, np.where(lam < 0, -1, 0))
        self._have_state = True
        return DenseSolve("solved", np.array(x).reshape(self.N, self.nu), float(info["solve_time"]),
                          int(info["iterations"]))


# ----------------------------------------------------------------------------- EKF update
@numba.njit(cache=True)
def ekf_update_all(x, P, z, ch, st, ang, r, gate, last_value, last_accepted, n_samples, run, run_since):
    """The EKF update when every present channel passes the gate: the arithmetic of
    :meth:`udrobot_ctrl.control.ekf.UDrobotEKF.update` (wrapped innovation, ``S = P[st, st] + diag(r)``, joint NIS
    against ``gate``, gain and Joseph form), in place on ``x`` (12,) and ``P`` (12, 12), with the per-channel
    bookkeeping (latest value, samples, rejection runs). Plain loops (sizes <= 13; no BLAS/LAPACK calls, which
    would cost seconds of numba compilation on a fresh machine); ``S^-1`` by Cholesky (S is positive definite).

    Returns ``(accepted, nis, y, S, SI, K)``. When the joint NIS exceeds ``gate`` nothing is touched
    (``accepted`` False) and the caller gates sensor by sensor; a non-positive-definite S also returns False
    (the caller's numpy path then decides)."""
    m = ch.size
    y = np.empty(m)
    S = np.empty((m, m))
    SI = np.zeros((m, m))
    K = np.zeros((12, m))
    for i in range(m):
        v = z[ch[i]] - x[st[i]]
        if ang[i]:
            v = (v + np.pi) % (2 * np.pi) - np.pi
        y[i] = v
        for j in range(m):
            S[i, j] = P[st[i], st[j]]
        S[i, i] += r[i]
    # S^-1 = L^-T L^-1 with S = L L'
    L = np.zeros((m, m))
    for j in range(m):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False, np.nan, y, S, SI, K
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, m):
            v = S[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            L[i, j] = v / L[j, j]
    Li = np.zeros((m, m))
    for j in range(m):
        Li[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, m):
            v = 0.0
            for k in range(j, i):
                v -= L[i, k] * Li[k, j]
            Li[i, j] = v / L[i, i]
    for i in range(m):
        for j in range(i + 1):
            v = 0.0
            for k in range(i, m):
                v += Li[k, i] * Li[k, j]
            SI[i, j] = v
            SI[j, i] = v
    SIy = np.zeros(m)
    for i in range(m):
        for j in range(m):
            SIy[i] += SI[i, j] * y[j]
    nis = 0.0
    for i in range(m):
        nis += y[i] * SIy[i]
    if not nis <= gate:
        return False, nis, y, S, SI, K
    for i in range(m):
        last_value[ch[i]] = z[ch[i]]
        n_samples[ch[i]] += 1
        run[ch[i]] = 0
        run_since[ch[i]] = np.nan
        last_accepted[ch[i]] = z[ch[i]]
    for a in range(12):  # K = P[:, st] S^-1
        for j in range(m):
            v = 0.0
            for i in range(m):
                v += P[a, st[i]] * SI[i, j]
            K[a, j] = v
    # Joseph form: (I - K H) P (I - K H)' + K diag(r) K', with H the rows e_st
    I_KH = np.eye(12)
    for a in range(12):
        for i in range(m):
            I_KH[a, st[i]] -= K[a, i]
    T = np.zeros((12, 12))
    for a in range(12):
        for b in range(12):
            v = 0.0
            for c in range(12):
                v += I_KH[a, c] * P[c, b]
            T[a, b] = v
    Pn = np.zeros((12, 12))
    for a in range(12):
        for b in range(12):
            v = 0.0
            for c in range(12):
                v += T[a, c] * I_KH[b, c]
            for i in range(m):
                v += K[a, i] * r[i] * K[b, i]
            Pn[a, b] = v
    for a in range(12):
        for b in range(12):
            P[a, b] = 0.5 * (Pn[a, b] + Pn[b, a])
    for a in range(12):
        v = 0.0
        for i in range(m):
            v += K[a, i] * y[i]
        x[a] += v
    x[5] = (x[5] + np.pi) % (2 * np.pi) - np.pi
    return True, nis, y, S, SI, K


# ----------------------------------------------------------------------------- fault monitor
@numba.njit(cache=True)
def frozen_statistics(buf, count, z, sigma, angle, frozen, threshold, stats, change):
    """Ring-buffer step of the frozen-sensor test for every channel (see
    :class:`udrobot_ctrl.control.faults.FrozenChannelDetector`).

    ``buf`` (channels, n) and ``count`` (channels,) are the ring buffers and sample counts, updated with the
    finite entries of ``z``; ``stats`` receives ``(n - 1) s^2 / sigma^2`` of every channel whose window is full
    and was just sampled (angles unwrapped as :func:`numpy.unwrap`), NaN for the others; ``change`` marks the
    channels whose verdict flips (``frozen`` and above ``threshold``, or live and below). Returns their number."""
    n = buf.shape[1]
    a = np.empty(n)
    n_change = 0
    for i in range(z.size):
        stats[i] = np.nan
        change[i] = False
        if not np.isfinite(z[i]):
            continue
        buf[i, count[i] % n] = z[i]
        count[i] += 1
        if count[i] < n:
            continue
        start = count[i] % n
        for j in range(n):
            a[j] = buf[i, (start + j) % n]
        if angle[i]:
            cum = 0.0
            prev = a[0]
            for j in range(1, n):
                cur = a[j]
                dd = cur - prev
                ddmod = (dd + np.pi) % (2 * np.pi) - np.pi
                if ddmod == -np.pi and dd > 0:
                    ddmod = np.pi
                if abs(dd) >= np.pi:
                    cum += ddmod - dd
                a[j] = cur + cum
                prev = cur
        mean = 0.0
        for j in range(n):
            mean += a[j]
        mean /= n
        ss = 0.0
        for j in range(n):
            ss += (a[j] - mean) ** 2
        stats[i] = ss / sigma[i] ** 2
        change[i] = stats[i] > threshold if frozen[i] else stats[i] < threshold
        if change[i]:
            n_change += 1
    return n_change


@numba.njit(cache=True, fastmath=_FASTMATH)
def propagate_windows(w, k, At, Bt, xn, fc, z, ch, st, angle, x, Phi, G, C, F, E, Z):
    """One step of the open fault-detection windows ``w`` (slots; step counts ``k`` per slot, incremented):
    ``Phi <- A Phi``, ``G <- A G + B``, ``C <- A C + B diag(fc)``, state ``x <- xn`` and the residuals
    ``z[ch] - x[st]`` (angles wrapped) of the channels ``ch``. ``At`` (12 W, 12), ``Bt`` (nu W, 12) and ``xn``
    (12, W) are the mapped linearisation's outputs, transposed (slot s: ``A_s = At[12 s:12 s + 12].T``)."""
    nu = fc.size
    for a in range(w.size):
        s = w[a]
        kk = k[s]
        P0, P1 = Phi[s, kk], Phi[s, kk + 1]
        G0, G1 = G[s, kk], G[s, kk + 1]
        C0, C1 = C[s, kk], C[s, kk + 1]
        for i in range(12):
            x[s, i] = xn[i, s]
            for j in range(12):
                P1[i, j] = 0.0
            for j in range(nu):
                b = Bt[nu * s + j, i]
                G1[i, j] = b
                C1[i, j] = b * fc[j]
            for m in range(12):
                am = At[12 * s + m, i]
                for j in range(12):
                    P1[i, j] += am * P0[m, j]
                for j in range(nu):
                    G1[i, j] += am * G0[m, j]
                    C1[i, j] += am * C0[m, j]
        for j in range(nu):
            F[s, kk, j] = fc[j]
        for c in range(ch.size):
            e = z[ch[c]] - x[s, st[c]]
            if angle[c]:
                e = (e + np.pi) % (2 * np.pi) - np.pi
            E[s, kk + 1, ch[c]] = e
            Z[s, kk + 1, ch[c]] = z[ch[c]]
        k[s] = kk + 1
