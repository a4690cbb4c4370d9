"""numba kernels of :mod:`udrobot_ctrl.gap.smoother`: the Kalman update, the covariance prediction and the RTS pass.

The smoother's forward pass calls the casadi plant (its state transition and measurement Jacobians) once per
sample from Python; the linear algebra around those calls (gain, update, prediction) and the whole backward RTS pass
run here, compiled: at the smoother's sizes (19 or 21 states, up to 9 measurements) the numpy calls they replace
cost more in call overhead than in arithmetic. Covariances are solved with a Cholesky factorisation (they are
symmetric positive definite); a kernel reports a matrix rounding has left indefinite instead of raising, and the
caller solves that one step with the general solver (:func:`udrobot_ctrl.gap.smoother.spd_solve`'s rule). Compiled
once per machine and cached on disk (:func:`udrobot_ctrl.caches.configure_numba_cache`).
"""
from udrobot_ctrl.caches import configure_numba_cache

configure_numba_cache()  # before the decorators below choose their cache folder

import math  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402


@numba.njit(cache=True)
def cholesky_solve(A, B, X) -> bool:
    """X = A^-1 B for a symmetric positive definite A (n, n) (lower triangle read) and B (n, k); False (X
    unspecified) when A is not numerically positive definite."""
    n, k = B.shape
    L = np.zeros((n, n))
    for j in range(n):
        s = A[j, j]
        for c in range(j):
            s -= L[j, c] * L[j, c]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for c in range(j):
                s -= L[i, c] * L[j, c]
            L[i, j] = s / d
    # the substitutions row by row over every column at once (contiguous rows of X); each entry's sum is taken in
    # the same order as one column at a time, so the result is the same to the bit, at a third of the time
    for i in range(n):  # L Y = B
        for col in range(k):
            X[i, col] = B[i, col]
        for c in range(i):
            lic = L[i, c]
            for col in range(k):
                X[i, col] -= lic * X[c, col]
        d = L[i, i]
        for col in range(k):
            X[i, col] = X[i, col] / d
    for i in range(n - 1, -1, -1):  # L^T X = Y
        for c in range(i + 1, n):
            lci = L[c, i]
            for col in range(k):
                X[i, col] -= lci * X[c, col]
        d = L[i, i]
        for col in range(k):
            X[i, col] = X[i, col] / d
    return True


@numba.njit(cache=True)
def kalman_update(x, P, H, y, r, P_out) -> bool:
    """Measurement update in place: x += K y, P_out = sym(P - K H P) with K = P H^T (H P H^T + diag(r))^-1.

    Parameters
    ----------
    x : (ns,) ndarray
        Predicted state (the filter's part of it), updated in place.
    P : (ns, ns) ndarray
        Predicted covariance.
    H : (nr, ns) ndarray
        Measurement Jacobian of the logged channels.
    y : (nr,) ndarray
        Innovation (angles already wrapped).
    r : (nr,) ndarray
        Measurement noise variances.
    P_out : (ns, ns) ndarray
        Filtered covariance (written).

    Returns
    -------
    bool
        False (nothing written) when the innovation covariance is not numerically positive definite.
    """
    PHt = P @ H.T
    S = H @ PHt
    for i in range(r.size):
        S[i, i] += r[i]
    KT = np.empty((H.shape[0], P.shape[0]))
    if not cholesky_solve(S, np.ascontiguousarray(PHt.T), KT):
        return False
    x += KT.T @ y
    Pn = P - KT.T @ PHt.T
    P_out[:, :] = 0.5 * (Pn + Pn.T)
    return True


@numba.njit(cache=True)
def predict_covariance(F, P, Q, P_out) -> bool:
    """P_out = F P F^T + Q; False when it is not finite."""
    P_out[:, :] = F @ P @ F.T + Q
    return bool(np.all(np.isfinite(P_out)))


@numba.njit(cache=True)
def innovation(lo, h, Hfull, z, ok, rows, angle_rows, rdiag):
    """(H, y, r) of one sample's logged channels: the rows ``rows[ok]`` of the measurement Jacobian ``Hfull`` on the
    filter's state components ``lo:`` (C-contiguous), the innovation ``z[ok] - h[rows[ok]]`` (angles wrapped to
    [-pi, pi) as :func:`udrobot_ctrl.dynamics.plant.wrap_angle`) and the noise variances ``rdiag[ok]``."""
    nr = 0
    for i in range(ok.size):
        if ok[i]:
            nr += 1
    ns = Hfull.shape[1] - lo
    H = np.empty((nr, ns))
    y = np.empty(nr)
    r = np.empty(nr)
    j = 0
    for i in range(ok.size):
        if ok[i]:
            row = rows[i]
            for c in range(ns):
                H[j, c] = Hfull[row, lo + c]
            y[j] = z[i] - h[row]
            for a in angle_rows:
                if row == a:
                    y[j] = (y[j] + np.pi) % (2 * np.pi) - np.pi
            r[j] = rdiag[i]
            j += 1
    return H, y, r


