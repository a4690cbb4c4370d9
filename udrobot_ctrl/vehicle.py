"""The vehicle: rigid body, restoring, hydrodynamic matrices and thrusters as plain data.

A :class:`Vehicle` is exactly the content of a ``udrobot-model/1`` file (docs/formats/model.md). It is
built from

* a UDrobot model name ``SET:FORM`` (``pendulum:chin`` ...): the shipped UDrobot description
  ``models/udrobot.toml`` with an identified coefficient set and a damping form;
* a vehicle name (``bluerov2``, ``bluerov2-heavy``, :data:`VEHICLE_MODEL_NAMES`): a shipped vehicle
  description ``models/NAME.toml`` that carries its own published coefficients (``[hydrodynamics]``,
  docs/vehicle_models.md), or a path to such a TOML;
* a ``udrobot-model/1`` JSON file,

and written back by :func:`to_model_dict`. Thrusters are data: any number, any layout; their order is the
autopilot's motor order (thruster i is driven by the run's ``pwm_i``).
"""
from __future__ import annotations

import difflib
import json
import os
import warnings
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np
import tomllib

from identification import fossen
from identification.fossen import AXES
from identification.sets import coefficient_set_from_dict, load_coefficient_set
from identification.similitude import FullSizeVehicle
from udrobot_ctrl.constants import DOF_NAMES
from udrobot_ctrl.dynamics.effects import check_against_model, parse_effects
from udrobot_ctrl.dynamics.sim import set_model_loader
from udrobot_ctrl.dynamics.thrusters import MAX_CURVE_BYTES, load_curve, shipped_curve_name, thrust_limits
from udrobot_files.inputs import inside, read_regular
from udrobot_files.nesting import unique_keys
from udrobot_files.output import atomic_write

MODEL_FORMAT = "udrobot-model/1"
# the public API (docs/api)
__all__ = ["MODEL_NAMES", "ALL_MODEL_NAMES", "Thruster", "Vehicle", "load_model", "build_vehicle", "vehicle_model",
           "model_from_dict", "to_model_dict", "read_model_file", "write_model_file"]
#: UDrobot models: shipped coefficient set : damping form.
MODEL_NAMES = ("cfd:chin", "cfd:morison", "free_decay:morison", "pendulum:chin", "pendulum:morison")
#: Other vehicles shipped as descriptions with their own published coefficients (models/NAME.toml).
VEHICLE_MODEL_NAMES = ("bluerov2", "bluerov2-heavy")
#: Every model name accepted by :func:`load_model` besides a file path.
ALL_MODEL_NAMES = MODEL_NAMES + VEHICLE_MODEL_NAMES
VEHICLE_FORMAT = "udrobot-vehicle/1"


@dataclass(frozen=True)
class Thruster:
    """One thruster: position (m, body frame), unit direction of positive thrust, limits (N).

    Attributes
    ----------
    name : str
        Thruster name (``T1`` ...); thruster i is driven by the run's ``pwm_i``.
    position : tuple of 3 float
        Position of the thrust's point of application relative to CO in body axes, m.
    direction : tuple of 3 float
        Unit vector (dimensionless) of positive thrust in body axes.
    max_forward_N, max_reverse_N : float
        Largest thrust magnitude along ``direction`` and against it, N (both >= 0).
    """

    name: str
    position: tuple
    direction: tuple
    max_forward_N: float
    max_reverse_N: float


@dataclass(frozen=True)
class Vehicle:
    """Nominal 6-DOF plant parameters (SI units, body frame at CO, SNAME axes).

    Attributes
    ----------
    mass : float
        Rigid-body mass, kg.
    inertia_cg : (3, 3) ndarray
        Inertia about the CG in body axes, kg m^2.
    r_g, r_b : (3,) ndarray
        Centres of gravity and buoyancy relative to CO, m.
    weight, buoyancy : float
        W = m g and B = rho g V, N.
    added_mass, linear_damping, quadratic_damping : (6, 6) ndarray
        M_A (kg, kg m^2), D_L (N s/m, N m s) and Q with D_n(nu)_ij = Q_ij |nu_j|.
    thrusters : tuple of Thruster
        The thrusters in the autopilot's motor order (thruster i is driven by ``pwm_i``).
    name : str
        Model name (``pendulum:chin``, ``bluerov2-heavy`` ...).
    rho : float
        Water density, kg/m^3 (default 1000).
    g : float
        Gravitational acceleration, m/s^2 (default 9.81).
    provenance : dict
        ``{"field[i][j]": "measured: ..."}`` for every non-default number.
    extras : dict
        Optional description data carried along: ``voltage`` (thruster supply, V), ``thruster_model`` (curve
        name), ``ardusub_frame`` (the AP_Motors6DOF frame name).
    effects : tuple of PlantEffect
        Effects beyond the nominal model (:mod:`udrobot_ctrl.dynamics.effects`), empty for a nominal plant.
    """

    name: str
    mass: float
    inertia_cg: np.ndarray
    r_g: np.ndarray
    r_b: np.ndarray
    weight: float
    buoyancy: float
    added_mass: np.ndarray
    linear_damping: np.ndarray
    quadratic_damping: np.ndarray
    thrusters: tuple
    rho: float = 1000.0
    g: float = 9.81
    provenance: dict = field(default_factory=dict)
    extras: dict = field(default_factory=dict)
    effects: tuple = ()  # PlantEffect entries (udrobot_ctrl.dynamics.effects): the plant beyond the nominal model

    @property
    def n_thrusters(self) -> int:
        return len(self.thrusters)

    def with_changes(self, **changes) -> Vehicle:
        """A copy with some fields replaced (e.g. a scaled damping for a sensitivity study)."""
        return replace(self, **changes)


