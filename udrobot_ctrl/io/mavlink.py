"""MAVLink telemetry logs (``.tlog``) and ArduPilot dataflash logs (``.bin``) via pymavlink, damage-tolerant.

Field logs are routinely damaged (docs/mappings.md, "Field-log damage"): QGroundControl tlogs written on BlueOS
vehicles hold frames with bad CRCs (camera and distance-sensor messages), dataflash logs end with a record cut
short when the vehicle is switched off. The framing is walked here explicitly so that every byte is accounted
for: each frame is decoded with pymavlink (``MAVLink.decode`` for tlogs; ``DFReader.DFFormat`` layouts for
dataflash); a frame that does not decode is skipped and counted in a :class:`Damage` record (kind, message
type, count, bytes, first byte offsets), garbage is skipped by resynchronising on the next plausible frame
start, and a truncated tail ends the read. A file is refused (:class:`LogImportError` naming it) only when
nothing decodes.

Times:
- ``.tlog``: each frame is preceded by the 8-byte big-endian receive time (µs since the UNIX epoch); all
  streams use that one clock. Where the message carries the autopilot clock (``time_boot_ms`` /
  ``time_usec``), it is kept as the alternative clock, aligned by the median offset, so the notes report
  the telemetry jitter.
- ``.bin``: ``TimeUS`` (µs since autopilot boot) for every message.

Multi-instance dataflash messages (``BARO``, ``IMU``, ``BAT`` ...) are split by their instance column
``I`` (or ``Instance``): instance 0 is stream ``BARO``, instance 1 is ``BARO[1]``.

Besides the mapped streams, every read collects what the log says about the vehicle: parameters
(``PARAM_VALUE`` / ``PARM``) and text messages (``STATUSTEXT`` / ``MSG``); :func:`detect_vehicle` turns them
into the vehicle name and its motor outputs.
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .streams import LogImportError, finish_stream

TLOG_STAMP = struct.Struct(">Q")
DF_HEAD = b"\xa3\x95"
DF_FMT_TYPE = 128
FIRST_OFFSETS = 5
DAY_US = 86_400 * 1_000_000
# receive times outside 2000-01-01 .. 2100-01-01 are not a tlog stamp (used to resynchronise over garbage)
STAMP_MIN_US, STAMP_MAX_US = 946_684_800 * 1_000_000, 4_102_444_800 * 1_000_000
MAV_TYPE_GCS = 6
# messages a ground station sends, read from their sender (every other stream leaves ground stations out): the
# joystick as QGroundControl sent it (QGC logs its outgoing messages), with the sender's ids
GCS_STREAMS = {"MANUAL_CONTROL": ("x", "y", "z", "r")}
# NAMED_VALUE_FLOAT values kept in LogFacts.named: ArduSub's current pilot gain (sent with the other joystick state)
NAMED_FLOATS = ("PilotGain",)


# ------------------------------------------------------------------------------------------------ damage


@dataclass
class DamageKind:
    """One kind of damage in a log: how often, how many bytes, where it starts (first byte offsets)."""

    count: int = 0
    nbytes: int = 0
    offsets: list = field(default_factory=list)


@dataclass
class Damage:
    """Damage found while reading a field log, keyed by kind (``bad CRC DISTANCE_SENSOR (132)``, ...)."""

    kinds: dict = field(default_factory=dict)

    def add(self, kind: str, offset: int, nbytes: int) -> None:
        entry = self.kinds.setdefault(kind, DamageKind())
        entry.count += 1
        entry.nbytes += nbytes
        if len(entry.offsets) < FIRST_OFFSETS:
            entry.offsets.append(offset)

    def count(self, prefix: str = "") -> int:
        """Total count of damage kinds starting with ``prefix`` (all kinds by default)."""
        return sum(k.count for name, k in self.kinds.items() if name.startswith(prefix))

    def summary(self) -> str:
        """One line for an error message: each kind with its count and first byte offset."""
        if not self.kinds:
            return "empty file"
        return "; ".join(f"{name}: {k.count} ({k.nbytes} bytes) from byte offset {k.offsets[0]}"
                         for name, k in sorted(self.kinds.items(), key=lambda kv: -kv[1].count))

    def notes(self, path) -> list:
        """``damage:`` lines for the sidecar notes (one per kind, largest first); ``damage: none`` if clean."""
        if not self.kinds:
            return [f"damage: none found in {path} (every byte belongs to a decoded frame)"]
        total = sum(k.count for k in self.kinds.values())
        lines = [f"damage: {total} damaged item(s) in {path} skipped and counted below; the rest of the file "
                 f"was read"]
        for name, k in sorted(self.kinds.items(), key=lambda kv: -kv[1].count):
            lines.append(f"damage: {name}: {k.count} ({k.nbytes} bytes), first byte offsets "
                         f"{', '.join(str(o) for o in k.offsets)}")
        return lines


@dataclass
class LogFacts:
    """What a MAVLink/dataflash log says besides its streams.

    Attributes
    ----------
    params : dict of str -> float
        Last logged value of every parameter (``PARAM_VALUE`` / ``PARM``).
    texts : list of str
        ``STATUSTEXT`` / ``MSG`` texts in log order.
    named : dict of str -> (times s, values) lists
        The autopilot's ``NAMED_VALUE_FLOAT`` values named in :data:`NAMED_FLOATS` (tlogs only).
    damage : Damage
    decoded : int
        Frames / records with valid framing (and CRC).
    notes : list of str
        Further statements for the run's notes (e.g. ``frames:`` unknown message ids).
    """

    params: dict = field(default_factory=dict)
    texts: list = field(default_factory=list)
    named: dict = field(default_factory=dict)
    damage: Damage = field(default_factory=Damage)
    decoded: int = 0
    notes: list = field(default_factory=list)


@dataclass
class DecodedLog:
    """Streams a mapping asked for (name -> :class:`Stream`) and the log's :class:`LogFacts`."""

    streams: dict
    facts: LogFacts


