"""Where a replay stops representing the vehicle: the plant's domain, checked on a replayed trajectory.

The plant (:mod:`udrobot_ctrl.dynamics.plant`) is a deeply submerged rigid body: full buoyancy, added mass and
damping at any depth, no free surface, no wave or ventilation term, and hydrodynamic coefficients identified about
the upright attitude a ROV flies in. A replay (open loop, closed loop or a multiple-shooting window) that goes
where those assumptions fail still integrates, but its numbers are no longer the vehicle's. :func:`domain_check`
names those stretches with structured codes (:data:`CODES`):

``above_surface``
    z < 0 (NED depth: the body origin above the still water line). The plant keeps its full buoyancy and water
    forces in the air, so a replay there floats on nothing. ArduSub itself calls the vehicle at the surface from
    SURFACE_DEPTH (ArduSub/config.h SURFACE_DEPTH_DEFAULT, -10 cm: the pressure sensor 10 cm below the waterline
    when floating):
    the plant's domain ends at the waterline itself, z = 0.
``inverted``
    cos(phi) cos(theta) < 0: the body z axis (down through the keel) points above the horizontal, i.e. the vehicle
    is rolled or pitched beyond 90 deg (element (3, 3) of the body-to-NED rotation). A ROV is ballasted upright
    (BG below the CB), ArduSub's attitude modes command at most ANGLE_MAX of lean (ArduSub/config.h
    DEFAULT_ANGLE_MAX 4500 cdeg = 45 deg, settable to 80 deg in ArduSub/Parameters.cpp), and the coefficients are
    those of an upright hull; but ANGLE_MAX limits the pilot's command, not the states the plant represents (MANUAL
    has no angle limit, and a real vehicle can be knocked past it), so the plant's limit is the geometric one.
``thrust_saturated``
    a thruster held at its limit (within :data:`SATURATION_TOLERANCE` of the thrust the end of its command range
    gives) without a break for at least ``saturation_s`` seconds. The limit is in the model (the thrust is clipped),
    but a replay that rests on it for long is decided by the model's end-of-range thrust alone and, closed loop, by
    an autopilot that has lost authority (ArduSub's AP_Motors sets ``limit.throttle_upper/lower`` there and the
    depth loop's integrator stops): the replay's error then measures the limit, not the dynamics. The duration is a
    stated choice: half of the multiple-shooting window (:data:`SATURATION_WINDOW_FRACTION`), so that a window
    whose error is scored mostly under a clipped command is named; a whole-run replay uses half of the window
    ``diagnose`` defaults to (8 s: 4 s).

Only finite samples are checked (nan rows, outside a replay's windows, are skipped), and a span never bridges a
nan row.

A run whose *logged* vehicle was never in that domain (a converter kept no row of it: at the surface, disarmed;
docs/formats/runlog.md, ``cut``) has nothing a replay can be compared with: :func:`idle_drift` says what the plant
does there instead (with its motors at neutral it drifts at its own net buoyancy, where a floating vehicle stays
at the waterline), for the closed-loop replay's refusal.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.dynamics.thrusters import PWM_MAX, PWM_MIN, pwm_to_thrust

ABOVE_SURFACE = "above_surface"
INVERTED = "inverted"
THRUST_SATURATED = "thrust_saturated"
#: the codes :func:`domain_check` reports, in the order it reports them
CODES = (ABOVE_SURFACE, INVERTED, THRUST_SATURATED)
#: a thruster is at its limit when its thrust is within this fraction of the limit (4 us of the T-200's 400 us
#: half range of PWM: the ESC command's quantisation, 1 us, and the curve's rounding, with a margin)
SATURATION_TOLERANCE = 0.01
#: the saturation that names a multiple-shooting window: at least this fraction of the window without a break
SATURATION_WINDOW_FRACTION = 0.5
#: the multiple-shooting window ``diagnose`` and ``simulate --windows`` default to, s (a whole-run replay's
#: saturation is judged on half of it)
DEFAULT_WINDOW_S = 8.0


@dataclass(frozen=True)
class DomainSpan:
    """One stretch of a replay outside the plant's domain.

    Attributes
    ----------
    code : str
        One of :data:`CODES`.
    t0, t1 : float
        First and last sample of the stretch, s (the replay's time base).
    thruster : int or None
        The thruster's index (0-based, the model's order) for ``thrust_saturated``; None otherwise.
    """

    code: str
    t0: float
    t1: float
    thruster: int | None = None

    def to_json(self) -> dict:
        """``{"code", "t0", "t1"}`` (s, rounded to 1 ms) plus ``"thruster"`` for a saturation."""
        out = {"code": self.code, "t0": round(float(self.t0), 3), "t1": round(float(self.t1), 3)}
        if self.thruster is not None:
            out["thruster"] = int(self.thruster)
        return out

    def describe(self) -> str:
        """The span for a console line: ``above_surface 12.3-15.0 s`` (``thrust_saturated (thruster 3) ...``)."""
        which = f" (thruster {self.thruster})" if self.thruster is not None else ""
        return f"{self.code}{which} {self.t0:.2f}-{self.t1:.2f} s"


@dataclass(frozen=True)
class DomainCheck:
    """The spans of a replay outside the plant's domain (empty: the replay stayed in it).

    Attributes
    ----------
    spans : tuple of DomainSpan
        In order of their code (:data:`CODES`), then of time.
    saturation_s : float
        The saturation duration the check used, s.
    """

    spans: tuple = ()
    saturation_s: float = SATURATION_WINDOW_FRACTION * DEFAULT_WINDOW_S

    @property
    def codes(self) -> tuple:
        """The codes of the spans, each once, in :data:`CODES` order."""
        return tuple(c for c in CODES if any(s.code == c for s in self.spans))

    def __bool__(self) -> bool:
        """True when some span left the domain."""
        return bool(self.spans)

    @classmethod
    def joined(cls, checks) -> DomainCheck:
        """One check of several replays of one run (its segments, each replayed on its own, in one time base).

        Parameters
        ----------
        checks : sequence of DomainCheck
            The parts' checks, made with one saturation duration.

        Returns
        -------
        DomainCheck
            Their spans, in order of code (:data:`CODES`), then of time.
        """
        checks = list(checks)
        spans = sorted((s for c in checks for s in c.spans), key=lambda s: (CODES.index(s.code), s.t0))
        return cls(tuple(spans), checks[0].saturation_s if checks else cls.saturation_s)

    def to_json(self) -> dict:
        """``{"codes": [...], "spans": [...]}`` (:meth:`DomainSpan.to_json`)."""
        return {"codes": list(self.codes), "spans": [s.to_json() for s in self.spans]}


def true_runs(mask) -> list:
    """(start, stop) index pairs (stop exclusive) of the stretches of True in the boolean array ``mask``."""
    d = np.diff(np.concatenate([[0], np.asarray(mask, np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def domain_check(t, x, thrust=None, f_lo=None, f_hi=None, saturation_s=None) -> DomainCheck:
    """The stretches of a replayed trajectory outside the plant's domain (module docstring).

    Parameters
    ----------
    t : (n,) array_like
        Time, s.
    x : (n, 12) array_like
        Replayed state [x y z phi theta psi u v w p q r] (m, rad, m/s, rad/s); rows with a nan are not checked.
    thrust : (n, k) array_like, optional
        The thrust each thruster delivered, N (no saturation check without it).
    f_lo, f_hi : (k,) or (n, k) array_like, optional
        The thrust at the reverse / forward end of each thruster's command range, N (f_lo <= 0 <= f_hi):
        :func:`thrust_limits`. Required with ``thrust``.
    saturation_s : float, optional
        The shortest unbroken stretch at a limit that counts, s (default: half of the 8 s default window).

    Returns
    -------
    DomainCheck
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    sat_s = SATURATION_WINDOW_FRACTION * DEFAULT_WINDOW_S if saturation_s is None else float(saturation_s)
    ok = np.all(np.isfinite(x[:, :6]), axis=1) if x.size else np.zeros(0, bool)
    spans = []
    with np.errstate(invalid="ignore"):
        tests = {ABOVE_SURFACE: ok & (x[:, 2] < 0.0),
                 INVERTED: ok & (np.cos(x[:, 3]) * np.cos(x[:, 4]) < 0.0)}
    for code, mask in tests.items():
        spans += [DomainSpan(code, t[a], t[b - 1]) for a, b in true_runs(mask)]
    if thrust is not None:
        f = np.asarray(thrust, float).reshape(len(t), -1)
        lo = np.broadcast_to(np.asarray(f_lo, float), f.shape)
        hi = np.broadcast_to(np.asarray(f_hi, float), f.shape)
        with np.errstate(invalid="ignore"):
            near = 1.0 - SATURATION_TOLERANCE
            at = ((f >= near * hi) & (hi > 0)) | ((f <= near * lo) & (lo < 0))
        at &= ok[:, None]
        for j in range(f.shape[1]):
            spans += [DomainSpan(THRUST_SATURATED, t[a], t[b - 1], j) for a, b in true_runs(at[:, j])
                      if t[b - 1] - t[a] >= sat_s - 1e-9]
    return DomainCheck(tuple(spans), sat_s)


