"""Issue 40 item 6: an ``effects`` list cannot give a model the physics its base fields may not have."""
from __future__ import annotations

import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from udrobot_ctrl.cli import main
from udrobot_ctrl.dynamics.effects import CATALOGUE, PARAMETER_RANGES, plant_effect
from udrobot_ctrl.vehicle import load_model, model_from_dict, to_model_dict

BASE = to_model_dict(load_model("cfd:chin"))

# a valid entry of each effect, from which one parameter at a time is changed
VALID = {
    "thrust_inflow_loss": {"k1_per_mps": 0.1, "k2_per_mps": 0.1},
    "thruster_deadband": {"width_fraction": 0.1, "shift": 0.5, "command_exponent": 1.5},
    "thruster_asymmetry": {"reverse_loss": 0.2},
    "thruster_lag": {"T_lag_s": 0.1, "thrust_exponent": 1.0},
    "tether_drag": {"k_quadratic_N_s2_per_m2": 10.0, "k_linear_N_s_per_m": 1.0, "anchor_north_m": -3.0,
                    "anchor_east_m": 0.0, "anchor_down_m": -0.3, "cable_taut": 0.5},
    "wall_effect": {"decay_length_m": 0.1, "added_mass_at_contact_kg": 5.0, "suction_N_s2_per_m2": 20.0,
                    "seabed_depth_m": 3.0},
    "water_current": {"current_north_mps": 0.1, "current_east_mps": 0.0, "current_down_mps": 0.0},
    "linear_damping": {f"d_{d}": 1.0 for d in ("Xu", "Yv", "Zw", "Kp", "Mq", "Nr")},
    "quadratic_damping_error": {f"scale_{d}|{v}|": 0.1 for d, v in zip(("Xu", "Yv", "Zw", "Kp", "Mq", "Nr"),
                                                                       "uvwpqr")},
    "added_mass_error": {f"scale_{d}": 0.1 for d in ("Xdu", "Ydv", "Zdw", "Kdp", "Mdq", "Ndr")},
    "cross_coupled_damping": {"D_Xv": 0.1},
    "buoyancy_offset": {"dB_N": -1.0},
    "cg_cb_offset": {"dBG_x_Nm": 0.1, "dBG_y_Nm": 0.0, "dBG_z_Nm": 0.0},
}


def _model(tmp_path, effects):
    doc = dict(BASE, effects=effects)
    path = tmp_path / "m.json"
    path.write_text(json.dumps(doc))
    return path


def test_every_catalogue_parameter_has_a_range():
    for name, kind in CATALOGUE.items():
        names = set(kind.optional).union(*((kind.parameters,) + kind.alternatives))
        assert names == set(PARAMETER_RANGES[name]), name
    for name, params in VALID.items():
        plant_effect({"name": name, "params": params})  # the valid entries are valid


@pytest.mark.parametrize("name,key,value", [
    ("linear_damping", "d_Xu", -1e3),  # total linear damping negative
    ("linear_damping", "d_Zw", 1e300),
    ("buoyancy_offset", "dB_N", -1e4),  # total buoyancy negative
    ("water_current", "current_north_mps", 100.0),
    ("cg_cb_offset", "dBG_x_Nm", 1e12),
    ("thruster_lag", "T_lag_s", 1e300),
])
def test_model_file_with_impossible_effect_is_refused_naming_file_effect_parameter_range(tmp_path, capsys, name,
                                                                                          key, value):
    path = _model(tmp_path, [{"name": name, "params": {**VALID[name], key: value}}])
    assert main(["model", "show", "--model", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "effects[0]" in err and name in err and key in err, err
    assert "[" in err and "]" in err, err  # the accepted range


def test_nan_parameter_is_refused(tmp_path, capsys):
    path = tmp_path / "m.json"
    path.write_text(json.dumps(dict(BASE, effects=[{"name": "buoyancy_offset", "params": {"dB_N": float("nan")}}])))
    assert "NaN" in path.read_text()
    assert main(["model", "show", "--model", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "dB_N" in err and "finite" in err


def test_energy_generating_cross_damping_is_refused():
    d_xu = BASE["linear_damping"][0][0]
    doc = dict(BASE, effects=[{"name": "cross_coupled_damping", "params": {"D_Xv": 50 * d_xu + 1e3,
                                                                           "D_Yu": 50 * d_xu + 1e3}}])
    with pytest.raises(ValueError, match="cross_coupled_damping.*generate energy"):
        model_from_dict(doc, "m.json")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.sampled_from(sorted(VALID)), data=st.data(),
       value=st.one_of(st.floats(allow_nan=False, allow_infinity=False, width=64),
                       st.sampled_from([1e300, -1e300, 1e12, -1e12])))
def test_any_parameter_outside_its_range_is_refused_and_inside_accepted(name, data, value):
    key = data.draw(st.sampled_from(sorted(VALID[name])))
    lo, hi, _ = PARAMETER_RANGES[name][key]
    doc = dict(BASE, effects=[{"name": name, "params": {**VALID[name], key: value}}])
    if not lo <= value <= hi:
        with pytest.raises(ValueError, match=rf"m\.json: effects\[0\].*{name}.*{key.replace('|', '.')}"):
            model_from_dict(doc, "m.json")
        return
    try:
        vehicle = model_from_dict(doc, "m.json")
    except ValueError as exc:  # inside the absolute range but against the model: a named, bounded refusal
        msg = str(exc)
        assert "m.json: effects[0]" in msg or "m.json: effect(s)" in msg, msg
        return
    assert all(math.isfinite(v) for e in vehicle.effects for v in e.params.values())


def test_model_show_lists_effects(tmp_path, capsys):
    path = _model(tmp_path, [{"name": "buoyancy_offset", "params": {"dB_N": -4.0}},
                             {"name": "thruster_lag", "params": {"T_lag_s": 0.2}}])
    assert main(["model", "show", "--model", str(path)]) == 0
    out = capsys.readouterr().out
    assert "effects (2" in out and "buoyancy_offset (parameters): dB_N -4" in out
    assert "thruster_lag (lag): T_lag_s 0.2" in out
    assert main(["model", "show", "--model", "cfd:chin"]) == 0
    assert "effects: none" in capsys.readouterr().out