def _dialect():
    from pymavlink.dialects.v20 import ardupilotmega

    return ardupilotmega


# ------------------------------------------------------------------------------------------------ tlog


def _frame_length(data, start):
    """(frame length in bytes, msgid) of the MAVLink frame at ``start`` or (None, None) if no start byte."""
    magic = data[start]
    if magic == 0xFE:
        return 8 + data[start + 1], data[start + 5]
    if magic == 0xFD:
        return (12 + data[start + 1] + (13 if data[start + 2] & 0x01 else 0),
                data[start + 7] | data[start + 8] << 8 | data[start + 9] << 16)
    return None, None


def _plausible_stamp(data, pos, last_us) -> bool:
    """True if ``pos`` holds an 8-byte receive time (near the last one, or a plausible date) and a start byte."""
    if pos + 9 > len(data) or data[pos + 8] not in (0xFD, 0xFE):
        return False
    (usec,) = TLOG_STAMP.unpack_from(data, pos)
    if last_us is not None:
        return abs(usec - last_us) < DAY_US
    return STAMP_MIN_US <= usec <= STAMP_MAX_US


def _resync(data, pos, last_us) -> int:
    while pos + 9 <= len(data) and not _plausible_stamp(data, pos, last_us):
        pos += 1
    return pos if pos + 9 <= len(data) else len(data)


def _crc_ok(data, start, end, msgtype, x25crc) -> bool:
    """The frame's X.25 checksum (with the message's CRC_EXTRA) matches, as pymavlink's decode checks it."""
    signed = data[start] == 0xFD and data[start + 2] & 0x01
    crc_end = end - (13 if signed else 0) - 2
    buf = bytearray(data[start + 1:crc_end])
    buf.append(msgtype.crc_extra)
    return x25crc(buf).crc == (data[crc_end] | data[crc_end + 1] << 8)


def iter_tlog(path, damage: Damage | None = None, wanted=None, tally: dict | None = None):
    """Yield (index, byte_offset, receive_time_s, message) for every decodable frame of a ``.tlog``.

    Damage is skipped and recorded in ``damage``: frames with a bad CRC (kind ``bad CRC TYPE (msgid)``; the
    frame's declared length is trusted when the next frame starts right after it), bytes that do not start
    a frame (``garbage (no frame start)``, skipped up to the next plausible receive time + start byte) and a
    truncated last frame (``truncated tail``). Frames of a message id unknown to the ardupilotmega dialect are
    yielded with ``message = None`` (valid framing, not decodable).

    ``wanted`` (set of message type names): frames of other types are only checked (CRC, framing; damage
    counted the same way) and not decoded or yielded, which keeps a 30-minute tlog fast. ``tally['valid']``
    counts every frame with a valid CRC, yielded or not.
    """
    dialect = _dialect()
    x25crc = dialect.x25crc
    tally = {} if tally is None else tally
    tally.setdefault("valid", 0)
    data = Path(path).read_bytes()
    damage = Damage() if damage is None else damage
    mav = dialect.MAVLink(None)
    mav.robust_parsing = False
    mav_error = dialect.MAVError
    known = dialect.mavlink_map
    size = len(data)
    offset, index, last_us = 0, 0, None
    while offset < size:
        if size - offset < 8 + 8:  # smaller than a stamp + the smallest v1 frame
            damage.add("truncated tail", offset, size - offset)
            break
        start = offset + 8
        length, msg_id = _frame_length(data, start)
        (usec,) = TLOG_STAMP.unpack_from(data, offset)
        if length is None or not (abs(usec - last_us) < DAY_US if last_us is not None
                                  else STAMP_MIN_US <= usec <= STAMP_MAX_US):
            nxt = _resync(data, offset + 1, last_us)
            damage.add("garbage (no frame start)", offset, nxt - offset)
            offset = nxt
            continue
        end = start + length
        if end > size:
            damage.add("truncated tail", offset, size - offset)
            break
        if msg_id not in known:
            if end < size and not _plausible_stamp(data, end, usec):
                nxt = _resync(data, offset + 1, last_us)
                damage.add("garbage (no frame start)", offset, nxt - offset)
                offset = nxt
                continue
            yield index, offset, usec * 1e-6, None
        elif wanted is not None and known[msg_id].msgname not in wanted:
            if _crc_ok(data, start, end, known[msg_id], x25crc):
                last_us = usec
                tally["valid"] += 1
            elif end < size and not _plausible_stamp(data, end, usec):
                nxt = _resync(data, offset + 1, last_us)
                damage.add("garbage (no frame start)", offset, nxt - offset)
                offset = nxt
                continue
            else:
                damage.add(f"bad CRC {known[msg_id].msgname} ({msg_id})", offset, end - offset)
        else:
            try:
                msg = mav.decode(bytearray(data[start:end]))
            except (mav_error, struct.error, ValueError, UnicodeDecodeError) as exc:  # a corrupt payload
                if end < size and not _plausible_stamp(data, end, usec):
                    # the length byte itself is not trustworthy: lost framing
                    nxt = _resync(data, offset + 1, last_us)
                    damage.add("garbage (no frame start)", offset, nxt - offset)
                    offset = nxt
                    continue
                kind = "bad CRC" if "CRC" in str(exc) else "undecodable"
                damage.add(f"{kind} {known[msg_id].msgname} ({msg_id})", offset, end - offset)
            else:
                last_us = usec
                tally["valid"] += 1
                yield index, offset, usec * 1e-6, msg
        offset = end
        index += 1


