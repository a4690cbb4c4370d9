"""Whether one run repeats another's data: the same samples shifted in time, re-written, or a stretch of it.

A diagnosis scores its fit on holdout runs; a holdout that *is* fit data (the fit run with its clock shifted by
1000 s, the same samples written again with fewer digits, or the fit run's own last 20 s) scores the fit on what
it has seen. :func:`repeated_stretch` finds the longest stretch of consecutive rows that two runs share, comparing
the measured channels and the commanded inputs cell by cell (never the time column, which a copy may shift), and
:func:`check_unseen` refuses a holdout that shares a stretch of at least :data:`MIN_REPEATED_ROWS` rows with a fit
run. A stretch in which nothing changes (a vehicle at rest, identical in two runs started alike) is not counted:
it is no evidence that the data were copied.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: relative tolerance at which two cells are one measurement written twice (assumed: a re-serialisation keeps at
#: least 6 significant digits, ``%g``'s default, whose rounding is at most 5e-6 of the value; 1e-5 covers it,
#: and two independent measurements of a channel agree that closely in every channel of a row only by chance)
SAME_VALUE_RTOL = 1e-5
#: consecutive repeated rows that make a holdout repeat fit data (assumed: ten rows of every channel and input
#: agreeing to 1e-5 do not happen by chance in measured data; short enough to catch a small overlap)
MIN_REPEATED_ROWS = 10
#: candidate rows of the fit run examined per probe row of the holdout (the nearest in the sorting column)
CANDIDATES_PER_PROBE = 8
#: alignments followed at most (rows that agree but lie in stretches where nothing changes, e.g. two runs at
#: rest, would otherwise be followed one by one): the cost stays linear in the runs' length
MAX_EXTENSIONS = 64


@dataclass(frozen=True)
class Repeat:
    """A stretch of rows two runs share.

    Attributes
    ----------
    rows : int
        Its length, rows.
    start_a, start_b : int
        Its first row (0-based) in run ``a`` and run ``b``.
    """

    rows: int
    start_a: int
    start_b: int


def _table(run, columns) -> np.ndarray:
    parts = [np.asarray(run.channels[c], dtype=float) for c in columns[0]]
    if columns[1]:
        parts += list(np.asarray(run.inputs, dtype=float).T)
    return np.column_stack(parts) if parts else np.empty((run.t.size, 0))


def _shared_columns(a, b) -> tuple:
    """(channel names measured in both, whether the inputs compare: same kind and count)."""
    names = [c for c in a.channels if c in b.channels
             and np.isfinite(a.channels[c]).any() and np.isfinite(b.channels[c]).any()]
    inputs = (a.input_kind == b.input_kind and np.shape(a.inputs)[1:] == np.shape(b.inputs)[1:]
              and np.isfinite(a.inputs).any())
    return names, inputs


def _same(x: np.ndarray, y: np.ndarray, atol: np.ndarray) -> np.ndarray:
    """Row-wise: every cell equal within :data:`SAME_VALUE_RTOL` (both nan counts as equal)."""
    close = np.abs(x - y) <= SAME_VALUE_RTOL * np.maximum(np.abs(x), np.abs(y)) + atol
    close |= np.isnan(x) & np.isnan(y)
    return close.all(axis=-1)


def repeated_stretch(a, b, min_rows: int = MIN_REPEATED_ROWS) -> Repeat | None:
    """The first stretch of at least ``min_rows`` consecutive rows of run ``b`` that repeats rows of run ``a``.

    Every ``min_rows // 2``-th row of ``b`` is probed (so any shared stretch of ``min_rows`` rows holds a probe);
    each probe is looked up in ``a`` by its value in ``a``'s most varied
    column (sorted, :data:`CANDIDATES_PER_PROBE` nearest), confirmed on every column, and followed both ways
    while the rows keep agreeing. Stretches in which no cell changes are ignored.

    Parameters
    ----------
    a, b : Run
        The two runs (``a`` a fit run, ``b`` a holdout).
    min_rows : int
        The shortest stretch reported.

    Returns
    -------
    Repeat or None
    """
    columns = _shared_columns(a, b)
    A, B = _table(a, columns), _table(b, columns)
    if A.shape[1] == 0 or A.shape[0] < min_rows or B.shape[0] < min_rows:
        return None
    scale = np.nanmax(np.abs(np.vstack([A, B])), axis=0)
    atol = SAME_VALUE_RTOL * np.where(np.isfinite(scale), scale, 0.0)
    finite = np.isfinite(A)
    distinct = [np.unique(A[finite[:, k], k]).size for k in range(A.shape[1])]
    key = int(np.argmax(distinct))
    order = np.argsort(np.where(finite[:, key], A[:, key], np.inf), kind="stable")
    ordered = A[order, key]
    probes = np.arange(0, B.shape[0], max(1, min_rows // 2))
    values = B[probes, key]
    ok = np.isfinite(values)
    probes, values = probes[ok], values[ok]
    tol = SAME_VALUE_RTOL * np.abs(values) + atol[key]
    lo = np.searchsorted(ordered, values - tol, side="left")
    hi = np.searchsorted(ordered, values + tol, side="right")
    idx = lo[:, None] + np.arange(CANDIDATES_PER_PROBE)[None, :]
    valid = idx < hi[:, None]
    J = order[np.minimum(idx, A.shape[0] - 1)][valid]
    P = np.broadcast_to(probes[:, None], idx.shape)[valid]
    hit = _same(A[J], B[P], atol)  # every column of the probe row agrees
    offsets = set()
    for j, p in zip(J[hit], P[hit]):
        if int(j) - int(p) in offsets:
            continue
        if len(offsets) >= MAX_EXTENSIONS:
            break
        offsets.add(int(j) - int(p))
        repeat = _extend(A, B, int(j), int(p), atol)
        if repeat.rows >= min_rows and _changes(B[repeat.start_b:repeat.start_b + repeat.rows], atol):
            return repeat
    return None


def _extend(A, B, j: int, p: int, atol) -> Repeat:
    """The stretch of rows agreeing along the diagonal through row ``j`` of A and row ``p`` of B."""
    m = min(A.shape[0] - j, B.shape[0] - p)
    ahead = _same(A[j:j + m], B[p:p + m], atol)
    forward = int(np.argmin(ahead)) if not ahead.all() else m
    m = min(j, p)
    back = _same(A[j - m:j][::-1], B[p - m:p][::-1], atol) if m else np.ones(0, bool)
    backward = int(np.argmin(back)) if not back.all() else m
    return Repeat(rows=forward + backward, start_a=j - backward, start_b=p - backward)


def _changes(rows: np.ndarray, atol) -> bool:
    """Whether any cell of the stretch changes from one row to the next (beyond the tolerance)."""
    if rows.shape[0] < 2:
        return False
    return not _same(rows[1:], rows[:-1], atol).all()


def check_unseen(fit, fit_names, holdout, holdout_names) -> None:
    """Refuse a holdout run that repeats a fit run's data (:func:`repeated_stretch`).

    Raises
    ------
    ValueError
        Naming both files, the rows shared and what is expected.
    """
    for h, hname in zip(holdout, holdout_names):
        for f, fname in zip(fit, fit_names):
            repeat = repeated_stretch(f, h)
            if repeat is None:
                continue
            whole = repeat.rows == h.t.size
            what = "every row of it" if whole else f"its data rows {repeat.start_b + 1}..{repeat.start_b + repeat.rows}"
            shift = float(h.t[repeat.start_b] - f.t[repeat.start_a])
            raise ValueError(f"holdout run {hname}: {what} ({repeat.rows} rows) repeat the fit run {fname} (from its "
                             f"data row {repeat.start_a + 1}" + (f", shifted by {shift:+.6g} s" if abs(shift) > 0
                                                                 else "") +
                             "): a holdout must be data the fit has not seen; give a run recorded separately")
