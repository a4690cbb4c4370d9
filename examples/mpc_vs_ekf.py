"""Output-feedback MPC per coefficient set: sensors -> EKF -> MPC on the nonlinear plant.

For each of the five coefficient sets A, the EKF and the MPC are designed on model A and fly the quick
standard mission (depth step, heading change, surge transit and stop) on the plant ``--plant`` (default
``cfd:morison``), seeing only the simulated sensors (pressure depth, IMU, DVL with dropouts; noise levels
assumed, see :class:`udrobot_ctrl.control.sensors.SensorConfig`). Prints tracking IAE, EKF RMSE and NIS, and solver
statistics per design model.

Usage: ``python examples/mpc_vs_ekf.py [--plant NAME] [--controller lmpc|nmpc] [--t-final S]``
"""
from __future__ import annotations

import argparse

import numpy as np

from udrobot_ctrl.control.ekf import UDrobotEKF
from udrobot_ctrl.control.missions import standard_mission
from udrobot_ctrl.control.mpc import LinearMPC, NonlinearMPC, wrap_angle
from udrobot_ctrl.control.sensors import SensorConfig, SensorSampler
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.vehicle import MODEL_NAMES, load_model


class OutputFeedback:
    """``ctrl(t, x_true)``: sample the sensors, filter, and run the MPC on the estimate."""

    def __init__(self, mpc, ekf, sampler):
        self.mpc, self.ekf, self.sampler = mpc, ekf, sampler
        self.f = None
        self.log = []

    def __call__(self, t, x):
        z = self.sampler(t, x)
        if self.f is None:
            self.ekf.update(z)  # first sample: correct the initial guess only
        else:
            self.ekf.step(self.f, z)
        self.f = self.mpc(t, self.ekf.x.copy())
        self.log.append((np.asarray(x, float).copy(), self.ekf.x.copy(), self.ekf.nis, self.ekf.dof))
        return self.f


def fly(design, plant, controller="lmpc", t_final=None, dt=0.05):
    mission = standard_mission(quick=True)
    t_final = t_final or mission.t_final
    v = load_model(design)
    cfg = SensorConfig(seabed_depth=10.0)
    cls = LinearMPC if controller == "lmpc" else NonlinearMPC
    x0 = mission.x0()
    loop = OutputFeedback(cls(v, mission, dt=dt, horizon=20), UDrobotEKF(v, dt, sensors=cfg, x0=x0),
                          SensorSampler(cfg, seed=0))
    res = simulate(plant, x0, t_final, controller=loop, dt=0.01, control_dt=dt)
    ref = mission.reference_array(res.t)
    iae = {c: float(np.sum(np.abs(e)) * 0.01) for c, e in (
        ("z", res.x[:, 2] - ref["z"]), ("psi", wrap_angle(res.x[:, 5] - ref["psi"])), ("u", res.x[:, 6] - ref["u"]))}
    xt, xe, nis, dof = (np.array(a) for a in zip(*loop.log))
    err = xe - xt
    err[:, 3:6] = wrap_angle(err[:, 3:6])
    rmse = {c: float(np.sqrt(np.mean(err[:, i] ** 2))) for c, i in (("z", 2), ("psi", 5), ("u", 6))}
    ok = dof > 0
    return {"iae": iae, "rmse": rmse, "nis_per_dof": float(np.mean(nis[ok] / dof[ok])),
            "fallbacks": loop.mpc.stats["fallbacks"], "ekf_resets": loop.ekf.stats["resets"],
            "solve_ms_median": float(np.median(loop.mpc.call_times) * 1e3)}


def main(argv=None):
    ap = argparse.ArgumentParser(description="output-feedback MPC + EKF per coefficient set")
    ap.add_argument("--plant", default="cfd:morison")
    ap.add_argument("--controller", choices=("lmpc", "nmpc"), default="lmpc")
    ap.add_argument("--t-final", type=float, default=None, help="s (default: the whole quick mission, 23 s)")
    args = ap.parse_args(argv)
    print(f"plant {args.plant}, controller {args.controller} + EKF, quick standard mission")
    print(f"{'design model':<22}{'IAE z m.s':>10}{'IAE psi':>9}{'IAE u':>8}{'RMSE z':>9}{'RMSE psi':>9}"
          f"{'RMSE u':>9}{'NIS/dof':>8}{'fallb.':>7}{'resets':>7}{'ms':>7}")
    for design in MODEL_NAMES:
        r = fly(design, args.plant, args.controller, args.t_final)
        print(f"{design:<22}{r['iae']['z']:>10.3f}{r['iae']['psi']:>9.3f}{r['iae']['u']:>8.3f}{r['rmse']['z']:>9.4f}"
              f"{r['rmse']['psi']:>9.4f}{r['rmse']['u']:>9.4f}{r['nis_per_dof']:>8.2f}{r['fallbacks']:>7d}"
              f"{r['ekf_resets']:>7d}{r['solve_ms_median']:>7.2f}")


if __name__ == "__main__":
    main()
