"""T-200 curve (from models/t200.toml, no data needed), its fit to Blue Robotics' data (skipped without the
data), controllability of the shipped layout and thrust allocation (pinv and OSQP)."""
from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import tomllib
from scipy.optimize import lsq_linear

from udrobot_ctrl.dynamics import thrusters as th
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.vehicle import load_model

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data" / "t200" / "t200_performance_tidy.csv"
needs_data = pytest.mark.skipif(not DATA.exists(), reason="../shared/data/t200 not available")


def _shipped_doc():
    return tomllib.loads(resources.files("udrobot_ctrl.models").joinpath("t200.toml").read_text())


def test_limits_at_12V_are_the_measured_ones_not_the_papers():
    fwd, rev = th.thrust_limits(12.0)
    assert fwd == pytest.approx(36.42, abs=0.05)  # Blue Robotics 3.714 kgf
    assert rev == pytest.approx(28.60, abs=0.05)  # Blue Robotics 2.917 kgf
    assert abs(fwd - 34.3) > 1.0  # the paper's 34.3 N is not used ...
    assert "34.3" in _shipped_doc()["provenance"]["paper_34_3N"]  # ... and the file says why
    assert "34.3" in th.__doc__


def test_curve_is_monotone_with_a_zero_band_and_voltage_scaling():
    pwm = np.arange(1100.0, 1900.5, 0.5)
    for volt in (10.0, 11.1, 12.0, 14.8, 16.0, 20.0, 22.0):
        f = th.pwm_to_thrust(pwm, volt)
        assert np.all(np.diff(f) >= 0), volt
        lo, hi = th.zero_band(volt)
        assert 1440 < lo < 1500 < hi < 1560
        inside = (pwm >= lo) & (pwm <= hi)
        assert np.all(f[inside] == 0) and np.all(f[pwm > hi + 1] > 0) and np.all(f[pwm < lo - 1] < 0)
    # the measured maxima scale roughly as V^1.2 forward and V^1.13 reverse
    f11, r11 = th.thrust_limits(11.0)
    f12, r12 = th.thrust_limits(12.0)
    assert f11 / f12 == pytest.approx((11 / 12) ** 1.2, rel=0.02)
    assert r11 / r12 == pytest.approx((11 / 12) ** 1.13, rel=0.02)
    # outside the data the power law extends the nearest curve continuously
    assert th.thrust_limits(20.0 + 1e-9)[0] == pytest.approx(th.thrust_limits(20.0)[0], rel=1e-6)
    assert th.pwm_to_thrust(1500.0, 12.0) == 0.0
    assert th.pwm_to_thrust(2500.0, 12.0) == pytest.approx(th.thrust_limits(12.0)[0])  # clipped command


def test_inverse_round_trips_and_returns_neutral_for_zero():
    rng = np.random.default_rng(1)
    volts = rng.uniform(10.5, 16.8, 200)
    f = rng.uniform(-28.0, 36.0, 200) * volts / 16.8
    pwm = th.thrust_to_pwm(f, volts)
    np.testing.assert_allclose(th.pwm_to_thrust(pwm, volts), f, atol=1e-9)
    assert th.thrust_to_pwm(0.0, 12.0) == 1500.0
    lo, hi = th.zero_band(12.0)
    assert th.thrust_to_pwm(1e-6, 12.0) == pytest.approx(hi, abs=0.05)
    assert th.thrust_to_pwm(-1e-6, 12.0) == pytest.approx(lo, abs=0.05)
    assert th.thrust_to_pwm(100.0, 12.0) == 1900.0 and th.thrust_to_pwm(-100.0, 12.0) == 1100.0
    grid = np.linspace(-40, 45, 401)
    assert np.all(np.diff(th.thrust_to_pwm(grid, 12.0)) >= 0)
    assert np.isnan(th.thrust_to_pwm(np.nan, 12.0))
    with pytest.raises(ValueError, match="voltage"):
        th.pwm_to_thrust(1600.0, -1.0)


def test_shipped_file_states_provenance_and_residual():
    doc = _shipped_doc()
    prov = doc["provenance"]
    assert prov["source"].startswith("measured:") and len(prov["data_sha256"]) == 64
    assert "rms" in prov["residual"]
    for row in doc["curve"]:
        for key in ("forward", "reverse"):
            assert row[key]["rms_N"] < 0.5 and row[key]["max_abs_N"] < 1.5


