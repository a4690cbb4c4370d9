"""Physics of the tether template: cross-flow drag normal to the cable, towards an anchor or along a fixed direction."""
from dataclasses import replace

import numpy as np
import pytest

from udrobot_ctrl.dynamics import effects as fx
from udrobot_ctrl.dynamics.effects import TETHER_SPEED_FLOOR, PlantEffect
from udrobot_ctrl.dynamics.effects import cable_direction as _cable_direction
from udrobot_ctrl.dynamics.plant import generalized_forces, plant_parameters, rotation_zyx
from udrobot_ctrl.gap import effects as gap_effects
from udrobot_ctrl.gap.effects import (
    FAR_ANCHOR_M,
    WALK_AZIMUTHS,
    WALK_BACK_M,
    WALL_SUBSETS_MAX_PLANES,
    Actuation,
    Stack,
    _tether_columns,
    catalogue,
    discriminating_manoeuvre,
    mask_bits,
    on_planes,
    plane_bit,
    plane_masks,
)
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


ANCHOR = {"anchor_north_m": -3.0, "anchor_east_m": 0.5, "anchor_down_m": -0.3}


def _anchored_states(rng, n=60):
    x = _state(rng, n)
    x[:, :3] = rng.uniform([-8, -6, 0.3], [8, 6, 3.0], (n, 3))  # around the anchor, under the surface
    return x


def _stack(x, p):
    """A stack whose filter is the identity: the regressor as the plant sees it, sample by sample."""
    n = x.shape[0]
    run = {"eta": x[:, :6], "nu": x[:, 6:], "idx": np.arange(n), "smooth": lambda y, held=False: y}
    return Stack(nu=x[:, 6:], nu_dot=np.zeros((n, 6)), eta=x[:, :6], f=np.zeros((n, 4)), B=p.T, inflow=p.T,
                 f_ref=np.ones(4), surfaces={}, runs=[run], p=p, M_A=p.M_A)


WALKING = {**ANCHOR, "walk_azimuth_rad": 0.7, "walk_fraction": 1.0}
#: tied at the top rear of the hull (body frame, m), within pendulum:chin's 0.18 m size
ATTACHED = {**ANCHOR, "attach_x_m": -0.15, "attach_y_m": 0.02, "attach_z_m": -0.1}


@pytest.mark.parametrize("geometry", [ANCHOR, WALKING, ATTACHED, {**WALKING, **ATTACHED, "cable_taut": 1.0},
                                      {"cable_azimuth_rad": 2.5, "cable_elevation_rad": 0.4}],
                         ids=["anchor", "walking", "attached", "walking-taut-attached", "fixed-direction"])
def test_tether_regressor_is_the_derivative_of_the_plant_force(geometry):
    """b0 + A a of the diagnoser's design is the corrected plant's own force (the effect it writes to a model)."""
    rng = np.random.default_rng(1)
    p0 = plant_parameters(load_model("pendulum:chin"))
    x = _anchored_states(rng)
    eff = catalogue()["tether_drag"]
    shape = tuple(geometry.get(k, 0.0) for k in eff.shape_names) if "anchor_north_m" in geometry else None
    if shape is None:  # the diagnoser fits anchors; a fixed direction enters through the same plant function
        b0, A = np.zeros((x.shape[0], 6)), _tether_columns({"eta": x[:, :6], "nu": x[:, 6:]}, geometry, 1)
    else:
        b0, A, names, lo, hi = eff.design(_stack(x, p0), shape)
        assert names == ("k_quadratic_N_s2_per_m2", "k_linear_N_s_per_m")
    a = np.array([12.0, 1.5])
    params = {**geometry, "k_quadratic_N_s2_per_m2": a[0], "k_linear_N_s_per_m": a[1]}
    corrected = plant_parameters(load_model("pendulum:chin").with_changes(
        effects=(PlantEffect("tether_drag", params),)))
    plant_force = generalized_forces(x, p0) - generalized_forces(x, corrected)  # what the effect adds to the plant
    np.testing.assert_allclose(b0 + A @ a, plant_force, rtol=1e-10, atol=1e-12)
    hooks = eff.hooks(params, p0, Actuation(None, None, None, None))  # the replay's force is the same function
    np.testing.assert_allclose(hooks.force(x, None, {}), plant_force, rtol=1e-10, atol=1e-12)


