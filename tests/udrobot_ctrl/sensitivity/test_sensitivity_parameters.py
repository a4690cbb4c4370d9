"""Parameter space: ranges derived from the three coefficient sets contain every set's value."""
import numpy as np
import pytest

from udrobot_ctrl.sensitivity.parameters import (
    apply_sample,
    default_space,
    parse_range,
    read_study_file,
    set_values,
)
from udrobot_ctrl.vehicle import MODEL_NAMES, load_model


@pytest.mark.parametrize("model", ["cfd:chin", "pendulum:chin", "cfd:morison", "free_decay:morison"])
def test_ranges_contain_every_set_value(model):
    space = default_space(model)
    checked = 0
    for quantity, per_set in set_values(space.form).items():
        for i, axis in enumerate(("surge", "sway", "heave")):
            p = space.parameters[space.index(f"{axis}.{quantity}")]
            for set_name, vals in per_set.items():
                assert p.low < vals[i] < p.high, (p.name, set_name, vals[i], p.low, p.high)
                checked += 1
            assert p.low < p.nominal < p.high
    assert checked >= 15
    # surge C_D: free decay 1.40, CFD 1.70, pendulum 2.34 all inside, widened by the 10 % margin
    if space.form == "morison":
        cd = space.parameters[space.index("surge.CD")]
        assert cd.low == pytest.approx(1.4015 * 0.9) and cd.high == pytest.approx(2.3432 * 1.1)


def test_every_shipped_model_gets_a_space_and_nominal_sample_is_identity():
    for name in MODEL_NAMES:
        space = default_space(name)
        v = apply_sample(space, space.nominal)
        ref = load_model(name)
        for k in ("added_mass", "linear_damping", "quadratic_damping"):
            np.testing.assert_allclose(getattr(v, k), getattr(ref, k), rtol=1e-12, atol=1e-12)


def test_sample_changes_exactly_one_entry_and_cd_maps_to_morison_drag():
    space = default_space("cfd:morison")
    x = space.nominal.copy()
    x[space.index("surge.CD")] = 2.3432
    v = apply_sample(space, x)
    # K_D = 1/2 rho C_D A with A = 0.04938 m^2 (Table 5 K_D / C_D)
    assert v.quadratic_damping[0, 0] == pytest.approx(0.5 * 1000 * 2.3432 * 0.04938, rel=1e-9)
    diff = v.quadratic_damping != space.vehicle.quadratic_damping
    assert diff.sum() == 1
    x = space.nominal.copy()
    x[space.index("yaw.added_mass_scale")] = 1.5
    v = apply_sample(space, x)
    assert v.added_mass[5, 5] == pytest.approx(1.5 * space.vehicle.added_mass[5, 5])


def test_user_ranges_and_errors(tmp_path):
    space = default_space("pendulum:chin")
    name, rng = parse_range("surge.KQ=30:70")
    s2 = space.with_ranges({name: rng})
    assert s2.parameters[s2.index("surge.KQ")].low == 30 and s2.parameters[s2.index("surge.KQ")].source == "user"
    with pytest.raises(ValueError, match="expected NAME=LOW:HIGH"):
        parse_range("surge.KQ 30 70")
    with pytest.raises(ValueError, match="low < high"):
        space.with_ranges({"surge.KQ": (70, 30)})
    with pytest.raises(ValueError, match="unknown parameter"):
        space.subset(["surge.CD"])  # chin form has no C_D
    f = tmp_path / "study.toml"
    f.write_text('parameters = ["surge.KQ", "heave.KQ"]\n[ranges]\n"surge.KQ" = [30.0, 70.0]\n')
    doc = read_study_file(f)
    assert doc["parameters"] == ["surge.KQ", "heave.KQ"] and doc["ranges"]["surge.KQ"] == (30.0, 70.0)
    f.write_text('[ranges]\n"surge.KQ" = [30.0]\n')
    with pytest.raises(ValueError, match=r"study.toml: \[ranges\] surge.KQ"):
        read_study_file(f)
    with pytest.raises(ValueError, match="surge.KQ = -1.0"):
        x = space.nominal.copy()
        x[space.index("surge.KQ")] = -1.0
        apply_sample(space, x)
