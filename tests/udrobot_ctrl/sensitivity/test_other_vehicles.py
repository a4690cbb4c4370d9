"""Sensitivity on the BlueROV2 models: thrust allocation, design states and ranges come from the vehicle."""
from __future__ import annotations

import numpy as np
import pytest

from udrobot_ctrl.control.missions import standard_mission
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.sensitivity.evaluators import MissionEvaluator, surge_thrusts
from udrobot_ctrl.sensitivity.parameters import default_space
from udrobot_ctrl.vehicle import load_model


@pytest.mark.parametrize("name", ["cfd:chin", "bluerov2-heavy"])
def test_surge_force_is_a_pure_surge_wrench(name):
    T = plant_parameters(load_model(name)).T
    tau = T @ surge_thrusts(T, 20.0)
    np.testing.assert_allclose(tau, [20.0, 0, 0, 0, 0, 0], atol=1e-9)


def test_bluerov2_surge_force_carries_its_pitch_moment():
    T = plant_parameters(load_model("bluerov2")).T
    tau = T @ surge_thrusts(T, 20.0)
    np.testing.assert_allclose(tau, [20.0, 0, 0, 0, 0.0725 * 20.0, 0], atol=1e-9)


@pytest.mark.slow
def test_the_study_flies_compares_lqr_on_the_heavy_and_it_keeps_control():
    space = default_space("bluerov2-heavy")
    out = MissionEvaluator(space, "lqr", mission=standard_mission(quick=True))(space.nominal[None])
    assert out["error"] == [""]
    assert out["lost_control"][0] == 0 and np.isfinite(out["iae_z"][0])


def test_ranges_come_from_the_published_alternatives():
    space = default_space("bluerov2-heavy")
    p = space.parameters[space.index("surge.KQ")]
    assert p.nominal == 141.0 and p.low == pytest.approx(18.18 * 0.9) and p.high == pytest.approx(141.0 * 1.1)
    assert "Wu2018" in p.source
    p6 = default_space("bluerov2").parameters[default_space("bluerov2").index("surge.added_mass")]
    assert p6.low == pytest.approx(2.6 * 0.9) and "11.4kg-set" in p6.source