# ----------------------------------------------------------------------------- loading
def _models_dir():
    return resources.files("udrobot_ctrl.models")


def _read_toml(name: str) -> dict:
    res = _models_dir().joinpath(name)
    if not res.is_file():
        raise FileNotFoundError(f"model data file {name!r} is not shipped in udrobot_ctrl.models")
    return tomllib.loads(res.read_text())


def resolve_curve(name, model_file=None, source: str = "<description>", field: str = "thruster_model.name") -> str:
    """The thruster curve a model names (``thruster_model.name``, ``thruster_curve.name``), as
    :func:`udrobot_ctrl.dynamics.thrusters.load_curve` takes it, checked: never a file from elsewhere.

    A plain name of a shipped curve (``t200``) stays a name. Any other reference is a file (``.toml`` added when it
    has no suffix) looked up next to the model file, then in the package's models folder; it is accepted only if,
    with every link resolved, it lies inside one of those two folders (a ``..`` escape, an absolute path elsewhere
    or a link out are refused; the working folder is never searched), and is a regular file of at most
    ``MAX_CURVE_BYTES`` (never a pipe or a device such as ``/dev/zero``). A shipped model (``model_file`` None)
    may name only shipped curves.

    Parameters
    ----------
    name : str
        The reference as written in the model.
    model_file : str or Path, optional
        The model file that holds it (None for a shipped model or a dictionary).
    source : str
        The model, for messages.
    field : str
        The field holding the reference, for messages.

    Returns
    -------
    str
        The shipped name, or the absolute path of the curve file (links resolved).

    Raises
    ------
    ValueError
        Naming the model, the field and what was expected.
    """

    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"{source}: {field} must be the name of a thruster curve (t200) or a curve "
                         f"file next to the model, got {name!r}")
    if shipped_curve_name(name):
        return name
    ref = Path(name)
    if not ref.suffix:
        ref = ref.with_suffix(".toml")
    package = Path(str(_models_dir()))
    folders = [Path(model_file).resolve().parent] if model_file is not None else []
    folders.append(package)
    where = " or ".join(str(f) for f in folders)
    for folder in folders:
        candidate = ref if ref.is_absolute() else folder / ref
        if not os.path.lexists(candidate):
            continue
        if not inside(candidate, folders):
            raise ValueError(f"{source}: {field} {name!r} leads to {os.path.realpath(candidate)}, "
                             f"outside the model's folder and the package's models (expected a curve file in "
                             f"{where})")
        real = os.path.realpath(candidate)
        read_regular(real, MAX_CURVE_BYTES, f"{source}: {field} {name!r}:")
        return real
    raise ValueError(f"{source}: {field} {name!r} is neither a shipped curve (t200) nor a curve file "
                     f"in {where}" + (" (an absolute path outside those folders is not read)"
                                      if ref.is_absolute() else ""))


def _tagged(entry, where, prov, key):
    if isinstance(entry, dict):
        prov[key] = entry.get("provenance", "")
        return entry["value"]
    return entry


def vehicle_description(name: str = "udrobot") -> dict:
    """Raw vehicle description (geometry, inertia, thrusters) from ``models/NAME.toml``."""
    return _read_toml(f"{name}.toml")


def full_size_vehicle(name: str = "udrobot") -> FullSizeVehicle:
    """The full-size vehicle facts identification refers scale-model results to, from ``models/NAME.toml``.

    Projected areas (m^2, surge/sway/heave: the default areas for C_D) and displaced volume (m^3: the
    ``vehicle`` reference displaced mass of the added mass), with their provenance.
    """
    d = vehicle_description(name)
    if "projected_area" not in d:
        raise ValueError(f"models/{name}.toml has no [projected_area] table: identification needs the full-size "
                         f"projected areas (give --area instead)")
    areas = d["projected_area"]
    return FullSizeVehicle(projected_area={a: float(areas[a]["value"]) for a in AXES},
                           displaced_volume=float(d["displaced_volume"]["value"]), source=f"models/{name}.toml",
                           area_provenance=areas["surge"]["provenance"],
                           volume_provenance=d["displaced_volume"]["provenance"])


def coefficient_set(name: str) -> fossen.CoefficientSet:
    """Shipped coefficient set ``cfd``, ``free_decay`` or ``pendulum``, or a path to a set file."""
    path = Path(name)
    if path.suffix == ".toml" and path.exists():
        return load_coefficient_set(path)
    if name not in ("cfd", "free_decay", "pendulum"):
        raise ValueError(f"unknown coefficient set {name!r}: expected cfd, free_decay, pendulum or a .toml path")
    return coefficient_set_from_dict(_read_toml(f"{name}.toml"), f"models/{name}.toml")