@dataclass(frozen=True)
class IdleDrift:
    """How the plant moves with no thrust (motors at neutral: a disarmed ArduSub), upright (:func:`idle_drift`).

    Attributes
    ----------
    net_up : float
        Buoyancy minus weight, N (> 0: buoyant, the vehicle rises; < 0: heavy, it sinks).
    speed : float
        Terminal vertical speed, m/s, positive down (NED: sinking > 0, rising < 0; 0 when neutral; inf when the
        model has no heave damping).
    """

    net_up: float
    speed: float

    def over(self, duration_s: float) -> float:
        """Depth change at the terminal speed over ``duration_s`` seconds, m (positive down)."""
        return self.speed * float(duration_s)


def idle_drift(p) -> IdleDrift:
    """The plant's terminal heave with no thrust, upright: ``D_L w + Q |w| w = W - B`` along body z (= down).

    Parameters
    ----------
    p : PlantParameters
        The model (weight, buoyancy, heave damping ``D_L[2, 2]``, ``Q[2, 2]``).

    Returns
    -------
    IdleDrift
        Net buoyancy (N) and the speed (m/s, down) the fully submerged plant settles at: no free surface stops a
        buoyant model at the waterline, and a heavy one sinks at this speed however shallow it starts.
    """
    net_down = float(p.weight) - float(p.buoyancy)
    lin, quad = float(p.D_L[2, 2]), float(p.Q[2, 2])
    f = abs(net_down)
    if f == 0.0:
        return IdleDrift(-net_down, 0.0)
    if quad > 0.0:
        w = 2.0 * f / (lin + np.sqrt(lin * lin + 4.0 * quad * f))  # the positive root, without cancellation
    elif lin > 0.0:
        w = f / lin
    else:
        w = np.inf
    return IdleDrift(-net_down, float(np.copysign(w, net_down)))