def _tlog_value(msg, name, idx):
    value = getattr(msg, name)
    if idx is not None:
        value = value[idx]
    return float(value)


def _split_field(f):
    name, _, idx = f.partition("[")
    return name, (int(idx.rstrip("]")) if idx else None)


def read_tlog_streams(path, mapping, optional: dict | None = None) -> DecodedLog:
    """The message types ``mapping`` needs from a ``.tlog``, as streams on the receive-time clock.

    Parameters
    ----------
    path : str or Path
    mapping : Mapping
    optional : dict of str -> iterable of str, optional
        Further stream fields read when the message has them (nan otherwise), e.g. ``servo9_raw``.

    Returns
    -------
    DecodedLog
        Streams plus parameters, texts and damage. Messages from ground stations (systems whose HEARTBEAT
        says MAV_TYPE_GCS) are left out of the streams, except the :data:`GCS_STREAMS` a ground station sends
        (MANUAL_CONTROL: fields x, y, z, r, src_system, src_component), read from whichever system sent them.
    """
    needs = mapping.needs()
    optional = optional or {}
    data = {}
    for name in set(needs) | set(optional):
        req = [(f, *_split_field(f)) for f in sorted(needs.get(name, ()))]
        opt = [(f, *_split_field(f)) for f in sorted(set(optional.get(name, ())) - set(needs.get(name, ())))]
        data[name] = {"t": [], "boot": [], "req": req, "opt": opt,
                      "cols": {f: [] for f, _, _ in req + opt}}
    for name, fields in GCS_STREAMS.items():
        req = [(f, f, None) for f in fields]
        data.setdefault(name, {"t": [], "boot": [], "req": req, "opt": [], "cols": {f: [] for f in fields}})
        data[name]["sender"] = True
        data[name]["cols"].update({"src_system": [], "src_component": []})
    facts = LogFacts()
    gcs = set()
    unknown = 0
    tally = {}
    wanted = set(data) | {"HEARTBEAT", "PARAM_VALUE", "STATUSTEXT", "NAMED_VALUE_FLOAT"}
    for index, offset, t, msg in iter_tlog(path, facts.damage, wanted, tally):
        if msg is None:
            unknown += 1
            continue
        mtype = msg.get_type()
        if mtype == "HEARTBEAT" and msg.type == MAV_TYPE_GCS:
            gcs.add(msg.get_srcSystem())
        elif mtype == "PARAM_VALUE":
            pid = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode("latin-1")
            facts.params[pid.rstrip("\0")] = float(msg.param_value)
        elif mtype == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("latin-1")
            facts.texts.append(text.rstrip("\0"))
        elif mtype == "NAMED_VALUE_FLOAT" and msg.get_srcSystem() not in gcs:
            key = (msg.name if isinstance(msg.name, str) else msg.name.decode("latin-1")).rstrip("\0")
            if key in NAMED_FLOATS:
                times, values = facts.named.setdefault(key, ([], []))
                times.append(t)
                values.append(float(msg.value))
        entry = data.get(mtype)
        if entry is None or (msg.get_srcSystem() in gcs and "sender" not in entry):
            continue
        cols = entry["cols"]
        if "sender" in entry:
            cols["src_system"].append(float(msg.get_srcSystem()))
            cols["src_component"].append(float(msg.get_srcComponent()))
        try:
            for f, name, idx in entry["req"]:
                cols[f].append(_tlog_value(msg, name, idx))
        except (AttributeError, IndexError, ValueError, TypeError) as exc:
            raise LogImportError(f"{path}: message {index} at byte offset {offset} ({mtype}): no usable "
                                 f"field for the mapping ({type(exc).__name__}: {exc}); fields: "
                                 f"{', '.join(msg.get_fieldnames())}") from exc
        for f, name, idx in entry["opt"]:
            try:
                cols[f].append(_tlog_value(msg, name, idx))
            except (AttributeError, IndexError, ValueError, TypeError):
                cols[f].append(np.nan)
        entry["t"].append(t)
        names = msg._fieldnames
        if "time_boot_ms" in names:
            boot = msg.time_boot_ms * 1e-3
        elif "time_usec" in names:
            boot = msg.time_usec * 1e-6
        else:
            boot = np.nan
        entry["boot"].append(float(boot))
    facts.decoded = tally["valid"] + unknown
    if unknown:
        facts.notes.append(f"frames: {unknown} of {facts.decoded} frames in {path} have message ids unknown to the "
                           f"ardupilotmega dialect (framing and length valid) and were not decoded")
    if facts.decoded == 0:
        raise LogImportError(f"{path}: nothing usable decodes (no MAVLink frame with a valid CRC): "
                             f"{facts.damage.summary()}")
    streams = {}
    for name, entry in data.items():
        if not entry["t"]:
            continue
        t = np.asarray(entry["t"])
        boot = np.asarray(entry["boot"])
        alt, alt_source = None, ""
        back = np.flatnonzero(np.diff(boot) < -1.0) if boot.size > 1 else np.array([], int)
        if np.all(np.isfinite(boot)) and np.any(boot > 0) and back.size == 0:
            alt = boot + np.median(t - boot)
            alt_source = "autopilot time (aligned by median offset)"
        stream = finish_stream(name, t, entry["cols"], "tlog receive time", alt, alt_source)
        if back.size:
            k = back[0]
            stream.notes.append(f"{name}: the autopilot clock goes back {back.size} time(s), first at receive time "
                                f"{t[k + 1] - t[0]:.1f} s into the stream ({boot[k]:.1f} -> {boot[k + 1]:.1f} s since "
                                f"boot): a reboot; the receive time is used throughout")
        bad = facts.damage.count(f"bad CRC {name} (")
        if bad:
            stream.notes.append(f"{name}: {bad} frames with bad CRCs skipped (see damage:); the stream has "
                                f"{t.size} good ones")
        streams[name] = stream
    return DecodedLog(streams, facts)


