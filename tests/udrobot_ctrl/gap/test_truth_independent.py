"""The second truth generator (truth_independent.py) produces the physics its docstring claims.

Each test checks a form against its closed-form expectation; tolerances follow from the numerics (float round-off
for algebraic identities, the integration and the light damping for the pitch oscillation).
"""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import restoring_forces

from . import truth_independent as ti


def _state(**kw):
    x = np.zeros((1, 12))
    for k, v in kw.items():
        x[0, ti.STATES.index(k)] = v
    return x


def test_ballast_move_shifts_cg_and_changes_inertia_by_parallel_axis():
    tr = ti.IndependentTruth(effects={"cg_cb_offset": {"m_b": 1.2, "dz": -0.07, "dx": 0.02}})
    m = tr.mass
    d = np.array([0.02, 0.0, -0.07])
    assert np.allclose(tr.r_g_true - tr.p.r_g, 1.2 * d / m, atol=1e-12)
    r0, r1 = ti.BALLAST_AT, ti.BALLAST_AT + d
    # parallel-axis terms of a point mass about the origin: I_xx = m (y^2 + z^2), I_xz = -m x z
    dI = tr.M_RB_true[3:, 3:] - tr.M_RB_nom[3:, 3:]
    assert dI[0, 0] == pytest.approx(1.2 * ((r1[1] ** 2 + r1[2] ** 2) - (r0[1] ** 2 + r0[2] ** 2)), rel=1e-9)
    assert dI[1, 1] == pytest.approx(1.2 * ((r1[0] ** 2 + r1[2] ** 2) - (r0[0] ** 2 + r0[2] ** 2)), rel=1e-9)
    assert dI[0, 2] == pytest.approx(-1.2 * (r1[0] * r1[2] - r0[0] * r0[2]), rel=1e-9)
    # the surge-pitch coupling m z_g follows the CG
    assert tr.M_RB_true[0, 4] == pytest.approx(m * tr.r_g_true[2], rel=1e-12)
    assert np.allclose(tr.M_true, tr.M_true.T)


def test_cg_raise_changes_restoring_moment_at_a_held_angle():
    c = {"m_b": 1.2, "dz": -0.07, "dx": 0.0}
    tr = ti.IndependentTruth(effects={"cg_cb_offset": c})
    phi = 0.2
    F, _ = tr.extra(_state(phi=phi), 0.0)
    dzg = c["m_b"] * c["dz"] / tr.mass
    # g_K = (z_g W - z_b B) cos(theta) sin(phi) sits on the left of the equation: the extra moment is -dz_g W sin(phi)
    assert F[0, 3] == pytest.approx(-dzg * tr.p.weight * np.sin(phi), rel=1e-9)
    assert F[0, 3] > 0  # a raised CG weakens the righting moment: the extra moment leans further
    g_true = restoring_forces(_state(phi=phi)[0, :6], tr.p.weight, tr.p.buoyancy, tr.r_g_true, tr.p.r_b)
    g_nom = restoring_forces(_state(phi=phi)[0, :6], tr.p.weight, tr.p.buoyancy, tr.p.r_g, tr.p.r_b)
    assert np.allclose(F[0], g_nom - g_true, atol=1e-12)


def _pitch_period(tr, theta0=0.08, duration=12.0, dt=0.005):
    """Zero-thrust pitch oscillation from rest at theta0: mean period between upward zero crossings, s."""
    x = _state(z=1.5, theta=theta0)
    f = np.zeros((1, tr.T.shape[1]))
    th = []
    for k in range(int(duration / dt)):
        t = k * dt
        k1 = tr.deriv(x, f, t)
        k2 = tr.deriv(x + dt / 2 * k1, f, t + dt / 2)
        k3 = tr.deriv(x + dt / 2 * k2, f, t + dt / 2)
        k4 = tr.deriv(x + dt * k3, f, t + dt)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        th.append(x[0, 4])
    th = np.array(th)
    up = np.flatnonzero((th[:-1] < 0) & (th[1:] >= 0))
    tc = (up + (-th[up]) / (th[up + 1] - th[up])) * dt
    return float(np.mean(np.diff(tc)))


@pytest.mark.slow
@pytest.mark.parametrize("dz", [-0.08, 0.08])
def test_cg_move_changes_pitch_period_through_restoring_and_inertia(dz):
    """Free pitch oscillation: T = 2 pi sqrt(I / (W BG_z)) with I the pitch inertia (rigid body about the origin plus
    added) and the surge coupling m z_g: the ballast move changes both, and the period follows both."""
    nom = ti.IndependentTruth()
    tr = ti.IndependentTruth(effects={"cg_cb_offset": {"m_b": 1.3, "dz": dz, "dx": 0.0}})

    def predicted(t):
        M = t.M_true
        # surge is free: eliminate it from the (u, q) block (Schur complement) for the effective pitch inertia
        inertia = M[4, 4] - M[4, 0] ** 2 / M[0, 0]
        bg = t.r_g_true[2] * t.p.weight - t.p.r_b[2] * t.p.buoyancy
        return 2 * np.pi * np.sqrt(inertia / bg)

    T_nom, T_tr = _pitch_period(nom), _pitch_period(tr)
    # light damping (zeta ~ 0.02) lengthens the damped period by < 0.1 %; 1 % covers it and the crossing timing
    assert T_nom == pytest.approx(predicted(nom), rel=0.01)
    assert T_tr == pytest.approx(predicted(tr), rel=0.01)
    # and the inertia change matters: the restoring change alone would predict a period off by more than the tolerance
    bg = tr.r_g_true[2] * tr.p.weight - tr.p.r_b[2] * tr.p.buoyancy
    M = nom.M_true
    restoring_only = 2 * np.pi * np.sqrt((M[4, 4] - M[4, 0] ** 2 / M[0, 0]) / bg)
    assert abs(T_tr / restoring_only - 1) > 0.01
    assert (T_tr > T_nom) == (dz < 0)  # a raised CG: weaker righting, slower oscillation


