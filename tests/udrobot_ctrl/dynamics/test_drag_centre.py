"""A centre of pressure off the CO (``drag_centre_offset``) and a tether tied off the CO (``attach_*_m``): dissipative,
moment r x F, the same in numpy, casadi and the compiled (numba) path, carried and checked by model files."""
import json

import casadi as ca
import numpy as np
import pytest

from tests.udrobot_ctrl.dynamics.test_effects_plant import assert_refused_on_load
from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics import plant_casadi
from udrobot_ctrl.dynamics.plant import generalized_forces, plant_parameters
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.vehicle import load_model, read_model_file, to_model_dict

BASE = load_model("bluerov2-heavy")
CENTRE = {"x_cp_m": 0.04, "y_cp_m": -0.03, "z_cp_m": 0.05}
ANCHOR = {"k_quadratic_N_s2_per_m2": 15.0, "k_linear_N_s_per_m": 2.0, "anchor_north_m": -6.0,
          "anchor_east_m": 2.0, "anchor_down_m": 0.0}
ATTACH = {"attach_x_m": -0.15, "attach_y_m": 0.02, "attach_z_m": -0.08}


def _plant(*effects):
    return plant_parameters(BASE.with_changes(effects=tuple(fx.PlantEffect(n, q) for n, q in effects)))


def _states(n=400, seed=0, scale=0.6):
    rng = np.random.default_rng(seed)
    x = rng.normal(scale=scale, size=(n, 12))
    x[:, 3:5] *= 0.5
    return x


def _drag(x, p):
    """The damping force on the vehicle, -(D_L nu + D_n(nu) nu) (N, N m), of the nominal plant ``p``."""
    nu = x[:, 6:]
    return -(nu @ p.D_L.T + (np.abs(nu) * nu) @ p.Q.T)


@pytest.mark.parametrize("seed", range(4))
def test_drag_at_a_centre_of_pressure_is_dissipative(seed):
    """Power of the total damping (the nominal drag plus the offset's change) <= 0 for random states and random
    centres within the vehicle's size: the drag acts on the centre's own velocity, F(v_cp) . v_cp <= 0."""
    rng = np.random.default_rng(seed)
    size = fx.vehicle_size([t.position for t in BASE.thrusters])
    x = _states(seed=seed)
    p0 = plant_parameters(BASE)
    for _ in range(5):
        r = dict(zip(fx.DRAG_CENTRE, rng.uniform(-size, size, 3)))
        p = _plant(("drag_centre_offset", r))
        added = generalized_forces(x, p0) - generalized_forces(x, p)  # the effect's force on the vehicle
        power = np.sum((_drag(x, p0) + added) * x[:, 6:], axis=1)
        assert power.max() <= 1e-12 * np.abs(power).max()
        assert np.abs(added).max() > 1e-3  # it acts


