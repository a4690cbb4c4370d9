"""``udrobot-ctrl model export|show``: the exported file reads back to an identical plant."""
from __future__ import annotations

import json

import numpy as np
import pytest

from udrobot_ctrl.cli import main
from udrobot_ctrl.dynamics.plant import plant_parameters, state_derivative
from udrobot_ctrl.vehicle import MODEL_NAMES, load_model


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_export_reads_back_to_identical_plant(tmp_path, name):
    out = tmp_path / "m.json"
    assert main(["model", "export", "--model", name, "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["format"] == "udrobot-model/1" and doc["provenance"]
    a, b = plant_parameters(load_model(name)), plant_parameters(load_model(str(out)))
    for field in ("M", "M_inv", "D_L", "Q", "r_g", "r_b", "T", "f_min", "f_max"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert (a.weight, a.buoyancy) == (b.weight, b.buoyancy)
    rng = np.random.default_rng(1)
    x, tau = rng.normal(size=(10, 12)) * 0.5, rng.normal(size=(10, 6)) * 10
    np.testing.assert_array_equal(state_derivative(x, tau, a), state_derivative(x, tau, b))


def test_export_refuses_to_overwrite(tmp_path, capsys):
    out = tmp_path / "m.json"
    out.write_text("keep me")
    assert main(["model", "export", "--model", "cfd:chin", "--out", str(out)]) == 2
    assert out.read_text() == "keep me"
    assert "exists" in capsys.readouterr().err


def test_show_lists_actuated_and_passive_dofs_and_provenance(capsys):
    assert main(["model", "show", "--model", "pendulum:morison"]) == 0
    text = capsys.readouterr().out
    assert "actuated DOFs: X, Z, K, N" in text and "passive: Y, M" in text
    assert "provenance:" in text and "measured" in text


def test_unknown_model_is_a_clean_error(capsys):
    assert main(["model", "show", "--model", "nosuch:chin"]) == 2
    assert "nosuch" in capsys.readouterr().err


def test_show_prints_thruster_coordinates_as_plain_numbers(capsys):
    """Thruster positions and directions print as numbers (a vehicle TOML's arrays are numpy floats: their repr is
    ``np.float64(0.156)`` under numpy 2, which a reader should never see)."""
    assert main(["model", "show", "--model", "bluerov2-heavy"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("thruster T")]
    assert len(lines) == 8
    assert not any("np." in ln or "float" in ln for ln in lines)
    assert "position [0.156, 0.111, 0.085] m, direction [-0.7071, 0.7071, 0.0]" in lines[0]