def build_vehicle(set_name: str, form: str, description: dict | None = None) -> Vehicle:
    """Assemble the nominal plant from the vehicle description and a coefficient set.

    Parameters
    ----------
    set_name : str
        ``cfd``, ``free_decay``, ``pendulum`` or a path to a coefficient-set TOML.
    form : {'chin', 'morison'}
        Damping form.
    description : dict, optional
        Parsed vehicle description; the shipped UDrobot by default.

    Returns
    -------
    Vehicle
        The nominal plant named ``SET:FORM``, with the provenance of every number.
    """
    d = description or vehicle_description()
    prov: dict = {}
    rho = float(_tagged(d["rho"], "rho", prov, "rho"))
    g = float(_tagged(d["g"], "g", prov, "g"))
    mass = float(_tagged(d["mass"], "mass", prov, "mass"))
    volume = float(_tagged(d["displaced_volume"], "displaced_volume", prov, "buoyancy"))
    prov["weight"] = "derived: mass * g"
    prov["buoyancy"] = "derived: rho * g * displaced_volume; " + prov["buoyancy"]
    inertia = np.array(_tagged(d["inertia_cg"], "inertia_cg", prov, "inertia_cg"), dtype=float)
    r_g = np.array(_tagged(d["r_g"], "r_g", prov, "r_g"), dtype=float)
    r_b = np.array(_tagged(d["r_b"], "r_b", prov, "r_b"), dtype=float)
    dims = np.array([_tagged(d["geometry"][k], k, prov, f"geometry.{k}") for k in ("length", "width", "height")])
    area = np.array([_tagged(d["projected_area"][k], k, prov, f"projected_area.{k}")
                     for k in fossen.AXES])
    tm = d["thruster_model"]
    fwd = float(_tagged(tm["max_forward_N"], "", prov, "thrusters.max_forward_N"))
    rev = float(_tagged(tm["max_reverse_N"], "", prov, "thrusters.max_reverse_N"))
    thrusters = []
    for i, t in enumerate(d["thrusters"]):
        thrusters.append(Thruster(t["name"], tuple(float(v) for v in t["position"]),
                                  tuple(float(v) for v in t["direction"]), fwd, rev))
        prov[f"thrusters[{i}]"] = t.get("provenance", "")
    coeffs = coefficient_set(set_name)
    M_A = fossen.added_mass_matrix(coeffs, form, dims)
    D_L, Q = fossen.damping_matrices(coeffs, form, dims, area, rho)
    prov.update(fossen.provenance_entries(coeffs, form))
    return Vehicle(
        name=f"{coeffs.name}:{form}", mass=mass, inertia_cg=inertia, r_g=r_g, r_b=r_b,
        weight=mass * g, buoyancy=rho * g * volume, added_mass=M_A, linear_damping=D_L,
        quadratic_damping=Q, thrusters=tuple(thrusters), rho=rho, g=g, provenance=prov,
        extras={"dims": dims, "projected_area": area, "thruster_model": resolve_curve(tm.get("name", "t200")),
                "voltage": float(_tagged(tm.get("voltage", 12.0), "", prov, "thrusters.voltage"))},
    )


def _diag_entries(table: dict, src: str, what: str, prov: dict, key: str) -> np.ndarray:
    """A positive diagonal (6,) from a ``{X: {value, provenance}, ..., N: ...}`` table."""
    out = np.zeros(6)
    for i, dof in enumerate(DOF_NAMES):
        if dof not in table:
            raise ValueError(f"{src}: [hydrodynamics.{what}] lacks {dof!r} (expected X Y Z K M N)")
        val = float(_tagged(table[dof], dof, prov, f"{key}[{i}][{i}]"))
        if not np.isfinite(val) or val < 0:
            raise ValueError(f"{src}: [hydrodynamics.{what}] {dof} = {val!r}: expected a finite value >= 0 "
                             "(positive magnitude, M_A = -diag(X_udot, ...), D = -diag(X_u, ...))")
        out[i] = val
    return out


def _thrust_limits_at(voltage: float, curve_name: str):
    """(max_forward_N, max_reverse_N) of the shipped thruster curve ``models/CURVE.toml`` at ``voltage`` (V)."""
    return thrust_limits(voltage, load_curve(curve_name))


