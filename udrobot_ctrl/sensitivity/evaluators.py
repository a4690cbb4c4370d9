"""Evaluators: picklable ``evaluator(X) -> {metric: (n,)}`` that turn coefficient samples into metrics.

They carry only a specification (parameter space, controller kind, mission); anything expensive
(a controller design, an MPC solver) is built lazily in the worker process (nominal designs are cached
there).

:class:`MissionEvaluator` flies exactly what ``udrobot-ctrl compare`` flies: the controllers of
:func:`udrobot_ctrl.control.missions.make_controller` (gain-scheduled LQR, PID, linear and nonlinear MPC,
designed as ``compare`` designs them), through a :class:`~udrobot_ctrl.control.missions.Mission` (default:
the standard quick mission, ``compare --quick``), on the plant of :mod:`udrobot_ctrl.dynamics.sim` at
``compare``'s steps (RK4 0.01 s, controller 0.05 s), scored by
:func:`udrobot_ctrl.control.metrics.mission_metrics`. A chunk of samples is flown as one batch
(:func:`udrobot_ctrl.control.missions.run_mission_batch`: one stacked simulation, the LQR and PID laws
vectorised over vehicles, the MPCs one solver per vehicle), which gives each vehicle the same trajectory
as a run of its own. Scheduled LQRs take a compiled path that flies the same batch in one call
(:func:`udrobot_ctrl.sensitivity.batch.fly_lqr_batch`, equal up to rounding) and scores it at once
(:func:`udrobot_ctrl.sensitivity.batch.batch_metrics`, equal to :func:`flat_metrics`).
"""
from __future__ import annotations

import numpy as np

from udrobot_ctrl.control.compare import CONTROL_DT, SIM_DT
from udrobot_ctrl.control.linearize import held_rows
from udrobot_ctrl.control.lqr import ScheduledLQR
from udrobot_ctrl.control.metrics import mission_metrics
from udrobot_ctrl.control.missions import (
    CONTROLLER_KINDS,
    make_controller,
    run_mission,
    run_mission_batch,
    standard_mission,
)
from udrobot_ctrl.dynamics.plant import plant_parameters
from udrobot_ctrl.dynamics.sim import SimResult, simulate, stack_parameters
from udrobot_ctrl.sensitivity.batch import LOST_PITCH_DEG, batch_metrics, fly_lqr_batch
from udrobot_ctrl.sensitivity.parameters import ParameterSpace, apply_sample


def runtime_effects(space: ParameterSpace) -> tuple:
    """Names of the space vehicle's run-time effects (thrust maps, lag, tether, current, wall; ``dynamics.effects``).

    The batched, compiled kernels hold the nominal equations only, so a model with such effects (a corrected model
    of ``diagnose --out-model``) is flown one vehicle at a time through the numpy simulator, which simulates them
    (about 1 s per 23 s mission instead of milliseconds per vehicle in a batch). Its parameter effects are folded
    into the matrices and need nothing of the kind."""
    return tuple(e.name for e in plant_parameters(space.vehicle).effects)


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
        self.runtime_effects = runtime_effects(space)
        if self.runtime_effects:
            self.max_chunk = 16  # one numpy simulation per vehicle (see runtime_effects)

    def describe(self) -> str:
        return (f"terminal surge speed, {self.thrust_N} N for {self.t_final} s, dt {self.dt} s, "
                f"model {self.space.vehicle.name}")

    def __call__(self, X):
        vehicles, errors = _vehicles(self.space, X)
        ok = [i for i, v in enumerate(vehicles) if v is not None]
        u = np.full(len(vehicles), np.nan)
        if ok and self.runtime_effects:
            for i in ok:
                p = plant_parameters(vehicles[i])
                res = simulate(p, np.zeros(12), self.t_final, inputs=surge_thrusts(p.T, self.thrust_N)[None],
                               dt=self.dt, on_divergence="freeze")
                u[i] = res.x[-1, 6]
        elif ok:
            p = stack_parameters([vehicles[i] for i in ok])
            f = surge_thrusts(p.T, self.thrust_N)
            res = simulate(p, np.zeros(12), self.t_final, inputs=f[None], dt=self.dt, on_divergence="freeze",
                           parallel=False)
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


