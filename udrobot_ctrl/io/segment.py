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
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from udrobot_ctrl.io import files


@dataclass(frozen=True)
class Launch:
    """One release and its decay: sample indices [start, stop), release amplitude (signal units) and rest value."""

    start: int
    stop: int
    t_release: float
    amplitude: float
    rest: float


def _runs(mask: np.ndarray) -> list:
    """(start, stop) index pairs of True runs."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def find_launches(t, y, min_amplitude_frac=0.3, still_frac=0.05, hold_s=0.3, end_frac=0.05) -> list:
    """Releases and decays in a free-decay signal.

    Parameters
    ----------
    t : (n,) array_like
        Strictly increasing times, s.
    y : (n,) array_like
        Angle (rad) or displacement (m); nan samples never count as held.
    min_amplitude_frac, still_frac, hold_s, end_frac : float
        See the module docstring.

    Returns
    -------
    list of Launch
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
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
                                   rest=rest))
    return launches


def write_launches(t, y, launches, out_dir, stem: str, column: str, protect=()) -> list:
    """Write ``STEM_launchK.csv`` with columns ``t,COLUMN`` (t = 0 at release) for each launch; atomic, no overwrite.

    Returns the written paths. ``column`` is ``theta`` (pendulum, rad) or ``y`` (spring, m).
    """
    if column not in ("theta", "y"):
        raise ValueError(f"launch column must be 'theta' (pendulum) or 'y' (spring), got {column!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    paths = []
    for k, launch in enumerate(launches, start=1):
        path = out_dir / f"{stem}_launch{k}.csv"
        if path.exists():
            raise ValueError(f"{path}: exists; refusing to overwrite a launch file")
        sl = slice(launch.start, launch.stop)
        with files.open_atomic(path, "w", force=False, protect=protect) as fh:
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(["t", column])
            for ti, yi in zip(t[sl] - t[launch.start], y[sl]):
                writer.writerow([repr(float(ti)), "" if np.isnan(yi) else repr(float(yi))])
        paths.append(path)
    return paths