# ------------------------------------------------------------------------------------------------ dataflash


def _df_layout(fmt):
    return struct.Struct(fmt.msg_struct)


def iter_dataflash(path, damage: Damage | None = None, wanted=None, tally: dict | None = None):
    """Yield (index, byte_offset, name, dict of field -> value) for every dataflash record.

    Values use pymavlink's multipliers (e.g. ``c`` int16 * 0.01). FMT records define the layouts. Damage is
    skipped and recorded in ``damage``: bytes that are not ``A3 95 <known type>`` (``garbage (no record
    header)``, skipped to the next record header), a last record cut short (``truncated tail (TYPE)``) and
    FMT records pymavlink cannot parse (``bad FMT``). Dataflash has no checksum: corruption inside a record
    that keeps its header is not detectable. ``wanted`` (set of message names): records of other types are
    stepped over without unpacking (their framing is still checked); the index still counts them.
    ``tally['valid']`` counts every well-framed record (FMT included), yielded or not.
    """
    from pymavlink.DFReader import FORMAT_TO_STRUCT, DFFormat, null_term

    format_chars = set(FORMAT_TO_STRUCT)

    data = Path(path).read_bytes()
    damage = Damage() if damage is None else damage
    tally = {} if tally is None else tally
    tally.setdefault("valid", 0)
    formats = {DF_FMT_TYPE: DFFormat(DF_FMT_TYPE, "FMT", 89, "BBnNZ", "Type,Length,Name,Format,Columns")}
    layouts = {}
    size = len(data)
    offset, index = 0, 0
    while offset < size:
        if size - offset < 3:
            damage.add("truncated tail", offset, size - offset)
            break
        mtype = data[offset + 2]
        if data[offset] != 0xA3 or data[offset + 1] != 0x95 or mtype not in formats:
            nxt = data.find(DF_HEAD, offset + 1)
            while nxt != -1 and (nxt + 2 >= size or data[nxt + 2] not in formats):
                nxt = data.find(DF_HEAD, nxt + 1)
            nxt = size if nxt == -1 else nxt
            damage.add("garbage (no record header)", offset, nxt - offset)
            offset = nxt
            continue
        fmt = formats[mtype]
        if offset + fmt.len > size:
            damage.add(f"truncated tail ({fmt.name})", offset, size - offset)
            break
        tally["valid"] += 1
        if wanted is not None and mtype != DF_FMT_TYPE and fmt.name not in wanted:
            offset += fmt.len
            index += 1
            continue
        layout = layouts.get(mtype)
        if layout is None:
            try:
                layout = layouts[mtype] = _df_layout(fmt)
            except struct.error:
                layout = None
            if layout is None or layout.size != fmt.len - 3:
                layouts.pop(mtype, None)
                damage.add(f"bad layout {fmt.name}", offset, fmt.len)
                offset += fmt.len
                continue
        elements = layout.unpack_from(data, offset + 3)
        if mtype == DF_FMT_TYPE:
            ftype, flen, name, form, cols = elements
            form = null_term(form)
            if set(form) <= format_chars:  # else DFFormat would print and raise a bare Exception
                formats[ftype] = DFFormat(ftype, null_term(name), flen, form, null_term(cols))
                layouts.pop(ftype, None)
            else:
                damage.add("bad FMT", offset, fmt.len)
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


def _instance(values):
    for col in ("I", "Instance"):
        inst = values.get(col)
        if isinstance(inst, (int, float)):
            return int(inst)
    return 0


