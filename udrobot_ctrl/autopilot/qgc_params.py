"""QGroundControl parameter files (``.params``): write and read ArduSub parameters in ArduSub's own names and units.

Format (QGroundControl developer guide, "Parameter File Format")::

    # Onboard parameters for Vehicle 1
    #
    # # Vehicle-Id Component-Id Name Value Type
    1	1	ATC_RAT_RLL_P	0.135	9

one parameter a line, tab-separated: the vehicle (MAVLink system) id, the component id (1: the autopilot), the
parameter name, its value, and its MAVLink type (``MAV_PARAM_TYPE``: 9 = REAL32, 6 = INT32, 4 = INT16, 2 = INT8);
lines starting with ``#`` are comments. QGroundControl's *Parameters > Tools > Load from file* reads it, and
Mission Planner's *Load* reads the same lines. The values are in ArduSub's units (e.g. ``PSC_ACCZ_P`` in its
throttle-per-cm/s^2 x 1000 scaling, ``ATC_ANG_*_P`` in 1/s); the conversion to SI lives in
:mod:`udrobot_ctrl.ardusub.params`.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from udrobot_ctrl.ardusub.params import ParameterError, parameter_problems

#: MAV_PARAM_TYPE values (MAVLink common.xml)
MAV_PARAM_TYPE_REAL32 = 9
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_INT16 = 4
MAV_PARAM_TYPE_INT8 = 2
_INTEGER_TYPES = {1, 2, 3, 4, 5, 6, 7, 8}
#: ArduSub parameters that are integers (everything else this project writes is a float)
INTEGER_PARAMETERS = {"SCHED_LOOP_RATE": MAV_PARAM_TYPE_INT16, "ATC_RATE_FF_ENAB": MAV_PARAM_TYPE_INT8,
                      "FRAME_CONFIG": MAV_PARAM_TYPE_INT8}


def format_params(params: Mapping, vehicle_id: int = 1, component_id: int = 1, comments=()) -> str:
    """The text of a QGroundControl ``.params`` file holding ``params`` (name -> value, ArduSub units).

    Parameters
    ----------
    params : mapping of str to float
        ArduSub parameter names (upper case, at most 16 characters) and values in ArduSub's units.
    vehicle_id, component_id : int
        MAVLink system and component ids (1 and 1: the usual single vehicle's autopilot).
    comments : iterable of str
        Extra ``#`` lines after the header (provenance: which model, which command).

    Returns
    -------
    str
        The file's text: one tab-separated ``vehicle component name value type`` line per parameter.

    Raises
    ------
    ValueError
        A name that is not an ArduPilot parameter name or a non-finite value.
    """
    lines = [f"# Onboard parameters for Vehicle {vehicle_id}", "#"]
    lines += [f"# {c}" for c in comments]
    lines.append("# # Vehicle-Id Component-Id Name Value Type")
    for name in sorted(params):
        value = float(params[name])
        if not (name and len(name) <= 16 and name.replace("_", "").isalnum() and name == name.upper()):
            raise ValueError(f"parameter name {name!r}: ArduPilot names are upper case, letters, digits and '_', "
                             f"at most 16 characters")
        if not math.isfinite(value):
            raise ValueError(f"parameter {name} = {value}: not a finite number")
        kind = INTEGER_PARAMETERS.get(name, MAV_PARAM_TYPE_REAL32)
        text = str(int(round(value))) if kind in _INTEGER_TYPES else f"{value:.9g}"
        lines.append(f"{vehicle_id}\t{component_id}\t{name}\t{text}\t{kind}")
    return "\n".join(lines) + "\n"


def parse_params(text: str, source: str = "<params>") -> dict:
    """Parameters (name -> float) of a QGroundControl ``.params`` text (also accepts Mission Planner's
    ``NAME,VALUE`` lines), checked as every logged parameter set is
    (:func:`~udrobot_ctrl.ardusub.params.check_log_params`).

    Parameters
    ----------
    text : str
        The file's content.
    source : str
        The file's name, for the messages.

    Returns
    -------
    dict
        Parameter name -> value (float, ArduSub units), in the file's order.

    Raises
    ------
    ValueError
        A line that is neither a comment, nor ``vehicle component name value type``, nor ``NAME,VALUE``, naming
        the file and the line number; a name given twice (naming both lines: which one the vehicle holds is not
        known); a file without a parameter line; a value ArduSub cannot hold (NaN, infinite, beyond float32, outside
        the parameter's documented domain).
    """
    out, lines = {}, {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split("\t") if "\t" in line else (line.split(",") if "," in line else line.split())
        try:
            if len(fields) == 5:
                int(fields[0]), int(fields[1]), int(fields[4])
                name, value = fields[2].strip(), float(fields[3])
            elif len(fields) == 2:
                name, value = fields[0].strip(), float(fields[1])
            else:
                raise ValueError
        except ValueError:
            raise ValueError(f"{source}, line {number}: expected 'vehicle-id<TAB>component-id<TAB>NAME<TAB>value"
                             f"<TAB>type' (QGroundControl .params), got {raw!r}") from None
        if name in lines:
            raise ValueError(f"{source}, lines {lines[name]} and {number}: parameter {name} given twice; expected "
                             f"each parameter once (which value the vehicle holds is not known)")
        out[name], lines[name] = value, number
    if not out:
        raise ValueError(f"{source}: no parameter lines (only comments or blank lines); expected QGroundControl "
                         f"'vehicle-id<TAB>component-id<TAB>NAME<TAB>value<TAB>type' lines")
    problems = parameter_problems(out)
    if problems:
        p = problems[0]
        raise ParameterError(f"{source}, line {lines[p.name]}: {p.sentence()}")
    return out


def read_params(path) -> dict:
    """Parameters (name -> float, ArduSub units) of a QGroundControl ``.params`` file (:func:`parse_params`).

    Parameters
    ----------
    path : str or Path
        The ``.params`` file.

    Returns
    -------
    dict
        Parameter name -> value (float, ArduSub units).
    """
    path = Path(path)
    return parse_params(path.read_text(), str(path))


__all__ = ["INTEGER_PARAMETERS", "MAV_PARAM_TYPE_REAL32", "format_params", "parse_params", "read_params"]