def limit_rows(limit, rows):
    """The rows ``rows`` (an index array or a slice) of a per-row thrust limit (n, k) N, or the limit itself when it
    is one per thruster (k,): a limit of :func:`thrust_limits` for a part of the replay it was made for."""
    limit = np.asarray(limit)
    return limit[rows] if limit.ndim == 2 else limit


def thrust_limits(f_min, f_max, kind: str, voltage=None) -> tuple:
    """(f_lo, f_hi) N: the thrust at the ends of the command range of each thruster, as :func:`domain_check`
    takes them.

    Parameters
    ----------
    f_min, f_max : (k,) array_like
        The model's thrust limits, N (PlantParameters.f_min / f_max).
    kind : str
        The run's input kind: ``pwm`` (the T-200 curve at 1100 / 1900 us, thrusters.PWM_MIN / PWM_MAX, at the
        row's ``voltage``, within the model's limits), ``thrust`` (the model's limits); ``tau`` has no thruster
        (returns None, None).
    voltage : (n,) array_like, optional
        Supply voltage per row, V (``pwm`` only).
    """
    lo, hi = np.asarray(f_min, float), np.asarray(f_max, float)
    if kind == "tau":
        return None, None
    if kind == "pwm" and voltage is not None:
        v = np.asarray(voltage, float)[:, None]
        return np.maximum(pwm_to_thrust(PWM_MIN, v), lo), np.minimum(pwm_to_thrust(PWM_MAX, v), hi)
    return lo, hi