def read_bin_streams(path, mapping, optional: dict | None = None) -> DecodedLog:
    """The messages ``mapping`` needs from a dataflash ``.bin``, on the ``TimeUS`` clock (s since boot).

    ``optional`` as in :func:`read_tlog_streams`. Parameters (``PARM``) and texts (``MSG``) are collected.
    """
    needs = mapping.needs()
    optional = optional or {}
    data = {}
    for name in set(needs) | set(optional):
        req = sorted(needs.get(name, ()))
        opt = sorted(set(optional.get(name, ())) - set(req))
        data[name] = {"t": [], "req": req, "opt": opt, "cols": {f: [] for f in req + opt}}
    facts = LogFacts()
    wanted = {name.split("[")[0] for name in data} | {"PARM", "MSG"}
    tally = {}
    for _index, offset, name, values in iter_dataflash(path, facts.damage, wanted, tally):
        if name == "PARM":
            facts.params[str(values.get("Name", ""))] = float(values.get("Value", np.nan))
            continue
        if name == "MSG":
            facts.texts.append(str(values.get("Message", "")))
            continue
        inst = _instance(values)
        entry = data.get(name if inst == 0 else f"{name}[{inst}]")
        if entry is None:
            continue
        try:
            t = values["TimeUS"] * 1e-6
        except (KeyError, TypeError):
            # the type's FMT record lost its TimeUS column to damage (a flipped byte in the name): its records have
            # no time; skipped and counted (a stream left empty is named by the mapping step)
            fields = ", ".join(values)[:80]
            facts.damage.add(f"no TimeUS in {name} (damaged FMT record? fields: {fields})", offset, 0)
            continue
        cols = entry["cols"]
        entry["t"].append(t)
        for f in entry["req"]:
            value = values.get(f)
            if isinstance(value, (int, float)):
                cols[f].append(float(value))
            else:  # this firmware logs the message without that field: the stream lacks it (noted)
                entry.setdefault("lacks", set()).add(f)
                cols[f].append(np.nan)
        for f in entry["opt"]:
            value = values.get(f, np.nan)
            cols[f].append(float(value) if isinstance(value, (int, float)) else np.nan)
    facts.decoded = tally["valid"]
    if facts.decoded == 0:
        raise LogImportError(f"{path}: nothing usable decodes (no dataflash record): {facts.damage.summary()}")
    streams = {}
    for name, e in data.items():
        if not e["t"]:
            continue
        lacks = sorted(e.get("lacks", ()))
        cols = {f: v for f, v in e["cols"].items() if f not in lacks}
        streams[name] = finish_stream(name, e["t"], cols, "TimeUS (autopilot boot time)")
        if lacks:
            streams[name].notes.append(f"{name}: this log's {name} records have no field(s) {', '.join(lacks)}; "
                                       f"mapping entries that need them are skipped")
    return DecodedLog(streams, facts)


# ------------------------------------------------------------------------------------------------ vehicle

# ArduSub FRAME_CONFIG (AP_Motors/MotorFrame_sub values; ArduPilot wiki "sub-frames"): value -> (frame string
# as in STATUSTEXT "Frame: ...", motor count, vehicle name in this project or None)
ARDUSUB_FRAMES = {
    0: ("BLUEROV1", 6, None),
    1: ("VECTORED", 6, "bluerov2"),
    2: ("VECTORED_6DOF", 8, "bluerov2-heavy"),
    3: ("VECTORED_6DOF_90DEG", 8, None),
    4: ("SIMPLEROV_3", 3, None),
    5: ("SIMPLEROV_4", 4, None),
    6: ("SIMPLEROV_5", 5, None),
    7: ("CUSTOM", None, None),
}
SERVO_MOTOR1, SERVO_MOTOR8 = 33, 40  # SERVOn_FUNCTION values Motor1..Motor8
_FRAME_TEXT = re.compile(r"Frame:\s*([A-Z0-9_]+)")


@dataclass
class VehicleInfo:
    """The vehicle as the log describes it.

    Attributes
    ----------
    name : str or None
        ``bluerov2`` (FRAME_CONFIG 1), ``bluerov2-heavy`` (2), ``ardusub-frame-N`` otherwise; None if the log
        does not say.
    frame : int or None
        FRAME_CONFIG value.
    motor_servos : tuple of int
        Servo output number of motor 1, 2, ... (from SERVOn_FUNCTION 33..40, or the ArduSub default servo k =
        motor k for the frame's motor count); empty when unknown.
    notes : list of str
        ``vehicle:`` lines: what was read and what was assumed.
    servo_source : str
        ``'function'`` (SERVOn_FUNCTION), ``'default'`` (servo k = motor k assumed), ``'outputs'`` (inferred from
        the logged outputs) or ``''`` (unknown).
    """

    name: str | None
    frame: int | None
    motor_servos: tuple
    notes: list
    servo_source: str = ""


_FIRMWARE_TEXT = re.compile(r"\bArduSub\s+V\d+\.\d+\S*(?:\s+[A-Z]+\d*)?(?:\s+\([0-9a-fA-F]+\))?")


def firmware_text(facts: LogFacts) -> str | None:
    """The autopilot's version banner (``ArduSub V4.1.0 (89639005)``, sent as STATUSTEXT / MSG at boot and on a
    ground station's connection), the last one in the log; None when the log holds none."""
    found = [m.group(0) for t in facts.texts if (m := _FIRMWARE_TEXT.search(t))]
    return found[-1] if found else None


