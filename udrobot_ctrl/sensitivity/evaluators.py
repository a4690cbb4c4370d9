"""Evaluators: picklable ``evaluator(X) -> {metric: (n,)}`` that turn coefficient samples into metrics.

They carry only a specification (parameter space, controller kind, mission); anything expensive
(a controller design, an MPC solver) is built lazily in the worker process and cached there.
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.control.linearize import held_rows
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
    """Open-loop surge speed after ``t_final`` s of a constant surge force ``thrust_N`` (N).

    The force is allocated over the vehicle's own thrusters as the minimum-norm thrusts giving surge
    ``thrust_N`` and zero on every other wrench row set independently of surge
    (:func:`udrobot_ctrl.control.linearize.held_rows`): UDrobot's two surge thrusters share it equally; a
    vectored BlueROV2 runs its four 45 deg horizontals.

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
            f = surge_thrusts(bp.T, self.thrust_N)
            res = simulate_batch(bp, np.zeros(12), self.t_final, lambda t, x: np.broadcast_to(f, (len(x), f.size)),
                                 dt=self.dt)
            u[ok] = res.x[-1, :, 6]
        return {"u_terminal": u, "error": errors}


def surge_thrusts(T, force_N: float) -> np.ndarray:
    """Minimum-norm thrusts (n,) N giving surge ``force_N`` and zero on the rows held independently of surge.

    Raises
    ------
    ValueError
        If the thrusters cannot produce a surge force (zero surge row).
    """
    T = np.asarray(T, float)
    if not np.any(np.abs(T[0]) > 1e-9):
        raise ValueError("no thruster acts in surge: the terminal-speed metric needs a surge force")
    rows = [0] + held_rows(T)
    rhs = np.zeros(len(rows))
    rhs[0] = force_N
    return np.linalg.lstsq(T[rows], rhs, rcond=None)[0]


# ----------------------------------------------------------------------------- closed-loop missions
_DESIGN_CACHE: dict = {}  # per worker process: nominal designs keyed by the evaluator's spec


