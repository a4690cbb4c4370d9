"""The plant's domain checked on a replayed trajectory (issue 58.4): above the surface, inverted, a thruster held
at its limit; one pure check (udrobot_ctrl.dynamics.domain) that simulate and diagnose both call."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.dynamics.domain import (
    ABOVE_SURFACE,
    INVERTED,
    SATURATION_TOLERANCE,
    THRUST_SATURATED,
    domain_check,
    thrust_limits,
)
from udrobot_ctrl.dynamics.thrusters import PWM_MAX, PWM_MIN, pwm_to_thrust

DT = 0.05


def _state(n):
    x = np.zeros((n, 12))
    x[:, 2] = 1.0  # 1 m deep, level
    return x


def test_a_replay_that_rises_through_the_surface_is_named_over_the_samples_above_it():
    t = np.arange(0.0, 10.0, DT)
    x = _state(t.size)
    x[:, 2] = 0.5 - 0.25 * t  # through z = 0 at t = 2 s, back below at none: above from 2.05 s to the end
    chk = domain_check(t, x)
    (span,) = chk.spans
    assert span.code == ABOVE_SURFACE and chk.codes == (ABOVE_SURFACE,)
    assert span.t0 == pytest.approx(t[np.flatnonzero(x[:, 2] < 0)[0]]) and span.t1 == pytest.approx(t[-1])
    assert chk.to_json() == {"codes": [ABOVE_SURFACE], "spans": [{"code": ABOVE_SURFACE, "t0": round(span.t0, 3),
                                                                  "t1": round(t[-1], 3)}]}


def test_at_the_waterline_itself_and_upright_at_80_degrees_of_roll_the_replay_is_in_the_domain():
    t = np.arange(0.0, 4.0, DT)
    x = _state(t.size)
    x[:, 2] = 0.0
    x[:, 3] = np.radians(80.0)  # beyond ArduSub's default ANGLE_MAX (45 deg) but still keel down
    assert not domain_check(t, x) and domain_check(t, x).codes == ()


def test_rolled_or_pitched_past_90_degrees_is_inverted_and_both_past_is_upright_again():
    t = np.arange(0.0, 6.0, DT)
    x = _state(t.size)
    x[:, 3] = np.where((t >= 1.0) & (t < 2.0), np.radians(120.0), 0.0)  # rolled over for 1 s
    x[:, 4] = np.where((t >= 4.0) & (t < 4.5), np.radians(-100.0), 0.0)  # pitched over, nose down, 0.5 s
    spans = domain_check(t, x).spans
    assert [(s.code, s.t0, s.t1) for s in spans] == [(INVERTED, pytest.approx(1.0), pytest.approx(1.95)),
                                                      (INVERTED, pytest.approx(4.0), pytest.approx(4.45))]
    x[:, 3] = x[:, 4] = np.pi  # rolled and pitched by 180 deg: the same attitude as yawed by 180 deg, upright
    assert not domain_check(t, x)


def test_a_thruster_at_its_limit_counts_from_the_stated_duration_on_and_a_nan_row_breaks_the_stretch():
    t = np.arange(0.0, 20.0, DT)
    x = _state(t.size)
    f_lo, f_hi = np.array([-30.0, -30.0]), np.array([40.0, 40.0])
    f = np.zeros((t.size, 2))
    f[(t >= 2.0) & (t < 7.0), 0] = 40.0  # 5 s at the forward limit
    f[(t >= 10.0) & (t < 13.0), 0] = 40.0  # 3 s: shorter than 4 s
    f[(t >= 8.0) & (t < 13.0), 1] = -30.0 * (1 - SATURATION_TOLERANCE / 2)  # 5 s within the tolerance of reverse
    f[(t >= 14.0) & (t < 19.0), 1] = -30.0 * (1 - 2 * SATURATION_TOLERANCE)  # 5 s just short of the limit
    chk = domain_check(t, x, f, f_lo, f_hi, saturation_s=4.0)
    assert [(s.code, s.thruster, round(s.t0, 6), round(s.t1, 6)) for s in chk.spans] == [
        (THRUST_SATURATED, 0, 2.0, 6.95), (THRUST_SATURATED, 1, 8.0, 12.95)]
    assert chk.spans[0].to_json()["thruster"] == 0 and chk.saturation_s == 4.0
    x[int(round(4.0 / DT))] = np.nan  # a row outside the replay (between windows): 2.0-3.95 and 4.05-6.95
    assert [s.thruster for s in domain_check(t, x, f, f_lo, f_hi, saturation_s=4.0).spans] == [1]
    assert not domain_check(t, x, f)  # no limits given: no saturation check is possible
    assert domain_check(t, x, f, f_lo, f_hi, saturation_s=2.9).spans[1].t0 == pytest.approx(10.0)


def test_pwm_limits_are_the_curve_at_the_logged_voltage_so_1900_us_on_a_low_battery_is_saturated():
    """A T-200 at 1900 us on a 12 V battery gives less than the model's 14.8 V limit: still the end of its range."""
    f_min, f_max = np.full(2, -40.0), np.full(2, 50.0)
    volts = np.array([16.0, 12.0])
    lo, hi = thrust_limits(f_min, f_max, "pwm", volts)
    assert lo.shape == hi.shape == (2, 2)
    assert hi[1, 0] == pytest.approx(min(pwm_to_thrust(PWM_MAX, 12.0), 50.0))
    assert lo[1, 0] == pytest.approx(max(pwm_to_thrust(PWM_MIN, 12.0), -40.0))
    t = np.arange(0.0, 6.0, DT)
    f = np.full((t.size, 2), pwm_to_thrust(PWM_MAX, 12.0))
    lo_n, hi_n = thrust_limits(f_min, f_max, "pwm", np.full(t.size, 12.0))
    assert [s.thruster for s in domain_check(t, _state(t.size), f, lo_n, hi_n).spans] == [0, 1]
    assert thrust_limits(f_min, f_max, "tau") == (None, None)
    assert np.array_equal(thrust_limits(f_min, f_max, "thrust")[1], f_max)


@pytest.mark.parametrize("model", ["bluerov2-heavy", "bluerov2"])
def test_idle_drift_is_the_speed_the_plant_itself_settles_at_with_no_thrust(model):
    """With its motors at neutral (a disarmed ArduSub) the fully submerged plant drifts at its own net buoyancy: the
    heavy model sinks, the buoyant one rises, each at the speed idle_drift gives, however shallow it starts."""
    from udrobot_ctrl.dynamics.domain import idle_drift
    from udrobot_ctrl.dynamics.plant import plant_parameters
    from udrobot_ctrl.dynamics.sim import simulate
    from udrobot_ctrl.vehicle import load_model

    vehicle = load_model(model)
    p = plant_parameters(vehicle)
    drift = idle_drift(p)
    assert np.sign(drift.speed) == np.sign(p.weight - p.buoyancy) != 0
    x0 = np.zeros(12)
    x0[2] = 0.02  # at the waterline, where a floating vehicle would stay
    res = simulate(vehicle, x0, 20.0, inputs=np.zeros((2000, p.T.shape[1])), dt=0.01)
    w_end = res.x[-1, 8]
    assert w_end == pytest.approx(drift.speed, rel=0.01)
    assert (res.x[-1, 2] - x0[2]) * drift.speed > 0  # it leaves the waterline: the plant has nothing to float on
    assert drift.over(10.0) == pytest.approx(10.0 * drift.speed)
