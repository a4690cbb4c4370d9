"""Physics of the tether template: cross-flow drag normal to the cable."""
import numpy as np
import pytest

from udrobot_ctrl.dynamics.effects import TETHER_SPEED_FLOOR
from udrobot_ctrl.dynamics.effects import cable_direction as _cable_direction
from udrobot_ctrl.dynamics.plant import plant_parameters, rotation_zyx
from udrobot_ctrl.gap.effects import Actuation, catalogue
from udrobot_ctrl.vehicle import load_model


def _tether_force(az, el, x, kq=10.0, kl=2.0):
    p = plant_parameters(load_model("pendulum:chin"))
    params = {"cable_azimuth_rad": az, "cable_elevation_rad": el, "k_quadratic_N_s2_per_m2": kq,
              "k_linear_N_s_per_m": kl}
    hooks = catalogue()["tether_drag"].hooks(params, p, Actuation(None, None, None, None))
    return hooks.force(x, None, {})


def _state(rng, n=50):
    x = np.zeros((n, 12))
    x[:, 3:6] = rng.uniform(-0.4, 0.4, (n, 3))
    x[:, 6:12] = rng.uniform(-0.6, 0.6, (n, 6))
    return x


def cable_direction(azimuth, elevation):
    return np.asarray(_cable_direction(azimuth, elevation))


def test_cable_direction_is_unit_and_vertical_at_90_deg():
    assert np.linalg.norm(cable_direction(1.3, 0.4)) == pytest.approx(1.0)
    assert cable_direction(0.7, np.pi / 2) == pytest.approx(np.array([0.0, 0.0, -1.0]), abs=1e-12)


def test_vertical_cable_is_horizontal_drag_opposing_motion():
    rng = np.random.default_rng(0)
    x = _state(rng)
    F = _tether_force(0.0, np.pi / 2, x)
    R = rotation_zyx(x[:, 3], x[:, 4], x[:, 5])
    F_ned = np.einsum("nij,nj->ni", R, F[:, :3])
    V = np.einsum("nij,nj->ni", R, x[:, 6:9])
    Vh = V.copy()
    Vh[:, 2] = 0.0
    # |V_n| carries the template's regularisation floor (1e-4 m/s: a finite Jacobian at rest, 1e-8 relative here)
    speed = np.sqrt(np.sum(Vh ** 2, axis=1, keepdims=True) + TETHER_SPEED_FLOOR ** 2)
    expect = -(10.0 * speed + 2.0) * Vh
    assert F_ned == pytest.approx(expect, abs=1e-10)
    assert np.all(np.sum(F_ned * V, 1) <= 1e-12)  # drag never adds energy
    assert np.all(F[:, 3:] == 0.0)  # lumped at the body origin


def test_motion_along_the_cable_has_no_drag_and_normal_motion_full_drag():
    az, el = np.radians(160.0), np.radians(20.0)
    e = cable_direction(az, el)
    x = np.zeros((2, 12))
    x[0, 6:9] = 0.5 * e  # level attitude: body velocity = NED velocity
    n = np.cross(e, [0.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    x[1, 6:9] = 0.5 * n
    F = _tether_force(az, el, x)
    assert np.abs(F[0]).max() < 1e-12
    speed = np.sqrt(0.5 ** 2 + TETHER_SPEED_FLOOR ** 2)
    assert F[1, :3] == pytest.approx(-(10.0 * speed + 2.0) * 0.5 * n, abs=1e-12)
