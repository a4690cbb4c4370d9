"""Mapping files (``udrobot-mapping/1``, TOML): which stream and field gives each ``udrobot-run/1`` column.

A mapping is read by :func:`load_mapping` (a path or a shipped name: ``ardusub``, ``bluerov2-mavros``,
``tartan-auv``) and applied to decoded streams by :func:`assemble_run`. The format is documented in
docs/mappings.md. In short::

    [mapping]
    format = "udrobot-mapping/1"
    name = "ardusub"
    source = "mavlink"          # mavlink | ros | rostopic_csv
    rate_hz = 50.0              # output time base (uniform); omit to use the samples of `time_base`
    time_base = "ATTITUDE"      # stream whose span (and, without rate_hz, samples) define t
    time = "header"             # ROS: header.stamp when present, else bag record time ("receive")
    max_gap_s = 0.5             # linear interpolation never bridges a gap longer than this ...
    input_kind = "pwm"

    gap_factor = 3.0            # ... or longer than gap_factor x the stream's own median interval, whichever is longer

    [select.z]                  # optional: choose among the alternatives of `z` by evidence (select_by_evidence)
    flat = 0.01
    moving = 0.10
    agree = 0.05
    min_value = -0.1

    [motors]                    # optional: all motor outputs in motor order (servo numbers from the log)
    sources = [{stream = "SERVO_OUTPUT_RAW", field = "servo{n}_raw"}]
    default_servos = [1, 2, 3, 4]

    [[channels]]                # several [[channels]] with the same `to`: the first present in the log wins
                                # (or, with [select.COLUMN], the first that passes the evidence checks)
    to = ["phi", "theta", "psi"]
    stream = "ATTITUDE"
    fields = ["roll", "pitch", "yaw"]
    scale = 1.0                 # value = scale * raw + offset, then `transform`
    transform = "none"          # none | quaternion_to_euler | vector_enu_to_ned | vector_flu_to_frd
                                # | pressure_to_depth | world_to_body (after resampling, needs phi/theta/psi)
                                # | delta_over_dt (3 deltas / interval) | bit (params.bit of an integer field)
    role = "measurement"        # measurement | estimate, for [select.COLUMN]
    keep_if = {orientation = 25}  # only the samples whose field equals the value
    tag = "DVL-measured"        # what kind of source, stated in the notes
    valid = [{field = "Stat", equal = 4, reason = "status not Good"}]  # invalid samples dropped, counted
    lookup = {"10" = 1, "11" = 0}  # raw value -> output value, other samples dropped

    [cut]                       # optional: keep every stretch the plant represents, as segments (io.stretches)
    min_depth = 0.3
    armed_column = "armed"
    upside_down_s = 10.0

Resampling: measured channels linearly (angles unwrapped), inputs and extra columns zero-order hold
(the command logged at t_k holds until the next one). The output t starts at 0; the absolute log time of
t = 0 and every rule actually used go to the sidecar ``notes``; an extra column ``t_source`` holds the
original (log clock) time stamp of the time-base sample at or before each output sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np
import tomllib

from udrobot_ctrl.io.runlog import (
    ANGLE_CHANNELS,
    CHANNELS,
    ESTIMATED,
    MEASURED,
    TAU_COLUMNS,
    UNAIDED,
    Run,
    hold_previous,
    interpolate_linear,
)
from udrobot_files.nesting import too_deep

from .streams import LogImportError, Stream

MAPPING_FORMAT = "udrobot-mapping/1"
SOURCES = ("mavlink", "ros", "rostopic_csv", "qgc_csv")
TRANSFORMS = {
    "none": (None, None),
    "quaternion_to_euler": (4, 3),
    "vector_enu_to_ned": (3, 3),
    "vector_flu_to_frd": (3, 3),
    "pressure_to_depth": (1, 1),
    "world_to_body": (3, 3),
    "delta_over_dt": (4, 3),
    "bit": (1, 1),
}
G = 9.81
AUXILIARY_CHANNELS = ("altitude", "voltage", "ax", "ay", "az")  # never shorten the run to their span
#: what a navigation filter's output estimates (a rule's ``estimates``): its aiding is judged per quantity
#: (:func:`udrobot_ctrl.io.mavlink.ekf_aiding` for ArduPilot's EKF)
ESTIMATES = ("velocity", "position_xy", "position_z", "attitude")
UNAIDED_NOTE = "provenance: unaided: "  # the notes' lines naming estimated-unaided columns (convert prints them)


class MappingError(ValueError):
    """A mapping file that is not valid ``udrobot-mapping/1``; the message names the file and the field."""


@dataclass(frozen=True)
class ValidCheck:
    """One ``valid`` check of a ``[[channels]]`` entry: samples that fail it are dropped and counted by ``reason``.

    A sample fails when its ``field`` value (raw, before ``scale``) is not one of ``ignore`` (values that mean
    "not logged", e.g. ArduPilot's Quality = -1) and: differs from ``equal``, is below ``min`` / above ``max``,
    below / above the sample's own ``min_field`` / ``max_field`` (DISTANCE_SENSOR min_distance / max_distance),
    or below / above ``param_scale`` x the log parameter ``min_param`` / ``max_param`` (RNGFND1_MIN_CM). A field
    the log does not hold skips the check (noted). Bounds are inclusive; nan values fail.
    """

    field: str
    reason: str
    equal: float | None = None
    min: float | None = None
    max: float | None = None
    min_field: str | None = None
    max_field: str | None = None
    min_param: str | None = None
    max_param: str | None = None
    param_scale: float = 1.0
    ignore: tuple = ()

    def fields(self) -> tuple:
        """Stream fields this check reads."""
        return tuple(f for f in (self.field, self.min_field, self.max_field) if f)


@dataclass(frozen=True)
class CutSpec:
    """``[cut]``: rows the plant cannot represent, cut out of a converted run (see :mod:`udrobot_ctrl.io.stretches`).

    Attributes
    ----------
    min_depth : float or None
        m: rows with ``z`` below this are at (or out of) the surface.
    armed_column : str or None
        Extra column holding 1 (armed) / 0 (disarmed); rows where it is 0 are cut.
    upside_down_s : float or None
        s: body z axis pointing up (cos(phi) cos(theta) < 0) for longer than this is cut.
    """

    min_depth: float | None = 0.3
    armed_column: str | None = "armed"
    upside_down_s: float | None = 10.0


@dataclass(frozen=True)
class ChannelRule:
    """One ``[[channels]]`` entry: output column(s) from field(s) of one stream.

    ``tag`` says what kind of source this is (``DVL-measured``, ``EKF-estimated``) in the notes; ``valid`` holds
    :class:`ValidCheck` s (invalid samples dropped, counted per reason); ``lookup`` maps raw values of the first
    field to output values (samples with other values are dropped), e.g. dataflash EV ids 10/11 -> armed 1/0.
    ``estimates`` (one of :data:`ESTIMATES`) names the filter quantity the columns ``estimated_columns`` (all of
    ``to`` when empty) are estimates of: the sidecar's ``channels`` entry says whether a sensor aided it
    (:func:`sidecar_channels`).
    """

    to: tuple
    stream: str
    fields: tuple
    transform: str = "none"
    scale: float = 1.0
    offset: float = 0.0
    frame: str = "ned_frd"
    params: dict = field(default_factory=dict)
    index: int = 0
    role: str = ""
    keep_if: tuple = ()
    tag: str = ""
    valid: tuple = ()
    lookup: tuple = ()
    estimates: str = ""
    estimated_columns: tuple = ()

    def estimated(self, column: str) -> bool:
        """True when ``column`` of this rule is a filter's estimate (role ``estimate``, or named by ``estimates``)."""
        if self.estimates:
            return column in (self.estimated_columns or self.to)
        return self.role == "estimate"

    def source(self, column: str) -> str:
        """Where ``column`` comes from, for the sidecar: ``STREAM.field`` (its own field when fields and outputs
        pair up, else every field of the rule, with the transform)."""
        if self.transform == "none" and len(self.fields) == len(self.to) and column in self.to:
            return f"{self.stream}.{self.fields[self.to.index(column)]}"
        return f"{self.stream}.{'/'.join(self.fields)} ({self.transform})"


@dataclass(frozen=True)
class SelectSpec:
    """``[select.COLUMN]``: pick among the column's candidate rules by evidence (see :func:`select_by_evidence`).

    Attributes
    ----------
    flat : float
        A candidate whose range is below this while the reference moves more than ``moving`` is *flat*.
    moving : float
        Reference range above which a flat candidate is rejected.
    agree : float
        An ``estimate`` whose RMS difference to the reference exceeds max(agree, 3 x reference noise) is rejected.
    min_value : float or None
        Values below this are implausible (depth above the surface); a candidate with more than 5 % of its
        samples below it is rejected.
    """

    flat: float = 0.01
    moving: float = 0.10
    agree: float = 0.05
    min_value: float | None = None


@dataclass(frozen=True)
class MotorSpec:
    """``[motors]``: motor outputs mapped in motor order from the vehicle's servo function map.

    ``sources`` are (stream, field pattern with ``{n}`` = servo number, keep_if) in order of preference;
    ``default_servos`` is used when the log does not say which servo drives which motor.
    """

    sources: tuple
    default_servos: tuple
    max_servo: int = 16


@dataclass(frozen=True)
class Mapping:
    """A parsed mapping file (see the module docstring and docs/mappings.md); :func:`load_mapping` builds it.

    Attributes
    ----------
    name : str
        The mapping's name (``ardusub`` ...).
    source : {'mavlink', 'ros', 'rostopic_csv', 'qgc_csv'}
        The kind of log it reads.
    path : str
        The file it was read from, for the messages.
    rules : tuple of ChannelRule
        The ``[[channels]]`` entries: which stream and fields give each run column.
    rate_hz : float, optional
        Rate of the output time base, Hz; None: the samples of ``time_base``.
    time_base : str, optional
        Stream whose span (and, without ``rate_hz``, samples) define t.
    time : {'header', 'receive'}
        ROS: stamp from the message header when present, else the bag's record time.
    max_gap_s : float
        Interpolation never bridges a gap longer than this, s (or ``gap_factor`` x the stream's median interval).
    input_kind : str, optional
        The run's input kind (``pwm`` ...).
    metadata : dict
        ``[metadata]``: written to the run's sidecar as it is.
    description : str
        What the mapping is for.
    files : dict
        ``[files]``: stream name -> file-name pattern with ``{suffix}`` (``rostopic echo -p`` CSV sets).
    gap_factor : float
        A gap longer than this multiple of a stream's median interval is not bridged (dimensionless).
    select : dict
        Column -> :class:`SelectSpec`: choose among a column's alternatives by evidence.
    motors : MotorSpec, optional
        ``[motors]``: every motor output in motor order.
    cut : CutSpec, optional
        ``[cut]``: the rows the plant cannot represent, cut out of the run.
    """

    name: str
    source: str
    path: str
    rules: tuple
    rate_hz: float | None = None
    time_base: str | None = None
    time: str = "header"
    max_gap_s: float = 0.5
    input_kind: str | None = None
    metadata: dict = field(default_factory=dict)
    description: str = ""
    files: dict = field(default_factory=dict)
    gap_factor: float = 3.0
    select: dict = field(default_factory=dict)
    motors: MotorSpec | None = None
    cut: CutSpec | None = None

    def needs(self) -> dict:
        """Stream name -> set of field paths the mapping reads."""
        out = {}
        for rule in self.rules:
            out.setdefault(rule.stream, set()).update(rule.fields)
            out[rule.stream].update(f for f, _ in rule.keep_if)
        if self.time_base:
            out.setdefault(self.time_base, set())
        return out

    def optional_needs(self) -> dict:
        """Stream name -> fields read when present (nan otherwise): every servo of the ``[motors]`` sources and the
        fields of ``valid`` checks (a firmware that does not log RFND Quality still gives its distances)."""
        out = {}
        for rule in self.rules:
            for check in rule.valid:
                out.setdefault(rule.stream, set()).update(check.fields())
        if self.motors:
            for stream, pattern, keep_if in self.motors.sources:
                out.setdefault(stream, set()).update(pattern.format(n=n) for n in range(1, self.motors.max_servo + 1))
                out[stream].update(f for f, _ in keep_if)
        return out


def shipped_mappings() -> list:
    """Names of the mappings shipped in ``udrobot_ctrl.models/mappings``."""
    root = resources.files("udrobot_ctrl.models") / "mappings"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def load_mapping(name_or_path) -> Mapping:
    """Load a mapping from a TOML path or a shipped name (``ardusub``, ``bluerov2-mavros``, ``tartan-auv``).

    Parameters
    ----------
    name_or_path : str, Path or Mapping
        A shipped name (:func:`shipped_mappings`), a ``udrobot-mapping/1`` TOML path, or a Mapping (returned as
        it is).

    Returns
    -------
    Mapping
        The parsed and checked mapping.

    Raises
    ------
    MappingError
        An unknown name or an invalid file (naming the file and the field).
    """
    if isinstance(name_or_path, Mapping):
        return name_or_path
    text_path = Path(str(name_or_path))
    if text_path.suffix == ".toml" or text_path.exists():
        if not text_path.is_file():
            raise MappingError(f"{text_path}: mapping file not found")
        return parse_mapping(text_path.read_text(encoding="utf-8"), str(text_path))
    root = resources.files("udrobot_ctrl.models") / "mappings" / f"{name_or_path}.toml"
    if not root.is_file():
        raise MappingError(f"unknown mapping {name_or_path!r}: not a file and not a shipped mapping "
                           f"({', '.join(shipped_mappings())})")
    return parse_mapping(root.read_text(encoding="utf-8"), f"shipped mapping {name_or_path}")


def _as_tuple(value, where, what):
    if isinstance(value, str):
        return (value,)
    if isinstance(value, list) and value and all(isinstance(v, str) and v for v in value):
        return tuple(value)
    raise MappingError(f"{where}: '{what}' must be a non-empty string or list of strings, got {value!r}")


def _number(table, key, default, where, positive=False):
    value = table.get(key, default)
    if value is None:
        return None
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) \
            or (positive and value <= 0):
        raise MappingError(f"{where}: '{key}' must be a finite {'positive ' if positive else ''}number, got {value!r}")
    return float(value)


