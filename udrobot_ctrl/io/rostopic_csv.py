"""``rostopic echo -p`` CSV exports: ``%time`` (bag record time, ns) plus ``field.*`` columns, one file per topic.

The mapping's ``[files]`` table names each stream's file with a ``{suffix}`` placeholder
(``navigation_state = "navigation_state{suffix}.csv"``); given one of the files, the others are found next
to it with the same suffix (``navigation_state_3.csv`` -> ``wrench_3.csv``). A field path ``position.x``
reads column ``field.position.x``. With ``time = "header"`` a stream that has ``field.header.stamp`` (ns)
is timed by it and the record time is kept as the alternative clock (its delay goes to the notes).
"""
from __future__ import annotations

import csv
import re
from pathlib import Path

from .runlog import non_ascii_digits, separator_hint
from .streams import LogImportError, Stream, finish_stream

_NUM = re.compile(r"^[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?$", re.ASCII)  # digits 0-9 only


def resolve_files(path, files: dict) -> dict:
    """Stream name -> file path for the set ``path`` belongs to (by the ``{suffix}`` patterns)."""
    path = Path(path)
    for pattern in files.values():
        head, tail = pattern.split("{suffix}")
        name = path.name
        if name.startswith(head) and name.endswith(tail) and len(name) >= len(head) + len(tail):
            suffix = name[len(head): len(name) - len(tail)]
            return {s: path.with_name(p.replace("{suffix}", suffix)) for s, p in files.items()}
    raise LogImportError(f"{path}: file name matches none of the mapping's [files] patterns "
                         f"({', '.join(files.values())})")


def _number(cell: str, where: str) -> float:
    s = cell.strip()
    if _NUM.match(s):
        value = float(s)
        if value in (float("inf"), float("-inf")):
            raise LogImportError(f"{where}: value {s[:30]!r} overflows")
        return value
    if s.lower() in ("", "nan"):
        return float("nan")
    raise LogImportError(f"{where}: non-numeric cell {s[:40]!r}{non_ascii_digits(s)}; expected a number")


def read_topic_csv(path, name: str, fields, time: str = "header") -> Stream:
    """Read one ``rostopic echo -p`` CSV into a :class:`Stream` (every row; any bad cell is an error).

    Parameters
    ----------
    path : Path
        The CSV file.
    name : str
        Stream name.
    fields : iterable of str
        Field paths to read (``position.x`` -> column ``field.position.x``).
    time : {'header', 'receive'}
        Use ``field.header.stamp`` (ns) when present, or ``%time`` (bag record time, ns).
    """
    path = Path(path)
    if not path.is_file():
        raise LogImportError(f"{path}: file of stream '{name}' not found")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise LogImportError(f"{path}: byte offset {exc.start}: not UTF-8 text") from exc
    reader = csv.reader(text.splitlines())
    header = next(reader, None)
    if not header or header[0] != "%time":
        raise LogImportError(f"{path}: line 1: expected a rostopic echo -p header starting with '%time', "
                             f"got {(header or [''])[0][:40]!r}{separator_hint(header or [])}")
    index = {h: j for j, h in enumerate(header)}
    wanted = list(dict.fromkeys(fields))
    for f in wanted:
        if f"field.{f}" not in index:
            raise LogImportError(f"{path}: line 1: no column 'field.{f}' for stream '{name}' "
                                 f"(columns: {', '.join(header[:20])}{' ...' if len(header) > 20 else ''})")
    use_header = time == "header" and "field.header.stamp" in index
    record, stamp, columns = [], [], {f: [] for f in wanted}
    for row_no, row in enumerate(reader, start=1):
        line = row_no + 1
        if not row:
            raise LogImportError(f"{path}: line {line}: blank line inside the data")
        if len(row) != len(header):
            raise LogImportError(f"{path}: line {line} (message {row_no}): {len(row)} cells, header has {len(header)}"
                                 f" (truncated file?)")
        record.append(_number(row[0], f"{path}: line {line}, column '%time'") * 1e-9)
        if use_header:
            stamp.append(_number(row[index["field.header.stamp"]], f"{path}: line {line}, column "
                                 f"'field.header.stamp'") * 1e-9)
        for f in wanted:
            columns[f].append(_number(row[index[f"field.{f}"]], f"{path}: line {line}, column 'field.{f}'"))
    if not record:
        raise LogImportError(f"{path}: no messages after the header")
    if use_header:
        return finish_stream(name, stamp, columns, "header.stamp", t_alternative=record,
                             alternative_source="%time (bag record time)")
    return finish_stream(name, record, columns, "%time (bag record time)")


def read_streams(path, mapping) -> dict:
    """All streams the mapping needs, from the file set ``path`` belongs to. Missing files are errors."""
    files = resolve_files(path, mapping.files)
    needs = mapping.needs()
    return {s: read_topic_csv(files[s], s, needs.get(s, ()), mapping.time) for s in files if s in needs}