class MissionEvaluator:
    """Closed-loop metrics of a controller on perturbed plants.

    Parameters
    ----------
    space : ParameterSpace
        Coefficients varied; its vehicle is the nominal plant *and* the design model.
    controller : {'lqr', 'pid', 'mpc', 'lmpc', 'nmpc'}
        ``mpc`` = ``lmpc`` (linear MPC with hard thrust limits); ``nmpc`` needs the missions backend.
    mission : DepthHeadingMission, optional
        Mission of the fast path (default: 1 m depth and 90 deg heading steps at 0.5 m/s, 20 s, dt 0.04 s).
    redesign : bool
        False (default): design once on the nominal model, evaluate on each perturbed plant (what a
        user who trusts one coefficient set gets). True: redesign on each perturbed model (the
        sensitivity of the *best achievable* performance to the coefficient).
    controller_opts : dict, optional
        Passed to the design (LQRWeights / PIDTuning / MPCSettings fields on the batch backend).
    backend : {'auto', 'batch', 'missions'}
        ``batch``: this package's vectorised mission (lqr, pid, mpc: one chunk of vehicles simulated at
        once). ``missions``: one simulation per sample through :mod:`udrobot_ctrl.control.missions` (any
        controller, the toolbox's standard mission, quick variant by default). ``auto``: batch unless the
        controller is nmpc.
    sim_dt, control_dt : float
        Integration and controller steps of the missions backend, s (the batch backend uses the
        mission's ``dt`` and, for MPC, ``MPCSettings.Ts``).
    """

    def __init__(self, space, controller: str = "lqr", mission=None, redesign: bool = False,
                 controller_opts: dict | None = None, backend: str = "auto", sim_dt: float = 0.02,
                 control_dt: float = 0.05):
        from udrobot_ctrl.sensitivity.mission import DepthHeadingMission

        if controller not in ("lqr", "pid", "lmpc", "nmpc", "mpc"):
            raise ValueError(f"controller must be lqr, pid, lmpc, nmpc or mpc, got {controller!r}")
        if backend == "auto":
            backend = "batch" if controller != "nmpc" else "missions"
        if backend not in ("batch", "missions"):
            raise ValueError(f"backend must be auto, batch or missions, got {backend!r}")
        if backend == "batch" and controller == "nmpc":
            raise ValueError("the batch backend supports lqr, pid and (linear) mpc, not 'nmpc'; use backend='missions'")
        if backend == "missions":
            import importlib.util

            needed = {"lqr": "udrobot_ctrl.control.lqr",
                      "pid": "udrobot_ctrl.control.pid"}.get(controller, "udrobot_ctrl.control.mpc")
            for mod in ("udrobot_ctrl.control.missions", needed):
                if importlib.util.find_spec(mod) is None:
                    raise ValueError(f"controller {controller!r} on the missions backend needs {mod}, not available "
                                     "in this build (lqr, pid and mpc work on the batched fast path)")
        self.space = space
        self.controller = controller
        self.backend = backend
        self.mission = mission if mission is not None else (
            DepthHeadingMission() if backend == "batch" else None)
        self.redesign = bool(redesign)
        self.controller_opts = dict(controller_opts or {})
        # samples per task: vectorised batches amortise numpy overhead (1.8 ms/run at 256 vs 4.2 at 64);
        # one-by-one runs keep tasks small so progress and interruptions stay fine-grained
        self.max_chunk = 256 if backend == "batch" else 4
        self.sim_dt, self.control_dt = float(sim_dt), float(control_dt)

    def describe(self) -> str:
        how = "redesigned per sample" if self.redesign else "designed on nominal"
        extra = "" if self.backend == "batch" else f", dt {self.sim_dt} s, control_dt {self.control_dt} s"
        return (f"{self.controller} on {self.space.vehicle.name} ({how}), {self.backend} backend{extra}, "
                f"mission {self.mission}, opts {sorted(self.controller_opts.items())}")

    def _key(self):
        return (self.describe(), tuple(self.space.names), tuple(self.space.nominal))

    def __call__(self, X):
        vehicles, errors = _vehicles(self.space, X)
        if self.backend == "batch":
            metrics = self._batch(vehicles, errors)
        else:
            metrics = self._per_sample(vehicles, errors)
        return {**metrics, "error": errors}

    # ------------------------------------------------------------------ batched fast path
    def _design(self, vehicle):
        """Design on one model: LQR (K, trim), PID (gains, trim) or MPC (qp, trim)."""
        from udrobot_ctrl.dynamics.plant import plant_parameters
        from udrobot_ctrl.sensitivity.mission import (
            LQRWeights,
            MPCSettings,
            PIDTuning,
            lqr_gain,
            mpc_matrices,
            pid_gains,
            trim_thrust,
        )

        if self.controller == "lqr":
            return lqr_gain(vehicle, LQRWeights(**self.controller_opts), self.mission)
        if self.controller in ("mpc", "lmpc"):
            qp = mpc_matrices(vehicle, self.mission, MPCSettings(**self.controller_opts))
            return qp, qp["trim"]
        tuning = PIDTuning(**self.controller_opts)
        return pid_gains(vehicle, tuning), trim_thrust(plant_parameters(vehicle), self.mission.operating_point())

    def _nominal_design(self):
        key = self._key()
        if key not in _DESIGN_CACHE:
            _DESIGN_CACHE[key] = self._design(self.space.vehicle)
        return _DESIGN_CACHE[key]

    def _batch(self, vehicles, errors):
        from udrobot_ctrl.sensitivity.mission import (
            BatchLQR,
            BatchMPC,
            BatchPID,
            MPCSettings,
            PIDTuning,
            design_states,
            mission_metrics,
        )

        ok = [i for i, v in enumerate(vehicles) if v is not None]
        if not ok:
            return {}
        bp = batch_plant([vehicles[i] for i in ok])
        gain, trim = self._nominal_design()
        if self.redesign:  # gains and feed-forward trim from each perturbed model
            designs = []
            for i in ok:
                try:
                    designs.append(self._design(vehicles[i]))
                except Exception as exc:  # noqa: BLE001 - a failed design is that sample's error
                    designs.append(None)
                    errors[i] = f"{self.controller} redesign failed: {exc}"
            fill = self._nominal_design()
            designs = [d if d is not None else fill for d in designs]
            trim = np.stack([d[1] for d in designs])
            if self.controller == "lqr":
                gain = np.stack([d[0] for d in designs])
            elif self.controller in ("mpc", "lmpc"):
                gain = [d[0] for d in designs]
            else:
                gain = {k: tuple(np.array([d[0][k][j] for d in designs]) for j in range(3)) for k in gain}
        m = self.mission
        control_dt = None
        if self.controller == "lqr":
            ctrl = BatchLQR(gain, trim, m, design_states(bp.T))
        elif self.controller in ("mpc", "lmpc"):
            settings = MPCSettings(**self.controller_opts)
            ctrl = BatchMPC(gain, m, bp.f_min, bp.f_max, settings)
            control_dt = settings.Ts
        else:
            ctrl = BatchPID(gain, trim, bp.T, m, PIDTuning(**self.controller_opts).integral_limit_N)
        res = simulate_batch(bp, m.x0(), m.t_final, ctrl, dt=m.dt, control_dt=control_dt)
        met = mission_metrics(res, m, bp.f_min, bp.f_max)
        out = {k: np.full(len(vehicles), np.nan) for k in met}
        for k, v in met.items():
            out[k][ok] = v
        for j, i in enumerate(ok):
            if not np.all(np.isfinite(res.x[-1, j])) and not errors[i]:
                errors[i] = "simulation diverged"
        return out

    # ------------------------------------------------------------------ generic path
    def _missions(self):
        from udrobot_ctrl.control import missions

        mission = self.mission if self.mission is not None else missions.standard_mission(quick=True)
        return missions, mission

    def _per_sample(self, vehicles, errors):
        """One closed-loop run per sample through :func:`udrobot_ctrl.control.missions.run_mission` (any controller)."""
        from udrobot_ctrl.dynamics.plant import plant_parameters

        missions, mission = self._missions()
        kind = "lmpc" if self.controller == "mpc" else self.controller
        rows = []
        for i, v in enumerate(vehicles):
            if v is None:
                rows.append({})
                continue
            try:
                # a fresh design for every sample (on the nominal model unless redesign): a reset solver
                # would keep its warm start, and results must not depend on which samples ran before
                design = v if self.redesign else self.space.vehicle
                ctrl = missions.make_controller(kind, design, mission, control_dt=self.control_dt,
                                                **self.controller_opts)
                res = missions.run_mission(ctrl, v, mission, dt=self.sim_dt, control_dt=self.control_dt)
                p = plant_parameters(v)
                rows.append(_flat_metrics(res, mission, p.f_min, p.f_max))
            except Exception as exc:  # noqa: BLE001 - the sweep goes on, the sample carries the error
                rows.append({})
                errors[i] = f"{type(exc).__name__}: {exc}"
        names = sorted({k for r in rows for k in r})
        return {k: np.array([float(r.get(k, np.nan)) for r in rows]) for k in names}


def _flat_metrics(res, mission, f_min, f_max) -> dict:
    """Scalar metrics of a run: :func:`udrobot_ctrl.control.metrics.mission_metrics` flattened, plus ``max_speed``
    (m/s), ``fallbacks`` (SafeController substitutions) and ``unsettled`` (events not settled; their
    settling time is censored at the mission duration so that global indices stay defined)."""
    from udrobot_ctrl.control import metrics

    met = metrics.mission_metrics(res, mission, f_min, f_max)
    out = {}
    unsettled = 0
    for k, v in met.items():
        if isinstance(v, dict):
            for kk, vv in v.items():
                out[f"{k}_{kk}"] = float(vv)
        elif v is None:
            out[k] = float(mission.t_final)
            unsettled += k != "settling_s"  # settling_s repeats settling_z_s
        else:
            out[k] = float(v)
    out["unsettled"] = float(unsettled)
    out["max_speed"] = float(np.max(np.linalg.norm(np.asarray(res.x)[:, 6:9], axis=-1)))
    out["fallbacks"] = float(getattr(getattr(res, "controller", None), "fallbacks", 0))
    return out
