"""Per-step fast paths of the controllers and estimators: compiled casadi calls and the MPC QP solvers.

* :class:`CompiledFunction`: a casadi Function (the plant's RK4 step and its Jacobians, generated from
  :mod:`udrobot_ctrl.dynamics.equations` through :mod:`udrobot_ctrl.dynamics.plant_casadi`, so there is one
  model) evaluated through its gcc-compiled C code with :mod:`ctypes` on preallocated numpy buffers. casadi's
  own Python call converts every argument and result (~30-40 us for the MPC's linearisation); the direct call
  costs ~2-3 us for the same C code. Falls back to the casadi Function when gcc is missing.
* :class:`CondensedMPCQP`: the MPC tracking QP (thrust limits, optional state bounds), solved exactly by an
  active-set method warm-started with the working set of the shifted previous solution. With thrust limits
  only (box constraints; the linear MPC and the RTI NMPC): a block-principal-pivoting active set whose every
  iteration is one Riccati recursion over the horizon with the inputs of the working set fixed at their bounds
  (:func:`_riccati_box_qp`, numba; ``O(N (nx + nu)^3)``, usually one iteration warm), for one affine model
  ``x_{k+1} = A x_k + B f_k + c`` or one per stage. With state bounds (general constraints): the QP condensed
  to the thrusts (:func:`_condense`) and solved by DAQP (Arnström et al., IEEE TAC 2022, a dual active-set
  solver made for MPC).
  Measured (issue 38, N = 20, bluerov2-heavy: 10 states, 8 thrusters, 160 variables): condensing ~67 us and
  the Cholesky of the 160 x 160 condensed Hessian ~135 us per iteration against ~55 us for the Riccati
  iteration (no condensing); for the UDrobot (4 thrusters) ~57 us against ~40 us. DAQP's ``update`` with a
  new Hessian refactorises for ~100 us, so DAQP is kept for the general constraints only.
* Kernels of the EKF update (:func:`ekf_update_all`), of the fault monitor (:func:`frozen_statistics`,
  :func:`window_inputs`, :func:`advance_windows`, :func:`open_window`) and of the MPC's reference preview
  (:func:`preview_table`): the per-step arithmetic of :mod:`udrobot_ctrl.control.ekf`,
  :mod:`udrobot_ctrl.control.faults` and :mod:`udrobot_ctrl.control.mpc` without Python overhead.

Riccati active-set iteration (working set fixed; ``f_b`` the bound inputs, ``f_f`` the free ones of stage k)::

    S_k = R_ff + B_f' P_{k+1} B_f,  L_k = B_f' P_{k+1} A,  K_k = -S_k^-1 L_k,  P_k = Q + A' P_{k+1} A - L_k' S_k^-1 L_k
    p_k = -Q r_k + A' (P_{k+1} d_k + p_{k+1}),   d_k = B_b f_b + c + B_f k_k,   P_N = Q_N,  p_N = -Q_N r_N

then ``f_f = K_k x_k + k_k`` forward, and the condensed gradient of every input by the adjoint sweep
(``R (f_k - f_trim_k) + B' mu_{k+1}``, ``mu_k = Q e_k + A' mu_{k+1}``) for the bound inputs' multipliers: the
same KKT test and working-set changes as the condensed solver (:func:`_box_qp`), to the same tolerances.

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
    input_buffers, output_buffers : tuple of ndarray
        The flat (column-major) buffers themselves: a caller may write the inputs in place and call with no
        arguments (nothing is copied), and read the outputs in their memory order.
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
        self.input_buffers = tuple(self._in)  # flat, column-major: write in place, then call with no arguments
        self.output_buffers = tuple(self._out)
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
    by block principal pivoting: the condensed box solver, the reference of :func:`_riccati_box_qp` (which
    applies the same working-set rules without forming ``H``; tests/udrobot_ctrl/control/test_mpc_dense.py).

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


@numba.njit(cache=True)
def _all_below(M, x0, Xr, Ft, limit):
    """True when every entry of the QP data is finite and below ``limit`` in magnitude."""
    return (np.all(np.abs(M) < limit) and np.all(np.abs(x0) < limit) and np.all(np.abs(Xr) < limit)
            and np.all(np.abs(Ft) < limit))


# ----------------------------------------------------------------------------- Riccati active set (box constraints)
@numba.njit(cache=True, fastmath=_FASTMATH)
def _riccati_pass(MT, A_all, x0, Xr, Ft, Q, QN, R, state, lo, hi, U, X, Gr, K, kff, fidx, nfree, scale):
    """Solve the tracking QP with the inputs of the working set ``state`` fixed at their bounds (the others free)
    by one backward Riccati recursion and one forward sweep; then the gradient of the condensed cost (halved) with
    respect to every input by the adjoint sweep. ``U`` (N nu,) and ``X`` (N + 1, nx) receive the plan, ``Gr``
    (N nu,) the gradient, ``scale[0]`` the largest magnitude of its two terms (``R (u - f_trim)``, ``B' mu``), at
    least 1. Returns False if a stage Hessian ``R_ff + B_f' P B_f`` is not positive definite.

    Stage ``k``'s model is ``MT[k]`` (``[A_k | B_k | c_k]`` transposed, (nx + nu + 1, nx)) and ``A_all[k] = A_k``;
    one model for every stage when they hold one."""
    N, nu = Ft.shape
    nx = MT.shape[2]
    one = MT.shape[0] == 1
    P = np.empty((nx, nx))
    Pn = QN.copy()
    p = np.empty(nx)
    pn = np.empty(nx)
    for i in range(nx):
        s = 0.0
        for m in range(nx):
            s -= QN[i, m] * Xr[N, m]
        pn[i] = s
    BtP = np.empty((nu, nx))
    S = np.empty((nu, nu))
    Lm = np.empty((nu, nx))
    PA = np.empty((nx, nx))
    h = np.empty(nu)
    ub = np.empty(nu)
    w = np.empty(nu)
    d0 = np.empty(nx)
    dk = np.empty(nx)
    tmp = np.empty(nx)
    for k in range(N - 1, -1, -1):
        ks = 0 if one else k
        A, At, Bt, c = A_all[ks], MT[ks, :nx], MT[ks, nx:nx + nu], MT[ks, nx + nu]
        nf = 0
        for j in range(nu):
            s = state[k * nu + j]
            if s == 0:
                fidx[k, nf] = j
                nf += 1
                ub[j] = 0.0
            elif s > 0:
                ub[j] = hi[k * nu + j]
            else:
                ub[j] = lo[k * nu + j]
            w[j] = ub[j] - Ft[k, j]
        nfree[k] = nf
        for i in range(nx):  # d0 = c + B u_bound
            d0[i] = c[i]
        for j in range(nu):
            if ub[j] != 0.0:
                for i in range(nx):
                    d0[i] += Bt[j, i] * ub[j]
        for a in range(nf):  # BtP = B_f' P  (nf, nx)
            fa = fidx[k, a]
            for i in range(nx):
                BtP[a, i] = 0.0
            for m in range(nx):
                bm = Bt[fa, m]
                for i in range(nx):
                    BtP[a, i] += bm * Pn[m, i]
        for a in range(nf):
            fa = fidx[k, a]
            for b in range(a + 1):  # S = R_ff + B_f' P B_f (lower)
                fb = fidx[k, b]
                s = R[fa, fb]
                for i in range(nx):
                    s += BtP[a, i] * Bt[fb, i]
                S[a, b] = s
            s = 0.0  # h = (R w)_f + B_f' (P d0 + p)
            for j in range(nu):
                s += R[fa, j] * w[j]
            for i in range(nx):
                s += BtP[a, i] * d0[i] + Bt[fa, i] * pn[i]
            h[a] = s
            for j in range(nx):  # L = B_f' P A
                Lm[a, j] = 0.0
            for m in range(nx):
                bm = BtP[a, m]
                for j in range(nx):
                    Lm[a, j] += bm * A[m, j]
        for a in range(nf):  # Cholesky S = Lc Lc' in place (lower)
            s = S[a, a]
            for b in range(a):
                s -= S[a, b] * S[a, b]
            if not s > 0.0:
                return False
            d = np.sqrt(s)
            S[a, a] = d
            for e in range(a + 1, nf):
                s = S[e, a]
                for b in range(a):
                    s -= S[e, b] * S[a, b]
                S[e, a] = s / d
        # Y = Lc^-1 [L | h] (forward), stored in Lm / h
        for a in range(nf):
            for b in range(a):
                sab = S[a, b]
                for j in range(nx):
                    Lm[a, j] -= sab * Lm[b, j]
                h[a] -= sab * h[b]
            inv = 1.0 / S[a, a]
            for j in range(nx):
                Lm[a, j] *= inv
            h[a] *= inv
        # P_k = Q + A' P A - Y' Y (Y = Lc^-1 L); PA = P A first
        for i in range(nx):
            for j in range(nx):
                PA[i, j] = 0.0
            for m in range(nx):
                pim = Pn[i, m]
                for j in range(nx):
                    PA[i, j] += pim * A[m, j]
        for i in range(nx):  # lower triangle (symmetric)
            for j in range(i + 1):
                P[i, j] = Q[i, j]
            for m in range(nx):
                ami = A[m, i]
                for j in range(i + 1):
                    P[i, j] += ami * PA[m, j]
            for a in range(nf):
                ya = Lm[a, i]
                for j in range(i + 1):
                    P[i, j] -= ya * Lm[a, j]
        # K = -Lc^-T Y, kff = -Lc^-T y_h (backward), in place
        for a in range(nf - 1, -1, -1):
            for b in range(a + 1, nf):
                sba = S[b, a]
                for j in range(nx):
                    Lm[a, j] -= sba * Lm[b, j]
                h[a] -= sba * h[b]
            inv = 1.0 / S[a, a]
            for j in range(nx):
                Lm[a, j] *= inv
            h[a] *= inv
        for a in range(nf):
            for j in range(nx):
                K[k, a, j] = -Lm[a, j]
            kff[k, a] = -h[a]
        # p_k = -Q r_k + A' (P_{k+1} d_k + p_{k+1}), d_k = d0 + B_f kff
        for i in range(nx):
            s = d0[i]
            for a in range(nf):
                s += Bt[fidx[k, a], i] * kff[k, a]
            dk[i] = s
        for i in range(nx):
            s = pn[i]
            for m in range(nx):
                s += Pn[i, m] * dk[m]
            tmp[i] = s
        for i in range(nx):
            s = 0.0
            for m in range(nx):
                s += At[i, m] * tmp[m] - Q[i, m] * Xr[k, m]
            p[i] = s
        for i in range(nx):
            for j in range(i + 1):
                Pn[i, j] = P[i, j]
                Pn[j, i] = P[i, j]
            pn[i] = p[i]
    # forward sweep
    for i in range(nx):
        X[0, i] = x0[i]
    for k in range(N):
        ks = 0 if one else k
        A, Bt, c = A_all[ks], MT[ks, nx:nx + nu], MT[ks, nx + nu]
        for j in range(nu):
            s = state[k * nu + j]
            if s > 0:
                U[k * nu + j] = hi[k * nu + j]
            elif s < 0:
                U[k * nu + j] = lo[k * nu + j]
        for a in range(nfree[k]):
            s = kff[k, a]
            for j in range(nx):
                s += K[k, a, j] * X[k, j]
            U[k * nu + fidx[k, a]] = s
        for i in range(nx):
            s = c[i]
            for j in range(nx):
                s += A[i, j] * X[k, j]
            for j in range(nu):
                s += Bt[j, i] * U[k * nu + j]
            X[k + 1, i] = s
    # adjoint sweep: Gr_k = R (u_k - ft_k) + B' mu_{k+1}; mu_N = QN e_N, mu_k = Q e_k + A' mu_{k+1}
    mu = np.empty(nx)
    for i in range(nx):
        s = 0.0
        for m in range(nx):
            s += QN[i, m] * (X[N, m] - Xr[N, m])
        mu[i] = s
    gs = 1.0
    for k in range(N - 1, -1, -1):
        ks = 0 if one else k
        Bt = MT[ks, nx:nx + nu]
        for j in range(nu):
            s = 0.0
            for q in range(nu):
                s += R[j, q] * (U[k * nu + q] - Ft[k, q])
            s2 = 0.0
            for i in range(nx):
                s2 += Bt[j, i] * mu[i]
            gs = max(gs, abs(s), abs(s2))
            Gr[k * nu + j] = s + s2
        if k > 0:
            At = MT[0 if one else k, :nx]  # mu_k = Q e_k + A_k' mu_{k+1}
            for i in range(nx):
                s = 0.0
                for m in range(nx):
                    s += At[i, m] * mu[m] + Q[i, m] * (X[k, m] - Xr[k, m])
                tmp[i] = s
            for i in range(nx):
                mu[i] = tmp[i]
    scale[0] = gs
    return True


@numba.njit(cache=True, fastmath=_FASTMATH)
def _riccati_box_qp(MT, x0, Xr, Ft, Q, QN, R, lo, hi, state, U, X, limit, max_iter):
    """The linear MPC's tracking QP with thrust limits only (box constraints), solved exactly without condensing:
    the block-principal-pivoting active set of :func:`_box_qp` (same working-set rules and tolerances), each
    iteration one Riccati recursion over the horizon with the inputs at their bounds fixed (``O(N (nx + nu)^3)``
    instead of a Cholesky of the ``N nu`` condensed Hessian). ``MT`` (1 or N, nx + nu + 1, nx): the transposed
    ``[A | B | c]`` of every stage (``x_{k+1} = A_k x_k + B_k f_k + c_k``), or one for all; ``state`` (N nu,) int8
    working set (in: warm start, out: optimal); ``U`` (N nu,) and ``X`` (N + 1, nx) receive the plan.

    Returns the number of iterations, -1 (iteration limit or a stage Hessian not positive definite) or -2 (data
    non-finite or ``>= limit`` in magnitude)."""
    N, nu = Ft.shape
    nx = MT.shape[2]
    if not _all_below(MT, x0, Xr, Ft, limit):
        return -2
    A_all = np.empty((MT.shape[0], nx, nx))
    for k in range(MT.shape[0]):
        for i in range(nx):
            for j in range(nx):
                A_all[k, i, j] = MT[k, j, i]
    n = N * nu
    Gr = np.empty(n)
    K = np.empty((N, nu, nx))
    kff = np.empty((N, nu))
    fidx = np.empty((N, nu), np.int64)
    nfree = np.empty(N, np.int64)
    scale = np.ones(1)
    for i in range(n):
        if lo[i] == hi[i]:
            state[i] = 1  # a fixed variable (a stuck thruster) is never freed
    best, stall = n + 1, 0
    dtol = 0.0
    for it in range(max_iter):
        if not _riccati_pass(MT, A_all, x0, Xr, Ft, Q, QN, R, state, lo, hi, U, X, Gr, K, kff, fidx, nfree, scale):
            return -1
        if it == 0:  # dual tolerance relative to the gradient's terms at the first iterate
            if not scale[0] < limit:
                return -2
            dtol = 1e-10 * scale[0]
        n_bad, last = 0, -1
        for i in range(n):
            tol = 1e-10 * (1.0 + abs(lo[i]) + abs(hi[i]))
            if state[i] == 0:
                bad = U[i] > hi[i] + tol or U[i] < lo[i] - tol
            elif lo[i] == hi[i]:
                bad = False
            else:
                bad = Gr[i] > dtol if state[i] > 0 else Gr[i] < -dtol
            if bad:
                n_bad += 1
                last = i
        if n_bad == 0:
            for i in range(n):
                if not np.isfinite(U[i]):
                    return -1
                U[i] = min(max(U[i], lo[i]), hi[i])
            return it + 1
        if n_bad < best:
            best, stall = n_bad, 0
        else:
            stall += 1
        for i in range(n):
            if stall >= 3 and i != last:
                continue
            tol = 1e-10 * (1.0 + abs(lo[i]) + abs(hi[i]))
            if state[i] == 0:
                if U[i] > hi[i] + tol:
                    state[i] = 1
                elif U[i] < lo[i] - tol:
                    state[i] = -1
            elif lo[i] != hi[i]:
                if (Gr[i] > dtol) if state[i] > 0 else (Gr[i] < -dtol):
                    state[i] = 0
    return -1



@numba.njit(cache=True)
def preview_table(times, rows, trim_rows, t, preview, psi, psi_col, r_out, ft_out):
    """Fill the horizon's references ``r_out`` (N + 1, nx) and trim thrusts ``ft_out`` (N, nu) from a
    piecewise-constant, right-continuous table (breakpoints ``times`` (m,), rows (m + 1, nx), trims (m + 1, nu)) at
    the times ``t + preview``: ``numpy.searchsorted(times, t + preview, side="right")`` row lookups, the heading
    column ``psi_col`` unwrapped to within pi of ``psi`` (``psi + wrap(r - psi)``, as
    :meth:`udrobot_ctrl.control.mpc.LinearMPC.references`)."""
    m = times.size
    nx = rows.shape[1]
    nu = trim_rows.shape[1]
    for k in range(preview.size):
        tk = t + preview[k]
        lo, hi = 0, m  # first index with times[i] > tk
        while lo < hi:
            mid = (lo + hi) // 2
            if times[mid] <= tk:
                lo = mid + 1
            else:
                hi = mid
        for i in range(nx):
            r_out[k, i] = rows[lo, i]
        if psi_col >= 0:
            r_out[k, psi_col] = (rows[lo, psi_col] - psi + np.pi) % (2 * np.pi) - np.pi + psi
        if k < ft_out.shape[0]:
            for j in range(nu):
                ft_out[k, j] = trim_rows[lo, j]


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
    """The tracking QP of :class:`udrobot_ctrl.control.mpc.SparseMPCQP`, solved exactly by an active set.

    Same problem (same weights, thrust limits, optional state bounds on ``x_1 .. x_N``) and the same minimiser:
    with thrust limits only, the Riccati active set (:func:`_riccati_box_qp`; one affine model for the horizon,
    or one per stage: the RTI's Gauss-Newton QP); with state bounds, condensed to the thrusts for the
    time-invariant model of the linear MPC and solved by DAQP (to machine accuracy).

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
        self._data = None
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
        """Take the model ``x_{k+1} = A x_k + B f_k + c`` (reduced states; ``ABc = [A | B | c]``,
        (nx, nx + nu + 1), or one per stage (N, nx, nx + nu + 1): thrust limits only), initial state ``x0`` (nx,),
        references ``xref`` (N+1, nx) and trim thrusts ``uref`` (N, nu). With state bounds the QP is condensed here
        (DAQP); with thrust limits only the data are kept for the Riccati active set of :meth:`solve` (nothing to
        condense).

        Raises
        ------
        FloatingPointError
            If any of the data is non-finite or larger than :data:`QP_DATA_LIMIT` (nothing is changed).
        """
        M, x0 = np.asarray(ABc, float), np.ascontiguousarray(x0, float)
        xref, uref = np.ascontiguousarray(xref, float), np.ascontiguousarray(uref, float)
        if M.ndim == 3 and self.m_general:
            raise ValueError("a model per stage needs thrust limits only (state bounds condense one model)")
        if self.m_general == 0:
            MT = np.ascontiguousarray(M.T[None] if M.ndim == 2 else M.transpose(0, 2, 1))
            ok = _all_below(MT, x0, xref, uref, QP_DATA_LIMIT)
            if ok:
                self._data = (MT, x0, xref, uref)
        else:
            M = np.ascontiguousarray(M)
            ok = _condense(M, x0, xref, uref, self.Q, self.QN, self.R, self._Lq, self._tn_scale, self._bnd_state,
                           self._bnd_lo, self._bnd_hi, self._Gm, self.H, self.g, self._Ab, self._ab_lo, self._ab_hi,
                           self._Xf, QP_DATA_LIMIT, True)
        if not ok:
            self._ready = False
            raise FloatingPointError(f"QP data is non-finite or larger than {QP_DATA_LIMIT:.0e}")
        self._ready = True

    def update_transposed(self, MT, x0, xref, uref):
        """:meth:`update` with the model(s) given transposed, ``MT[k] = [A_k | B_k | c_k]'`` (1 or N,
        nx + nu + 1, nx) C-contiguous: the memory order of a casadi function's column-major output, used as it
        is (kept by reference until :meth:`solve`). One model with state bounds is condensed as by :meth:`update`.
        """
        if self.m_general:
            if MT.shape[0] != 1:
                raise ValueError("a model per stage needs thrust limits only (state bounds condense one model)")
            return self.update(MT[0].T, x0, xref, uref)
        if not _all_below(MT, x0, xref, uref, QP_DATA_LIMIT):
            self._ready = False
            raise FloatingPointError(f"QP data is non-finite or larger than {QP_DATA_LIMIT:.0e}")
        self._data = (MT, x0, xref, uref)
        self._ready = True

    @property
    def states(self) -> np.ndarray:
        """Predicted states (N + 1, nx) of the last box-constrained solve (a view, overwritten by the next)."""
        return self._Xf

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
        M, x0, xref, uref = self._data
        it = _riccati_box_qp(M, x0, xref, uref, self.Q, self.QN, self.R, self.lo, self.hi, self._state, self._u,
                             self._Xf, QP_DATA_LIMIT, self.max_iter)
        dt = time.perf_counter() - t0
        if it < 0:  # the kernel checks the plan is finite
            self._have_state = False
            why = "data non-finite or too large" if it == -2 else "iteration limit or not positive definite"
            return DenseSolve(f"active set failed ({why})", None, dt, max(it, 0))
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


@numba.njit(cache=True)
def window_inputs(f_cmd, gain, offset, f_min, f_max, fc, fc_slots):
    """The thrust the thrusters produce for ``f_cmd`` with the detected faults applied (``clip(gain f + offset)``,
    :meth:`udrobot_ctrl.control.faults.ThrusterFaultDetector.correct`) into ``fc`` (nu,) and every row of
    ``fc_slots`` (W, nu) (the mapped linearisation's thrust input). Returns False (nothing written) when ``f_cmd``
    is not finite."""
    nu = f_cmd.size
    for j in range(nu):
        if not np.isfinite(f_cmd[j]):
            return False
    for j in range(nu):
        fc[j] = min(max(gain[j] * f_cmd[j] + offset[j], f_min[j]), f_max[j])
    for s in range(fc_slots.shape[0]):
        for j in range(nu):
            fc_slots[s, j] = fc[j]
    return True


@numba.njit(cache=True)
def open_window(active, order, created, k, t0, x0, P0, x, Phi, G, C, E, Z, t, x_est, P_est):
    """Open a detection window at ``t`` from the estimate ``x_est`` (12,), ``P_est`` (12, 12) in the first free slot
    (or the oldest one when none is free): the bank of :class:`udrobot_ctrl.control.faults.ThrusterFaultDetector`.
    ``created`` (1,) counts the windows opened. Returns the slot, or -1 (nothing opened) when the estimate is not
    finite."""
    for i in range(12):
        if not np.isfinite(x_est[i]):
            return -1
        for j in range(12):
            if not np.isfinite(P_est[i, j]):
                return -1
    w = -1
    for s in range(active.size):
        if not active[s]:
            w = s
            break
    if w < 0:  # were none free, the oldest window would be dropped rather than stop the loop
        w = 0
        for s in range(1, active.size):
            if order[s] < order[w]:
                w = s
    active[w] = True
    created[0] += 1
    order[w] = created[0]
    k[w] = 0
    t0[w] = t
    for i in range(12):
        x0[w, i] = x_est[i]
        x[w, i] = x_est[i]
        for j in range(12):
            P0[w, i, j] = P_est[i, j]
            Phi[w, 0, i, j] = 1.0 if i == j else 0.0
        for j in range(G.shape[3]):
            G[w, 0, i, j] = 0.0
            C[w, 0, i, j] = 0.0
    E[w] = np.nan
    Z[w] = np.nan
    return w


@numba.njit(cache=True, fastmath=_FASTMATH)
def advance_windows(active, k, At, Bt, xn, fc, z, exclude, chan_state, angle, n_steps, x, Phi, G, C, F, E, Z):
    """One step of the open fault-detection windows (``active`` slots; step counts ``k`` per slot, incremented):
    ``Phi <- A Phi``, ``G <- A G + B``, ``C <- A C + B diag(fc)``, state ``x <- xn`` and the residuals
    ``z[c] - x[chan_state[c]]`` (angles wrapped) of the channels ``c`` with a finite sample not ``exclude`` d.
    ``At`` (12 W, 12), ``Bt`` (nu W, 12) and ``xn`` (W, 12) are the mapped linearisation's output buffers
    (slot s: ``A_s = At[12 s:12 s + 12].T``). Returns the number of open windows with ``n_steps`` steps (done)."""
    nu = fc.size
    n_done = 0
    for s in range(active.size):
        if not active[s]:
            continue
        kk = k[s]
        P0, P1 = Phi[s, kk], Phi[s, kk + 1]
        G0, G1 = G[s, kk], G[s, kk + 1]
        C0, C1 = C[s, kk], C[s, kk + 1]
        for i in range(12):
            x[s, i] = xn[s, i]
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
        for c in range(z.size):
            if exclude[c] or not np.isfinite(z[c]):
                continue
            e = z[c] - x[s, chan_state[c]]
            if angle[c]:
                e = (e + np.pi) % (2 * np.pi) - np.pi
            E[s, kk + 1, c] = e
            Z[s, kk + 1, c] = z[c]
        k[s] = kk + 1
        if kk + 1 >= n_steps:
            n_done += 1
    return n_done