def _valid_output(name: str) -> bool:
    return name in CHANNELS or name in TAU_COLUMNS or name.startswith(("thrust_", "pwm_")) or name.isidentifier()


def parse_mapping(text: str, source_name: str = "mapping") -> Mapping:
    """Parse and validate mapping TOML text; errors name ``source_name`` and the offending field."""
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MappingError(f"{source_name}: invalid TOML ({exc})") from exc
    except RecursionError:
        raise MappingError(str(too_deep(source_name, "TOML"))) from None
    head = doc.get("mapping")
    if not isinstance(head, dict):
        raise MappingError(f"{source_name}: missing [mapping] table")
    where = f"{source_name}: [mapping]"
    if head.get("format") != MAPPING_FORMAT:
        raise MappingError(f"{where}: 'format' must be {MAPPING_FORMAT!r}, got {head.get('format')!r}")
    source = head.get("source")
    if source not in SOURCES:
        raise MappingError(f"{where}: 'source' must be one of {SOURCES}, got {source!r}")
    time = head.get("time", "header")
    if time not in ("header", "receive"):
        raise MappingError(f"{where}: 'time' must be 'header' or 'receive', got {time!r}")
    input_kind = head.get("input_kind")
    if input_kind not in (None, "thrust", "pwm", "tau"):
        raise MappingError(f"{where}: 'input_kind' must be thrust, pwm or tau, got {input_kind!r}")
    rules = []
    entries = doc.get("channels", [])
    if not isinstance(entries, list) or not entries:
        raise MappingError(f"{source_name}: no [[channels]] entries")
    for i, entry in enumerate(entries):
        w = f"{source_name}: channels[{i}]"
        unknown = set(entry) - {"to", "stream", "field", "fields", "transform", "scale", "offset", "frame", "params",
                                "comment", "role", "keep_if", "tag", "valid", "lookup", "estimates",
                                "estimated_columns"}
        if unknown:
            raise MappingError(f"{w}: unknown key(s) {sorted(unknown)}")
        if "to" not in entry or "stream" not in entry or ("field" in entry) == ("fields" in entry):
            raise MappingError(f"{w}: needs 'to', 'stream' and exactly one of 'field' / 'fields'")
        to = _as_tuple(entry["to"], w, "to")
        for name in to:
            if not _valid_output(name):
                raise MappingError(f"{w}: output column {name!r} is not a udrobot-run/1 column or identifier")
        fields = _as_tuple(entry.get("fields", entry.get("field")), w, "fields")
        transform = entry.get("transform", "none")
        if transform not in TRANSFORMS:
            raise MappingError(f"{w}: unknown transform {transform!r}; expected one of {', '.join(TRANSFORMS)}")
        n_in, n_out = TRANSFORMS[transform]
        if n_in is None and len(fields) != len(to):
            raise MappingError(f"{w}: {len(fields)} fields for {len(to)} outputs; they must pair up")
        if n_in is not None and (len(fields) != n_in or len(to) != n_out):
            raise MappingError(f"{w}: transform {transform} takes {n_in} fields and gives {n_out} outputs "
                               f"(got {len(fields)} and {len(to)})")
        frame = entry.get("frame", "ned_frd")
        if frame not in ("ned_frd", "enu_flu"):
            raise MappingError(f"{w}: 'frame' must be 'ned_frd' or 'enu_flu', got {frame!r}")
        params = entry.get("params", {})
        if not isinstance(params, dict):
            raise MappingError(f"{w}: 'params' must be a table")
        role = entry.get("role", "")
        if role not in ("", "measurement", "estimate"):
            raise MappingError(f"{w}: 'role' must be 'measurement' or 'estimate', got {role!r}")
        keep_if = entry.get("keep_if", {})
        if not isinstance(keep_if, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                    for v in keep_if.values()):
            raise MappingError(f"{w}: 'keep_if' must be a table of field = number (samples kept where equal)")
        tag = entry.get("tag", "")
        if not isinstance(tag, str):
            raise MappingError(f"{w}: 'tag' must be a string (e.g. 'DVL-measured')")
        lookup = entry.get("lookup", {})
        if not isinstance(lookup, dict) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                   for v in lookup.values()):
            raise MappingError(f"{w}: 'lookup' must be a table of \"raw value\" = number")
        try:
            lookup = tuple(sorted((float(k), float(v)) for k, v in lookup.items()))
        except ValueError:
            raise MappingError(f"{w}: 'lookup' keys must be numbers written as strings, got {sorted(lookup)}") \
                from None
        if lookup and len(fields) != 1:
            raise MappingError(f"{w}: 'lookup' maps one field; got {len(fields)}")
        estimates = entry.get("estimates", "")
        if estimates not in ("",) + ESTIMATES:
            raise MappingError(f"{w}: 'estimates' must be one of {', '.join(ESTIMATES)}, got {estimates!r}")
        estimated = _as_tuple(entry["estimated_columns"], w, "estimated_columns") if "estimated_columns" in entry \
            else ()
        if estimated and (not estimates or set(estimated) - set(to)):
            raise MappingError(f"{w}: 'estimated_columns' must be outputs of the entry ({', '.join(to)}) and needs "
                               f"'estimates'")
        rules.append(ChannelRule(to=to, stream=str(entry["stream"]), fields=fields, transform=transform,
                                 scale=_number(entry, "scale", 1.0, w), offset=_number(entry, "offset", 0.0, w),
                                 frame=frame, params=params, index=i, role=role,
                                 keep_if=tuple(sorted((str(k), float(v)) for k, v in keep_if.items())),
                                 tag=tag, valid=_valid_checks(entry.get("valid", []), w), lookup=lookup,
                                 estimates=estimates, estimated_columns=estimated))
    files = doc.get("files", {})
    if not isinstance(files, dict) or not all(isinstance(v, str) and "{suffix}" in v for v in files.values()):
        raise MappingError(f"{source_name}: [files] must map stream names to patterns containing '{{suffix}}'")
    metadata = doc.get("metadata", {})
    if not isinstance(metadata, dict):
        raise MappingError(f"{source_name}: [metadata] must be a table")
    select = {}
    sel_doc = doc.get("select", {})
    if not isinstance(sel_doc, dict):
        raise MappingError(f"{source_name}: [select] must hold [select.COLUMN] tables")
    for column, table in sel_doc.items():
        w = f"{source_name}: [select.{column}]"
        if not isinstance(table, dict) or set(table) - {"flat", "moving", "agree", "min_value"}:
            raise MappingError(f"{w}: keys are flat, moving, agree, min_value (numbers)")
        select[column] = SelectSpec(flat=_number(table, "flat", 0.01, w, positive=True),
                                    moving=_number(table, "moving", 0.10, w, positive=True),
                                    agree=_number(table, "agree", 0.05, w, positive=True),
                                    min_value=_number(table, "min_value", None, w))
    motors = None
    if "motors" in doc:
        m = doc["motors"]
        w = f"{source_name}: [motors]"
        if not isinstance(m, dict) or not isinstance(m.get("sources"), list) or not m["sources"]:
            raise MappingError(f"{w}: needs sources = [{{stream = ..., field = \"...{{n}}...\"}}, ...]")
        sources = []
        for src in m["sources"]:
            if not isinstance(src, dict) or not isinstance(src.get("stream"), str) \
                    or not isinstance(src.get("field"), str) or "{n}" not in src["field"]:
                raise MappingError(f"{w}: each source needs 'stream' and a 'field' pattern containing {{n}}")
            keep_if = src.get("keep_if", {})
            if not isinstance(keep_if, dict) or not all(isinstance(v, (int, float)) for v in keep_if.values()):
                raise MappingError(f"{w}: a source's 'keep_if' must be a table of field = number")
            sources.append((src["stream"], src["field"], tuple(sorted((k, float(v)) for k, v in keep_if.items()))))
        default = m.get("default_servos", [])
        if not isinstance(default, list) or not all(isinstance(k, int) and k >= 1 for k in default):
            raise MappingError(f"{w}: default_servos must be a list of servo numbers >= 1")
        motors = MotorSpec(sources=tuple(sources), default_servos=tuple(default),
                           max_servo=int(_number(m, "max_servo", 16, w, positive=True)))
    cut = None
    if "cut" in doc:
        c = doc["cut"]
        w = f"{source_name}: [cut]"
        if not isinstance(c, dict) or set(c) - {"min_depth", "armed_column", "upside_down_s"}:
            raise MappingError(f"{w}: keys are min_depth (m), armed_column (a column name), upside_down_s (s)")
        armed = c.get("armed_column")
        if armed is not None and not (isinstance(armed, str) and armed.isidentifier()):
            raise MappingError(f"{w}: 'armed_column' must be a column name, got {armed!r}")
        cut = CutSpec(min_depth=_number(c, "min_depth", None, w), armed_column=armed,
                      upside_down_s=_number(c, "upside_down_s", None, w, positive=True))
    return Mapping(name=str(head.get("name", source_name)), source=source, path=source_name, rules=tuple(rules),
                   rate_hz=_number(head, "rate_hz", None, where, positive=True),
                   time_base=head.get("time_base"), time=time,
                   max_gap_s=_number(head, "max_gap_s", 0.5, where, positive=True), input_kind=input_kind,
                   metadata=metadata, description=str(head.get("description", "")), files=files,
                   gap_factor=_number(head, "gap_factor", 3.0, where, positive=True), select=select, motors=motors,
                   cut=cut)


