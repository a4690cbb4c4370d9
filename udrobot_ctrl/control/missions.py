"""The standard control mission, a safe controller wrapper, the controller factory and the mission runner.

Standard mission (:func:`standard_mission`), references for the three tracked channels
(depth ``z`` m, NED positive down; heading ``psi`` rad; surge speed ``u`` m/s), all piecewise constant:

=========  ==============================  =============  ==============
channel    change                          full (t, s)    quick (t, s)
=========  ==============================  =============  ==============
z          0.5 m -> 1.5 m (depth step)     1              0.5
psi        0 -> 90 deg (heading change)    12             6
u          0 -> 0.5 m/s (surge transit)    22             11
u          0.5 -> 0 m/s (stop)             36             17
end                                        46             23
=========  ==============================  =============  ==============

The vehicle starts at rest, level, at 0.5 m depth, heading 0 (so the first event is a pure depth step).
Each event is scored in its own *window*, from its time to the next event of any channel (or the end),
so a settling time or overshoot belongs to one manoeuvre (:mod:`udrobot_ctrl.control.metrics`).

Controllers are callables ``controller(t, x) -> thrusts`` (N, one per thruster) for the 12-state
``x = [x y z phi theta psi u v w p q r]``. :func:`make_controller` builds one of ``lqr``, ``pid``, ``lmpc``,
``nmpc`` designed on a model for a mission; :func:`run_mission` flies it on a plant model with
:func:`udrobot_ctrl.dynamics.sim.simulate`. :class:`SafeController` wraps any controller so that an exception or a
non-finite command in the loop becomes the last good command (or zero) and is counted, never raised.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from udrobot_ctrl.control import mpc
from udrobot_ctrl.control.lqr import BatchScheduledLQR, ScheduledLQR
from udrobot_ctrl.control.pid import BatchPID, PIDController
from udrobot_ctrl.dynamics.sim import as_parameters, simulate, stack_parameters

CHANNELS = ("z", "psi", "u")
CHANNEL_INDEX = {"z": 2, "psi": 5, "u": 6}
CHANNEL_UNITS = {"z": "m", "psi": "rad", "u": "m/s"}
CONTROLLER_KINDS = ("lqr", "pid", "lmpc", "nmpc")


@dataclass(frozen=True)
class ReferenceStep:
    """A step of one channel's reference at time ``t`` (s) to ``value`` (m, rad or m/s)."""

    channel: str
    t: float
    value: float


