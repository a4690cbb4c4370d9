"""Catalogue effects as parts of the plant: twins agree, each effect has its physics, model files carry them."""
import json

import casadi as ca
import numpy as np
import pytest

from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics import plant_casadi
from udrobot_ctrl.dynamics.plant import (
    delivered_wrench,
    generalized_forces,
    kinematics,
    plant_parameters,
    rotation_zyx,
    state_derivative,
)
from udrobot_ctrl.dynamics.sim import Actuators, simulate
from udrobot_ctrl.gap.effects import Actuation, plant_hooks
from udrobot_ctrl.vehicle import load_model, read_model_file, to_model_dict

NOMINAL = load_model("pendulum:chin")

EXAMPLES = {
    "thrust_inflow_loss": {"k1_per_mps": 0.3, "k2_per_mps": 0.1},
    "thruster_lag": {"T_lag_s": 0.3},
    "thruster_deadband": {"width_fraction": 0.1, "shift": 1.0},
    "thruster_asymmetry": {"reverse_loss": 0.3},
    "tether_drag": {"k_quadratic_N_s2_per_m2": 20.0, "k_linear_N_s_per_m": 2.0, "anchor_north_m": -3.0,
                    "anchor_east_m": 0.5, "anchor_down_m": -0.3},
    "wall_effect": {"decay_length_m": 0.2, "added_mass_at_contact_kg": 8.0, "suction_N_s2_per_m2": 30.0,
                    "seabed_depth_m": 2.0, **fx.wall_parameters([{"point": [0.0, 0.5, 0.0], "normal": [0, -2.0, 0]}])},
    "water_current": {"current_north_mps": 0.2, "current_east_mps": -0.1, "current_down_mps": 0.02},
    "linear_damping": {f"d_{d}{v}": 3.0 for d, v in zip(fx.DOF, fx.VEL)},
    "quadratic_damping_error": {f"scale_{d}{v}|{v}|": 0.5 for d, v in zip(fx.DOF, fx.VEL)},
    "added_mass_error": {f"scale_{d}d{v}": 0.4 for d, v in zip(fx.DOF, fx.VEL)},
    "cross_coupled_damping": {"D_Xv": 2.0, "Q_Zu|u|": 5.0, "D_Nv": 0.5},
    "buoyancy_offset": {"dB_N": 3.0},
    "cg_cb_offset": {"dBG_x_Nm": 0.2, "dBG_y_Nm": -0.1, "dBG_z_Nm": 0.3},
    "drag_centre_offset": {"x_cp_m": 0.04, "y_cp_m": -0.02, "z_cp_m": 0.06},
}


def _with(*names):
    return NOMINAL.with_changes(effects=tuple(fx.PlantEffect(n, EXAMPLES[n]) for n in names))


