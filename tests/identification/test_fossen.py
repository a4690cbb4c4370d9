"""identification.fossen and identification.sets: coefficient sets -> Fossen M_A and D(nu)."""
import numpy as np
import pytest

from identification import fossen
from identification.sets import (
    coefficient_set_from_dict,
    dump_coefficient_set,
    load_coefficient_set,
    write_coefficient_set,
)


def _set(**kw):
    doc = {"name": "t", "surge": {}, "sway": {}, "heave": {}}
    for key, vals in kw.items():
        for axis, v in zip(fossen.AXES, vals):
            doc[axis][key] = {"value": v, "provenance": "measured: test"}
    return coefficient_set_from_dict(doc)


def test_morison_quadratic_is_half_rho_cd_area():
    kd = fossen.quadratic_from_drag_coefficient([1.7021, 0.6226, 1.2929], [0.04938, 0.09039, 0.09039], 1000.0)
    # Cely 2019 Table 5: K_D = 42.0253 / 28.1384 / 58.4346 N s^2/m^2
    np.testing.assert_allclose(kd, [42.0253, 28.1384, 58.4346], rtol=2e-3)


def test_strip_theory_yaw_added_inertia_of_uniform_box():
    # sway added mass 12 kg spread over a 1 m long body: N_rdot = 12 * 1^2 / 12 = 1 kg m^2 (+ surge part)
    rot = fossen.strip_theory_rotational([0.0, 12.0, 0.0], [1.0, 0.5, 0.2], power=2)
    assert rot[2] == pytest.approx(1.0)
    # quadratic: integral of x^2 |x| over [-L/2, L/2] per unit length -> K_Q L^3 / 32
    rotq = fossen.strip_theory_rotational([0.0, 32.0, 0.0], [2.0, 0.5, 0.2], power=3)
    assert rotq[2] == pytest.approx(8.0)


def test_quadratic_moment_matches_numerical_strip_integral():
    L, kq, r = 0.6, 20.0, 0.7
    x = np.linspace(-L / 2, L / 2, 20001)
    moment = np.trapezoid(x * (kq / L) * np.abs(x * r) * x * r, x)
    est = fossen.strip_theory_rotational([0, kq, 0], [L, 0.0, 0.0], power=3)[2] * abs(r) * r
    assert est == pytest.approx(moment, rel=1e-6)


def test_forms_and_missing_coefficients():
    cs = _set(added_mass=[1, 2, 3], CD=[1.0, 1.0, 1.0])
    assert cs.forms == ("morison",)
    with pytest.raises(ValueError, match="no 'chin' form"):
        fossen.translational_damping(cs, "chin", [0.1] * 3)
    with pytest.raises(ValueError, match="damping form"):
        fossen.translational_damping(cs, "linear", [0.1] * 3)
    kl, kq = fossen.translational_damping(cs, "morison", [0.2, 0.2, 0.2])
    assert np.all(kl == 0) and kq == pytest.approx([100.0] * 3)


def test_damping_force_chin_and_batch():
    D_L = np.diag([1.0, 2, 3, 4, 5, 6])
    Q = np.diag([10.0, 20, 30, 40, 50, 60])
    nu = np.array([[0.5, -1, 0, 0, 0, 0.1], [1.0, 0, 0, 0, 0, 0]])
    f = fossen.damping_force(nu, D_L, Q)
    assert f[0, 0] == pytest.approx(0.5 + 10 * 0.25)
    assert f[0, 1] == pytest.approx(-2 - 20)
    assert f[1, 0] == pytest.approx(11.0)


def test_set_round_trip_and_bad_files(tmp_path):
    path = tmp_path / "mine.toml"
    write_coefficient_set(path, "mine", {"added_mass": [1.0, 2.0, 3.0], "KL": [0.1, 0.2, 0.3],
                                         "KQ": [10.0, 20.0, 30.0], "CD": None})
    cs = load_coefficient_set(path)
    assert cs.name == "mine" and cs.forms == ("chin",)
    np.testing.assert_allclose(cs.KQ, [10, 20, 30])
    text = dump_coefficient_set("x", {"added_mass": [1.0, 2.0, 3.0]})
    (tmp_path / "neg.toml").write_text(text.replace("value = 2.0", "value = -2.0"))
    with pytest.raises(ValueError, match=r"neg.toml: \[sway\] added_mass"):
        load_coefficient_set(tmp_path / "neg.toml")
    (tmp_path / "broken.toml").write_text("[surge\nadded_mass = 1")
    with pytest.raises(ValueError, match="broken.toml: not valid TOML"):
        load_coefficient_set(tmp_path / "broken.toml")
    (tmp_path / "partial.toml").write_text(text.replace("[heave]", "[heave]\nKL = 1.0"))
    with pytest.raises(ValueError, match="KL missing for surge, sway"):
        load_coefficient_set(tmp_path / "partial.toml")
