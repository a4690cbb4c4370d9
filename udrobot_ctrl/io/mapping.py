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
    max_gap_s = 0.5             # linear interpolation never bridges a gap longer than this
    input_kind = "pwm"

    [[channels]]                # several [[channels]] with the same `to`: the first present in the log wins
    to = ["phi", "theta", "psi"]
    stream = "ATTITUDE"
    fields = ["roll", "pitch", "yaw"]
    scale = 1.0                 # value = scale * raw + offset, then `transform`
    transform = "none"          # none | quaternion_to_euler | vector_enu_to_ned | vector_flu_to_frd
                                # | pressure_to_depth | world_to_body (after resampling, needs phi/theta/psi)

Resampling: measured channels linearly (angles unwrapped), inputs and extra columns zero-order hold
(the command logged at t_k holds until the next one). The output t starts at 0; the absolute log time of
t = 0 and every rule actually used go to the sidecar ``notes``; an extra column ``t_source`` holds the
original (log clock) time stamp of the time-base sample at or before each output sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import tomllib

from udrobot_ctrl.io.runlog import (
    ANGLE_CHANNELS,
    CHANNELS,
    TAU_COLUMNS,
    Run,
    hold_previous,
    interpolate_linear,
)

from .streams import LogImportError, Stream

MAPPING_FORMAT = "udrobot-mapping/1"
SOURCES = ("mavlink", "ros", "rostopic_csv")
TRANSFORMS = {
    "none": (None, None),
    "quaternion_to_euler": (4, 3),
    "vector_enu_to_ned": (3, 3),
    "vector_flu_to_frd": (3, 3),
    "pressure_to_depth": (1, 1),
    "world_to_body": (3, 3),
}
G = 9.81


class MappingError(ValueError):
    """A mapping file that is not valid ``udrobot-mapping/1``; the message names the file and the field."""


@dataclass(frozen=True)
class ChannelRule:
    """One ``[[channels]]`` entry: output column(s) from field(s) of one stream."""

    to: tuple
    stream: str
    fields: tuple
    transform: str = "none"
    scale: float = 1.0
    offset: float = 0.0
    frame: str = "ned_frd"
    params: dict = field(default_factory=dict)
    index: int = 0


@dataclass(frozen=True)
class Mapping:
    """A parsed mapping file (see module docstring)."""

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

    def needs(self) -> dict:
        """Stream name -> set of field paths the mapping reads."""
        out = {}
        for rule in self.rules:
            out.setdefault(rule.stream, set()).update(rule.fields)
        if self.time_base:
            out.setdefault(self.time_base, set())
        return out


def shipped_mappings() -> list:
    """Names of the mappings shipped in ``udrobot_ctrl.models/mappings``."""
    root = resources.files("udrobot_ctrl.models") / "mappings"
    return sorted(p.name[:-5] for p in root.iterdir() if p.name.endswith(".toml"))


def load_mapping(name_or_path) -> Mapping:
    """Load a mapping from a TOML path or a shipped name (``ardusub``, ``bluerov2-mavros``, ``tartan-auv``)."""
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
                                "comment"}
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
        rules.append(ChannelRule(to=to, stream=str(entry["stream"]), fields=fields, transform=transform,
                                 scale=_number(entry, "scale", 1.0, w), offset=_number(entry, "offset", 0.0, w),
                                 frame=frame, params=params, index=i))
    files = doc.get("files", {})
    if not isinstance(files, dict) or not all(isinstance(v, str) and "{suffix}" in v for v in files.values()):
        raise MappingError(f"{source_name}: [files] must map stream names to patterns containing '{{suffix}}'")
    metadata = doc.get("metadata", {})
    if not isinstance(metadata, dict):
        raise MappingError(f"{source_name}: [metadata] must be a table")
    return Mapping(name=str(head.get("name", source_name)), source=source, path=source_name, rules=tuple(rules),
                   rate_hz=_number(head, "rate_hz", None, where, positive=True),
                   time_base=head.get("time_base"), time=time,
                   max_gap_s=_number(head, "max_gap_s", 0.5, where, positive=True), input_kind=input_kind,
                   metadata=metadata, description=str(head.get("description", "")), files=files)


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


