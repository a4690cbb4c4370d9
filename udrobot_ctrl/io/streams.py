"""Common in-memory form of a decoded log: named streams of timestamped fields, and the import error type."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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


def finish_stream(name, times, columns, time_source, t_alternative=None, alternative_source="") -> Stream:
    """Build a :class:`Stream` from per-message lists: sort by time (stable) and keep the last of equal stamps.

    Sorting and de-duplication are recorded in ``notes`` (never silent).
    """
    t = np.asarray(times, dtype=float)
    fields = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
    alt = None if t_alternative is None else np.asarray(t_alternative, dtype=float)
    notes = []
    if t.size and np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        notes.append(f"{name}: {int(np.sum(np.diff(t) < 0))} out-of-order time stamps ({time_source}); sorted")
        t = t[order]
        fields = {k: v[order] for k, v in fields.items()}
        alt = None if alt is None else alt[order]
    if t.size > 1:
        keep = np.append(np.diff(t) > 0, True)
        if not keep.all():
            notes.append(f"{name}: {int((~keep).sum())} samples share a time stamp with the next one; "
                         f"the last of each group is kept")
            t = t[keep]
            fields = {k: v[keep] for k, v in fields.items()}
            alt = None if alt is None else alt[keep]
    return Stream(name=name, t=t, fields=fields, time_source=time_source, t_alternative=alt,
                  alternative_source=alternative_source, notes=notes)
