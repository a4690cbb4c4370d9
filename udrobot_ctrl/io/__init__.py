"""Real log formats in and out: ROS bags, MAVLink/dataflash logs, rostopic CSV -> ``udrobot-run/1`` runs.

:func:`load_any` is what other commands call for ``--input``: it dispatches on the file type.
:func:`convert_log` applies a mapping (``udrobot_ctrl.io.mapping``) to a log and returns a :class:`Run`.
"""
from __future__ import annotations

from pathlib import Path

from udrobot_ctrl.io.runlog import Run, read_run

from .mapping import Mapping, MappingError, load_mapping
from .streams import LogImportError

DEFAULT_MAPPINGS = {"ros": "bluerov2-mavros", "mavlink": "ardusub"}


def log_kind(path) -> str:
    """'run' (udrobot-run/1 CSV), 'rostopic_csv', 'ros' (bag), 'tlog' or 'bin' from the name (and CSV header)."""
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
        return "rostopic_csv" if head.startswith(b"%time") else "run"
    raise LogImportError(f"{path}: unknown log type (expected .csv, .bag, .mcap, .db3, a ROS 2 bag directory, "
                         f".tlog or .bin)")


def read_streams(path, mapping: Mapping) -> dict:
    """Decode the streams ``mapping`` needs from any supported log."""
    kind = log_kind(path)
    expected = {"ros": "ros", "tlog": "mavlink", "bin": "mavlink", "rostopic_csv": "rostopic_csv"}[kind] \
        if kind != "run" else None
    if kind == "run":
        raise LogImportError(f"{path}: already a udrobot-run/1 CSV; nothing to convert")
    if mapping.source != expected:
        raise MappingError(f"{path}: is a {kind} log but mapping {mapping.name} is for source '{mapping.source}'")
    if kind == "ros":
        from . import rosbag

        return rosbag.read_streams(path, mapping)
    if kind == "tlog":
        from . import mavlink

        return mavlink.read_tlog_streams(path, mapping)
    if kind == "bin":
        from . import mavlink

        return mavlink.read_bin_streams(path, mapping)
    from . import rostopic_csv

    return rostopic_csv.read_streams(path, mapping)


def convert_log(path, mapping=None, require_inputs: bool = True) -> Run:
    """Convert a log to a :class:`Run` with a mapping (path, shipped name or :class:`Mapping`).

    Without a mapping, bags use ``bluerov2-mavros`` and ``.tlog``/``.bin`` use ``ardusub``.
    """
    from .mapping import assemble_run

    kind = log_kind(path)
    if mapping is None:
        source = {"tlog": "mavlink", "bin": "mavlink"}.get(kind, kind)
        if source not in DEFAULT_MAPPINGS:
            raise MappingError(f"{path}: a {kind} log needs an explicit mapping (--mapping)")
        mapping = DEFAULT_MAPPINGS[source]
    mapping = load_mapping(mapping)
    streams = read_streams(path, mapping)
    run = assemble_run(mapping, streams, str(path), require_inputs=require_inputs)
    run.path = str(path)
    return run


def load_any(path, mapping=None, require_inputs: bool = True) -> Run:
    """A :class:`Run` from any supported file: a ``udrobot-run/1`` CSV is read as is, logs are converted.

    Parameters
    ----------
    path : str or Path
        ``.csv`` (udrobot-run/1 or rostopic echo -p), ``.bag``, ``.mcap``, ``.db3``, ROS 2 bag directory,
        ``.tlog`` or ``.bin``.
    mapping : str, Path or Mapping, optional
        For logs; defaults per type as in :func:`convert_log`.
    """
    if log_kind(path) == "run":
        return read_run(path)
    return convert_log(path, mapping, require_inputs=require_inputs)


__all__ = ["load_any", "convert_log", "read_streams", "log_kind", "load_mapping", "LogImportError", "MappingError"]