_CHECK_KEYS = {"field", "reason", "equal", "min", "max", "min_field", "max_field", "min_param", "max_param",
               "param_scale", "ignore"}


def _valid_checks(entries, where) -> tuple:
    """``valid = [{field = ..., reason = ..., min = ...}, ...]`` -> tuple of :class:`ValidCheck`."""
    if not isinstance(entries, list):
        raise MappingError(f"{where}: 'valid' must be a list of tables {{field = ..., reason = ..., ...}}")
    checks = []
    for k, e in enumerate(entries):
        w = f"{where}: valid[{k}]"
        if not isinstance(e, dict) or set(e) - _CHECK_KEYS or not isinstance(e.get("field"), str) \
                or not isinstance(e.get("reason"), str):
            raise MappingError(f"{w}: needs 'field' and 'reason' (strings); other keys: "
                               f"{', '.join(sorted(_CHECK_KEYS - {'field', 'reason'}))}")
        for key in ("min_field", "max_field", "min_param", "max_param"):
            if key in e and not isinstance(e[key], str):
                raise MappingError(f"{w}: '{key}' must be a field / parameter name")
        ignore = e.get("ignore", [])
        if not isinstance(ignore, list) or not all(isinstance(v, (int, float)) for v in ignore):
            raise MappingError(f"{w}: 'ignore' must be a list of numbers")
        checks.append(ValidCheck(field=e["field"], reason=e["reason"], equal=_number(e, "equal", None, w),
                                 min=_number(e, "min", None, w), max=_number(e, "max", None, w),
                                 min_field=e.get("min_field"), max_field=e.get("max_field"),
                                 min_param=e.get("min_param"), max_param=e.get("max_param"),
                                 param_scale=_number(e, "param_scale", 1.0, w, positive=True),
                                 ignore=tuple(float(v) for v in ignore)))
    return tuple(checks)


