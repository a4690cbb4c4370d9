"""Which log a file is, and its streams: the format-level steps of a conversion (no mapping applied yet).

:func:`log_kind` tells the format from the name and header, :func:`read_streams` decodes what a mapping needs,
:func:`log_input_files` lists every file a conversion reads and :func:`motor_evidence` classifies the logged
motor outputs. The conversion itself (mapping, vehicle, motor directions, gains) is :mod:`udrobot_ctrl.convert`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from udrobot_ctrl.io import mavlink, qgc_csv, rosbag, rostopic_csv
from udrobot_ctrl.io.mapping import Mapping, MappingError, load_mapping, motor_rules, rule_stream
from udrobot_ctrl.io.mavlink import OutputEvidence, classify_outputs
from udrobot_ctrl.io.qgc_csv import is_qgc_csv
from udrobot_ctrl.io.streams import LogImportError

#: the mapping a log of each source is converted with when none is given (:func:`convert_log`, ``convert --mapping``)
DEFAULT_MAPPINGS = {"ros": "bluerov2-mavros", "mavlink": "ardusub", "qgc_csv": "qgc-csv"}


def log_kind(path) -> str:
    """'run' (udrobot-run/1 CSV), 'rostopic_csv', 'qgc_csv', 'ros' (bag), 'tlog' or 'bin' from the name and header.

    A ``.csv`` is a QGroundControl telemetry export when its header starts with ``Timestamp,`` (QGC's CSV
    telemetry logging), a ``rostopic echo -p`` export when it starts with ``%time``, else a ``udrobot-run/1`` run.

    Parameters
    ----------
    path : str or Path
        The file (or a ROS 2 bag folder).

    Returns
    -------
    str
        The kind of log: ``run``, ``rostopic_csv``, ``qgc_csv``, ``ros``, ``tlog`` or ``bin``.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".bag", ".mcap", ".db3") or (path.is_dir() and (path / "metadata.yaml").is_file()):
        return "ros"
    if suffix == ".tlog":
        return "tlog"
    if suffix == ".bin":
        return "bin"
    if suffix == ".csv":
        with open(path, "rb") as fh:
            head = fh.read(6)
        if head.startswith(b"%time"):
            return "rostopic_csv"
        return "qgc_csv" if is_qgc_csv(path) else "run"
    raise LogImportError(f"{path}: unknown log type (expected .csv, .bag, .mcap, .db3, a ROS 2 bag directory, "
                         f".tlog or .bin)")


def read_streams(path, mapping: Mapping):
    """Decode the streams ``mapping`` needs from any supported log.

    Parameters
    ----------
    path : str or Path
        The log (not a ``udrobot-run/1`` CSV: that is refused).
    mapping : Mapping
        The mapping (its ``source`` must match the log's kind).

    Returns
    -------
    dict or DecodedLog
        Stream name -> :class:`~udrobot_ctrl.io.streams.Stream`, or for ``.tlog`` / ``.bin`` a
        :class:`~udrobot_ctrl.io.mavlink.DecodedLog` (streams plus parameters, texts and damage counts).
    """
    kind = log_kind(path)
    expected = {"ros": "ros", "tlog": "mavlink", "bin": "mavlink", "rostopic_csv": "rostopic_csv",
                "qgc_csv": "qgc_csv"}[kind] if kind != "run" else None
    if kind == "run":
        raise LogImportError(f"{path}: already a udrobot-run/1 CSV; nothing to convert")
    if mapping.source != expected:
        raise MappingError(f"{path}: is a {kind} log but mapping {mapping.name} is for source '{mapping.source}'")
    if kind == "ros":
        return rosbag.read_streams(path, mapping)
    if kind == "tlog":
        return mavlink.read_tlog_streams(path, mapping, mapping.optional_needs())
    if kind == "bin":
        return mavlink.read_bin_streams(path, mapping, mapping.optional_needs())
    if kind == "qgc_csv":
        return qgc_csv.read_streams(path, mapping)

    return rostopic_csv.read_streams(path, mapping)


def log_input_files(path, mapping=None) -> list:
    """Every file converting ``path`` with ``mapping`` reads: outputs must be none of them (``--force`` or not).

    Parameters
    ----------
    path : str or Path
        The log as given to ``convert``.
    mapping : str, Path, Mapping or None
        The ``--mapping`` argument.

    Returns
    -------
    list of Path
        The log; the mapping file if it is a file; for a ``rostopic echo -p`` CSV the other files of its set (the
        mapping's ``[files]`` patterns with the same suffix); for a ROS 2 bag folder, the files in it. A set or a
        mapping that cannot be resolved adds nothing here (the conversion reports it).
    """
    path = Path(path)
    out = [path]
    if mapping is not None and not isinstance(mapping, Mapping) and Path(str(mapping)).is_file():
        out.append(Path(str(mapping)))
    if path.is_dir():
        out += sorted(p for p in path.iterdir() if p.is_file())
        return out
    try:
        kind = log_kind(path)
        if kind == "rostopic_csv":
            if mapping is None:
                return out
            out += [p for p in rostopic_csv.resolve_files(path, load_mapping(mapping).files).values() if p != path]
    except (OSError, LogImportError, MappingError):
        pass
    return out


def motor_evidence(mapping: Mapping, streams: dict) -> OutputEvidence | None:
    """:func:`~udrobot_ctrl.io.mavlink.classify_outputs` of the first ``[motors]`` source in the log with any
    logged output (None without one).

    Parameters
    ----------
    mapping : Mapping
        The mapping (its ``[motors]`` sources).
    streams : dict
        Stream name -> decoded stream of the log.

    Returns
    -------
    OutputEvidence or None
        Which servo outputs are active motors (from their PWM, us), or None when no source is logged.
    """
    if not mapping.motors:
        return None
    servos = range(1, mapping.motors.max_servo + 1)
    for rule in motor_rules(mapping, tuple(servos)):
        stream = rule_stream(rule, streams)
        if stream is not None and any(np.isfinite(stream.fields[f]).any() for f in rule.fields):
            pattern = next(p for s, p, _ in mapping.motors.sources if s == rule.stream)
            return classify_outputs(stream, pattern, mapping.motors.max_servo)
    return None