@dataclass(frozen=True)
class Mission:
    """Piecewise-constant references of depth, heading and surge speed.

    Attributes
    ----------
    name : str
        Label used in reports.
    t_final : float
        Mission duration, s.
    initial : dict
        Initial reference (and initial state) per channel: ``z`` m, ``psi`` rad, ``u`` m/s.
    steps : tuple of ReferenceStep
        Reference changes, sorted by time.
    settle_band : float
        Settling band as a fraction of each step's size (0.02 = 2 %).
    """

    name: str
    t_final: float
    initial: dict = field(default_factory=lambda: {"z": 0.5, "psi": 0.0, "u": 0.0})
    steps: tuple = ()
    settle_band: float = 0.02

    def __post_init__(self):
        if not self.t_final > 0:
            raise ValueError(f"mission {self.name!r}: t_final must be > 0 s, got {self.t_final}")
        for s in self.steps:
            if s.channel not in CHANNELS:
                raise ValueError(f"mission {self.name!r}: step channel {s.channel!r} is not one of {CHANNELS}")
            if not 0 <= s.t < self.t_final:
                raise ValueError(f"mission {self.name!r}: step at t = {s.t} s outside [0, {self.t_final}) s")
        for c in CHANNELS:
            if c not in self.initial:
                raise ValueError(f"mission {self.name!r}: initial reference lacks channel {c!r}")
        object.__setattr__(self, "steps", tuple(sorted(self.steps, key=lambda s: s.t)))

    # -- references ---------------------------------------------------------------------------------
    def value(self, channel: str, t: float) -> float:
        """Reference of one channel at time ``t`` (s)."""
        v = float(self.initial[channel])
        for s in self.steps:
            if s.channel == channel and s.t <= t:
                v = float(s.value)
        return v

    def reference(self, t: float) -> dict:
        """References at ``t``: ``{"z": m, "psi": rad, "u": m/s}`` (the form the MPCs accept)."""
        return {c: self.value(c, t) for c in CHANNELS}

    def __call__(self, t: float) -> dict:
        return self.reference(t)

    def state_reference(self, t: float) -> np.ndarray:
        """(12,) state reference at ``t``: z, psi, u set, everything else 0 (level, no sway/heave/rates)."""
        x = np.zeros(12)
        for c, v in self.reference(t).items():
            x[CHANNEL_INDEX[c]] = v
        return x

    def reference_array(self, t) -> dict:
        """Vectorised references: channel -> (n,) array over the times ``t`` (s)."""
        t = np.asarray(t, float)
        out = {}
        for c in CHANNELS:
            r = np.full(t.shape, float(self.initial[c]))
            for s in self.steps:
                if s.channel == c:
                    r = np.where(t >= s.t, float(s.value), r)
            out[c] = r
        return out

    def x0(self) -> np.ndarray:
        """Initial state: at rest, level, at the initial depth and heading (surge at the initial reference)."""
        return self.state_reference(0.0)

    # -- scoring windows ----------------------------------------------------------------------------
    def events(self):
        """List of (step, previous value, window end time) for every reference change."""
        out = []
        times = [s.t for s in self.steps]
        for i, s in enumerate(self.steps):
            prev = self.value(s.channel, s.t - 1e-12) if s.t > 0 else float(self.initial[s.channel])
            later = [tt for tt in times[i + 1:] if tt > s.t]
            out.append((s, prev, later[0] if later else self.t_final))
        return out

    def step_scale(self, channel: str) -> float:
        """Largest step size of a channel (m, rad, m/s), the IAE normaliser; 1 if the channel never steps."""
        sizes = [abs(s.value - prev) for s, prev, _ in self.events() if s.channel == channel]
        return max(sizes) if sizes and max(sizes) > 0 else 1.0

    def operating_speeds(self) -> tuple:
        """Distinct surge references (m/s) the mission visits."""
        return tuple(sorted({float(self.initial["u"])} | {float(s.value) for s in self.steps if s.channel == "u"}))


def standard_mission(quick: bool = False) -> Mission:
    """The standard mission: depth step 0.5 -> 1.5 m, heading 0 -> 90 deg, surge 0.5 m/s transit and stop.

    ``quick=True`` is the same sequence compressed to 23 s (tests and the demo); the full one lasts 46 s.

    Parameters
    ----------
    quick : bool
        The 23 s version instead of the 46 s one.

    Returns
    -------
    Mission
        Initial references z 0.5 m, psi 0, u 0 and the four reference steps.
    """
    if quick:
        times, t_final, name = (0.5, 6.0, 11.0, 17.0), 23.0, "standard-quick"
    else:
        times, t_final, name = (1.0, 12.0, 22.0, 36.0), 46.0, "standard"
    return Mission(
        name=name, t_final=t_final, initial={"z": 0.5, "psi": 0.0, "u": 0.0},
        steps=(ReferenceStep("z", times[0], 1.5), ReferenceStep("psi", times[1], math.pi / 2),
               ReferenceStep("u", times[2], 0.5), ReferenceStep("u", times[3], 0.0)),
    )


# ----------------------------------------------------------------------------- safe wrapper
class SafeController:
    """Wrap ``controller(t, x) -> thrusts`` so it never throws in the loop.

    An exception or a non-finite / wrongly shaped command is replaced by the last good command (zero
    thrust before the first one), clipped to ``[f_min, f_max]``; ``fallbacks`` counts them and
    ``last_error`` keeps the latest reason (a ``RuntimeWarning`` is issued the first time).
    """

    def __init__(self, controller, f_min, f_max):
        self.controller = controller
        self.f_min, self.f_max = np.asarray(f_min, float), np.asarray(f_max, float)
        self.last = np.zeros_like(self.f_min)
        self.fallbacks = 0
        self.last_error = ""

    def __call__(self, t, x):
        try:
            f = np.asarray(self.controller(t, x), float).reshape(self.f_min.shape)
            if not np.all(np.isfinite(f)):
                raise FloatingPointError("non-finite thrust command")
        except Exception as exc:  # noqa: BLE001 - a controller in the loop must never throw: held, warned
            self.fallbacks += 1
            self.last_error = f"t = {t:.3f} s: {type(exc).__name__}: {exc}"
            if self.fallbacks == 1:
                warnings.warn(f"controller failed ({self.last_error}); holding the last good command",
                              RuntimeWarning, stacklevel=2)
            return self.last.copy()
        self.last = np.clip(f, self.f_min, self.f_max)
        return self.last.copy()


