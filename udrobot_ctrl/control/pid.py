"""Decoupled PID loops per actuated DOF (surge speed, depth, heading, roll), tuned from the linear model.

Plant models per loop, read off the linearisation (:mod:`udrobot_ctrl.control.linearize`) at the design point
(hover for depth, heading and roll; the mission's transit speed for surge). With the wrench-input
matrix ``B_tau = B T^+`` (12 x 6) and the diagonal entries ``a = A[v, v]`` (velocity state v of the DOF),
``b = B_tau[v, dof]``:

* surge speed u / X:            G = b / (s - a)                first order (lag tau1 = -1/a)
* depth z / Z, heading psi / N: G = b / (s (s - a))            integrator + first-order lag
* roll phi / K:                 G = b / (s^2 - a s - k)        lightly damped pendulum (k = A[p, phi])

Tuning (named methods):

* SIMC (Skogestad 2003) for surge, depth and heading with an effective delay ``theta = control_dt / 2``
  (zero-order hold; thruster spin-up not modelled, *assumed* negligible) and a closed-loop time constant
  ``tau_c`` per loop (defaults below: depth and heading chosen to settle within a mission manoeuvre, the others
  *assumed*, see ``_default_tau_c``):
  first order -> PI ``Kc = tau1 / (k (tau_c + theta))``, ``tau_I = min(tau1, 4 (tau_c + theta))``; when
  ``tau1 > 8 theta`` the lag is approximated as an integrator (SIMC's rule), and integrator + lag with a
  long lag becomes a double integrator ``k'' / s^2``: ``Kc = 1 / (4 k'' (tau_c + theta)^2)``,
  ``tau_I = tau_D = 4 (tau_c + theta)`` (series form, converted to parallel gains).
* pole placement for roll: PID placing the closed-loop poles of ``G`` at ``(s + 1/tau_c)^3``.

Control law (per loop, derivative on the measurement, no derivative kick)::

    tau_dof = tau_trim + Kp e + I - Kd d(y)/dt,   dI/dt = Ki e + (tau_achieved - tau_commanded) / T_t

with ``e`` the error to the setpoint filtered by ``1 / (SETPOINT_FILTER Kp/Ki s + 1)``, which cancels the
closed-loop zero of the integral action (:data:`SETPOINT_FILTER`): without it a depth step overshoots about 20 %.

``tau_trim`` is the design model's trim wrench at the reference speed; the wrench of the four loops (X, Z, K,
N) is mapped to thrusts by the constrained OSQP allocator (:class:`udrobot_ctrl.dynamics.thrusters.ThrustAllocator`,
clipped pseudo-inverse if unavailable). Anti-windup (``anti_windup``): ``back-calculation`` (default,
tracking time ``T_t = sqrt(tau_I tau_D)`` or ``tau_I`` for PI, Astrom and Hagglund), ``conditional``
(integration stops while the loop's wrench is not achieved and the error would grow it) or ``none``.

Margins: :func:`loop_margins` returns gain and phase margins (``control.margin``) of each loop's
``L = C G e^{-theta s}`` (delay as a 2nd-order Pade approximant).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import osqp

from udrobot_ctrl.control.linearize import STATE_INDEX, linearize, trim_at
from udrobot_ctrl.dynamics.plant import PlantParameters, kinematics, wrap_angle
from udrobot_ctrl.dynamics.thrusters import ThrustAllocator, actuated_dofs

#: loop -> (output state, rate state, DOF index in tau)
LOOPS = {"surge": ("u", None, 0), "depth": ("z", "w", 2), "roll": ("phi", "p", 3), "heading": ("psi", "r", 5)}
#: levelling loop added when the layout actuates pitch on its own (BlueROV2 Heavy); UDrobot and the 6-thruster
#: BlueROV2 leave pitch to the restoring moment
PITCH_LOOP = {"pitch": ("theta", "q", 4)}
ALL_LOOPS = {**LOOPS, **PITCH_LOOP}
_LOOP_VEL = {"surge": "u", "depth": "w", "roll": "p", "heading": "r", "pitch": "q"}


def loops_for(T) -> dict:
    """Loops of a thruster layout: :data:`LOOPS`, plus :data:`PITCH_LOOP` when pitch is actuated alone."""
    return {**LOOPS, **PITCH_LOOP} if "M" in actuated_dofs(T).actuated else dict(LOOPS)


def _default_tau_c():
    # closed-loop time constants (s). Depth and heading: SIMC's double-integrator rule puts the slowest closed-loop
    # pole at 0.176 / (tau_c + theta) rad/s (the real root of x^3 + x^2 + x/2 + 1/16 with x = s (tau_c + theta);
    # 0.54 rad/s for tau_c 0.3 s), so a 2 % settling takes about 22 (tau_c + theta): 7 s for 0.3 s, longer than
    # the 5.5 s a manoeuvre of the quick mission lasts. 0.15 / 0.1 s settle a 1 m depth step and a 90 deg turn in
    # about 3-4 s, and with the filtered setpoint (SETPOINT_FILTER) keep the thrusters off their limits on every
    # shipped model; surge, roll, pitch unchanged (assumed)
    return {"surge": 0.5, "depth": 0.15, "roll": 0.3, "heading": 0.1, "pitch": 0.3}


#: Setpoint prefilter time constant in units of the loop's ``Kp / Ki``. The integral action puts a closed-loop
#: zero at ``-Ki / Kp`` (derivative on the measurement keeps the D term out of the setpoint path); a zero slower
#: than the closed-loop poles makes a setpoint step overshoot (15-17 % in the linear depth loop of every shipped
#: model, about 20 % flown, with 0.3). A prefilter ``1 / (Kp/Ki s + 1)`` cancels it (Skogestad 2003, sec. 6,
#: setpoint filter): the step then follows the closed-loop poles, without overshoot in the linear loop.
SETPOINT_FILTER = 1.0


@dataclass(frozen=True)
class PIDTuning:
    """Tuning targets: closed-loop time constants (s) per loop and the effective delay (s).

    Attributes
    ----------
    tau_c : dict
        Loop name (``surge``, ``depth``, ``roll``, ``heading``, ``pitch``) -> closed-loop time constant, s;
        the names given override the defaults (surge 0.5, depth 0.15, roll 0.3, heading 0.1, pitch 0.3 s: depth
        and heading settle the quick mission's steps in 3-4 s off the thrust limits of the shipped models; surge,
        roll and pitch assumed).
    delay : float, optional
        Effective delay theta of the SIMC rules, s; None: half the control period.
    """

    tau_c: dict = field(default_factory=_default_tau_c)
    delay: float | None = None  # None: control_dt / 2


@dataclass
class LoopDesign:
    """One tuned loop: plant model (a, b, k), method, parallel gains and the tracking time."""

    name: str
    method: str
    a: float
    b: float
    k: float
    kp: float
    ki: float
    kd: float
    t_track: float
    delay: float

    def plant_tf(self):
        """python-control transfer function of the loop's plant model (from DOF wrench to output)."""
        import control

        s = control.tf("s")
        if self.name == "surge":
            return self.b / (s - self.a)
        if self.name in ("roll", "pitch"):
            return self.b / (s**2 - self.a * s - self.k)
        return self.b / (s * (s - self.a))

    def controller_tf(self):
        """C(s) = Kp + Ki/s + Kd s (derivative filtered at 10/ tau_D... here ideal; used for margins only)."""
        import control

        s = control.tf("s")
        c = self.kp + self.ki / s
        if self.kd:
            c = c + self.kd * s / (1 + s * 0.01)
        return c


