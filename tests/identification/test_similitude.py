"""Scale model -> full size (30 % spring model, Table 2; 22 % pendulum model, Table 3)."""
from __future__ import annotations

import pytest

from identification import similitude
from identification.identify import RigOptions, resolve_rig
from udrobot_ctrl.vehicle import full_size_vehicle

RHO, MU = 1000.0, 1.0e-3  # water density kg/m^3, dynamic viscosity Pa s


def quadratic_drag_coefficient(cd, length):
    """K_Q = 1/2 rho C_D A of a body whose projected area is 0.3 L^2 (geometric similitude)."""
    return 0.5 * RHO * cd * 0.3 * length ** 2


def linear_viscous_coefficient(length):
    """Skin-friction linear damping F = c mu L u (Stokes-like, c a shape constant): K_L = c mu L."""
    return 7.0 * MU * length


@pytest.mark.parametrize("scale", [0.30, 0.22])
def test_laws_follow_from_the_physics_of_each_term(scale):
    full_length = 0.395  # Table 1, L5
    model_length = scale * full_length
    # quadratic drag: same C_D, area ~ L^2  ->  K_Q,full = K_Q,model / lambda^2
    kq_model = quadratic_drag_coefficient(1.4, model_length)
    assert similitude.scale_values(kq_model, "KQ", scale) == pytest.approx(quadratic_drag_coefficient(1.4, full_length))
    # viscous linear damping ~ mu L  ->  K_L,full = K_L,model / lambda (Reynolds law)
    kl_model = linear_viscous_coefficient(model_length)
    assert similitude.scale_values(kl_model, "KL", scale) == pytest.approx(linear_viscous_coefficient(full_length))
    # Froude alternative: lambda^-2.5
    assert similitude.full_scale_factor("KL", scale, "froude") == pytest.approx(scale ** -2.5)
    # dimensionless coefficients are unchanged
    assert similitude.full_scale_factor("Cm", scale) == 1.0
    assert similitude.full_scale_factor("CD", scale) == 1.0


def test_reference_masses():
    """Geometric reference rho V_model / lambda^3 for each model, the vehicle's, or a given mass."""
    m_spring, desc = similitude.reference_displaced_mass("geometric", 344_868e-9, 0.30)
    assert m_spring == pytest.approx(12.77, abs=0.01) and "geometric" in desc
    m_pend, _ = similitude.reference_displaced_mass("geometric", 107_597e-9, 0.22)
    assert m_pend == pytest.approx(10.10, abs=0.01)
    m_none, _ = similitude.reference_displaced_mass(None, 107_597e-9, 0.22)
    assert m_none == m_pend
    m_vehicle, desc = similitude.reference_displaced_mass("vehicle", 344_868e-9, 0.30, vehicle=full_size_vehicle())
    assert 9.0 < m_vehicle < 10.0 and "udrobot.toml" in desc  # rho V of the full-size description
    with pytest.raises(ValueError, match="full-size vehicle"):
        similitude.reference_displaced_mass("vehicle", 344_868e-9, 0.30)  # the vehicle is the caller's to give
    assert similitude.reference_displaced_mass(9.2, 344_868e-9, 0.30)[0] == 9.2
    for bad in ("heavy", -3.0):
        with pytest.raises(ValueError):
            similitude.reference_displaced_mass(bad, 344_868e-9, 0.30)


@pytest.mark.parametrize("cm, added_mass_paper", [
    (0.8172, 7.5187), (0.1945, 1.7895), (1.1564, 10.6391),  # free decay, Table 7 / sec. 4.2.1
    (0.9024, 8.3027), (0.2404, 2.2117), (0.8283, 7.6211),  # pendulum Chin, sec. 4.3.1
    (0.9073, 8.3472), (0.2406, 2.2135), (0.8281, 7.6194),  # pendulum Morison, sec. 4.4.1
])
def test_paper_added_masses_are_cm_times_9_20_kg(cm, added_mass_paper):
    """The paper's full-size added masses are C_m x 9.20 kg (not its 9.36 kg, nor a scaled volume)."""
    full = similitude.full_scale({"Cm": {"value": cm, "ci95": [cm - 0.01, cm + 0.01]},
                                  "added_mass_kg": {"value": 0.3, "ci95": None}}, 0.30, 9.20)
    assert full["added_mass_kg"]["value"] == pytest.approx(added_mass_paper, rel=5e-4)
    assert full["added_mass_kg"]["ci95"] == pytest.approx([(cm - 0.01) * 9.20, (cm + 0.01) * 9.20])
    assert full["Cm"]["value"] == cm
    # 9.36 kg (Table 1) would miss by 1.7 %
    assert abs(cm * 9.36 / added_mass_paper - 1) > 0.015


def test_full_scale_scales_values_and_intervals_and_states_the_law():
    agg = {"KQ": {"value": 2.46, "ci95": [2.4, 2.5]}, "KL": {"value": 0.236, "ci95": [0.2, 0.27]},
           "CD": {"value": 2.34, "ci95": [2.3, 2.4]}, "Re": {"min": 1.0, "max": 2.0}}
    full = similitude.full_scale(agg, 0.22, 9.2)
    assert full["KQ"]["value"] == pytest.approx(2.46 / 0.22 ** 2)  # ~50.8 N s^2/m^2 as Table 10
    assert full["KQ"]["ci95"] == pytest.approx([2.4 / 0.22 ** 2, 2.5 / 0.22 ** 2])
    assert full["KL"]["value"] == pytest.approx(0.236 / 0.22)  # ~1.07 N s/m as Table 10
    assert "lambda^2" in full["KQ"]["law"] and "reynolds" in full["KL"]["law"]
    assert "Re" not in full and "added_mass_kg" not in full  # no C_m: no added mass
    froude = similitude.full_scale(agg, 0.22, 9.2, KL_law="froude")
    assert froude["KL"]["value"] == pytest.approx(0.236 * 0.22 ** -2.5)


def test_invalid_scale_and_law():
    with pytest.raises(ValueError, match="scale"):
        similitude.full_scale_factor("KQ", 0.0)
    with pytest.raises(ValueError, match="law"):
        similitude.full_scale_factor("KL", 0.3, "weber")
    with pytest.raises(ValueError, match="no scaling law"):
        similitude.full_scale_factor("omega_n", 0.3)


def test_default_area_needs_the_full_size_vehicle():
    """Without --area the projected areas come from the full-size vehicle the caller gives, scaled by lambda^2."""
    with pytest.raises(ValueError, match="projected area"):
        resolve_rig("spring", RigOptions())
    udrobot = full_size_vehicle()
    o = resolve_rig("spring", RigOptions(vehicle=udrobot))
    assert o.area["heave"] == pytest.approx(udrobot.projected_area["heave"] * 0.30 ** 2)
    assert "models/udrobot.toml" in o.provenance["area"]