def vehicle_from_description(d: dict, source: str = "<description>", model_file=None) -> Vehicle:
    """A :class:`Vehicle` from a description that carries its own coefficients (``[hydrodynamics]``).

    The description (docs/vehicle_models.md) gives rho, g, mass, displaced volume, inertia about the CG, r_g,
    r_b, the positive diagonals of M_A, D_L and D_n per DOF, the thruster model (curve name and supply voltage:
    the thrust limits are the curve's at that voltage unless ``max_forward_N``/``max_reverse_N`` are given) and
    the thrusters in autopilot motor order. Every number keeps its provenance string. ``model_file``: the TOML
    file read (None for a shipped vehicle): a thruster curve it names is looked for next to it
    (:func:`resolve_curve`).

    Raises
    ------
    ValueError
        Naming ``source`` and the field, for a missing or malformed entry.
    """
    if d.get("format") != VEHICLE_FORMAT:
        raise ValueError(f"{source}: field 'format' is {d.get('format')!r}, expected {VEHICLE_FORMAT!r}")
    if "hydrodynamics" not in d:
        raise ValueError(f"{source}: no [hydrodynamics] table: a description without its own coefficients "
                         "needs a coefficient set (SET:FORM)")
    prov: dict = {}
    try:
        rho = float(_tagged(d["rho"], "rho", prov, "rho"))
        g = float(_tagged(d["g"], "g", prov, "g"))
        mass = float(_tagged(d["mass"], "mass", prov, "mass"))
        volume = float(_tagged(d["displaced_volume"], "displaced_volume", prov, "buoyancy"))
        inertia = np.array(_tagged(d["inertia_cg"], "inertia_cg", prov, "inertia_cg"), dtype=float)
        r_g = np.array(_tagged(d["r_g"], "r_g", prov, "r_g"), dtype=float)
        r_b = np.array(_tagged(d["r_b"], "r_b", prov, "r_b"), dtype=float)
        hyd = d["hydrodynamics"]
        tm = d["thruster_model"]
        tables = [hyd[k] for k in ("added_mass", "linear_damping", "quadratic_damping")]
    except KeyError as exc:
        raise ValueError(f"{source}: missing field {exc.args[0]!r}") from None
    prov["weight"] = "derived: mass * g"
    prov["buoyancy"] = "derived: rho * g * displaced_volume; " + prov["buoyancy"]
    M_A, D_L, Q = (np.diag(_diag_entries(tab, source, k, prov, k)) for tab, k in
                   zip(tables, ("added_mass", "linear_damping", "quadratic_damping")))
    voltage = float(_tagged(tm["voltage"], "", prov, "thrusters.voltage"))
    curve = resolve_curve(tm.get("name", "t200"), model_file, source)
    if "max_forward_N" in tm:
        fwd = float(_tagged(tm["max_forward_N"], "", prov, "thrusters.max_forward_N"))
        rev = float(_tagged(tm["max_reverse_N"], "", prov, "thrusters.max_reverse_N"))
    else:
        fwd, rev = _thrust_limits_at(voltage, curve)
        prov["thrusters.max_forward_N"] = prov["thrusters.max_reverse_N"] = (
            f"derived: models/{curve}.toml bollard curve at {voltage:g} V (pwm 1900 / 1100 us)")
    thrusters = []
    for i, t in enumerate(d.get("thrusters", [])):
        try:
            pos, dirn = np.array(t["position"], float), np.array(t["direction"], float)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: thrusters[{i}] needs numeric position and direction ({exc})") from None
        if pos.shape != (3,) or dirn.shape != (3,) or abs(np.linalg.norm(dirn) - 1.0) > 1e-6:
            raise ValueError(f"{source}: thrusters[{i}]: position and direction must be 3-vectors, direction of "
                             f"unit length (got |d| = {np.linalg.norm(dirn):.6g})")
        thrusters.append(Thruster(str(t.get("name", f"T{i + 1}")), tuple(pos), tuple(dirn), fwd, rev))
        prov[f"thrusters[{i}]"] = t.get("provenance", "")
    if not thrusters:
        raise ValueError(f"{source}: no [[thrusters]]")
    name = str(d.get("name", Path(source).stem))
    return Vehicle(
        name=name, mass=mass, inertia_cg=inertia, r_g=r_g, r_b=r_b, weight=mass * g, buoyancy=rho * g * volume,
        added_mass=M_A, linear_damping=D_L, quadratic_damping=Q, thrusters=tuple(thrusters), rho=rho, g=g,
        provenance=prov,
        extras={"thruster_model": curve, "voltage": voltage, "ardusub_frame": d.get("ardusub_frame"),
                "places": tuple(t.get("place", "") for t in d["thrusters"]),
                "alternatives": {k: {q: np.asarray(v[q], float) for q in ("added_mass", "linear_damping",
                                                                           "quadratic_damping") if q in v}
                                 for k, v in d.get("alternatives", {}).items()}},
    )


def vehicle_model(name: str) -> Vehicle:
    """A shipped vehicle with its own coefficients (:data:`VEHICLE_MODEL_NAMES`) or a path to such a TOML.

    Parameters
    ----------
    name : str
        ``bluerov2``, ``bluerov2-heavy`` or the path of a ``udrobot-vehicle/1`` TOML with ``[hydrodynamics]``.

    Returns
    -------
    Vehicle
        The vehicle with its published coefficients (docs/vehicle_models.md).
    """
    path = Path(name)
    if path.suffix.lower() == ".toml" and os.path.lexists(path):  # model_text refuses a pipe or a device
        try:
            doc = tomllib.loads(model_text(path))
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{path}: not valid TOML ({exc})") from exc
        return vehicle_from_description(doc, str(path), model_file=path)
    if name not in VEHICLE_MODEL_NAMES:
        raise ValueError(f"unknown vehicle {name!r}: expected one of {', '.join(VEHICLE_MODEL_NAMES)} or a "
                         "udrobot-vehicle/1 .toml path")
    return vehicle_from_description(_read_toml(f"{name}.toml"), f"models/{name}.toml")


