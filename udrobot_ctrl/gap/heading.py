"""Whether the runs can tell a steady current from a body-fixed force: the headings they were flown on.

A steady current is fixed in the world: the force it makes (damping acting on the velocity relative to the water)
turns with the vehicle's heading in the body frame. On runs flown on one heading it is a constant body-frame force,
which a thrust bias or a drag error makes as well: the runs cannot separate them, whatever the velocity sensor.
Runs on other headings can, and a holdout flown on a heading far from the fit runs' is the test a current fitted
on the fit runs must pass (docs/formats/diagnosis.md, ``heading_coverage``).

:func:`heading_coverage` reads the headings of the prepared fit and holdout runs and says which of the three
applies (:data:`READINGS`). :func:`current_parts` fits the current on the fit runs and on the holdout runs apart
and says whether they share one (:data:`CURRENT_READINGS`): one steady current of one size and direction, two
that point the same way off the bow while the vehicle turned (a body-fixed force that turns with the vehicle: a
thrust bias or a drag error, not a current), or two that differ otherwise.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.stats import chi2

from udrobot_ctrl.dynamics.plant import wrap_angle
from udrobot_ctrl.gap.attribute import Attributor, Fit
from udrobot_ctrl.gap.parts import Agreement, agreement

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
#: holdout likelihood ratio (chi-square, 0.99 quantile, 3 degrees of freedom: c_N, c_E, c_D) of the holdout runs'
#: own current against none above which the holdout runs support a current at all
CURRENT_CHI2 = float(chi2.ppf(0.99, 3))
#: horizontal currents slower than this (m/s) are given no direction. Assumed: a tenth of the weakest current the
#: catalogue's tests draw (0.08 m/s) and about a DVL's velocity noise per sample; below it the angle is noise
DIRECTION_SPEED = 0.01
#: two parts' currents whose directions off the bow agree within this (deg), while the vehicle turned at least
#: REVERSED_DEG between the parts, turn with the vehicle. Assumed: half of REVERSED_DEG, so that such currents are
#: closer in the body frame than in the world
BODY_FIXED_DEG = REVERSED_DEG / 2
#: a fitted vertical current faster than this (m/s) stands in for a heave force. Assumed: steady vertical flows in
#: open water (upwelling, mm/s and less) and in a pool are far slower; only eddies and internal waves reach a few
#: cm/s, and they are not steady
VERTICAL_CURRENT_MPS = 0.05
#: the kinds of :class:`CurrentParts` reading
CURRENT_READINGS = ("one current", "no current", "turns with the vehicle", "not one current")


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
class PartCurrent:
    """A steady current fitted on one part of the runs (the fit runs, or the holdout runs).

    Attributes
    ----------
    north, east, down : float
        The current's NED components, m/s.
    speed : float
        Its horizontal speed, m/s.
    toward_deg : float
        The direction it flows toward, deg from north in (-180, 180] (nan below :data:`DIRECTION_SPEED`).
    off_bow_deg : float
        That direction less the part's mean heading, deg in (-180, 180]: where it flows in the body frame
        (0 ahead, 180 aft; nan below :data:`DIRECTION_SPEED`).
    """

    north: float
    east: float
    down: float
    speed: float
    toward_deg: float
    off_bow_deg: float


@dataclass(frozen=True)
class CurrentParts:
    """The steady current fitted on the fit runs and on the holdout runs apart (``heading_coverage.currents``).

    Attributes
    ----------
    fit, holdout : PartCurrent
        Each part's current, fitted alone on its runs' equation error (the holdout's search starts from the fit
        runs' current as well, so it is never worse there).
    world_angle_deg : float
        Angle between the two horizontal currents, deg in [0, 180] (nan when either is below
        :data:`DIRECTION_SPEED`).
    body_angle_deg : float
        Angle between their directions off the bow, deg in [0, 180] (nan likewise).
    holdout_lr : float
        Holdout equation-error likelihood ratio of the holdout runs' own current against none (N_eff of the
        holdout runs; :data:`CURRENT_CHI2`).
    share : float
        The fit runs' current's likelihood gain on the holdout runs (frozen) as a share of the holdout's own
        current's (:class:`udrobot_ctrl.gap.parts.Agreement`); negative when it makes the holdout worse than none.
    reading : str
        One of :data:`CURRENT_READINGS`.
    text : str
        The reading in words, with both currents.
    """

    fit: PartCurrent
    holdout: PartCurrent
    world_angle_deg: float
    body_angle_deg: float
    holdout_lr: float
    share: float
    reading: str
    text: str


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
    currents : CurrentParts or None
        The current fitted on each part apart (:func:`current_parts`); None when the diagnosis did not fit one
        that the channels identify.
    """

    fit: Headings
    holdout: Headings
    all_std_deg: float
    separation_deg: float
    reading: str
    text: str
    currents: CurrentParts | None = None

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
    sep = abs(_wrap_deg(f.mean_deg - h.mean_deg))
    if round(both.std_deg, 1) < ONE_HEADING_STD_DEG:  # judged as printed (0.1 deg): 19.96 is not 'under 20.0'
        reading = READINGS[0]
        text = (f"every run holds one heading (mean {f.mean_deg:.0f} deg, spread {both.std_deg:.1f} deg): a steady "
                "current is a body-fixed force on these runs, which a thrust bias or a drag error makes as well; "
                "missing: a run on another heading (the reverse transect) or a velocity through the water")
    elif sep >= REVERSED_DEG:
        reading = READINGS[1]
        text = (f"the holdout runs head {sep:.0f} deg away from the fit runs (mean {h.mean_deg:.0f} against "
                f"{f.mean_deg:.0f} deg): a steady current fitted on the fit runs turns with the vehicle there, so "
                "the holdout tests its direction")
    else:
        reading = READINGS[2]
        text = (f"the headings vary (spread {both.std_deg:.1f} deg; holdout {sep:.0f} deg from the fit runs): a "
                "steady current's body-frame force turns with them, which the fit can use")
    return HeadingCoverage(f, h, both.std_deg, sep, reading, text)