def _simc(name, a, b, tau_c, theta):
    """SIMC gains (parallel form) for surge (first order) or depth/heading (integrator + lag)."""
    if name == "surge":
        if -a > 0 and 1.0 / (-a) <= 8 * theta:
            tau1, k = 1.0 / (-a), b / (-a)
            kc = tau1 / (k * (tau_c + theta))
            ti = min(tau1, 4 * (tau_c + theta))
            return "SIMC first order (PI)", kc, kc / ti, 0.0, ti
        # long lag: integrator k' = b
        kc = 1.0 / (b * (tau_c + theta))
        ti = 4 * (tau_c + theta)  # the drag slope vanishes at rest: keep the integrator rule (no min with tau1)
        return "SIMC integrating (PI)", kc, kc / ti, 0.0, ti
    tau2 = 1.0 / (-a) if a < 0 else np.inf
    if tau2 > 8 * theta and tau2 > 4 * (tau_c + theta):
        # double integrator k'' = b
        kc = 1.0 / (4 * b * (tau_c + theta) ** 2)
        ti = td = 4 * (tau_c + theta)
        method = "SIMC double integrator (PID)"
    else:
        kprime = b / (-a)
        kc = 1.0 / (kprime * (tau_c + theta))
        ti, td = 4 * (tau_c + theta), tau2
        method = "SIMC integrator + lag (PID)"
    # series -> parallel
    f = 1 + td / ti
    return method, kc * f, kc / ti, kc * td, np.sqrt(ti * td)


