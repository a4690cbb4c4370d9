"""T-200 curve (models/t200_poly.toml), actuated DOFs and allocation (udrobot_ctrl.thrusters_alt)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from udrobot_ctrl.plant import plant_parameters
from udrobot_ctrl.thrusters_alt import (
    ThrustAllocator,
    actuated_dofs,
    fit_t200,
    load_t200,
    pwm_to_thrust,
    read_t200_csv,
    thrust_allocation_pinv,
    thrust_to_pwm,
)
from udrobot_ctrl.vehicle import load_model

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "t200" / "t200_performance_tidy.csv"
needs_data = pytest.mark.skipif(not DATA.exists(), reason="shared T-200 data not present")


def test_curve_limits_band_and_monotone_at_12V():
    assert pwm_to_thrust(1900, 12) == pytest.approx(36.4, abs=0.1)
    assert pwm_to_thrust(1100, 12) == pytest.approx(-28.6, abs=0.1)
    for pwm in (1464, 1500, 1536):
        assert pwm_to_thrust(pwm, 12) == 0.0
    assert pwm_to_thrust(1540, 12) > 0 > pwm_to_thrust(1460, 12)
    f = pwm_to_thrust(np.arange(1100, 1901), 12)
    assert np.all(np.diff(f) >= -1e-9)
    # more voltage, more thrust; roughly V^1.2 forward
    assert pwm_to_thrust(1900, 16) / pwm_to_thrust(1900, 12) == pytest.approx((16 / 12) ** 1.2, rel=0.03)
    with pytest.raises(ValueError, match="voltage"):
        pwm_to_thrust(1700, 25)


def test_inverse_round_trip():
    for v in (10.0, 12.0, 15.3, 20.0):
        c = load_t200()
        _, _, band, fmax, rmax = c.at(v)
        f = np.linspace(-0.98 * rmax, 0.98 * fmax, 200)
        # thrusts smaller than at the band edges cannot be produced: 1500 us (zero)
        f = f[(f > pwm_to_thrust(band[1] + 0.5, v)) | (f < pwm_to_thrust(band[0] - 0.5, v))]
        np.testing.assert_allclose(pwm_to_thrust(thrust_to_pwm(f, v), v), f, atol=1e-3)
    assert thrust_to_pwm(0.0) == 1500.0
    p = thrust_to_pwm(np.linspace(-40, 50, 300))
    assert np.all(np.diff(p) >= 0) and p.min() >= 1100 and p.max() <= 1900


@needs_data
def test_fit_matches_data_and_shipped_coefficients():
    shipped = load_t200()
    doc = fit_t200(DATA)
    for e in doc["voltage"]:
        assert e["forward_rms_N"] < 0.5 and e["reverse_rms_N"] < 0.5
    for v, (pwm, f) in read_t200_csv(DATA).items():
        model = pwm_to_thrust(pwm, v)
        assert np.sqrt(np.mean((model - f) ** 2)) < 0.5
        assert np.max(np.abs(model - f)) < 1.5
        i = list(shipped.voltages).index(v)
        assert shipped.max_forward_N[i] == pytest.approx(f.max())


def test_actuated_dofs_of_the_layout():
    p = plant_parameters(load_model("pendulum:chin"))
    rep = actuated_dofs(p.T)
    assert rep.rank == 4
    assert set(rep.actuated) == {"X", "Z", "K", "N"} and set(rep.passive) == {"Y", "M"}


def test_allocation_pinv_and_constrained():
    p = plant_parameters(load_model("pendulum:chin"))
    tau = np.array([20.0, 0, -10.0, 1.0, 0, 2.0])
    f = thrust_allocation_pinv(p.T, tau)
    np.testing.assert_allclose(p.T @ f, tau, atol=1e-9)
    alloc = ThrustAllocator.from_parameters(p)
    r = alloc(tau)
    assert r.status.startswith("solved")
    np.testing.assert_allclose(r.f, f, atol=1e-3)
    np.testing.assert_allclose(r.unachieved, 0, atol=1e-3)
    # too much surge: forward limit 2 x 36.4 N; reverse limit 2 x 28.6 N
    r = alloc(np.array([100.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(r.f[:2], p.f_max[:2], atol=1e-3)
    assert r.unachieved[0] == pytest.approx(100 - 2 * p.f_max[0], abs=1e-2)
    r = alloc(np.array([-100.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(r.f[:2], p.f_min[:2], atol=1e-3)
    assert np.all(r.f >= p.f_min - 1e-9) and np.all(r.f <= p.f_max + 1e-9)
    # unreachable DOF (sway) is reported, not silently dropped
    r = alloc(np.array([0, 5.0, 0, 0, 0, 0]))
    assert r.unachieved[1] == pytest.approx(5.0, abs=1e-3)
    r = alloc(np.array([np.nan, 0, 0, 0, 0, 0]))
    assert r.status.startswith("fallback") and np.all(r.f == 0)