@needs_data
def test_curve_matches_blue_robotics_data():
    V, pwm, T = th.read_t200_csv(DATA)
    pred = th.pwm_to_thrust(pwm, V)
    nz = T != 0
    rms = np.sqrt(np.mean((pred[nz] - T[nz]) ** 2))
    assert rms < 0.35
    assert np.max(np.abs(pred[nz] - T[nz])) < 1.2
    # where Blue Robotics zeroed (< 300 RPM) the model gives less than the smallest measured thrust
    assert np.all(np.abs(pred[~nz]) < 0.6)


@needs_data
def test_refit_reproduces_the_shipped_coefficients():
    doc = th.fit_t200(DATA)
    shipped = th.curve_from_dict(_shipped_doc())
    refit = th.curve_from_dict(doc)
    assert doc["provenance"]["data_sha256"] == _shipped_doc()["provenance"]["data_sha256"]
    # The curve is only known to its fit residual (rms 0.13-0.39 N per voltage and direction); least_squares stops
    # at ftol/xtol 1e-8, so a refit with another BLAS/scipy lands ~1e-5 N away. Agreement to 1 % of the smallest
    # residual says "the same fit" without depending on one machine's last digits.
    rms_min = min(c[k]["rms_N"] for c in doc["curve"] for k in ("forward", "reverse"))
    pwm = np.arange(1100.0, 1901.0, 8.0)
    for volt in (10.0, 13.0, 20.0):
        np.testing.assert_allclose(th.pwm_to_thrust(pwm, volt, refit), th.pwm_to_thrust(pwm, volt, shipped),
                                   atol=0.01 * rms_min)


def test_shipped_layout_controls_surge_heave_roll_yaw_and_leaves_sway_pitch_passive():
    p = plant_parameters(load_model("pendulum:chin"))
    rep = th.actuated_dofs(p.T)
    assert rep.rank == 4
    assert rep.actuated == ("X", "Z", "K", "N")
    assert rep.passive == ("Y", "M") and rep.coupled == ()
    # a single oblique thruster acts on X and Y only together
    one = th.actuated_dofs(np.array([[1.0], [1.0], [0], [0], [0], [0]]))
    assert one.coupled == ("X", "Y") and one.rank == 1


def test_pinv_reproduces_achievable_wrenches():
    p = plant_parameters(load_model("cfd:chin"))
    rng = np.random.default_rng(3)
    f = rng.uniform(-5, 5, 4)
    tau = p.T @ f
    np.testing.assert_allclose(p.T @ th.thrust_allocation_pinv(p.T, tau), tau, atol=1e-12)


def test_osqp_allocation_respects_each_limit_and_reports_the_shortfall():
    p = plant_parameters(load_model("cfd:chin"))
    alloc = th.ThrustAllocator.from_parameters(p)
    rng = np.random.default_rng(4)
    for _ in range(30):
        tau = rng.normal(scale=[60, 5, 60, 6, 3, 8])
        r = alloc(tau)
        assert r.ok
        assert np.all(r.f >= p.f_min - 1e-7) and np.all(r.f <= p.f_max + 1e-7)
        np.testing.assert_allclose(r.unachieved, tau - p.T @ r.f, atol=1e-12)
        ref = lsq_linear(p.T, tau, bounds=(p.f_min, p.f_max), tol=1e-12)
        assert np.linalg.norm(r.unachieved) <= np.linalg.norm(tau - p.T @ ref.x) + 1e-4
    # a feasible request is met exactly; a too-large surge saturates both horizontal thrusters forward
    r = alloc(np.array([20.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(r.unachieved, 0, atol=1e-5)
    r = alloc(np.array([200.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(r.f[:2], p.f_max[:2], atol=1e-5)
    assert r.unachieved[0] == pytest.approx(200.0 - 2 * p.f_max[0], abs=1e-4)
    # reverse is weaker than forward: a reverse surge request saturates at the reverse limit
    r = alloc(np.array([-200.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(r.f[:2], p.f_min[:2], atol=1e-5)
    # unactuated sway cannot be produced at all and is reported
    r = alloc(np.array([0, 10.0, 0, 0, 0, 0]))
    assert r.unachieved[1] == pytest.approx(10.0, abs=1e-6)


def test_allocator_never_throws():
    T = plant_parameters(load_model("cfd:chin")).T
    alloc = th.ThrustAllocator(T, -np.ones(4), np.ones(4))
    r = alloc(np.array([np.nan, 0, 0, 0, 0, 0]))
    assert not r.ok and np.all(r.f == 0)
    r = alloc("garbage")
    assert not r.ok
    bad = th.ThrustAllocator(T, np.ones(4), -np.ones(4))  # inconsistent limits
    r = bad(np.array([1.0, 0, 0, 0, 0, 0]))
    assert not r.ok and "limits" in r.status and np.all(np.isfinite(r.f))