# ------------------------------------------------------------------------------------------- transforms

_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def quaternion_to_rotation(qx, qy, qz, qw) -> np.ndarray:
    """(m, 3, 3) rotation matrices (body -> world) from unit quaternions (normalised here; zero norm -> nan)."""
    q = np.stack([qx, qy, qz, qw], axis=-1).astype(float)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(norm > 0, q / norm, np.nan)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def rotation_to_euler(R: np.ndarray) -> tuple:
    """ZYX Euler angles (phi, theta, psi), rad, of body -> world rotation matrices (Fossen convention)."""
    phi = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    theta = -np.arcsin(np.clip(R[..., 2, 0], -1.0, 1.0))
    psi = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return phi, theta, psi


def quaternion_to_euler(qx, qy, qz, qw, frame="ned_frd") -> tuple:
    """Quaternion (x, y, z, w) -> (phi, theta, psi) rad in NED/FRD.

    ``frame='enu_flu'`` is the ROS convention (REP-103/105: world ENU, body FLU, as mavros publishes); it is
    converted with R_ned_frd = A R_enu_flu B, A = ENU->NED axis swap, B = diag(1, -1, -1).
    """
    R = quaternion_to_rotation(qx, qy, qz, qw)
    if frame == "enu_flu":
        R = _ENU_TO_NED @ R @ _FLU_TO_FRD
    return rotation_to_euler(R)


P_ATM_STD = 101325.0  # Pa, ISA sea-level standard atmosphere
P_ATM_MAX = 105000.0  # Pa, above any sea-level weather: a higher minimum pressure was never at the surface
MID_DIVE_M = 0.5  # m: a first sample this much deeper than the log's shallowest point means a mid-dive start


@dataclass(frozen=True)
class SurfaceReference:
    """Surface pressure used for a depth, and why (for the notes)."""

    pressure_pa: float
    reason: str


def surface_reference(pressure_pa, rho: float, params: dict, log_params: dict) -> SurfaceReference:
    """Choose the surface (zero-depth) pressure of an absolute-pressure series, by evidence.

    Order: a number in ``params.surface_pressure_pa``; the log parameters named in ``params.surface_params``
    (ArduSub ``BARO2_GND_PRESS``: the autopilot's own surface calibration of the external sensor); then the
    log itself: the first samples (median of the first 5, assumed pre-dive) unless the log starts mid-dive
    (first sample more than 0.5 m of water deeper than the shallowest point: the shallowest point is then
    taken as the surface when it is below 1050 hPa, else the standard atmosphere 1013.25 hPa is assumed).
    ``surface_pressure_pa = "first"`` forces the first sample.
    """
    p = np.asarray(pressure_pa, dtype=float)
    finite = p[np.isfinite(p)]
    if finite.size == 0:
        raise LogImportError("no finite pressure sample to take the surface pressure from")
    p0 = params.get("surface_pressure_pa", "log")
    if isinstance(p0, (int, float)) and not isinstance(p0, bool):
        return SurfaceReference(float(p0), f"surface pressure {p0:.0f} Pa given by the mapping")
    if p0 == "first":
        return SurfaceReference(float(finite[0]), "first sample, assumed taken at the surface (mapping says 'first')")
    for name in params.get("surface_params", []):
        value = log_params.get(name)
        if value is not None and np.isfinite(value) and 50_000.0 < value < 150_000.0:
            return SurfaceReference(float(value), f"log parameter {name} = {value:.0f} Pa (the autopilot's surface "
                                                  f"calibration)")
    first = float(np.median(finite[:5]))
    k = min(5, finite.size)
    shallow = float(np.min(np.convolve(finite, np.ones(k) / k, mode="valid")))  # 5-sample mean: noise-robust
    metre = rho * G
    if first - shallow > MID_DIVE_M * metre:
        if shallow < P_ATM_MAX:
            return SurfaceReference(shallow, f"log starts mid-dive (first samples {(first - shallow) / metre:.2f} m "
                                             f"deeper than the shallowest point); the shallowest point "
                                             f"({shallow / 100:.1f} hPa) is taken as the surface (assumed)")
        return SurfaceReference(P_ATM_STD, f"log starts mid-dive and never reaches the surface (shallowest "
                                           f"{shallow / 100:.1f} hPa > {P_ATM_MAX / 100:.0f} hPa); standard atmosphere "
                                           f"1013.25 hPa assumed (about 1 cm of depth error per hPa of weather)")
    if first > P_ATM_MAX:
        return SurfaceReference(P_ATM_STD, f"first samples at {first / 100:.1f} hPa, far above atmospheric: the log "
                                           f"starts under water; standard atmosphere 1013.25 hPa assumed (about "
                                           f"1 cm of depth error per hPa of weather)")
    return SurfaceReference(first, f"median of the first samples ({first / 100:.1f} hPa), assumed taken at the "
                                   f"surface before the dive (no surface-pressure parameter in the log)")


def water_density(params: dict, log_params: dict) -> tuple:
    """(rho kg/m^3, reason): 1000 x log parameter ``params.specific_gravity_param`` (ArduSub BARO_SPEC_GRAV), else
    ``params.water_density`` (default 1000, fresh water assumed)."""
    name = params.get("specific_gravity_param")
    value = log_params.get(name) if name else None
    if value is not None and np.isfinite(value) and 0.9 < value < 1.1:
        return 1000.0 * value, f"rho = 1000 x {name} ({value:g}) = {1000 * value:.0f} kg/m^3"
    rho = params.get("water_density", 1000.0)
    if not isinstance(rho, (int, float)) or rho <= 0:
        raise MappingError("params water_density must be a positive number")
    return float(rho), f"rho = {rho:g} kg/m^3 (mapping default{'; no ' + name + ' in the log' if name else ''})"


