"""ArduSub's own cascaded gains designed on a model, with the emulated ArduSub in the loop (``design ardusub``).

What is designed (ArduSub's names; the search runs on them in ArduSub's units, the flights in SI through
:meth:`~udrobot_ctrl.ardusub.params.ArduSubParameters.from_log_params`):

* roll, pitch: ``ATC_ANG_RLL/PIT_P`` (angle P, 1/s) and the rate PID's ``ATC_RAT_RLL/PIT_P``, ``_I``. The D
  terms stay: on the model a large rate D (0.03-0.04) shortens the attitude steps but chatters the shared vertical
  thrusters to their limits in a depth step at 100 Hz, and it is the gain most sensitive to the gyro noise and the
  loop rate, which the model does not have;
* yaw: ``ATC_ANG_YAW_P`` and ``ATC_RAT_YAW_P``, ``_I`` (Sub's default yaw D is 0 and stays 0);
* depth: ``PSC_POSZ_P`` (1/s), ``PSC_VELZ_P`` (1/s) and ``PSC_ACCZ_P``, ``_I`` (ArduSub's units, see
  :mod:`.params`).

The limits and filters (``IMAX``, ``FLTT/FLTE/FLTD``, ``ATC_INPUT_TC``, ``ATC_ACCEL_*_MAX``, ``PILOT_*``) are kept as
the log (or ArduSub's defaults) has them: they shape the pilot's feel and the vehicle's sensor noise. Each gain
stays inside the range ArduSub documents for it in the target firmware (:mod:`.firmware`: Sub's own ``@Range``,
not ArduCopter's).

How, in two stages per loop (the loops searched in parallel, :func:`udrobot_ctrl.parallel.fork_map`):

1. **margins** (:func:`linear_search`): on the loop's linear model with the filters, the motor lag and the delays
   (:mod:`.loop_margins`), the gains of the highest crossover frequency that keep the specification's phase and
   gain margins on every model of the spread, by a coordinate search (factors 2, sqrt 2, 2^(1/4) on each gain and
   on the inner loop's gains together). No flight is needed, and the margins stop the gains where the filters and
   delays leave no more phase: without them more gain is always better and the search runs to the range's end.
2. **steps** (:func:`tune_loop`): every candidate is flown on the nominal model by
   :func:`udrobot_ctrl.dynamics.sim.simulate` with the emulated autopilot as its controller (the
   :class:`~udrobot_ctrl.autopilot.fly.LoggedPilot` of ``simulate --closed-loop``, in GUIDED with the step as its
   target; the thrusters follow their command with the margins' motor lag, :func:`with_motor_lag`): a 1 m depth
   step, a 45 deg yaw step and 10 deg roll and pitch steps from rest, trimmed for the model's net buoyancy. The
   cost of a loop is its step's IAE (normalised by the step size, s) with penalties for overshoot beyond the
   specification, settling later than specified (or not at all), any thruster at its limit, and divergence, plus
   a penalty for margins below the specification. Starting from the better of the current gains and stage 1's, a
   coordinate search (factors sqrt 2, 2^(1/4)) refines it; a candidate that loses the margins the current point
   keeps is not flown. The metrics are the project's one definition
   (:func:`udrobot_ctrl.control.metrics.step_response`, :func:`~udrobot_ctrl.control.metrics.integral_abs_error`,
   :func:`~udrobot_ctrl.control.metrics.at_thrust_limit`).

The new gains of all loops are then flown together on every model of the *spread* (:func:`model_spread`) and
their margins computed on each. If a loop diverges, saturates a thruster in the depth or yaw step, or loses its
margins, the gains are moved back towards the old ones (half, then a quarter of the way, geometrically). What
still fails is a :class:`SpecFailure` (a code, the loop, the model, the figure and its specification): the design
is then not written without ``--force`` (:attr:`ArduSubDesign.failures`). The same checks on the current gains
(:meth:`ArduSubDesign.current_failures`) and the :meth:`ArduSubDesign.verdict` say when the current gains are
fine and changing them buys little.

Frames. The BlueROV2 models carry their ArduSub frame. A vehicle without one (the UDrobot: two horizontal and two
vertical thrusters) is designed on a CUSTOM frame (``FRAME_CONFIG`` 7) whose factors are the normalised columns of
the pseudo-inverse of its thruster matrix (:func:`layout_frame`): what a custom ``AP_Motors6DOF::setup_motors``
table would hold. ArduSub has no such table built in, so these gains only apply to an ArduSub built with those
factors; the design says so. A mixer input with no factor on any motor (pitch on the BlueROV2's VECTORED frame and
on the UDrobot) cannot be commanded: that loop is not designed, its gains stay.

Check flight: :mod:`.check_flight` turns the design into the doublets to fly on the vehicle.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from scipy.optimize import brentq

from udrobot_ctrl.ardusub.modes import Mode, Targets
from udrobot_ctrl.ardusub.params import ArduSubParameters, gain_log_params
from udrobot_ctrl.autopilot.ardusub import ArduSubAutopilot
from udrobot_ctrl.autopilot.firmware import ASSUMED_FIRMWARE, Firmware, gain_range, range_violations
from udrobot_ctrl.autopilot.fly import LoggedCommands, LoggedPilot
from udrobot_ctrl.autopilot.loop_margins import (
    GAIN_MARGIN_MIN_DB,
    PHASE_MARGIN_MIN_DEG,
    LoopTiming,
    Margins,
    axis_plant,
    loop_margins,
)
from udrobot_ctrl.autopilot.motors import MIXER_INPUTS, Frame, MotorParameters, custom_frame, frame, mix, to_pwm
from udrobot_ctrl.control.metrics import at_thrust_limit, integral_abs_error, step_response
from udrobot_ctrl.dynamics.effects import parse_effects
from udrobot_ctrl.dynamics.plant import plant_parameters, thrust_to_wrench
from udrobot_ctrl.dynamics.sim import simulate
from udrobot_ctrl.dynamics.thrusters import pwm_to_thrust
from udrobot_ctrl.parallel import fork_map
from udrobot_ctrl.sensitivity.executor import as_executor
from udrobot_ctrl.sensitivity.local import LocalResult, local_sensitivity
from udrobot_ctrl.sensitivity.parameters import ParameterSpace, apply_sample, default_space
from udrobot_ctrl.vehicle import Vehicle, load_model
from udrobot_files.output import save_figure

LOOPS = ("roll", "pitch", "yaw", "depth")
#: the gains designed per loop (ArduSub names)
LOOP_PARAMETERS = {
    "roll": ("ATC_ANG_RLL_P", "ATC_RAT_RLL_P", "ATC_RAT_RLL_I"),
    "pitch": ("ATC_ANG_PIT_P", "ATC_RAT_PIT_P", "ATC_RAT_PIT_I"),
    "yaw": ("ATC_ANG_YAW_P", "ATC_RAT_YAW_P", "ATC_RAT_YAW_I"),
    "depth": ("PSC_POSZ_P", "PSC_VELZ_P", "PSC_ACCZ_P", "PSC_ACCZ_I"),
}
#: the step flown per loop: size (m or rad), its time and the flight's length (s)
STEP_SIZE = {"roll": math.radians(10.0), "pitch": math.radians(10.0), "yaw": math.radians(45.0), "depth": 1.0}
STEP_TIME, STEP_LENGTH = 1.0, {"roll": 5.0, "pitch": 5.0, "yaw": 10.0, "depth": 12.0}
START_DEPTH = 2.0  # m: deep enough for a 1 m step up or down
#: mixer input of each loop (its column in the frame's factors)
LOOP_INPUT = {"roll": "roll", "pitch": "pitch", "yaw": "yaw", "depth": "throttle"}
UDROBOT_SETS = ("cfd:chin", "cfd:morison", "free_decay:morison", "pendulum:chin", "pendulum:morison")
SEARCH_FACTORS = (2.0, math.sqrt(2.0), 2.0 ** 0.25)
SCAN_SCALES = (0.5, 2.0, 4.0, 8.0)  # the first scan of the inner loop's gains, times the old ones


@dataclass(frozen=True)
class Specification:
    """What the designed loops must do on the model (SI).

    Attributes
    ----------
    depth_settling_s, yaw_settling_s, attitude_settling_s : float
        Settling time of the 1 m depth step, the 45 deg yaw step and the 10 deg roll/pitch steps, s.
    depth_overshoot_pct, yaw_overshoot_pct, attitude_overshoot_pct : float
        Largest overshoot, % of the step.
    depth_band, angle_band : float
        Settling band, fraction of the step (2 % of 1 m = 2 cm; 5 % of 45 deg = 2.25 deg: the T200's dead band
        leaves a small heading limit cycle that a 2 % band would call unsettled).
    saturation_allowed : bool
        False: no thruster may reach its thrust limit in the depth and yaw steps (the thrust headroom).
    command_limit : float
        The search's preferred largest motor command on the nominal model, fraction of full thrust (0.8: 20 %
        headroom left for the models of the spread and for disturbances): commands above it are penalised in the
        search, but not a pass/fail criterion (a thruster *at* its limit is).
    phase_margin_deg, gain_margin_db : float
        The smallest phase (deg) and gain (dB) margin every loop must keep on every model of the spread
        (:mod:`.loop_margins`: 45 deg, 6 dB).
    """

    depth_settling_s: float = 6.0
    depth_overshoot_pct: float = 10.0
    yaw_settling_s: float = 5.0
    yaw_overshoot_pct: float = 10.0
    attitude_settling_s: float = 3.0
    attitude_overshoot_pct: float = 15.0
    depth_band: float = 0.02
    angle_band: float = 0.05
    saturation_allowed: bool = False
    command_limit: float = 0.8
    phase_margin_deg: float = PHASE_MARGIN_MIN_DEG
    gain_margin_db: float = GAIN_MARGIN_MIN_DB

    def settling_s(self, loop: str) -> float:
        """The settling-time specification of ``loop`` (s)."""
        return {"depth": self.depth_settling_s, "yaw": self.yaw_settling_s}.get(loop, self.attitude_settling_s)

    def overshoot_pct(self, loop: str) -> float:
        """The overshoot specification of ``loop`` (%)."""
        return {"depth": self.depth_overshoot_pct, "yaw": self.yaw_overshoot_pct}.get(loop,
                                                                                     self.attitude_overshoot_pct)

    def band(self, loop: str) -> float:
        """The settling band of ``loop`` (fraction of the step)."""
        return self.depth_band if loop == "depth" else self.angle_band


@dataclass(frozen=True)
class StepResponse:
    """One loop's step flown under the emulated ArduSub.

    Attributes
    ----------
    loop : str
        ``roll``, ``pitch``, ``yaw`` or ``depth``.
    model : str
        The model flown.
    t : (n,) ndarray
        Time, s (the step at :data:`STEP_TIME`).
    y : (n,) ndarray
        The loop's output: depth (m, down) or angle (rad).
    before, target : float
        The output before and the target after the step (m or rad).
    overshoot_pct : float
        Overshoot, % of the step (nan if the flight diverged).
    settling_s : float or None
        Settling time after the step, s (None: not settled by the end).
    iae : float
        Integral of |error| after the step divided by the step size, s.
    max_command : float
        Largest motor command during the flight, fraction of full thrust (1 = at the PWM limit).
    saturation_s : float
        Time with a thruster at its thrust limit, s.
    stable : bool
        Finite, bounded (error below twice the step) and converging: the largest error in the flight's last
        quarter is below a quarter of the step or below 0.9 times the largest in the quarter before (a slow but
        shrinking error is stable, a growing or sustained large oscillation is not).
    """

    loop: str
    model: str
    t: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    before: float
    target: float
    overshoot_pct: float
    settling_s: float | None
    iae: float
    max_command: float
    saturation_s: float
    stable: bool

    def meets(self, spec: Specification) -> bool:
        """The response meets ``spec``: stable, settled in time, overshoot within and (unless allowed) no
        thruster at its limit."""
        return bool(self.stable and self.settling_s is not None and self.settling_s <= spec.settling_s(self.loop)
                    and self.overshoot_pct <= spec.overshoot_pct(self.loop)
                    and (spec.saturation_allowed or self.saturation_s == 0.0))

    def summary(self) -> dict:
        """Scalar metrics (JSON-ready): overshoot %, settling s, IAE s, max command, saturation s, stable."""
        return {"overshoot_pct": _num(self.overshoot_pct), "settling_s": _num(self.settling_s), "iae_s": _num(self.iae),
                "max_command": _num(self.max_command), "saturation_s": _num(self.saturation_s),
                "stable": self.stable}


#: the codes of :class:`SpecFailure`, with the sentence each is printed as
FAILURE_CODES = {
    "settling": "settles in {value:.2f} s on {model}, the specification is {limit:g} s",
    "overshoot": "overshoots {value:.1f} % on {model}, the specification is {limit:g} %",
    "unstable": "the step diverges on {model}",
    "saturation": "a thruster is at its limit for {value:.2f} s in the step on {model} ({detail})",
    "phase_margin": "phase margin {value:.1f} deg on {model}, below the {limit:g} deg required",
    "gain_margin": "gain margin {value:.1f} dB on {model}, below the {limit:g} dB required",
    "closed_loop_unstable": "the linear loop with its filters and delays is unstable on {model}",
    "out_of_range": "{detail}",
    "unwritable": "{detail}",
}


@dataclass(frozen=True)
class SpecFailure:
    """One way a set of gains fails the specification.

    Attributes
    ----------
    code : str
        A key of :data:`FAILURE_CODES`.
    loop : str
        The loop (``depth``, ``yaw``, ``roll_rate`` ...; for ``out_of_range`` the loop of the gain).
    model : str
        The model of the spread it fails on ('' when not model-specific).
    value, limit : float
        The figure and its specification (s, %, deg, dB; nan when not applicable).
    detail : str
    """

    code: str
    loop: str
    model: str = ""
    value: float = math.nan
    limit: float = math.nan
    detail: str = ""

    def __post_init__(self):
        if self.code not in FAILURE_CODES:
            raise ValueError(f"unknown failure code {self.code!r}: expected one of {sorted(FAILURE_CODES)}")

    def sentence(self) -> str:
        """The failure as the console prints it."""
        value = "not settled" if self.code == "settling" and not math.isfinite(self.value) else self.value
        text = FAILURE_CODES[self.code]
        if value == "not settled":
            text = "does not settle within the flight on {model}, the specification is {limit:g} s"
        return f"{self.loop}: " + text.format(value=value, limit=self.limit, model=self.model or "the model",
                                              detail=self.detail)

    def to_dict(self) -> dict:
        return {"code": self.code, "loop": self.loop, "model": self.model, "value": _num(self.value),
                "limit": _num(self.limit), "detail": self.detail, "sentence": self.sentence()}


@dataclass(frozen=True)
class LoopDesign:
    """The design of one loop.

    Attributes
    ----------
    loop : str
    designed : bool
        False when the frame cannot command the loop (its gains unchanged; ``note`` says why).
    old, new : dict
        ArduSub name -> value (ArduSub's units) before and after.
    nominal_old, nominal_new : StepResponse
        The step on the nominal model with the old and the new gains.
    spread_old, spread_new : tuple of StepResponse
        The step on every model of the spread (the nominal first).
    margins_old, margins_new : tuple of Margins
        The loop's margins (and its rate loop's, for an attitude axis) on every model of the spread with the old
        and the new gains (:mod:`.loop_margins`).
    evaluations : int
        Flights the search used.
    note : str
    """

    loop: str
    designed: bool
    old: dict
    new: dict
    nominal_old: StepResponse
    nominal_new: StepResponse
    spread_old: tuple
    spread_new: tuple
    margins_old: tuple = ()
    margins_new: tuple = ()
    evaluations: int = 0
    note: str = ""

    def stable_on_spread(self) -> bool:
        """Every model of the spread is stable with the new gains."""
        return all(r.stable for r in self.spread_new)


@dataclass(frozen=True)
class ArduSubDesign:
    """ArduSub gains designed on a model (:func:`design_ardusub`).

    Attributes
    ----------
    model : str
        The nominal model's name.
    frame_name : str
        The ArduSub frame flown (``VECTORED_6DOF`` ..., or ``CUSTOM`` from the thruster layout).
    spec : Specification
        The specification the gains were designed to.
    loops : dict of str to LoopDesign
        Loop name (``roll``, ``pitch``, ``yaw``, ``depth``) -> its design (old and new gains, responses, margins).
    base_params : dict
        The parameters the design started from (ArduSub names and units: the log's, else empty = defaults).
    spread : tuple of str
        The models of the spread (the nominal first) and how each was made.
    failures : tuple of SpecFailure
        How the new gains fail the specification (empty: they meet it and may be written).
    notes : tuple of str
        Assumptions (frame, defaults used, the spread's construction, the loop timing).
    loop_rate_hz : float
        The autopilot rate of the flights (Hz).
    firmware : Firmware
        The firmware whose ranges bound the gains.
    timing : LoopTiming
        The nominal model's filters and delays in the margins.
    """

    model: str
    frame_name: str
    spec: Specification
    loops: dict
    base_params: dict
    spread: tuple
    failures: tuple
    notes: tuple
    loop_rate_hz: float
    firmware: Firmware = ASSUMED_FIRMWARE
    timing: LoopTiming | None = None

    @property
    def safe(self) -> bool:
        """The new gains meet the specification (no failure)."""
        return not self.failures

    @property
    def refusal(self) -> tuple:
        """The failures as sentences."""
        return tuple(f.sentence() for f in self.failures)

    def current_failures(self) -> tuple:
        """How the vehicle's current gains fail the specification in the designed loops (same checks)."""
        return tuple(f for d in self.loops.values() if d.designed
                     for f in loop_failures(d.loop, d.spread_old or (d.nominal_old,), d.margins_old, self.spec))

    def verdict(self) -> tuple:
        """(code, sentence): ``current_fine`` when the current gains meet the specification and the new ones
        improve no designed loop's nominal IAE by more than that IAE varies over the spread with the current
        gains (the model's own uncertainty); ``improves`` when the new gains meet it and do better;
        ``refused`` when they fail it."""
        if self.failures:
            return "refused", "the new gains fail the specification: " + "; ".join(self.refusal)
        gains = []
        for d in self.loops.values():
            if not d.designed:
                continue
            old_iae = [r.iae for r in d.spread_old if math.isfinite(r.iae)]
            spread = (max(old_iae) - min(old_iae)) if len(old_iae) > 1 else 0.0
            gains.append((d.loop, d.nominal_old.iae - d.nominal_new.iae, spread))
        if not self.current_failures() and all(g <= s for _, g, s in gains):
            return "current_fine", ("your current gains meet the specification, and the new ones improve no loop's "
                                    "step (IAE) by more than it varies over the model's spread: changing them buys "
                                    "little")
        better = ", ".join(f"{lp} IAE -{g:.2f} s (spread {s:.2f} s)" for lp, g, s in gains)
        return "improves", f"the new gains meet the specification: {better}"

    def changes(self) -> dict:
        """ArduSub name -> (old, new) for every designed gain whose value changes (ArduSub's units)."""
        out = {}
        for d in self.loops.values():
            for name, new in d.new.items():
                if not math.isclose(new, d.old[name], rel_tol=1e-6, abs_tol=1e-9):
                    out[name] = (d.old[name], new)
        return out

    def changed_params(self) -> dict:
        """ArduSub name -> new value, only the parameters that change: the content of the ``.params`` file."""
        return {k: v[1] for k, v in self.changes().items()}

    def parameters(self) -> ArduSubParameters:
        """The autopilot's parameters with the new gains (SI)."""
        return ArduSubParameters.from_log_params({**self.base_params, **self.changed_params()}, self.loop_rate_hz)

    def to_dict(self) -> dict:
        """JSON-ready summary: old/new gains, per-loop metrics on the nominal and the spread, refusal, notes."""
        loops = {}
        for name, d in self.loops.items():
            loops[name] = {"designed": d.designed, "note": d.note, "old": d.old, "new": d.new,
                           "margins": [{"loop": o.loop, "model": o.model, "old": o.summary(),
                                        "new": n.summary() if n is not None else None}
                                       for o, n in zip(d.margins_old, d.margins_new or (None,) * len(d.margins_old))],
                           "evaluations": d.evaluations,
                           "nominal": {"old": d.nominal_old.summary(), "new": d.nominal_new.summary()},
                           "spread": [{"model": o.model, "old": o.summary(), "new": n.summary()}
                                      for o, n in zip(d.spread_old, d.spread_new)],
                           "meets_spec": d.nominal_new.meets(self.spec)}
        return {"format": "udrobot-ardusub-design/1", "model": self.model, "frame": self.frame_name,
                "loop_rate_hz": self.loop_rate_hz, "specification": dict(self.spec.__dict__),
                "spread": list(self.spread),
                "changes": {k: {"old": o, "new": n} for k, (o, n) in self.changes().items()},
                "firmware": self.firmware.label, "firmware_source": self.firmware.source,
                "safe": self.safe, "failures": [f.to_dict() for f in self.failures],
                "current_failures": [f.to_dict() for f in self.current_failures()],
                "verdict": dict(zip(("code", "sentence"), self.verdict())), "notes": list(self.notes),
                "loops": loops}


def _num(v):
    return None if v is None or not math.isfinite(float(v)) else round(float(v), 6)


# ------------------------------------------------------------------------------------------------ frames
def layout_frame(vehicle: Vehicle) -> Frame:
    """A CUSTOM ArduSub frame from a vehicle's thruster layout.

    The factors of mixer input j are the column of the pseudo-inverse of the thruster matrix for its body axis
    (roll K, pitch M, yaw N, throttle -Z (up), forward X, lateral Y), normalised to a largest factor of 1; a
    column below 1e-6 of the largest is zero (the input cannot be commanded). This is what a user would write
    in ``AP_Motors6DOF::setup_motors`` for ``SUB_FRAME_CUSTOM``: an *assumption* that the vehicle's ArduSub is
    built with these factors.
    """
    T = plant_parameters(vehicle).T  # (6, n): wrench = T f
    inverse = np.linalg.pinv(T)     # (n, 6)
    axis = {"roll": (3, 1.0), "pitch": (4, 1.0), "yaw": (5, 1.0), "throttle": (2, -1.0), "forward": (0, 1.0),
            "lateral": (1, 1.0)}
    factors = np.zeros((T.shape[1], 6))
    scale = np.abs(inverse).max()
    for j, name in enumerate(MIXER_INPUTS):
        k, sign = axis[name]
        col = sign * inverse[:, k]
        peak = np.abs(col).max()
        if peak > 1e-6 * scale:
            factors[:, j] = np.round(col / peak, 6) + 0.0  # no -0.0
    return custom_frame(factors, name="CUSTOM")


def vehicle_frame(vehicle: Vehicle) -> tuple:
    """(frame, note): the model's ArduSub frame, or :func:`layout_frame` with a note saying it is assumed."""
    tag = (vehicle.extras or {}).get("ardusub_frame")
    if tag:
        fr = frame(tag)
        if fr.n_motors == vehicle.n_thrusters:
            return fr, ""
    fr = layout_frame(vehicle)
    return fr, (f"{vehicle.name} has no ArduSub frame: designed on a CUSTOM frame (FRAME_CONFIG 7) whose factors come "
                f"from its thruster layout (pseudo-inverse of the thruster matrix, columns {MIXER_INPUTS}): "
                f"{np.array2string(fr.factors, separator=',').replace(chr(10), '')}; stock ArduSub has no table for "
                f"CUSTOM, so these gains apply only to a build whose setup_motors holds these factors")


# ------------------------------------------------------------------------------------------------ spread
def model_spread(model, extra=()) -> tuple:
    """(vehicles, descriptions): the nominal model first, then the models its predictions must also hold on.

    * a UDrobot coefficient set (``SET:FORM``): the five shipped sets (cfd:chin, cfd:morison, free_decay:morison,
      pendulum:chin, pendulum:morison);
    * a vehicle with ``[alternatives]`` (BlueROV2): each published alternative set (Wu2018) on the six diagonal
      entries of added mass, linear and quadratic damping, and the nominal with damping x 0.7 and added mass
      x 1.3 (a lightly damped, heavy corner: *assumed*, for coefficients that no second source checks);
    * a model with plant effects (a corrected model from ``diagnose --out-model``): the corrected model and the
      same coefficients without the effects (the nominal);
    * ``extra``: further models (names or files) given by the user.
    """
    nominal = load_model(model)
    vehicles, names = [nominal], [f"{nominal.name} (nominal)"]
    if isinstance(model, str) and model in UDROBOT_SETS:
        for other in UDROBOT_SETS:
            if other != model:
                vehicles.append(load_model(other))
                names.append(other)
    alts = (nominal.extras or {}).get("alternatives") or {}
    for src, mats in alts.items():
        changes = {}
        for key in ("added_mass", "linear_damping", "quadratic_damping"):
            if key in mats:
                m = np.array(getattr(nominal, key), float)
                m[np.diag_indices(6)] = np.asarray(mats[key], float)[:6]
                changes[key] = m
        vehicles.append(nominal.with_changes(name=f"{nominal.name}+{src}", **changes))
        names.append(f"{nominal.name} with the {src} coefficients")
    if alts:
        vehicles.append(nominal.with_changes(name=f"{nominal.name} low damping",
                                             linear_damping=0.7 * np.asarray(nominal.linear_damping),
                                             quadratic_damping=0.7 * np.asarray(nominal.quadratic_damping),
                                             added_mass=1.3 * np.asarray(nominal.added_mass)))
        names.append(f"{nominal.name} with damping x 0.7 and added mass x 1.3 (assumed corner)")
    if nominal.effects:
        vehicles.append(nominal.with_changes(name=f"{nominal.name} without effects", effects=()))
        names.append(f"{nominal.name} without its {len(nominal.effects)} effect(s) (the nominal coefficients)")
    for e in extra:
        vehicles.append(load_model(e))
        names.append(str(e))
    return tuple(vehicles), tuple(names)


# ------------------------------------------------------------------------------------------------ flights
class _StepPilot(LoggedPilot):
    """:class:`LoggedPilot` in GUIDED with unshaped targets: ArduSub shapes the step as it shapes a commanded one."""

    def _targets(self, k: int) -> Targets:
        c = self.commands
        att = c.attitude_target[k]
        return Targets(roll=float(att[0]), pitch=float(att[1]), yaw=float(att[2]), depth=float(c.z_target[k]))


def _hover_integrator(p, fr: Frame, motors: MotorParameters, hover: float) -> float | None:
    """The depth loop's accel integrator (throttle, down frame) that holds the model's net buoyancy."""
    def heave(thr):
        pwm = to_pwm(mix(fr, np.array([0.0, 0.0, 0.0, thr, 0.0, 0.0]), motors), motors, integer=False)
        return thrust_to_wrench(pwm_to_thrust(pwm, p.supply_voltage), p)[2] + (p.weight - p.buoyancy)

    try:
        if heave(-1.0) * heave(1.0) > 0:
            return None
        thr = brentq(heave, -1.0, 1.0, xtol=1e-5)
    except (ValueError, RuntimeError):
        return None
    return hover - (0.5 + thr / 2.0)


def step_flight(vehicle: Vehicle, params: ArduSubParameters, fr: Frame, loop: str,
                motors: MotorParameters | None = None, spec: Specification | None = None,
                size: float | None = None, t_final: float | None = None) -> StepResponse:
    """Fly one loop's step on ``vehicle`` under the emulated ArduSub (GUIDED, one tick per control step).

    Parameters
    ----------
    vehicle : Vehicle
    params : ArduSubParameters
        The autopilot's parameters (SI); its ``loop_rate_hz`` is the control step.
    fr : Frame
        The mixer.
    loop : str
        ``roll``, ``pitch``, ``yaw`` or ``depth``.
    motors : MotorParameters, optional
        PWM range (ArduSub's defaults); directions +1 (the model's thrusters are in motor-command sense).
    spec : Specification, optional
        For the settling band.
    size : float, optional
        Step size (m or rad); :data:`STEP_SIZE` by default.
    t_final : float, optional
        Flight length (s); :data:`STEP_LENGTH` by default.
    """
    if loop not in LOOPS:
        raise ValueError(f"loop {loop!r}: expected one of {LOOPS}")
    spec = spec or Specification()
    size = STEP_SIZE[loop] if size is None else float(size)
    t_final = STEP_LENGTH[loop] if t_final is None else float(t_final)
    p = plant_parameters(vehicle)
    motors = motors or MotorParameters.default(fr.n_motors)
    motors = replace(motors, directions=(1,) * fr.n_motors)
    k = {"roll": 0, "pitch": 1, "yaw": 2}.get(loop)
    att = np.zeros((2, 3))
    if k is not None:
        att[1, k] = size
    z = np.array([START_DEPTH, START_DEPTH + (size if loop == "depth" else 0.0)])
    commands = LoggedCommands(t=np.array([0.0, STEP_TIME]), mode=np.full(2, float(Mode.GUIDED)),
                              armed=np.ones(2, bool), rcin=None, attitude_target=att, z_target=z,
                              horizontal=np.zeros((2, 2)), voltage=np.full(2, p.supply_voltage))
    dt = 1.0 / params.loop_rate_hz
    autopilot = ArduSubAutopilot(params)
    trim = _hover_integrator(p, fr, motors, params.depth.throttle_hover)
    if trim is not None:
        autopilot.set_integrators(accel_down=trim)
    pilot = _StepPilot(commands, autopilot, fr, motors, p, dt)
    x0 = np.zeros(12)
    x0[2] = START_DEPTH
    res = simulate(vehicle, x0, t_final, controller=pilot, dt=dt, on_divergence="freeze")
    t = np.asarray(res.t, float)
    index = 2 if loop == "depth" else 3 + k
    y = np.asarray(res.x[:, index], float)
    before, target = float(y[0]), float(y[0] + size)
    finite = bool(np.all(np.isfinite(y)))
    over, settle = step_response(t, y, STEP_TIME, t_final, before, target, spec.band(loop))
    after = t >= STEP_TIME
    err = np.abs(y - target)
    iae = integral_abs_error(t[after], err[after]) / abs(size) if finite else math.inf
    quarter = 0.25 * (t_final - STEP_TIME)
    tail, before_tail = t >= t_final - quarter, (t >= t_final - 2 * quarter) & (t < t_final - quarter)
    stable = finite and bool(np.max(err[after]) < 2.0 * abs(size)) and bool(
        np.max(err[tail]) < max(0.25 * abs(size), 0.9 * np.max(err[before_tail])))
    pwm = np.asarray(pilot.pwm, float)
    max_command = float(np.max(np.abs(pwm - 1500.0)) / 400.0) if pwm.size else 0.0
    u = np.asarray(res.u, float)
    sat = at_thrust_limit(u, p.f_min, p.f_max)
    saturation = float(np.sum(np.diff(t)[: sat.size] * sat))
    return StepResponse(loop=loop, model=vehicle.name, t=t, y=y, before=before, target=target,
                        overshoot_pct=float(over) if finite else math.nan, settling_s=settle if finite else None,
                        iae=float(iae), max_command=max_command, saturation_s=saturation, stable=stable)


# ------------------------------------------------------------------------------------------------ design
def gain_values(params: ArduSubParameters) -> dict:
    """The designed gains of ``params`` as ArduSub parameters (name -> value, ArduSub's units)."""
    out = gain_log_params(params)
    for a, value in zip(("RLL", "PIT", "YAW"), params.attitude.angle_p):
        out[f"ATC_ANG_{a}_P"] = float(value)
    return {name: out[name] for names in LOOP_PARAMETERS.values() for name in names}


def _cost(r: StepResponse, spec: Specification) -> float:
    """The search's cost of one step (s): IAE plus penalties."""
    if not r.stable:
        return 1e3 + (r.iae if math.isfinite(r.iae) else 1e3)
    settle_spec = spec.settling_s(r.loop)
    late = 2.0 if r.settling_s is None else max(0.0, r.settling_s - settle_spec) / settle_spec
    over = max(0.0, r.overshoot_pct - spec.overshoot_pct(r.loop)) / max(spec.overshoot_pct(r.loop), 1.0)
    sat = 0.0 if spec.saturation_allowed else (10.0 + r.saturation_s if r.saturation_s > 0 else 0.0)
    headroom = 5.0 * max(0.0, r.max_command - spec.command_limit) / (1.0 - spec.command_limit)
    return r.iae * (1.0 + over) + 3.0 * late + 3.0 * over + sat + headroom


def _params_with(base: dict, values: dict, loop_rate_hz: float) -> ArduSubParameters:
    return ArduSubParameters.from_log_params({**base, **values}, loop_rate_hz)


# ------------------------------------------------------------------------------------------------ margins
class _Robustness:
    """The margins of the loops on every model of the spread, the axis plants computed once per model."""

    def __init__(self, vehicles, fr: Frame, base: dict, timing_rate_hz: float):
        self.vehicles, self.frame, self.base, self.rate = tuple(vehicles), fr, base, float(timing_rate_hz)
        self.timings = tuple(LoopTiming.of(v, base, self.rate) for v in self.vehicles)
        self._plants = {}

    def plant(self, k: int, loop: str):
        key = (k, loop)
        if key not in self._plants:
            self._plants[key] = axis_plant(self.vehicles[k], self.frame, loop, depth=START_DEPTH)
        return self._plants[key]

    def margins(self, values: dict, loop: str, timings=None) -> tuple:
        """Margins of ``loop`` (and of its rate loop for an attitude axis) on every model, gains ``values``
        (canonical names) over the base parameters."""
        params = _params_with(self.base, values, self.rate)
        out = []
        for k, v in enumerate(self.vehicles):
            timing = (timings or self.timings)[k]
            ap = self.plant(k, loop)
            whiches = ("outer",) if loop == "depth" else ("rate", "outer")
            out += [loop_margins(v, self.frame, params, loop, timing, w, ap) for w in whiches]
        return tuple(out)


def _margin_penalty(margins, spec: Specification) -> float:
    """The search's penalty for margins below the specification (0 when every model meets it)."""
    out = 0.0
    for m in margins:
        if not m.stable:
            out += 100.0
            continue
        pm = m.phase_margin_deg if math.isfinite(m.phase_margin_deg) else 180.0
        gm = m.gain_margin_db if math.isfinite(m.gain_margin_db) else 60.0
        out += 20.0 * max(0.0, spec.phase_margin_deg - pm) / spec.phase_margin_deg
        out += 20.0 * max(0.0, spec.gain_margin_db - gm) / spec.gain_margin_db
    return out


def _range(name: str, firmware: Firmware, ranges: dict | None = None) -> tuple:
    """(low, high) of a gain: ``ranges[name]`` when given (a test's or a user's bound), else ``firmware``'s."""
    if ranges and name in ranges:
        return tuple(ranges[name])
    r = gain_range(name, firmware)
    return (r[0], r[1]) if r is not None else (0.0, math.inf)


def tune_loop(loop: str, vehicle: Vehicle, fr: Frame, base: dict, old: dict, spec: Specification,
              loop_rate_hz: float, motors: MotorParameters | None = None, max_evaluations: int = 30,
              robustness: _Robustness | None = None, firmware: Firmware = ASSUMED_FIRMWARE) -> tuple:
    """Coordinate search of one loop's gains on ``vehicle`` (see the module notes).

    The cost of a candidate is its nominal step's (:func:`_cost`) plus the penalty of its margins on the
    spread (:func:`_margin_penalty`, computed first: a candidate whose margins alone cost more than the best
    so far is not flown). Every gain stays inside ``firmware``'s documented range.

    Returns
    -------
    (dict, StepResponse, int)
        The loop's new gains (ArduSub names and units), the nominal step with them, the number of flights.
    """
    names = LOOP_PARAMETERS[loop]
    current = {n: float(min(max(old[n], _range(n, firmware)[0]), _range(n, firmware)[1])) for n in names}

    def penalty(values):
        return _margin_penalty(robustness.margins({**old, **values}, loop), spec) if robustness else 0.0

    def fly(values):
        return step_flight(vehicle, _params_with(base, {**old, **values}, loop_rate_hz), fr, loop, motors, spec)

    best = fly(current)
    current_pen = penalty(current)
    best_cost, evaluations = _cost(best, spec) + current_pen, 1
    if robustness is not None and max_evaluations > 1:
        # the linear optimum (highest bandwidth within the margins) is the search's start unless its step is worse
        # than the current gains' (it can saturate the thrusters, which the linear loop does not know)
        trial = linear_search(loop, robustness, old, current, spec, firmware)
        r, pen = fly(trial), penalty(trial)
        evaluations += 1
        if _cost(r, spec) + pen < best_cost:
            current, best, best_cost, current_pen = trial, r, _cost(r, spec) + pen, pen

    def attempt(trial):
        nonlocal current, best, best_cost, evaluations, current_pen
        pen = penalty(trial)
        if (pen > 0.0 and current_pen == 0.0) or pen >= best_cost:
            return False  # loses the margins the current gains keep, or the margins alone cost more: not flown
        r = fly(trial)
        evaluations += 1
        c = _cost(r, spec) + pen
        if c < best_cost * 0.995:
            current, best, best_cost, current_pen = trial, r, c, pen
            return True
        return False

    # then the steps: each gain in turn, and the inner loop (rate PID or velocity + accel gains) scaled together
    directions = [names[1:]] + [(n,) for n in names]
    for factor in SEARCH_FACTORS[1:]:
        improved = True
        while improved and evaluations < max_evaluations:
            improved = False
            for direction in directions:
                for f in (factor, 1.0 / factor):
                    trial = _scaled(current, direction, f, firmware)
                    if all(math.isclose(trial[n], current[n]) for n in direction) or evaluations >= max_evaluations:
                        continue
                    if attempt(trial):
                        improved = True
                        break
    rounded = {}
    for n, v in current.items():
        lo, hi = _range(n, firmware)
        rounded[n] = float(min(max(float(f"{v:.4g}"), lo), hi))
    return rounded, best, evaluations


def _scaled(values: dict, names, factor: float, firmware: Firmware, ranges: dict | None = None) -> dict:
    """``values`` with the gains ``names`` times ``factor``, inside ``firmware``'s ranges (a gain at 0 starts
    from its range's low end, or 5 % of its high end)."""
    out = dict(values)
    for name in names:
        lo, hi = _range(name, firmware, ranges)
        value = values[name] * factor if values[name] > 0 else (lo if lo > 0 else 0.05 * hi) * factor
        out[name] = float(min(max(value, lo), hi))
    return out


def linear_search(loop: str, robustness: _Robustness, old: dict, start: dict, spec: Specification,
                  firmware: Firmware, iterations: int = 80, ranges: dict | None = None) -> dict:
    """The loop's gains that give the highest crossover frequency on its slowest model of the spread while
    every model keeps the margins (:func:`_margin_penalty` 0), by a coordinate search on the linear loops alone
    (no flight; factors 2, sqrt 2, 2^(1/4) on each gain and on the inner loop's gains together, within
    ``firmware``'s ranges). Returns ``start`` when no candidate meets the margins and improves on it.

    The crossover it maximises is the outer loop's (the angle loop of an attitude axis, the depth cascade),
    the bandwidth of what the pilot commands; the margins bound it, so the gains stop where the filters,
    the motor lag and the delays leave no more phase (the issue's runaway to the range's end does not occur
    unless the range's end still has margin). ``ranges`` overrides the firmware's ranges (name -> (low, high)).
    """
    names = LOOP_PARAMETERS[loop]

    def cost(values):
        margins = robustness.margins({**old, **values}, loop)
        pen = _margin_penalty(margins, spec)
        outer = [m.crossover_rad_s for m in margins if m.loop == loop and math.isfinite(m.crossover_rad_s)]
        return pen - (math.log(min(outer)) if outer and pen == 0.0 else 0.0)

    current, best, n = dict(start), cost(start), 1
    directions = [names[1:]] + [(name,) for name in names]
    for factor in SEARCH_FACTORS:
        improved = True
        while improved and n < iterations:
            improved = False
            for direction in directions:
                for f in (factor, 1.0 / factor):
                    trial = _scaled(current, direction, f, firmware, ranges)
                    if all(math.isclose(trial[k], current[k]) for k in direction) or n >= iterations:
                        continue
                    c = cost(trial)
                    n += 1
                    if c < best - 1e-3:
                        current, best, improved = trial, c, True
                        break
    return current


def _blend(old: dict, new: dict, w: float) -> dict:
    """Geometric blend old^(1-w) new^w (arithmetic where one of them is 0)."""
    out = {}
    for n, v in new.items():
        o = old[n]
        out[n] = float(f"{(o ** (1 - w) * v ** w if o > 0 and v > 0 else o + w * (v - o)):.4g}")
    return out


def design_ardusub(model, log_params: dict | None = None, spec: Specification | None = None,
                   loop_rate_hz: float = 100.0, loops=LOOPS, spread_extra=(), max_evaluations: int = 12,
                   firmware: Firmware | None = None, timing_rate_hz: float | None = None,
                   motor_lag_in_flights: bool = True) -> ArduSubDesign:
    """Design ArduSub's attitude and depth gains on ``model`` with the emulated ArduSub in the loop.

    Parameters
    ----------
    model : str, Path or Vehicle
        The nominal model (a name, a ``udrobot-model/1`` file such as ``diagnose --out-model``'s, or a Vehicle).
    log_params : dict, optional
        The vehicle's parameters (canonical names and ArduSub's units, :func:`.firmware.from_firmware` of a log's),
        e.g. :func:`~udrobot_ctrl.ardusub.params.run_log_params` of a converted run; ArduSub's defaults for the
        missing ones (and for all when None).
    spec : Specification, optional
        The specifications (the defaults of :class:`Specification`).
    loop_rate_hz : float
        The autopilot's tick in the step flights (Hz). 100 Hz keeps a design fast; the PID filters (5-30 Hz) stay
        below its Nyquist rate. The margins use the vehicle's own rate (``timing_rate_hz``).
    loops : iterable of str
        The loops to design (others keep their gains).
    spread_extra : iterable
        Further models of the spread (:func:`model_spread`).
    max_evaluations : int
        Step flights per loop of the search.
    firmware : Firmware, optional
        The firmware the gains are for: its documented ranges bound the search (:data:`.firmware.ASSUMED_FIRMWARE`
        when None).
    timing_rate_hz : float, optional
        The loop rate of the margins (Hz): the log's ``SCHED_LOOP_RATE``, else ArduSub's 400 Hz.
    motor_lag_in_flights : bool
        Fly the steps with the motor/ESC lag of the margins (:func:`with_motor_lag`) on every model that has no
        ``thruster_lag`` effect of its own, so the flights and the margins see the same thrusters.

    Returns
    -------
    ArduSubDesign
        The tuned loops, their step responses and margins on the spread, and the specification failures.
    """
    spec = spec or Specification()
    firmware = firmware or ASSUMED_FIRMWARE
    if not 10.0 <= loop_rate_hz <= 2000.0:
        raise ValueError(f"loop_rate_hz must be between 10 and 2000 Hz (ArduSub runs 100-400 Hz), got {loop_rate_hz}")
    unknown = [lp for lp in loops if lp not in LOOPS]
    if unknown:
        raise ValueError(f"unknown loop(s) {unknown}: expected some of {LOOPS}")
    base = {k: float(v) for k, v in (log_params or {}).items()}
    vehicles, spread_names = model_spread(model, spread_extra)
    nominal = vehicles[0]
    fr, frame_note = vehicle_frame(nominal)
    notes = [frame_note] if frame_note else []
    start = _params_with(base, {}, loop_rate_hz)
    old = gain_values(start)
    defaulted = sorted(set(start.assumed) & set(old))
    if defaulted:
        notes.append(f"started from ArduSub's defaults for {', '.join(defaulted)} (not in the log's parameters)")
    notes.append(f"spread: {'; '.join(spread_names)}")
    notes.append(f"flights: GUIDED steps from rest at {START_DEPTH:g} m, trimmed for the net buoyancy, ArduSub at "
                 f"{loop_rate_hz:g} Hz; limits and filters (IMAX, FLT*, INPUT_TC, ACCEL_*_MAX) kept")
    rate = timing_rate_hz or float(base.get("SCHED_LOOP_RATE") or 400.0)
    robust = _Robustness(vehicles, fr, base, rate)
    t0 = robust.timings[0]
    if motor_lag_in_flights:
        vehicles = tuple(with_motor_lag(v, t.motor_tau_s) for v, t in zip(vehicles, robust.timings))
        nominal = vehicles[0]
        notes.append(f"flights: the thrusters follow their command with the margins' motor lag "
                     f"({t0.motor_tau_s * 1e3:.0f} ms, {t0.motor_tau_source}) where the model has none")
    notes.append(f"margins: linear loops at {rate:g} Hz with INS_GYRO_FILTER {t0.gyro_filter_hz:g} Hz, "
                 f"INS_ACCEL_FILTER {t0.accel_filter_hz:g} Hz, the PID filters, a {t0.output_delay_s * 1e3:.2f} ms "
                 f"output delay, motor lag {t0.motor_tau_s * 1e3:.0f} ms ({t0.motor_tau_source}), depth latency "
                 f"{t0.depth_latency_s * 1e3:.0f} ms (assumed); required {spec.phase_margin_deg:g} deg and "
                 f"{spec.gain_margin_db:g} dB on every model of the spread")
    notes.append(f"ranges: {firmware.label} ({firmware.source or 'given'}): ArduSub's documented @Range")
    commandable = {lp: bool(np.any(fr.factors[:, MIXER_INPUTS.index(LOOP_INPUT[lp])])) for lp in LOOPS}
    designed = [lp for lp in LOOPS if lp in loops and commandable[lp]]

    def flights_of(params, which):
        """Every (loop, model) step of ``which`` loops with ``params``, over the cores (fork_map)."""
        items = [(lp, k) for lp in which for k in range(len(vehicles))]
        got = fork_map(lambda item: step_flight(vehicles[item[1]], params, fr, item[0], spec=spec), items)
        return {lp: tuple(r for (lq, _), r in zip(items, got) if lq == lp) for lp in which}

    # the old gains' flights on the spread and each loop's search (from the old gains of the others; the joint
    # flights below check them together) as one batch over the cores, the searches and the longest steps first:
    # the flights fill the cores a search leaves idle (each task is independent: the same numbers in any order)
    tasks = [("tune", lp, 0) for lp in designed] + [("fly", lp, k) for lp in LOOPS for k in range(len(vehicles))]
    tasks.sort(key=lambda task: (task[0] != "tune", -STEP_LENGTH[task[1]]))

    def run(task):
        kind, lp, k = task
        if kind == "tune":
            return tune_loop(lp, nominal, fr, base, old, spec, loop_rate_hz, max_evaluations=max_evaluations,
                             robustness=robust, firmware=firmware)
        return step_flight(vehicles[k], start, fr, lp, spec=spec)

    done = dict(zip(tasks, fork_map(run, tasks)))
    spread_old = {lp: tuple(done[("fly", lp, k)] for k in range(len(vehicles))) for lp in LOOPS}
    tuned = {lp: done[("tune", lp, 0)] for lp in designed}
    designs = {}
    for loop in LOOPS:
        old_loop = {n: old[n] for n in LOOP_PARAMETERS[loop]}
        margins = robust.margins(old, loop) if commandable[loop] else ()
        if loop not in designed:
            why = ("not requested" if loop not in loops else
                   f"frame {fr.name} has no {LOOP_INPUT[loop]} factor on any motor: the loop cannot be commanded")
            designs[loop] = LoopDesign(loop, False, old_loop, old_loop, spread_old[loop][0], spread_old[loop][0],
                                       (), (), margins, margins, 0, f"gains unchanged: {why}")
            continue
        values, best, n_eval = tuned[loop]
        designs[loop] = LoopDesign(loop, True, old_loop, values, spread_old[loop][0], best, (), (), margins, (),
                                   n_eval)
    # all loops together on the spread: they share the thrusters (a loop's gains can saturate another loop's step);
    # where the new gains diverge, saturate or lose their margins, move back towards the old ones (half, a quarter
    # of the way, geometrically); a step that is only slow or overshoots is not helped by that
    final_old = {n: v for lp in designed for n, v in designs[lp].old.items()}
    final_new = {n: v for lp in designed for n, v in designs[lp].new.items()}
    tried = []
    for w in (1.0, 0.5, 0.25):
        values = final_new if w == 1.0 else _blend(final_old, final_new, w)
        params = _params_with(base, {**old, **values}, loop_rate_hz)
        flights = flights_of(params, designed)
        margins = {lp: robust.margins({**old, **values}, lp) for lp in designed}
        failures = [f for lp in designed for f in loop_failures(lp, flights[lp], margins[lp], spec)]
        tried.append((w, values, flights, margins, failures))
        if not any(f.code not in ("settling", "overshoot") for f in failures):
            break
    if any(f.code not in ("settling", "overshoot") for f in failures):
        # no back-off keeps the spread safe: the full design is the one reported (and refused)
        w, values, flights, margins, failures = tried[0]
    for lp in LOOPS:
        d = designs[lp]
        if not d.designed:
            designs[lp] = replace(d, spread_old=spread_old[lp], spread_new=spread_old[lp])
            continue
        vals = {n: values[n] for n in d.new}
        note = (f"backed off to {w:.0%} of the way from the old gains (geometric): at full step the new gains "
                f"failed the specification on the spread" if w != 1.0 else "")
        designs[lp] = replace(d, new=vals, nominal_new=flights[lp][0], spread_old=spread_old[lp],
                              spread_new=flights[lp], margins_new=margins[lp], note=note)
    failures = list(failures)
    written = {n: v for lp in designed for n, v in designs[lp].new.items()}
    failures += [SpecFailure("out_of_range", _loop_of(r.name), detail=r.sentence())
                 for r in range_violations(written, firmware)]
    at_end = [f"{n} = {v:g}" for n, v in written.items() if not math.isclose(v, old[n])
              and any(math.isclose(v, b, rel_tol=1e-6) for b in _range(n, firmware))]
    if at_end:
        notes.append(f"at the end of ArduSub's documented range ({firmware.label}): {', '.join(at_end)}")
    return ArduSubDesign(model=nominal.name, frame_name=fr.name, spec=spec, loops=designs, base_params=base,
                         spread=spread_names, failures=tuple(failures), notes=tuple(notes),
                         loop_rate_hz=float(loop_rate_hz), firmware=firmware, timing=t0)


def with_motor_lag(vehicle: Vehicle, tau_s: float) -> Vehicle:
    """``vehicle`` with a ``thruster_lag`` plant effect of time constant ``tau_s`` (s) on the thrust, unless it
    has one already (a corrected model's own lag wins) or ``tau_s`` is 0."""
    if tau_s <= 0 or any(e.name == "thruster_lag" for e in vehicle.effects or ()):
        return vehicle
    lag = parse_effects([{"name": "thruster_lag", "params": {"T_lag_s": float(tau_s)}}])
    return vehicle.with_changes(effects=tuple(vehicle.effects or ()) + tuple(lag))


def _loop_of(name: str) -> str:
    for lp, names in LOOP_PARAMETERS.items():
        if name in names:
            return lp
    return ""


def loop_failures(loop: str, responses, margins, spec: Specification) -> list:
    """The specification failures of one loop: its nominal step (the first response) late or overshooting,
    any model's step unstable or saturating a thruster (depth and yaw), any model's margins below the spec."""
    out = []
    if responses:
        r = responses[0]
        if r.stable:
            if r.settling_s is None or r.settling_s > spec.settling_s(loop):
                out.append(SpecFailure("settling", loop, r.model, math.inf if r.settling_s is None else r.settling_s,
                                       spec.settling_s(loop)))
            if r.overshoot_pct > spec.overshoot_pct(loop):
                out.append(SpecFailure("overshoot", loop, r.model, r.overshoot_pct, spec.overshoot_pct(loop)))
    for r in responses:
        if not r.stable:
            out.append(SpecFailure("unstable", loop, r.model))
        elif loop in ("depth", "yaw") and not spec.saturation_allowed and r.saturation_s > 0:
            out.append(SpecFailure("saturation", loop, r.model, r.saturation_s, 0.0,
                                   f"largest command {r.max_command:.2f}"))
    for m in margins:
        if not m.stable:
            out.append(SpecFailure("closed_loop_unstable", m.loop, m.model))
            continue
        if m.phase_margin_deg < spec.phase_margin_deg:
            out.append(SpecFailure("phase_margin", m.loop, m.model, m.phase_margin_deg, spec.phase_margin_deg))
        if m.gain_margin_db < spec.gain_margin_db:
            out.append(SpecFailure("gain_margin", m.loop, m.model, m.gain_margin_db, spec.gain_margin_db))
    return out


def check_gains(model, params: ArduSubParameters, spec: Specification | None = None, spread_extra=(),
                loops=("depth", "yaw"), log_params: dict | None = None) -> list:
    """The specification failures (:class:`SpecFailure`) of given gains (e.g. a hand-written ``.params``) flown
    on the model's spread, with their margins: empty when they meet the specification.

    Parameters
    ----------
    model : str, Path or Vehicle
        The nominal model.
    params : ArduSubParameters
        The gains to check; ``params.loop_rate_hz`` is the step flights' tick (Hz).
    spec : Specification, optional
        The specification (the defaults of :class:`Specification`).
    spread_extra : iterable
        Further models of the spread (:func:`model_spread`).
    loops : iterable of str
        The loops to fly.
    log_params : dict, optional
        The vehicle's parameters (canonical names, ArduSub units): the filters and loop rate of the margins.

    Returns
    -------
    list of SpecFailure
        Each way the gains fail the specification, by loop and model; empty when they meet it.
    """
    spec = spec or Specification()
    vehicles, _ = model_spread(model, spread_extra)
    fr, _ = vehicle_frame(vehicles[0])
    base = dict(log_params or {})
    robust = _Robustness(vehicles, fr, base, float(base.get("SCHED_LOOP_RATE") or 400.0))
    values = gain_values(params)
    out = []
    for loop in loops:
        flights = [step_flight(v, params, fr, loop, spec=spec) for v in vehicles]
        out += loop_failures(loop, flights, robust.margins(values, loop), spec)
    return out


# ------------------------------------------------------------------------------------------------ sensitivity
#: the coefficients each loop's prediction depends on (the sensitivity package's AXIS.QUANTITY names, by axis)
SENSITIVITY_AXES = {"depth": "heave", "yaw": "yaw", "roll": "roll", "pitch": "pitch"}


class StepMetrics:
    """Sensitivity evaluator: the predicted steps' metrics for each coefficient sample of a parameter space.

    ``evaluator(X) -> {metric: (n,)}`` as :func:`udrobot_ctrl.sensitivity.local.local_sensitivity` takes it; the
    metrics are ``<loop>_settling_s``, ``<loop>_overshoot_pct``, ``<loop>_iae_s`` and ``<loop>_max_command`` of
    each loop's step (:func:`step_flight`) with the gains ``params`` on the frame ``fr``. A chunk's samples (each
    with its loops' flights) are spread over the cores (:func:`udrobot_ctrl.parallel.fork_map`; the same numbers).
    """

    def __init__(self, space: ParameterSpace, params: ArduSubParameters, fr: Frame, loops=("depth", "yaw"),
                 spec: Specification | None = None):
        self.space, self.params, self.frame, self.loops = space, params, fr, tuple(loops)
        self.spec = spec or Specification()

    def describe(self) -> str:
        return (f"ArduSub steps {', '.join(self.loops)} on {self.space.vehicle.name}, frame {self.frame.name}, "
                f"{self.params.loop_rate_hz:g} Hz")

    def __call__(self, X):
        X = np.asarray(X, float)
        out = {f"{lp}_{m}": np.full(len(X), np.nan) for lp in self.loops
               for m in ("settling_s", "overshoot_pct", "iae_s", "max_command")}
        vehicles, errors = [], []
        for row in X:
            try:
                vehicles.append(apply_sample(self.space, row))
                errors.append("")
            except ValueError as exc:
                vehicles.append(None)
                errors.append(str(exc))
        # the chunk's samples over the cores, each sample's loops in one worker (what its flights build for its
        # model is built once); fork_map: the same numbers in any order
        items = [i for i, vehicle in enumerate(vehicles) if vehicle is not None]
        flights = fork_map(lambda i: [step_flight(vehicles[i], self.params, self.frame, lp, spec=self.spec)
                                      for lp in self.loops], items)
        for i, sample in zip(items, flights):
            for lp, r in zip(self.loops, sample):
                out[f"{lp}_settling_s"][i] = np.nan if r.settling_s is None else r.settling_s
                out[f"{lp}_overshoot_pct"][i] = r.overshoot_pct
                out[f"{lp}_iae_s"][i] = r.iae
                out[f"{lp}_max_command"][i] = r.max_command
        out["error"] = errors
        return out


def prediction_sensitivity(design: ArduSubDesign, model=None, loops=("depth", "yaw"),
                           rel_step: float = 0.05) -> LocalResult:
    """Local sensitivity (:func:`~udrobot_ctrl.sensitivity.local.local_sensitivity`) of the predicted steps with
    the new gains to the model's uncertain coefficients of the loops' axes (heave for depth, yaw for yaw), over
    the sensitivity package's ranges (:func:`~udrobot_ctrl.sensitivity.parameters.default_space`).

    Parameters
    ----------
    design : ArduSubDesign
    model : str, Path or Vehicle, optional
        The nominal model (``design.model`` by default).
    loops : iterable of str
    rel_step : float
        Relative finite-difference step (5 %: the settling time is a threshold crossing, smaller steps only see
        its jumps).

    Raises
    ------
    ValueError
        When the model's coefficient space cannot be built (naming why).
    """
    vehicle = load_model(model if model is not None else design.model)
    if design.timing is not None:  # the thrusters of the design's flights
        vehicle = with_motor_lag(vehicle, design.timing.motor_tau_s)
    space = default_space(vehicle)
    axes = {SENSITIVITY_AXES[lp] for lp in loops}
    names = [n for n in space.names if n.split(".", 1)[0] in axes]
    if not names:
        raise ValueError(f"{vehicle.name}: no uncertain coefficient of {sorted(axes)} in its parameter space")
    space = space.subset(names)
    fr, _ = vehicle_frame(vehicle)
    evaluator = StepMetrics(space, design.parameters(), fr, loops, design.spec)
    executor = as_executor(workers=1)  # chunks in this process; each chunk's flights over the cores (StepMetrics)
    try:
        return local_sensitivity(evaluator, space, rel_step=rel_step, executor=executor, progress=False)
    finally:
        executor.close()


# ------------------------------------------------------------------------------------------------ plots
LOOP_UNITS = {"depth": ("depth (m, down)", 1.0), "yaw": ("yaw (deg)", 180 / math.pi),
              "roll": ("roll (deg)", 180 / math.pi), "pitch": ("pitch (deg)", 180 / math.pi)}


def plot_loop(design: ArduSubDesign, loop: str, path=None) -> Figure:
    """Step responses of one loop, old gains against new, on the nominal model (lines) and the spread (shaded
    band between the lowest and the highest response of its models); saved to ``path`` when given."""
    d = design.loops[loop]
    label, scale = LOOP_UNITS[loop]
    fig = Figure(figsize=(7, 4))
    ax = fig.subplots()
    for name, nominal, spread, color in (("old", d.nominal_old, d.spread_old, "tab:gray"),
                                         ("new", d.nominal_new, d.spread_new, "tab:blue")):
        if spread:
            n = min(r.y.size for r in spread)
            ys = np.array([r.y[:n] for r in spread]) * scale
            ax.fill_between(spread[0].t[:n], np.nanmin(ys, axis=0), np.nanmax(ys, axis=0), color=color, alpha=0.25,
                            lw=0, label=f"{name}: spread ({len(spread)} models)")
        s = nominal.summary()
        settle = "not settled" if s["settling_s"] is None else f"settles {s['settling_s']:.2f} s"
        ax.plot(nominal.t, nominal.y * scale, color=color, lw=1.6,
                label=f"{name}: {settle}, overshoot {s['overshoot_pct'] or 0:.1f} %, IAE {s['iae_s']:.2f} s")
    ax.axhline(d.nominal_new.target * scale, color="k", ls=":", lw=0.8)
    if loop == "depth":
        ax.invert_yaxis()
    ax.set_xlabel("time (s)")
    ax.set_ylabel(label)
    ax.set_title(f"{design.model}: {loop} step under the emulated ArduSub ({design.frame_name})"
                 + ("" if d.designed else " - not designed"), fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    if path is not None:
        save_figure(fig, Path(path))
    return fig


__all__ = ["ArduSubDesign", "FAILURE_CODES", "LOOPS", "LOOP_PARAMETERS", "LoopDesign", "Margins", "SpecFailure",
           "Specification", "StepMetrics", "StepResponse", "check_gains", "design_ardusub", "gain_values",
           "layout_frame", "loop_failures", "model_spread", "plot_loop", "prediction_sensitivity", "step_flight",
           "tune_loop", "vehicle_frame"]