def detect_vehicle(facts: LogFacts) -> VehicleInfo:
    """Vehicle name and motor outputs from FRAME_CONFIG, ``Frame: ...`` texts and SERVOn_FUNCTION."""
    notes = []
    frame = facts.params.get("FRAME_CONFIG")
    frame = int(frame) if frame is not None and np.isfinite(frame) else None
    text_frames = [m.group(1) for t in facts.texts if (m := _FRAME_TEXT.search(t))]
    by_string = {v[0]: k for k, v in ARDUSUB_FRAMES.items()}
    if frame is not None:
        notes.append(f"vehicle: parameter FRAME_CONFIG = {frame}"
                     + (f" ({ARDUSUB_FRAMES[frame][0]})" if frame in ARDUSUB_FRAMES else " (not an ArduSub frame)"))
        if text_frames and by_string.get(text_frames[-1]) not in (None, frame):
            notes.append(f"vehicle: STATUSTEXT says 'Frame: {text_frames[-1]}', which disagrees with FRAME_CONFIG; "
                         f"FRAME_CONFIG used")
    elif text_frames:
        frame = by_string.get(text_frames[-1])
        notes.append(f"vehicle: no FRAME_CONFIG parameter in the log; text 'Frame: {text_frames[-1]}' read"
                     + ("" if frame is not None else " (unknown frame string)"))
    servo_fn = {}
    for key, value in facts.params.items():
        m = re.fullmatch(r"SERVO(\d+)_FUNCTION", key)
        if m and SERVO_MOTOR1 <= value <= SERVO_MOTOR8:
            servo_fn[int(value) - SERVO_MOTOR1 + 1] = int(m.group(1))
    expected = ARDUSUB_FRAMES.get(frame, (None, None, None))[1] if frame is not None else None
    if servo_fn:
        motors = sorted(servo_fn)
        if motors != list(range(1, len(motors) + 1)):
            notes.append(f"vehicle: SERVOn_FUNCTION gives motors {motors} (not 1..n); missing motors have no output")
        servos = tuple(servo_fn[k] for k in motors)
        notes.append("vehicle: motor outputs from SERVOn_FUNCTION (33..40 = Motor1..8): "
                     + ", ".join(f"motor {k} = servo {servo_fn[k]}" for k in motors))
        if expected is not None and expected != len(servos):
            notes.append(f"vehicle: frame {frame} has {expected} motors but {len(servos)} servo outputs are "
                         f"motors; the servo functions are used")
    elif expected is not None:
        servos = tuple(range(1, expected + 1))
        notes.append(f"vehicle: no SERVOn_FUNCTION parameters in the log; ArduSub default assumed: motor k on "
                     f"servo k, k = 1..{expected}")
    else:
        servos = ()
    if frame is None:
        name = None
    else:
        name = ARDUSUB_FRAMES.get(frame, (None, None, None))[2] or f"ardusub-frame-{frame}"
    if name is not None:
        notes.append(f"vehicle: named {name} with {len(servos)} thrusters (motor outputs in motor order -> "
                     f"pwm_1..pwm_{len(servos)})")
    source = "function" if servo_fn else ("default" if servos else "")
    return VehicleInfo(name=name, frame=frame, motor_servos=servos, notes=notes, servo_source=source)


# ------------------------------------------------------------------------------------------------ outputs

MOTOR_PWM_RANGE = (1100.0, 1900.0)  # us: ArduSub motor outputs (MOT_PWM_MIN / MOT_PWM_MAX defaults)
NEUTRAL_BAND_US = 50.0  # us: a motor output comes this close to 1500 at some time (lights at 1594-1708 never do)
#: a motor output changes value from one sample to the next at least this many times: its controller's sums move it
#: all the time, where a lights channel or a stepped servo changes a handful of times (ArduSub's lights: button steps,
#: LIGHTS_STEPS = 8 levels). Assumed, well above a stepped channel's changes. It replaced a median within 150 us of
#: 1500 us, which missed the horizontal thrusters of a dive flown on long transects (200-300 us off neutral for
#: most of the log) and let through lights at half brightness (1500 us)
MOTOR_CHANGES = 20
MIN_MOVE_US = 10.0  # us: an output whose range is smaller does not move
INFERRED_VEHICLES = {6: "bluerov2", 8: "bluerov2-heavy"}  # active motor outputs 1..n -> vehicle


@dataclass(frozen=True)
class OutputActivity:
    """One servo output as the log shows it.

    Attributes
    ----------
    servo : int
        Output number (RCOU ``Cn`` / SERVO_OUTPUT_RAW ``servoN_raw``).
    kind : str
        ``'motor'`` (moves, in the motor PWM range, around 1500 us), ``'neutral'`` (exactly 1500 us throughout:
        a disarmed motor, or a trimmed servo), ``'unused'`` (0 / not logged) or ``'other'`` (lights, servos).
    evidence : str
        Numbers behind the verdict (range, median).
    """

    servo: int
    kind: str
    evidence: str