def pressure_to_depth(pressure_pa, params: dict, where: str, log_params: dict | None = None) -> tuple:
    """Depth (m, positive down) from absolute pressure (Pa): (p - p_surface) / (rho g), and the notes.

    The surface pressure follows :func:`surface_reference`, the density :func:`water_density`.
    """
    pressure_pa = np.asarray(pressure_pa, dtype=float)
    log_params = log_params or {}
    rho, rho_reason = water_density(params, log_params)
    try:
        ref = surface_reference(pressure_pa, rho, params, log_params)
    except LogImportError as exc:
        raise LogImportError(f"{where}: {exc}") from exc
    depth = (pressure_pa - ref.pressure_pa) / (rho * G)
    notes = []
    finite = depth[np.isfinite(depth)]
    if ref.reason.startswith("log parameter") and finite.size and np.mean(finite < -0.1) > 0.05:
        # the autopilot's calibration does not fit this log (recalibrated, sensor swapped): use the log's own
        own = surface_reference(pressure_pa, rho, {**params, "surface_params": []}, log_params)
        notes.append(f"{ref.reason} puts {100 * np.mean(finite < -0.1):.0f} % of the samples more than 0.1 m above "
                     f"the surface: not used")
        ref = own
        depth = (pressure_pa - ref.pressure_pa) / (rho * G)
        finite = depth[np.isfinite(depth)]
    notes.insert(0, f"surface reference {ref.pressure_pa / 100:.2f} hPa: {ref.reason}; {rho_reason}, g = {G} m/s^2")
    if finite.size and np.mean(finite < -0.1) > 0.05:
        notes.append(f"{100 * np.mean(finite < -0.1):.0f} % of the depth samples are more than 0.1 m above the "
                     f"surface (min {finite.min():.2f} m): the surface reference is wrong for this log")
    return depth, notes


def _apply_rule(rule: ChannelRule, stream: Stream, where: str, log_params: dict | None = None) -> tuple:
    """(outputs on the stream's own samples, notes) of one rule (world_to_body deferred: raw NED values)."""
    try:
        raw = [stream.fields[f] * rule.scale + rule.offset for f in rule.fields]
    except KeyError as exc:
        raise LogImportError(f"{where}: stream '{stream.name}' has no field {exc.args[0]!r} "
                             f"(fields: {', '.join(sorted(stream.fields))})") from exc
    tr = rule.transform
    if tr == "none":
        return dict(zip(rule.to, raw)), []
    if tr == "quaternion_to_euler":
        return dict(zip(rule.to, quaternion_to_euler(*raw, frame=rule.frame))), []
    if tr == "pressure_to_depth":
        depth, notes = pressure_to_depth(raw[0], rule.params, where, log_params)
        return {rule.to[0]: depth}, notes
    if tr == "bit":
        bit = rule.params.get("bit")
        if not isinstance(bit, int) or isinstance(bit, bool) or not 0 <= bit < 64:
            raise MappingError(f"{where}: channels[{rule.index}] transform bit needs params.bit (0..63), got {bit!r}")
        with np.errstate(invalid="ignore"):
            value = np.where(np.isfinite(raw[0]), np.floor(raw[0] / 2.0**bit) % 2, np.nan)
        return {rule.to[0]: value}, []
    if tr == "delta_over_dt":
        dt = _delta_interval(rule, stream)
        with np.errstate(invalid="ignore", divide="ignore"):
            rates = [np.where(dt > 0, d / dt, np.nan) for d in raw[:3]]
        bad = int(np.sum(~(dt > 0)))
        notes = [f"{bad} samples with a non-positive interval {rule.fields[3]} -> nan"] if bad else []
        return dict(zip(rule.to, rates)), notes
    vec = np.stack(raw, axis=-1)
    if tr == "vector_enu_to_ned":
        vec = vec @ _ENU_TO_NED.T
    elif tr == "vector_flu_to_frd":
        vec = vec @ _FLU_TO_FRD.T
    elif tr == "world_to_body" and rule.frame == "enu_flu":
        vec = vec @ _ENU_TO_NED.T
    return dict(zip(rule.to, vec.T)), []


def _delta_interval(rule: ChannelRule, stream: Stream) -> np.ndarray:
    """Interval (s) of a ``delta_over_dt`` rule: its 4th field x ``params.dt_scale`` (1e-6 for a us field)."""
    scale = rule.params.get("dt_scale", 1.0)
    if not isinstance(scale, (int, float)) or isinstance(scale, bool) or not scale > 0:
        raise MappingError(f"channels[{rule.index}] ({rule.stream}): params.dt_scale must be a positive number")
    return stream.fields[rule.fields[3]] * float(scale)


def _euler_rotation(phi, theta, psi) -> np.ndarray:
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    return np.stack([
        np.stack([cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st], -1),
        np.stack([sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf], -1),
        np.stack([-st, ct * sf, ct * cf], -1),
    ], -2)


# ------------------------------------------------------------------------------------------- assembly


def median_interval(t) -> float:
    """Median of the positive sample intervals of a stream, s (nan with fewer than two distinct times)."""
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[dt > 0]
    return float(np.median(dt)) if dt.size else float("nan")


def gap_limit(t, mapping: Mapping) -> float:
    """Longest interval linear interpolation bridges for a stream: max(max_gap_s, gap_factor x its median interval).

    A slow but steady stream (2 Hz SERVO_OUTPUT_RAW / SCALED_PRESSURE2 in default QGC telemetry) is thus
    interpolated between its samples instead of turning into mostly nan; a real gap (several missed samples)
    still becomes nan.
    """
    med = median_interval(t)
    return max(mapping.max_gap_s, mapping.gap_factor * med) if np.isfinite(med) else mapping.max_gap_s


def _interp_gapped(t, y, t_new, max_gap, angle):
    out = interpolate_linear(t, y, t_new, angle=angle)
    if t.size > 1:
        i0 = np.clip(np.searchsorted(t, t_new, side="right") - 1, 0, t.size - 2)
        exact = np.isin(t_new, t)
        out[(t[i0 + 1] - t[i0] > max_gap) & ~exact] = np.nan
    return out


@dataclass
class Candidate:
    """One present source of an output column, evaluated on its own samples."""

    rule: ChannelRule
    t: np.ndarray
    y: np.ndarray
    verdict: str = ""

    @property
    def label(self) -> str:
        return f"{self.rule.stream}[{','.join(self.rule.fields)}]"


def _noise(y) -> float:
    """Sample-to-sample noise (robust std of the first difference / sqrt 2) of a series."""
    d = np.diff(y[np.isfinite(y)])
    if d.size < 3:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def select_by_evidence(column: str, candidates: list, spec: SelectSpec) -> tuple:
    """Pick one of the present sources of ``column`` by checking them against each other.

    Checks, in order: mostly nan (> 50 %) -> rejected; more than 5 % of samples below ``spec.min_value``
    (e.g. a depth above the surface) -> rejected. The first remaining ``measurement`` is the reference. Any
    other candidate is *flat* (rejected) when its range is below ``spec.flat`` while the reference moves more
    than ``spec.moving``, or when it is exactly constant while the reference moves more than 5x its noise; an
    ``estimate`` whose RMS difference to the reference exceeds max(``spec.agree``, 3 x reference noise) is
    rejected (noisy or offset). The first candidate (mapping order) that passes wins; if none passes, the
    first present one is used and the notes say so.

    Returns
    -------
    (Candidate, list of str)
        The winner and the ``source:`` note lines naming every candidate's verdict.
    """
    ok = []
    for c in candidates:
        fin = np.isfinite(c.y)
        if fin.mean() < 0.5:
            c.verdict = f"rejected: mostly nan ({100 * (1 - fin.mean()):.0f} % of its samples)"
        elif spec.min_value is not None and np.mean(c.y[fin] < spec.min_value) > 0.05:
            c.verdict = (f"rejected: {100 * np.mean(c.y[fin] < spec.min_value):.0f} % of samples below "
                         f"{spec.min_value:g} (implausible, e.g. above the surface)")
        else:
            ok.append(c)
    ref = next((c for c in ok if c.rule.role == "measurement"), None)
    if ref is not None:
        ref_y = ref.y[np.isfinite(ref.y)]
        ref_range, ref_noise = float(np.ptp(ref_y)), _noise(ref.y)
    for c in ok:
        y = c.y[np.isfinite(c.y)]
        rng = float(np.ptp(y))
        if ref is None or c is ref:
            c.verdict = f"ok ({'measurement, the reference' if c is ref else 'no measurement to check it against'};" \
                        f" range {y.min():.3f}..{y.max():.3f})"
            continue
        if (rng < spec.flat and ref_range > spec.moving) or (rng == 0.0 and ref_range > 5 * ref_noise > 0):
            c.verdict = (f"rejected: flat (range {rng:.3f}) while {ref.label} moves {ref_range:.3f} "
                         f"(its noise {ref_noise:.4f})")
            continue
        inside = (c.t >= ref.t[0]) & (c.t <= ref.t[-1])
        yr = np.interp(c.t[inside], ref.t, ref.y)
        d = c.y[inside] - yr
        d = d[np.isfinite(d)]
        rms = float(np.sqrt(np.mean(d**2))) if d.size else float("nan")
        tol = max(spec.agree, 3 * ref_noise)
        if c.rule.role == "estimate" and not rms <= tol:
            c.verdict = (f"rejected: disagrees with {ref.label} by RMS {rms:.3f} > {tol:.3f} (noisy or offset "
                         f"estimate; range {y.min():.3f}..{y.max():.3f})")
        else:
            c.verdict = f"ok (agrees with {ref.label} within RMS {rms:.3f}; range {y.min():.3f}..{y.max():.3f})"
    winner = next((c for c in candidates if c.verdict.startswith("ok")), None)
    notes = []
    if winner is None:
        winner = candidates[0]
        notes.append(f"source: {column}: no candidate passed the checks; {winner.label} used anyway")
    else:
        notes.append(f"source: {column} <- {winner.label}, chosen by evidence: {winner.verdict}")
    for c in candidates:
        if c is not winner:
            notes.append(f"source: {column} candidate {c.label} not used: {c.verdict}")
    return winner, notes


