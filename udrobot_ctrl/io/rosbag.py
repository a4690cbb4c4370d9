"""ROS 1 (``.bag``) and ROS 2 (directory with ``metadata.yaml``, ``.db3`` or ``.mcap``) bags via ``rosbags``.

No ROS installation is needed. Message types come from the bag itself (ROS 1 connection headers, ROS 2
metadata when recorded with definitions), else from rosbags' ROS 2 Humble store plus the few ``mavros_msgs``
definitions below (so a mavros bag recorded without definitions still decodes).

Field paths: ``orientation.x``, ``channels[2]``, ``header.stamp`` (time values -> float s), ``data``.
Every message of a mapped topic is decoded; any failure is a :class:`LogImportError` naming the topic,
the message index (0-based, in bag order over the mapped topics) and its record time.
"""
from __future__ import annotations

import re
import struct
from pathlib import Path

from .streams import LogImportError, finish_stream

# mavros_msgs definitions (ROS 2 spelling), from mavros' msg/ directory
MAVROS_MSGS = {
    "mavros_msgs/msg/RCOut": "std_msgs/Header header\nuint16[] channels\n",
    "mavros_msgs/msg/RCIn": "std_msgs/Header header\nuint8 rssi\nuint16[] channels\n",
    "mavros_msgs/msg/VFR_HUD": ("std_msgs/Header header\nfloat32 airspeed\nfloat32 groundspeed\nint16 heading\n"
                                "float32 throttle\nfloat32 altitude\nfloat32 climb\n"),
    "mavros_msgs/msg/Altitude": ("std_msgs/Header header\nfloat32 monotonic\nfloat32 amsl\nfloat32 local\n"
                                 "float32 relative\nfloat32 terrain\nfloat32 bottom_clearance\n"),
}

_SEGMENT = re.compile(r"^([A-Za-z_]\w*)(?:\[(\d+)\])?$")


def typestore():
    """rosbags ROS 2 Humble type store with the :data:`MAVROS_MSGS` types added."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {}
    for name, text in MAVROS_MSGS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def get_field(msg, path: str) -> float:
    """Value of a field path in a decoded message, as float (times -> s, bools -> 0/1)."""
    value = msg
    for part in path.split("."):
        m = _SEGMENT.match(part)
        if not m:
            raise KeyError(f"bad field path segment {part!r} in {path!r}")
        value = getattr(value, m.group(1))
        if m.group(2) is not None:
            value = value[int(m.group(2))]
    if hasattr(value, "sec") and hasattr(value, "nanosec"):
        return value.sec + value.nanosec * 1e-9
    return float(value)


def is_bag(path) -> bool:
    """True for a ROS 1 ``.bag``, a ``.mcap``/``.db3`` file or a ROS 2 bag directory."""
    path = Path(path)
    return path.suffix in (".bag", ".mcap", ".db3") or (path.is_dir() and (path / "metadata.yaml").is_file())


def read_streams(path, mapping) -> dict:
    """Decode the topics ``mapping`` needs from a bag into :class:`~udrobot_ctrl.io.streams.Stream` objects."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag1 import ReaderError as Rosbag1Error
    from rosbags.rosbag2 import ReaderError as Rosbag2Error
    from rosbags.serde import SerdeError

    # what rosbags raises on corrupt or truncated data (OverflowError: a huge length read from overwritten
    # bytes); any other exception is a bug and stays one
    bag_errors = (AnyReaderError, Rosbag1Error, Rosbag2Error, SerdeError, OSError, EOFError, struct.error,
                  ValueError, IndexError, KeyError, UnicodeDecodeError, OverflowError)

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such bag")
    bag_path = path.parent if path.suffix in (".mcap", ".db3") and (path.parent / "metadata.yaml").is_file() \
        else path
    needs = mapping.needs()
    data = {topic: {"t": [], "alt": [], "cols": {f: [] for f in fields}, "header": None} for topic, fields in
            needs.items()}
    index = -1
    try:
        reader = AnyReader([bag_path], default_typestore=typestore())
        reader.open()
    except bag_errors as exc:
        raise LogImportError(f"{path}: cannot open bag ({type(exc).__name__}: {exc}); file size "
                             f"{_size(path)} bytes") from exc
    try:
        connections = [c for c in reader.connections if c.topic in needs]
        for index, (conn, stamp_ns, raw) in enumerate(reader.messages(connections=connections)):
            where = f"{path}: message {index} (topic {conn.topic}, record time {stamp_ns} ns)"
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except bag_errors as exc:
                raise LogImportError(f"{where}: cannot decode {conn.msgtype} ({type(exc).__name__}: {exc})") from exc
            entry = data[conn.topic]
            if entry["header"] is None:
                entry["header"] = mapping.time == "header" and hasattr(msg, "header")
            record = stamp_ns * 1e-9
            try:
                if entry["header"]:
                    entry["t"].append(get_field(msg, "header.stamp"))
                    entry["alt"].append(record)
                else:
                    entry["t"].append(record)
                for f, column in entry["cols"].items():
                    column.append(get_field(msg, f))
            except (AttributeError, IndexError, KeyError, TypeError, ValueError) as exc:
                raise LogImportError(f"{where}: field path problem in {conn.msgtype}: {type(exc).__name__}: {exc}") \
                    from exc
    except LogImportError:
        raise
    except bag_errors as exc:
        raise LogImportError(f"{path}: reading failed after message {index} ({type(exc).__name__}: {exc}); "
                             f"the bag is corrupt or truncated, nothing was imported") from exc
    finally:
        reader.close()
    streams = {}
    for topic, entry in data.items():
        if not entry["t"]:
            continue
        if entry["header"]:
            streams[topic] = finish_stream(topic, entry["t"], entry["cols"], "header.stamp", entry["alt"],
                                           "bag record time")
        else:
            streams[topic] = finish_stream(topic, entry["t"], entry["cols"], "bag record time")
    return streams


def _size(path: Path) -> int:
    if path.is_file():
        return path.stat().st_size
    return int(sum(p.stat().st_size for p in path.rglob("*") if p.is_file())) if path.is_dir() else 0


def stream_summary(streams: dict) -> str:
    """One line per stream: samples and rate (for CLI verbose output)."""
    lines = []
    for name, s in streams.items():
        rate = (s.t.size - 1) / (s.t[-1] - s.t[0]) if s.t.size > 1 else float("nan")
        lines.append(f"{name}: {s.t.size} samples, {rate:.1f} Hz, fields {', '.join(s.fields)}")
    return "\n".join(lines) if lines else "(no mapped streams)"