def test_tether_search_covers_anchors_around_the_runs_and_the_fixed_directions():
    rng = np.random.default_rng(2)
    p0 = plant_parameters(load_model("pendulum:chin"))
    x = _anchored_states(rng)
    x[:, 0] += 40.0  # runs far from the frame's origin: the grid follows the data
    grid, bounds = catalogue()["tether_drag"].search_space(_stack(x, p0))
    g_all = np.array(grid)
    walk = g_all[:, 4] == 1.0  # walking top ends: on the surface, along four line azimuths
    assert walk.sum() >= 4 * len(WALK_BACK_M) * 2 and np.all(g_all[walk, 2] == 0.0)
    np.testing.assert_allclose(np.unique(g_all[walk, 3]), WALK_AZIMUTHS)
    for (lo, hi), v in zip(bounds, g_all.T):
        assert np.all((v >= lo) & (v <= hi))
    assert np.all(g_all[~walk, 4] == 0.0)
    g = g_all[~walk, :3]
    centre = np.median(x[:, :2], axis=0)
    dist = np.linalg.norm(g - np.r_[centre, np.median(x[:, 2])], axis=1)
    near = dist < 100
    assert near.sum() >= 9 and np.all(g[near, 2] == 0.0)  # at the surface, around and above the runs
    assert np.hypot(*(g[near, :2] - centre).T).max() > np.hypot(*(x[:, :2] - centre).T).max()  # and beyond them
    np.testing.assert_allclose(dist[~near], FAR_ANCHOR_M, rtol=1e-9)  # the fixed-direction limit
    assert any(np.allclose(r[:2], centre) and r[2] < -0.99 * FAR_ANCHOR_M for r in g)
    names = catalogue()["tether_drag"].shape_names
    attach = [names.index(k) for k in fx.TETHER_ATTACH]
    assert np.all(g_all[:, attach] == 0.0)  # the grid ties the cable at the CO; the refinement moves it
    size = fx.vehicle_size([t.position for t in load_model("pendulum:chin").thrusters])
    assert [bounds[i] for i in attach] == [(-size, size)] * 3  # a point of the hull


@pytest.mark.parametrize("a", [0.0, 0.4, 1.0])
def test_quadratic_damping_regressor_is_the_plant_force_at_its_norm_weight(a):
    """The quadratic damping error's design at shape ``norm_weight`` a, times the scales, is the corrected plant's
    force, and the replay's hooks apply the same."""
    rng = np.random.default_rng(2)
    p0 = plant_parameters(load_model("pendulum:chin"))
    x = _state(rng)
    eff = catalogue()["quadratic_damping_error"]
    b0, A, names, lo, hi = eff.design(_stack(x, p0), (a,))
    scales = rng.uniform(-0.5, 1.0, 6)
    params = {**dict(zip(names, scales)), "norm_weight": a}
    corrected = plant_parameters(load_model("pendulum:chin").with_changes(
        effects=(PlantEffect("quadratic_damping_error", params),)))
    plant_force = generalized_forces(x, p0) - generalized_forces(x, corrected)
    np.testing.assert_allclose(b0 + A @ scales, plant_force, rtol=1e-8, atol=1e-9)
    hooks = eff.hooks(params, p0, Actuation(None, None, None, p0.M_A))
    np.testing.assert_allclose(hooks.force(x, None, {}), plant_force, rtol=1e-8, atol=1e-9)



def test_look_alikes_come_with_the_manoeuvre_that_separates_them():
    """Pairs the diagnoser confuses on ordinary pool runs each name a specific separating manoeuvre, in either
    order; any other pair gets the generic advice naming both effects."""
    for a, b in (("wall_effect", "added_mass_error"), ("added_mass_error", "cg_cb_offset"),
                 ("cross_coupled_damping", "quadratic_damping_error"), ("thruster_lag", "thruster_deadband"),
                 ("quadratic_damping_error", "thrust_inflow_loss")):
        text = discriminating_manoeuvre(a, b)
        assert text == discriminating_manoeuvre(b, a) and "regressors of" not in text
    assert "water_current" in discriminating_manoeuvre("water_current", "thruster_lag")


