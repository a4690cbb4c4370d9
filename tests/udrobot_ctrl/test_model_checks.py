"""Model files, coefficient sets and CFD tables that describe impossible physics are rejected, naming file and key."""
from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from identification.cfd import read_force_table
from identification.decay import LaunchError
from identification.sets import coefficient_set_from_dict, load_coefficient_set
from udrobot_ctrl.cli import main
from udrobot_ctrl.vehicle import load_model, model_from_dict, to_model_dict

SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
DOC = to_model_dict(load_model("cfd:chin"))


def _doc(**changes):
    doc = copy.deepcopy(DOC)
    for path, value in changes.items():
        keys = path.split("__")
        target = doc
        for k in keys[:-1]:
            target = target[int(k)] if k.isdigit() else target[k]
        target[int(keys[-1]) if keys[-1].isdigit() else keys[-1]] = value
    return doc


@pytest.mark.parametrize("change, message", [
    ({"thrusters__0__position": [float("nan"), 0.0, 0.0]}, r"thrusters\[0\]\.position: expected 3 finite"),
    ({"thrusters__1__direction": [0.0, 0.0, 0.0]}, r"thrusters\[1\]\.direction: \|d\| = 0; expected a unit vector"),
    ({"thrusters__0__max_forward_N": -36.4}, r"thrusters\[0\]\.max_forward_N = -36.4"),
    ({"thrusters__0__max_reverse_N": True}, r"thrusters\[0\]\.max_reverse_N: expected a number, got true"),
    ({"mass": True}, r"field 'mass' must be a number, got true"),
    ({"buoyancy": -10.0}, r"field 'buoyancy' = -10.0 must be finite and >= 0"),
    ({"linear_damping__2__2": -1.0}, r"'linear_damping'\[2\]\[2\] = -1.0 < 0"),
    ({"quadratic_damping__0__0": -5.0}, r"'quadratic_damping'\[0\]\[0\] = -5.0 < 0"),
    ({"linear_damping__0__1": 50.0}, r"'linear_damping': symmetric part has eigenvalue"),
    ({"added_mass__0__0": "3"}, r"field 'added_mass'\[0\]\[0\]: expected a number"),
    ({"inertia_cg__0__0": -0.1}, r"'inertia_cg' must be symmetric positive definite"),
])
def test_impossible_models_are_rejected_naming_the_field(tmp_path, capsys, change, message):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(_doc(**change)))
    with pytest.raises(ValueError, match=message) as exc:
        load_model(str(path))
    assert str(path) in str(exc.value)
    assert main(["model", "show", "--model", str(path)]) == 2
    assert "udrobot-ctrl model: error: " + str(path) in capsys.readouterr().err


def test_unknown_and_misspelt_model_fields():
    doc = _doc()
    doc["linear_dampng"] = doc.pop("linear_damping")
    with pytest.raises(ValueError, match=r"missing field 'linear_damping' \(found 'linear_dampng': a typo"), \
            pytest.warns(UserWarning, match="did you mean 'linear_damping'"):
        model_from_dict(doc, "m.json")
    doc = _doc()
    doc["thruster"] = []
    with pytest.warns(UserWarning, match=r"m.json: unknown field 'thruster' ignored \(did you mean 'thrusters'\?\)"):
        model_from_dict(doc, "m.json")


@SETTINGS
@given(i=st.integers(0, 5), j=st.integers(0, 5), scale=st.floats(0.0, 3.0))
def test_damping_accepted_iff_it_dissipates(i, j, scale):
    """Accepted exactly when nu^T D nu >= 0 for every nu (diag >= 0, symmetric part PSD): the physics, not a list."""
    D = np.diag([4.0, 6.0, 5.0, 0.5, 0.6, 0.4])
    if i != j:
        D[i, j] = scale * 2 * math.sqrt(D[i, i] * D[j, j])  # |D_ij + D_ji| / 2 vs sqrt(D_ii D_jj)
    doc = _doc(linear_damping=D.tolist())
    dissipative = np.linalg.eigvalsh(0.5 * (D + D.T)).min() >= -1e-9 * np.abs(D).max()
    if dissipative:
        model_from_dict(doc, "m.json")
        rng = np.random.default_rng(0)
        nu = rng.normal(size=(100, 6))
        assert np.all(np.einsum("ki,ij,kj->k", nu, D, nu) >= -1e-9)
    else:
        with pytest.raises(ValueError, match="symmetric part has eigenvalue"):
            model_from_dict(doc, "m.json")