@dataclass(frozen=True)
class OutputEvidence:
    """Classification of every logged servo output of a log (:func:`classify_outputs`)."""

    stream: str
    outputs: tuple

    def servos(self, kind: str) -> tuple:
        """Output numbers of one kind, ascending."""
        return tuple(o.servo for o in self.outputs if o.kind == kind)

    def describe(self) -> str:
        """One line naming each output's kind and evidence (outputs at neutral and unused ones grouped)."""
        parts = [f"{self.stream} output {o.servo}: {o.kind} ({o.evidence})" for o in self.outputs
                 if o.kind in ("motor", "other")]
        for kind, what in (("neutral", "at exactly 1500 us throughout (neutral)"), ("unused", "unused (0 or not "
                                                                                              "logged)")):
            servos = self.servos(kind)
            if servos:
                parts.append(f"output{'s' if len(servos) > 1 else ''} {', '.join(map(str, servos))} {what}")
        return "; ".join(parts)


def classify_outputs(stream, pattern: str, max_servo: int) -> OutputEvidence:
    """Which logged outputs drive motors, from the PWM values alone.

    A motor output has >= 95 % of its non-zero samples in the motor range 1100..1900 us, comes within 50 us of
    the 1500 us neutral at some time, moves (range >= 10 us) and changes value from sample to sample at least
    ``MOTOR_CHANGES`` times (wherever it spends most of the log: the horizontal thrusters of a dive flown on long
    transects sit 200-300 us off neutral); one at exactly 1500 us throughout is ``neutral`` (a disarmed motor, or a
    servo at its trim). A lights channel (1594-1708 us, never near neutral, or stepped between a few levels), an
    output at 0 and a constant off-neutral output are not motors.

    Parameters
    ----------
    stream : Stream
        The motor-output stream (RCOU, SERVO_OUTPUT_RAW port 0).
    pattern : str
        Field pattern with ``{n}`` (``C{n}``, ``servo{n}_raw``).
    max_servo : int
    """
    outputs = []
    lo, hi = MOTOR_PWM_RANGE
    for n in range(1, max_servo + 1):
        values = stream.fields.get(pattern.format(n=n))
        finite = values[np.isfinite(values)] if values is not None else np.array([])
        nonzero = finite[finite != 0]
        if nonzero.size == 0:
            outputs.append(OutputActivity(n, "unused", "0 or not logged"))
            continue
        vmin, vmax, med = float(nonzero.min()), float(nonzero.max()), float(np.median(nonzero))
        evidence = f"{vmin:.0f}..{vmax:.0f} us, median {med:.0f}"
        in_range = np.mean((nonzero >= lo) & (nonzero <= hi)) >= 0.95
        if vmin == vmax == ARDUSUB_PWM_NEUTRAL:
            kind = "neutral"
        elif (in_range and vmax - vmin >= MIN_MOVE_US and vmin <= ARDUSUB_PWM_NEUTRAL + NEUTRAL_BAND_US
              and vmax >= ARDUSUB_PWM_NEUTRAL - NEUTRAL_BAND_US
              and np.count_nonzero(np.diff(nonzero)) >= MOTOR_CHANGES):
            kind = "motor"
        else:
            kind = "other"
        outputs.append(OutputActivity(n, kind, evidence))
    return OutputEvidence(stream=stream.name, outputs=tuple(outputs))


def vehicle_thrusters(name: str, mapping_default: tuple = ()) -> int | None:
    """Thruster count of a vehicle name a log can be converted for.

    ``bluerov2`` 6, ``bluerov2-heavy`` 8, ``ardusub-frame-N`` with a known motor count, or the mapping's default
    vehicle ``mapping_default`` = (name, default servos); None if unknown.
    """
    known = {v[2]: v[1] for v in ARDUSUB_FRAMES.values() if v[2]}
    known.update({f"ardusub-frame-{k}": v[1] for k, v in ARDUSUB_FRAMES.items() if v[1]})
    if mapping_default and mapping_default[0]:
        known.setdefault(mapping_default[0], len(mapping_default[1]))
    return known.get(name)


