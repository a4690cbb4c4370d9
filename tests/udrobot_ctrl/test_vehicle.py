"""Model names load; their surge/sway/heave entries equal Cely 2019's tables (issue 2, test 4)."""
import json
from importlib import resources

import numpy as np
import pytest
import tomllib

from udrobot_ctrl.dynamics.plant import SingularMassMatrixError, plant_parameters
from udrobot_ctrl.dynamics.thrusters import actuated_dofs, thrust_limits
from udrobot_ctrl.vehicle import (
    MODEL_NAMES,
    apply_motor_directions,
    load_model,
    read_model_file,
    to_model_dict,
    vehicle_from_description,
    vehicle_model,
    write_model_file,
)

PAPER = {
    # Cely 2019: Table 10 / sec. 4.3 (pendulum Chin), sec. 4.4 (pendulum Morison), Table 7 / sec. 4.2 (spring), Table 5
    "pendulum:chin": {"added_mass": [8.3027, 2.2117, 7.6211], "KL": [1.0745, 0.6508, 0.3834],
                      "KQ": [50.8618, 17.4666, 55.7484]},
    "pendulum:morison": {"added_mass": [8.3472, 2.2135, 7.6194], "CD": [2.3432, 0.5838, 1.1145]},
    "free_decay:morison": {"added_mass": [7.5187, 1.7895, 10.6391], "CD": [1.4015, 0.5075, 0.9917]},
    "cfd:chin": {"KL": [1.0503, 0.5706, 0.1306], "KQ": [43.2322, 28.7941, 58.5848]},
    "cfd:morison": {"CD": [1.7021, 0.6226, 1.2929], "KD": [42.0253, 28.1384, 58.4346]},
}


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_model_loads_with_paper_values(name):
    v = load_model(name)
    assert v.name == name
    ref = PAPER[name]
    area = v.extras["projected_area"]
    if "added_mass" in ref:
        np.testing.assert_allclose(np.diag(v.added_mass)[:3], ref["added_mass"], rtol=1e-12)
    if "KL" in ref:
        np.testing.assert_allclose(np.diag(v.linear_damping)[:3], ref["KL"], rtol=1e-12)
    if "KQ" in ref:
        np.testing.assert_allclose(np.diag(v.quadratic_damping)[:3], ref["KQ"], rtol=1e-12)
    if "CD" in ref:
        np.testing.assert_allclose(np.diag(v.quadratic_damping)[:3], 0.5 * v.rho * np.array(ref["CD"]) * area,
                                   rtol=1e-12)
        assert np.all(np.diag(v.linear_damping) == 0.0)  # Morison form: no linear term
    if "KD" in ref:  # Table 5 K_D reproduced through the derived reference areas
        np.testing.assert_allclose(np.diag(v.quadratic_damping)[:3], ref["KD"], rtol=2e-3)
    assert v.mass == 9.36
    assert len(v.thrusters) == 4
    plant_parameters(v)  # mass matrix is positive definite


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_every_number_has_provenance(name):
    v = load_model(name)
    doc = to_model_dict(v)
    for key in ("mass", "inertia_cg", "r_g", "r_b", "buoyancy"):
        assert doc["provenance"][key], key
    for i in range(6):
        for field in ("added_mass", "quadratic_damping") + (("linear_damping",) if name.endswith("chin") else ()):
            tag = doc["provenance"][f"{field}[{i}][{i}]"]
            assert tag.split(":")[0] in {"measured", "cfd", "estimated", "assumed", "derived"}, (field, i, tag)
        if i >= 3:
            assert doc["provenance"][f"added_mass[{i}][{i}]"].startswith("estimated")
    assert doc["provenance"]["inertia_cg"].startswith("estimated")


def test_cfd_added_mass_is_tagged_assumed():
    v = load_model("cfd:chin")
    assert v.provenance["added_mass[0][0]"].startswith("assumed")


def test_free_decay_has_no_chin_form():
    with pytest.raises(ValueError, match="no 'chin' form"):
        load_model("free_decay:chin")


def test_unknown_names_are_rejected_clearly():
    with pytest.raises(ValueError, match="unknown coefficient set 'towing'"):
        load_model("towing:chin")
    with pytest.raises(ValueError, match="expected SET:FORM"):
        load_model("pendulum")


def test_model_file_round_trip(tmp_path):
    v = load_model("pendulum:chin")
    path = tmp_path / "m.json"
    write_model_file(v, path)
    back = read_model_file(path)
    for field in ("added_mass", "linear_damping", "quadratic_damping", "inertia_cg", "r_g", "r_b"):
        np.testing.assert_array_equal(getattr(back, field), getattr(v, field))
    assert back.thrusters == v.thrusters and back.provenance == v.provenance
    assert load_model(str(path)).weight == v.weight