def test_exported_models_still_load_without_warnings(tmp_path, recwarn):
    from udrobot_ctrl.vehicle import MODEL_NAMES

    for name in MODEL_NAMES:
        doc = to_model_dict(load_model(name))
        model_from_dict(json.loads(json.dumps(doc)), name)
    assert not [w for w in recwarn if issubclass(w.category, UserWarning)]


# ----------------------------------------------------------------------------- coefficient sets

SET = {"format": "udrobot-coefficients/1", "name": "s", "description": "",
       **{axis: {"added_mass": {"value": 3.0, "provenance": "measured"}, "KL": 1.0, "KQ": 40.0, "CD": 1.1}
          for axis in ("surge", "sway", "heave")}}


def test_misspelt_form_added_mass_is_rejected_with_suggestion(tmp_path):
    doc = copy.deepcopy(SET)
    doc["heave"]["added_mass_morrison"] = 5.0
    with pytest.raises(ValueError, match=r"\[heave\] added_mass_morrison: unknown quantity "
                                         r"\(did you mean 'added_mass_morison'\?\)"):
        coefficient_set_from_dict(doc, "x.toml")


@SETTINGS
@given(where=st.sampled_from(["top", "surge", "entry"]),
       key=st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=20))
def test_unknown_set_keys_are_rejected(where, key):
    doc = copy.deepcopy(SET)
    known = {"top": ("format", "name", "description", "forms", "surge", "sway", "heave"),
             "surge": ("added_mass", "KL", "KQ", "CD", "added_mass_chin", "added_mass_morison"),
             "entry": ("value", "provenance")}[where]
    if key in known:
        return
    target = doc if where == "top" else doc["surge"] if where == "surge" else doc["surge"]["added_mass"]
    target[key] = 1.0
    with pytest.raises(ValueError, match=rf"x\.toml: .*{key}"):
        coefficient_set_from_dict(doc, "x.toml")


@pytest.mark.parametrize("value, message", [(True, "expected a number, got True"), ("4", "expected a number"),
                                            (-1.0, "expected a finite value >= 0")])
def test_set_values_must_be_numbers(value, message):
    doc = copy.deepcopy(SET)
    doc["sway"]["KQ"] = value
    with pytest.raises(ValueError, match=rf"x\.toml: \[sway\] KQ.*{message}"):
        coefficient_set_from_dict(doc, "x.toml")


def test_set_file_typo_through_the_cli(tmp_path, capsys):
    text = "\n".join(['format = "udrobot-coefficients/1"', 'name = "t"'] + [
        f"[{a}]\nadded_mass = 3.0\nKL = 1.0\nKQ = 40.0\n" + ("added_mass_morrison = 5.0\n" if a == "heave" else "")
        for a in ("surge", "sway", "heave")])
    path = tmp_path / "t.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match="did you mean 'added_mass_morison'"):
        load_coefficient_set(path)
    assert main(["model", "show", "--model", f"{path}:chin"]) == 2
    assert "added_mass_morrison" in capsys.readouterr().err


# ----------------------------------------------------------------------------- CFD tables

@pytest.mark.parametrize("rows, message", [
    ("0.5,5\n1,5\n2,5", r"row 3, field 'force': \|force\| 5 N at \|speed\| 1 m/s \(row 3\) is not above 5 N"),
    ("0.5,-2\n1,-9.8\n2,-39", r"row 2, field 'force': force -2 N at speed 0.5 m/s is of the opposite sign"),
    ("0.5,0\n1,0\n2,0", r"row 2, field 'force': force 0 N at speed 0.5 m/s is zero"),
    ("0.5,10\n1,8\n2,30", r"not above 10 N at 0.5 m/s"),
])
def test_cfd_tables_that_are_not_drag_curves(tmp_path, rows, message):
    path = tmp_path / "cfd_surge.csv"
    path.write_text("speed,force\n" + rows + "\n")
    with pytest.raises(LaunchError, match=message):
        read_force_table(path)


@SETTINGS
@given(kl=st.floats(0.0, 5.0), kq=st.floats(0.1, 80.0), sign=st.sampled_from([1.0, -1.0]))
def test_physical_drag_tables_are_accepted(tmp_path, kl, kq, sign):
    """Any F = K_L u + K_Q |u| u with K_L >= 0, K_Q > 0 (either flow direction, u = 0 included) is a drag curve."""
    u = sign * np.r_[0.0, 0.2, 0.5, 1.0, 2.0, 4.0]
    f = kl * u + kq * np.abs(u) * u
    path = tmp_path / "cfd_sway.csv"
    path.write_text("speed,force\n" + "\n".join(f"{float(a)!r},{float(b)!r}" for a, b in zip(u, f)) + "\n")
    table = read_force_table(path)
    np.testing.assert_array_equal(table.force, f)
