"""Automatic launch segmentation for free-decay tests (pendulum angle, spring displacement).

A launch test holds the body at a displaced position, releases it and records the decay; a log usually
holds several launches. :func:`find_launches` finds each release (the end of a hold) and the decay after
it; :func:`write_launches` writes one CSV per launch with columns ``t,theta`` or ``t,y`` (t = 0 at the
release), the inputs the identification CLI accepts.

Method (all thresholds relative, so units do not matter):
1. rest = median of the signal over the whole log (a decay log spends most time near rest);
2. a *hold* is a stretch of at least ``hold_s`` where |y - rest| > ``min_amplitude_frac`` max|y - rest|
   and |dy/dt| < ``still_frac`` max|dy/dt| (speed from a centred difference);
3. the release is the last sample of the hold still at the hold level (within 3 sigma of its first half,
   at least 0.1 % of the amplitude): released from rest, the body leaves the hold with zero speed;
   the decay ends at the next hold, or when the running peak
   |y - rest| over one estimated period falls below ``end_frac`` times the release amplitude, or at the end.

Field logs (a dive, not a rig): two more rules keep only what a free-decay identification can use.

* Angles are unwrapped first (``angle=True``; the convert CLI sets it for phi, theta, psi): a roll trace
  through +-180 deg jumps by 2 pi, which looks like a hold and a release; the written launch holds the
  unwrapped angle relative to nothing else (the identification subtracts the rest offset).
* Only a *free* vehicle decays freely: with a ``free`` mask (:func:`idle_mask`: every thruster inside its
  dead band, or zero commanded thrust / wrench) a launch starts only at a free release and ends at the first
  powered sample; a decay cut shorter than ``min_free_periods`` estimated periods is dropped. A powered
  stretch never yields a launch, however decay-like it looks.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from udrobot_ctrl.dynamics.thrusters import PWM_NEUTRAL, load_curve
from udrobot_files import output as files

#: Thrust (N) and wrench (N, N m) magnitudes below which a thruster / the vehicle counts as idle (assumed:
#: ~1 % of a T200's 12 V maximum, below what moves a 10 kg ROV measurably within one decay period).
IDLE_THRUST_N = 0.3
IDLE_WRENCH = 0.3


def pwm_deadband_us(curve_name: str = "t200") -> float:
    """Half-width (us) of the narrowest zero band of the thruster curve over its voltages (T200: 27.7 us at 20 V).

    A PWM within it of 1500 us gives no thrust at any supply voltage (Blue Robotics bollard data).
    """
    c = load_curve(curve_name)
    return float(min(np.min(c.fwd_d0), np.min(c.rev_d0)))


def idle_mask(input_kind: str, inputs, deadband_us: float | None = None) -> np.ndarray:
    """Per row, True when every actuator is idle (the vehicle is free to decay).

    Parameters
    ----------
    input_kind : {'pwm', 'thrust', 'tau'}
        Kind of the commanded inputs (``udrobot-run/1``).
    inputs : (n, k) array_like
        Commands: PWM (us), thrusts (N) or a body wrench (N, N m).
    deadband_us : float, optional
        PWM half dead band around 1500 us (default :func:`pwm_deadband_us`).

    Returns
    -------
    (n,) bool ndarray
        A row with any nan command is not idle (unknown), except when no command is logged at all (every
        value nan: a rig without thrusters, all rows free).
    """
    u = np.asarray(inputs, dtype=float)
    if u.ndim != 2:
        raise ValueError(f"inputs must be (n, k), got shape {u.shape}")
    if u.shape[1] == 0 or not np.isfinite(u).any():
        return np.ones(u.shape[0], dtype=bool)
    if input_kind == "pwm":
        band = pwm_deadband_us() if deadband_us is None else float(deadband_us)
        idle = np.abs(u - PWM_NEUTRAL) <= band
    elif input_kind == "thrust":
        idle = np.abs(u) <= IDLE_THRUST_N
    elif input_kind == "tau":
        idle = np.abs(u) <= IDLE_WRENCH
    else:
        raise ValueError(f"input kind must be pwm, thrust or tau, got {input_kind!r}")
    return np.all(idle & np.isfinite(u), axis=1)


@dataclass(frozen=True)
class Launch:
    """One release and its decay: sample indices [start, stop), release amplitude (signal units), rest value and
    the estimated period (s; the decay's duration when it shows fewer than three zero crossings)."""

    start: int
    stop: int
    t_release: float
    amplitude: float
    rest: float
    period: float = float("nan")


def _runs(mask: np.ndarray) -> list:
    """(start, stop) index pairs of True runs."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def unwrap_angle(y) -> np.ndarray:
    """Angle (rad) unwrapped over its finite samples (nan kept): jumps of more than pi become continuous."""
    y = np.asarray(y, dtype=float).copy()
    ok = np.isfinite(y)
    y[ok] = np.unwrap(y[ok])
    return y


def find_launches(t, y, min_amplitude_frac=0.3, still_frac=0.05, hold_s=0.3, end_frac=0.05, *,
                  angle: bool = False, free=None, min_free_periods: float = 1.5, lookback_s: float = 3.0) -> list:
    """Releases and decays in a free-decay signal.

    Parameters
    ----------
    t : (n,) array_like
        Strictly increasing times, s.
    y : (n,) array_like
        Angle (rad) or displacement (m); nan samples never count as held.
    min_amplitude_frac, still_frac, hold_s, end_frac : float
        See the module docstring.
    angle : bool
        ``y`` is an angle: unwrap it first (:func:`unwrap_angle`); launches then index the unwrapped trace
        (write them with :func:`write_launches` on ``unwrap_angle(y)``).
    free : (n,) bool array_like, optional
        True where the vehicle is free (thrusters idle, :func:`idle_mask`); None = free everywhere (a rig).
        Each free stretch is searched on its own, with the ``lookback_s`` seconds before it (the hold may be
        powered: thrusters holding the vehicle, released by going idle); thresholds are relative to that
        window, so large powered manoeuvres elsewhere in the dive do not hide a launch.
    min_free_periods : float
        With ``free``: shortest decay kept, in estimated periods, when power comes back before the decay ends.
    lookback_s : float
        With ``free``: seconds before a free stretch searched for the hold, s.

    Returns
    -------
    list of Launch
    """
    t = np.asarray(t, dtype=float)
    y = unwrap_angle(y) if angle else np.asarray(y, dtype=float)
    if free is None:
        return _find(t, y, min_amplitude_frac, still_frac, hold_s, end_frac)
    free = np.asarray(free, dtype=bool)
    if free.shape != t.shape:
        raise ValueError(f"free mask has shape {free.shape}, expected {t.shape}")
    out = []
    prev_end = 0
    for a, b in _runs(free):
        w0 = max(prev_end, int(np.searchsorted(t, t[a] - lookback_s)))
        prev_end = b
        for ln in _find(t[w0:b], y[w0:b], min_amplitude_frac, still_frac, hold_s, end_frac):
            start, stop = ln.start + w0, ln.stop + w0
            if start + 1 < a:
                continue  # released while the thrusters still ran: not a free decay
            if stop == b and b < t.size and t[stop - 1] - t[start] < min_free_periods * ln.period:
                continue  # power came back before enough of the decay was recorded
            out.append(Launch(start, stop, ln.t_release, ln.amplitude, ln.rest, ln.period))
    return out


def _find(t, y, min_amplitude_frac, still_frac, hold_s, end_frac) -> list:
    """The segmentation of the module docstring on one window (indices relative to it)."""
    if t.size < 5 or not np.any(np.isfinite(y)):
        return []
    rest = float(np.nanmedian(y))
    d = y - rest
    amp_max = np.nanmax(np.abs(d))
    if not amp_max > 0:
        return []
    v = np.gradient(np.where(np.isfinite(y), y, rest), t)
    v_max = np.nanmax(np.abs(v))
    held = (np.abs(d) > min_amplitude_frac * amp_max) & (np.abs(v) < still_frac * v_max) & np.isfinite(y)
    holds = [(a, b) for a, b in _runs(held) if t[b - 1] - t[a] >= hold_s]
    launches = []
    for k, (a, b) in enumerate(holds):
        # released from rest, the body leaves the hold slowly (zero initial speed): step back to the last
        # sample still at the hold level (within 3 sigma of the hold, at least 0.1 % of the amplitude)
        level = np.nanmedian(y[a:b])
        tol = max(3 * np.nanstd(y[a: max(b - int(0.5 * (b - a)), a + 1)]), 1e-3 * abs(level - rest))
        release = b - 1
        while release > a and abs(y[release] - level) > tol:
            release -= 1
        limit = holds[k + 1][0] if k + 1 < len(holds) else t.size
        amplitude = abs(d[release])
        # period estimate from zero crossings after release
        seg = d[release:limit]
        crossings = np.flatnonzero(np.diff(np.signbit(seg[np.isfinite(seg)])))
        period = 2 * np.median(np.diff(t[release + crossings])) if crossings.size > 2 else (t[limit - 1] - t[release])
        stop = limit
        window = max(int(np.ceil(period / np.median(np.diff(t)))), 1)
        peak = np.abs(seg)
        for i in range(window, seg.size, max(window // 4, 1)):
            if np.nanmax(peak[i - window: i]) < end_frac * amplitude:
                stop = release + i
                break
        if stop - release >= 5:
            launches.append(Launch(start=release, stop=stop, t_release=float(t[release]), amplitude=float(amplitude),
                                   rest=rest, period=float(period)))
    return launches


def write_launches(t, y, launches, out_dir, stem: str, column: str, angle: bool = False, protect=()) -> list:
    """Write ``STEM_launchK.csv`` with columns ``t,COLUMN`` (t = 0 at release) for each launch; atomic, no overwrite.

    Returns the written paths. ``column`` is ``theta`` (pendulum, rad) or ``y`` (spring, m). With ``angle``
    the trace is unwrapped (as :func:`find_launches` with ``angle=True``) and each launch shifted by the whole
    turns of its rest angle, so it lies within +-pi around its rest (a decay after a full roll is written
    about 0, not 2 pi).
    """
    if column not in ("theta", "y"):
        raise ValueError(f"launch column must be 'theta' (pendulum) or 'y' (spring), got {column!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = np.asarray(t, dtype=float)
    y = unwrap_angle(y) if angle else np.asarray(y, dtype=float)
    paths = []
    for k, launch in enumerate(launches, start=1):
        path = out_dir / f"{stem}_launch{k}.csv"
        if path.exists():
            raise ValueError(f"{path}: exists; refusing to overwrite a launch file")
        sl = slice(launch.start, launch.stop)
        with files.open_atomic(path, "w", force=False, protect=protect) as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(["t", column])
            turns = 2 * np.pi * np.round(launch.rest / (2 * np.pi)) if angle else 0.0
            for ti, yi in zip(t[sl] - t[launch.start], y[sl] - turns):
                writer.writerow([repr(float(ti)), "" if np.isnan(yi) else repr(float(yi))])
        paths.append(path)
    return paths