def test_bad_model_files_name_the_field(tmp_path):
    doc = to_model_dict(load_model("cfd:chin"))
    doc["added_mass"] = doc["added_mass"][:5]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"bad.json: field 'added_mass' has shape \(5, 6\)"):
        read_model_file(bad)
    (tmp_path / "trunc.json").write_text('{"format": "udrobot-model/1", ')
    with pytest.raises(ValueError, match="trunc.json: not a model file: not valid JSON"):
        read_model_file(tmp_path / "trunc.json")


def test_singular_mass_matrix_is_reported():
    v = load_model("pendulum:chin")
    bad = v.with_changes(added_mass=np.diag([-9.36, 0, 0, 0, 0, 0]) + 0.0)
    with pytest.raises(SingularMassMatrixError, match="pendulum:chin"):
        plant_parameters(bad)


def test_buoyancy_and_mass_inconsistency_is_resolved_openly():
    v = load_model("pendulum:chin")
    # Table 1 volume (528,797 mm^3) would give ~5.2 N of buoyancy; we assume a slightly positive trim instead
    assert 0.0 < v.buoyancy - v.weight < 1.0
    assert "cannot float" in v.provenance["buoyancy"]
    assert "9.20 kg" in v.provenance["mass"]


# ----------------------------------------------------------------------------- other vehicles (issue 12 item 5)
BLUEROV = {"bluerov2": 6, "bluerov2-heavy": 8}
PROVENANCE_TAGS = {"measured", "cfd", "estimated", "assumed", "derived"}


@pytest.mark.parametrize("name", sorted(BLUEROV))
def test_bluerov_loads_with_its_own_coefficients(name):
    v = load_model(name)
    assert v.name == name and v.n_thrusters == BLUEROV[name]
    assert [t.name for t in v.thrusters] == [f"T{i + 1}" for i in range(BLUEROV[name])]
    # von Benzon 2022 Table A1 magnitudes (positive M_A and D entries)
    np.testing.assert_allclose(np.diag(v.added_mass), [6.36, 7.12, 18.68, 0.189, 0.135, 0.222])
    np.testing.assert_allclose(np.diag(v.quadratic_damping), [141.0, 217.0, 190.0, 1.19, 0.47, 1.5])
    assert np.all(v.added_mass == np.diag(np.diag(v.added_mass)))
    # T200 limits of the shared curve at the stated 4S battery voltage, not the UDrobot's 12 V values
    assert v.extras["voltage"] == 14.8
    fwd, rev = thrust_limits(14.8)
    assert 44.39 < fwd < 51.44 and 34.49 < rev < 39.91  # between the 14 V and 16 V measured maxima
    assert all(t.max_forward_N == fwd and t.max_reverse_N == rev for t in v.thrusters)
    p = plant_parameters(v)
    assert p.T.shape == (6, BLUEROV[name]) and p.supply_voltage == 14.8
    for key, tag in v.provenance.items():
        assert tag.split(":")[0] in PROVENANCE_TAGS, (key, tag)
    for i in range(6):
        for field in ("added_mass", "linear_damping", "quadratic_damping"):
            assert "vB2022 Table A1" in v.provenance[f"{field}[{i}][{i}]"]


def test_bluerov2_hydrodynamics_from_the_heavy_are_tagged_estimated():
    v = load_model("bluerov2")
    assert v.provenance["added_mass[0][0]"].startswith("estimated")
    assert "Heavy" in v.provenance["added_mass[0][0]"]
    assert load_model("bluerov2-heavy").provenance["added_mass[0][0]"].startswith("measured")