def load_model(model) -> Vehicle:
    """A :class:`Vehicle` from a model name (:data:`ALL_MODEL_NAMES`), a model file, or a Vehicle.

    Parameters
    ----------
    model : str, Path or Vehicle
        ``SET:FORM`` (UDrobot, :data:`MODEL_NAMES`), a vehicle name (:data:`VEHICLE_MODEL_NAMES`), a
        ``udrobot-model/1`` JSON path, a ``udrobot-vehicle/1`` TOML path with its own ``[hydrodynamics]``, or a
        Vehicle (returned as it is).

    Returns
    -------
    Vehicle
        The model (SI units, body frame at CO).

    Raises
    ------
    ValueError
        For an unknown name or an invalid file (the message names the file and field).
    """
    if isinstance(model, Vehicle):
        return model
    text = str(model)
    path = Path(text)
    if text in VEHICLE_MODEL_NAMES or (path.suffix.lower() == ".toml" and os.path.lexists(path)):
        return vehicle_model(text)
    if path.suffix.lower() == ".json" or (path.exists() and path.is_file()):
        return read_model_file(path)
    if ":" not in text:
        raise ValueError(f"model {text!r}: expected SET:FORM (one of {', '.join(MODEL_NAMES)}), a vehicle "
                         f"({', '.join(VEHICLE_MODEL_NAMES)}) or a model file")
    set_name, form = text.rsplit(":", 1)
    return build_vehicle(set_name, form)


def apply_motor_directions(vehicle: Vehicle, directions) -> Vehicle:
    """The vehicle as seen through logged PWM when ArduSub ``MOT_i_DIRECTION`` = ``directions[i]`` (+1 or -1).

    ArduSub's motor factor tables (and the shipped BlueROV2 models) give the force of a positive motor
    command. ``MOT_i_DIRECTION = -1`` (a propeller of the other hand, or swapped motor wires) makes the autopilot
    output ``pwm_i`` = 1500 - (command) instead of 1500 + (command): a logged ``pwm_i`` below 1500 us is then the
    thruster's strong (forward) sense along ``direction``, above 1500 us its weak sense along ``-direction``.
    The exact treatment converts the logged PWM to the motor command first
    (:func:`udrobot_ctrl.io.mavlink.motor_command_pwm`) and keeps this model. This function gives the
    nearest model for the logged PWM as it is: thruster i's direction negated and its forward/reverse limits
    swapped; between the limits the PWM -> thrust curve of the other sense is used (the T200's forward and
    reverse curves differ by up to ~25 %, models/t200.toml).
    """
    dirs = np.asarray(directions, float).ravel()
    if dirs.shape != (vehicle.n_thrusters,) or not np.all(np.isin(dirs, (-1.0, 1.0))):
        raise ValueError(f"model {vehicle.name!r}: expected {vehicle.n_thrusters} motor directions of +1 or -1, "
                         f"got {list(np.asarray(directions).ravel())}")
    thr = tuple(t if s > 0 else replace(t, direction=tuple(-np.asarray(t.direction, float)),
                                        max_forward_N=t.max_reverse_N, max_reverse_N=t.max_forward_N)
                for t, s in zip(vehicle.thrusters, dirs))
    prov = dict(vehicle.provenance)
    for i, s in enumerate(dirs):
        if s < 0:
            prov[f"thrusters[{i}]"] = (prov.get(f"thrusters[{i}]", "") + "; direction reversed and limits swapped "
                                       "(MOT_DIRECTION = -1)")
    return replace(vehicle, thrusters=thr, provenance=prov)


# ----------------------------------------------------------------------------- udrobot-model/1
def to_model_dict(v: Vehicle) -> dict:
    """The ``udrobot-model/1`` document of a vehicle (docs/formats/model.md).

    Parameters
    ----------
    v : Vehicle
        The vehicle.

    Returns
    -------
    dict
        JSON-ready document (lists, SI units); :func:`model_from_dict` reads it back.
    """
    return {
        "format": MODEL_FORMAT,
        "name": v.name,
        "rho": v.rho,
        "g": v.g,
        "mass": v.mass,
        "inertia_cg": np.asarray(v.inertia_cg).tolist(),
        "r_g": np.asarray(v.r_g).tolist(),
        "r_b": np.asarray(v.r_b).tolist(),
        "weight": v.weight,
        "buoyancy": v.buoyancy,
        "added_mass": np.asarray(v.added_mass).tolist(),
        "linear_damping": np.asarray(v.linear_damping).tolist(),
        "quadratic_damping": np.asarray(v.quadratic_damping).tolist(),
        "thrusters": [
            {"name": t.name, "position": list(t.position), "direction": list(t.direction),
             "max_forward_N": t.max_forward_N, "max_reverse_N": t.max_reverse_N}
            for t in v.thrusters
        ],
        "provenance": dict(v.provenance),
        **({"effects": [e.to_dict() for e in v.effects]} if v.effects else {}),
        **_curve_entry(v),
        **({"ardusub_frame": str(v.extras["ardusub_frame"])} if (v.extras or {}).get("ardusub_frame") else {}),
    }


