"""QGroundControl telemetry CSV exports ("CSV telemetry logging" in QGC's application settings).

QGC writes, once per second while the vehicle is armed (or always, with "save CSV log even if not armed"),
one row of its vehicle *facts*: a header ``Timestamp,roll,pitch,heading,rollRate,...,gps.lat,...,
battery0.voltage,...`` (top-level facts by name, fact groups as ``group.fact``) and rows whose first cell is
the local wall-clock time ``yyyy-MM-dd hh:mm:ss.zzz``. Values are QGC's display ("cooked") units: angles in
degrees, rates in deg/s, altitudes in m (``altitudeRelative`` positive up: ArduSub shows -depth), voltages in V.
Empty cells are facts without a value yet (nan).

The file is recognised by its header (first cell ``Timestamp``), so it is never mistaken for a
``udrobot-run/1`` run (whose first column is ``t``). All numeric columns become one stream, named by the
mapping's single stream (``telemetry`` in the shipped ``qgc-csv`` mapping); non-numeric columns (flight mode,
hobbs meter ``hh:mm:ss``) are left out.
"""
from __future__ import annotations

import csv
import math
import re
from datetime import datetime
from pathlib import Path

from .runlog import non_ascii_digits
from .streams import LogImportError, Stream, finish_stream

HEADER_FIRST = "Timestamp"
_NUMBER = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$", re.ASCII)  # digits 0-9 only (not '٣', '３')
TIME_FORMATS = ("%Y-%m-%d %H:%M:%S.%f", "%Y-%m-%d %H:%M:%S", "%Y-%m-%dT%H:%M:%S.%f", "%Y-%m-%dT%H:%M:%S")


def is_qgc_csv(path) -> bool:
    """True if the file's first header cell is ``Timestamp`` (QGC's CSV telemetry log)."""
    with open(path, "rb") as fh:
        head = fh.read(64).lstrip(b"\xef\xbb\xbf")
    return head.split(b",", 1)[0].strip() == HEADER_FIRST.encode()


def _time(cell: str, where: str) -> float:
    s = cell.strip()
    for fmt in TIME_FORMATS:
        try:
            return datetime.strptime(s, fmt).timestamp()  # local wall clock, as QGC writes it
        except ValueError:
            continue
    try:
        return float(s)
    except ValueError:
        raise LogImportError(f"{where}: Timestamp {s[:40]!r} is neither 'yyyy-MM-dd hh:mm:ss.zzz' nor a number") \
            from None


def _cell(s: str) -> float:
    """A cell's value: nan when empty, None when not a plain decimal number in ASCII digits (a text fact, or a
    damaged cell)."""
    s = s.strip()
    if s == "":
        return math.nan
    if not _NUMBER.match(s) and s.lower() not in ("nan", "+nan", "-nan"):
        return None
    return float(s)


def read_qgc_csv(path, name: str = "telemetry") -> Stream:
    """One :class:`Stream` of every numeric column of a QGC telemetry CSV (time = wall clock, s since epoch).

    Raises
    ------
    LogImportError
        Header without ``Timestamp`` first, unreadable time stamp (row named), no data rows.
    """
    path = Path(path)
    with open(path, newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        rows = [(reader.line_num, r) for r in reader]  # (file line, 1-based with the header, cells)
    if not rows or not rows[0][1] or rows[0][1][0].strip() != HEADER_FIRST:
        raise LogImportError(f"{path}: not a QGroundControl telemetry CSV (first header cell must be "
                             f"'{HEADER_FIRST}')")
    header = [h.strip() for h in rows[0][1]]
    data = [(line, r) for line, r in rows[1:] if any(c.strip() for c in r)]  # blank lines skipped, not renumbered
    if not data:
        raise LogImportError(f"{path}: QGC telemetry CSV has a header but no data rows")
    times = []
    columns = {h: [] for h in header[1:]}
    bad = {h: [] for h in header[1:]}  # (row, cell) of the cells that are not numbers, per column
    longer, first_longer, most = 0, None, len(header)
    for k, row in data:
        if len(row) > len(header):  # QGC adds fact columns (a second battery) after writing its header
            longer += 1
            first_longer = first_longer or k
            most = max(most, len(row))
            row = row[:len(header)]
        elif len(row) < len(header):
            raise LogImportError(f"{path}: row {k} has {len(row)} cells, the header {len(header)}; a QGC telemetry "
                                 f"row has at least one cell per header column")
        times.append(_time(row[0], f"{path}: row {k}, column Timestamp"))
        for h, cell in zip(header[1:], row[1:]):
            value = _cell(cell)
            if value is None:
                bad[h].append((k, cell))
                value = math.nan
            columns[h].append(value)
    # a text column (flight mode, hobbs meter hh:mm:ss) has no number at all; a numeric column with a few
    # damaged cells keeps its other rows, each bad cell read as missing (nan) and counted
    read = {h: sum(1 for v in columns[h] if not math.isnan(v)) for h in columns}
    text = [h for h in columns if bad[h] and len(bad[h]) >= read[h]]
    for h, cells in bad.items():
        for k, cell in cells:
            digit = non_ascii_digits(cell)
            if digit and h not in text:
                raise LogImportError(f"{path}: row {k}, column {h}: cell {cell.strip()[:40]!r}{digit}")
    fields = {h: v for h, v in columns.items() if h not in text}
    stream = finish_stream(name, times, fields, "QGC wall-clock Timestamp (local time)")
    if longer:
        stream.notes.append(f"{path}: {longer} of {len(data)} rows have more cells than the header (first: row "
                            f"{first_longer}, up to {most} cells for {len(header)} header columns: facts QGC added "
                            f"after writing the header, e.g. a second battery); the cells beyond the header have no "
                            f"name and are ignored")
    damaged = {h: cells for h, cells in bad.items() if cells and h not in text}
    if damaged:
        total = sum(len(c) for c in damaged.values())
        detail = "; ".join(f"{h}: {len(c)} (first row {c[0][0]}, {c[0][1].strip()[:20]!r})" for h, c in damaged.items())
        stream.notes.append(f"{path}: {total} cell{'s' if total != 1 else ''} not a number, read as missing (only "
                            f"that cell of its row; the row's other columns are kept): {detail}")
    if text:
        stream.notes.append(f"{path}: non-numeric QGC columns not read: {', '.join(text)}")
    return stream


def read_streams(path, mapping) -> dict:
    """The mapping's single stream from a QGC telemetry CSV (fields checked against the header)."""
    names = sorted(mapping.needs())
    if len(names) != 1:
        raise LogImportError(f"{path}: a qgc_csv mapping reads one stream (the CSV), got {names}")
    stream = read_qgc_csv(path, names[0])
    return {names[0]: stream}


__all__ = ["is_qgc_csv", "read_qgc_csv", "read_streams"]