def choose_vehicle(detected: VehicleInfo, evidence: OutputEvidence | None, override: str | None = None,
                   mapping_default: tuple = (), where: str = "log") -> VehicleInfo:
    """The vehicle and its motor outputs.

    In order: ``override`` (``convert --vehicle``); what the log names (FRAME_CONFIG, ``Frame:`` text); else
    inferred from the active motor outputs of ``evidence`` (outputs 1..6 -> bluerov2, 1..8 -> bluerov2-heavy;
    all at neutral when none moves). Without an output stream the log's own (empty) answer is returned.

    Parameters
    ----------
    detected : VehicleInfo
        :func:`detect_vehicle`'s answer.
    evidence : OutputEvidence or None
        :func:`classify_outputs` of the motor-output stream, None if the log has none.
    override : str, optional
        Vehicle name given by the user.
    mapping_default : tuple
        (name, servos) of the mapping's default vehicle, a further name ``override`` may use.
    where : str
        File name for messages.

    Raises
    ------
    LogImportError
        The outputs do not tell the vehicle (a count other than 6 / 8, gaps, outputs at neutral beside moving
        ones): the message lists the outputs and asks for ``--vehicle``; or the chosen vehicle (without a
        SERVOn_FUNCTION map) has fewer thrusters than the log has moving motor outputs.
    """
    notes = list(detected.notes)
    evid = f"; evidence: {evidence.describe()}" if evidence is not None else ""
    moving = evidence.servos("motor") if evidence is not None else ()
    if override is not None:
        n = vehicle_thrusters(override, mapping_default)
        if n is None:
            known = sorted({v[2] for v in ARDUSUB_FRAMES.values() if v[2]}
                           | ({mapping_default[0]} if mapping_default and mapping_default[0] else set()))
            raise LogImportError(f"{where}: --vehicle {override!r}: unknown thruster count; known vehicles: "
                                 f"{', '.join(known)}, ardusub-frame-N")
        if detected.servo_source == "function" and len(detected.motor_servos) == n:
            servos, source, how = detected.motor_servos, "function", "motor outputs from SERVOn_FUNCTION"
        else:
            servos, source = tuple(range(1, n + 1)), "default"
            how = f"motor k on servo k, k = 1..{n} (ArduSub default, assumed)"
        if detected.name is not None and detected.name != override:
            notes.append(f"vehicle: the log names {detected.name}; --vehicle {override} overrides it")
        notes.append(f"vehicle: {override} with {n} thrusters given by --vehicle; {how}{evid}")
        info = VehicleInfo(name=override, frame=detected.frame, motor_servos=servos, notes=notes,
                           servo_source=source)
    elif detected.name is not None or evidence is None:
        info = detected
    else:
        neutral = evidence.servos("neutral")
        active, how = moving, "move around 1500 us"
        if not moving and neutral:
            active, how = neutral, "sit at the 1500 us neutral throughout (disarmed; no output moves)"
        n = len(active)
        if not (n in INFERRED_VEHICLES and active == tuple(range(1, n + 1)) and not (moving and neutral)):
            default = f", {mapping_default[0]}" if mapping_default and mapping_default[0] else ""
            raise LogImportError(
                f"{where}: the log does not name its vehicle (no FRAME_CONFIG, no 'Frame:' text) and its motor outputs "
                f"do not tell it: {evidence.describe()}. Expected outputs 1..6 (bluerov2) or 1..8 (bluerov2-heavy) "
                f"moving around 1500 us. Give the vehicle: udrobot-ctrl convert --vehicle NAME (bluerov2, "
                f"bluerov2-heavy{default})")
        name = INFERRED_VEHICLES[n]
        servos = tuple(range(1, n + 1))
        notes.append(f"vehicle: inferred {name} ({n} thrusters) from the logged outputs, not named by the log (no "
                     f"FRAME_CONFIG, no 'Frame:' text): outputs 1..{n} {how} in the motor range "
                     f"{MOTOR_PWM_RANGE[0]:.0f}..{MOTOR_PWM_RANGE[1]:.0f} us; motor k on servo k assumed (ArduSub "
                     f"default){evid}")
        return VehicleInfo(name=name, frame=None, motor_servos=servos, notes=notes, servo_source="outputs")
    if evidence is not None and info.servo_source != "function" and info.motor_servos:
        dropped = [k for k in moving if k not in info.motor_servos]
        if dropped:
            raise LogImportError(
                f"{where}: vehicle {info.name} has {len(info.motor_servos)} thrusters (servo "
                f"{', '.join(map(str, info.motor_servos))}) but output(s) {', '.join(map(str, dropped))} also drive "
                f"motors (they move around 1500 us) and would be dropped; {evidence.describe()}. Give a vehicle with "
                f"all of them: convert --vehicle NAME")
    return info


ARDUSUB_PWM_NEUTRAL = 1500.0  # us, ArduSub motor output at zero command


def motor_command_pwm(pwm, directions):
    """Logged ESC PWM (us, (..., n)) -> the motor-command PWM of ArduSub (``MOT_i_DIRECTION`` = ``directions[i]``).

    ArduSub outputs 1500 - (command) for a motor with ``MOT_i_DIRECTION = -1`` (propeller of the other hand or
    swapped wires), so that the thruster's strong (forward) sense still follows a positive command: mirroring
    the PWM about 1500 us recovers 1500 + (command), which this curve and the vehicle model's directions expect.
    """
    pwm = np.asarray(pwm, float)
    d = np.asarray(directions, float)
    if d.shape != pwm.shape[-1:] or not np.all(np.isin(d, (-1.0, 1.0))):
        raise ValueError(f"expected {pwm.shape[-1]} motor directions of +1 or -1, got {list(d.ravel())}")
    return np.where(d < 0, 2 * ARDUSUB_PWM_NEUTRAL - pwm, pwm)


def water_density_from_params(params: dict) -> tuple | None:
    """(rho kg/m^3, note) from ArduSub's ``BARO_SPEC_GRAV`` (specific gravity the autopilot was told; rho = 1000 x
    it), or None when the log does not hold it or holds an implausible value."""
    sg = params.get("BARO_SPEC_GRAV")
    if sg is None or not np.isfinite(sg) or not 0.9 < sg < 1.1:
        return None
    return 1000.0 * sg, (f"water_density: {1000 * sg:.0f} kg/m^3 from log parameter BARO_SPEC_GRAV = {sg:g} (the "
                         f"water the operator configured: 1.0 fresh, 1.024 sea water)")
