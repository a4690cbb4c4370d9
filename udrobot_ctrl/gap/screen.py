"""Which runs a diagnosis can use: runs the plant cannot answer are reported, not diagnosed.

Two kinds of run are screened out before the diagnosis (docs/formats/diagnosis.md, *Runs that are not
diagnosed*):

- :class:`Unexcited` (:func:`unexcited_runs`): no actuator command leaves ``UNEXCITED_COMMAND`` of its capacity for
  the whole run, so the log holds no input for a model to answer;
- :class:`Unrepresented` (:func:`unrepresented_runs`): the converter found no row the plant represents (the sidecar's
  ``cut.kept`` is null: the whole log at the surface, disarmed or upside down; docs/formats/runlog.md), so whatever
  the replay misses there is the free surface, the deck or the idle motors, not an effect of the catalogue.

:func:`screen_runs` applies both and lists every reason that applies to a run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from udrobot_ctrl.dynamics.plant import PlantParameters
from udrobot_ctrl.gap.data import actuators

#: a run whose every actuator command stays within this fraction of its capacity for the whole run is unexcited:
#: nothing was commanded, so whatever moved the vehicle (a hand, the cable, waves) is not in the log
UNEXCITED_COMMAND = 0.01


def run_label(run):
    """File name of a run; a split part keeps its tag (``a.csv[last 1/3]``, whose '/' is not a folder)."""
    if not run.path:
        return "run"
    base, bracket, tag = run.path.partition("[")
    return Path(base).name + bracket + tag


@dataclass(frozen=True)
class Unexcited:
    """A run with no commanded excitation (:func:`unexcited_runs`): reported, not diagnosed."""

    run: str
    max_command: float  # largest |command| over the run, as a fraction of the actuator's capacity
    depth_span_m: float  # range of the logged depth, m (nan when z is not logged)

    #: what the run lacks, in the notes' ``not diagnosed (<kind>)``, and the report field that lists such runs
    kind = "no excitation"
    field = "unexcited_runs"

    def reason(self) -> str:
        depth = (f", depth moving {100 * self.depth_span_m:.1f} cm" if math.isfinite(self.depth_span_m) else "")
        return (f"{self.run}: no excitation (the largest actuator command of the whole run is "
                f"{100 * self.max_command:.2g}% of its capacity, at most {100 * UNEXCITED_COMMAND:g}% counts as none"
                f"{depth}): nothing was commanded, so the log holds no input for a model "
                f"to answer and whatever moved the vehicle is not in it; fly commanded manoeuvres (steps, sweeps) to "
                f"diagnose, or use udrobot-ctrl identify for free-decay launches")

    def to_json(self) -> dict:
        return {"run": self.run, "max_command_fraction": self.max_command, "depth_span_m": self.depth_span_m,
                "reason": self.reason()}


@dataclass(frozen=True)
class Unrepresented:
    """A run of which the converter kept no stretch (:func:`unrepresented_runs`): reported, not diagnosed."""

    run: str
    invalid_share: dict  # converter's check -> fraction of the run's rows failing it (the sidecar's cut.invalid_share)

    kind = "not represented by the plant"
    field = "unrepresented_runs"

    def reason(self) -> str:
        failed = "; ".join(f"{check}: {100 * share:.0f} % of the rows" for check, share in self.invalid_share.items()
                           if share > 0) or "every row fails a check"
        return (f"{self.run}: not represented by the plant (the converter kept no stretch of it: {failed}); the model "
                f"is a submerged, armed, upright vehicle, so a replay of this run misses the free surface, the deck "
                f"or the idle motors, which no catalogue effect stands for; a log with a submerged, armed stretch is "
                f"diagnosed on that stretch (convert --no-cut to diagnose this one as it is)")

    def to_json(self) -> dict:
        return {"run": self.run, "invalid_share": dict(self.invalid_share), "reason": self.reason()}


def unexcited_runs(runs, p: PlantParameters) -> list:
    """Per run, an :class:`Unexcited` when no actuator command leaves ``UNEXCITED_COMMAND`` of its capacity during
    the whole run (e.g. every PWM at 1500 us), else None.

    The capacity is each thruster's larger thrust limit (``thrust_i``, ``pwm_i`` converted by the thruster curve),
    or for a commanded wrench (``tau_*``) what the thrusters together give along each DOF. An actuator whose
    capacity the model does not give (a wrench DOF of a model without thrusters: a vehicle logged after its
    allocation) excites the run whenever it is not zero.
    """
    cap_t = np.maximum(p.f_max, -p.f_min)
    out = []
    for r in runs:
        f = np.abs(np.nan_to_num(actuators(r, p)[0]))
        cap = cap_t if r.input_kind in ("thrust", "pwm") else np.abs(p.T) @ cap_t
        known = cap > 0
        frac = float(np.max(f[:, known] / cap[known])) if f.size and known.any() else 0.0
        if f.size and np.any(f[:, ~known] > 0):
            frac = math.inf  # commanded, against a capacity the model does not know
        z = np.asarray(r.channels.get("z", np.zeros(0)), float)
        z = z[np.isfinite(z)]
        span = float(np.ptp(z)) if z.size else float("nan")
        out.append(Unexcited(run_label(r), frac, span) if frac <= UNEXCITED_COMMAND else None)
    return out


def unrepresented_runs(runs) -> list:
    """Per run, an :class:`Unrepresented` when its sidecar says the converter kept no stretch (``cut`` present with
    ``kept`` null), else None. A run without a ``cut`` record (a pool CSV, a run converted without cutting) is not
    judged here: the depth below which a vehicle is "at the surface" depends on the site, and a pool run may sit
    shallower than a field log's threshold."""
    out = []
    for r in runs:
        cut = (r.metadata or {}).get("cut")
        missing = isinstance(cut, dict) and "kept" in cut and cut["kept"] is None
        out.append(Unrepresented(run_label(r), dict(cut.get("invalid_share") or {})) if missing else None)
    return out


#: the reasons a run is not diagnosed, in the order a run's reasons are listed (each kind names its report field)
KINDS = (Unrepresented, Unexcited)


def screen_runs(runs, p: PlantParameters) -> list:
    """Per run, the tuple of reasons it is not diagnosed (its :class:`Unrepresented`, then its :class:`Unexcited`:
    a log at the surface with every PWM at neutral is both), empty when it can be diagnosed."""
    return [tuple(x for x in pair if x is not None)
            for pair in zip(unrepresented_runs(runs), unexcited_runs(runs, p))]


__all__ = ["KINDS", "UNEXCITED_COMMAND", "Unexcited", "Unrepresented", "run_label", "screen_runs", "unexcited_runs",
           "unrepresented_runs"]