def flat_metrics(res, mission, f_min, f_max) -> dict:
    """Scalar metrics of one run: :func:`udrobot_ctrl.control.metrics.mission_metrics` with its own keys and
    values, flattened for tables, plus the sensitivity-specific columns.

    * ``final_error`` becomes ``final_error_z`` (m), ``final_error_psi`` (rad), ``final_error_u`` (m/s);
    * a settling time that is ``None`` in ``mission_metrics`` (the response leaves the 2 % band at the end
      of its event's window: not settled) is censored at the mission duration ``mission.t_final`` so that
      global indices stay defined, and ``unsettled`` counts such channels (0..3: z, psi, u);
    * ``max_speed`` (m/s): largest body-frame translational speed;
    * ``lost_control`` (0/1): ``max_pitch_deg`` beyond :data:`LOST_PITCH_DEG` (passive pitch lost).
    """
    met = mission_metrics(res, mission, f_min, f_max)
    out, unsettled = {}, 0
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
    out["lost_control"] = float(out["max_pitch_deg"] > LOST_PITCH_DEG)
    return out


class MissionEvaluator:
    """Closed-loop metrics of one of ``compare``'s controllers on perturbed vehicles.

    Which vehicle a sample perturbs: the *plant* always (the sample's coefficients are applied to the
    space's vehicle, :func:`~udrobot_ctrl.sensitivity.parameters.apply_sample`); the *design model* only with
    ``redesign``.

    Parameters
    ----------
    space : ParameterSpace
        Coefficients varied; its vehicle is the nominal plant *and* the design model.
    controller : {'lqr', 'pid', 'lmpc', 'nmpc', 'mpc'}
        A kind of :func:`udrobot_ctrl.control.missions.make_controller` (``mpc`` = ``lmpc``).
    mission : Mission, optional
        Default: :func:`udrobot_ctrl.control.missions.standard_mission` ``(quick=True)`` (23 s).
    redesign : bool
        False (default): design once on the nominal model, fly it on each perturbed plant (what a user
        who trusts one coefficient set gets). True: redesign on each perturbed model (the sensitivity of
        the *best achievable* performance to the coefficient).
    controller_opts : dict, optional
        Passed to :func:`~udrobot_ctrl.control.missions.make_controller` (the controller's design options).
    sim_dt, control_dt : float
        RK4 and controller steps, s (default ``compare``'s 0.01 s and 0.05 s).
    """

    def __init__(self, space, controller: str = "lqr", mission=None, redesign: bool = False,
                 controller_opts: dict | None = None, sim_dt: float = SIM_DT, control_dt: float = CONTROL_DT):
        kind = "lmpc" if controller == "mpc" else controller
        if kind not in CONTROLLER_KINDS:
            raise ValueError(f"controller must be one of {', '.join(CONTROLLER_KINDS)} or mpc, got {controller!r}")
        if not (sim_dt > 0 and control_dt > 0):
            raise ValueError(f"sim_dt and control_dt must be > 0 s, got {sim_dt} and {control_dt}")
        self.space = space
        self.controller = kind
        self.mission = mission if mission is not None else standard_mission(quick=True)
        self.redesign = bool(redesign)
        self.controller_opts = dict(controller_opts or {})
        self.sim_dt, self.control_dt = float(sim_dt), float(control_dt)
        # samples per task: the vectorised LQR/PID batches amortise the per-step overhead over many vehicles;
        # the MPCs solve one QP/NLP per vehicle, so small tasks keep progress and interruptions fine-grained
        self.max_chunk = 256 if kind in ("lqr", "pid") else 4
        self.runtime_effects = runtime_effects(space)
        if self.runtime_effects:
            self.max_chunk = 4  # one numpy simulation per vehicle (see runtime_effects)

    def describe(self) -> str:
        how = "redesigned per sample" if self.redesign else "designed on nominal"
        m = self.mission
        steps = ", ".join(f"{s.channel}={s.value:g}@{s.t:g}s" for s in m.steps)
        return (f"{self.controller} on {self.space.vehicle.name} ({how}), mission {m.name} ({m.t_final:g} s; "
                f"initial {m.initial}; {steps}), dt {self.sim_dt} s, control_dt {self.control_dt} s, "
                f"opts {sorted(self.controller_opts.items())}")

    def _design(self, model):
        return make_controller(self.controller, model, self.mission, control_dt=self.control_dt,
                               **self.controller_opts)

    def _nominal(self):
        """The nominal design, cached per process (LQR, PID: read-only inside the batch laws)."""
        key = (self.describe(), tuple(self.space.names), tuple(self.space.nominal))
        if key not in _DESIGN_CACHE:
            _DESIGN_CACHE[key] = self._design(self.space.vehicle)
        return _DESIGN_CACHE[key]

    def _controllers(self, vehicles, ok, errors):
        """One designed controller per vehicle of ``ok`` (ids whose design failed are dropped with an error)."""
        shared = self.controller in ("lqr", "pid") and not self.redesign
        ctrls, kept = [], []
        for i in ok:
            if shared:
                ctrls.append(self._nominal())
                kept.append(i)
                continue
            try:  # a fresh MPC per sample: results must not depend on which samples a solver saw before
                ctrls.append(self._design(vehicles[i] if self.redesign else self.space.vehicle))
                kept.append(i)
            except (ValueError, np.linalg.LinAlgError, RuntimeError) as exc:
                errors[i] = f"{self.controller} design failed: {type(exc).__name__}: {exc}"
        return ctrls, kept

    def __call__(self, X):
        vehicles, errors = _vehicles(self.space, X)
        ok = [i for i, v in enumerate(vehicles) if v is not None]
        ctrls, ok = self._controllers(vehicles, ok, errors)
        rows = [{} for _ in vehicles]
        if ok and self.runtime_effects:
            for ctrl, i in zip(ctrls, ok):
                rows[i] = self._fly_alone(ctrl, vehicles[i], errors, i)
        elif ok and all(isinstance(c, ScheduledLQR) for c in ctrls):
            plants = [plant_parameters(vehicles[i]) for i in ok]
            # the whole mission of every vehicle in one compiled call, the metrics of the batch at once
            p = stack_parameters(plants)
            t, x, u, hold, diverged, fallbacks = fly_lqr_batch(ctrls, p, self.mission, self.sim_dt, self.control_dt)
            met = batch_metrics(t, x, u, self.mission, p.f_min, p.f_max, hold)
            for j, i in enumerate(ok):
                if diverged[j] >= 0:
                    errors[i] = f"diverged at t = {t[diverged[j]]:.2f} s"
                    rows[i] = {"lost_control": 1.0}
                    continue
                rows[i] = {**{k: float(v[j]) for k, v in met.items()}, "fallbacks": float(fallbacks[j])}
        elif ok:
            plants = [plant_parameters(vehicles[i]) for i in ok]
            # serial kernel: the executor runs chunks in parallel processes; threads inside them oversubscribe
            res = run_mission_batch(ctrls, plants, self.mission, dt=self.sim_dt, control_dt=self.control_dt,
                                    parallel=False)
            f_min, f_max = plants[0].f_min, plants[0].f_max  # shared: stack_parameters checked it
            fallbacks = res.controller.fallbacks
            for j, i in enumerate(ok):
                x = res.x[:, j]
                if not np.all(np.isfinite(x[-1])):
                    k = int(np.argmax(~np.all(np.isfinite(x), axis=-1)))
                    errors[i] = f"diverged at t = {res.t[k]:.2f} s"
                    rows[i] = {"lost_control": 1.0}
                    continue
                one = SimResult(t=res.t, x=x, u=res.u[:, j], tau=res.tau[:, j], saturated=res.saturated[:, j])
                rows[i] = {**flat_metrics(one, self.mission, f_min, f_max), "fallbacks": float(fallbacks[j])}
        names = sorted({k for r in rows for k in r})
        return {**{k: np.array([r.get(k, np.nan) for r in rows], float) for k in names}, "error": errors}

    def _fly_alone(self, ctrl, vehicle, errors, i) -> dict:
        """One vehicle with run-time effects through the numpy simulator (:func:`run_mission`), as the batch
        flies it: a safe controller, a diverged flight counted as lost control with its time in ``errors[i]``."""
        reset = getattr(ctrl, "reset", None)
        if callable(reset):
            reset()  # a shared nominal design: forget the previous flight's integrators and warm starts
        p = plant_parameters(vehicle)
        try:
            res = run_mission(ctrl, p, self.mission, dt=self.sim_dt, control_dt=self.control_dt)
        except FloatingPointError as exc:
            errors[i] = f"diverged: {exc}"
            return {"lost_control": 1.0}
        return {**flat_metrics(res, self.mission, p.f_min, p.f_max), "fallbacks": float(res.controller.fallbacks)}
