"""What a correction buys: controllers redesigned on a plant with effects, flown on that plant (issue 14)."""
from __future__ import annotations

import pytest

from udrobot_ctrl.control.compare import run_design
from udrobot_ctrl.dynamics.effects import PlantEffect
from udrobot_ctrl.vehicle import load_model

#: a heavier vehicle on a trailing tether whose thrusters lose thrust with inflow (each an assumed magnitude of the
#: size the diagnoser reports on pool logs: 4 N of missing buoyancy, C_D ~ 1 on a few metres of cable)
EFFECTS = (
    PlantEffect("tether_drag", {"k_quadratic_N_s2_per_m2": 15.0, "k_linear_N_s_per_m": 1.0,
                                "cable_azimuth_rad": 3.14, "cable_elevation_rad": 0.5}),
    PlantEffect("buoyancy_offset", {"dB_N": -4.0}),
    PlantEffect("thrust_inflow_loss", {"k1_per_mps": 0.3, "k2_per_mps": 0.0}),
)


@pytest.fixture(scope="module")
def rows():
    corrected = load_model("pendulum:chin").with_changes(name="corrected", effects=EFFECTS)
    out = {}
    for kind in ("lqr", "lmpc", "pid"):
        for design in ("pendulum:chin", corrected):
            (row,), _ = run_design(kind, design, [corrected], quick=True, keep_trajectory=False)
            assert row["status"].startswith("ok"), row["status"]
            out[kind, "corrected" if design is corrected else "nominal"] = row
    return out


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["lqr", "lmpc"])
def test_a_controller_redesigned_on_the_corrected_plant_tracks_better_on_it(rows, kind):
    # the trim and the linearisation now include the missing weight and the tether: without integral action the
    # nominal design carries a steady depth and speed error that the redesign removes
    assert rows[kind, "corrected"]["iae"] < 0.95 * rows[kind, "nominal"]["iae"]


@pytest.mark.slow
def test_integral_action_already_hides_most_of_the_correction(rows):
    # the PID's integrators absorb the constant buoyancy and drag offsets: the redesign helps little either way
    nominal, corrected = rows["pid", "nominal"]["iae"], rows["pid", "corrected"]["iae"]
    assert corrected == pytest.approx(nominal, rel=0.10)
