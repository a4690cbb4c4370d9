"""Real log formats in and out: ROS bags, MAVLink/dataflash logs, QGC CSV, rostopic CSV -> ``udrobot-run/1`` runs.

:func:`load_any` is what other commands call for ``--input``: it dispatches on the file type.
:func:`convert_log` applies a mapping (``udrobot_ctrl.io.mapping``) to a log and returns a :class:`Run`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from udrobot_ctrl.io.runlog import Run, read_run

from . import mavlink, qgc_csv, rosbag, rostopic_csv
from .mapping import Mapping, MappingError, assemble_run, load_mapping, motor_rules, rule_stream
from .mavlink import (
    DecodedLog,
    OutputEvidence,
    choose_vehicle,
    classify_outputs,
    detect_vehicle,
    motor_command_pwm,
    water_density_from_params,
)
from .qgc_csv import is_qgc_csv
from .streams import LogImportError
from .stretches import cut_run

DEFAULT_MAPPINGS = {"ros": "bluerov2-mavros", "mavlink": "ardusub", "qgc_csv": "qgc-csv"}


def log_kind(path) -> str:
    """'run' (udrobot-run/1 CSV), 'rostopic_csv', 'qgc_csv', 'ros' (bag), 'tlog' or 'bin' from the name and header.

    A ``.csv`` is a QGroundControl telemetry export when its header starts with ``Timestamp,`` (QGC's CSV
    telemetry logging), a ``rostopic echo -p`` export when it starts with ``%time``, else a ``udrobot-run/1`` run.
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

    Returns a dict of streams, or for ``.tlog`` / ``.bin`` a :class:`~udrobot_ctrl.io.mavlink.DecodedLog`
    (streams plus parameters, texts and damage counts).
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


def motor_evidence(mapping: Mapping, streams: dict) -> OutputEvidence | None:
    """:func:`~udrobot_ctrl.io.mavlink.classify_outputs` of the first ``[motors]`` source in the log with any
    logged output (None without one)."""
    if not mapping.motors:
        return None
    servos = range(1, mapping.motors.max_servo + 1)
    for rule in motor_rules(mapping, tuple(servos)):
        stream = rule_stream(rule, streams)
        if stream is not None and any(np.isfinite(stream.fields[f]).any() for f in rule.fields):
            pattern = next(p for s, p, _ in mapping.motors.sources if s == rule.stream)
            return classify_outputs(stream, pattern, mapping.motors.max_servo)
    return None


def convert_log(path, mapping=None, require_inputs: bool = True, vehicle: str | None = None,
                cut: bool = True) -> Run:
    """Convert a log to a :class:`Run` with a mapping (path, shipped name or :class:`Mapping`).

    Without a mapping, bags use ``bluerov2-mavros``, ``.tlog``/``.bin`` use ``ardusub`` and QGC CSV exports
    ``qgc-csv``. For MAVLink/dataflash logs the damage skipped while reading goes to the notes (``damage:``
    lines), the vehicle goes to the sidecar's ``vehicle`` (``vehicle:`` lines say what was read, inferred and
    assumed), and all its motor outputs are mapped to pwm_1..pwm_n in motor order through the mapping's
    ``[motors]`` table. The vehicle is ``vehicle`` when given, else what the log names (FRAME_CONFIG,
    "Frame: ..." texts, SERVOn_FUNCTION), else inferred from the active motor outputs
    (:func:`~udrobot_ctrl.io.mavlink.choose_vehicle`: an ambiguous log is refused, asking for ``vehicle``).
    With a ``[cut]`` table in the mapping and ``cut`` true, the stretches the plant cannot represent (surface,
    disarmed, upside down) are cut out (:func:`~udrobot_ctrl.io.stretches.cut_run`; ``cut:`` notes).

    Parameters
    ----------
    vehicle : str, optional
        Vehicle name (``bluerov2``, ``bluerov2-heavy``, or the mapping's default vehicle): overrides the log.
    cut : bool
        Apply the mapping's ``[cut]`` (False keeps every row).
    """
    kind = log_kind(path)
    if mapping is None:
        source = {"tlog": "mavlink", "bin": "mavlink"}.get(kind, kind)
        if source not in DEFAULT_MAPPINGS:
            raise MappingError(f"{path}: a {kind} log needs an explicit mapping (--mapping)")
        mapping = DEFAULT_MAPPINGS[source]
    mapping = load_mapping(mapping)
    decoded = read_streams(path, mapping)
    if isinstance(decoded, DecodedLog):
        facts = decoded.facts
        default = (mapping.metadata.get("vehicle"), mapping.motors.default_servos if mapping.motors else ())
        evidence = motor_evidence(mapping, decoded.streams)
        vehicle = choose_vehicle(detect_vehicle(facts), evidence, vehicle, default, str(path))
        notes = facts.damage.notes(path) + facts.notes + vehicle.notes
        servos = vehicle.motor_servos
        if not servos and mapping.motors:
            servos = mapping.motors.default_servos
            notes.append(f"vehicle: the log does not say which vehicle it is (no FRAME_CONFIG, no 'Frame:' text); "
                         f"mapping default vehicle {mapping.metadata.get('vehicle', '(none)')!r} with motors on "
                         f"servo {', '.join(map(str, servos))} assumed")
        run = assemble_run(mapping, decoded.streams, str(path), extra_notes=notes, require_inputs=require_inputs,
                           log_params=facts.params, extra_rules=motor_rules(mapping, servos))
        if vehicle.name is not None:
            run.metadata["vehicle"] = vehicle.name
        note = apply_motor_directions(run, facts.params)
        if note:
            run.metadata["notes"] += "\n" + note
        density = water_density_from_params(facts.params)
        if density is not None and "water_density" not in mapping.metadata:
            run.metadata["water_density"] = density[0]
            run.metadata["notes"] += "\n" + density[1]
    else:
        if vehicle is not None:
            raise LogImportError(f"{path}: --vehicle applies to MAVLink / dataflash logs (the outputs of this log "
                                 f"are named by its mapping {mapping.name})")
        run = assemble_run(mapping, decoded, str(path), require_inputs=require_inputs)
    if cut and mapping.cut is not None:
        result = cut_run(run, mapping.cut)
        run = result.run
        run.metadata["notes"] += "\n" + "\n".join(result.notes)
    run.path = str(path)
    return run