def motor_rules(mapping: Mapping, servos) -> list:
    """Input rules pwm_1..pwm_n (motor order) from the ``[motors]`` sources for the given servo numbers."""
    if not mapping.motors or not servos:
        return []
    to = tuple(f"pwm_{k}" for k in range(1, len(servos) + 1))
    return [ChannelRule(to=to, stream=stream, fields=tuple(pattern.format(n=n) for n in servos),
                        index=-1 - i, role="", keep_if=keep_if)
            for i, (stream, pattern, keep_if) in enumerate(mapping.motors.sources)]


def _is_input(name: str) -> bool:
    return name in TAU_COLUMNS or name.startswith(("thrust_", "pwm_"))


def _input_layout(mapping: Mapping, found, where, require_inputs: bool, rules=None):
    """(kind, columns, notes) of the run's inputs; columns the mapping names but the log lacks -> error or nan."""
    rules = mapping.rules if rules is None else rules
    mapped = [n for r in rules for n in r.to if _is_input(n)]
    kinds = {("tau" if n in TAU_COLUMNS else n.split("_")[0]) for n in mapped} or \
        ({mapping.input_kind} if mapping.input_kind else set())
    if len(kinds) != 1:
        raise LogImportError(f"{where}: the mapping must give one kind of input columns (all thrust_i, all pwm_i "
                             f"or all six tau_*), got {sorted(set(mapped)) or 'none'}")
    kind = kinds.pop()
    n = len(TAU_COLUMNS) if kind == "tau" else max(len(dict.fromkeys(mapped)), 1)  # >= 1 column (nan if unmapped)
    cols = list(TAU_COLUMNS) if kind == "tau" else [f"{kind}_{i}" for i in range(1, n + 1)]
    if kind != "tau" and mapped and set(cols) != set(mapped):
        raise LogImportError(f"{where}: mapped input columns {sorted(set(mapped))} are not {kind}_1..{kind}_{n}")
    absent = [c for c in cols if c not in found]
    if absent and require_inputs:
        raise LogImportError(f"{where}: input column(s) {', '.join(absent)} not found in the log (their streams are "
                             f"missing or empty); a run needs its commands. Pass require_inputs=False "
                             f"(convert --allow-missing-inputs) to import the states with nan inputs")
    notes = [f"inputs not in this log, written as nan: {', '.join(absent)}"] if absent else []
    return kind, cols, notes


def _subset(stream: Stream, keep, notes, fields=None) -> Stream:
    alt = None if stream.t_alternative is None else stream.t_alternative[keep]
    fields = stream.fields if fields is None else fields
    return Stream(name=stream.name, t=stream.t[keep], fields={k: v[keep] for k, v in fields.items()},
                  time_source=stream.time_source, t_alternative=alt, alternative_source=stream.alternative_source,
                  notes=stream.notes + notes)


def invalid_samples(check: ValidCheck, stream: Stream, log_params: dict | None = None) -> tuple:
    """(bool mask of the samples that fail ``check``, note or '') on ``stream``'s samples.

    A check whose field the stream does not hold (or holds only as nan: the firmware does not log it) fails no
    sample and says so in the note.
    """
    values = stream.fields.get(check.field)
    if values is None or not np.isfinite(values).any():
        return np.zeros(stream.t.size, bool), f"{check.field} not logged: check '{check.reason}' not applied"
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(values)
        if check.equal is not None:
            bad |= values != check.equal
        bounds = [(check.min, np.less), (check.max, np.greater)]
        for name, op in ((check.min_field, np.less), (check.max_field, np.greater)):
            if name and name in stream.fields:
                bounds.append((stream.fields[name], op))
        params = [n for n in (check.min_param, check.max_param) if n]
        found = [n for n in params if (log_params or {}).get(n) is not None and np.isfinite(log_params[n])]
        for name, op in ((check.min_param, np.less), (check.max_param, np.greater)):
            if name in found:
                bounds.append((check.param_scale * log_params[name], op))
        for bound, op in bounds:
            if bound is not None:
                bad |= op(values, bound)
        if check.ignore:
            bad &= ~np.isin(values, check.ignore)
    if params and not found and check.equal is None and check.min is None and check.max is None \
            and not check.min_field and not check.max_field:
        return bad, f"parameter(s) {', '.join(params)} not in the log: check '{check.reason}' not applied"
    return bad, ""


def rule_stream(rule: ChannelRule, streams: dict, log_params: dict | None = None,
                rejected: list | None = None) -> Stream | None:
    """The rule's stream, restricted to the samples whose ``keep_if`` fields equal the given values (e.g. only the
    downward DISTANCE_SENSOR, orientation 25), that pass the rule's ``valid`` checks (dropped samples counted per
    reason in the stream's notes) and, with a ``lookup``, whose value is one of its keys (mapped to its value);
    None if absent, lacking a field or left without samples (then, when every sample failed a validity check, the
    counts are appended to ``rejected``)."""
    stream = streams.get(rule.stream)
    if stream is None or stream.t.size == 0 or not all(f in stream.fields for f in rule.fields):
        return None
    if rule.keep_if:
        if not all(f in stream.fields for f, _ in rule.keep_if):
            return None
        keep = np.ones(stream.t.size, bool)
        for f, value in rule.keep_if:
            keep &= stream.fields[f] == value
        if not keep.any():
            return None
        cond = ", ".join(f"{f} = {v:g}" for f, v in rule.keep_if)
        if not keep.all():
            stream = _subset(stream, keep, [f"{stream.name}: {int((~keep).sum())} of {keep.size} samples dropped "
                                            f"(kept where {cond})"])
    if rule.valid:
        keep = np.ones(stream.t.size, bool)
        counts, skipped = [], []
        for check in rule.valid:
            bad, note = invalid_samples(check, stream, log_params)
            if note:
                skipped.append(note)
            new = bad & keep
            if new.any():
                counts.append(f"{int(new.sum())} {check.reason}")
            keep &= ~bad
        notes = []
        label = f"{stream.name}[{','.join(rule.fields)}] -> {'/'.join(rule.to)}"
        if counts:
            frac = 1.0 - keep.mean()
            notes.append(f"{label}: {int((~keep).sum())} of {keep.size} samples invalid and dropped ("
                         + "; ".join(counts) + ")"
                         + (f"; ALMOST ALL ({100 * frac:.0f} %) of the readings are invalid: {'/'.join(rule.to)} "
                            f"from this sensor is unusable in this log" if frac > 0.9 else ""))
        elif not skipped:
            notes.append(f"{label}: all {keep.size} samples pass the validity checks")
        notes += [f"{label}: {n}" for n in skipped]
        if not keep.any():
            if rejected is not None:
                rejected.extend(n for n in notes if n not in rejected)
            return None
        stream = _subset(stream, keep, notes)
    if rule.lookup:
        raw = stream.fields[rule.fields[0]]
        keys = np.array([k for k, _ in rule.lookup])
        keep = np.isin(raw, keys)
        if not keep.any():
            return None
        mapped = np.interp(raw, keys, [v for _, v in rule.lookup])  # exact at the keys
        fields = {**stream.fields, rule.fields[0]: mapped}
        values = ", ".join(f"{k:g} -> {v:g}" for k, v in rule.lookup)
        stream = _subset(stream, keep, [f"{stream.name}: {rule.fields[0]} mapped {values}; "
                                        f"{int((~keep).sum())} of {keep.size} samples with other values dropped"],
                         fields)
    return stream


