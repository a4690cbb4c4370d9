"""Pendulum free-decay test (Cely 2019 sec. 3.3, eqs. 10-16), dimensionally consistent physics.

Launches are simulated here from the pendulum's Lagrangian (scipy ``solve_ivp``), independently of the
package: potential U = (m - rho V) g y(theta) of the model at r from the pivot (below it when heavy, above
it when buoyant), kinetic energy 1/2 (I_p + (m + m_a) r^2) theta'^2, and the generalised drag force
-(K_L v + K_Q |v| v) r with v = r theta'.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from identification import decay, pendulum
from identification.decay import LaunchError
from identification.pendulum import PendulumRig

RHO, G = 1000.0, 9.81
VOLUME = 107_597e-9  # Table 3
MASS = 0.146  # Table 3
IMU_NOISE = math.radians(0.02)  # rad (assumed, as identification.synthetic)
AREA = 0.0024  # m^2, about the 22 % model's surge area (0.04938 x 0.22^2)


def pendulum_trace(mass, volume, r, added_mass, KL, KQ, amplitude, pivot_inertia=0.0, fs=100.0, duration=8.0,
                   hold=0.5, noise=IMU_NOISE, bias=0.0, seed=0):
    """Angle from the stable equilibrium, released from rest after a hold; IMU-like noise and level bias."""
    net = (mass - RHO * volume) * G  # weight minus buoyancy, N (negative: buoyant)
    side = 1.0 if net > 0 else -1.0  # hanging below the pivot, or standing above it
    J = pivot_inertia + (mass + added_mass) * r ** 2

    def dU(theta):  # U = net * y, y = -side r cos(theta)
        return net * side * r * math.sin(theta)

    def rhs(_, s):
        th, w = s
        v = r * w
        return [w, (-dU(th) - (KL * v + KQ * abs(v) * v) * r) / J]

    t = np.arange(0.0, hold + duration, 1.0 / fs)
    moving = t >= hold
    sol = solve_ivp(rhs, (t[moving][0], t[-1]), [amplitude, 0.0], t_eval=t[moving], rtol=1e-10, atol=1e-12,
                    method="DOP853")
    th = np.full(t.size, float(amplitude))
    th[moving] = sol.y[0]
    return t, th + bias + noise * np.random.default_rng(seed).standard_normal(t.size)


def identify(t, th, rig, method="output-error"):
    return pendulum.identify_launch(decay.Launch("pend.csv", t, th), rig, method=method)


def test_pivot_inertia_and_longer_arm():
    """A 0.45 m arm with a pivot/arm inertia of 4e-3 kg m^2 (comparable to the model's m r^2 ~ 0.03)."""
    r, ip, ma, KL, KQ = 0.45, 4e-3, 0.09, 0.05, 2.4
    rows = [identify(*pendulum_trace(MASS, VOLUME, r, ma, KL, KQ, math.radians(a), ip, seed=i),
                     PendulumRig(MASS, VOLUME, r, AREA, pivot_inertia=ip)) for i, a in enumerate((5, 10, 15))]
    for res in rows:
        assert res["added_mass_kg"] == pytest.approx(ma, rel=0.02)
        assert res["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
        assert res["KL"] == pytest.approx(KL, rel=0.20)
        assert res["KQ"] == pytest.approx(KQ, rel=0.05)
        assert res["CD_chin"] == pytest.approx(2 * KQ / (RHO * AREA), rel=0.05)
    # ignoring the pivot inertia attributes I_p / r^2 to the added mass (rotational inertia at the model radius)
    t, th = pendulum_trace(MASS, VOLUME, r, ma, KL, KQ, math.radians(10), ip, seed=9)
    naive = identify(t, th, PendulumRig(MASS, VOLUME, r, AREA))
    assert naive["added_mass_kg"] == pytest.approx(ma + ip / r ** 2, rel=0.02)


def test_drag_coefficient_does_not_depend_on_arm_length():
    """The same body on a 0.25 m and a 0.60 m arm: one C_m, K_Q and C_D (eq. 16 read literally would not)."""
    ma, KQ = 0.10, 2.0
    out = []
    for r in (0.25, 0.60):
        t, th = pendulum_trace(MASS, VOLUME, r, ma, 0.0, KQ, math.radians(12), seed=1)
        out.append(identify(t, th, PendulumRig(MASS, VOLUME, r, AREA)))
    for res in out:
        assert res["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
        assert res["CD"] == pytest.approx(2 * KQ / (RHO * AREA), rel=0.05)
        assert res["morison"]["KQ"] == pytest.approx(KQ, rel=0.05)
    # the damping rate a2 = K_Q r^3 / J scales with r (J ~ r^2), so a literal eq. 16 C_D = 2 a2 / (rho A)
    # would change by the arm ratio; the consistent C_D does not
    assert out[0]["CD"] == pytest.approx(out[1]["CD"], rel=0.03)


def test_buoyant_model_standing_above_the_pivot():
    """B > W: the model floats above the pivot; restoring moment (B - W) r sin(theta)."""
    mass, r, ma, KL, KQ = 0.060, 0.30, 0.08, 0.03, 1.5
    assert RHO * VOLUME > mass  # buoyant
    rig = PendulumRig(mass, VOLUME, r, AREA)
    assert rig.restoring_moment == pytest.approx((RHO * VOLUME - mass) * G * r)
    for a in (5, 15):
        res = identify(*pendulum_trace(mass, VOLUME, r, ma, KL, KQ, math.radians(a), seed=a), rig)
        assert res["added_mass_kg"] == pytest.approx(ma, rel=0.02)
        assert res["KL"] == pytest.approx(KL, rel=0.20)
        assert res["KQ"] == pytest.approx(KQ, rel=0.05)
        # natural frequency of a buoyant pendulum: sqrt((B - W) r / J)
        assert res["omega_n"] == pytest.approx(math.sqrt((RHO * VOLUME - mass) * G * r / ((mass + ma) * r ** 2)),
                                               rel=0.01)


def test_neutrally_buoyant_model_is_rejected():
    with pytest.raises(ValueError, match="nearly cancel"):
        PendulumRig(RHO * VOLUME, VOLUME, 0.3, AREA)


@pytest.mark.parametrize("bias", [0.15, -0.3])
def test_rest_offset_of_the_imu(bias):
    """An IMU mounted at an angle reads theta + bias at rest; the fit measures angles from the rest reading."""
    r, ma, KL, KQ = 0.30, 0.10, 0.04, 2.2
    res = identify(*pendulum_trace(MASS, VOLUME, r, ma, KL, KQ, math.radians(10), bias=bias, seed=2),
                   PendulumRig(MASS, VOLUME, r, AREA))
    assert res["amplitude_deg"] == pytest.approx(10.0, rel=0.02)
    assert res["added_mass_kg"] == pytest.approx(ma, rel=0.02)
    assert res["KL"] == pytest.approx(KL, rel=0.20)
    assert res["KQ"] == pytest.approx(KQ, rel=0.05)


def test_morison_form_on_morison_body_and_chin_on_chin_body():
    """The Morison fit of a quadratic-only body gives its C_D; the Chin fit then finds K_L ~ 0."""
    r, ma, cd = 0.30, 0.10, 1.6
    KQ = 0.5 * RHO * cd * AREA
    res = identify(*pendulum_trace(MASS, VOLUME, r, ma, 0.0, KQ, math.radians(15), seed=4),
                   PendulumRig(MASS, VOLUME, r, AREA))
    assert res["CD"] == pytest.approx(cd, rel=0.05)
    assert res["morison"]["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
    assert abs(res["KL"]) < 0.1 * KQ * 0.1  # below a tenth of the quadratic drag's rate at 0.1 m/s
    assert "KL" not in res["morison"]
    # a body with a real linear term: the Morison form must absorb it into a larger C_D
    res2 = identify(*pendulum_trace(MASS, VOLUME, r, ma, 0.15, KQ, math.radians(15), seed=5),
                    PendulumRig(MASS, VOLUME, r, AREA))
    assert res2["KL"] == pytest.approx(0.15, rel=0.20)
    assert res2["CD"] > 1.1 * cd


def test_paper_regression_method_agrees_with_output_error():
    """The paper's Savitzky-Golay + least-squares method on the same launches (2.5 to 15 deg)."""
    r, ma, KL, KQ = 0.30, 0.10, 0.04, 2.2
    rig = PendulumRig(MASS, VOLUME, r, AREA)
    for a in (5, 10, 15):
        t, th = pendulum_trace(MASS, VOLUME, r, ma, KL, KQ, math.radians(a), seed=a)
        reg = identify(t, th, rig, method="regression")
        oe = identify(t, th, rig)
        assert reg["Cm"] == pytest.approx(oe["Cm"], rel=0.02)
        assert reg["Cm"] == pytest.approx(ma / (RHO * VOLUME), rel=0.02)
        assert reg["KQ"] == pytest.approx(KQ, rel=0.15)  # derivatives of a noisy angle: looser than the ODE fit


def test_relation_to_paper_eq15():
    """With r = 1 m and no pivot inertia, the added mass is eq. 15's |rho V g - m g| / a1 - m."""
    rig = PendulumRig(MASS, VOLUME, 1.0, AREA)
    a1 = 2.0
    c = pendulum.coefficients_from_rates(a1, 0.0, 1.0, rig)
    assert c["added_mass_kg"] == pytest.approx(abs(RHO * VOLUME * G - MASS * G) / a1 - MASS)


def test_degrees_instead_of_radians_is_an_error(tmp_path):
    t, th = pendulum_trace(MASS, VOLUME, 0.3, 0.1, 0.04, 2.2, math.radians(10))
    p = tmp_path / "deg.csv"
    p.write_text("t,theta\n" + "".join(f"{a:.3f},{math.degrees(b):.6f}\n" for a, b in zip(t, th)))
    with pytest.raises(LaunchError, match="radians") as exc:
        pendulum.read_pendulum_launch(p)
    assert str(p) in str(exc.value)


def test_log_with_rest_and_pull_before_the_release():
    r, ma, KL, KQ = 0.30, 0.10, 0.04, 2.2
    t, th = pendulum_trace(MASS, VOLUME, r, ma, KL, KQ, math.radians(10), seed=6)
    pre_t = np.arange(0.0, 2.0, 0.01)
    pre = np.where(pre_t < 1.0, 0.0, math.radians(10) * np.minimum((pre_t - 1.0) / 0.7, 1.0))
    pre = pre + IMU_NOISE * np.random.default_rng(1).standard_normal(pre_t.size)
    res = identify(np.concatenate([pre_t, t + 2.0]), np.concatenate([pre, th]), PendulumRig(MASS, VOLUME, r, AREA))
    assert res["amplitude_deg"] == pytest.approx(10.0, rel=0.02)
    assert res["added_mass_kg"] == pytest.approx(ma, rel=0.02)
    assert res["KQ"] == pytest.approx(KQ, rel=0.05)
