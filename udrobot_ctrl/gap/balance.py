"""What the thrusters held in steady flight against what the model needs there (the report's ``steady_balance``).

In steady flight (rates and accelerations near zero) the equation of motion is a balance: the thrusters'
generalised force equals the model's own forces at the measured state (restoring, damping, Coriolis). A vehicle under
an autopilot holds that balance with its integrators, so the logged outputs, through the thruster curves and the
thruster geometry, measure the steady force the real vehicle needed: its *trim*. Where the model needs a different
force there, the difference is a steady force the model lacks, in newtons and newton-metres: a buoyancy error shows
in heave while hovering, a drag centre off the CO as a pitch moment that grows with the speed, a thrust loss or a
tether as surge thrust beyond the model's drag. A replay of such a stretch drifts because the logged trim pushes the
model where the real vehicle did not go, and the NRMSE of a channel the autopilot held still (a regulated pitch)
turns a small steady moment into a large number; the balance says what it is in physical units.

Definitions (docs/formats/diagnosis.md, ``steady_balance``):

* *steady* samples: every body rate below :data:`STEADY_RATE` and every translational acceleration below
  :data:`STEADY_ACCEL` (measured or smoothed velocities and their derivatives);
* per part (fit runs, holdout runs) and speed bin (the norm of (u, v, w), bins :data:`~udrobot_ctrl.gap.locate.
  SPEED_BINS`), on the DOFs whose velocity a sensor observes in every run of the part:
  ``held`` = mean of the thrusters' generalised force B f (f the logged commands through the thrust curves),
  ``nominal`` = mean of what the nominal model needs to fly the measured motion, M nu_dot + C(nu) nu + D(nu) nu +
  g(eta) (= held + the equation-error residual), ``corrected`` = the same with the significant effects' force
  taken off (what the thrusters' nominal curve must deliver for the corrected model), ``se`` = the standard error of
  the nominal imbalance's mean;
* ``se`` = std(residual) / sqrt(n_eff), ``n_eff`` = the bin's duration over the residual's correlation time, taken as
  the Savitzky-Golay window that smooths the velocities (the residual is filtered over it);
* a DOF is *imbalanced* when |held - nominal| > :data:`BALANCE_Z` x se.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from udrobot_ctrl.gap.attribute import filter_forces
from udrobot_ctrl.gap.data import Prepared
from udrobot_ctrl.gap.locate import DOF, SPEED_BINS, bin_label
from udrobot_ctrl.gap.shrink import effect_wrench

#: steady flight: every body rate below this (rad/s). Assumed: 3 deg/s, a turn or a pitch transient is faster; a
#: vehicle the autopilot holds level wanders by less
STEADY_RATE = 0.05
#: ... and every translational acceleration below this (m/s^2). Assumed: a 0.1 m/s speed change takes 2 s or more,
#: so the added mass carries less than a tenth of a transit's drag
STEADY_ACCEL = 0.05
#: a part's speed bin is reported when it holds at least this much steady flight (s). Assumed: a few correlation
#: times of the residual (the smoothing window, 1-2 s), enough for a mean to a few standard errors
MIN_STEADY_S = 5.0
#: a DOF is imbalanced when the nominal model's need differs from what the thrusters held by more than this many
#: standard errors (a 3-sigma two-sided test: 0.3 % false alarms per DOF and bin)
BALANCE_Z = 3.0
#: units of the generalised forces
UNIT = dict(zip(DOF, ("N", "N", "N", "N m", "N m", "N m")))


@dataclass(frozen=True)
class DofBalance:
    """One DOF of a :class:`BalanceBin` (generalised force, N or N m).

    Attributes
    ----------
    held : float
        Mean generalised force of the thrusters (the logged commands through the thrust curves).
    nominal : float
        Mean generalised force the nominal model needs to fly the measured motion.
    corrected : float or None
        The same for the corrected model (nominal plus the significant effects); None when none is significant.
    se : float
        Standard error of the mean imbalance ``held - nominal``.
    unit : str
    """

    held: float
    nominal: float
    corrected: float | None
    se: float
    unit: str

    @property
    def imbalanced(self) -> bool:
        """Whether the nominal model's need differs from what was held by more than ``BALANCE_Z`` standard errors."""
        return bool(abs(self.held - self.nominal) > BALANCE_Z * self.se)

    @property
    def corrected_imbalanced(self) -> bool | None:
        """The same for the corrected model (None without one)."""
        return None if self.corrected is None else bool(abs(self.held - self.corrected) > BALANCE_Z * self.se)

    def to_json(self) -> dict:
        return {"held": self.held, "nominal": self.nominal, "corrected": self.corrected, "se": self.se,
                "unit": self.unit, "imbalanced": self.imbalanced, "corrected_imbalanced": self.corrected_imbalanced}