class SafeBatch:
    """:class:`SafeController` for a vectorised batch law ``controller(t, x (N, 12)) -> (N, n)``, per vehicle.

    A vehicle whose command is non-finite gets its last good command (zero before the first one); an
    exception of the whole call gives every vehicle its last good command. Commands are clipped to
    ``[f_min, f_max]``; ``fallbacks`` (N,) counts the substitutions of each vehicle.
    """

    def __init__(self, controller, f_min, f_max):
        self.controller = controller
        self.f_min, self.f_max = np.asarray(f_min, float), np.asarray(f_max, float)
        n = len(controller)
        self.last = np.zeros((n,) + self.f_min.shape)
        self.fallbacks = np.zeros(n, dtype=np.int64)
        self.last_error = ""

    def __len__(self) -> int:
        return len(self.last)

    def __call__(self, t, x):
        try:
            f = np.asarray(self.controller(t, x), float).reshape(self.last.shape)
        except Exception as exc:  # noqa: BLE001 - a controller in the loop must never throw: held, warned
            self.fallbacks += 1
            self.last_error = f"t = {t:.3f} s: {type(exc).__name__}: {exc}"
            warnings.warn(f"batch controller failed ({self.last_error}); holding the last good commands",
                          RuntimeWarning, stacklevel=2)
            return self.last.copy()
        bad = ~np.all(np.isfinite(f), axis=1)
        if bad.any():
            self.fallbacks[bad] += 1
            self.last_error = f"t = {t:.3f} s: non-finite thrust command"
        self.last = np.where(bad[:, None], self.last, np.clip(f, self.f_min, self.f_max))
        return self.last.copy()


class ControllerBatch:
    """N controllers, one per vehicle, each in its own :class:`SafeController`, called row by row.

    For laws that are not vectorised (the MPCs: one solver per vehicle). ``fallbacks`` (N,) per vehicle.
    """

    def __init__(self, controllers, f_min, f_max):
        self.safe = [SafeController(c, f_min, f_max) for c in controllers]

    def __len__(self) -> int:
        return len(self.safe)

    def __call__(self, t, x):
        x = np.asarray(x, float).reshape(len(self.safe), 12)
        return np.stack([s(t, xi) for s, xi in zip(self.safe, x)])

    @property
    def fallbacks(self) -> np.ndarray:
        return np.array([s.fallbacks for s in self.safe], dtype=np.int64)

    @property
    def last_error(self) -> str:
        return next((s.last_error for s in self.safe if s.last_error), "")


def batch_controller(controllers, f_min, f_max):
    """One ``controller(t, x (N, 12)) -> thrusts (N, n)`` flying the N designed ``controllers`` (one per vehicle).

    Scheduled LQRs and PIDs (clipped pseudo-inverse allocation) are vectorised
    (:class:`~udrobot_ctrl.control.lqr.BatchScheduledLQR`, :class:`~udrobot_ctrl.control.pid.BatchPID`) inside a
    :class:`SafeBatch`; any other controller runs row by row in a :class:`ControllerBatch`. Either way each
    vehicle gets exactly the command its own controller, wrapped in :class:`SafeController`, would give.
    """
    ctrls = list(controllers)
    if all(isinstance(c, ScheduledLQR) for c in ctrls):
        return SafeBatch(BatchScheduledLQR(ctrls), f_min, f_max)
    if all(isinstance(c, PIDController) and c.allocation == "clipped pseudo-inverse" for c in ctrls):
        return SafeBatch(BatchPID(ctrls), f_min, f_max)
    return ControllerBatch(ctrls, f_min, f_max)