def test_tether_designs_of_many_anchors_are_each_anchors_own():
    """The grid's anchors computed together (per cable form) give each anchor's design as computed alone: fixed and
    walking top ends, slack and taut, in any order."""
    rng = np.random.default_rng(4)
    p0 = plant_parameters(load_model("pendulum:chin"))
    st = _stack(_anchored_states(rng), p0)
    eff = catalogue()["tether_drag"]
    co, aft = (0.0, 0.0, 0.0), (-0.15, 0.0, -0.1)  # tied at the CO, or at the top rear
    shapes = [(3.0, -2.0, 0.0, 0.0, 0.0, 0.0) + co, (-1.0, 4.0, 0.0, 0.7, 1.0, 1.0) + co,
              (8.0, 1.0, -0.5, 0.0, 0.0, 1.0) + aft, (0.5, 0.5, 0.0, 0.7, 1.0, 1.0) + aft,
              (-6.0, 2.0, 0.0, 0.0, 0.0, 0.0) + co, (3.0, -2.0, 0.0, 0.0, 0.0, 0.0) + aft]
    together = eff.designs(st, shapes)
    for shape, d in zip(shapes, together):
        alone = eff.designs(st, [shape])[0]
        assert np.array_equal(d.A, alone.A) and np.array_equal(d.b0, alone.b0)
    assert not np.allclose(together[0].A, together[4].A)  # the anchors differ
    assert not np.allclose(together[0].A, together[5].A)  # and so do the attachments


def test_tether_columns_in_blocks_of_samples_are_the_whole_runs(monkeypatch):
    """The cable terms are evaluated a block of samples at a time: blocks of any size give the numbers of the whole
    run at once, for every cable form."""
    rng = np.random.default_rng(5)
    x = _anchored_states(rng)
    run = {"eta": x[:, :6], "nu": x[:, 6:]}
    names = fx.TETHER_ANCHOR + fx.TETHER_WALK + (fx.TETHER_TAUT,) + fx.TETHER_ATTACH
    for form in ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.7, 1.0, 1.0, -0.15, 0.0, -0.1)):
        geometry = dict(zip(names, [rng.normal(size=3) * 4.0 for _ in range(3)] + list(form)))
        monkeypatch.setattr(gap_effects, "TETHER_BLOCK", 10 ** 9)
        whole = _tether_columns(run, geometry, 3)
        monkeypatch.setattr(gap_effects, "TETHER_BLOCK", 3 * 7)  # blocks of 7 samples
        np.testing.assert_array_equal(_tether_columns(run, geometry, 3), whole)


