"""Common in-memory form of a decoded log: named streams of timestamped fields, and the import error type."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .runlog import MAX_GAP_RATIO, MAX_GAP_S, MIN_RATIO_GAP_S


class LogImportError(ValueError):
    """A log that cannot be imported completely: the message names the file and the byte offset or message index."""


@dataclass
class Stream:
    """One message stream (a ROS topic, a MAVLink/dataflash message type, a rostopic CSV file).

    Attributes
    ----------
    name : str
        Topic / message type / file key.
    t : (m,) ndarray
        Sample times on the log's own clock, s (absolute: UNIX epoch for bags and tlogs, boot time for dataflash).
    fields : dict of str -> (m,) ndarray
        Requested field paths (``orientation.x``, ``channels[2]``, ``servo1_raw``) as float arrays.
    time_source : str
        What ``t`` is ('header.stamp', 'bag record time', 'tlog receive time', 'TimeUS', '%time').
    t_alternative : (m,) ndarray or None
        The other clock when the log has two (e.g. bag record time when ``t`` is the header stamp), s.
    """

    name: str
    t: np.ndarray
    fields: dict
    time_source: str
    t_alternative: np.ndarray | None = None
    alternative_source: str = ""
    notes: list = field(default_factory=list)


def gap_limit(t) -> tuple:
    """(limit, median step) of the clock-jump rule of run logs (``runlog.check_time_gaps``) for sorted times ``t``.

    An interval is a clock jump when it exceeds :data:`~udrobot_ctrl.io.runlog.MAX_GAP_S` (6 h), or both
    :data:`~udrobot_ctrl.io.runlog.MAX_GAP_RATIO` (1e4) median steps and
    :data:`~udrobot_ctrl.io.runlog.MIN_RATIO_GAP_S` (60 s).
    """
    med = float(np.median(np.diff(t)))
    return min(MAX_GAP_S, max(MAX_GAP_RATIO * med, MIN_RATIO_GAP_S)), med


def clock_jump_segment(name, t, time_source) -> tuple:
    """The stretch of sorted times ``t`` to keep when clock jumps split it: the one with the most samples.

    A few corrupt bytes in a time stamp (a flipped bit in a dataflash ``TimeUS``, a damaged tlog receive time)
    put a record hours or days away from the others; a conversion onto a uniform grid across that gap would
    allocate in proportion to it. The stream is cut at every interval over the run-log limit (:func:`gap_limit`)
    and only its largest stretch is kept.

    Parameters
    ----------
    name : str
        The stream, for the note.
    t : (m,) ndarray
        Sorted times, s.
    time_source : str
        What ``t`` is, for the note.

    Returns
    -------
    (slice, str or None)
        The samples to keep and a note saying what was dropped (which stream, how many records, the jumps and
        the limit), or ``(slice(None), None)`` when nothing is dropped.
    """
    if t.size < 3:
        return slice(None), None
    limit, med = gap_limit(t)
    cuts = np.flatnonzero(np.diff(t) > limit)
    if not cuts.size:
        return slice(None), None
    bounds = np.r_[0, cuts + 1, t.size]
    k = int(np.argmax(np.diff(bounds)))
    a, b = int(bounds[k]), int(bounds[k + 1])
    before, after = a, t.size - b
    biggest = float(np.diff(t)[cuts].max())
    where = []
    if before:
        where.append(f"{before} before it ({t[0]:.6g}..{t[a - 1]:.6g} s)")
    if after:
        where.append(f"{after} after it ({t[b]:.6g}..{t[-1]:.6g} s)")
    note = (f"{name}: {before + after} of {t.size} records dropped ({' and '.join(where)}): clock jumps of up to "
            f"{biggest:.6g} s in {time_source} (limit {limit:.6g} s: over 6 h, or over 1e4 median intervals of "
            f"{med:.3g} s and 60 s, as for run logs) cut the stream into {len(cuts) + 1} stretches; the largest, "
            f"{b - a} records at {t[a]:.6g}..{t[b - 1]:.6g} s, is kept. Corrupt time stamps, or a second session in "
            f"the log (convert it separately)")
    return slice(a, b), note


SPIKE_STEPS = 100.0  # a stamp over this many median intervals (and SPIKE_MIN_S) from both neighbours is a spike
SPIKE_MIN_S = 1.0  # s; below this an out-of-line stamp is jitter (bag header stamps), never dropped


def time_spikes(t) -> np.ndarray:
    """Mask of the isolated corrupt stamps of ``t`` (finite, in the order the log holds them): :func:`_spikes_once`,
    repeated on the records it keeps until it finds no more. Three corrupt records among five (every other record
    flipped) put the median on a corrupt one and hide the middle one; with the other two dropped, it stands out."""
    t = np.asarray(t, dtype=float)
    spikes = _spikes_once(t)
    while spikes.any():
        keep = np.flatnonzero(~spikes)
        more = _spikes_once(t[keep])
        if not more.any():
            break
        spikes[keep[more]] = True
    return spikes


def _spikes_once(t) -> np.ndarray:
    """One pass of :func:`time_spikes`: records more than
    :data:`SPIKE_STEPS` median intervals (and :data:`SPIKE_MIN_S`) away from the median of the five records around
    them (the first or last five at the ends; up to two corrupt records among five are found); at either end, where
    a pause would look the same, only a record out of line into the stream (one of the first two later, one of the
    last two earlier, than the median).

    Such a record (a flipped byte in a dataflash ``TimeUS`` or a tlog receive time) would, once sorted, stretch
    its stream by the size of the flip, and a conversion onto a grid across the stretch would allocate in
    proportion; the clock-jump limit (:func:`clock_jump_segment`) allows up to 1e4 median intervals. The median of
    five consecutive stamps of an ordered stream is the middle one, so a pause of any length is never a spike.
    """
    t = np.asarray(t, dtype=float)
    n = t.size
    spikes = np.zeros(n, dtype=bool)
    if n < 3:
        return spikes
    limit = max(SPIKE_STEPS * float(np.median(np.abs(np.diff(t)))), SPIKE_MIN_S)
    centre = np.empty(n)
    if n >= 5:
        centre[2:n - 2] = np.median(np.lib.stride_tricks.sliding_window_view(t, 5), axis=1)
    for i in sorted({0, 1, n - 2, n - 1} | ({2, n - 3} if n < 5 else set())):  # the five records at that end
        centre[i] = np.median(t[:5] if i < n / 2 else t[-5:])
    off = t - centre
    spikes = np.abs(off) > limit
    # at either end a record before (after) a pause stays: the first, or the second if not earlier than the first
    # (and the last, or the one before it if not later than the last)
    pause = np.zeros(n, dtype=bool)
    pause[0], pause[1] = off[0] < 0, off[1] < 0 and t[1] >= t[0]
    pause[-1], pause[-2] = off[-1] > 0, off[-2] > 0 and t[-2] <= t[-1]
    spikes &= ~pause
    return spikes


def _select(t, fields, alt, idx):
    """The samples ``idx`` (mask or index array) of a stream's time stamps, fields and alternative clock (or None)."""
    return t[idx], {k: v[idx] for k, v in fields.items()}, None if alt is None else alt[idx]