# ----------------------------------------------------------------------------- factory and runner
def make_controller(kind: str, design_model, mission: Mission, control_dt: float = 0.05, **opts):
    """Controller of ``kind`` designed on ``design_model`` for ``mission``.

    Parameters
    ----------
    kind : {'lqr', 'pid', 'lmpc', 'nmpc'}
        Gain-scheduled LQR (:class:`udrobot_ctrl.control.lqr.ScheduledLQR`), decoupled PID with allocation
        (:class:`udrobot_ctrl.control.pid.PIDController`), linear MPC on OSQP or nonlinear MPC
        (:mod:`udrobot_ctrl.control.mpc`, imported lazily).
    design_model : str, Path, Vehicle or PlantParameters
        The model the controller is designed on (a name of ``MODEL_NAMES``, a file, ...).
    mission : Mission
        Supplies the reference ``mission.reference(t)`` and the operating points.
    control_dt : float
        Controller sampling period, s (PID integrator step, MPC interval).
    **opts
        Passed to the controller's constructor.

    Returns
    -------
    ScheduledLQR, PIDController, LinearMPC or NonlinearMPC
        The controller, ``controller(t, x) -> thrusts`` (N).
    """
    p = as_parameters(design_model)
    if kind == "lqr":
        opts.setdefault("dt", control_dt)  # discrete design at the sampling period (ZOH, dlqr)
        return ScheduledLQR.design(p, mission.reference, **opts)
    if kind == "pid":
        return PIDController.design(p, mission.reference, dt=control_dt, **opts)
    if kind in ("lmpc", "nmpc"):
        cls = mpc.LinearMPC if kind == "lmpc" else mpc.NonlinearMPC
        opts.setdefault("dt", control_dt)
        return cls(p, mission, **opts)
    raise ValueError(f"controller kind must be one of {', '.join(CONTROLLER_KINDS)}, got {kind!r}")


def run_mission(controller, plant_model, mission: Mission, dt: float = 0.01, control_dt: float = 0.05,
                safe: bool = True):
    """Fly ``controller`` on ``plant_model`` through ``mission``; returns the
    :class:`~udrobot_ctrl.dynamics.sim.SimResult`.

    Parameters
    ----------
    controller : callable
        ``controller(t, x) -> thrusts`` (N), sampled every ``control_dt`` s and held.
    plant_model : str, Path, Vehicle or PlantParameters
        The simulated plant.
    mission : Mission
        The references, the initial state and the duration.
    dt : float
        RK4 integration step, s.
    control_dt : float
        Controller period, s (zero-order hold between calls).
    safe : bool
        Wrap the controller in :class:`SafeController` (the wrapper is available as ``result.controller``).

    Returns
    -------
    SimResult
        The flight (times s, states, thrusts N, wrenches, saturation), with the controller as ``.controller``.

    Raises
    ------
    FloatingPointError
        If the plant state diverges (from :func:`udrobot_ctrl.dynamics.sim.simulate`).
    """
    p = as_parameters(plant_model)
    ctrl = SafeController(controller, p.f_min, p.f_max) if safe else controller
    res = simulate(p, mission.x0(), mission.t_final, controller=ctrl, dt=dt, control_dt=control_dt)
    res.controller = ctrl
    return res


def run_mission_batch(controllers, plant_models, mission: Mission, dt: float = 0.01, control_dt: float = 0.05,
                      parallel: bool | None = None):
    """Fly N designed controllers, one per plant, through ``mission`` in one batch simulation.

    Each vehicle flies as :func:`run_mission` would fly it alone (``safe=True``): the controllers are
    wrapped by :func:`batch_controller`, the plants stacked (:func:`~udrobot_ctrl.dynamics.sim.stack_parameters`;
    they must share the thruster layout) and simulated together. A vehicle that diverges is frozen at NaN
    without stopping the others (``on_divergence="freeze"``). ``parallel``: threaded RK4 kernel (see
    :func:`~udrobot_ctrl.dynamics.sim.integrate_rk4`; default automatic, False in worker processes).

    Returns
    -------
    SimResult
        ``x`` (n+1, N, 12), ``u`` (n, N, k); ``result.controller`` is the batch wrapper (``fallbacks`` (N,)).
    """
    ctrls = list(controllers)
    plants = list(plant_models)
    if len(ctrls) != len(plants):
        raise ValueError(f"{len(ctrls)} controllers for {len(plants)} plants; expected one controller per plant")
    p = stack_parameters(plants)
    ctrl = batch_controller(ctrls, p.f_min, p.f_max)
    res = simulate(p, mission.x0(), mission.t_final, controller=ctrl, dt=dt, control_dt=control_dt,
                   on_divergence="freeze", parallel=parallel)
    res.controller = ctrl
    return res