def _curve_entry(v: Vehicle) -> dict:
    """Optional ``thruster_curve`` field: the curve and supply voltage behind the limits and pwm -> thrust."""
    ex = v.extras or {}
    if "voltage" not in ex:
        return {}
    return {"thruster_curve": {"name": str(ex.get("thruster_model", "t200")), "supply_voltage_V": float(ex["voltage"])}}


#: relative disagreement allowed between a model file's ``weight`` and its ``mass * g``: a weight written to four
#: significant figures (the file format's example writes 91.8 N for 9.36 kg at 9.81 m/s^2, 0.02 % off)
WEIGHT_TOLERANCE = 1e-3
MODEL_KEYS = ("format", "name", "rho", "g", "mass", "inertia_cg", "r_g", "r_b", "weight", "buoyancy", "added_mass",
              "linear_damping", "quadratic_damping", "thrusters", "provenance", "effects", "thruster_curve",
              "ardusub_frame")
THRUSTER_KEYS = ("name", "position", "direction", "max_forward_N", "max_reverse_N")
PSD_TOL = 1e-9  # relative: eigenvalues of sym(D) above -PSD_TOL * max|D| count as >= 0 (round-off of exported files)


def did_you_mean(key: str, known) -> str:
    """`` (did you mean 'x'?)`` for the closest known key (difflib), or ''."""
    close = difflib.get_close_matches(str(key), list(known), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _missing(key: str, doc: dict, known, where: str) -> ValueError:
    """Error for a missing field, pointing at an unknown field of ``doc`` that looks like a typo of it."""
    close = difflib.get_close_matches(key, [k for k in doc if k not in known], n=1, cutoff=0.6)
    hint = f" (found {close[0]!r}: a typo of {key!r}?)" if close else ""
    return ValueError(f"{where}: missing field {key!r}{hint}")


def _check_keys(doc: dict, known, where: str) -> None:
    """Warn about unknown keys (kept out of the model), with the closest known key."""
    for key in doc:
        if key not in known:
            warnings.warn(f"{where}: unknown field {key!r} ignored{did_you_mean(key, known)}; known fields: "
                          f"{', '.join(known)}", UserWarning, stacklevel=4)


def _numbers_only(value, where: str) -> None:
    """Reject booleans and strings anywhere in a (nested list) value: JSON true is not 1."""
    if isinstance(value, (bool, str)) or value is None:
        raise ValueError(f"{where}: expected a number, got {json.dumps(value)}")
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            _numbers_only(v, f"{where}[{i}]")


def _matrix(doc, key, shape, src):
    if key not in doc:
        raise _missing(key, doc, MODEL_KEYS, src)
    _numbers_only(doc[key], f"{src}: field {key!r}")
    try:
        a = np.array(doc[key], dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{src}: field {key!r} is not numeric ({exc})") from exc
    if a.shape != shape:
        raise ValueError(f"{src}: field {key!r} has shape {a.shape}, expected {shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{src}: field {key!r} has non-finite entries")
    return a


def _check_dissipative(D: np.ndarray, key: str, src: str) -> None:
    """A damping matrix must dissipate: diagonal >= 0 and the symmetric part positive semidefinite."""
    diag = np.diag(D)
    if np.any(diag < 0):
        i = int(np.argmax(diag < 0))
        raise ValueError(f"{src}: field {key!r}[{i}][{i}] = {float(diag[i])!r} < 0 ({DOF_NAMES[i]}): negative damping "
                         f"feeds energy into the motion; expected >= 0")
    eig = np.linalg.eigvalsh(0.5 * (D + D.T))
    if eig.min() < -PSD_TOL * max(float(np.abs(D).max()), 1.0):
        raise ValueError(f"{src}: field {key!r}: symmetric part has eigenvalue {eig.min():.4g} < 0; the "
                         f"off-diagonal terms make the damping generate energy for some motion (expected "
                         f"(D + D^T)/2 positive semidefinite)")


def _thruster(t, i: int, src: str) -> Thruster:
    where = f"{src}: thrusters[{i}]"
    if not isinstance(t, dict):
        raise ValueError(f"{where}: expected an object with {', '.join(THRUSTER_KEYS)}, got {json.dumps(t)}")
    _check_keys(t, THRUSTER_KEYS, where)
    for key in THRUSTER_KEYS:
        if key not in t:
            raise _missing(key, t, THRUSTER_KEYS, where)
    vec = {}
    for key in ("position", "direction"):
        _numbers_only(t[key], f"{where}.{key}")
        a = np.asarray(t[key], dtype=float) if isinstance(t[key], list) else np.zeros(0)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(f"{where}.{key}: expected 3 finite numbers (m, body frame), got {json.dumps(t[key])}")
        vec[key] = a
    norm = float(np.linalg.norm(vec["direction"]))
    if abs(norm - 1.0) > 1e-3:
        raise ValueError(f"{where}.direction: |d| = {norm:.6g}; expected a unit vector (the direction of positive "
                         f"thrust)")
    lim = {}
    for key in ("max_forward_N", "max_reverse_N"):
        _numbers_only(t[key], f"{where}.{key}")
        lim[key] = float(t[key])
        if not np.isfinite(lim[key]) or lim[key] < 0 or (key == "max_forward_N" and lim[key] == 0):
            raise ValueError(f"{where}.{key} = {t[key]!r}: expected a finite thrust magnitude in N, "
                             f"{'> 0' if key == 'max_forward_N' else '>= 0'}")
    return Thruster(str(t["name"]), tuple(vec["position"].tolist()), tuple(vec["direction"].tolist()),
                    lim["max_forward_N"], lim["max_reverse_N"])


def model_from_dict(doc: dict, source: str = "<dict>", model_file=None) -> Vehicle:
    """Parse and check a ``udrobot-model/1`` document; errors name the source and field.

    Rejected: booleans or strings as numbers, non-positive rho, g, mass, weight, a weight not mass * g
    (:data:`WEIGHT_TOLERANCE`), negative buoyancy, inertia not symmetric positive definite, negative or
    energy-generating damping, thrusters with non-finite position, non-unit direction or negative limits.
    Unknown fields are ignored with a warning (and a "did you mean").

    Parameters
    ----------
    doc : dict
        The parsed document.
    source : str
        Where it came from (a file name), for the error messages.
    model_file : str or Path, optional
        The model file the document was read from: a thruster curve it names is looked up next to it (or in the
        package's models folder) only (:func:`resolve_curve`).

    Returns
    -------
    Vehicle
        The checked model.
    """
    if not isinstance(doc, dict):
        raise ValueError(f"{source}: expected a JSON object (udrobot-model/1), got {type(doc).__name__}")
    if doc.get("format") != MODEL_FORMAT:
        raise ValueError(f"{source}: field 'format' is {doc.get('format')!r}, expected {MODEL_FORMAT!r}")
    _check_keys(doc, MODEL_KEYS, source)
    scal = {}
    for key in ("rho", "g", "mass", "weight", "buoyancy"):
        if key not in doc:
            raise _missing(key, doc, MODEL_KEYS, source)
        if isinstance(doc[key], bool) or not isinstance(doc[key], (int, float)):
            raise ValueError(f"{source}: field {key!r} must be a number, got {json.dumps(doc[key])}")
        scal[key] = float(doc[key])
        if not np.isfinite(scal[key]) or (scal[key] < 0 if key == "buoyancy" else scal[key] <= 0):
            raise ValueError(f"{source}: field {key!r} = {doc[key]!r} must be finite and "
                             f"{'>= 0' if key == 'buoyancy' else '> 0'}")
    mg = scal["mass"] * scal["g"]
    if abs(scal["weight"] - mg) > WEIGHT_TOLERANCE * mg:
        raise ValueError(f"{source}: field 'weight' = {doc['weight']!r} N disagrees with mass * g = "
                         f"{scal['mass']:g} kg * {scal['g']:g} m/s^2 = {mg:.4g} N by "
                         f"{100 * (scal['weight'] / mg - 1):+.3g} %; expected the same weight to "
                         f"{100 * WEIGHT_TOLERANCE:g} % (W = m g, Fossen 2021 eq. 4.6: a trim error belongs in "
                         f"'buoyancy')")
    if not isinstance(doc.get("thrusters", []), list):
        raise ValueError(f"{source}: field 'thrusters' must be a list of thruster objects")
    thrusters = [_thruster(t, i, source) for i, t in enumerate(doc.get("thrusters", []))]
    inertia = _matrix(doc, "inertia_cg", (3, 3), source)
    if not np.allclose(inertia, inertia.T, atol=1e-9 * max(float(np.abs(inertia).max()), 1.0)) or \
            np.linalg.eigvalsh(inertia).min() <= 0:
        raise ValueError(f"{source}: field 'inertia_cg' must be symmetric positive definite (kg m^2)")
    damping = {k: _matrix(doc, k, (6, 6), source) for k in ("linear_damping", "quadratic_damping")}
    for key, D in damping.items():
        _check_dissipative(D, key, source)
    added = _matrix(doc, "added_mass", (6, 6), source)
    if np.any(np.diag(added) < 0):
        i = int(np.argmax(np.diag(added) < 0))
        warnings.warn(f"{source}: field 'added_mass'[{i}][{i}] = {float(added[i, i])!r} < 0 ({DOF_NAMES[i]}); "
                      f"unusual for a submerged body", UserWarning, stacklevel=2)
    extras = {}
    curve = doc.get("thruster_curve")
    if curve is not None:
        try:
            extras = {"thruster_model": resolve_curve(curve.get("name", "t200"), model_file, source,
                                                            "thruster_curve.name"),
                      "voltage": float(curve["supply_voltage_V"])}
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: field 'thruster_curve' must be {{\"name\": str, \"supply_voltage_V\": "
                             f"number}} ({exc!r})") from exc
        if not (np.isfinite(extras["voltage"]) and extras["voltage"] > 0):
            raise ValueError(f"{source}: thruster_curve.supply_voltage_V = {curve['supply_voltage_V']!r} must be > 0")
    frame = doc.get("ardusub_frame")
    if frame is not None:
        if not isinstance(frame, str) or not frame:
            raise ValueError(f"{source}: field 'ardusub_frame' must be an ArduSub frame name such as "
                             f"\"VECTORED_6DOF\", got {frame!r}")
        extras["ardusub_frame"] = frame
    effects = parse_effects(doc.get("effects"), source)
    check_against_model(effects, linear_damping=damping["linear_damping"],
                        quadratic_damping=damping["quadratic_damping"], buoyancy=scal["buoyancy"],
                        weight=scal["weight"], r_g=_matrix(doc, "r_g", (3,), source),
                        r_b=_matrix(doc, "r_b", (3,), source), source=source,
                        thruster_positions=[t.position for t in thrusters])
    return Vehicle(
        name=str(doc.get("name", Path(source).stem)), mass=scal["mass"],
        inertia_cg=inertia, r_g=_matrix(doc, "r_g", (3,), source),
        r_b=_matrix(doc, "r_b", (3,), source), weight=scal["weight"], buoyancy=scal["buoyancy"],
        added_mass=added, linear_damping=damping["linear_damping"], quadratic_damping=damping["quadratic_damping"],
        thrusters=tuple(thrusters), rho=scal["rho"], g=scal["g"], provenance=dict(doc.get("provenance", {})),
        effects=effects,
        extras=extras,
    )


#: the largest model file read, bytes (assumed: a udrobot-model/1 JSON or a vehicle TOML is a few kB, 16 MiB leaves
#: room for any provenance and effects list and stops a huge or endless file at once)
MAX_MODEL_BYTES = 16 << 20


def model_text(path) -> str:
    """The text of a model file: a regular file of at most :data:`MAX_MODEL_BYTES` (never a pipe or a device,
    :func:`udrobot_files.inputs.read_regular`), UTF-8.

    Raises
    ------
    FileNotFoundError
        No such file.
    ValueError
        Not a regular file, too large, or not UTF-8 (``UnicodeDecodeError``).
    """
    if not os.path.lexists(path):
        raise FileNotFoundError(f"model file {path} does not exist")
    return read_regular(path, MAX_MODEL_BYTES, "model file").decode("utf-8")


def read_model_file(path) -> Vehicle:
    """Read a ``udrobot-model/1`` JSON file.

    Parameters
    ----------
    path : str or Path
        The JSON file.

    Returns
    -------
    Vehicle
        The checked model (:func:`model_from_dict`).
    """
    path = Path(path)
    try:
        doc = json.loads(model_text(path), object_pairs_hook=unique_keys(path))  # a second 'effects' is refused
    except FileNotFoundError:
        raise FileNotFoundError(f"model file {path} does not exist") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        where = (f"line {exc.lineno}, column {exc.colno}: {exc.msg}" if isinstance(exc, json.JSONDecodeError)
                 else f"byte {exc.start} is not UTF-8 text")
        raise ValueError(f"{path}: not a model file: {_what_file_is(path)}not valid JSON ({where}); a model is "
                         f"a name ({', '.join(ALL_MODEL_NAMES)}), a "
                         f"udrobot-model/1 JSON or a udrobot-vehicle/1 TOML") from exc
    return model_from_dict(doc, str(path), model_file=path)


def _what_file_is(path: Path) -> str:
    """'this is a run log (...); ' when ``path`` looks like a udrobot-run/1 CSV or a field log, else ''."""
    suffix = path.suffix.lower()
    if suffix in (".bin", ".tlog", ".bag", ".mcap", ".db3"):
        return f"this is a field log ({suffix}: give it to convert, simulate --input or diagnose as a run); "
    try:
        with path.open("r", errors="replace") as fh:
            header = fh.readline()
    except OSError:
        return ""
    cells = [c.strip() for c in header.split(",")]
    if "t" in cells and len(cells) > 1:
        return "this is a run log (a CSV with a 't' column: give it as a run, not as --model); "
    return ""


def write_model_file(v: Vehicle, path, protect=()) -> None:
    """Write ``udrobot-model/1`` JSON atomically (never over a file in ``protect``: :mod:`udrobot_files.output`).

    Parameters
    ----------
    v : Vehicle
        The model to write (:func:`to_model_dict`).
    path : str or Path
        Destination file.
    protect : sequence of path, optional
        Files that must not be overwritten (the command's inputs).
    """
    atomic_write(path, json.dumps(to_model_dict(v), indent=2), protect=protect)


set_model_loader(load_model)  # the dynamics layer resolves model names with it (dynamics.sim.as_parameters)