def pressure_to_depth(pressure_pa, params: dict, where: str):
    """Depth (m, positive down) from absolute pressure (Pa): (p - p_surface) / (rho g).

    ``params.water_density`` (kg/m^3, default 1000: assumed fresh water) and ``params.surface_pressure_pa``
    (a number, or "first" = the first sample, assumed taken at the surface; default "first").
    """
    rho = params.get("water_density", 1000.0)
    p0 = params.get("surface_pressure_pa", "first")
    pressure_pa = np.asarray(pressure_pa, dtype=float)
    if p0 == "first":
        finite = pressure_pa[np.isfinite(pressure_pa)]
        if finite.size == 0:
            raise LogImportError(f"{where}: no finite pressure sample to take the surface pressure from")
        p0 = float(finite[0])
    if not isinstance(p0, (int, float)) or not isinstance(rho, (int, float)) or rho <= 0:
        raise MappingError(f"{where}: params surface_pressure_pa / water_density must be numbers")
    return (pressure_pa - p0) / (rho * G)


def _apply_rule(rule: ChannelRule, stream: Stream, where: str) -> dict:
    """Outputs of one rule on the stream's own samples (world_to_body is deferred: raw NED values returned)."""
    try:
        raw = [stream.fields[f] * rule.scale + rule.offset for f in rule.fields]
    except KeyError as exc:
        raise LogImportError(f"{where}: stream '{stream.name}' has no field {exc.args[0]!r} "
                             f"(fields: {', '.join(sorted(stream.fields))})") from exc
    tr = rule.transform
    if tr == "none":
        return dict(zip(rule.to, raw))
    if tr == "quaternion_to_euler":
        return dict(zip(rule.to, quaternion_to_euler(*raw, frame=rule.frame)))
    if tr == "pressure_to_depth":
        return {rule.to[0]: pressure_to_depth(raw[0], rule.params, where)}
    vec = np.stack(raw, axis=-1)
    if tr == "vector_enu_to_ned":
        vec = vec @ _ENU_TO_NED.T
    elif tr == "vector_flu_to_frd":
        vec = vec @ _FLU_TO_FRD.T
    elif tr == "world_to_body" and rule.frame == "enu_flu":
        vec = vec @ _ENU_TO_NED.T
    return dict(zip(rule.to, vec.T))


def _euler_rotation(phi, theta, psi) -> np.ndarray:
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    return np.stack([
        np.stack([cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st], -1),
        np.stack([sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf], -1),
        np.stack([-st, ct * sf, ct * cf], -1),
    ], -2)


# ------------------------------------------------------------------------------------------- assembly


def _interp_gapped(t, y, t_new, max_gap, angle):
    out = interpolate_linear(t, y, t_new, angle=angle)
    if t.size > 1:
        i0 = np.clip(np.searchsorted(t, t_new, side="right") - 1, 0, t.size - 2)
        exact = np.isin(t_new, t)
        out[(t[i0 + 1] - t[i0] > max_gap) & ~exact] = np.nan
    return out


def _select_rules(mapping: Mapping, streams: dict) -> tuple:
    """First rule per output that has a non-empty stream; report what was chosen and what is missing."""
    chosen, skipped, seen = [], [], set()
    for rule in mapping.rules:
        if set(rule.to) & seen:
            continue
        stream = streams.get(rule.stream)
        if stream is None or stream.t.size == 0:
            skipped.append(rule)
            continue
        chosen.append(rule)
        seen.update(rule.to)
    missing = sorted({n for r in skipped for n in r.to} - seen)
    return chosen, missing


def _is_input(name: str) -> bool:
    return name in TAU_COLUMNS or name.startswith(("thrust_", "pwm_"))


def _input_layout(mapping: Mapping, found, where, require_inputs: bool):
    """(kind, columns, notes) of the run's inputs; columns the mapping names but the log lacks -> error or nan."""
    mapped = [n for r in mapping.rules for n in r.to if _is_input(n)]
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


