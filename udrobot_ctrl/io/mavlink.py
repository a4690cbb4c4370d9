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
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from udrobot_ctrl.ardusub.params import usable_log_params

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
#: GPS messages whose fix is counted (LogFacts.fixes): message type -> fix field. Dataflash GPS.Status is
#: AP_GPS::GPS_Status (0 NO_GPS, 1 NO_FIX, 2 2D, 3 3D, ...), MAVLink fix_type is GPS_FIX_TYPE (same numbering)
GPS_FIX_FIELDS = {"GPS": "Status", "GPS_RAW_INT": "fix_type", "GPS2_RAW": "fix_type", "GPS_INPUT": "fix_type"}
#: EKF3 uses a GPS only with a 3D fix (AP_NavEKF3_VehicleStatus.cpp, NavEKF3_core::calcGpsGoodToAlign:
#: gps.status() < AP_GPS::GPS_OK_FIX_3D fails the check)
GPS_FIX_3D = 3
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
    counts : dict of str -> int
        Well-framed frames / records per message type (every type, read or not).
    fixes : dict of str -> (int, int)
        GPS message type -> (samples with a 3D fix or better, samples): dataflash ``GPS`` Status, tlog
        ``GPS_RAW_INT`` / ``GPS2_RAW`` / ``GPS_INPUT`` fix_type (:data:`GPS_FIX_FIELDS`).
    times : dict of str -> list of float
        Log times (s, the streams' clock) of the aiding sensors' records (:data:`SENSOR_RECORDS`, XKFD) and, under
        ``"NAME fix"``, of the GPS samples with a 3D fix: when the EKF had data (:func:`ekf_aiding`).
    """

    params: dict = field(default_factory=dict)
    texts: list = field(default_factory=list)
    named: dict = field(default_factory=dict)
    damage: Damage = field(default_factory=Damage)
    decoded: int = 0
    notes: list = field(default_factory=list)
    counts: dict = field(default_factory=dict)
    fixes: dict = field(default_factory=dict)
    times: dict = field(default_factory=dict)

    def add_fix(self, name: str, fix, t: float) -> None:
        """Count one GPS sample of message type ``name`` at log time ``t`` (s) with fix type ``fix`` (a 3D fix is
        >= 3)."""
        good, n = self.fixes.get(name, (0, 0))
        ok = isinstance(fix, (int, float)) and fix >= GPS_FIX_3D
        self.fixes[name] = (good + int(ok), n + 1)
        if ok:
            self.times.setdefault(f"{name} fix", []).append(t)

    def add_time(self, name: str, t: float) -> None:
        """Note a record of aiding sensor ``name`` at log time ``t`` (s)."""
        self.times.setdefault(name, []).append(t)


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
    counts every frame with a valid CRC, yielded or not; ``tally['types']`` counts them per message type (the
    EKF's aiding is judged from which sensors' messages the log holds: :func:`ekf_aiding`).
    """
    dialect = _dialect()
    x25crc = dialect.x25crc
    tally = {} if tally is None else tally
    tally.setdefault("valid", 0)
    types = tally.setdefault("types", {})
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
                types[known[msg_id].msgname] = types.get(known[msg_id].msgname, 0) + 1
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
                types[known[msg_id].msgname] = types.get(known[msg_id].msgname, 0) + 1
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


#: the EKF's velocity outputs: NavEKF3_core::ConstrainStates (and NavEKF2's) hold every velocity state within
#: +-500 m/s ("velocity limit 500 m/sec"), so a logged value beyond it is a damaged record, not a speed
EKF_VELOCITY_LIMIT = 500.0  # m/s
EKF_VELOCITY_FIELDS = {"XKF1": ("VN", "VE", "VD"), "NKF1": ("VN", "VE", "VD"),
                       "LOCAL_POSITION_NED": ("vx", "vy", "vz")}


def drop_impossible(name: str, cols: dict) -> list:
    """Set the EKF velocities of message ``name`` beyond :data:`EKF_VELOCITY_LIMIT` to nan in ``cols`` (field ->
    list of values, in place); returns the notes (one per field with such samples)."""
    notes = []
    for f in EKF_VELOCITY_FIELDS.get(name.split("[")[0], ()):
        if f not in cols:
            continue
        v = np.asarray(cols[f], float)
        with np.errstate(invalid="ignore"):
            bad = np.abs(v) > EKF_VELOCITY_LIMIT
        if bad.any():
            notes.append(f"{name}.{f}: {int(bad.sum())} of {v.size} samples beyond the EKF's velocity limit of "
                         f"+-{EKF_VELOCITY_LIMIT:g} m/s (NavEKF3_core::ConstrainStates; largest "
                         f"{float(np.max(np.abs(v[bad]))):.3g} m/s): damaged records, read as not measured")
            v[bad] = np.nan
            cols[f] = list(v)
    return notes


def checked_params(facts: LogFacts) -> None:
    """The one check of a log's parameter records (:func:`~udrobot_ctrl.ardusub.params.usable_log_params`), in
    place: a record ArduSub cannot hold (a SCHED_LOOP_RATE of 1e5, a NaN gain) is left out of ``facts.params``
    with a ``parameters:`` note, so ArduSub's default stands in for it and no converter passes it on."""
    facts.params, problems = usable_log_params(facts.params)
    for p in problems:
        facts.notes.append(f"parameters: {p.sentence()}: a damaged or impossible record, left out (ArduSub's "
                           f"default stands in for it)")


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
    wanted = set(data) | {"HEARTBEAT", "PARAM_VALUE", "STATUSTEXT", "NAMED_VALUE_FLOAT"} | set(GPS_FIX_FIELDS) \
        | AIDING_RECORDS
    for index, offset, t, msg in iter_tlog(path, facts.damage, wanted, tally):
        if msg is None:
            unknown += 1
            continue
        mtype = msg.get_type()
        if mtype in GPS_FIX_FIELDS:
            facts.add_fix(mtype, getattr(msg, GPS_FIX_FIELDS[mtype], None), t)
        elif mtype in AIDING_RECORDS:
            facts.add_time(mtype, t)
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
    facts.counts = dict(tally["types"])
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
        impossible = drop_impossible(name, entry["cols"])
        stream = finish_stream(name, t, entry["cols"], "tlog receive time", alt, alt_source)
        stream.notes.extend(impossible)
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
    checked_params(facts)
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
    ``tally['valid']`` counts every well-framed record (FMT included), yielded or not; ``tally['types']`` counts
    them per message name.
    """
    from pymavlink.DFReader import FORMAT_TO_STRUCT, DFFormat, null_term

    format_chars = set(FORMAT_TO_STRUCT)

    data = Path(path).read_bytes()
    damage = Damage() if damage is None else damage
    tally = {} if tally is None else tally
    tally.setdefault("valid", 0)
    types = tally.setdefault("types", {})
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
        types[fmt.name] = types.get(fmt.name, 0) + 1
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

    Raises
    ------
    LogImportError
        Nothing decodes; a ``.bin`` that is a Blue Robotics Ping recording (:func:`ping_viewer_signature`) is named
        as such.
    """
    what = ping_viewer_signature(path)
    if what is not None:
        raise LogImportError(f"{path}: not an ArduPilot dataflash log: {what}; it holds sonar echoes, not the "
                             f"vehicle's motion or commands, so there is nothing to convert")
    needs = mapping.needs()
    optional = optional or {}
    data = {}
    for name in set(needs) | set(optional):
        req = sorted(needs.get(name, ()))
        opt = sorted(set(optional.get(name, ())) - set(req))
        data[name] = {"t": [], "req": req, "opt": opt, "cols": {f: [] for f in req + opt}}
    facts = LogFacts()
    wanted = {name.split("[")[0] for name in data} | {"PARM", "MSG"} | set(GPS_FIX_FIELDS) | AIDING_RECORDS
    tally = {}
    for _index, offset, name, values in iter_dataflash(path, facts.damage, wanted, tally):
        stamp = values.get("TimeUS")
        if name in GPS_FIX_FIELDS and isinstance(stamp, (int, float)):
            facts.add_fix(name, values.get(GPS_FIX_FIELDS[name]), stamp * 1e-6)
        elif name in AIDING_RECORDS and isinstance(stamp, (int, float)):
            facts.add_time(name, stamp * 1e-6)
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
    facts.counts = dict(tally["types"])
    if facts.decoded == 0:
        raise LogImportError(f"{path}: nothing usable decodes (no dataflash record): {facts.damage.summary()}")
    streams = {}
    for name, e in data.items():
        if not e["t"]:
            continue
        lacks = sorted(e.get("lacks", ()))
        cols = {f: v for f, v in e["cols"].items() if f not in lacks}
        impossible = drop_impossible(name, cols)
        streams[name] = finish_stream(name, e["t"], cols, "TimeUS (autopilot boot time)")
        streams[name].notes.extend(impossible)
        if lacks:
            streams[name].notes.append(f"{name}: this log's {name} records have no field(s) {', '.join(lacks)}; "
                                       f"mapping entries that need them are skipped")
    checked_params(facts)
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


# ------------------------------------------------------------------------------------------------ EKF aiding

#: EK3_SRCn_* source values (AP_NavEKF_Source.h, enum classes SourceXY / SourceZ)
EKF_SOURCES = {0: "None", 1: "Baro", 2: "RangeFinder", 3: "GPS", 4: "Beacon", 5: "OpticalFlow", 6: "ExternalNav",
               7: "WheelEncoder"}
#: defaults of EK3_SRC1_POSXY / VELXY / POSZ / VELZ when a log does not hold them (AP_NavEKF_Source.cpp, var_info:
#: POSXY = SourceXY::GPS, VELXY = SourceXY::GPS, POSZ = SourceZ::BARO, VELZ = SourceZ::GPS)
EKF_SOURCE_DEFAULTS = {"POSXY": 3, "VELXY": 3, "POSZ": 1, "VELZ": 3}
#: records of each sensor (dataflash names, MAVLink names) whose presence says the autopilot received its data
SENSOR_RECORDS = {
    "baro": ("BARO", "SCALED_PRESSURE", "SCALED_PRESSURE2", "SCALED_PRESSURE3"),
    "rangefinder": ("RFND", "RANGEFINDER", "DISTANCE_SENSOR"),
    "beacon": ("BCN",),
    "optflow": ("OF", "OPTICAL_FLOW", "OPTICAL_FLOW_RAD"),
    "wheel": ("WENC", "WHEEL_DISTANCE"),
    # external navigation (VISO_TYPE: a DVL or a camera through AP_VisualOdom): velocity / position deltas ...
    "extnav_velocity": ("VISO", "VISV", "VISION_POSITION_DELTA", "VISION_SPEED_ESTIMATE", "ODOMETRY"),
    # ... and positions (VISP: AP_VisualOdom_Backend logs each VISION_POSITION_ESTIMATE it passes on)
    "extnav_position": ("VISP", "VISION_POSITION_ESTIMATE", "GLOBAL_VISION_POSITION_ESTIMATE", "ODOMETRY"),
}
#: XKFD (EKF3 "Body Frame Odometry errors", the innovations of the body-frame odometry it fused) is written only
#: when EKF3 fuses body-frame odometry (a DVL's VISION_POSITION_DELTA, AP_VisualOdom): its presence is evidence that
#: the horizontal velocity was aided even where the log holds no EK3_SRC* / VISO_TYPE parameters
BODY_ODOMETRY_FUSED = "XKFD"


#: the EKF leaves its aided mode (AID_ABSOLUTE -> AID_NONE, dead reckoning) when no position or velocity data has been
#: fused for the shortest of its aiding-loss checks: MIN(tiltDriftTimeMax_ms 15000, posRetryTimeNoVel_ms 7000,
#: posRetryTimeUseVel_ms 10000) = 7 s (AP_NavEKF3.h constants; NavEKF3_core::setAidingMode, case AID_ABSOLUTE)
EKF_AID_TIMEOUT_S = 7.0
#: every record type whose times :class:`LogFacts` keeps (the aiding sensors and the EKF's body-odometry innovations)
AIDING_RECORDS = frozenset(n for names in SENSOR_RECORDS.values() for n in names) | {BODY_ODOMETRY_FUSED}


@dataclass(frozen=True)
class Aiding:
    """Whether an EKF output had a sensor of its quantity (or of its rate) behind it, and why (the parameters and
    records read), as :func:`ekf_aiding` judges it."""

    aided: bool
    why: str


@dataclass(frozen=True)
class AxisAiding:
    """The data the EKF had for one axis (horizontal or vertical): the log times (s) of every delivery of its
    configured sources (a GPS sample with a 3D fix, a DVL delta, a baro sample, ...) and the evidence."""

    times: np.ndarray
    why: str

    def judge(self, label: str, times=None) -> Aiding:
        """Aided when a source delivered within :data:`EKF_AID_TIMEOUT_S` before every one of ``times`` (the run's
        rows, log clock; None: at any time in the log). Rows before the first delivery count as aided when it comes
        within the timeout of the first row (a sensor streaming as the log starts: a log trimmed mid-dive). A run
        aided only part of the time is judged unaided: its other rows are dead reckoning, and the sidecar's kind
        holds for the whole column."""
        if self.times.size == 0:
            return Aiding(False, f"{label} UNAIDED (dead reckoning): {self.why}")
        if times is None:
            return Aiding(True, f"{label} aided: {self.why}")
        t = np.asarray(times, float)
        t = t[np.isfinite(t)]
        delivered = self.times
        if t.size and delivered[0] - t.min() <= EKF_AID_TIMEOUT_S:
            delivered = np.concatenate([[min(t.min(), delivered[0])], delivered])
        k = np.searchsorted(delivered, t, side="right") - 1
        ok = (k >= 0) & (t - delivered[np.maximum(k, 0)] <= EKF_AID_TIMEOUT_S)
        if ok.all():
            return Aiding(True, f"{label} aided: {self.why}")
        return Aiding(False, f"{label} UNAIDED (dead reckoning) in {int((~ok).sum())} of {ok.size} rows (no source "
                             f"data for more than the EKF's {EKF_AID_TIMEOUT_S:g} s timeout): {self.why}")


@dataclass(frozen=True)
class EkfAiding:
    """The aiding of the autopilot's EKF per quantity, from the log's own configuration (:func:`ekf_aiding`).

    Attributes
    ----------
    horizontal, vertical : AxisAiding
        Horizontal (N, E) and vertical (D) velocity and position.
    notes : tuple of str
        ``provenance:`` lines for the run's notes (what was read, what was assumed).
    """

    horizontal: AxisAiding
    vertical: AxisAiding
    notes: tuple = ()

    def of(self, quantity: str, times=None) -> Aiding:
        """The aiding of an EKF output over the log times ``times`` (s; None: anywhere in the log): ``velocity``
        (the NED velocity, rotated to body u, v, w: each mixes the horizontal and vertical components, so it is aided
        only when both are), ``position_xy``, ``position_z``, ``attitude`` (the AHRS/EKF attitude, always aided by the
        gyros, accelerometers and compass)."""
        if quantity == "attitude":
            return Aiding(True, "attitude from the EKF/AHRS, aided by the accelerometers (gravity) and the compass "
                                "(heading)")
        if quantity == "position_xy":
            return self.horizontal.judge("horizontal", times)
        if quantity == "position_z":
            return self.vertical.judge("vertical", times)
        if quantity == "velocity":
            parts = (self.horizontal.judge("horizontal", times), self.vertical.judge("vertical", times))
            if all(a.aided for a in parts):
                return Aiding(True, "; ".join(a.why for a in parts))
            return Aiding(False, "; ".join(a.why for a in parts if not a.aided))
        raise ValueError(f"unknown EKF quantity {quantity!r}; expected velocity, position_xy, position_z or attitude")


def _times(facts: LogFacts, names) -> np.ndarray:
    """Sorted log times (s) of the records ``names``."""
    found = [np.asarray(facts.times[n], float) for n in names if facts.times.get(n)]
    return np.sort(np.concatenate(found)) if found else np.zeros(0)


def _records(facts: LogFacts, kind: str) -> list:
    """(name, count) of the log's records of sensor ``kind`` (:data:`SENSOR_RECORDS`)."""
    return [(n, facts.counts.get(n, len(facts.times.get(n, ())))) for n in SENSOR_RECORDS[kind]
            if facts.counts.get(n) or facts.times.get(n)]


def _gps_fix(facts: LogFacts) -> tuple:
    """(times of the samples with a 3D fix, evidence): the autopilot's own GPS messages (dataflash GPS, tlog
    GPS_RAW_INT) first, else what a companion sent it (GPS_INPUT, e.g. a Water Linked UGPS)."""
    gps_type = facts.params.get("GPS_TYPE")
    if gps_type is not None and gps_type == 0:
        return np.zeros(0), "GPS_TYPE = 0 (no GPS)"
    for name in ("GPS", "GPS_RAW_INT", "GPS2_RAW", "GPS_INPUT"):
        if name in facts.fixes:
            good, n = facts.fixes[name]
            return _times(facts, [f"{name} fix"]), f"{name}: {good} of {n} samples with a 3D fix"
    return np.zeros(0), "no GPS messages in the log" + (f" (GPS_TYPE = {gps_type:g})" if gps_type is not None else "")


def _deliveries(source: int, axis: str, facts: LogFacts) -> tuple:
    """(log times of the data EKF source ``source`` had in this log, evidence) for ``axis`` ``xy`` or ``z``."""
    if source == 0:
        return np.zeros(0), "no source"
    if source == 3:
        return _gps_fix(facts)
    if source == 6:
        viso = facts.params.get("VISO_TYPE")
        if viso is not None and viso == 0:
            return np.zeros(0), "VISO_TYPE = 0 (no visual odometry / DVL)"
        kinds = ("extnav_velocity", "extnav_position") if axis == "xy" else ("extnav_position",)
        names = tuple(dict.fromkeys(n for k in kinds for n in SENSOR_RECORDS[k]))
        recs = [(n, len(facts.times[n])) for n in names if facts.times.get(n)]
        if not recs:
            what = "velocity or position" if axis == "xy" else "position"
            return np.zeros(0), f"no external-navigation {what} records (VISO/VISP/VISION_*)"
        return _times(facts, names), (("VISO_TYPE not in the log; " if viso is None else f"VISO_TYPE = {viso:g}; ")
                                      + ", ".join(f"{n} x{c}" for n, c in recs))
    kind = {1: "baro", 2: "rangefinder", 4: "beacon", 5: "optflow", 7: "wheel"}.get(source)
    if kind is None:
        return np.zeros(0), f"unknown source value {source}"
    recs = _records(facts, kind)
    return _times(facts, SENSOR_RECORDS[kind]), ", ".join(f"{n} x{c}" for n, c in recs) or f"no {kind} records"


def _source_param(facts: LogFacts, name: str, bank: int = 1) -> tuple:
    """(value, text) of EK3_SRC<bank>_<name>, ArduPilot's default when the log does not hold it (bank 1)."""
    key = f"EK3_SRC{bank}_{name}"
    value = facts.params.get(key)
    if value is None or not np.isfinite(value):
        value = EKF_SOURCE_DEFAULTS[name] if bank == 1 else 0
        return value, f"{key} = {value} ({EKF_SOURCES[value]}; not in the log: ArduPilot's default assumed)"
    value = int(value)
    return value, f"{key} = {value} ({EKF_SOURCES.get(value, 'unknown')})"


def ekf_aiding(facts: LogFacts) -> EkfAiding:
    """Which of the EKF's outputs a sensor fed, from the log's own configuration (ArduPilot EKF3).

    The EKF's sources are ``EK3_SRC1_POSXY`` / ``VELXY`` / ``POSZ`` / ``VELZ`` (AP_NavEKF_Source.h: 0 None, 1 Baro,
    2 RangeFinder, 3 GPS, 4 Beacon, 5 OpticalFlow, 6 ExternalNav, 7 WheelEncoder; ArduPilot's defaults
    :data:`EKF_SOURCE_DEFAULTS` where the log lacks them). A source counts only where its sensor delivered data in
    this log: a GPS with a 3D fix (``GPS_TYPE`` not 0; :data:`GPS_FIX_3D`), external navigation with ``VISO_TYPE``
    not 0 and VISO / VISP / VISION_* records (a DVL), a baro with BARO / SCALED_PRESSURE records, and so on
    (:data:`SENSOR_RECORDS`). The horizontal velocity and position are aided when the horizontal velocity source or
    the horizontal position source delivered (a position fix observes the velocity through its rate; a velocity
    sensor such as a DVL makes the position its integral), or when the EKF logged its body-odometry innovations
    (:data:`BODY_ODOMETRY_FUSED`); the vertical ones likewise with VELZ / POSZ. A row is aided when some source
    delivered within :data:`EKF_AID_TIMEOUT_S` before it (:meth:`AxisAiding.judge`). Under water a GPS has no fix:
    an EKF whose horizontal sources are GPS, with ``VISO_TYPE = 0`` and no DVL, dead-reckons
    (``estimated-unaided``). Source sets 2 and 3 (switched by an RC option) are not followed: set 1 is taken as
    active, noted when another set had data.

    Parameters
    ----------
    facts : LogFacts
        Parameters, message counts, record times and GPS fixes of the log.

    Returns
    -------
    EkfAiding
    """
    notes = []
    ekf_type = facts.params.get("AHRS_EKF_TYPE")
    ekf2 = ekf_type is not None and ekf_type == 2
    if ekf2:
        notes.append("provenance: AHRS_EKF_TYPE = 2 (EKF2, no EK3_SRC* parameters): its sources are judged as EKF3's "
                     "defaults (GPS horizontally, baro vertically) plus any external navigation in the log")

    def axis(names, xy, bank=1):
        times, texts = [], []
        for name in names:
            value, text = _source_param(facts, name, bank)
            t, evidence = _deliveries(value, "xy" if xy else "z", facts)
            texts.append(f"{text}: {evidence}")
            times.append(t)
        if ekf2 and xy:
            t, evidence = _deliveries(6, "xy", facts)
            if t.size:
                texts.append(f"external navigation: {evidence}")
                times.append(t)
        return np.sort(np.concatenate(times)), "; ".join(texts)

    h_times, h_why = axis(("VELXY", "POSXY"), True)
    odom = _times(facts, [BODY_ODOMETRY_FUSED])
    if odom.size:
        h_times = np.sort(np.concatenate([h_times, odom]))
        h_why += (f"; the EKF logged {odom.size} {BODY_ODOMETRY_FUSED} records (innovations of the body-frame "
                  f"odometry it fused: a DVL / visual odometry aided it)")
    v_times, v_why = axis(("VELZ", "POSZ"), False)
    aiding = EkfAiding(AxisAiding(h_times, h_why), AxisAiding(v_times, v_why))
    horizontal, vertical = aiding.horizontal.judge("horizontal"), aiding.vertical.judge("vertical")
    for k in (2, 3):
        if not horizontal.aided and any(f"EK3_SRC{k}_{n}" in facts.params for n in ("VELXY", "POSXY")):
            other, _ = axis(("VELXY", "POSXY"), True, k)
            if other.size:
                notes.append(f"provenance: EK3_SRC{k}_VELXY/POSXY had data in this log; source set 1 is taken as the "
                             f"active one (the log does not say whether an RC switch selected set {k})")
    notes.append(f"provenance: EKF {horizontal.why}")
    notes.append(f"provenance: EKF {vertical.why}")
    return replace(aiding, notes=tuple(notes))


# ------------------------------------------------------------------------------------------------ not a dataflash log

#: Ping Viewer (Blue Robotics' application for its Ping echo sounder and Ping360 sonar) writes its sensor logs as
#: ``.bin``: a Qt QDataStream (big-endian) that opens with the QString "PingViewer sensor log file" (uint32 byte
#: length, then UTF-16BE text; bluerobotics/ping-viewer, ``LogSensorStruct::_validHeader``, and its doc
#: "Binary log file structure"); the recorded messages are Ping-protocol frames ("BR", payload length, message id,
#: ..., checksum: docs.bluerobotics.com/ping-protocol)
PING_VIEWER_HEADER = "PingViewer sensor log file"
PING_START = b"BR"


def _ping_frame_at(data: bytes, k: int) -> bool:
    """A whole Ping-protocol frame starts at byte ``k``: 'B' 'R', payload length (uint16 LE), message id (uint16 LE),
    source and destination ids, the payload and a uint16 LE checksum = the byte sum of everything before it."""
    if data[k:k + 2] != PING_START or k + 10 > len(data):
        return False
    n = data[k + 2] | data[k + 3] << 8
    end = k + 8 + n
    if end + 2 > len(data):
        return False
    return (sum(data[k:end]) & 0xFFFF) == (data[end] | data[end + 1] << 8)


def ping_viewer_signature(path) -> str | None:
    """What a ``.bin`` that is not ArduPilot dataflash is, when it is a Blue Robotics Ping recording: a Ping Viewer
    sensor log (its header string, UTF-16BE or UTF-8) or a raw Ping-protocol stream (a checksummed 'BR' frame at the
    start); None otherwise. Reads the first 4 kB only."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head[:2] == DF_HEAD:
        return None
    if PING_VIEWER_HEADER.encode("utf-16-be") in head[:128] or PING_VIEWER_HEADER.encode() in head[:128]:
        return ("a Ping Viewer sensor log (Blue Robotics Ping echo sounder / Ping360 sonar recording, header "
                f"'{PING_VIEWER_HEADER}')")
    if _ping_frame_at(head, 0):
        return "a raw Ping-protocol stream (Blue Robotics Ping echo sounder / Ping360 sonar messages, 'BR' framing)"
    return None