@numba.njit(cache=True)
def forward_update(x, lo, P, h, Hfull, z, ok, rows, angle_rows, rdiag, P_out) -> bool:
    """The forward pass's measurement update of one sample: :func:`kalman_update` of the filter's state ``x[lo:]``
    with the sample's logged channels (:func:`innovation`); False (nothing written) as :func:`kalman_update`."""
    H, y, r = innovation(lo, h, Hfull, z, ok, rows, angle_rows, rdiag)
    return kalman_update(x[lo:], P, H, y, r, P_out)


@numba.njit(cache=True)
def forward_predict(x, x_next, Ffull, lo, F_out, P, Q, P_out) -> bool:
    """The forward pass's prediction of one sample: ``x = x_next``, ``F_out`` = the transition Jacobian ``Ffull`` on
    the filter's state components ``lo:``, :func:`predict_covariance` into ``P_out``; False when the covariance or
    the state is not finite."""
    x[:] = x_next
    n = F_out.shape[0]
    for i in range(n):
        for j in range(n):
            F_out[i, j] = Ffull[lo + i, lo + j]
    return predict_covariance(F_out, P, Q, P_out) and bool(np.all(np.isfinite(x)))


@numba.njit(cache=True)
def update_sample(k, x, lo, h, Hfull, Z, finite, measured, rows, angle_rows, rdiag, xs_p, xs_f, P_pred, Ps_f) -> bool:
    """The forward pass at sample ``k``, the prediction ``x`` and its covariance ``P_pred`` in hand: ``xs_p[k] = x``,
    then, when the sample has a logged channel (``measured[k]``), :func:`forward_update` with its row of ``Z`` and
    ``finite`` into ``Ps_f[k]`` (else ``Ps_f[k] = P_pred``), and ``xs_f[k] = x``; the per-sample views taken here,
    not in Python. False (``xs_f[k]`` and ``Ps_f[k]`` not written) when the innovation covariance is not
    numerically positive definite."""
    xs_p[k] = x
    if measured[k]:
        if not forward_update(x, lo, P_pred, h, Hfull, Z[k], finite[k], rows, angle_rows, rdiag, Ps_f[k]):
            return False
    else:
        Ps_f[k] = P_pred
    xs_f[k] = x
    return True


@numba.njit(cache=True)
def predict_sample(k, x, x_next, Ffull, lo, Fs, Ps_f, Q, P_pred) -> bool:
    """:func:`forward_predict` of sample ``k`` into ``Fs[k]`` and ``P_pred`` (the prediction of sample k + 1: one
    buffer, not kept per sample; the backward pass computes it again, :func:`predicted_covariance`); the
    per-sample views taken here, not in Python."""
    return forward_predict(x, x_next, Ffull, lo, Fs[k], Ps_f[k], Q, P_pred)


@numba.njit(cache=True)
def predicted_covariance(k, Fs, Ps_f, Q, P_out) -> bool:
    """The forward pass's predicted covariance of sample k + 1, ``Fs[k] Ps_f[k] Fs[k]^T + Q``, into ``P_out``: the
    same call on the same arrays as :func:`predict_sample`'s (:func:`predict_covariance`), so the same numbers, bit
    for bit, while ``Ps_f[k]`` still holds the filtered covariance. False when it is not finite."""
    return predict_covariance(Fs[k], Ps_f[k], Q, P_out)


@numba.njit(cache=True)
def rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Q, Fs, lo, k_start) -> int:
    """Backward Rauch-Tung-Striebel pass from step ``k_start`` down to 0, in place on ``xs`` and ``Ps``.

    Step k: C = P_f[k] F[k]^T P_p[k+1]^-1, x[k] = x_f[k] + C (x[k+1] - x_p[k]), P[k] = P_f[k] + C (P[k+1] -
    P_p[k+1]) C^T, on the filter's state components ``lo:`` (``xs_p[k]`` is the prediction of step k+1), with the
    predicted covariance P_p[k+1] = F[k] P_f[k] F[k]^T + Q computed again (:func:`predicted_covariance`: the forward
    pass's numbers; not kept per sample, a third of the pass's memory). ``Ps`` may be ``Ps_f`` (smoothed in place:
    step k reads its filtered covariance before it writes the smoothed one).

    Returns
    -------
    int
        -1 when done, else the step whose predicted covariance was not numerically positive definite (nothing
        written for it; the caller solves it with the general solver and resumes at the step before).
    """
    ns = Ps.shape[1]
    CT = np.empty((ns, ns))
    Pp = np.empty((ns, ns))
    for k in range(k_start, -1, -1):
        predicted_covariance(k, Fs, Ps_f, Q, Pp)
        if not cholesky_solve(Pp, Fs[k] @ Ps_f[k], CT):
            return k
        C = np.ascontiguousarray(CT.T)
        dx = xs[k + 1, lo:] - xs_p[k, lo:]
        xs[k, lo:] = xs_f[k, lo:] + C @ dx
        Ps[k] = Ps_f[k] + C @ (Ps[k + 1] - Pp) @ CT
    return -1
