"""Design a gain-scheduled LQR on one coefficient set and fly the standard mission on another.

    python examples/design_lqr.py [design_model] [plant_model] [--quick]

Prints the operating points (trim thrusts, top speed), the controllability report of the reduced
design state, the passive-DOF eigenvalues, the LQR gains' closed-loop poles and the mission metrics.
"""
import sys

import numpy as np

from udrobot_ctrl.control.linearize import linearize, operating_points, passive_modes
from udrobot_ctrl.control.lqr import ScheduledLQR
from udrobot_ctrl.control.metrics import mission_metrics
from udrobot_ctrl.control.missions import run_mission, standard_mission
from udrobot_ctrl.dynamics.sim import as_parameters


def main(argv):
    names = [a for a in argv if not a.startswith("--")]
    design = names[0] if names else "cfd:chin"
    plant = names[1] if len(names) > 1 else "free_decay:morison"
    mission = standard_mission(quick="--quick" in argv)
    p = as_parameters(design)
    for pt in operating_points(p):
        lin = linearize(p, pt)
        pm = passive_modes(lin)
        verdict = "stable" if pm["stable"] else "marginal" if pm["marginal"] else "UNSTABLE"
        print(f"{pt.name:>20}: trim thrust {np.round(pt.u0, 2)} N; passive eigenvalues "
              f"{np.round(pm['eigenvalues'], 3)} ({verdict})")
    ctrl = ScheduledLQR.design(p, mission.reference, dt=0.05)
    print(ctrl.designs[0].report.summary())
    for d in ctrl.designs:
        print(f"{d.lin.point.name:>20}: largest closed-loop |z| = {np.max(np.abs(d.closed_loop_poles)):.3f} (discrete)")
    res = run_mission(ctrl, plant, mission)
    q = as_parameters(plant)
    m = mission_metrics(res, mission, q.f_min, q.f_max)
    print(f"LQR designed on {design}, flown on {plant} ({mission.name}):")
    for k, unit, fmt in (("iae", "s (weighted total)", ".3f"), ("overshoot", "% of the depth step", ".1f"),
                         ("settling_s", "s (depth, 2 % band)", ".2f"), ("energy_J", "J (estimated)", ".0f"),
                         ("saturation_s", "s at a thruster limit", ".2f"), ("max_pitch_deg", "deg", ".1f")):
        v = m[k]
        print(f"  {k:>14} = " + ("did not settle" if v is None else f"{v:{fmt}} {unit}"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
