"""Whether the runs can tell a steady current from a body-fixed force: the headings they were flown on.

A steady current is fixed in the world: the force it makes (damping acting on the velocity relative to the water)
turns with the vehicle's heading in the body frame. On runs flown on one heading it is a constant body-frame force,
which a thrust bias or a drag error makes as well: the runs cannot separate them, whatever the velocity sensor.
Runs on other headings can, and a holdout flown on a heading far from the fit runs' is the test a current fitted
on the fit runs must pass (docs/formats/diagnosis.md, ``heading_coverage``).

:func:`heading_coverage` reads the headings of the prepared fit and holdout runs and says which of the three
applies (:data:`READINGS`).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from udrobot_ctrl.dynamics.plant import wrap_angle

#: runs whose headings spread less than this (circular standard deviation, deg) hold one heading: a world-fixed
#: current is then a body-fixed force to within sin(20 deg) = 0.34 of its size across track. Assumed (a
#: judgement of when a rotated current is still a look-alike of a constant force), not measured
ONE_HEADING_STD_DEG = 20.0
#: a holdout whose mean heading is at least this far (deg) from the fit runs' turns the fit runs' current by as
#: much: its along-track part changes sign, so the holdout tests the current's direction
REVERSED_DEG = 90.0
#: the catalogue effect the headings speak for: a world-fixed force, the only one of the catalogue
CURRENT = "water_current"
#: the kinds of :class:`HeadingCoverage` reading
READINGS = ("one heading", "holdout reversed", "headings vary")


@dataclass(frozen=True)
class Headings:
    """The headings of a set of runs (the fit runs, or the holdout runs).

    Attributes
    ----------
    mean_deg : float
        Circular mean of the measured heading psi over their samples, deg in (-180, 180].
    std_deg : float
        Circular standard deviation, deg (sqrt(-2 ln R), R the mean resultant length).
    samples : int
        Samples with a measured heading.
    """

    mean_deg: float
    std_deg: float
    samples: int


@dataclass(frozen=True)
class HeadingCoverage:
    """What the headings of the runs let a diagnosis say of a steady current (the report's ``heading_coverage``).

    Attributes
    ----------
    fit, holdout : Headings
        The fit runs' and the holdout runs' headings.
    all_std_deg : float
        Circular standard deviation of the headings of every run, deg.
    separation_deg : float
        Angle between the fit and the holdout runs' mean headings, deg in [0, 180].
    reading : str
        One of :data:`READINGS`: ``one heading`` (a current cannot be told from a body-fixed force on these
        runs), ``holdout reversed`` (the holdout tests the direction of a current fitted on the fit runs) or
        ``headings vary``.
    text : str
        The reading in words, with the measurement that is missing when it is ``one heading``.
    """

    fit: Headings
    holdout: Headings
    all_std_deg: float
    separation_deg: float
    reading: str
    text: str

    def to_json(self) -> dict:
        return asdict(self)


def _psi(pr) -> np.ndarray:
    """The measured heading of a prepared run (rad), without the samples where it was not logged."""
    psi = np.asarray(pr.meas.get("psi", np.full(0, np.nan)), float)
    return psi[np.isfinite(psi)]


def headings(psi_runs) -> Headings | None:
    """Circular mean and standard deviation of the headings ``psi_runs`` (a sequence of (n,) arrays, rad);
    None without a sample."""
    psi = np.concatenate([np.asarray(p, float) for p in psi_runs]) if len(psi_runs) else np.zeros(0)
    if psi.size == 0:
        return None
    z = np.mean(np.exp(1j * psi))
    r = min(float(abs(z)), 1.0)
    std = math.degrees(math.sqrt(-2.0 * math.log(r))) if r > 0 else math.inf
    return Headings(math.degrees(float(np.angle(z))), std, int(psi.size))


def heading_coverage(fit, holdout) -> HeadingCoverage | None:
    """What the headings of the prepared ``fit`` and ``holdout`` runs (:class:`udrobot_ctrl.gap.data.Prepared`,
    their measured ``psi``) let the diagnosis say of a steady current; None when either has no measured heading.

    Parameters
    ----------
    fit, holdout : sequence of Prepared
        The diagnosis' fit and holdout runs.

    Returns
    -------
    HeadingCoverage or None
    """
    psi_fit, psi_holdout = [_psi(pr) for pr in fit], [_psi(pr) for pr in holdout]
    f, h = headings(psi_fit), headings(psi_holdout)
    if f is None or h is None:
        return None
    both = headings(psi_fit + psi_holdout)
    sep = math.degrees(abs(float(wrap_angle(math.radians(f.mean_deg - h.mean_deg)))))
    if both.std_deg < ONE_HEADING_STD_DEG:
        reading = READINGS[0]
        text = (f"every run holds one heading (mean {f.mean_deg:.0f} deg, spread {both.std_deg:.0f} deg): a steady "
                "current is a body-fixed force on these runs, which a thrust bias or a drag error makes as well; "
                "missing: a run on another heading (the reverse transect) or a velocity through the water")
    elif sep >= REVERSED_DEG:
        reading = READINGS[1]
        text = (f"the holdout runs head {sep:.0f} deg away from the fit runs (mean {h.mean_deg:.0f} against "
                f"{f.mean_deg:.0f} deg): a steady current fitted on the fit runs turns with the vehicle there, so "
                "the holdout tests its direction")
    else:
        reading = READINGS[2]
        text = (f"the headings vary (spread {both.std_deg:.0f} deg; holdout {sep:.0f} deg from the fit runs): a "
                "steady current's body-frame force turns with them, which the fit can use")
    return HeadingCoverage(f, h, both.std_deg, sep, reading, text)
