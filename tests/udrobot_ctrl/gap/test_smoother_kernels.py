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


def test_cholesky_solve_of_many_right_hand_sides_solves_each_as_alone():
    """The substitutions run over every right-hand side at once: each column's numbers are those of its own solve."""
    A, B = _spd(19), RNG.normal(size=(19, 19))
    X = np.empty_like(B)
    assert cholesky_solve(A, B, X)
    for j in range(B.shape[1]):
        x = np.empty((19, 1))
        assert cholesky_solve(A, np.ascontiguousarray(B[:, j:j + 1]), x)
        assert np.array_equal(X[:, j], x[:, 0])


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
    Q = 0.1 * _spd(ns)
    xs_f, xs_p = RNG.normal(size=(m, ns + 2)), RNG.normal(size=(m, ns + 2))
    xs, Ps = xs_f.copy(), Ps_f.copy()
    assert rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Q, Fs, 2, m - 2) == -1
    ref_x, ref_P = xs_f.copy(), Ps_f.copy()
    for k in range(m - 2, -1, -1):
        Pp = Fs[k] @ Ps_f[k] @ Fs[k].T + Q  # the forward pass's prediction of step k + 1
        C = Ps_f[k] @ Fs[k].T @ np.linalg.inv(Pp)
        ref_x[k, 2:] = xs_f[k, 2:] + C @ (ref_x[k + 1, 2:] - xs_p[k, 2:])
        ref_P[k] = Ps_f[k] + C @ (ref_P[k + 1] - Pp) @ C.T
    np.testing.assert_allclose(xs, ref_x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Ps, ref_P, rtol=1e-9, atol=1e-10)
    assert np.array_equal(xs[:, :2], xs_f[:, :2])  # the components outside the filter are left alone
    # smoothed in place (Ps is Ps_f, as the smoother calls it): the same numbers
    xs_in, Ps_in = xs_f.copy(), Ps_f.copy()
    assert rts_pass(xs_in, xs_f, xs_p, Ps_in, Ps_in, Q, Fs, 2, m - 2) == -1
    assert np.array_equal(xs_in, xs) and np.array_equal(Ps_in, Ps)
    Ps_f[2] = -Ps_f[2]  # step 2's prediction is then indefinite: the pass hands that step back
    xs, Ps = xs_f.copy(), Ps_f.copy()
    assert rts_pass(xs, xs_f, xs_p, Ps, Ps_f, Q, Fs, 2, m - 2) == 2


def test_the_backward_pass_prediction_is_the_forward_pass_one_bit_for_bit():
    """The covariance the forward pass predicts (predict_sample, not kept) and the one the backward pass computes
    again (predicted_covariance) are the same numbers: the smoothed run does not change by not keeping it."""
    from udrobot_ctrl.gap.smoother_kernels import predict_sample, predicted_covariance

    m, n_full, lo = 5, 21, 2
    ns = n_full - lo
    Fs, Ps_f = np.empty((m, ns, ns)), np.stack([_spd(ns) for _ in range(m)])
    Q = np.diag(RNG.uniform(1e-6, 1e-3, ns))
    for k in range(m):
        x, x_next, Ffull = RNG.normal(size=n_full), RNG.normal(size=n_full), np.eye(n_full) + 0.05 * RNG.normal(
            size=(n_full, n_full))
        forward, again = np.empty((ns, ns)), np.empty((ns, ns))
        assert predict_sample(k, x, x_next, Ffull, lo, Fs, Ps_f, Q, forward)
        assert np.array_equal(x, x_next) and np.array_equal(Fs[k], Ffull[lo:, lo:])
        assert predicted_covariance(k, Fs, Ps_f, Q, again)
        assert np.array_equal(forward, again)
        np.testing.assert_allclose(again, Fs[k] @ Ps_f[k] @ Fs[k].T + Q, rtol=1e-12)


def test_forward_steps_are_the_numpy_innovation_update_and_prediction():
    """The forward pass's fused kernels give bit for bit what the numpy steps they replace give."""
    from udrobot_ctrl.dynamics.plant import wrap_angle
    from udrobot_ctrl.gap.smoother_kernels import forward_predict, forward_update, innovation

    n_full, lo, n_meas = 21, 2, 15
    ns = n_full - lo
    rows = np.arange(n_meas)
    ok = np.ones(n_meas, bool)
    ok[[0, 1, 7, 13]] = False
    angle_rows = np.array([3, 4, 5])
    h, Hfull = RNG.normal(size=n_meas), np.asfortranarray(RNG.normal(size=(n_meas, n_full)))
    z, rdiag = RNG.normal(size=n_meas) * 4.0, RNG.uniform(0.01, 0.1, n_meas)
    z[3:6] = [3.1, -3.1, 6.0]  # innovations that wrap
    H, y, r = innovation(lo, h, Hfull, z, ok, rows, angle_rows, rdiag)
    r_ok = rows[ok]
    y_np = z[ok] - h[r_ok]
    ang = np.flatnonzero(np.isin(r_ok, angle_rows))
    y_np[ang] = wrap_angle(y_np[ang])
    assert np.array_equal(H, np.ascontiguousarray(Hfull[r_ok, lo:])) and H.flags.c_contiguous
    assert np.array_equal(y, y_np) and np.array_equal(r, rdiag[ok])

    P, x = _spd(ns), RNG.normal(size=n_full)
    x1, P1 = x.copy(), np.empty((ns, ns))
    x2, P2 = x.copy(), np.empty((ns, ns))
    assert forward_update(x1, lo, P, h, Hfull, z, ok, rows, angle_rows, rdiag, P1)
    assert kalman_update(x2[lo:], P, np.ascontiguousarray(Hfull[r_ok, lo:]), y_np, rdiag[ok], P2)
    assert np.array_equal(x1, x2) and np.array_equal(P1, P2)

    Ffull, Q, x_next = np.asfortranarray(RNG.normal(size=(n_full, n_full))), _spd(ns), RNG.normal(size=n_full)
    F_out, P_out, P_ref = np.empty((ns, ns)), np.empty((ns, ns)), np.empty((ns, ns))
    assert forward_predict(x1, x_next, Ffull, lo, F_out, P1, Q, P_out)
    assert predict_covariance(np.ascontiguousarray(Ffull[lo:, lo:]), P1, Q, P_ref)
    assert np.array_equal(x1, x_next) and np.array_equal(F_out, Ffull[lo:, lo:]) and np.array_equal(P_out, P_ref)
    x_next[4] = np.nan  # a non-finite state is refused
    assert not forward_predict(x1, x_next, Ffull, lo, F_out, P1, Q, P_out)
