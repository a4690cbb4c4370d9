"""``compare`` designs each controller once per design model and flies it on every plant: a controller with state
(PID integrators, MPC warm start) must fly the second plant exactly as a freshly designed one would."""
from __future__ import annotations

import pytest

from udrobot_ctrl.control.compare import CONTROL_DT, _fly, run_design
from udrobot_ctrl.control.missions import make_controller, standard_mission

DESIGN, PLANTS = "pendulum:chin", ["cfd:morison", "free_decay:morison"]
# PID: bit for bit. Linear MPC: reset() forgets the plan, but OSQP keeps its ADMM state (warm start, adapted
# rho) inside the solver, so the two flights agree to the solver's tolerance (eps_rel 1e-4), not bit for bit.
REL = {"pid": 1e-12, "lmpc": 1e-4}
KEYS = ("iae", "overshoot", "settling_s", "energy_J", "saturation_s", "max_pitch_deg")


@pytest.mark.parametrize("kind", ["pid", "lmpc"])
def test_reused_design_flies_like_a_fresh_one(kind):
    rows, _ = run_design(kind, DESIGN, PLANTS, quick=True, keep_trajectory=False)
    mission = standard_mission(True)
    fresh, _ = _fly(make_controller(kind, DESIGN, mission, control_dt=CONTROL_DT), kind, DESIGN, PLANTS[1], mission)
    reused = rows[1]
    assert reused["plant"] == PLANTS[1] and reused["status"] == "ok"
    for k in KEYS:
        if fresh[k] is None:  # e.g. settling_s: did not settle
            assert reused[k] is None, k
        else:
            assert reused[k] == pytest.approx(fresh[k], rel=REL[kind], abs=1e-12), k
