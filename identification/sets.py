"""Read and write coefficient-set files (``udrobot-coefficients/1``, TOML).

A set file holds, per translational axis (``[surge]``, ``[sway]``, ``[heave]``), tagged values
``{ value = ..., provenance = "measured: ..." }`` for ``added_mass`` (kg), ``KL`` (N s/m),
``KQ`` (N s^2/m^2), ``CD`` (-), and optionally ``added_mass_<form>`` for a form-specific
added mass. The identification CLI writes this format with ``--out``.
"""
from __future__ import annotations

import difflib
from pathlib import Path

import numpy as np
import tomllib

from identification.fossen import AXES, FORMS, CoefficientSet
from udrobot_files.output import atomic_write

FORMAT = "udrobot-coefficients/1"
QUANTITIES = ("added_mass", "KL", "KQ", "CD")
AXIS_KEYS = QUANTITIES + tuple(f"added_mass_{form}" for form in FORMS)
TOP_KEYS = ("format", "name", "description", "forms", *AXES)
ENTRY_KEYS = ("value", "provenance")


def _hint(key, known) -> str:
    close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _number(value, where):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    return float(value)


def _value(entry, where):
    if isinstance(entry, dict):
        if "value" not in entry:
            raise ValueError(f"{where}: expected a number or {{value = ..., provenance = ...}}"
                             f"{_hint(next(iter(entry), ''), ENTRY_KEYS)}")
        for key in entry:
            if key not in ENTRY_KEYS:
                raise ValueError(f"{where}: unknown field {key!r}{_hint(key, ENTRY_KEYS)}; an entry holds "
                                 f"{' and '.join(ENTRY_KEYS)}")
        return _number(entry["value"], where), str(entry.get("provenance", ""))
    return _number(entry, where), ""


def coefficient_set_from_dict(doc: dict, source: str = "<dict>") -> CoefficientSet:
    """Build a :class:`CoefficientSet` from a parsed set document; errors name ``source``."""
    if doc.get("format", FORMAT) != FORMAT:
        raise ValueError(f"{source}: format {doc.get('format')!r}, expected {FORMAT!r}")
    for key in doc:
        if key not in TOP_KEYS:
            raise ValueError(f"{source}: unknown key {key!r}{_hint(key, TOP_KEYS)}; a set holds "
                             f"{', '.join(TOP_KEYS)}")
    name = str(doc.get("name") or Path(source).stem)
    forms_given = doc.get("forms")
    if forms_given is not None:
        if not isinstance(forms_given, list) or not all(isinstance(f, str) for f in forms_given):
            raise ValueError(f"{source}: forms must be a list of names among {', '.join(FORMS)}")
        for f in forms_given:
            if f not in FORMS:
                raise ValueError(f"{source}: forms: unknown form {f!r}{_hint(f, FORMS)}; expected {', '.join(FORMS)}")
    values: dict[str, list] = {}
    prov = {}
    for i, axis in enumerate(AXES):
        table = doc.get(axis)
        if not isinstance(table, dict):
            raise ValueError(f"{source}: missing table [{axis}]")
        for key, entry in table.items():
            if key not in AXIS_KEYS:
                raise ValueError(f"{source}: [{axis}] {key}: unknown quantity{_hint(key, AXIS_KEYS)}; expected "
                                 f"{', '.join(AXIS_KEYS)}")
            v, p = _value(entry, f"{source}: [{axis}] {key}")
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"{source}: [{axis}] {key} = {v}: expected a finite value >= 0")
            values.setdefault(key, [None, None, None])[i] = v
            prov[f"{axis}.{key}"] = p
    for key, vals in values.items():
        missing = [AXES[i] for i, v in enumerate(vals) if v is None]
        if missing:
            raise ValueError(f"{source}: {key} missing for {', '.join(missing)}")
    if "added_mass" not in values:
        raise ValueError(f"{source}: every set needs added_mass (kg) per axis")
    added = {"default": np.array(values["added_mass"])}
    for form in FORMS:
        if f"added_mass_{form}" in values:
            added[form] = np.array(values[f"added_mass_{form}"])
    arr = {k: (np.array(values[k]) if k in values else None) for k in ("KL", "KQ", "CD")}
    forms = tuple(doc.get("forms") or [f for f in FORMS if (f == "chin" and arr["KL"] is not None
                                                          and arr["KQ"] is not None)
                                        or (f == "morison" and arr["CD"] is not None)])
    return CoefficientSet(name=name, added_mass=added, forms=forms, description=str(doc.get("description", "")),
                          provenance=prov, **arr)


def load_coefficient_set(path) -> CoefficientSet:
    """Load a coefficient-set TOML file.

    Parameters
    ----------
    path : str or Path
        The TOML (docs/formats/model.md, coefficient sets).

    Returns
    -------
    CoefficientSet
        The checked set (errors name the file and field).
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from exc
    return coefficient_set_from_dict(doc, str(path))


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def dump_coefficient_set(name: str, per_axis: dict, provenance: dict | None = None,
                         description: str = "") -> str:
    """TOML text of a set. ``per_axis = {"added_mass": (3,), "KL": (3,), ...}``; None entries skipped.

    ``provenance`` maps ``"axis.key"`` (or ``"key"`` for every axis) to the provenance text.
    """
    provenance = provenance or {}
    lines = [f"format = {_toml_str(FORMAT)}", f"name = {_toml_str(name)}",
             f"description = {_toml_str(description)}", ""]
    for i, axis in enumerate(AXES):
        lines.append(f"[{axis}]")
        for key, vals in per_axis.items():
            if vals is None:
                continue
            v = float(np.asarray(vals, float)[i])
            p = provenance.get(f"{axis}.{key}", provenance.get(key, "measured"))
            lines.append(f"{key} = {{ value = {v!r}, provenance = {_toml_str(p)} }}")
        lines.append("")
    return "\n".join(lines)


def write_coefficient_set(path, name, per_axis, provenance=None, description="", protect=()) -> None:
    """Write a set file atomically (never leaves a half-written file, never over a ``protect`` file).

    Parameters
    ----------
    path : str or Path
        Destination TOML.
    name : str
        The set's name.
    per_axis : dict
        Quantity (``added_mass`` kg, ``KL`` N s/m, ``KQ`` N s^2/m^2, ``CD`` dimensionless) -> (3,) values for
        surge, sway, heave; None entries skipped.
    provenance : dict, optional
        ``"axis.key"`` (or ``"key"`` for every axis) -> the provenance text.
    description : str
        What the set is.
    protect : sequence of path, optional
        Files that must not be overwritten (the command's inputs).
    """
    path = Path(path)
    text = dump_coefficient_set(name, per_axis, provenance, description)
    coefficient_set_from_dict(tomllib.loads(text), str(path))  # validate before writing
    atomic_write(path, text, protect=protect)
