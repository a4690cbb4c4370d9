"""Cut the stretches of a converted run that the plant cannot represent (``[cut]`` in a mapping).

The vehicle model describes a submerged, upright vehicle under thrust. A field log also holds the launch at the
surface, the boat deck, disarmed minutes and, rarely, a capsized vehicle. A row is *invalid* when

- ``z`` < ``min_depth`` (at or near the surface, or out of the water: depth around or above 0 m; the threshold
  is an assumption stated in the notes; rows without a depth are not judged),
- the ``armed`` column is 0 (disarmed: the thrusters do not follow the controller),
- the body z axis points up (cos(phi) cos(theta) < 0) for longer than ``upside_down_s``.

The longest contiguous stretch of valid rows is kept as the run (t restarts at 0 there; the ``cut:`` notes give
its log time); every stretch left out is listed with its times and reasons. A run without any valid row is kept
whole with a prominent ``cut: WARNING`` note (a log entirely at the surface still converts). The same verdict goes
into the sidecar's ``cut`` field (:meth:`CutResult.record`), which ``diagnose`` reads to leave such a run out.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .mapping import CutSpec
from .runlog import Run


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


@dataclass(frozen=True)
class CutResult:
    """What :func:`cut_run` kept and cut.

    Attributes
    ----------
    run : Run
        The kept stretch (the input run when nothing was cut, or nothing was valid).
    kept : Stretch or None
        The kept stretch, None when no row is valid (the run is then kept whole).
    cut : tuple of Stretch
        Stretches left out (invalid ones with reasons, shorter valid ones with reason ``shorter valid stretch``).
    notes : list of str
        ``cut:`` lines for the sidecar notes.
    invalid_share : dict
        Check -> fraction of the input run's rows failing it (every check applied, 0 for one no row fails).
    n_rows : int
        Rows of the input run.
    """

    run: Run
    kept: Stretch | None
    cut: tuple
    notes: list
    invalid_share: dict
    n_rows: int

    def record(self) -> dict:
        """The sidecar's ``cut`` field (docs/formats/runlog.md): the checks applied with the fraction of rows failing
        each, and the stretch kept (``t_start``, ``t_stop`` in the converted log's t, s; ``rows`` [first, last];
        ``of`` rows), or None when no row passes (the run kept whole, not represented by the plant)."""
        kept = None if self.kept is None else {"t_start": self.kept.t_start, "t_stop": self.kept.t_stop,
                                               "rows": [self.kept.start, self.kept.stop - 1], "of": self.n_rows}
        return {"invalid_share": dict(self.invalid_share), "kept": kept}


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
    """Keep the longest contiguous stretch of valid rows of ``run`` (see module docstring).

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
        return CutResult(run, Stretch(0, run.n, float(run.t[0]), float(run.t[-1])), (),
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
        return CutResult(run, None, tuple(cut), [
            f"cut: WARNING: no row of this run passes the checks ({reasons}); the whole run is kept, but the plant "
            f"(a submerged, armed, upright vehicle) does not represent it: use it for the sensors, not for "
            f"identification or a diagnosis of the dynamics (a diagnosis reports it, not diagnosed)"], share, run.n)
    kept = max(good, key=lambda s: (s.stop - s.start, -s.start))
    cut += [replace(s, reasons=("shorter valid stretch (the longest is kept)",)) for s in good if s is not kept]
    cut.sort(key=lambda s: s.start)
    rows = np.arange(kept.start, kept.stop)
    new = replace(run, t=run.t[rows] - run.t[kept.start], channels={c: v[rows] for c, v in run.channels.items()},
                  inputs=run.inputs[rows], extra={c: v[rows] for c, v in run.extra.items()},
                  metadata=dict(run.metadata))
    source = run.extra.get("t_source")
    stamp = f" (t_source {source[kept.start]:.3f} s)" if source is not None else ""
    notes = [f"cut: kept rows {kept.start}..{kept.stop - 1} of {run.n}: t = {kept.t_start:.2f}..{kept.t_stop:.2f} s "
             f"of the converted log ({kept.duration:.1f} s, the longest stretch the plant represents); t = 0 is now "
             f"t = {kept.t_start:.3f} s of the converted log{stamp}; {total:.0f} % of the rows fail a check "
             f"({checks}). Times below are in the converted log's t"]
    for s in cut:
        notes.append(f"cut: left out t = {s.t_start:.2f}..{s.t_stop:.2f} s ({s.duration:.1f} s): "
                     f"{'; '.join(s.reasons)}")
    return CutResult(new, kept, tuple(cut), notes, share, run.n)


__all__ = ["CutResult", "Stretch", "cut_run", "invalid_rows"]