def assemble_run(mapping: Mapping, streams: dict, source_path: str, extra_notes=(), require_inputs=True) -> Run:
    """Apply ``mapping`` to decoded ``streams`` and resample onto one time base.

    Returns
    -------
    Run
        ``t`` starts at 0 s; ``extra['t_source']`` is the time-base stream's original time (log clock, s) at or
        before each sample; ``metadata['notes']`` records the source of every column, the interpolation used,
        the time origin and any clock delays (e.g. header stamp vs bag record time).
    """
    where = f"{source_path} (mapping {mapping.name})"
    chosen, missing = _select_rules(mapping, streams)
    if not chosen:
        raise LogImportError(f"{where}: none of the mapped streams is in the log "
                             f"(wanted {', '.join(sorted(mapping.needs()))}; log has "
                             f"{', '.join(sorted(s for s, v in streams.items() if v.t.size)) or 'nothing'})")
    base_name = mapping.time_base if mapping.time_base in streams and streams[mapping.time_base].t.size else \
        chosen[0].stream
    base = streams[base_name]
    used = {r.stream for r in chosen}
    start = max(streams[s].t[0] for s in used)
    stop = min(streams[s].t[-1] for s in used)
    if not stop > start:
        raise LogImportError(f"{where}: the mapped streams do not overlap in time "
                             + "; ".join(f"{s}: {streams[s].t[0]:.3f}..{streams[s].t[-1]:.3f} s" for s in sorted(used)))
    if mapping.rate_hz:
        t_rel = np.arange(int(np.floor((stop - start) * mapping.rate_hz + 1e-9)) + 1) / mapping.rate_hz
        grid = start + t_rel
        interp = f"uniform {mapping.rate_hz:g} Hz grid"
    else:
        grid = base.t[(base.t >= start) & (base.t <= stop)]
        t_rel = grid - grid[0]
        interp = f"samples of {base_name}"

    out, provenance = {}, []
    deferred = []
    for rule in chosen:
        stream = streams[rule.stream]
        values = _apply_rule(rule, stream, where)
        for name, y in values.items():
            if _is_input(name) or name not in CHANNELS:
                out[name] = hold_previous(stream.t, y, grid)
            else:
                out[name] = _interp_gapped(stream.t, y, grid, mapping.max_gap_s, angle=name in ANGLE_CHANNELS)
        if rule.transform == "world_to_body":
            deferred.append(rule)
        src = ",".join(rule.fields)
        rate = (stream.t.size - 1) / (stream.t[-1] - stream.t[0]) if stream.t.size > 1 else float("nan")
        provenance.append(f"{'/'.join(rule.to)} <- {rule.stream}[{src}] ({rule.transform}, scale {rule.scale:g}, "
                          f"offset {rule.offset:g}; {stream.t.size} samples, {rate:.1f} Hz, time {stream.time_source})")
    for rule in deferred:
        att = [out.get(a) for a in ANGLE_CHANNELS]
        if any(a is None for a in att):
            raise LogImportError(f"{where}: channels[{rule.index}] world_to_body needs phi, theta, psi in the mapping")
        R = _euler_rotation(*att)
        vec = np.stack([out[n] for n in rule.to], axis=-1)
        body = np.einsum("...ji,...j->...i", R, vec)  # R^T v: world NED -> body FRD
        for k, name in enumerate(rule.to):
            out[name] = body[:, k]

    kind, cols, input_notes = _input_layout(mapping, out, where, require_inputs)
    inputs = np.column_stack([out.get(c, np.full(grid.shape, np.nan)) for c in cols])
    channels = {c: out[c] for c in CHANNELS if c in out}
    extra = {n: v for n, v in out.items() if n not in channels and n not in cols}
    extra["t_source"] = hold_previous(base.t, base.t, grid)
    notes = [f"converted from {source_path} with mapping {mapping.name} ({mapping.path}); t = 0 is log time "
             f"{grid[0]:.6f} s ({base.time_source} clock of {base_name}); time base: {interp} over the span where "
             f"all used streams overlap; measured channels linear (angles unwrapped; no bridging of gaps > "
             f"{mapping.max_gap_s:g} s), inputs zero-order hold; t_source = original {base_name} time stamp held"]
    notes += provenance
    if missing:
        notes.append("not in this log: " + ", ".join(missing))
    for s in sorted(used):
        notes += streams[s].notes
        st = streams[s]
        if st.t_alternative is not None and st.t_alternative.size:
            d = st.t_alternative - st.t
            notes.append(f"{s}: {st.alternative_source} - {st.time_source} delay median {np.median(d) * 1e3:.1f} ms "
                         f"(p5 {np.percentile(d, 5) * 1e3:.1f}, p95 {np.percentile(d, 95) * 1e3:.1f}, max "
                         f"{d.max() * 1e3:.1f} ms)")
    notes += input_notes + list(extra_notes)
    metadata = {"format": "udrobot-run/1", **mapping.metadata}
    metadata["notes"] = "\n".join(([mapping.metadata["notes"]] if "notes" in mapping.metadata else []) + notes)
    return Run(path="", t=t_rel, channels=channels, input_kind=kind, inputs=inputs, extra=extra,
               metadata=metadata)
