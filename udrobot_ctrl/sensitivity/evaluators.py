"""Evaluators: picklable ``evaluator(X) -> {metric: (n,)}`` that turn coefficient samples into metrics.

They carry only a specification (parameter space, controller kind, mission); anything expensive
(a controller design, an MPC solver) is built lazily in the worker process and cached there.
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.sensitivity.batch import batch_plant, simulate_batch
from udrobot_ctrl.sensitivity.parameters import ParameterSpace, apply_sample


def _vehicles(space: ParameterSpace, X):
    """Perturbed vehicles of the rows of X; a row that makes an invalid vehicle gives (None, message)."""
    out, errors = [], []
    for row in np.asarray(X, float):
        try:
            out.append(apply_sample(space, row))
            errors.append("")
        except ValueError as exc:
            out.append(None)
            errors.append(str(exc))
    return out, errors


class TerminalSurgeSpeed:
    """Open-loop surge speed after ``t_final`` s of a constant total surge thrust (both horizontal thrusters).

    For the chin form the steady state solves ``F = K_L u + K_Q u^2`` (sway, heave and rotations stay
    near zero): the analytic reference of the local-sensitivity tests. Metric ``u_terminal`` in m/s.
    """

    def __init__(self, space: ParameterSpace, thrust_N: float = 20.0, t_final: float = 12.0, dt: float = 0.02):
        self.space, self.thrust_N, self.t_final, self.dt = space, float(thrust_N), float(t_final), float(dt)

    def describe(self) -> str:
        return (f"terminal surge speed, {self.thrust_N} N for {self.t_final} s, dt {self.dt} s, "
                f"model {self.space.vehicle.name}")

    def __call__(self, X):
        vehicles, errors = _vehicles(self.space, X)
        ok = [i for i, v in enumerate(vehicles) if v is not None]
        u = np.full(len(vehicles), np.nan)
        if ok:
            bp = batch_plant([vehicles[i] for i in ok])
            surge = np.abs(bp.T[0]) > 0.5
            f = np.where(surge, self.thrust_N / surge.sum(), 0.0)
            res = simulate_batch(bp, np.zeros(12), self.t_final, lambda t, x: np.broadcast_to(f, (len(x), f.size)),
                                 dt=self.dt)
            u[ok] = res.x[-1, :, 6]
        return {"u_terminal": u, "error": errors}