def apply_motor_directions(run: Run, params: dict) -> str:
    """Mirror the logged PWM of motors with ``MOT_k_DIRECTION = -1`` about 1500 us, in place; returns the note.

    ArduSub writes 1500 - (command) to a reversed motor (a propeller of the other hand, or swapped wires), so that
    its thrust still follows the command; after mirroring, ``pwm_k`` > 1500 us means positive thrust along
    thruster k's direction in the vehicle model, as the T-200 curve and the model expect
    (:func:`udrobot_ctrl.io.mavlink.motor_command_pwm`). Nothing is changed when the log holds no
    direction parameters or the run's inputs are not PWM.
    """
    if run.input_kind != "pwm":
        return ""
    n = run.inputs.shape[1]
    dirs = [params.get(f"MOT_{k}_DIRECTION") for k in range(1, n + 1)]
    if all(d is None for d in dirs):
        return ""
    known = [1.0 if d is None or not np.isfinite(d) else float(np.sign(d) or 1.0) for d in dirs]
    run.inputs = motor_command_pwm(run.inputs, known)
    reversed_ = [k + 1 for k, d in enumerate(known) if d < 0]
    listed = ", ".join(f"{k + 1}: {'?' if d is None else int(d)}" for k, d in enumerate(dirs))
    return (f"motors: MOT_k_DIRECTION ({listed}) from the log; pwm of reversed motor(s) "
            f"{', '.join(map(str, reversed_)) or 'none'} mirrored about 1500 us (pwm' = 3000 - pwm) so that pwm_k > "
            f"1500 us is thruster k's positive thrust in the vehicle model")


def load_any(path, mapping=None, require_inputs: bool = True, vehicle: str | None = None) -> Run:
    """A :class:`Run` from any supported file: a ``udrobot-run/1`` CSV is read as is, logs are converted.

    Parameters
    ----------
    path : str or Path
        ``.csv`` (udrobot-run/1 or rostopic echo -p), ``.bag``, ``.mcap``, ``.db3``, ROS 2 bag directory,
        ``.tlog`` or ``.bin``.
    mapping : str, Path or Mapping, optional
        For logs; defaults per type as in :func:`convert_log`.
    vehicle : str, optional
        Vehicle of a MAVLink / dataflash log, as in :func:`convert_log`.
    """
    if log_kind(path) == "run":
        return read_run(path)
    return convert_log(path, mapping, require_inputs=require_inputs, vehicle=vehicle)


__all__ = ["load_any", "convert_log", "read_streams", "log_kind", "load_mapping", "LogImportError", "MappingError"]