def _pole_placement(a, b, k, tau_c):
    w = 1.0 / tau_c
    return "pole placement (s + 1/tau_c)^3", (3 * w**2 + k) / b, w**3 / b, (3 * w + a) / b


def design_loops(p: PlantParameters, tuning: PIDTuning | None = None, control_dt: float = 0.05,
                 surge_speed: float = 0.5, depth: float = 1.0) -> dict:
    """Tune the loops of the layout (:func:`loops_for`: four, or five with pitch) from the design model's
    linearisation.

    Surge, depth and heading by Skogestad's SIMC rules (first order or integrating plant), roll and pitch by
    pole placement on their second-order model.

    Parameters
    ----------
    p : PlantParameters
        The design model.
    tuning : PIDTuning, optional
        Closed-loop time constants and delay (defaults when None).
    control_dt : float
        Controller period, s (the default delay is half of it).
    surge_speed : float
        Surge speed of the surge loop's trim, m/s.
    depth : float
        Depth of the trims, m.

    Returns
    -------
    dict
        Loop name -> :class:`LoopDesign` (plant model, method, parallel gains).
    """
    tuning = tuning or PIDTuning()
    tau_c = _default_tau_c()
    tau_c.update(tuning.tau_c)
    theta = control_dt / 2 if tuning.delay is None else float(tuning.delay)
    Tp = np.linalg.pinv(p.T)
    out = {}
    for name, (y, _rate, dof) in loops_for(p.T).items():
        point = trim_at(p, surge_speed if name == "surge" else 0.0, depth)
        lin = linearize(p, point)
        Btau = lin.B @ Tp
        iv = STATE_INDEX[_LOOP_VEL[name]]
        a, b = float(lin.A[iv, iv]), float(Btau[iv, dof])
        if not b > 0:
            raise ValueError(f"model {p.name!r}: loop {name} has no control authority (b = {b:.3g})")
        k = float(lin.A[iv, STATE_INDEX[y]]) if name in ("roll", "pitch") else 0.0
        if name in ("roll", "pitch"):
            method, kp, ki, kd = _pole_placement(a, b, k, tau_c[name])
            tt = np.sqrt(max(kp / ki, 1e-6) * max(kd / kp, 1e-6))
        else:
            method, kp, ki, kd, tt = _simc(name, a, b, tau_c[name], theta)
            if kd == 0.0:
                tt = kp / ki
        out[name] = LoopDesign(name, method, a, b, k, float(kp), float(ki), float(kd), float(tt), theta)
    return out


def loop_margins(loops: dict) -> dict:
    """Gain and phase margins per loop of ``L = C G P`` (P: 2nd-order Pade approximant of the loop's delay).

    Returns per loop: ``gain_margin`` (upper: factor by which the gain may grow, inf if never unstable),
    ``gain_margin_lower`` (factor it may shrink to, > 0 for the conditionally stable double-integrator
    loops whose phase is below -180 deg at low frequency; 0 if none), ``phase_margin_deg`` and the
    crossover frequencies (rad/s) from ``control.margin``.
    """
    import control

    out = {}
    for name, lp in loops.items():
        num, den = control.pade(lp.delay, 2) if lp.delay > 0 else ([1.0], [1.0])
        L = lp.controller_tf() * lp.plant_tf() * control.tf(num, den)
        gm, pm, wcg, wcp = control.margin(L)
        gms = np.atleast_1d(control.stability_margins(L, returnall=True)[0])
        upper = [g for g in gms if g > 1]
        lower = [g for g in gms if 1e-6 < g < 1]
        out[name] = {"gain_margin": float(min(upper)) if upper else float("inf"),
                     "gain_margin_lower": float(max(lower)) if lower else 0.0,
                     "phase_margin_deg": float(pm), "w_phase_crossover": float(wcg), "w_gain_crossover": float(wcp),
                     "method": lp.method}
    return out