def test_wall_replay_hooks_are_the_plants_suction_and_added_mass_over_every_surface():
    """The replay's wall hooks (all measured surfaces in one evaluation) are the plant's own wall_effect terms
    summed over its planes: the seabed and two walls of other normals; an unmeasured distance is no surface."""
    rng = np.random.default_rng(3)
    p = plant_parameters(load_model("pendulum:chin"))
    x = _state(rng, 40)
    x[:, :3] = rng.uniform([-2.0, -1.0, 0.5], [2.0, 3.0, 2.5], (40, 3))
    q = {"decay_length_m": 0.4, "suction_N_s2_per_m2": 30.0, "added_mass_at_contact_kg": 6.0, "seabed_depth_m": 3.0,
         "wall1_point_n_m": 3.0, "wall1_point_e_m": 0.0, "wall1_point_d_m": 0.0, "wall1_normal_n": -1.0,
         "wall1_normal_e": 0.0, "wall1_normal_d": 0.0,
         "wall2_point_n_m": 0.0, "wall2_point_e_m": -2.0, "wall2_point_d_m": 0.0, "wall2_normal_n": 0.3,
         "wall2_normal_e": 1.0, "wall2_normal_d": 0.0}
    planes = fx.wall_planes(q)
    assert len(planes) == 3
    ctx = {"surfaces": [(np.asarray(fx.plane_distance(x[:, :6].T, pt, n), float), np.asarray(n), f"plane {k}")
                        for k, (pt, n) in enumerate(planes)]}
    eff = PlantEffect("wall_effect", q)
    hooks = catalogue()["wall_effect"].hooks(q, p, Actuation(None, None, None, p.M_A))
    X = list(x.T)
    force = np.stack(np.broadcast_arrays(*fx.external_force(fx.NUMPY, X[:6], X[6:], (eff,))), -1)
    mass = np.stack([np.stack(np.broadcast_arrays(*r), -1)
                     for r in fx.added_mass_increment(fx.NUMPY, X[:6], X[6:], (eff,))], -2)
    np.testing.assert_allclose(hooks.force(x, None, ctx), force, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(hooks.mass(x, ctx), mass, rtol=1e-12, atol=1e-12)
    assert np.abs(mass).max() > 0.1 and np.abs(force).max() > 1e-3  # the surfaces are near enough to act
    far = {"surfaces": [(np.where(np.arange(40) % 2, d, np.nan), n, lab) for d, n, lab in ctx["surfaces"]]}
    np.testing.assert_allclose(hooks.mass(x, far)[::2], 0.0, atol=0.0)  # unmeasured: no surface
    np.testing.assert_allclose(hooks.mass(x, far)[1::2], mass[1::2], rtol=1e-12, atol=1e-12)
    assert np.all(hooks.mass(x, {"surfaces": []}) == 0.0) and np.all(hooks.force(x, None, {"surfaces": []}) == 0.0)
    # the terms force and mass share within one ctx are those of the state asked for, not of an earlier one
    turned = x.copy()
    turned[:, 3:6] += 0.3
    assert not np.allclose(hooks.mass(turned, ctx), mass)
    np.testing.assert_array_equal(hooks.mass(turned, ctx), hooks.mass(turned, {"surfaces": ctx["surfaces"]}))
    np.testing.assert_array_equal(hooks.force(x, None, ctx), hooks.force(x, None, {"surfaces": ctx["surfaces"]}))


def test_plane_masks_enumerate_the_plane_subsets_and_labels_map_to_bits():
    assert [plane_bit(lab) for lab in ("seabed", "seabed (altitude)", "wall 0", "wall 3", "plane 0 of the model")] \
        == [0, 0, 1, 4, -1]
    assert sorted(plane_masks([0, 1])) == [1, 2, 3] and plane_masks([]) == (0,) and plane_masks([2]) == (4,)
    many = list(range(WALL_SUBSETS_MAX_PLANES + 1))
    assert sorted(plane_masks(many)) == sorted([1 << b for b in many] + [2 ** len(many) - 1])  # alone, and all
    assert mask_bits(5.0) == {0, 2} and mask_bits(0) == frozenset()
    surfaces = [(None, None, "seabed (altitude)"), (None, None, "wall 0"), (None, None, "wall 1")]
    assert [lab for _, _, lab in on_planes(surfaces, 5.0)] == ["seabed (altitude)", "wall 1"]
    assert on_planes(surfaces, None) == surfaces  # a model file's wall effect: its own planes, all of them


def test_a_wall_effects_plane_subset_acts_as_the_plant_on_those_planes_only():
    """Fitted on a subset of the measured planes (``planes_mask``), the replay hooks are the plant's wall effect with
    those planes only, and the design's columns those of a stack that knows those planes only."""
    rng = np.random.default_rng(5)
    p = plant_parameters(load_model("pendulum:chin"))
    x = _state(rng, 40)
    x[:, :3] = rng.uniform([-2.0, -1.0, 2.2], [2.0, -0.2, 2.9], (40, 3))
    seabed = {"seabed_depth_m": 3.0}
    wall = {"wall1_point_n_m": 0.0, "wall1_point_e_m": 0.0, "wall1_point_d_m": 0.0, "wall1_normal_n": 0.0,
            "wall1_normal_e": -1.0, "wall1_normal_d": 0.0}
    q = {"decay_length_m": 0.3, "suction_N_s2_per_m2": 40.0, "added_mass_at_contact_kg": 6.0}
    ctx = {"surfaces": [(np.asarray(fx.plane_distance(x[:, :6].T, pt, n), float), np.asarray(n), lab)
                        for (pt, n), lab in zip(fx.wall_planes({**q, **seabed, **wall}), ("seabed", "wall 0"))]}
    hooks = catalogue()["wall_effect"].hooks({**q, "planes_mask": 1.0}, p, Actuation(None, None, None, p.M_A))
    only = PlantEffect("wall_effect", {**q, **seabed})
    X = list(x.T)
    force = np.stack(np.broadcast_arrays(*fx.external_force(fx.NUMPY, X[:6], X[6:], (only,))), -1)
    np.testing.assert_allclose(hooks.force(x, None, ctx), force, rtol=1e-12, atol=1e-12)
    both = catalogue()["wall_effect"].hooks(q, p, Actuation(None, None, None, p.M_A))
    assert np.abs(both.force(x, None, ctx) - force).max() > 1e-2  # the wall, 0.2-1 m off, acts when listed
    nu_dot = rng.normal(0, 0.3, (40, 6))
    s = _stack(x, p)
    run = {**s.runs[0], "nu_dot": nu_dot, "surfaces": ctx["surfaces"]}
    two = replace(s, runs=[run], memo={}, surfaces={lab: (d, n) for d, n, lab in ctx["surfaces"]})
    one = replace(s, runs=[{**run, "surfaces": ctx["surfaces"][:1]}], memo={})
    wall_effect = catalogue()["wall_effect"]
    np.testing.assert_array_equal(wall_effect.design(two, (0.3, 1.0)).A, wall_effect.design(one, (0.3, 1.0)).A)
    assert not np.allclose(wall_effect.design(two, (0.3, 3.0)).A, wall_effect.design(one, (0.3, 1.0)).A)
    grid, _ = wall_effect.search_space(two)
    assert sorted({sh[1] for sh in grid}) == [1.0, 2.0, 3.0] and wall_effect.default_form(two) == (3.0,)
    mixed = replace(two, surfaces={**two.surfaces, "seabed (altitude)": two.surfaces["seabed"]})  # one seabed twice
    assert wall_effect.default_form(mixed) == (3.0,)


def _surface_stack(x, p, nu_dot, dist):
    """:func:`_stack` with a seabed at distance ``dist`` and the accelerations ``nu_dot`` (a fresh memo)."""
    s = _stack(x, p)
    run = {**s.runs[0], "nu_dot": nu_dot, "surfaces": [(dist, np.array([0.0, 0.0, 1.0]), "seabed")]}
    return replace(s, runs=[run], memo={})


def test_designs_that_keep_shape_free_terms_equal_fresh_ones_on_copies_with_moved_velocities():
    """A stack keeps a wall's surface geometry and a current's rotations per run arrays (Stack.kept): every decay
    length and current reads them, and a copy whose velocities or pose moved (identifiability's perturbed stacks)
    gets its own, not the original's."""
    rng = np.random.default_rng(3)
    p = plant_parameters(load_model("pendulum:chin"))
    x = _state(rng, 80)
    nu_dot, dist = rng.normal(0, 0.3, (80, 6)), rng.uniform(0.05, 1.0, 80)
    wall, current = catalogue()["wall_effect"], catalogue()["water_current"]
    s = _surface_stack(x, p, nu_dot, dist)
    for lam in (0.1, 0.33):  # the second decay length reads what the first kept
        np.testing.assert_array_equal(wall.design(s, (lam, 1.0)).A,
                                      wall.design(_surface_stack(x, p, nu_dot, dist), (lam, 1.0)).A)
    assert np.abs(wall.design(s, (0.33, 1.0)).A).max() > 0  # near the seabed: the wall acts
    np.testing.assert_array_equal(current.design(s, (0.1, -0.1, 0.0)).b0,
                                  current.design(_surface_stack(x, p, nu_dot, dist), (0.1, -0.1, 0.0)).b0)
    moved = x.copy()
    moved[:, 6] += 0.2
    moved[:, 3] += 0.1
    copy = replace(s, runs=[dict(s.runs[0], nu=moved[:, 6:], eta=moved[:, :6])])  # shares s's memo
    fresh = _surface_stack(moved, p, nu_dot, dist)
    np.testing.assert_array_equal(wall.design(copy, (0.33, 1.0)).A, wall.design(fresh, (0.33, 1.0)).A)
    np.testing.assert_array_equal(current.design(copy, (0.1, -0.1, 0.0)).b0, current.design(fresh, (0.1, -0.1, 0.0)).b0)
    assert not np.array_equal(current.design(copy, (0.1, -0.1, 0.0)).b0, current.design(s, (0.1, -0.1, 0.0)).b0)