# ArduSub AP_Motors6DOF.cpp setup_motors(): roll, pitch, yaw, throttle, forward, lateral factors per motor.
ARDUSUB = {
    "bluerov2": [(0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
                 (1, 0, 0, -1, 0, 0), (-1, 0, 0, -1, 0, 0)],
    "bluerov2-heavy": [(0, 0, 1, 0, -1, 1), (0, 0, -1, 0, -1, -1), (0, 0, -1, 0, 1, 1), (0, 0, 1, 0, 1, -1),
                       (1, -1, 0, -1, 0, 0), (-1, -1, 0, -1, 0, 0), (1, 1, 0, -1, 0, 0), (-1, 1, 0, -1, 0, 0)],
}


@pytest.mark.parametrize("name", sorted(BLUEROV))
def test_thruster_order_and_signs_follow_ardusub(name):
    """Motor i = pwm_i; a positive command gives the wrench sign ArduSub's factor table assumes."""
    T = plant_parameters(load_model(name)).T
    for i, (roll, pitch, yaw, throttle, fwd, lat) in enumerate(ARDUSUB[name]):
        col = T[:, i]
        for factor, value in ((fwd, col[0]), (lat, col[1]), (-throttle, col[2]), (roll, col[3]), (yaw, col[5])):
            if factor:
                assert np.sign(value) == factor, (name, i + 1, col)
        if pitch:
            assert np.sign(col[4]) == pitch, (name, i + 1, col)


def test_heavy_actuates_all_six_dof_and_bluerov2_five():
    heavy = actuated_dofs(plant_parameters(load_model("bluerov2-heavy")).T)
    assert heavy.rank == 6 and heavy.actuated == ("X", "Y", "Z", "K", "M", "N")
    six = actuated_dofs(plant_parameters(load_model("bluerov2")).T)
    # pitch is not independent: horizontals 0.0725 m below CO, verticals at x = 0.0025 m -> M = 0.0725 X - 0.0025 Z
    assert six.rank == 5 and "M" not in six.actuated and {"Y", "K", "N"} <= set(six.actuated)
    T = plant_parameters(load_model("bluerov2")).T
    np.testing.assert_allclose(T[4], 0.0725 * T[0] - 0.0025 * T[2], atol=1e-12)


@pytest.mark.parametrize("name", sorted(BLUEROV))
def test_bluerov_model_file_round_trip(tmp_path, name):
    v = load_model(name)
    path = tmp_path / f"{name}.json"
    write_model_file(v, path)
    doc = json.loads(path.read_text())
    assert len(doc["thrusters"]) == BLUEROV[name] and doc["thruster_curve"]["supply_voltage_V"] == 14.8
    back = read_model_file(path)
    assert back.n_thrusters == v.n_thrusters and back.extras["voltage"] == 14.8
    for a, b in zip(back.thrusters, v.thrusters):
        assert a == b
    pa, pb = plant_parameters(back), plant_parameters(v)
    for field in ("M", "D_L", "Q", "T", "f_min", "f_max", "r_g", "r_b"):
        np.testing.assert_array_equal(getattr(pa, field), getattr(pb, field))
    assert (pa.weight, pa.buoyancy, pa.supply_voltage) == (pb.weight, pb.buoyancy, pb.supply_voltage)


def test_vehicle_toml_path_and_bad_descriptions(tmp_path):
    src = tmp_path / "myrov.toml"
    shipped = resources.files("udrobot_ctrl.models").joinpath("bluerov2.toml").read_text()
    text = shipped.replace('name = "bluerov2"', 'name = "myrov"')
    src.write_text(text)
    assert load_model(str(src)).name == "myrov"
    doc = tomllib.loads(text)
    doc["hydrodynamics"]["added_mass"]["Y"]["value"] = -7.12
    with pytest.raises(ValueError, match=r"added_mass\] Y = -7.12: expected a finite value >= 0"):
        vehicle_from_description(doc, "myrov.toml")
    doc = tomllib.loads(text)
    doc["thrusters"][2]["direction"] = [1.0, 1.0, 0.0]
    with pytest.raises(ValueError, match=r"myrov.toml: thrusters\[2\].*unit length"):
        vehicle_from_description(doc, "myrov.toml")
    doc = tomllib.loads(text)
    del doc["hydrodynamics"]["quadratic_damping"]
    with pytest.raises(ValueError, match="myrov.toml: missing field 'quadratic_damping'"):
        vehicle_from_description(doc, "myrov.toml")
    with pytest.raises(ValueError, match="unknown vehicle 'bluerov3'"):
        vehicle_model("bluerov3")


def test_motor_direction_reverses_one_thruster():
    """MOT_i_DIRECTION = -1: logged pwm below 1500 us is thruster i's strong sense along its direction."""
    from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
    from udrobot_ctrl.io.mavlink import motor_command_pwm

    v = load_model("bluerov2-heavy")
    dirs = [-1, -1, 1, 1, -1, 1, 1, -1]  # MOT_1..8_DIRECTION of the shipped ardusub_log_tools Heavy logs
    w = apply_motor_directions(v, dirs)
    Tv, Tw = plant_parameters(v).T, plant_parameters(w).T
    np.testing.assert_allclose(Tw, Tv * np.array(dirs, float))
    t1v, t1w = v.thrusters[0], w.thrusters[0]
    assert (t1w.max_forward_N, t1w.max_reverse_N) == (t1v.max_reverse_N, t1v.max_forward_N)
    assert w.thrusters[2] == v.thrusters[2]
    assert "MOT_DIRECTION = -1" in w.provenance["thrusters[0]"]
    # exact route: mirrored PWM through the unreversed model. Logged 1400 us on motor 1 (reversed) is a +100 us
    # command: the strong forward thrust along motor 1's ArduSub direction
    cmd = motor_command_pwm(np.array([1400.0] * 8), dirs)
    np.testing.assert_array_equal(cmd, [1600, 1600, 1400, 1400, 1600, 1400, 1400, 1600])
    f = pwm_to_thrust(cmd, 14.8)
    assert f[0] == pwm_to_thrust(1600.0, 14.8) > -pwm_to_thrust(1400.0, 14.8) > 0  # strong sense, not the weak one
    with pytest.raises(ValueError, match="expected 8 motor directions"):
        apply_motor_directions(v, [1, -1])
    with pytest.raises(ValueError, match="expected 8 motor directions"):
        motor_command_pwm(np.zeros(8), [1, 2, 1, 1, 1, 1, 1, 1])