def _allocator(p, allocation="pinv"):
    if allocation == "pinv":
        Tp = np.linalg.pinv(p.T)
        return (lambda tau: np.clip(Tp @ tau, p.f_min, p.f_max)), "clipped pseudo-inverse"
    try:
        alloc = ThrustAllocator.from_parameters(p)

        def run(tau):
            return alloc(tau).f
        return run, "OSQP box-constrained allocation"
    except (ValueError, osqp.OSQPException):  # OSQP rejects the allocation problem's data: clipped pinv
        Tp = np.linalg.pinv(p.T)
        return (lambda tau: np.clip(Tp @ tau, p.f_min, p.f_max)), "clipped pseudo-inverse"



class PIDController:
    """Four PID loops + thrust allocation: ``controller(t, x) -> thrusts`` (N); stateful (integrators).

    Parameters
    ----------
    params : PlantParameters
        Design model (trim feed-forward, allocation).
    loops : dict
        name -> :class:`LoopDesign` (from :func:`design_loops`).
    reference : callable
        ``reference(t) -> {"z": m, "psi": rad, "u": m/s}`` (roll reference 0).
    dt : float
        Sampling period, s (integrator step; the controller assumes it is called every ``dt``).
    anti_windup : {'back-calculation', 'conditional', 'none'}
        How an integrator is kept from winding up while the thrusters saturate.
    depth : float
        Depth of the trims used as feed-forward, m.
    setpoint_filter : float
        Setpoint prefilter time constant in units of each loop's ``Kp / Ki`` (a ratio; 0 disables it).
    """

    def __init__(self, params: PlantParameters, loops: dict, reference, dt: float = 0.05,
                 anti_windup: str = "back-calculation", depth: float = 1.0,
                 setpoint_filter: float = SETPOINT_FILTER):
        if anti_windup not in ("back-calculation", "conditional", "none"):
            raise ValueError(f"anti_windup must be 'back-calculation', 'conditional' or 'none', got {anti_windup!r}")
        if not dt > 0:
            raise ValueError(f"dt must be > 0 s, got {dt}")
        self.params, self.loops, self.reference, self.dt = params, loops, reference, float(dt)
        self.anti_windup = anti_windup
        self.setpoint_filter = float(setpoint_filter)
        self.allocate, self.allocation = _allocator(params)
        self.depth = depth
        self._trims: dict = {}
        self.reset()

    @classmethod
    def design(cls, params: PlantParameters, reference, dt: float = 0.05, tuning: PIDTuning | None = None,
               anti_windup: str = "back-calculation", surge_speed: float = 0.5, depth: float = 1.0,
               setpoint_filter: float = SETPOINT_FILTER) -> PIDController:
        """Tune from the design model (:func:`design_loops`) and build the controller."""
        loops = design_loops(params, tuning, control_dt=dt, surge_speed=surge_speed, depth=depth)
        return cls(params, loops, reference, dt, anti_windup, depth, setpoint_filter)

    def reset(self):
        self.integral = {n: 0.0 for n in self.loops}
        self.filtered = {}

    def margins(self) -> dict:
        return loop_margins(self.loops)

    def _filter(self, target: dict) -> dict:
        """First-order setpoint prefilter, time constant ``setpoint_filter * Kp / Ki`` per loop (0: none)."""
        out = {}
        for name in self.loops:
            y = ALL_LOOPS[name][0]
            r = target[y]
            prev = self.filtered.get(y)
            tf = self.setpoint_filter * (self.loops[name].kp / self.loops[name].ki if self.loops[name].ki else 0.0)
            if prev is None or tf <= 0:
                out[y] = r
            else:
                if y == "psi":
                    r = prev + wrap_angle(r - prev)
                out[y] = prev + (r - prev) * (1.0 - np.exp(-self.dt / tf))
            self.filtered[y] = out[y]
        return out

    def trim_wrench(self, surge: float) -> np.ndarray:
        key = round(float(surge), 6)
        w = self._trims.get(key)
        if w is None:
            w = self._trims[key] = self.params.T @ trim_at(self.params, key, self.depth).u0
        return w

    def __call__(self, t, x):
        x = np.asarray(x, float)
        p = self.params
        ref = self.reference(t)
        if not np.all(np.isfinite(x)):
            return np.clip(np.linalg.pinv(p.T) @ self.trim_wrench(ref["u"]), p.f_min, p.f_max)
        eta_dot = kinematics(x[:6], x[6:])
        target = self._filter({"u": ref["u"], "z": ref["z"], "phi": 0.0, "theta": 0.0, "psi": ref["psi"]})
        tau = self.trim_wrench(ref["u"]).copy()
        errs = {}
        for name in self.loops:
            y, rate, dof = ALL_LOOPS[name]
            lp = self.loops[name]
            e = target[y] - x[STATE_INDEX[y]]
            if y == "psi":
                e = wrap_angle(e)
            errs[name] = e
            d = eta_dot[STATE_INDEX[y]] if rate else 0.0
            tau[dof] += lp.kp * e + self.integral[name] - lp.kd * d
        f = self.allocate(tau)
        achieved = p.T @ f
        for name in self.loops:
            dof = ALL_LOOPS[name][2]
            lp = self.loops[name]
            short = achieved[dof] - tau[dof]  # < 0 when the loop asks more than the thrusters give
            e = errs[name]
            if self.anti_windup == "back-calculation":
                self.integral[name] += self.dt * (lp.ki * e + short / lp.t_track)
            elif self.anti_windup == "conditional":
                saturated = abs(short) > 1e-6 * max(1.0, abs(tau[dof]))
                if not (saturated and np.sign(e) == np.sign(tau[dof] - self.trim_wrench(ref["u"])[dof])):
                    self.integral[name] += self.dt * lp.ki * e
            else:
                self.integral[name] += self.dt * lp.ki * e
        return np.clip(f, p.f_min, p.f_max)