def part_current(c, heading_deg: float) -> PartCurrent:
    """A current ``c`` (NED, m/s) fitted on runs whose mean heading is ``heading_deg`` (deg)."""
    north, east, down = (float(v) for v in c)
    speed = math.hypot(north, east)
    if speed < DIRECTION_SPEED:
        return PartCurrent(north, east, down, speed, math.nan, math.nan)
    toward = math.degrees(math.atan2(east, north))
    return PartCurrent(north, east, down, speed, toward, _wrap_deg(toward - heading_deg))


def _wrap_deg(a: float) -> float:
    """``a`` (deg) wrapped into (-180, 180]."""
    return math.degrees(float(wrap_angle(math.radians(a))))


def _flow(c: PartCurrent) -> str:
    """One part's current in words."""
    where = (f"{c.speed:.3f} m/s toward {c.toward_deg % 360:03.0f} deg ({c.off_bow_deg:+.0f} deg off the bow)"
             if math.isfinite(c.toward_deg) else f"{c.speed:.3f} m/s across")
    return f"{where}, down {c.down:+.3f} m/s"


def read_currents(fit: PartCurrent, holdout: PartCurrent, turned_deg: float, ag: Agreement) -> tuple:
    """What the fit and holdout runs' currents say, ``(reading, text, world_angle_deg, body_angle_deg)``.

    Parameters
    ----------
    fit, holdout : PartCurrent
        The current fitted on each part.
    turned_deg : float
        Angle between the two parts' mean headings, deg (:attr:`HeadingCoverage.separation_deg`).
    ag : Agreement
        The holdout's own current against none (:data:`CURRENT_CHI2`), and the share of its gain the fit runs'
        current reaches there.

    Returns
    -------
    tuple
        One of :data:`CURRENT_READINGS`, its text, and the angles between the currents in the world and off the
        bow (deg; nan when either is slower than :data:`DIRECTION_SPEED`). ``one current`` needs the fit runs'
        current to reach :data:`~udrobot_ctrl.gap.parts.SAME_SHARE` of the holdout's own gain there *and* the two
        horizontal directions to lie within :data:`REVERSED_DEG` (a share reached through the vertical part alone
        is not one current); a vertical part beyond :data:`VERTICAL_CURRENT_MPS` is named as a heave force's
        stand-in.
    """
    world = abs(_wrap_deg(fit.toward_deg - holdout.toward_deg))
    body = abs(_wrap_deg(fit.off_bow_deg - holdout.off_bow_deg))
    both = f"fit runs {_flow(fit)}; holdout runs {_flow(holdout)}"
    lr, gain = ag.holdout_lr, ag.words()
    opposed = world > REVERSED_DEG  # False when a direction is undefined (nan)
    vertical = max(abs(fit.down), abs(holdout.down))
    heave = (f"; its vertical part ({vertical:.3f} m/s) is beyond a steady vertical flow (assumed at most "
             f"{VERTICAL_CURRENT_MPS:.2f} m/s): it stands in for a heave force (a buoyancy or vertical thrust error)"
             if vertical > VERTICAL_CURRENT_MPS else "")
    if lr <= CURRENT_CHI2:
        return (CURRENT_READINGS[1], f"{both}: the holdout runs support no current (likelihood ratio of their own "
                f"against none {lr:.1f} <= {CURRENT_CHI2:.1f})", world, body)
    if ag.agrees and not opposed:
        return CURRENT_READINGS[0], f"{both}: one current over both parts ({gain}){heave}", world, body
    if turned_deg >= REVERSED_DEG and body <= BODY_FIXED_DEG:
        return (CURRENT_READINGS[2], f"{both}: not one current ({gain}); off the bow they point the same way "
                f"({body:.0f} deg apart) while the vehicle turned {turned_deg:.0f} deg, so the force fitted as a "
                "current turns with the vehicle: a body-fixed force (a thrust bias or a drag error along the "
                f"track), not a steady current{heave}", world, body)
    apart = f"; their horizontal directions are {world:.0f} deg apart" if opposed else ""
    return (CURRENT_READINGS[3], f"{both}: not one current ({gain}{apart}); no steady current of one size and "
            f"direction fits both parts{heave}", world, body)


def current_parts(att_h: Attributor, fitted: Fit, coverage: HeadingCoverage) -> CurrentParts:
    """The steady current fitted on the fit runs (``fitted``, the diagnosis' single fit there) set beside the one
    fitted on the holdout runs (``att_h``), and whether they are one current (:func:`read_currents`).

    Parameters
    ----------
    att_h : Attributor
        The holdout runs' equation-error stack (``n_eff`` set).
    fitted : Fit
        The current alone fitted on the fit runs (its shape is the current, NED m/s).
    coverage : HeadingCoverage
        The two parts' headings.

    Returns
    -------
    CurrentParts
    """
    c_fit = tuple(fitted.shapes[CURRENT])
    own = att_h.best_shape(CURRENT, seeds=(c_fit,))
    ag = agreement(att_h, fitted, own)
    f = part_current(c_fit, coverage.fit.mean_deg)
    h = part_current(own.shapes[CURRENT], coverage.holdout.mean_deg)
    reading, text, world, body = read_currents(f, h, coverage.separation_deg, ag)
    return CurrentParts(f, h, world, body, ag.holdout_lr, ag.share, reading, text)
