"""The coefficient parameter space of a sensitivity study and how a sample perturbs a vehicle.

Parameters (names are ``AXIS.QUANTITY``):

* translational, per axis ``surge``, ``sway``, ``heave``:
  ``added_mass`` (kg), ``KL`` (N s/m, chin form), ``KQ`` (N s^2/m^2, chin form) or ``CD`` (-, morison form,
  mapped to K_D = 1/2 rho C_D A with the vehicle's projected area);
* rotational, per axis ``roll``, ``pitch``, ``yaw``: dimensionless scale factors
  ``added_mass_scale``, ``linear_damping_scale`` (chin only), ``quadratic_damping_scale`` multiplying the
  nominal strip-theory estimates (they are *estimated*, not measured, so a factor is the honest unit).

Ranges: for a translational quantity, [min, max] over the shipped sets that give it (cfd, free_decay,
pendulum; for added mass the form-specific value when the set has one) or, for a vehicle description with
its own coefficients (``bluerov2``, ``bluerov2-heavy``), over the other published sets it records
(``[alternatives]``: Wu 2018, the "11.4 kg" set), widened by ``margin`` (default
10 %, *assumed*: the paper gives no uncertainty on its coefficients, 10 % covers the regression scatter of
its fits, R^2 0.996) of the span's end values: ``[min (1 - margin), max (1 + margin)]``. The nominal value
is the user's model, and the range is extended to contain it. Rotational scales default to
[0.5, 1.5] (*assumed*: strip theory on a box is an order-of-magnitude estimate).

A sample is applied with :func:`apply_sample`: translational diagonal entries are replaced, rotational
diagonal entries are the nominal times the factor; everything else (rigid body, restoring, thrusters) is
unchanged. Each parameter therefore acts on exactly one matrix entry, so their effects can be attributed.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import tomllib

from identification.fossen import AXES, quadratic_from_drag_coefficient
from udrobot_ctrl.vehicle import Vehicle, coefficient_set, load_model, vehicle_description
from udrobot_files.nesting import loads_toml

ROT_AXES = ("roll", "pitch", "yaw")
SETS = ("cfd", "free_decay", "pendulum")
DEFAULT_MARGIN = 0.10
DEFAULT_SCALE_RANGE = (0.5, 1.5)
UNITS = {"added_mass": "kg", "KL": "N s/m", "KQ": "N s^2/m^2", "CD": "-",
         "added_mass_scale": "-", "linear_damping_scale": "-", "quadratic_damping_scale": "-"}
_MATRIX = {"added_mass": "added_mass", "KL": "linear_damping", "KQ": "quadratic_damping", "CD": "quadratic_damping",
           "added_mass_scale": "added_mass", "linear_damping_scale": "linear_damping",
           "quadratic_damping_scale": "quadratic_damping"}
_NAME_RE = re.compile(r"^(surge|sway|heave|roll|pitch|yaw)\.([A-Za-z_]+)$")


@dataclass(frozen=True)
class Parameter:
    """One uncertain coefficient.

    Attributes
    ----------
    name : str
        ``AXIS.QUANTITY``, e.g. ``surge.CD``.
    nominal : float
        Value in the nominal model, in the quantity's SI unit (:attr:`unit`: kg for an added mass, N s/m for K_L,
        N s^2/m^2 for K_Q; dimensionless for C_D and the scale factors).
    low, high : float
        Range for global studies and tornado plots, in the unit of ``nominal`` (kg, N s/m, N s^2/m^2 or -).
    source : str
        How the range was obtained (provenance of the range, ``derived``/``assumed``/``user``).
    """

    name: str
    nominal: float
    low: float
    high: float
    source: str = ""

    @property
    def axis(self) -> str:
        return self.name.split(".", 1)[0]

    @property
    def quantity(self) -> str:
        return self.name.split(".", 1)[1]

    @property
    def unit(self) -> str:
        return UNITS[self.quantity]

    @property
    def dof(self) -> int:
        return (AXES + ROT_AXES).index(self.axis)


@dataclass(frozen=True)
class ParameterSpace:
    """An ordered set of :class:`Parameter` for one damping form, with the nominal vehicle it perturbs.

    Attributes
    ----------
    parameters : tuple of Parameter
        The coefficients varied, in the order of a sample's columns.
    form : {'chin', 'morison'}
        The damping form of the coefficients.
    vehicle : Vehicle
        The nominal vehicle a sample perturbs (:func:`apply_sample`).
    """

    parameters: tuple
    form: str
    vehicle: Vehicle = field(repr=False, compare=False, default=None)

    @property
    def names(self) -> list:
        return [p.name for p in self.parameters]

    @property
    def nominal(self) -> np.ndarray:
        return np.array([p.nominal for p in self.parameters])

    @property
    def bounds(self) -> np.ndarray:
        """(d, 2) array of [low, high]."""
        return np.array([[p.low, p.high] for p in self.parameters])

    def __len__(self) -> int:
        return len(self.parameters)

    def index(self, name: str) -> int:
        return self.names.index(name)

    def salib_problem(self) -> dict:
        """SALib problem dictionary (num_vars, names, bounds)."""
        return {"num_vars": len(self), "names": self.names, "bounds": self.bounds.tolist()}

    def subset(self, names) -> ParameterSpace:
        """The space restricted to ``names`` (in that order); unknown names raise ValueError."""
        names = list(names)
        unknown = [n for n in names if n not in self.names]
        if unknown:
            raise ValueError(f"unknown parameter(s) {', '.join(unknown)}; available: {', '.join(self.names)}")
        return replace(self, parameters=tuple(self.parameters[self.index(n)] for n in names))

    def with_ranges(self, ranges: dict) -> ParameterSpace:
        """Override ranges: ``{name: (low, high)}`` (source ``user``); checks low <= nominal-free ordering."""
        params = list(self.parameters)
        for name, (lo, hi) in ranges.items():
            if name not in self.names:
                raise ValueError(f"range for unknown parameter {name!r}; available: {', '.join(self.names)}")
            lo, hi = float(lo), float(hi)
            if not (np.isfinite(lo) and np.isfinite(hi)) or lo >= hi:
                raise ValueError(f"range for {name}: expected finite low < high, got {lo} .. {hi}")
            if lo < 0:
                raise ValueError(f"range for {name}: coefficients are >= 0, got low = {lo}")
            i = self.index(name)
            params[i] = replace(params[i], low=lo, high=hi, source="user")
        return replace(self, parameters=tuple(params))

    def to_records(self) -> list:
        return [{"name": p.name, "unit": p.unit, "nominal": p.nominal, "low": p.low, "high": p.high,
                 "source": p.source} for p in self.parameters]


def _form_of(vehicle: Vehicle) -> str:
    """Damping form of a vehicle: ``morison`` when its translational linear damping is zero."""
    name_form = vehicle.name.rsplit(":", 1)[-1] if ":" in vehicle.name else ""
    if name_form in ("chin", "morison"):
        return name_form
    return "morison" if np.allclose(np.diag(vehicle.linear_damping)[:3], 0.0) else "chin"


def _projected_area(vehicle: Vehicle) -> np.ndarray:
    area = vehicle.extras.get("projected_area") if vehicle.extras else None
    if area is None:  # a model file carries no extras: use the shipped UDrobot description (assumed)
        d = vehicle_description()
        area = [d["projected_area"][k]["value"] for k in AXES]
    return np.asarray(area, dtype=float)


def set_values(form: str, sets=SETS) -> dict:
    """Translational values per quantity from the coefficient sets: ``{quantity: {set: (3,) array}}``.

    Only the quantities meaningful for ``form`` are returned (chin: added_mass, KL, KQ; morison:
    added_mass, CD); a set lacking a quantity is skipped for it.
    """
    quantities = ("added_mass", "KL", "KQ") if form == "chin" else ("added_mass", "CD")
    out = {q: {} for q in quantities}
    for s in sets:
        cs = coefficient_set(s)
        out["added_mass"][cs.name] = cs.added_mass_for(form)
        for q in quantities[1:]:
            val = getattr(cs, q)
            if val is not None:
                out[q][cs.name] = np.asarray(val, float)
    return out


_ALT_MATRIX = {"added_mass": "added_mass", "KL": "linear_damping", "KQ": "quadratic_damping"}


def published_values(vehicle: Vehicle, form: str) -> dict:
    """Translational values of the other published sets a vehicle description records (``[alternatives]``).

    Same shape as :func:`set_values`: ``{quantity: {source: (3,) array}}``; empty when the vehicle has none
    (UDrobot models: their spread comes from the shipped coefficient sets instead).
    """
    alts = (vehicle.extras or {}).get("alternatives") or {}
    if not alts:
        return {}
    quantities = ("added_mass", "KL", "KQ") if form == "chin" else ("added_mass",)
    out = {q: {} for q in quantities}
    for src, mats in alts.items():
        for q in quantities:
            key = _ALT_MATRIX[q]
            if key in mats:
                out[q][src] = np.asarray(mats[key], float)[:3]
    return out


def _translational_nominal(vehicle: Vehicle, quantity: str, i: int, area) -> float:
    if quantity == "added_mass":
        return float(vehicle.added_mass[i, i])
    if quantity == "KL":
        return float(vehicle.linear_damping[i, i])
    if quantity == "KQ":
        return float(vehicle.quadratic_damping[i, i])
    if quantity == "CD":
        return float(2.0 * vehicle.quadratic_damping[i, i] / (vehicle.rho * area[i]))
    raise ValueError(quantity)


def default_space(model="cfd:morison", margin: float = DEFAULT_MARGIN, sets=SETS,
                  scale_range=DEFAULT_SCALE_RANGE, rotational: bool = True) -> ParameterSpace:
    """The full coefficient space around ``model`` with ranges from the spread between ``sets``.

    Parameters
    ----------
    model : str, path or Vehicle
        Nominal model (``SET:FORM``, a udrobot-model/1 file or a Vehicle).
    margin : float
        Relative widening of the [min, max] span over the sets (0.10 = 10 %, *assumed*).
    sets : sequence of str
        Coefficient sets whose spread defines the ranges.
    scale_range : (float, float)
        Range of the rotational scale factors (*assumed*).
    rotational : bool
        Include the rotational scale factors.

    Returns
    -------
    ParameterSpace
        The parameters with their nominal values, ranges and the provenance of each range.
    """
    if not 0 <= margin < 1:
        raise ValueError(f"margin must be in [0, 1), got {margin}")
    vehicle = load_model(model)
    form = _form_of(vehicle)
    area = _projected_area(vehicle)
    # a vehicle with its own published coefficients (BlueROV2 ...): ranges from the other published sets
    values = published_values(vehicle, form) or set_values(form, sets)
    params = []
    for quantity, per_set in values.items():
        for i, axis in enumerate(AXES):
            nominal = _translational_nominal(vehicle, quantity, i, area)
            vals = [v[i] for v in per_set.values()] + [nominal]
            lo, hi = min(vals) * (1 - margin), max(vals) * (1 + margin)
            src = (f"derived: min..max over {', '.join(per_set)} ({', '.join(f'{v[i]:.4g}' for v in per_set.values())})"
                   f" and the nominal, widened by {margin:.0%} (assumed margin)")
            params.append(Parameter(f"{axis}.{quantity}", nominal, lo, hi, src))
    if rotational:
        kinds = ["added_mass_scale", "linear_damping_scale", "quadratic_damping_scale"]
        if form != "chin":
            kinds.remove("linear_damping_scale")
        for kind in kinds:
            for axis in ROT_AXES:
                params.append(Parameter(f"{axis}.{kind}", 1.0, float(scale_range[0]), float(scale_range[1]),
                                        "assumed: factor on the strip-theory estimate (order-of-magnitude)"))
    return ParameterSpace(tuple(params), form, vehicle)


def parse_range(text: str):
    """Parse ``NAME=LOW:HIGH`` (CLI ``--range``) into ``(name, (low, high))``."""
    m = re.match(r"^\s*([a-z]+\.[A-Za-z_]+)\s*=\s*([^:]+):(.+)$", text)
    if not m:
        raise ValueError(f"--range {text!r}: expected NAME=LOW:HIGH, e.g. surge.CD=1.2:2.6")
    try:
        return m.group(1), (float(m.group(2)), float(m.group(3)))
    except ValueError:
        raise ValueError(f"--range {text!r}: LOW and HIGH must be numbers") from None


def read_ranges(path) -> dict:
    """User ranges ``{name: (low, high)}`` from the ``[ranges]`` table of a study TOML (:func:`read_study_file`)."""
    return read_study_file(path)["ranges"]


def read_study_file(path) -> dict:
    """Parse a study TOML: ``parameters = [...]`` (optional) and ``[ranges]`` ``NAME = [low, high]``.

    Returns ``{"parameters": list or None, "ranges": {name: (low, high)}}``; errors name the file and key.
    """
    path = Path(path)
    try:
        doc = loads_toml(path.read_text(), path)
    except FileNotFoundError:
        raise FileNotFoundError(f"range file {path} does not exist") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from exc
    ranges = {}
    for name, val in doc.get("ranges", {}).items():
        if not _NAME_RE.match(name):
            raise ValueError(f"{path}: [ranges] key {name!r}: expected AXIS.QUANTITY, e.g. \"surge.CD\"")
        if not (isinstance(val, list) and len(val) == 2 and all(isinstance(v, (int, float)) for v in val)):
            raise ValueError(f"{path}: [ranges] {name} = {val!r}: expected [low, high]")
        ranges[name] = (float(val[0]), float(val[1]))
    params = doc.get("parameters")
    if params is not None and not (isinstance(params, list) and all(isinstance(p, str) for p in params)):
        raise ValueError(f"{path}: 'parameters' must be a list of names")
    return {"parameters": params, "ranges": ranges}


def apply_sample(space: ParameterSpace, values, vehicle: Vehicle | None = None) -> Vehicle:
    """A copy of the nominal vehicle with the coefficients of ``values`` (one per parameter).

    Raises
    ------
    ValueError
        On a wrong length, a non-finite value or a negative coefficient (naming the parameter).
    """
    vehicle = vehicle if vehicle is not None else space.vehicle
    values = np.asarray(values, dtype=float)
    if values.shape != (len(space),):
        raise ValueError(f"sample has shape {values.shape}, expected ({len(space)},) for {space.names}")
    mats = {k: np.array(getattr(vehicle, k), dtype=float) for k in ("added_mass", "linear_damping",
                                                                   "quadratic_damping")}
    area = None
    for p, v in zip(space.parameters, values):
        if not np.isfinite(v) or v < 0:
            raise ValueError(f"parameter {p.name} = {v}: expected a finite value >= 0")
        if v == p.nominal and vehicle is space.vehicle:
            continue  # keep the nominal entry bit-for-bit (C_D -> K_D round trip would change the last digit)
        j = p.dof
        q = p.quantity
        if q == "CD":
            area = _projected_area(vehicle) if area is None else area
            mats["quadratic_damping"][j, j] = float(quadratic_from_drag_coefficient(v, area[j], vehicle.rho))
        elif q.endswith("_scale"):
            nominal_entry = getattr(vehicle, _MATRIX[q])[j, j]
            mats[_MATRIX[q]][j, j] = nominal_entry * v
        else:
            mats[_MATRIX[q]][j, j] = v
    return vehicle.with_changes(**mats)
