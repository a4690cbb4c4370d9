"""The smoother's compiled linear algebra against the numpy formulas it replaces."""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.gap.smoother_kernels import cholesky_solve, kalman_update, predict_covariance, rts_pass

RNG = np.random.default_rng(5)


def _spd(n):
    A = RNG.normal(size=(n, n))
    return A @ A.T + np.eye(n)


def test_cholesky_solve_matches_the_general_solver_and_refuses_an_indefinite_matrix():
    A, B = _spd(19), RNG.normal(size=(19, 6))
    X = np.empty_like(B)
    assert cholesky_solve(A, B, X)
    np.testing.assert_allclose(X, np.linalg.solve(A, B), rtol=1e-9, atol=1e-12)
    indefinite = A - 30.0 * np.eye(19)
    assert np.linalg.eigvalsh(indefinite).min() < 0
    assert not cholesky_solve(indefinite, B, X)


def test_kalman_update_is_the_textbook_gain_and_covariance_update():
    ns, nr = 19, 7
    P, H, y, r = _spd(ns), RNG.normal(size=(nr, ns)), RNG.normal(size=nr), RNG.uniform(0.1, 1.0, nr)
    x = RNG.normal(size=ns)
    x_new, P_new = x.copy(), np.empty((ns, ns))
    assert kalman_update(x_new, P, H, y, r, P_new)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + np.diag(r))
    np.testing.assert_allclose(x_new, x + K @ y, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P_new, (np.eye(ns) - K @ H) @ P, rtol=1e-9, atol=1e-10)
    assert np.array_equal(P_new, P_new.T)
    # the innovation covariance rounding left indefinite: refused, nothing written
    untouched = x.copy()
    assert not kalman_update(untouched, P, H, y, -1e6 * np.ones(nr), P_new)
    assert np.array_equal(untouched, x)


def test_predicted_covariance_and_its_finiteness():
    F, P, Q = RNG.normal(size=(5, 5)), _spd(5), np.eye(5)
    out = np.empty((5, 5))
    assert predict_covariance(F, P, Q, out)
    np.testing.assert_allclose(out, F @ P @ F.T + Q, rtol=1e-12)
    assert not predict_covariance(F, P * np.inf, Q, out)


def test_rts_pass_matches_the_numpy_recursion_and_stops_at_an_indefinite_prediction():
    m, ns = 6, 4
    Fs = np.stack([np.eye(ns) + 0.1 * RNG.normal(size=(ns, ns)) for _ in range(m)])
    Ps_f = np.stack([_spd(ns) for _ in range(m)])
    Ps_p = np.stack([_spd(ns) for _ in range(m)])
    xs_f, xs_p = RNG.normal(size=(m, ns + 2)), RNG.normal(size=(m, ns + 2))
    xs, Ps = xs_f.copy(), Ps_f.copy()
    assert rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Ps_p, Fs, 2, m - 2) == -1
    ref_x, ref_P = xs_f.copy(), Ps_f.copy()
    for k in range(m - 2, -1, -1):
        C = Ps_f[k] @ Fs[k].T @ np.linalg.inv(Ps_p[k + 1])
        ref_x[k, 2:] = xs_f[k, 2:] + C @ (ref_x[k + 1, 2:] - xs_p[k, 2:])
        ref_P[k] = Ps_f[k] + C @ (ref_P[k + 1] - Ps_p[k + 1]) @ C.T
    np.testing.assert_allclose(xs, ref_x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Ps, ref_P, rtol=1e-9, atol=1e-10)
    assert np.array_equal(xs[:, :2], xs_f[:, :2])  # the components outside the filter are left alone
    Ps_p[3] = -Ps_p[3]  # step 2 needs it: the pass hands that step back
    xs, Ps = xs_f.copy(), Ps_f.copy()
    assert rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Ps_p, Fs, 2, m - 2) == 2