def _present(rule, streams, log_params=None, rejected=None):
    return rule_stream(rule, streams, log_params, rejected) is not None


def _finite_fields(rule, streams):
    """A motor source whose servo fields are all nan (the log lacks those outputs) is not present."""
    stream = rule_stream(rule, streams)
    return all(np.isfinite(stream.fields[f]).any() for f in rule.fields)


def _mid_interval(rule: ChannelRule, stream: Stream) -> tuple:
    """(stream stamped at the middle of each delta's interval, note): a delta over [t - dt, t] is the mean rate
    at t - dt/2; kept at t when the shifted stamps would not increase (the note says so)."""
    dt = _delta_interval(rule, stream)
    t_mid = stream.t - 0.5 * np.where(np.isfinite(dt) & (dt > 0), dt, 0.0)
    if t_mid.size > 1 and not np.all(np.diff(t_mid) > 0):
        return stream, "deltas over intervals that overlap: stamped at the end of their interval"
    shift = float(np.median(stream.t - t_mid)) if t_mid.size else 0.0
    return replace(stream, t=t_mid, t_alternative=None), (f"mean rate over each interval, stamped at its middle "
                                                          f"(t - {rule.fields[3]}/2, median shift {shift:.3f} s)")


def _rate_notes(name, stream, grid_rate, is_input) -> list:
    med = median_interval(stream.t)
    if not np.isfinite(med) or grid_rate is None or 1.0 / med >= min(5.0, grid_rate / 2):
        return []
    if is_input:
        return [f"rate: {name} from {stream.name} at {1 / med:.1f} Hz (median interval {med:.2f} s) on a "
                f"{grid_rate:g} Hz grid: each command is held up to {med:.2f} s. The diagnoser can use this run for "
                f"slow responses (steady states, holds, responses slower than ~{4 * med:.0f} s) but cannot resolve "
                f"command changes, thruster dynamics or oscillations faster than ~{2 * med:.1f} s"]
    return [f"rate: {name} from {stream.name} at {1 / med:.1f} Hz (median interval {med:.2f} s), linearly "
            f"interpolated onto the {grid_rate:g} Hz grid: motion faster than ~{2 * med:.1f} s is not observed in it"]


def _gap_notes(name, stream, values, limit, grid) -> list:
    frac = float(np.mean(~np.isfinite(values))) if values.size else 0.0
    if frac <= 0.05:
        return []
    dt = np.diff(stream.t)
    big = dt[dt > limit]
    span = ""
    if stream.t[0] > grid[0] or stream.t[-1] < grid[-1]:
        span = (f"; {stream.name} covers only {stream.t[0] - grid[0]:.1f}..{stream.t[-1] - grid[0]:.1f} s of the "
                f"run's 0..{grid[-1] - grid[0]:.1f} s")
    return [f"gaps: {name} is nan in {100 * frac:.0f} % of the rows: {stream.name} has {big.size} gap(s) longer than "
            f"{limit:.2f} s (longest {big.max() if big.size else 0:.1f} s) that are not bridged{span}; the diagnoser "
            f"compares {name} only where it is finite"]


def sidecar_channels(rules, aiding=None, times=None) -> tuple:
    """The sidecar's ``channels`` entry for the state columns of the chosen ``rules`` (docs/formats/runlog.md).

    Parameters
    ----------
    rules : sequence of ChannelRule
        The rule that gave each column (the first per column counts).
    aiding : callable, optional
        (quantity, times) -> object with ``aided`` (bool) and ``why`` (str): whether a sensor fed the filter's
        estimate of the quantity (one of :data:`ESTIMATES`) at every one of the log times ``times``
        (:meth:`udrobot_ctrl.io.mavlink.EkfAiding.of`). Without it an estimate is ``estimated`` (the source cannot
        say).
    times : (n,) ndarray, optional
        Log times (s) of the run's rows.

    Returns
    -------
    channels : dict
        column -> ``{"source", "kind"}``, plus ``"estimates"`` (the quantity) and ``"aiding"`` (the evidence) for
        judged estimates; ``kind`` is one of :data:`udrobot_ctrl.io.runlog.CHANNEL_KINDS`.
    notes : list of str
        ``provenance:`` lines naming every estimated-unaided column.
    """
    out = {}
    for rule in rules:
        for c in rule.to:
            if c not in CHANNELS or c in out:
                continue
            entry = {"source": rule.source(c), "kind": MEASURED}
            if rule.estimated(c):
                entry["kind"] = ESTIMATED
                if rule.estimates and aiding is not None:
                    entry["estimates"] = rule.estimates
            out[c] = entry
    return judge_channels(out, aiding, times)


def judge_channels(channels: dict, aiding, times=None) -> tuple:
    """``channels`` with each entry that names the quantity it ``estimates`` judged ``estimated`` or
    ``estimated-unaided`` by ``aiding`` over the rows at log times ``times`` (:func:`sidecar_channels`); a converter
    that cuts rows judges again on the rows it keeps. Returns (channels, ``provenance:`` notes for the unaided
    columns, grouped by source)."""
    out, unaided = {}, {}
    for c, entry in channels.items():
        entry = dict(entry)
        if entry.get("estimates") and aiding is not None:
            judged = aiding(entry["estimates"], times)
            entry["kind"] = ESTIMATED if judged.aided else UNAIDED
            entry["aiding"] = judged.why
            if not judged.aided:
                unaided.setdefault((entry["source"].split(".")[0], judged.why), []).append(c)
        out[c] = entry
    notes = [f"{UNAIDED_NOTE}{', '.join(cols)} <- {stream}: {UNAIDED} ({why}); written for the user to see, never "
             f"fitted, scored or counted as observed by diagnose" for (stream, why), cols in unaided.items()]
    return out, notes