@dataclass(frozen=True)
class BalanceBin:
    """Steady flight of one part (``fit`` or ``holdout`` runs) in one speed bin.

    Attributes
    ----------
    part : str
    speed : tuple of float
        (lowest, highest) speed of the bin, m/s (norm of u, v, w; the highest may be inf).
    seconds : float
        Steady flight in the bin, s.
    dofs : dict
        DOF name (``X Y Z K M N``) -> :class:`DofBalance`, the DOFs observed in every run of the part.
    """

    part: str
    speed: tuple
    seconds: float
    dofs: dict

    def to_json(self) -> dict:
        return {"part": self.part, "speed_m_s": _bounds_json(self.speed),
                "seconds": self.seconds, "dofs": {d: b.to_json() for d, b in self.dofs.items()}}


@dataclass(frozen=True)
class SteadyBalance:
    """The report's ``steady_balance``: :class:`BalanceBin` per part and speed bin, and the speed bins of steady
    flight that one part holds and the other does not (``uncovered``: (speed, part holding it, seconds))."""

    bins: tuple
    uncovered: tuple
    effects: tuple  # the significant effects in ``corrected``

    def to_json(self) -> dict:
        return {"steady": {"rate_rad_s": STEADY_RATE, "accel_m_s2": STEADY_ACCEL, "min_seconds": MIN_STEADY_S},
                "effects": list(self.effects), "bins": [b.to_json() for b in self.bins],
                "uncovered": [{"speed_m_s": _bounds_json(speed), "part": part, "seconds": s}
                              for speed, part, s in self.uncovered]}


def _bounds_json(speed) -> list:
    """A speed bin (low, high) as the report writes it: [low, high], high null for the open last bin."""
    return [speed[0], speed[1] if np.isfinite(speed[1]) else None]


def steady_samples(prep: Prepared) -> np.ndarray:
    """(n,) bool: samples of ``prep`` in steady flight (module docstring), with every observed DOF's velocity and
    acceleration finite."""
    nu, nu_dot = prep.nu, prep.nu_dot
    ok = np.isfinite(nu).all(axis=1) & np.isfinite(nu_dot[:, :3]).all(axis=1)
    with np.errstate(invalid="ignore"):
        calm = (np.abs(nu[:, 3:]).max(axis=1) < STEADY_RATE) & (np.abs(nu_dot[:, :3]).max(axis=1) < STEADY_ACCEL)
    return ok & calm


def _part_bins(part: str, preps, residuals, hooks) -> tuple:
    """(bins, seconds per speed bin) of one part's runs with their nominal equation-error residuals."""
    observed = np.logical_and.reduce([pr.observed & pr.dof_ok for pr in preps])
    held, nominal, corrected, weight = {}, {}, {}, {}
    seconds = np.zeros(len(SPEED_BINS) - 1)
    for pr, r in zip(preps, residuals):
        T = filter_forces(pr, pr.f @ pr.B.T, held=True)
        w = filter_forces(pr, effect_wrench(pr, hooks)) if hooks else np.zeros_like(T)
        steady = steady_samples(pr) & np.isfinite(r[:, observed]).all(axis=1) & np.isfinite(T).all(axis=1)
        speed = np.linalg.norm(pr.nu[:, :3], axis=1)
        corr_time = max(pr.window_s, pr.dt)
        for b, (lo, hi) in enumerate(zip(SPEED_BINS[:-1], SPEED_BINS[1:])):
            with np.errstate(invalid="ignore"):
                s = steady & (speed >= lo) & (speed < hi)
            if not s.any():
                continue
            seconds[b] += s.sum() * pr.dt
            held.setdefault(b, []).append(T[s])
            nominal.setdefault(b, []).append(T[s] + r[s])
            corrected.setdefault(b, []).append(T[s] + r[s] - w[s])
            weight.setdefault(b, []).append(s.sum() * pr.dt / corr_time)
    out = []
    for b in sorted(held):
        if seconds[b] < MIN_STEADY_S:
            continue
        T, N, C = (np.concatenate(x[b]) for x in (held, nominal, corrected))
        n_eff = max(sum(weight[b]), 1.0)
        dofs = {}
        for i in np.flatnonzero(observed):
            se = float(np.std(N[:, i] - T[:, i]) / np.sqrt(n_eff))
            dofs[DOF[i]] = DofBalance(float(T[:, i].mean()), float(N[:, i].mean()),
                                      float(C[:, i].mean()) if hooks else None, se, UNIT[DOF[i]])
        out.append(BalanceBin(part, (SPEED_BINS[b], SPEED_BINS[b + 1]), float(seconds[b]), dofs))
    return out, seconds


