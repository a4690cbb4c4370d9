"""MAVLink telemetry logs (``.tlog``) and ArduPilot dataflash logs (``.bin``) via pymavlink, read strictly.

pymavlink's own readers (``mavutil.mavlink_connection``) resynchronise silently over bad bytes, which
would import part of a corrupt file without saying so. Here the framing is walked explicitly and every
message is decoded with pymavlink (``MAVLink.decode`` for tlogs; ``DFReader.DFFormat`` layouts for
dataflash), so a bad CRC, an unknown dataflash type or a truncated last message is an error naming the
byte offset and message index.

Times:
- ``.tlog``: each frame is preceded by the 8-byte big-endian receive time (µs since the UNIX epoch); all
  streams use that one clock. Where the message carries the autopilot clock (``time_boot_ms`` /
  ``time_usec``), it is kept as the alternative clock, aligned by the median offset, so the notes report
  the telemetry jitter.
- ``.bin``: ``TimeUS`` (µs since autopilot boot) for every message.

Multi-instance dataflash messages (``BARO``, ``IMU``, ``BAT`` ...) are split by their instance column
``I``: instance 0 is stream ``BARO``, instance 1 is ``BARO[1]``.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from .streams import LogImportError, finish_stream

TLOG_STAMP = struct.Struct(">Q")
DF_HEAD = b"\xa3\x95"
DF_FMT_TYPE = 128


def _dialect():
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


def iter_tlog(path):
    """Yield (index, byte_offset, receive_time_s, message) for every frame of a ``.tlog``; strict.

    Raises
    ------
    LogImportError
        Truncated frame, bad start byte, bad CRC (byte offset and message index in the message).
    """
    dialect = _dialect()
    data = Path(path).read_bytes()
    mav = dialect.MAVLink(None)
    mav.robust_parsing = False
    offset, index = 0, 0
    while offset < len(data):
        where = f"{path}: message {index} at byte offset {offset}"
        if len(data) - offset < 8 + 3:
            raise LogImportError(f"{where}: truncated ({len(data) - offset} bytes left, need a timestamp and a frame)")
        (usec,) = TLOG_STAMP.unpack_from(data, offset)
        start = offset + 8
        magic = data[start]
        if magic == 0xFE:
            length = 8 + data[start + 1]
        elif magic == 0xFD:
            length = 12 + data[start + 1] + (13 if data[start + 2] & 0x01 else 0)
        else:
            raise LogImportError(f"{where}: byte 0x{magic:02x} at offset {start} is not a MAVLink start byte "
                                 f"(0xFE v1 / 0xFD v2); expected 8-byte timestamp + frame (corrupt tlog?)")
        if start + length > len(data):
            raise LogImportError(f"{where}: frame of {length} bytes runs past the end of the file "
                                 f"({len(data)} bytes): truncated")
        frame = bytearray(data[start:start + length])
        msg_id = frame[5] if magic == 0xFE else int.from_bytes(frame[7:10], "little")
        if msg_id not in dialect.mavlink_map:
            yield index, offset, usec * 1e-6, None  # valid framing, message unknown to the dialect
        else:
            try:
                msg = mav.decode(frame)
            except Exception as exc:
                raise LogImportError(f"{where}: cannot decode MAVLink frame (msgid {msg_id}): {exc}") from exc
            yield index, offset, usec * 1e-6, msg
        offset = start + length
        index += 1


def _tlog_value(msg, field):
    name, _, idx = field.partition("[")
    value = getattr(msg, name)
    if idx:
        value = value[int(idx.rstrip("]"))]
    return float(value)


def read_tlog_streams(path, mapping) -> dict:
    """The message types ``mapping`` needs from a ``.tlog``, as streams on the receive-time clock."""
    needs = mapping.needs()
    data = {name: {"t": [], "boot": [], "cols": {f: [] for f in fields}} for name, fields in needs.items()}
    unknown = 0
    count = 0
    for index, offset, t, msg in iter_tlog(path):
        count += 1
        if msg is None:
            unknown += 1
            continue
        entry = data.get(msg.get_type())
        if entry is None:
            continue
        try:
            for f, column in entry["cols"].items():
                column.append(_tlog_value(msg, f))
        except (AttributeError, IndexError, ValueError, TypeError) as exc:
            raise LogImportError(f"{path}: message {index} at byte offset {offset} ({msg.get_type()}): no usable "
                                 f"field for the mapping ({type(exc).__name__}: {exc}); fields: "
                                 f"{', '.join(msg.get_fieldnames())}") from exc
        entry["t"].append(t)
        names = msg.get_fieldnames()
        if "time_boot_ms" in names:
            boot = msg.time_boot_ms * 1e-3
        elif "time_usec" in names:
            boot = msg.time_usec * 1e-6
        else:
            boot = None
        entry["boot"].append(np.nan if boot is None else float(boot))
    if count == 0:
        raise LogImportError(f"{path}: empty tlog (no messages)")
    streams = {}
    for name, entry in data.items():
        if not entry["t"]:
            continue
        t = np.asarray(entry["t"])
        boot = np.asarray(entry["boot"])
        alt, alt_source = None, ""
        if np.all(np.isfinite(boot)):
            alt = boot + np.median(t - boot)
            alt_source = "autopilot time (aligned by median offset)"
        stream = finish_stream(name, t, entry["cols"], "tlog receive time", alt, alt_source)
        if unknown:
            stream.notes.append(f"{path}: {unknown} of {count} frames have message ids unknown to the "
                                f"ardupilotmega dialect (framing and length valid) and were not decoded")
        streams[name] = stream
    return streams


# ------------------------------------------------------------------------------------------------ dataflash


def _df_format(elements, where):
    from pymavlink.DFReader import DFFormat, null_term

    ftype, flen, name, fmt, columns = elements
    try:
        return DFFormat(ftype, null_term(name), flen, null_term(fmt), null_term(columns))
    except Exception as exc:
        raise LogImportError(f"{where}: invalid FMT record for type {ftype}: {exc}") from exc


def iter_dataflash(path):
    """Yield (index, byte_offset, name, dict of field -> value) for every dataflash record; strict.

    Values use pymavlink's multipliers (e.g. ``c`` int16 * 0.01). FMT records define the layouts.
    """
    from pymavlink.DFReader import DFFormat

    data = Path(path).read_bytes()
    # bootstrap FMT layout, as ArduPilot writes it (Type, Length, Name, Format, Columns)
    formats = {DF_FMT_TYPE: DFFormat(DF_FMT_TYPE, "FMT", 89, "BBnNZ", "Type,Length,Name,Format,Columns")}
    structs = {}
    offset, index = 0, 0
    while offset < len(data):
        where = f"{path}: message {index} at byte offset {offset}"
        if len(data) - offset < 3:
            raise LogImportError(f"{where}: truncated ({len(data) - offset} bytes left)")
        if data[offset:offset + 2] != DF_HEAD:
            raise LogImportError(f"{where}: bytes {data[offset:offset + 2].hex()} are not the dataflash header a395 "
                                 f"(corrupt log)")
        mtype = data[offset + 2]
        fmt = formats.get(mtype)
        if fmt is None:
            raise LogImportError(f"{where}: message type {mtype} has no FMT record before it (corrupt log)")
        if offset + fmt.len > len(data):
            raise LogImportError(f"{where}: {fmt.name} record of {fmt.len} bytes runs past the end of the file "
                                 f"({len(data)} bytes): truncated")
        unpack = structs.get(mtype)
        if unpack is None:
            unpack = structs[mtype] = struct.Struct(fmt.msg_struct)
            if unpack.size != fmt.len - 3:
                raise LogImportError(f"{where}: FMT of {fmt.name} says {fmt.len} bytes, format {fmt.format!r} "
                                     f"packs {unpack.size + 3}")
        elements = unpack.unpack_from(data, offset + 3)
        if mtype == DF_FMT_TYPE:
            new = _df_format(elements, where)
            formats[new.type] = new
            structs.pop(new.type, None)
        else:
            values = {}
            for col, value, mult in zip(fmt.columns, elements, fmt.msg_mults):
                if isinstance(value, bytes):
                    value = value.rstrip(b"\0").decode("latin-1")
                elif mult is not None:
                    value = value * mult
                values[col] = value
            yield index, offset, fmt.name, values
        offset += fmt.len
        index += 1


def read_bin_streams(path, mapping) -> dict:
    """The messages ``mapping`` needs from a dataflash ``.bin``, on the ``TimeUS`` clock (s since boot)."""
    needs = mapping.needs()
    data = {name: {"t": [], "cols": {f: [] for f in fields}} for name, fields in needs.items()}
    count = 0
    for index, offset, name, values in iter_dataflash(path):
        count += 1
        inst = values.get("I")
        key = name if not isinstance(inst, (int, float)) or inst == 0 else f"{name}[{int(inst)}]"
        entry = data.get(key)
        if entry is None:
            continue
        try:
            t = values["TimeUS"] * 1e-6
            cols = [(column, float(values[f])) for f, column in entry["cols"].items()]
        except (KeyError, TypeError, ValueError) as exc:
            raise LogImportError(f"{path}: message {index} at byte offset {offset} ({name}): missing or "
                                 f"non-numeric field {exc} (fields: {', '.join(values)})") from exc
        entry["t"].append(t)
        for column, value in cols:
            column.append(value)
    if count == 0:
        raise LogImportError(f"{path}: no dataflash messages")
    return {name: finish_stream(name, e["t"], e["cols"], "TimeUS (autopilot boot time)")
            for name, e in data.items() if e["t"]}
