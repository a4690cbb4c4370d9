"""Model names load; their surge/sway/heave entries equal Cely 2019's tables (issue 2, test 4)."""
import json

import numpy as np
import pytest

from udrobot_ctrl.dynamics.plant import SingularMassMatrixError, plant_parameters
from udrobot_ctrl.vehicle import MODEL_NAMES, load_model, read_model_file, to_model_dict, write_model_file

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
    with pytest.raises(ValueError, match="trunc.json: not valid JSON"):
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