def steady_balance(fit, holdout, fit_residuals, holdout_residuals, hooks=(), effects=()) -> SteadyBalance:
    """The steady-flight balance of the fit and holdout runs (module docstring).

    Parameters
    ----------
    fit, holdout : list of Prepared
        The diagnosis' prepared runs.
    fit_residuals, holdout_residuals : list of (n, 6) ndarray
        Their nominal equation-error residuals (:func:`udrobot_ctrl.gap.attribute.residual`), N and N m.
    hooks : sequence of Hooks
        The significant effects' replay hooks (:func:`udrobot_ctrl.gap.confirm.fitted_hooks`); empty: no corrected
        column.
    effects : sequence of str
        Their names.

    Returns
    -------
    SteadyBalance
    """
    bins, secs = [], {}
    for part, preps, res in (("fit", fit, fit_residuals), ("holdout", holdout, holdout_residuals)):
        if preps:
            b, secs[part] = _part_bins(part, preps, res, tuple(hooks))
            bins += b
    uncovered = []
    if len(secs) == 2:
        for b, (lo, hi) in enumerate(zip(SPEED_BINS[:-1], SPEED_BINS[1:])):
            for part, other in (("fit", "holdout"), ("holdout", "fit")):
                if secs[part][b] >= MIN_STEADY_S and secs[other][b] < MIN_STEADY_S:
                    uncovered.append(((lo, hi), part, float(secs[part][b])))
    return SteadyBalance(tuple(bins), tuple(uncovered), tuple(effects))


def _speed(bounds) -> str:
    """A speed bin's label from its JSON ``speed_m_s`` ([low, high], high null for the last bin)."""
    lo, hi = bounds
    return bin_label(lo, np.inf if hi is None else hi, "m/s")


def _force(v: float, unit: str) -> str:
    return f"{v:+.2f} {unit}"


def balance_lines(balance: dict) -> list:
    """The console's account of a report's ``steady_balance``: per part and speed bin, the DOFs where the nominal
    model's or the corrected model's need differs from what the thrusters held (what was held, what the nominal and
    the corrected model need there), then the speed bins one part holds and the other does not."""
    if not balance or not balance.get("bins"):
        return []
    lines = [f"  steady flight (rates below {balance['steady']['rate_rad_s']:g} rad/s, accelerations below "
             f"{balance['steady']['accel_m_s2']:g} m/s^2): what the thrusters held against what the model needs there"]
    for b in balance["bins"]:
        speed = _speed(b["speed_m_s"])
        off = [(d, x) for d, x in b["dofs"].items() if x["imbalanced"] or x.get("corrected_imbalanced")]
        if not off:
            lines.append(f"    {b['part']}, {speed} ({b['seconds']:.0f} s): balanced within {BALANCE_Z:g} standard "
                         f"errors in {' '.join(b['dofs'])}")
            continue
        parts = []
        for d, x in off:
            corr = f", corrected {_force(x['corrected'], x['unit'])}" if x["corrected"] is not None else ""
            parts.append(f"{d} held {_force(x['held'], x['unit'])}, nominal needs {_force(x['nominal'], x['unit'])}"
                         f"{corr} (se {x['se']:.2g})")
        lines.append(f"    {b['part']}, {speed} ({b['seconds']:.0f} s): " + "; ".join(parts))
    added = [(b, d, x) for b in balance["bins"] for d, x in b["dofs"].items()
             if x.get("corrected_imbalanced") and not x["imbalanced"]]
    if added:
        where = [f"{d} in {b['part']} {_speed(b['speed_m_s'])} (corrected needs "
                 f"{_force(x['corrected'], x['unit'])}, held {_force(x['held'], x['unit'])})" for b, d, x in added]
        lines.append("    the named effects add a steady force the thrusters did not hold (a part of them that steady "
                     "flight contradicts): " + ", ".join(where))
    for u in balance.get("uncovered") or []:
        speed = _speed(u["speed_m_s"])
        other = "holdout" if u["part"] == "fit" else "fit"
        lines.append(f"    the {other} runs hold no steady flight at {speed} (the {u['part']} runs {u['seconds']:.0f} "
                     f"s): a force acting there is not tested by them")
    return lines