def finish_stream(name, times, columns, time_source, t_alternative=None, alternative_source="") -> Stream:
    """Build a :class:`Stream` from per-message lists: sort by time (stable), keep the last of equal stamps, and
    drop records that clock jumps separate from the stream's largest stretch (:func:`clock_jump_segment`).

    Samples whose time stamp is not a finite number (NaN, inf) are dropped first, for that reason, then isolated
    corrupt stamps (:func:`time_spikes`). Sorting,
    de-duplication and dropped records are recorded in ``notes`` (never silent). An alternative clock
    with a jump over the limit in the kept stretch is not used (noted).
    """
    t = np.asarray(times, dtype=float)
    fields = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
    alt = None if t_alternative is None else np.asarray(t_alternative, dtype=float)
    notes = []
    bad = ~np.isfinite(t)
    if bad.any():  # before sorting: a NaN stamp compares false with its neighbours and would pass as a duplicate
        first = int(np.flatnonzero(bad)[0])
        notes.append(f"{name}: {int(bad.sum())} of {t.size} samples dropped for a bad time stamp (not a finite "
                     f"number in {time_source}; the first is message {first + 1}, value {t[first]!r}); their other "
                     f"fields are not used")
        t, fields, alt = _select(t, fields, alt, ~bad)
    spikes = time_spikes(t)
    if spikes.any():
        first = int(np.flatnonzero(spikes)[0])
        notes.append(f"{name}: {int(spikes.sum())} of {t.size} samples dropped for a corrupt time stamp out of line "
                     f"with both neighbours (over {SPIKE_STEPS:g} median intervals and {SPIKE_MIN_S:g} s away, the "
                     f"neighbours agreeing; the first is record {first + 1} at {t[first]:.6g} s in {time_source})")
        t, fields, alt = _select(t, fields, alt, ~spikes)
    if t.size and np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        notes.append(f"{name}: {int(np.sum(np.diff(t) < 0))} out-of-order time stamps ({time_source}); sorted")
        t, fields, alt = _select(t, fields, alt, order)
    if t.size > 1:
        keep = np.append(np.diff(t) > 0, True)
        if not keep.all():
            notes.append(f"{name}: {int((~keep).sum())} samples share a time stamp with the next one; "
                         f"the last of each group is kept")
            t, fields, alt = _select(t, fields, alt, keep)
    keep, note = clock_jump_segment(name, t, time_source)
    if note:
        notes.append(note)
        t, fields, alt = _select(t, fields, alt, keep)
    if alt is not None and alt.size > 2:
        d = np.diff(alt)
        jump = np.flatnonzero(~np.isfinite(d) | (np.abs(d) > gap_limit(t)[0]))
        if jump.size:
            notes.append(f"{name}: {alternative_source} not used: it jumps by {d[jump[0]]:.6g} s at {time_source} "
                         f"{t[jump[0] + 1]:.6g} s (over the clock-jump limit {gap_limit(t)[0]:.6g} s); "
                         f"{time_source} is used throughout")
            alt, alternative_source = None, ""
    return Stream(name=name, t=t, fields=fields, time_source=time_source, t_alternative=alt,
                  alternative_source=alternative_source, notes=notes)