def assemble_run(mapping: Mapping, streams: dict, source_path: str, extra_notes=(), require_inputs=True,
                 log_params: dict | None = None, extra_rules=(), aiding=None) -> Run:
    """Apply ``mapping`` to decoded ``streams`` and resample onto one time base.

    Parameters
    ----------
    log_params : dict, optional
        Parameters the log holds (surface pressure, water density for ``pressure_to_depth``).
    extra_rules : sequence of ChannelRule
        Rules placed before the mapping's own (motor outputs from the vehicle's servo map).
    aiding : callable, optional
        Whether the log's navigation filter was aided per quantity, for the sidecar's ``channels``
        (:func:`sidecar_channels`).

    Returns
    -------
    Run
        ``t`` starts at 0 s; ``extra['t_source']`` is the time-base stream's original time (log clock, s) at or
        before each sample; ``metadata['channels']`` says how each state column was obtained (measured, estimated,
        estimated-unaided: :func:`sidecar_channels`); ``metadata['notes']`` records the source of every column (and, for
        columns with a
        ``[select.COLUMN]`` table, why it was chosen), the interpolation used, the time origin, slow streams,
        gaps and any clock delays (e.g. header stamp vs bag record time).
    """
    where = f"{source_path} (mapping {mapping.name})"
    rules = list(extra_rules) + list(mapping.rules)
    extra_streams = {r.stream for r in extra_rules}
    rejected = []
    present = [r for r in rules if _present(r, streams, log_params, rejected)
               and (r.stream not in extra_streams or r.index >= 0 or _finite_fields(r, streams))]
    selection_notes, chosen, seen = [], [], set()
    for rule in present:
        if set(rule.to) & seen:
            continue
        selected = [c for c in rule.to if c in mapping.select]
        if selected:
            column = selected[0]
            cands = [r for r in present if column in r.to and not (set(r.to) - set(rule.to)) & seen]
            cand_objs = []
            for r in cands:
                r_stream = rule_stream(r, streams, log_params)
                values, _ = _apply_rule(r, r_stream, where, log_params)
                cand_objs.append(Candidate(r, r_stream.t, values[column]))
            winner, notes = select_by_evidence(column, cand_objs, mapping.select[column])
            selection_notes += notes
            rule = winner.rule
        chosen.append(rule)
        seen.update(rule.to)
    missing = sorted({n for r in rules for n in r.to} - seen)
    if not chosen:
        raise LogImportError(f"{where}: none of the mapped streams is in the log "
                             f"(wanted {', '.join(sorted(mapping.needs()))}; log has "
                             f"{', '.join(sorted(s for s, v in streams.items() if v.t.size)) or 'nothing'})")
    base_name = mapping.time_base if mapping.time_base in streams and streams[mapping.time_base].t.size else \
        chosen[0].stream
    base = streams[base_name]
    used = {r.stream for r in chosen}
    # auxiliary channels (altitude, voltage, accelerometer) do not cut the run: they are nan outside their own span
    # (named in gaps:), so a sonar that starts late never shortens the states and commands
    # nor do extra columns (autopilot context: a MODE message logged only at the first mode change, pilot inputs)
    core = {base_name} | {r.stream for r in chosen if not set(r.to) <= set(AUXILIARY_CHANNELS)
                          and any(n in CHANNELS or _is_input(n) for n in r.to)}
    start = max(streams[s].t[0] for s in core)
    stop = min(streams[s].t[-1] for s in core)
    if not stop > start:
        raise LogImportError(f"{where}: the time base and the command streams do not overlap in time "
                             + "; ".join(f"{s}: {streams[s].t[0]:.3f}..{streams[s].t[-1]:.3f} s" for s in sorted(core)))
    if mapping.rate_hz:
        t_rel = np.arange(int(np.floor((stop - start) * mapping.rate_hz + 1e-9)) + 1) / mapping.rate_hz
        grid = start + t_rel
        interp = f"uniform {mapping.rate_hz:g} Hz grid"
        grid_rate = mapping.rate_hz
    else:
        grid = base.t[(base.t >= start) & (base.t <= stop)]
        t_rel = grid - grid[0]
        interp = f"samples of {base_name}"
        med = median_interval(grid)
        grid_rate = 1.0 / med if np.isfinite(med) else None

    out, provenance, rate_notes, gap_notes = {}, [], [], []
    deferred = []
    used_streams = {}
    tag_notes = []
    for rule in chosen:
        stream = rule_stream(rule, streams, log_params)
        used_streams.setdefault(rule.stream, stream)
        values, rule_notes = _apply_rule(rule, stream, where, log_params)
        if rule.transform == "delta_over_dt":
            stream, shift_note = _mid_interval(rule, stream)
            rule_notes.append(shift_note)
        if rule.tag:
            tag_notes.append(f"source: {'/'.join(rule.to)} <- {rule.stream}[{','.join(rule.fields)}]: {rule.tag}")
        limit = gap_limit(stream.t, mapping)
        inputs_here = [n for n in values if _is_input(n)]
        for name, y in values.items():
            if _is_input(name) or name not in CHANNELS:
                out[name] = hold_previous(stream.t, y, grid)
            else:
                out[name] = _interp_gapped(stream.t, y, grid, limit, angle=name in ANGLE_CHANNELS)
                gap_notes += _gap_notes(name, stream, out[name], limit, grid)
        label = "/".join(rule.to) if len(rule.to) <= 6 else f"{rule.to[0]}..{rule.to[-1]}"
        if any(n in CHANNELS or _is_input(n) for n in rule.to):  # context columns are held (events, e.g. MODE)
            rate_notes += _rate_notes(label if inputs_here else "/".join(n for n in rule.to if n in CHANNELS) or label,
                                      stream, grid_rate, bool(inputs_here))
        if rule.transform == "world_to_body":
            deferred.append(rule)
        src = ",".join(rule.fields)
        rate = (stream.t.size - 1) / (stream.t[-1] - stream.t[0]) if stream.t.size > 1 else float("nan")
        med = median_interval(stream.t)
        provenance.append(f"{'/'.join(rule.to)} <- {rule.stream}[{src}] ({rule.transform}, scale {rule.scale:g}, "
                          f"offset {rule.offset:g}; {stream.t.size} samples, {rate:.1f} Hz, median interval "
                          f"{med:.3f} s, gaps > {limit:.2f} s not bridged; time {stream.time_source})"
                          + "".join(f"; {n}" for n in rule_notes) + (f" [{rule.tag}]" if rule.tag else ""))
    for rule in deferred:
        att = [out.get(a) for a in ANGLE_CHANNELS]
        if any(a is None for a in att):
            raise LogImportError(f"{where}: channels[{rule.index}] world_to_body needs phi, theta, psi in the mapping")
        R = _euler_rotation(*att)
        vec = np.stack([out[n] for n in rule.to], axis=-1)
        body = np.einsum("...ji,...j->...i", R, vec)  # R^T v: world NED -> body FRD
        for k, name in enumerate(rule.to):
            out[name] = body[:, k]

    kind, cols, input_notes = _input_layout(mapping, out, where, require_inputs, rules)
    inputs = np.column_stack([out.get(c, np.full(grid.shape, np.nan)) for c in cols])
    channels = {c: out[c] for c in CHANNELS if c in out}
    extra = {n: v for n, v in out.items() if n not in channels and n not in cols}
    extra["t_source"] = hold_previous(base.t, base.t, grid)
    notes = [f"converted from {source_path} with mapping {mapping.name} ({mapping.path}); t = 0 is log time "
             f"{grid[0]:.6f} s ({base.time_source} clock of {base_name}); time base: {interp} over the span where "
             f"all used streams overlap (except {'/'.join(AUXILIARY_CHANNELS)}, nan outside their own span); "
             f"measured channels linear (angles unwrapped; no bridging of gaps longer than "
             f"max({mapping.max_gap_s:g} s, {mapping.gap_factor:g} x the stream's median interval)), inputs "
             f"zero-order hold; t_source = original {base_name} time stamp held"]
    sources, source_notes = sidecar_channels(chosen, aiding, grid)
    notes += provenance + selection_notes + tag_notes + source_notes + rate_notes + gap_notes + rejected
    if missing:
        notes.append("not in this log: " + ", ".join(missing))
    for s in sorted(used):
        st = used_streams[s]
        notes += st.notes
        if st.t_alternative is not None and st.t_alternative.size:
            d = st.t_alternative - st.t
            notes.append(f"{s}: {st.alternative_source} - {st.time_source} delay median {np.median(d) * 1e3:.1f} ms "
                         f"(p5 {np.percentile(d, 5) * 1e3:.1f}, p95 {np.percentile(d, 95) * 1e3:.1f}, max "
                         f"{d.max() * 1e3:.1f} ms)")
    notes += input_notes + list(extra_notes)
    metadata = {"format": "udrobot-run/1", **mapping.metadata}
    metadata["channels"] = {c: e for c, e in sources.items() if c in channels}
    metadata["notes"] = "\n".join(([mapping.metadata["notes"]] if "notes" in mapping.metadata else []) + notes)
    return Run(path="", t=t_rel, channels=channels, input_kind=kind, inputs=inputs, extra=extra,
               metadata=metadata)