def _states(n=7, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.normal(scale=0.4, size=(n, 12))
    x[:, 2] = rng.uniform(1.2, 1.95, n)  # depth near the seabed of the wall example
    x[:, 3:5] *= 0.5
    f = rng.uniform(-25, 30, size=(n, 4))
    f[0] = [0.5, -0.5, 1.0, -1.0]  # inside the deadband
    return x, f


def test_every_catalogue_effect_has_a_plant_form():
    assert set(EXAMPLES) == set(fx.EFFECT_NAMES)


@pytest.mark.parametrize("name", [n for n in fx.EFFECT_NAMES if n != "thruster_lag"])
def test_numpy_and_casadi_plants_agree_with_the_effect(name):
    p = plant_parameters(_with(name))
    f_cas = plant_casadi.dynamics_function(p, "thrust")
    x, f = _states()
    maps = fx.thrust_effects(p.effects)
    for xi, fi in zip(x, f):
        fd = np.array(fx.static_thrust(fx.NUMPY, list(fi), maps, p.f_ref, p.capacities), float)
        ref = state_derivative(xi, delivered_wrench(xi, fd, p), p)
        np.testing.assert_allclose(np.asarray(f_cas(xi, fi)).ravel(), ref, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("a", [0.0, 0.5, 1.0])
def test_quadratic_damping_error_on_the_speed_norm_in_numpy_and_casadi(a):
    """-s_i Q_ii ((1 - a)|nu_i| + a |nu_g|) nu_i added to the nominal drag, the same in both twins; the norm part is
    a run-time force (a = 0 is folded into Q, as before)."""
    params = {**EXAMPLES["quadratic_damping_error"], "norm_weight": a}
    p0 = plant_parameters(NOMINAL)
    p = plant_parameters(NOMINAL.with_changes(effects=(fx.PlantEffect("quadratic_damping_error", params),)))
    assert len(p.effects) == (a > 0)
    x, _ = _states()
    nu = x[:, 6:]
    speed = np.concatenate([np.repeat(np.linalg.norm(nu[:, g], axis=1, keepdims=True), 3, axis=1)
                            for g in (slice(0, 3), slice(3, 6))], axis=1)
    extra = 0.5 * np.diag(p0.Q) * ((1 - a) * np.abs(nu) + a * speed) * nu  # EXAMPLES: every scale 0.5
    nominal_rhs = np.array([state_derivative(xi, np.zeros(6), p0) for xi in x])[:, 6:] @ np.asarray(p0.M).T
    rhs = np.array([state_derivative(xi, np.zeros(6), p) for xi in x])[:, 6:] @ np.asarray(p.M).T
    np.testing.assert_allclose(nominal_rhs - rhs, extra, rtol=1e-8, atol=1e-8)
    xs = ca.SX.sym("x", 12)
    twin = ca.Function("g", [xs], [plant_casadi.generalized_forces(xs, p)])
    np.testing.assert_allclose(np.vstack([np.asarray(twin(xi)).ravel() for xi in x]), generalized_forces(x, p),
                               rtol=1e-9, atol=1e-9)
    jac = ca.Function("j", [xs], [ca.jacobian(plant_casadi.generalized_forces(xs, p), xs)])
    assert np.isfinite(np.asarray(jac(np.zeros(12)))).all()  # linearisable at rest


#: the fixed-direction tether of model files written before anchors (the limit of a far anchor)
FIXED_TETHER = {"k_quadratic_N_s2_per_m2": 20.0, "k_linear_N_s_per_m": 2.0, "cable_azimuth_rad": 2.5,
                "cable_elevation_rad": 0.4}


#: a handler walking north along the pool edge (y = 0), 3.5 m behind the vehicle
WALKING_TETHER = {"k_quadratic_N_s2_per_m2": 20.0, "k_linear_N_s_per_m": 2.0, "anchor_north_m": -3.5,
                  "anchor_east_m": 0.0, "anchor_down_m": 0.0, "walk_azimuth_rad": 0.0, "walk_fraction": 1.0}


@pytest.mark.parametrize("tether", [FIXED_TETHER, WALKING_TETHER, {**WALKING_TETHER, "cable_taut": 1.0}],
                         ids=["fixed_direction", "walking", "walking_taut"])
def test_numpy_and_casadi_plants_agree_with_a_fixed_direction_or_walking_tether(tether):
    p = plant_parameters(NOMINAL.with_changes(effects=(fx.PlantEffect("tether_drag", tether),)))
    f_cas = plant_casadi.dynamics_function(p, "thrust")
    x, f = _states()
    for xi, fi in zip(x, f):
        ref = state_derivative(xi, delivered_wrench(xi, fi, p), p)
        np.testing.assert_allclose(np.asarray(f_cas(xi, fi)).ravel(), ref, rtol=1e-9, atol=1e-9)


def _tether_ned(params, x):
    X = np.moveaxis(x, -1, 0)
    F = np.stack(fx.external_force(fx.NUMPY, X[:6], X[6:], (fx.PlantEffect("tether_drag", params),)), -1)
    return np.einsum("nij,nj->ni", rotation_zyx(x[:, 3], x[:, 4], x[:, 5]), F[:, :3])


def test_anchored_tether_turns_with_the_vehicle_and_never_resists_motion_towards_the_anchor():
    q = EXAMPLES["tether_drag"]
    anchor = np.array([q["anchor_north_m"], q["anchor_east_m"], q["anchor_down_m"]])
    x, _ = _states(40, seed=4)
    x[:, :3] = np.random.default_rng(4).uniform([-8, -6, 0.5], [8, 6, 3], (40, 3))  # all around the anchor
    e = anchor - x[:, :3]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    R = rotation_zyx(x[:, 3], x[:, 4], x[:, 5])
    toward = x.copy()
    toward[:, 6:9] = np.einsum("nji,nj->ni", R, 0.4 * e)  # body velocity of 0.4 m/s straight at the anchor
    np.testing.assert_allclose(_tether_ned(q, toward), 0.0, atol=1e-12)
    V = np.einsum("nij,nj->ni", R, x[:, 6:9])
    Vn = V - np.sum(V * e, 1, keepdims=True) * e
    speed = np.sqrt(np.sum(Vn ** 2, 1, keepdims=True) + fx.TETHER_SPEED_FLOOR ** 2)
    np.testing.assert_allclose(_tether_ned(q, x), -(20.0 * speed + 2.0) * Vn, rtol=1e-10, atol=1e-12)


def test_a_far_anchor_is_the_fixed_direction():
    az, el = FIXED_TETHER["cable_azimuth_rad"], FIXED_TETHER["cable_elevation_rad"]
    far = 1e7  # m: the direction differs by < |position| / far ~ 1e-6 rad over the states below
    e = np.array(fx.cable_direction(az, el))
    q = {"k_quadratic_N_s2_per_m2": 20.0, "k_linear_N_s_per_m": 2.0, "anchor_north_m": far * e[0],
         "anchor_east_m": far * e[1], "anchor_down_m": far * e[2]}
    x, _ = _states(30, seed=6)
    np.testing.assert_allclose(_tether_ned(q, x), _tether_ned(FIXED_TETHER, x), rtol=1e-5, atol=1e-6)


def _cable_drag_ned(x, top, top_v, kq, kl, nodes=4000):
    """Reference: the cable from ``top`` (moving at ``top_v``) to the vehicle cut into ``nodes`` pieces, each
    dragged by the water normal to the cable and shared with the vehicle in proportion to its distance from the top
    (the lumped amplitudes normalised so that a fixed top end gives -(kq |V_n| + kl) V_n)."""
    R = rotation_zyx(x[3], x[4], x[5])
    v = R @ x[6:9]
    e = (top - x[:3]) / np.linalg.norm(top - x[:3])
    s = (np.arange(nodes) + 0.5) / nodes
    vs = top_v + s[:, None] * (v - top_v)
    vn = vs - (vs @ e)[:, None] * e
    sp = np.linalg.norm(vn, axis=1, keepdims=True)
    return -np.mean(s[:, None] * (4 * kq * sp + 3 * kl) * vn, axis=0)


def test_a_walking_top_end_drags_the_cable_along_with_the_vehicle():
    """A top end that walks with the vehicle (a handler on the pool edge): the plant's 3-node integral matches a
    finely cut cable within 1 %; surging along the walk with the cable along it drags nothing; with the cable
    oblique, twice what a fixed top end would (the whole cable moves); a walk fraction near 0 is the fixed anchor."""
    q = WALKING_TETHER
    x, _ = _states(25, seed=8)
    x[:, :3] = np.random.default_rng(8).uniform([-5, -2.5, 0.5], [5, -0.3, 2.0], (25, 3))
    got = _tether_ned(q, x)
    R = rotation_zyx(x[:, 3], x[:, 4], x[:, 5])
    for xi, gi, Ri in zip(x, got, R):
        vn_north = (Ri @ xi[6:9])[0]
        top = np.array([xi[0] - 3.5, 0.0, 0.0])
        ref = _cable_drag_ned(xi, top, np.array([vn_north, 0.0, 0.0]), 20.0, 2.0)
        assert np.linalg.norm(gi - ref) <= 0.01 * np.linalg.norm(ref) + 1e-9, (gi, ref)
    along = x[:5].copy()
    along[:, :3] = [[0.0, 0.0, 1e-9]] * 5  # on the walking line, at the surface: the cable lies along north
    along[:, 3:6] = 0.0
    along[:, 6:12] = [[0.5, 0, 0, 0, 0, 0]] * 5
    fixed = {k: v for k, v in q.items() if not k.startswith("walk_")}
    assert np.abs(_tether_ned(q, along)).max() < 1e-3
    assert np.abs(_tether_ned(fixed, along)).max() < 1e-3  # along the cable: no normal drag either way
    # off the line the cable is oblique: moving along the walk, the whole cable moves with the vehicle (4 int s ds
    # = 2 x the quadratic drag of a fixed top end, whose cable points move at s V)
    oblique = along.copy()
    oblique[:, 1] = -2.0
    quad = {**q, "k_linear_N_s_per_m": 0.0}
    fixed_quad = {**fixed, "k_linear_N_s_per_m": 0.0}
    np.testing.assert_allclose(_tether_ned(quad, oblique), 2.0 * _tether_ned(fixed_quad, oblique), rtol=1e-6)
    assert np.linalg.norm(_tether_ned(fixed_quad, oblique)[0]) > 0.1
    np.testing.assert_allclose(_tether_ned({**q, "walk_fraction": 1e-12}, x), _tether_ned(fixed, x), rtol=1e-6,
                               atol=1e-9)


def test_a_taut_cable_drags_in_proportion_to_its_length_and_a_slack_one_does_not():
    q = {**EXAMPLES["tether_drag"], "anchor_north_m": 0.0, "anchor_east_m": 0.0, "anchor_down_m": 0.0}
    x, _ = _states(2, seed=5)
    x[:, 3:6] = 0.0
    x[:, :3] = [[2.0, 0.0, 1.0], [4.0, 0.0, 2.0]]  # the same cable direction, 2.24 m and 4.47 m from the anchor
    x[:, 6:12] = [[0.0, 0.4, 0.0, 0.0, 0.0, 0.0]] * 2  # sway: across the cable
    slack, taut = _tether_ned(q, x), _tether_ned({**q, "cable_taut": 1.0}, x)
    np.testing.assert_allclose(slack[1], slack[0], rtol=1e-9)  # a fixed paid-out length
    np.testing.assert_allclose(taut[0], np.hypot(2.0, 1.0) * slack[0], rtol=1e-9)  # per metre of the line
    np.testing.assert_allclose(taut[1], 2.0 * taut[0], rtol=1e-9)
    half = _tether_ned({**q, "cable_taut": 0.5}, x)  # a blend of the two
    np.testing.assert_allclose(half, 0.5 * (slack + taut), rtol=1e-9)


def test_tools_without_actuator_states_refuse_a_lag():
    p = plant_parameters(_with("thruster_lag"))
    with pytest.raises(ValueError, match="thruster_lag"):
        plant_casadi.dynamics_function(p, "thrust")


def test_parameter_effects_change_the_matrices_they_name():
    p0 = plant_parameters(NOMINAL)
    p = plant_parameters(_with("linear_damping", "added_mass_error", "buoyancy_offset", "cg_cb_offset"))
    np.testing.assert_allclose(np.diag(p.D_L), np.diag(p0.D_L) + 3.0)
    np.testing.assert_allclose(np.diag(p.M_A), 1.4 * np.diag(p0.M_A))
    assert p.buoyancy == pytest.approx(p0.buoyancy + 3.0)
    bg0 = p0.r_g * p0.weight - p0.r_b * p0.buoyancy
    bg = p.r_g * p.weight - p.r_b * p.buoyancy
    np.testing.assert_allclose(bg - bg0, [0.2, -0.1, 0.3], atol=1e-12)
    assert p.effects == ()  # nothing left for run time


def test_buoyancy_offset_lifts_the_vehicle_by_dB_over_the_heave_mass():
    p0, p = plant_parameters(NOMINAL), plant_parameters(_with("buoyancy_offset"))
    x = np.zeros(12)
    dw = state_derivative(x, np.zeros(6), p)[8] - state_derivative(x, np.zeros(6), p0)[8]
    assert dw == pytest.approx(-3.0 * p.M_inv[2, 2], rel=1e-9)  # positive buoyancy accelerates upwards (-z)


def test_current_carries_a_free_vehicle_at_the_current_velocity():
    p = plant_parameters(_with("water_current").with_changes(
        effects=(fx.PlantEffect("water_current", {"current_north_mps": 0.2, "current_east_mps": -0.1,
                                                  "current_down_mps": 0.0}),)))
    res = simulate(p, np.r_[0, 0, 1.0, np.zeros(9)], 80.0, dt=0.02, input_kind="thrust")
    ned = kinematics(res.x[-1, :6], res.x[-1, 6:])[:2]  # moving with the water, nothing acts on it any more
    np.testing.assert_allclose(ned, [0.2, -0.1], atol=0.01)


def test_tether_drag_is_dissipative_and_a_vertical_cable_does_not_resist_heave():
    p = plant_parameters(_with("tether_drag"))
    x, _ = _states(50, seed=3)
    X = np.moveaxis(x, -1, 0)
    F = np.stack(fx.external_force(fx.NUMPY, X[:6], X[6:], p.effects), -1)
    power = np.sum(F[:, :3] * x[:, 6:9], axis=1)
    assert np.all(power <= 1e-12)
    up = fx.PlantEffect("tether_drag", {**FIXED_TETHER, "cable_elevation_rad": np.pi / 2})
    heave = np.zeros((1, 12))
    heave[0, 8] = 0.5
    H = np.moveaxis(heave, -1, 0)
    np.testing.assert_allclose(np.stack(fx.external_force(fx.NUMPY, H[:6], H[6:], (up,)), -1), 0.0, atol=1e-12)


def test_wall_effect_adds_mass_and_suction_only_near_the_seabed():
    p = plant_parameters(_with("wall_effect"))
    near, far = np.zeros(12), np.zeros(12)
    near[2], far[2] = 1.98, 0.5  # seabed at 2 m
    near[6] = far[6] = 0.5  # gliding along it
    for x, expect in ((near, True), (far, False)):
        X = x[:, None]
        dM = fx.added_mass_increment(fx.NUMPY, X[:6], X[6:], p.effects)
        F = np.ravel(fx.external_force(fx.NUMPY, X[:6], X[6:], p.effects))
        assert (float(np.ravel(dM[2][2])[0]) > 1.0) == expect
        assert (F[2] > 0.5) == expect  # suction pulls down (+z) towards the seabed


def test_a_side_wall_adds_mass_along_its_normal_and_pulls_a_vehicle_gliding_along_it():
    """Wall plane y = 0.5 m, water on y < 0.5 (normal given unnormalised): 2 cm from it, surging at 0.5 m/s, the
    vehicle gets a_m e^(-h/lam) of sway added mass and a_s e^(-h/lam) u^2 of suction towards +y; 2 m from it
    (10 decay lengths), nothing."""
    q = EXAMPLES["wall_effect"]
    p = plant_parameters(_with("wall_effect"))
    for y, expect in ((0.48, True), (-1.5, False)):
        x = np.zeros(12)
        x[1], x[2], x[6] = y, 0.5, 0.5
        X = x[:, None]
        dM = np.array([[float(np.ravel(c)[0]) for c in row] for row in fx.added_mass_increment(fx.NUMPY, X[:6],
                                                                                             X[6:], p.effects)])
        F = np.ravel(fx.external_force(fx.NUMPY, X[:6], X[6:], p.effects))
        decay = np.exp(-(0.5 - y) / q["decay_length_m"])  # the seabed acts along z only
        if expect:
            assert dM[1, 1] == pytest.approx(q["added_mass_at_contact_kg"] * decay, rel=1e-9)
            assert F[1] == pytest.approx(q["suction_N_s2_per_m2"] * decay * 0.25, rel=1e-9)
        else:
            assert dM[1, 1] < 1e-3 and abs(F[1]) < 1e-3
        assert dM[0, 0] == pytest.approx(0.0, abs=1e-12)  # nothing along the wall


def test_deadband_and_asymmetry_shape_the_delivered_thrust():
    db = (fx.PlantEffect("thruster_deadband", EXAMPLES["thruster_deadband"]),)
    ref = np.full(2, 30.0)
    out = fx.static_thrust(fx.NUMPY, [np.array(2.0), np.array(10.0)], db, ref)
    assert float(out[0]) == 0.0 and float(out[1]) == pytest.approx(10.0 - 3.0)
    asym = (fx.PlantEffect("thruster_asymmetry", {"reverse_loss": 0.3}),)
    out = fx.static_thrust(fx.NUMPY, [np.array(-10.0), np.array(10.0)], asym, ref)
    assert float(out[0]) == pytest.approx(-7.0) and float(out[1]) == 10.0


def test_deadband_acts_before_the_reverse_loss_whatever_the_list_order():
    """-4 N with a 3 N shifted deadband and a 50 % reverse loss: (-4 + 3) x 0.5 = -0.5 N (deadband first); the other
    order would give -4 x 0.5 = -2 -> inside the deadband -> 0. The plant and the diagnoser's replay hooks agree."""

    db = fx.PlantEffect("thruster_deadband", EXAMPLES["thruster_deadband"])
    asym = fx.PlantEffect("thruster_asymmetry", {"reverse_loss": 0.5})
    ref = np.full(1, 30.0)
    for effects in ((db, asym), (asym, db)):
        assert float(fx.static_thrust(fx.NUMPY, [np.array(-4.0)], effects, ref)[0]) == pytest.approx(-0.5)
        p = plant_parameters(NOMINAL)
        hooks = sorted((plant_hooks(e, p, Actuation(np.eye(6)[:, :1], np.eye(6)[:, :1], ref, p.M_A)) for e in effects),
                       key=lambda h: h.order)
        f = np.array([[-4.0]])
        for h in hooks:
            f = h.input_filter(f, 0.05)
        assert float(f[0, 0]) == pytest.approx(-0.5)


def _deadband(w, p, shift, **more):
    return (fx.PlantEffect("thruster_deadband", {"width_fraction": w, "shift": shift, "command_exponent": p,
                                                 **more}),)


def test_command_domain_deadband_at_p2_is_the_rescaled_pwm_deadband():
    """p = 2: thrust f_ref u^2 of the normalised command u; the ESC cuts u < w and, continuous (shift 1), delivers
    f_ref ((u - w) / (1 - w))^2 beyond: zero at the edge, full thrust at full command. A shift c blends it
    linearly with the hard cut (the nominal curve beyond w)."""
    ref, w = 30.0, 0.25
    f = np.linspace(-ref, ref, 241)
    u = np.sqrt(np.abs(f) / ref)
    rescaled = np.sign(f) * ref * (np.clip(u - w, 0.0, None) / (1.0 - w)) ** 2
    hard = np.where(u < w, 0.0, f)
    for c in (0.0, 0.4, 1.0):
        out = fx.static_thrust(fx.NUMPY, [f], _deadband(w, 2.0, c), [ref])[0]
        np.testing.assert_allclose(out, (1.0 - c) * hard + c * rescaled, rtol=1e-12, atol=1e-12)
    out = fx.static_thrust(fx.NUMPY, [np.array([ref, -ref, w ** 2 * ref * 0.999])], _deadband(w, 2.0, 1.0), [ref])[0]
    np.testing.assert_allclose(out, [ref, -ref, 0.0], atol=1e-12)  # full at full command, nothing inside


def test_command_exponent_one_is_the_old_deadband_exactly():
    """p = 1 (or no command_exponent in the model file): f -> 0 for |f| < d, f - shift d sign(f) beyond."""
    ref, w, c = 30.0, 0.1, 0.7
    f = np.linspace(-ref, ref, 301)
    old = np.where(np.abs(f) < w * ref, 0.0 * f, f - c * w * ref * np.sign(f))
    for effects in (_deadband(w, 1.0, c), (fx.PlantEffect("thruster_deadband", {"width_fraction": w, "shift": c}),)):
        np.testing.assert_array_equal(fx.static_thrust(fx.NUMPY, [f], effects, [ref])[0], old)
        # symmetric in thrust at p = 1 whatever the thruster's reverse capacity
        np.testing.assert_array_equal(fx.static_thrust(fx.NUMPY, [f], effects, [ref], ([ref], [0.7 * ref]))[0], old)


def test_command_domain_deadband_is_the_same_in_numpy_casadi_and_the_replay():
    """The casadi twin evaluates the same map (with a finite slope everywhere, also at f = 0) and the replay's input
    filter is the plant's function."""
    p = plant_parameters(NOMINAL.with_changes(effects=_deadband(0.2, 1.6, 0.8)))
    f_cas = plant_casadi.dynamics_function(p, "thrust")
    x, f = _states()
    f[1] = 0.0
    for xi, fi in zip(x, f):
        fd = np.array(fx.static_thrust(fx.NUMPY, list(fi), p.effects, p.f_ref, p.capacities), float)
        ref = state_derivative(xi, delivered_wrench(xi, fd, p), p)
        np.testing.assert_allclose(np.asarray(f_cas(xi, fi)).ravel(), ref, rtol=1e-9, atol=1e-9)
    sym = ca.SX.sym("f")
    out = fx.static_thrust(fx.CASADI, [sym], p.effects, p.f_ref[:1], (p.f_max[:1], -p.f_min[:1]))[0]
    slope = ca.Function("slope", [sym], [ca.jacobian(out, sym)])
    assert [float(slope(v)) for v in (0.0, 1e-9, -1e-9)] == [0.0, 0.0, 0.0]  # inside the deadband, no NaN
    assert 0.0 < float(slope(0.9 * p.f_ref[0])) < np.inf and 0.0 < float(slope(-0.9 * p.f_ref[0])) < np.inf
    hooks = plant_hooks(p.effects[0], p, Actuation(p.T, p.T, p.f_ref, p.M_A))
    np.testing.assert_array_equal(hooks.input_filter(f, 0.02), np.stack(
        fx.static_thrust(fx.NUMPY, list(f.T), p.effects, p.f_ref, p.capacities), -1))
    # p = 2, continuous: the simulator delivers each direction's capacity at full command (an asymmetric thruster's
    # reverse command is normalised by its reverse capacity), nothing inside w^2 of it
    p2 = plant_parameters(NOMINAL.with_changes(effects=_deadband(0.2, 2.0, 1.0)))
    assert p2.f_max[0] != -p2.f_min[0]
    u = np.zeros((4, 4))
    u[:, 0] = [p2.f_max[0], p2.f_min[0], 0.039 * p2.f_max[0], 0.039 * p2.f_min[0]]
    np.testing.assert_allclose(Actuators(p2, 0.02).delivered(u)[:, 0], [p2.f_max[0], p2.f_min[0], 0.0, 0.0],
                               rtol=1e-12)


def test_thruster_lag_delays_the_response_by_its_time_constant():
    T = 0.5
    lagged = _with("thruster_lag").with_changes(effects=(fx.PlantEffect("thruster_lag", {"T_lag_s": T}),))
    u = np.zeros((400, 4))
    u[1:, :2] = 15.0  # surge step after the first step (the lag starts at rest)
    fast = simulate(NOMINAL, np.r_[0, 0, 1.0, np.zeros(9)], 4.0, inputs=u, dt=0.01)
    slow = simulate(lagged, np.r_[0, 0, 1.0, np.zeros(9)], 4.0, inputs=u, dt=0.01)
    k = int(T / 0.01)
    assert slow.x[k, 6] < 0.5 * fast.x[k, 6]  # the lagged thrust has reached 63 %: less impulse so far
    assert slow.x[-1, 6] == pytest.approx(fast.x[-1, 6], rel=0.25)


def _step_thrust(T, k, F=20.0, dt=0.002, n=1500):
    """Delivered thrust of a lagged thruster after a step from rest to ``F`` N held from the second step, as the
    plant simulator delivers it (:class:`Actuators`), and the replay's input filter over the same commands."""
    lag = fx.PlantEffect("thruster_lag", {"T_lag_s": T, "thrust_exponent": k})
    p = plant_parameters(NOMINAL.with_changes(effects=(lag,)))
    u = np.zeros((n, 4))
    u[1:, 0] = F
    act = Actuators(p, dt)
    sim = np.array([act.delivered(row) for row in u])
    hooks = plant_hooks(lag, p, Actuation(p.T, p.T, p.f_ref, p.M_A))
    return sim, hooks.input_filter(u, dt)


@pytest.mark.parametrize("k", [1.0, 1.5, 2.0])
def test_rotor_speed_lag_step_response_is_the_closed_form(k):
    """A step F from rest: the lagged state sign(f)|f|^(1/k) rises as F^(1/k) (1 - e^(-t/T)), so the thrust is
    F (1 - e^(-t/T))^k, exactly at the samples (zero-order hold). It reaches 63 % (1 - 1/e) of F at
    t63 = -T ln(1 - (1 - 1/e)^(1/k)): T for the thrust lag (k = 1), 1.585 T for the rotor-speed lag (k = 2)."""
    T, F, dt = 0.3, 20.0, 0.002
    sim, replay = _step_thrust(T, k, F, dt)
    t = np.arange(1, sim.shape[0]) * dt  # the thrust of step j is the lag's value at its end: j dt after the step
    np.testing.assert_allclose(sim[1:, 0], F * (1.0 - np.exp(-t / T)) ** k, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(replay, sim, rtol=1e-12, atol=1e-12)  # the replay filters with the same function
    assert np.all(sim[:, 1:] == 0.0)
    t63 = t[np.argmax(sim[1:, 0] >= (1.0 - np.exp(-1.0)) * F)]
    expected = -T * np.log(1.0 - (1.0 - np.exp(-1.0)) ** (1.0 / k))
    assert t63 == pytest.approx(expected, abs=1.5 * dt)  # the first sample at or past it
    if k == 2.0:
        assert expected == pytest.approx(1.5850 * T, rel=1e-4)


def test_rotor_speed_lag_falls_faster_than_it_rises():
    """Thrust ~ s|s| with s lagged: from full thrust to zero the thrust is F e^(-2t/T) (k = 2), twice as fast a
    decay as the thrust lag's F e^(-t/T); a reversal passes through zero thrust when s does, at T ln 2."""
    T, F, dt = 0.3, 20.0, 0.002
    f = np.full((800, 1), F)
    f[1:] = 0.0
    t = np.arange(1, 800) * dt
    np.testing.assert_allclose(fx.first_order_lag(f, dt, T, thrust_exponent=2.0)[1:, 0], F * np.exp(-2 * t / T),
                               rtol=1e-12)
    f[1:] = -F
    y = fx.first_order_lag(f, dt, T, thrust_exponent=2.0)[1:, 0]
    assert t[np.argmax(y <= 0.0)] == pytest.approx(T * np.log(2.0), abs=dt)


def test_thrust_exponent_one_is_the_old_thrust_lag_bit_for_bit():
    rng = np.random.default_rng(3)
    f = np.repeat(rng.uniform(-30, 30, (40, 4)), 10, axis=0)
    dt, T = 0.02, 0.25
    a = np.exp(-dt / T)
    old = [f[0]]
    for row in f[1:]:  # the recursion the lag had before the exponent: a f_prev + (1 - a) f_cmd
        old.append(a * old[-1] + (1.0 - a) * row)
    np.testing.assert_array_equal(fx.first_order_lag_step(old[-2], f[-1], dt, T), old[-1])
    np.testing.assert_allclose(fx.first_order_lag(f, dt, T), np.array(old), rtol=1e-13, atol=1e-12)
    # a model file without the exponent is the thrust lag
    assert fx.thruster_lag((fx.PlantEffect("thruster_lag", {"T_lag_s": T}),)) == fx.ThrusterLag(T, 1.0)
    u = np.zeros((200, 4))
    u[1:, 0] = 15.0
    x0 = np.r_[0, 0, 1.0, np.zeros(9)]
    runs = [simulate(NOMINAL.with_changes(effects=(fx.PlantEffect("thruster_lag", q),)), x0, 2.0, inputs=u, dt=0.01)
            for q in ({"T_lag_s": T}, {"T_lag_s": T, "thrust_exponent": 1.0})]
    np.testing.assert_array_equal(runs[0].x, runs[1].x)


def test_a_lag_of_any_exponent_is_refused_by_the_static_plant():
    p = plant_parameters(NOMINAL.with_changes(effects=(fx.PlantEffect("thruster_lag", {"T_lag_s": 0.3,
                                                                                       "thrust_exponent": 2.0}),)))
    with pytest.raises(ValueError, match="thruster_lag"):
        plant_casadi.dynamics_function(p, "thrust")


@pytest.mark.parametrize("tether", [EXAMPLES["tether_drag"], FIXED_TETHER], ids=["anchor", "fixed-direction"])
def test_model_file_round_trips_effects(tmp_path, tether):
    v = NOMINAL.with_changes(effects=(fx.PlantEffect("tether_drag", tether),
                                      fx.PlantEffect("buoyancy_offset", EXAMPLES["buoyancy_offset"])))
    path = tmp_path / "corrected.json"
    path.write_text(json.dumps(to_model_dict(v)))
    back = read_model_file(path)
    assert back.effects == v.effects


@pytest.mark.parametrize("entry, message", [
    ({"name": "tether_darg", "params": {}}, "did you mean 'tether_drag'"),
    ({"name": "buoyancy_offset", "params": {"dB": 1.0}}, "did you mean 'dB_N'"),
    ({"name": "buoyancy_offset", "params": {}}, "misses parameter"),
    ({"name": "buoyancy_offset", "params": {"dB_N": "3"}}, "finite number"),
    ({"name": "thruster_lag", "params": {"T_lag_s": -1.0}}, "must be > 0"),
    ({"name": "thruster_lag", "params": {"T_lag_s": 0.3, "thrust_exponent": 2.5}},
     r"params.thrust_exponent: must be within \[1, 2\].*rotor speed.*got 2.5"),
    ({"name": "thruster_lag", "params": {"T_lag_s": 0.3, "thrust_exponent": 0.5}}, "thrust_exponent: must be within"),
    ({"name": "thruster_deadband", "params": {"width_fraction": 0.1, "shift": 1.0, "command_exponent": 3.0}},
     r"params.command_exponent: must be within \[1, 2\].*command\^p.*got 3"),
    ({"name": "thruster_lag", "params": {"T_lag_s": 0.3, "command_exponent": 2.0}},
     "has no parameter 'command_exponent'"),
    ({"name": "wall_effect", "params": {"decay_length_m": 0.2, "added_mass_at_contact_kg": 1.0,
                                        "suction_N_s2_per_m2": 1.0}}, "needs a plane"),
    ({"name": "wall_effect", "params": {"decay_length_m": 0.2, "added_mass_at_contact_kg": 1.0,
                                        "suction_N_s2_per_m2": 1.0, "wall1_point_n_m": 0.0}}, "misses wall1_point_e_m"),
    ({"name": "quadratic_damping_error", "params": {**EXAMPLES["quadratic_damping_error"], "norm_weight": 1.5}},
     r"params.norm_weight: must be within \[0, 1\].*got 1.5"),
    ({"name": "tether_drag", "params": {**EXAMPLES["tether_drag"], "cable_azimuth_rad": 1.0}}, "not both"),
    ({"name": "tether_drag", "params": {**FIXED_TETHER, "walk_azimuth_rad": 0.0, "walk_fraction": 1.0}},
     "walking top end needs an anchor"),
    ({"name": "tether_drag", "params": {**EXAMPLES["tether_drag"], "walk_fraction": 1.0}},
     "needs an anchor .* and both of walk_azimuth_rad, walk_fraction"),
    ({"name": "tether_drag", "params": {**WALKING_TETHER, "walk_fraction": 1.5}},
     r"params.walk_fraction: must be in \[0, 1\], got 1.5"),
    ({"name": "tether_drag", "params": {**FIXED_TETHER, "cable_taut": 1.0}}, "cable_taut needs an anchor"),
    ({"name": "tether_drag", "params": {**WALKING_TETHER, "cable_taut": 2.0}},
     r"params.cable_taut: must be in \[0, 1\] \(0 slack, 1 taut\), got 2"),
    ({"name": "tether_drag", "params": {"k_quadratic_N_s2_per_m2": 1.0, "k_linear_N_s_per_m": 0.0,
                                        "anchor_north_m": 1.0, "anchor_east_m": 2.0}}, "misses .*anchor_down_m"),
    ({"name": "tether_drag", "params": {"k_quadratic_N_s2_per_m2": 1.0, "k_linear_N_s_per_m": 0.0,
                                        "cable_azimuth_rad": 1.0}}, "misses parameter.*cable_elevation_rad"),
])
def test_bad_effects_are_refused_naming_the_entry(tmp_path, entry, message):
    assert_refused_on_load(tmp_path, NOMINAL, entry, message)


def assert_refused_on_load(tmp_path, vehicle, entry, message):
    """A model file of ``vehicle`` with the one effect ``entry`` is refused on load, the error matching ``message``
    and naming the file and the entry."""
    doc = to_model_dict(vehicle)
    doc["effects"] = [entry]
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=message) as err:
        read_model_file(path)
    assert "effects[0]" in str(err.value) and str(path) in str(err.value)


def test_simulation_paths_agree_with_thrust_lag_and_force_effects():
    v = NOMINAL.with_changes(effects=tuple(fx.PlantEffect(n, EXAMPLES[n]) for n in (
        "thrust_inflow_loss", "thruster_deadband", "thruster_lag", "tether_drag", "water_current")))
    rng = np.random.default_rng(5)
    u = np.repeat(rng.uniform(-20, 25, size=(10, 4)), 20, axis=0)
    x0 = np.r_[0, 0, 1.0, np.zeros(9)]
    a = simulate(v, x0, 2.0, inputs=u, dt=0.01, method="rk4")  # casadi step of the same equations
    b = simulate(v, x0, 2.0, inputs=u, dt=0.01, method="rk4_numpy")
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-10)
    assert np.abs(a.x[-1, 6:]).max() > 0.05  # it moved


@pytest.mark.slow
def test_simulate_command_replays_a_corrected_model_like_the_simulator(tmp_path):
    from udrobot_ctrl.cli.simulate import input_wrenches, replay
    from udrobot_ctrl.io.runlog import Run

    v = NOMINAL.with_changes(effects=tuple(fx.PlantEffect(n, EXAMPLES[n]) for n in (
        "thrust_inflow_loss", "thruster_asymmetry", "thruster_lag", "water_current")))
    p = plant_parameters(v)
    rng = np.random.default_rng(9)
    u = np.repeat(rng.uniform(-20, 25, size=(8, 4)), 25, axis=0)  # 200 rows at 20 Hz
    t = np.arange(200) * 0.05
    x0 = np.r_[0, 0, 1.0, np.zeros(9)]
    run = Run(path="r.csv", t=t, channels={}, input_kind="thrust", inputs=u, extra={}, metadata={})
    tau, thrust = input_wrenches(run, p)
    xs = replay(p, t, x0, tau, max_step=0.01, thrust=thrust)
    ref = simulate(v, x0, 9.95, inputs=np.repeat(u[:-1], 5, axis=0), dt=0.01, method="rk4_numpy")
    np.testing.assert_allclose(xs[1:], ref.x[5::5], rtol=1e-8, atol=1e-9)
