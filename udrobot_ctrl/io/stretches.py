"""Cut the stretches of a converted run that the plant cannot represent (``[cut]`` in a mapping).

The vehicle model describes a submerged, upright vehicle under thrust. A field log also holds the launch at the
surface, the boat deck, disarmed minutes and, rarely, a capsized vehicle. A row is *invalid* when

- ``z`` < ``min_depth`` (at or near the surface, or out of the water: depth around or above 0 m; the threshold
  is an assumption stated in the notes; rows without a depth are not judged),
- the ``armed`` column is 0 (disarmed: the thrusters do not follow the controller),
- the body z axis points up (cos(phi) cos(theta) < 0) for longer than ``upside_down_s``.

Every contiguous stretch of valid rows that a replay can start from is kept, each as one *segment* of the run (the
``segment`` column of docs/formats/runlog.md, numbered 1, 2, ... in time order); the rows cut between them are not
written. ``t`` stays the converted log's t (it is not shifted: the notes, the sidecar's ``cut`` record and the file
give the same times, and t increases strictly across segments). A valid stretch is too short to keep when it holds
fewer than :data:`MIN_SEGMENT_ROWS` rows or spans :data:`MIN_SEGMENT_S` or less: no replay window of the
diagnoser's default length opens on it (see those constants); if no valid stretch is that long, the longest one is
kept alone, with a note. Every stretch left out is listed with its times and reasons. A run without any valid row
is kept whole with a prominent ``cut: WARNING`` note (a log entirely at the surface still converts). The same
verdict goes into the sidecar's ``cut`` field (:meth:`CutResult.record`), which ``diagnose`` reads to leave such a
run out.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .mapping import CutSpec
from .runlog import SEGMENT, Run


@dataclass(frozen=True)
class Stretch:
    """Rows [start, stop) of a run and why they are valid or cut.

    Attributes
    ----------
    start, stop : int
        Row indices (stop exclusive).
    t_start, t_stop : float
        Times of the first and last row, s (the run's t before cutting).
    reasons : tuple of str
        Why the rows are cut (empty for a valid stretch).
    """

    start: int
    stop: int
    t_start: float
    t_stop: float
    reasons: tuple = ()

    @property
    def duration(self) -> float:
        """t_stop - t_start, s."""
        return self.t_stop - self.t_start


#: a replay window of the diagnoser's default length, s (``diagnose --window`` and ``simulate --windows`` default)
DEFAULT_WINDOW_S = 8.0
#: a segment kept spans more than this, s: ``udrobot_ctrl.gap.shrink.window_starts`` opens a window only where a
#: quarter of it fits in the run (and ``check_window`` refuses a window of 4 x the longest run or more), so a stretch
#: of a quarter of the default window or less gives no replay window of that length
MIN_SEGMENT_S = DEFAULT_WINDOW_S / 4
#: fewest rows of a segment kept: ``udrobot_ctrl.gap.data.prepare`` refuses a run of fewer (its Savitzky-Golay
#: derivatives and the smoother need them)
MIN_SEGMENT_ROWS = 20
#: reason of a valid stretch left out because no replay can start on it
TOO_SHORT = (f"valid but too short to replay ({MIN_SEGMENT_S:g} s or less, a quarter of the default "
             f"{DEFAULT_WINDOW_S:g} s replay window, or under {MIN_SEGMENT_ROWS} rows)")


@dataclass(frozen=True)
class CutResult:
    """What :func:`cut_run` kept and cut.

    Attributes
    ----------
    run : Run
        The kept segments as one run with a ``segment`` column (the input run when nothing was cut, or nothing was
        valid).
    segments : tuple of Stretch
        The kept stretches, in order (segment k + 1 is ``segments[k]``); empty when no row is valid (the run is then
        kept whole).
    cut : tuple of Stretch
        Stretches left out (invalid ones with reasons, valid ones too short to replay with :data:`TOO_SHORT`).
    notes : list of str
        ``cut:`` lines for the sidecar notes.
    invalid_share : dict
        Check -> fraction of the input run's rows failing it (every check applied, 0 for one no row fails).
    n_rows : int
        Rows of the input run.
    """

    run: Run
    segments: tuple
    cut: tuple
    notes: list
    invalid_share: dict
    n_rows: int

    @property
    def kept(self) -> Stretch | None:
        """The span from the first kept row to the last (rows cut inside it are not in the run), None when no row
        is valid."""
        if not self.segments:
            return None
        a, b = self.segments[0], self.segments[-1]
        return Stretch(a.start, b.stop, a.t_start, b.t_stop)

    @property
    def kept_duration(self) -> float:
        """Sum of the kept segments' durations, s (0 when none)."""
        return float(sum(s.duration for s in self.segments))

    def record(self) -> dict:
        """The sidecar's ``cut`` field (docs/formats/runlog.md): the checks applied with the fraction of rows failing
        each, and what was kept: ``t_start``, ``t_stop`` (the converted log's t, s) and ``rows`` [first, last] of
        the span from the first kept row to the last, ``of`` rows, and ``segments``: per kept segment its number,
        ``t_start``, ``t_stop`` and ``rows`` [first, last]; None when no row passes (the run kept whole, not
        represented by the plant)."""
        kept = self.kept
        if kept is not None:
            kept = {"t_start": kept.t_start, "t_stop": kept.t_stop, "rows": [kept.start, kept.stop - 1],
                    "of": self.n_rows,
                    "segments": [{"segment": k + 1, "t_start": s.t_start, "t_stop": s.t_stop,
                                  "rows": [s.start, s.stop - 1]} for k, s in enumerate(self.segments)]}
        return {"invalid_share": dict(self.invalid_share), "kept": kept}


def replayable(stretch: Stretch) -> bool:
    """True when a replay window can start on ``stretch``: at least :data:`MIN_SEGMENT_ROWS` rows spanning more than
    :data:`MIN_SEGMENT_S`."""
    return stretch.stop - stretch.start >= MIN_SEGMENT_ROWS and stretch.duration > MIN_SEGMENT_S


def _runs(mask: np.ndarray) -> list:
    """[start, stop) index pairs of the True runs of a boolean mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def invalid_rows(run: Run, spec: CutSpec) -> dict:
    """Reason -> boolean mask of the rows the plant cannot represent (see module docstring)."""
    masks = {}
    z = run.channels.get("z")
    if spec.min_depth is not None and z is not None:
        with np.errstate(invalid="ignore"):
            masks[f"at or near the surface (z < {spec.min_depth:g} m, assumed threshold)"] = z < spec.min_depth
    armed = run.extra.get(spec.armed_column) if spec.armed_column else None
    if armed is not None and np.asarray(armed).dtype.kind == "f":
        masks["disarmed (armed = 0)"] = armed == 0
    phi, theta = run.channels.get("phi"), run.channels.get("theta")
    if spec.upside_down_s is not None and phi is not None and theta is not None:
        with np.errstate(invalid="ignore"):
            up = np.cos(phi) * np.cos(theta) < 0
        long = np.zeros_like(up)
        for a, b in _runs(up):
            if run.t[b - 1] - run.t[a] >= spec.upside_down_s:
                long[a:b] = True
        masks[f"upside down (body z up) for more than {spec.upside_down_s:g} s"] = long
    return masks


def cut_run(run: Run, spec: CutSpec) -> CutResult:
    """Keep every stretch of valid rows of ``run`` a replay can start from, as the segments of one run (see the
    module docstring).

    Parameters
    ----------
    run : Run
        A converted run (t from 0).
    spec : CutSpec
        Thresholds (``[cut]`` of the mapping).

    Returns
    -------
    CutResult
    """
    masks = invalid_rows(run, spec)
    bad = np.zeros(run.n, bool)
    for m in masks.values():
        bad |= m
    checks = ", ".join(masks) or "none applicable (no z, armed or attitude)"
    share = {r: float(m.mean()) for r, m in masks.items()}
    if not bad.any():
        return CutResult(run, (Stretch(0, run.n, float(run.t[0]), float(run.t[-1])),), (),
                         [f"cut: nothing cut; every row passes the checks ({checks})"], share, run.n)

    def stretch(a, b, reasons=()):
        return Stretch(int(a), int(b), float(run.t[a]), float(run.t[b - 1]), tuple(reasons))

    good = [stretch(a, b) for a, b in _runs(~bad)]
    cut = []
    for a, b in _runs(bad):
        reasons = tuple(r for r, m in masks.items() if m[a:b].any())
        cut.append(stretch(a, b, reasons))
    total = 100 * bad.mean()
    if not good:
        reasons = "; ".join(f"{r}: {100 * m.mean():.0f} % of the rows" for r, m in masks.items() if m.any())
        return CutResult(run, (), tuple(cut), [
            f"cut: WARNING: no row of this run passes the checks ({reasons}); the whole run is kept, but the plant "
            f"(a submerged, armed, upright vehicle) does not represent it: use it for the sensors, not for "
            f"identification or a diagnosis of the dynamics (a diagnosis reports it, not diagnosed)"], share, run.n)
    kept = [s for s in good if replayable(s)]
    alone = not kept
    if alone:  # nothing a window opens on: the longest valid stretch still serves the sensors and a plain replay
        kept = [max(good, key=lambda s: (s.stop - s.start, -s.start))]
    cut += [replace(s, reasons=(TOO_SHORT,)) for s in good if s not in kept]
    cut.sort(key=lambda s: s.start)
    rows = np.concatenate([np.arange(s.start, s.stop) for s in kept])
    segment = np.concatenate([np.full(s.stop - s.start, k + 1.0) for k, s in enumerate(kept)])
    new = replace(run, t=run.t[rows], channels={c: v[rows] for c, v in run.channels.items()},
                  inputs=run.inputs[rows], extra={**{c: v[rows] for c, v in run.extra.items()}, SEGMENT: segment},
                  metadata=dict(run.metadata))
    source = run.extra.get("t_source")
    result = CutResult(new, tuple(kept), tuple(cut), [], share, run.n)
    notes = [f"cut: kept {len(kept)} segment(s), {rows.size} of {run.n} rows, {result.kept_duration:.1f} s of the "
             f"{run.duration:.1f} s converted log; {total:.0f} % of the rows fail a check ({checks}); t is the "
             f"converted log's t (not shifted), and each segment is replayed from its own first row (column "
             f"'segment'). Times below are in the converted log's t"]
    if alone:
        notes.append(f"cut: WARNING: no valid stretch is long enough to replay in windows ({TOO_SHORT}); the longest "
                     f"is kept alone")
    for k, s in enumerate(kept):
        stamp = f" (t_source {source[s.start]:.3f}..{source[s.stop - 1]:.3f} s)" if source is not None else ""
        notes.append(f"cut: segment {k + 1}: rows {s.start}..{s.stop - 1}, t = {s.t_start:.2f}..{s.t_stop:.2f} s "
                     f"({s.duration:.1f} s){stamp}")
    for s in cut:
        notes.append(f"cut: left out t = {s.t_start:.2f}..{s.t_stop:.2f} s ({s.duration:.1f} s): "
                     f"{'; '.join(s.reasons)}")
    return replace(result, notes=notes)


__all__ = ["CutResult", "MIN_SEGMENT_ROWS", "MIN_SEGMENT_S", "Stretch", "cut_run", "invalid_rows", "replayable"]