class BatchPID:
    """N :class:`PIDController` laws flown at once: ``controller(t, x (N, 12)) -> thrusts (N, n)``.

    Each vehicle keeps its own integrators and setpoint-filter states and uses its controller's gains,
    design model (trim wrench) and anti-windup, exactly as :meth:`PIDController.__call__`, with array
    operations over the vehicles. The controllers are only read (the same object may repeat: one design
    shared by several plants); they must share the reference, sampling period, anti-windup mode,
    setpoint filter, thruster layout and the clipped pseudo-inverse allocation.
    """

    def __init__(self, controllers):
        ctrls = list(controllers)
        if not ctrls:
            raise ValueError("BatchPID needs at least one controller")
        c0 = ctrls[0]
        for i, c in enumerate(ctrls):
            if not isinstance(c, PIDController):
                raise TypeError(f"controller {i} is a {type(c).__name__}, not a PIDController")
            same = (c.reference == c0.reference and c.dt == c0.dt and c.anti_windup == c0.anti_windup
                    and c.setpoint_filter == c0.setpoint_filter and c.allocation == c0.allocation
                    and np.array_equal(c.params.T, c0.params.T) and np.array_equal(c.params.f_min, c0.params.f_min)
                    and np.array_equal(c.params.f_max, c0.params.f_max))
            if not same:
                raise ValueError(f"controller {i} differs from controller 0 in reference, dt, anti-windup, setpoint "
                                 "filter, allocation or thrusters; only gains and design models may differ")
        if c0.allocation != "clipped pseudo-inverse":
            raise ValueError(f"BatchPID vectorises the clipped pseudo-inverse allocation, not {c0.allocation!r}")
        self.controllers = ctrls
        self.reference, self.dt, self.anti_windup = c0.reference, c0.dt, c0.anti_windup
        self.T, self.f_min, self.f_max = c0.params.T, c0.params.f_min, c0.params.f_max
        self.Tp = np.linalg.pinv(self.T)
        names = list(LOOPS)
        g = {k: np.array([[getattr(c.loops[n], k) for n in names] for c in ctrls])
             for k in ("kp", "ki", "kd", "t_track")}
        self.kp, self.ki, self.kd, self.t_track = g["kp"], g["ki"], g["kd"], g["t_track"]
        with np.errstate(divide="ignore", invalid="ignore"):
            self.t_filter = c0.setpoint_filter * np.where(self.ki != 0, self.kp / self.ki, 0.0)
        self.out_idx = [STATE_INDEX[y] for y, _r, _d in LOOPS.values()]
        self.has_rate = np.array([r is not None for _y, r, _d in LOOPS.values()])
        self.dofs = [d for _y, _r, d in LOOPS.values()]
        self.psi_col = [y for y, _r, _d in LOOPS.values()].index("psi")
        self._trims: dict = {}
        self.reset()

    def __len__(self) -> int:
        return len(self.controllers)

    def reset(self):
        n = (len(self.controllers), len(LOOPS))
        self.integral = np.zeros(n)
        self.filtered = np.zeros(n)
        self.started = np.zeros(n[0], bool)

    def trim_wrench(self, surge: float) -> np.ndarray:
        """(N, 6) trim wrench of every design model at the reference surge speed (N, N m)."""
        key = round(float(surge), 6)
        w = self._trims.get(key)
        if w is None:
            per_object = {}
            w = self._trims[key] = np.stack([per_object.setdefault(id(c), c.trim_wrench(key))
                                             for c in self.controllers])
        return w

    def _filter(self, target, ok):
        """Setpoint prefilter of :meth:`PIDController._filter` for the vehicles ``ok``."""
        prev = self.filtered
        step = np.where(self.t_filter > 0, 1.0 - np.exp(-self.dt / np.where(self.t_filter > 0, self.t_filter, 1.0)),
                        1.0)
        r = target.copy()
        r[:, self.psi_col] = prev[:, self.psi_col] + wrap_angle(target[:, self.psi_col] - prev[:, self.psi_col])
        moved = prev + (r - prev) * step
        first = ~self.started[:, None] | (self.t_filter <= 0)
        out = np.where(first, target, moved)
        self.filtered = np.where(ok[:, None], out, self.filtered)
        self.started |= ok
        return out

    def __call__(self, t, x):
        x = np.asarray(x, float).reshape(len(self), 12)
        ref = self.reference(t)
        trim = self.trim_wrench(ref["u"])
        ok = np.all(np.isfinite(x), axis=1)
        xs = np.where(ok[:, None], x, 0.0)
        eta_dot = np.concatenate([kinematics(xs[:, :6], xs[:, 6:]), np.zeros((len(x), 6))], axis=1)
        goal = np.array([ref["u"], ref["z"], 0.0, ref["psi"]])
        target = self._filter(np.broadcast_to(goal, (len(x), 4)), ok)
        e = target - xs[:, self.out_idx]
        e[:, self.psi_col] = wrap_angle(e[:, self.psi_col])
        d = np.where(self.has_rate, eta_dot[:, self.out_idx], 0.0)
        tau = trim.copy()
        tau[:, self.dofs] += self.kp * e + self.integral - self.kd * d
        f = np.clip(tau @ self.Tp.T, self.f_min, self.f_max)
        short = (f @ self.T.T - tau)[:, self.dofs]
        if self.anti_windup == "back-calculation":
            step = self.dt * (self.ki * e + short / self.t_track)
        elif self.anti_windup == "conditional":
            saturated = np.abs(short) > 1e-6 * np.maximum(1.0, np.abs(tau[:, self.dofs]))
            grows = np.sign(e) == np.sign(tau[:, self.dofs] - trim[:, self.dofs])
            step = np.where(saturated & grows, 0.0, self.dt * self.ki * e)
        else:
            step = self.dt * self.ki * e
        self.integral = np.where(ok[:, None], self.integral + step, self.integral)
        f_safe = np.clip(trim @ self.Tp.T, self.f_min, self.f_max)  # non-finite state: trim, as PIDController
        return np.where(ok[:, None], np.clip(f, self.f_min, self.f_max), f_safe)