def test_inflow_loss_sees_the_rotation_of_the_hull():
    """A roll rate p gives the vertical thruster at y = +0.15 m an axial inflow 0.15 p (omega x r): thrust falls on
    one side and rises on the other, by the open-water curve K_T(J)."""
    J0 = 0.5
    tr = ti.IndependentTruth(effects={"thrust_inflow_loss": {"J0": J0}})
    fc = np.array([[0.0, 0.0, 10.0, 10.0]])
    p_rate = 0.8
    f, _ = tr.thrust(fc, np.zeros((1, 4)), _state(p=p_rate), 0.01)
    y = tr.pos[:, 1]
    for i in (2, 3):
        ua = (1 - ti.WAKE) * y[i] * p_rate  # (omega x r) . d = p y for a vertical thruster
        n = np.sqrt(10.0 / (ti.RHO * ti.PROP_D ** 4 * ti.KT0)) + 1e-6
        J = ua / (n * ti.PROP_D)
        kt = np.clip(ti.KT0 * (1 - np.sign(J) * abs(J / J0) ** 1.3), 0, 1.4 * ti.KT0)
        assert f[0, i] == pytest.approx(ti.RHO * n ** 2 * ti.PROP_D ** 4 * kt, rel=1e-9)
    assert f[0, 3] < 10.0 < f[0, 2]  # the thruster moving along its axis (y > 0, p > 0) loses thrust
    f0, _ = tr.thrust(fc, np.zeros((1, 4)), _state(), 0.01)
    assert np.allclose(f0, fc, rtol=1e-6)  # no inflow, no loss


def test_tether_force_acts_at_the_attachment_point():
    tr = ti.IndependentTruth(effects={"tether_drag": {"d": 0.015, "cd": 1.1, "ct": 0.015, "anchor": (-3.0, 0.0, -0.3)}})
    F, _ = tr.extra(_state(x=0.5, y=-1.0, z=1.2, psi=0.4, u=0.5, v=0.1, r=0.2), 0.0)
    assert np.linalg.norm(F[0, :3]) > 0.1  # N: a 15 mm cable at 0.5 m/s
    assert np.allclose(F[0, 3:], np.cross(ti.TETHER_ATTACH, F[0, :3]), atol=1e-12)
    assert F[0, 0] < 0  # moving away from the anchor at speed: the cable holds the vehicle back


def test_seabed_added_mass_and_squeeze_damping_follow_the_gap_ratio():
    c = {"c_m": 0.5, "c_l": 0.5, "c_s": 0.8}
    tr = ti.IndependentTruth(effects={"wall_effect": c})
    for h in (0.25, 0.5):
        G = h / ti.HULL_HEIGHT
        F, dM = tr.extra(_state(z=ti.SEABED - h, w=0.1), 0.0)
        assert dM[0, 2, 2] == pytest.approx(c["c_m"] * tr.p.M_A[2, 2] / G ** 2, rel=1e-12)
        assert F[0, 2] == pytest.approx(-c["c_s"] * tr.p.D_L[2, 2] / G * 0.1, rel=1e-12)  # no tangential speed
        F, _ = tr.extra(_state(z=ti.SEABED - h, u=0.4), 0.0)
        suction = 0.5 * ti.RHO * ti.PLAN_AREA * c["c_l"] * np.exp(-G) * 0.16
        assert F[0, 2] == pytest.approx(suction, rel=1e-12)  # towards the bed (+down)


@pytest.mark.slow
def test_stock_runs_log_what_stock_sensors_give():
    runs = ti.generate({"cg_cb_offset": ti.random_magnitudes("cg_cb_offset", np.random.default_rng(1))},
                       n_runs=1, duration=6.0, rate=20.0, seed=2, sensors="stock")
    ch = set(runs[0].channels)
    assert {"z", "phi", "theta", "psi", "p", "q", "r", "ax", "ay", "az"} <= ch
    assert not ch & {"u", "v", "w", "x", "y", "altitude"}
    runs = ti.generate({}, n_runs=1, duration=6.0, rate=20.0, seed=2, sensors="stock", altitude=True)
    alt = runs[0].channels["altitude"]
    assert np.allclose(alt, ti.SEABED - runs[0].extra["true_z"], atol=5 * 0.01)


def test_strip_theory_drag_error_keeps_the_hull_dissipative():
    """The cross-flow drag error, of either sign, leaves a positive total heave and pitch drag (an error of the
    model, not a propulsive hull): drag power -F . nu < 0 for pure heave and pure pitch motion."""
    for seed in range(20):
        c = ti.random_magnitudes("quadratic_damping_error", np.random.default_rng(seed))
        tr = ti.IndependentTruth(effects={"quadratic_damping_error": c})
        for kw, i in (({"w": 0.4}, 8), ({"q": 1.0}, 10)):
            x = _state(**kw)
            F, _ = tr.extra(x, 0.0)
            total = F[0] - (np.abs(x[0, 6:]) * x[0, 6:]) @ tr.p.Q.T - x[0, 6:] @ tr.p.D_L.T
            assert total[i - 6] * x[0, i] < 0, (seed, c, kw)
        # a heave velocity loads the strips evenly: no pitch moment from it (the strips are symmetric about the origin)
        F, _ = tr.extra(_state(w=0.4), 0.0)
        assert abs(F[0, 4]) < 1e-9