def test_the_moment_is_r_cross_the_drag_at_the_centre():
    x = _states(50, seed=1)
    r = np.array([CENTRE[k] for k in fx.DRAG_CENTRE])
    p0 = plant_parameters(BASE)
    q = {**CENTRE, **fx.drag_block(p0.D_L, p0.Q)}
    nu = x[:, 6:]
    out = np.stack(fx.drag_centre_force(fx.NUMPY, list(nu.T), q), axis=-1)
    v_cp = nu[:, :3] + np.cross(nu[:, 3:], r)
    F_cp = -(v_cp @ p0.D_L[:3, :3].T + (np.abs(v_cp) * v_cp) @ p0.Q[:3, :3].T)
    F_co = -(nu[:, :3] @ p0.D_L[:3, :3].T + (np.abs(nu[:, :3]) * nu[:, :3]) @ p0.Q[:3, :3].T)
    np.testing.assert_allclose(out[:, :3], F_cp - F_co, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(out[:, 3:], np.cross(r, F_cp), rtol=1e-12, atol=1e-12)
    # surging forward with the centre below the CO: the drag pushes the bottom back, the nose goes down
    one = np.array(fx.drag_centre_force(fx.NUMPY, [0.2, 0, 0, 0, 0, 0], {**q, "x_cp_m": 0.0, "y_cp_m": 0.0}))
    F_x = -(p0.D_L[0, 0] * 0.2 + p0.Q[0, 0] * 0.04)
    np.testing.assert_allclose(one, [0, 0, 0, 0, CENTRE["z_cp_m"] * F_x, 0], atol=1e-12)


def test_a_centre_at_the_co_changes_nothing():
    x = _states(30, seed=2)
    p = _plant(("drag_centre_offset", dict.fromkeys(fx.DRAG_CENTRE, 0.0)))
    np.testing.assert_allclose(generalized_forces(x, p), generalized_forces(x, plant_parameters(BASE)), atol=1e-12)


@pytest.mark.parametrize("effects", [
    (("drag_centre_offset", CENTRE),),
    (("drag_centre_offset", CENTRE), ("water_current", {"current_north_mps": 0.2, "current_east_mps": -0.1,
                                                         "current_down_mps": 0.0}),
     ("linear_damping", {f"d_{d}{v}": 2.0 for d, v in zip(fx.DOF, fx.VEL)})),
    (("tether_drag", {**ANCHOR, **ATTACH}),),
    (("tether_drag", {**ANCHOR, **ATTACH, "walk_azimuth_rad": 0.5, "walk_fraction": 1.0, "cable_taut": 1.0}),),
], ids=["centre", "centre+current+damping", "attached-tether", "attached-walking-taut-tether"])
def test_numpy_casadi_and_compiled_paths_agree(effects):
    """The compiled path (numba kernel of the nominal equations plus the numpy effect terms, one vehicle), the numpy
    equations (a batch axis) and the casadi twin give the same generalised force, to 1e-9."""
    p = _plant(*effects)
    x = _states(40, seed=3)
    compiled = generalized_forces(x, p)
    batched = generalized_forces(x[None], p)[0]
    X = ca.SX.sym("x", 12)
    f = ca.Function("F", [X], [plant_casadi.generalized_forces(X, p)])
    cas = np.array([np.asarray(f(xi)).ravel() for xi in x])
    np.testing.assert_allclose(batched, compiled, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(cas, compiled, rtol=1e-9, atol=1e-9)


def test_simulation_paths_agree_with_a_centre_of_pressure():
    v = BASE.with_changes(effects=(fx.PlantEffect("drag_centre_offset", CENTRE),))
    rng = np.random.default_rng(4)
    u = np.repeat(rng.uniform(-20, 25, size=(8, 8)), 20, axis=0)
    x0 = np.r_[0, 0, 5.0, np.zeros(9)]
    a = simulate(v, x0, 1.6, inputs=u, dt=0.01, method="rk4")  # casadi step of the same equations
    b = simulate(v, x0, 1.6, inputs=u, dt=0.01, method="rk4_numpy")
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-10)
    assert np.abs(a.x[-1, 6:]).max() > 0.05


def test_tether_attached_off_the_co_makes_the_moment_r_cross_f_and_stays_dissipative():
    x = _states(300, seed=5)
    x[:, :3] = np.random.default_rng(5).uniform([-8, -6, 0.3], [8, 6, 3.0], (300, 3))
    r = np.array([ATTACH[k] for k in fx.TETHER_ATTACH])
    p0 = plant_parameters(BASE)
    for geometry in (ANCHOR, {k: v for k, v in ANCHOR.items() if not k.startswith("anchor")}
                     | {"cable_azimuth_rad": 2.0, "cable_elevation_rad": 0.6}):
        w = np.stack(fx.tether_force(fx.NUMPY, list(x[:, :6].T), list(x[:, 6:].T), {**geometry, **ATTACH}), -1)
        np.testing.assert_allclose(w[:, 3:], np.cross(r, w[:, :3]), rtol=1e-12, atol=1e-12)
        power = np.sum(w * x[:, 6:], axis=1)  # F . (v + omega x r)
        assert power.max() <= 1e-12 and np.abs(w[:, 3:]).max() > 1e-3
        # the default attachment (0) is the old tether at the CO, with no moment
        p = _plant(("tether_drag", {**geometry, **dict.fromkeys(fx.TETHER_ATTACH, 0.0)}))
        q = _plant(("tether_drag", geometry))
        np.testing.assert_array_equal(generalized_forces(x, p), generalized_forces(x, q))
        assert np.all(generalized_forces(x, p)[:, 3:] == generalized_forces(x, p0)[:, 3:])


def test_model_file_round_trips_a_centre_of_pressure_and_an_attached_tether(tmp_path):
    v = BASE.with_changes(effects=(fx.PlantEffect("drag_centre_offset", CENTRE),
                                   fx.PlantEffect("tether_drag", {**ANCHOR, **ATTACH})))
    path = tmp_path / "corrected.json"
    path.write_text(json.dumps(to_model_dict(v)))
    back = read_model_file(path)
    assert back.effects == v.effects
    x = _states(20, seed=6)
    np.testing.assert_array_equal(generalized_forces(x, plant_parameters(back)),
                                  generalized_forces(x, plant_parameters(v)))


@pytest.mark.parametrize("entry, message", [
    ({"name": "drag_centre_offset", "params": {**CENTRE, "z_cp_m": 0.4}},
     r"drag_centre_offset.*z_cp_m = 0.4 is outside \[-0.2488.*, 0.2488.*\] m .*largest distance of a thruster"),
    ({"name": "drag_centre_offset", "params": {**CENTRE, "x_cp_m": 7.0}},
     r"x_cp_m = 7 is outside its physical range \[-5, 5\]"),
    ({"name": "drag_centre_offset", "params": {"x_cp_m": 0.0, "y_cp_m": 0.0}}, "misses parameter.*z_cp_m"),
    ({"name": "drag_centre_offset", "params": {**CENTRE, "z_cp": 0.0}}, "did you mean 'z_cp_m'"),
    ({"name": "tether_drag", "params": {**ANCHOR, **ATTACH, "attach_x_m": -0.3}},
     r"tether_drag.*attach_x_m = -0.3 is outside \[-0.2488.*\] m"),
])
def test_out_of_range_points_are_refused_on_load(tmp_path, entry, message):
    assert_refused_on_load(tmp_path, BASE, entry, message)


def test_a_model_without_thrusters_takes_the_assumed_size():
    assert fx.vehicle_size(None) == fx.ASSUMED_VEHICLE_SIZE_M == fx.vehicle_size([])
    with pytest.raises(ValueError, match="assumed"):
        fx.check_against_model((fx.PlantEffect("drag_centre_offset", {**CENTRE, "x_cp_m": 0.6}),),
                               linear_damping=np.eye(6), quadratic_damping=np.eye(6), buoyancy=1.0, weight=1.0)
