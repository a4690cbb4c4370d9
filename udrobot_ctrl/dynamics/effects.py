"""Unmodelled effects as parts of the plant: the diagnosis catalogue written once, for every tool.

A model may carry an ``effects`` list (``udrobot-model/1``, ``docs/formats/model.md``): each entry is a
:class:`PlantEffect`, a catalogue name and its parameters, as the diagnoser reports them. Every effect enters
the plant in one of three ways:

* **parameters** -- it changes the nominal matrices, so every tool (numpy, casadi, numba kernels, linearisation,
  controller design) simulates it for free (:func:`fold_parameters`):

  ``linear_damping``            D_L,ii += d_i  (``d_Xu`` ... ``d_Nr``; N s/m, N m s)
  ``quadratic_damping_error``   Q_ii *= 1 + s_i  (``scale_Xu|u|`` ...); with the optional ``norm_weight`` a in
                                [0, 1] (default 0) the error's drag acts on the speed, not per axis:
                                -s_i Q_ii ((1 - a) |nu_i| + a |nu_g|) nu_i, |nu_g| the norm of the translational
                                (u v w) or rotational (p q r) velocity (the cross-flow principle: a body's drag
                                grows with the flow speed, which a per-axis |nu_i| nu_i model identified on
                                single-axis tests misses in combined motion). The norm part enters as a force
  ``added_mass_error``          M_A,ii *= 1 + s_i  (``scale_Xdu`` ...; M and its Coriolis part follow)
  ``cross_coupled_damping``     D_L,ij += D_ij, Q_ij += Q_ij  (``D_Xv``, ``Q_Xv|v|`` ...)
  ``buoyancy_offset``           B += dB  (``dB_N``; acting at the centre of buoyancy)
  ``cg_cb_offset``              (r_g W - r_b B) += dBG  (``dBG_x_Nm`` ...; the centre of buoyancy moves)

* **thrust** -- it changes the thrust each actuator delivers (:func:`static_thrust`, :func:`inflow_loss`,
  :func:`first_order_lag`):

  ``thruster_deadband``   a deadband of ``width_fraction`` w in the normalised command u = (|f|/F)^(1/p),
                          p = ``command_exponent`` in [1, 2] (optional, default 1): f -> 0 for u < w; beyond,
                          f -> f - c sign(f) (|f| - F (u - w)^p / (1 - w)^(2(p-1))), c = ``shift`` (0 hard, 1
                          continuous), F = f_ref^(2-p) C^(p-1), C the capacity in f's direction. p = 1:
                          f - c d sign(f), d = w f_ref; p = 2, c = 1: an ESC deadband in the PWM domain with thrust
                          ~ PWM offset^2, each direction's full thrust at full command (:func:`deadband_terms`)
  ``thruster_asymmetry``  f -> (1 - ``reverse_loss``) f for f < 0
  ``thrust_inflow_loss``  f -> f - (k1 |f| + k2 sqrt(|f| f_ref)) u_a, never reversing f; u_a the actuator's axial
                          advance speed (``k1_per_mps``, ``k2_per_mps``)
  ``thruster_lag``        first-order lag of time constant ``T_lag_s`` of s = sign(f) |f|^(1/k), the thrust
                          sign(s) |s|^k; k = ``thrust_exponent`` in [1, 2] (optional, default 1: a lag of the
                          thrust; 2: of the rotor speed, thrust ~ n|n|). A state of the actuator: simulated by
                          the simulator, refused by tools that need a static plant

  f_ref is each thruster's capacity (max(max_forward_N, max_reverse_N)); for a commanded wrench (``tau_*``
  runs: six virtual actuators) the maps act per DOF, with per-DOF parameters (``shift_X`` ...) allowed.

* **force** -- an external or velocity-dependent force (:func:`external_force`):

  ``tether_drag``    F_ned = -(k_q |V_n| + k_l) V_n, V_n the NED velocity normal to the cable's direction e: from
                     the vehicle towards a fixed anchor (``anchor_north_m anchor_east_m anchor_down_m``, the frame
                     of the logged x y z), or along a fixed direction (``cable_azimuth_rad`` from north,
                     ``cable_elevation_rad`` above the horizontal; the limit of an anchor far away); an anchor
                     may walk with the vehicle (``walk_azimuth_rad``, ``walk_fraction``: a handler on the pool
                     edge, a tender boat), the drag then integrated along the moving cable; a taut cable
                     (``cable_taut`` 1) drags in proportion to its straight-line length to the anchor
  ``water_current``  damping and added-mass Coriolis act on nu_r = nu - [R^T v_c; 0] (v_c NED, m/s)
  ``wall_effect``    near a plane at distance h: added mass a_m exp(-h/lam) n n^T and suction
                     -a_s exp(-h/lam) |V_t|^2 n, summed over the planes: the seabed at ``seabed_depth_m`` (NED z)
                     and up to four walls ``wall1_point_n_m`` ... ``wall1_normal_d`` (a point of the plane, NED m,
                     and its normal into the water) -- at least one plane.
  ``drag_centre_offset``  the base model's translational damping force (linear + quadratic, the u v w block of
                     D_L and Q) acts at the centre of pressure r_cp = (``x_cp_m y_cp_m z_cp_m``) from the CO: it is
                     evaluated with the velocity of that point, v_cp = v_r + omega x r_cp, and adds the moment
                     r_cp x F (:func:`drag_centre_force`); dissipative by construction (its power with the
                     nominal translational drag it replaces is F . v_cp <= 0)

  A tether (``tether_drag``) may be attached at a point r_a = (``attach_x_m attach_y_m attach_z_m``, optional,
  default 0: the CO) of the hull: its drag is evaluated with that point's position and velocity and adds the moment
  r_a x F (:func:`tether_unit_forces`).

Each term is written once with the elementary functions of a backend (:class:`Backend`: numpy arrays of any
batch shape, or casadi expressions), so the numpy plant, its casadi twin and the diagnoser evaluate the same
physics.
"""
from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np
from scipy.signal import lfilter

from udrobot_ctrl.constants import DOF_NAMES as DOF
from udrobot_ctrl.constants import VELOCITY_NAMES as VEL

CROSS_PAIRS = tuple((i, j) for i in range(6) for j in range(6) if i != j)


def _per_dof(prefix):
    return tuple(f"{prefix}_{d}" for d in DOF)


@dataclass(frozen=True)
class EffectKind:
    """A catalogue entry as the plant sees it.

    Attributes
    ----------
    name : str
    meaning : str
    enters : {'parameters', 'thrust', 'lag', 'force'}
    parameters : tuple of str
        The parameter names a model file gives.
    alternatives : tuple of tuple of str
        Other accepted parameter sets (per-DOF thruster maps of a commanded wrench).
    optional : tuple of str
        Parameters that may be absent: an exponent then takes its default (:data:`OPTIONAL_DEFAULTS`), an absent
        plane of a wall_effect is no plane.
    """

    name: str
    meaning: str
    enters: str
    parameters: tuple
    alternatives: tuple = ()
    optional: tuple = ()


WALL_SLOTS = 4  # walls a wall_effect may list besides the seabed
WALL_KEYS = ("point_n_m", "point_e_m", "point_d_m", "normal_n", "normal_e", "normal_d")
WALL_PARAMETERS = tuple(f"wall{i}_{k}" for i in range(1, WALL_SLOTS + 1) for k in WALL_KEYS)
#: the tether's cable geometry: an anchor (NED position, m, in the frame of the logged x y z) or, for model files
#: written before anchors, a fixed direction (rad)
TETHER_ANCHOR = ("anchor_north_m", "anchor_east_m", "anchor_down_m")
TETHER_FIXED_DIRECTION = ("cable_azimuth_rad", "cable_elevation_rad")
#: a top end that walks along a horizontal line (a handler on the pool edge, a tender boat) with the vehicle: the
#: line's azimuth (rad, from north) and the fraction (0-1) of the vehicle's motion along it that the top end follows
TETHER_WALK = ("walk_azimuth_rad", "walk_fraction")
#: how the cable's length follows the vehicle (with an anchor; 0-1, a blend): 0 a slack cable whose paid-out length
#: is fixed (lumped amplitudes), 1 a taut cable whose length is the straight-line distance to the top end (amplitudes
#: per metre of it)
TETHER_TAUT = "cable_taut"
#: where the cable is tied to the hull (body frame, m from the CO; optional, default 0: the CO): the drag then acts
#: there, with that point's velocity, and adds the moment r_a x F
TETHER_ATTACH = ("attach_x_m", "attach_y_m", "attach_z_m")
#: the centre of pressure of the translational drag (body frame, m from the CO), ``drag_centre_offset``
DRAG_CENTRE = ("x_cp_m", "y_cp_m", "z_cp_m")
#: the base model's translational damping a ``drag_centre_offset`` carries as a run-time force (filled in by
#: :func:`fold_parameters`; not a model-file parameter): D_L and Q, rows and columns u v w
DRAG_BLOCK_D = tuple(f"drag_D_{DOF[i]}{VEL[j]}" for i in range(3) for j in range(3))
DRAG_BLOCK_Q = tuple(f"drag_Q_{DOF[i]}{VEL[j]}|{VEL[j]}|" for i in range(3) for j in range(3))
#: the size (m) of a vehicle without thrusters, bounding a centre of pressure or a tether attachment from the CO
#: (assumed: a small ROV is under 1 m long, so any point of its hull lies within 0.5 m of a CO inside it)
ASSUMED_VEHICLE_SIZE_M = 0.5

CATALOGUE = {k.name: k for k in (
    EffectKind("thrust_inflow_loss", "thrust falls with the axial inflow speed through the thruster", "thrust",
               ("k1_per_mps", "k2_per_mps")),
    EffectKind("thruster_deadband", "small commands produce no thrust", "thrust", ("width_fraction", "shift"),
               alternatives=(("width_fraction",) + _per_dof("shift"),), optional=("command_exponent",)),
    EffectKind("thruster_asymmetry", "reverse thrust weaker than modelled, relative to forward", "thrust",
               ("reverse_loss",), alternatives=(_per_dof("reverse_loss"),)),
    EffectKind("thruster_lag", "thrust follows the command with a first-order lag", "lag", ("T_lag_s",),
               optional=("thrust_exponent",)),
    EffectKind("tether_drag", "umbilical cross-flow drag, normal to the cable", "force",
               ("k_quadratic_N_s2_per_m2", "k_linear_N_s_per_m") + TETHER_ANCHOR,
               alternatives=(("k_quadratic_N_s2_per_m2", "k_linear_N_s_per_m") + TETHER_FIXED_DIRECTION,),
               optional=TETHER_WALK + (TETHER_TAUT,) + TETHER_ATTACH),
    EffectKind("wall_effect", "extra added mass and suction near the seabed or a wall", "force",
               ("decay_length_m", "added_mass_at_contact_kg", "suction_N_s2_per_m2"),
               optional=("seabed_depth_m",) + WALL_PARAMETERS),
    EffectKind("water_current", "steady current; damping on the velocity relative to the water", "force",
               ("current_north_mps", "current_east_mps", "current_down_mps")),
    EffectKind("linear_damping", "linear damping missing or wrong", "parameters",
               tuple(f"d_{d}{v}" for d, v in zip(DOF, VEL))),
    EffectKind("quadratic_damping_error", "quadratic damping wrong in scale", "parameters",
               tuple(f"scale_{d}{v}|{v}|" for d, v in zip(DOF, VEL)), optional=("norm_weight",)),
    EffectKind("added_mass_error", "added mass wrong in scale", "parameters",
               tuple(f"scale_{d}d{v}" for d, v in zip(DOF, VEL))),
    EffectKind("cross_coupled_damping", "off-diagonal damping couples DOFs", "parameters", (),
               optional=tuple(n for i, j in CROSS_PAIRS for n in (f"D_{DOF[i]}{VEL[j]}",
                                                                  f"Q_{DOF[i]}{VEL[j]}|{VEL[j]}|"))),
    EffectKind("buoyancy_offset", "net buoyancy differs from the model", "parameters", ("dB_N",)),
    EffectKind("cg_cb_offset", "restoring moment (CG-CB separation) differs from the model", "parameters",
               ("dBG_x_Nm", "dBG_y_Nm", "dBG_z_Nm")),
    EffectKind("drag_centre_offset", "the translational drag acts at a centre of pressure off the CO", "force",
               DRAG_CENTRE),
)}
EFFECT_NAMES = tuple(CATALOGUE)
#: optional shape parameters (the thruster effects' exponents, the quadratic damping error's norm weight) and their
#: value when a model file leaves them out (the forms before they existed)
OPTIONAL_DEFAULTS = {"thrust_exponent": 1.0, "command_exponent": 1.0, "norm_weight": 0.0,
                     **dict.fromkeys(TETHER_ATTACH, 0.0)}
#: the nominal quadratic damping a ``quadratic_damping_error`` with a norm weight carries as a run-time force
#: (filled in by :func:`fold_parameters`; not a model-file parameter)
NOMINAL_Q = tuple(f"nominal_Q_{d}{v}|{v}|" for d, v in zip(DOF, VEL))
#: the range of the shape exponents: 1 (the form linear in the thrust) to 2 (thrust ~ rotor speed n|n| ~ command^2)
EXPONENT_RANGE = (1.0, 2.0)
EXPONENT_MEANING = {"thrust_exponent": "1: a lag of the thrust, 2: of the rotor speed, thrust ~ n|n|",
                    "command_exponent": "thrust ~ command^p beyond the deadband: 1 linear, 2 quadratic"}


#: the physical range of every effect parameter a model file may give: name -> (low, high, unit and why). A value
#: outside is refused where the ``effects`` list is parsed (:func:`plant_effect`), naming the file, the effect, the
#: parameter and this range. The diagnoser's search stays inside these (``udrobot_ctrl.gap.effects``: e.g. a
#: deadband width of 0.005-0.35, a lag of 0.005-1 s, damping scales of -0.95 to 10, drag amplitudes up to 1e4);
#: these ranges are wider, physical limits for hand-written files. Limits that depend on the vehicle (the total
#: damping, buoyancy and restoring moment) are checked against the base model by :func:`check_against_model`.
_POS_M = (-1e7, 1e7, "m, a position within 10 000 km of the origin of the logged x y z")
_NORMAL = (-1e6, 1e6, "-, a direction (normalised by the tool)")
_SCALE = (-1.0, 10.0, "-, a relative error: -1 removes the term (it cannot change sign), 10 is 11 times it")
_DAMPING = (-1e4, 1e4, "N s/m or N m s (the model's total must stay dissipative)")
_HULL_POINT = (-5.0, 5.0, "m from the CO, a point of the hull (also within the vehicle's size, check_against_model)")
PARAMETER_RANGES = {
    "thrust_inflow_loss": {"k1_per_mps": (0.0, 2.0, "1/(m/s), thrust lost per m/s of inflow"),
                           "k2_per_mps": (0.0, 2.0, "1/(m/s), thrust lost per m/s of inflow")},
    "thruster_deadband": {"width_fraction": (0.0, 0.9, "-, a fraction of the command range"),
                          "shift": (0.0, 1.0, "-, 0 a hard band, 1 thrust continuous from its edge"),
                          **dict.fromkeys(_per_dof("shift"), (0.0, 1.0, "-, 0 a hard band, 1 continuous")),
                          "command_exponent": (*EXPONENT_RANGE, EXPONENT_MEANING["command_exponent"])},
    "thruster_asymmetry": {"reverse_loss": (-1.0, 1.0, "-, 1 no reverse thrust, -1 twice the modelled one"),
                           **dict.fromkeys(_per_dof("reverse_loss"), (-1.0, 1.0, "-, 1 no reverse thrust"))},
    "thruster_lag": {"T_lag_s": (1e-6, 10.0, "s, a time constant > 0"),
                     "thrust_exponent": (*EXPONENT_RANGE, EXPONENT_MEANING["thrust_exponent"])},
    "tether_drag": {"k_quadratic_N_s2_per_m2": (0.0, 1e4, "N s^2/m^2, a drag (>= 0)"),
                    "k_linear_N_s_per_m": (0.0, 1e4, "N s/m, a drag (>= 0)"),
                    **dict.fromkeys(TETHER_ANCHOR, _POS_M),
                    "cable_azimuth_rad": (-2 * math.pi, 2 * math.pi, "rad, an angle from north"),
                    "cable_elevation_rad": (-math.pi / 2, math.pi / 2, "rad, an angle above the horizontal"),
                    "walk_azimuth_rad": (-2 * math.pi, 2 * math.pi, "rad, an angle from north"),
                    "walk_fraction": (0.0, 1.0, "-, the fraction of the motion the top end follows"),
                    TETHER_TAUT: (0.0, 1.0, "-, 0 slack, 1 taut"),
                    **dict.fromkeys(TETHER_ATTACH, _HULL_POINT)},
    "wall_effect": {"decay_length_m": (1e-6, 100.0, "m, a length > 0"),
                    "added_mass_at_contact_kg": (0.0, 1e4, "kg, an added mass (>= 0)"),
                    "suction_N_s2_per_m2": (0.0, 1e5, "N s^2/m^2, a suction coefficient (>= 0)"),
                    "seabed_depth_m": _POS_M,
                    **{n: (_NORMAL if "normal" in n else _POS_M) for n in WALL_PARAMETERS}},
    "water_current": {n: (-5.0, 5.0, "m/s, beyond the strongest tidal streams")
                      for n in ("current_north_mps", "current_east_mps", "current_down_mps")},
    "linear_damping": {f"d_{d}{v}": _DAMPING for d, v in zip(DOF, VEL)},
    "quadratic_damping_error": {**{f"scale_{d}{v}|{v}|": _SCALE for d, v in zip(DOF, VEL)},
                                "norm_weight": (0.0, 1.0, "-, 0 per-axis drag, 1 drag on the speed")},
    "added_mass_error": {f"scale_{d}d{v}": _SCALE for d, v in zip(DOF, VEL)},
    "cross_coupled_damping": {n: (-1e4, 1e4, "N s/m, N s^2/m^2 or their rotational forms") for i, j in CROSS_PAIRS
                              for n in (f"D_{DOF[i]}{VEL[j]}", f"Q_{DOF[i]}{VEL[j]}|{VEL[j]}|")},
    "buoyancy_offset": {"dB_N": (-1e6, 1e6, "N; also within +-0.5 W of the model, and B + dB >= 0")},
    "cg_cb_offset": {n: (-1e6, 1e6, "N m; also within +-0.1 W of the model (a 10 cm shift)")
                     for n in ("dBG_x_Nm", "dBG_y_Nm", "dBG_z_Nm")},
    "drag_centre_offset": dict.fromkeys(DRAG_CENTRE, _HULL_POINT),
}
#: relative round-off allowed at the vehicle-relative limits (a fit that ends on the diagnoser's bound reads back)
_REL_TOL = 1e-9
#: the vehicle-relative limits of :func:`check_against_model` (the diagnoser's bounds, ``udrobot_ctrl.gap.effects``)
BUOYANCY_OFFSET_OF_WEIGHT = 0.5  # |dB_N| <= 0.5 W
CG_CB_OFFSET_OF_WEIGHT = 0.1  # |dBG_i| <= 0.1 W (a 10 cm shift of the centre of gravity)


@dataclass(frozen=True)
class PlantEffect:
    """One effect of a model: a catalogue name and its parameters (SI units, names as in :data:`CATALOGUE`).

    Attributes
    ----------
    name : str
        Catalogue name of the effect (docs/formats/model.md, "effects").
    params : mapping of str to float
        Its parameters by name, SI units (each parameter's unit is in the catalogue).
    """

    name: str
    params: Mapping[str, float] = field(default_factory=dict)

    @property
    def kind(self) -> EffectKind:
        return CATALOGUE[self.name]

    def to_dict(self) -> dict:
        """``{"name": ..., "params": {...}}`` as in a model file."""
        return {"name": self.name, "params": {k: float(v) for k, v in self.params.items()}}


def _suggest(word, choices) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def plant_effect(doc, where: str = "effects[0]") -> PlantEffect:
    """Parse and check one ``{"name": ..., "params": {...}}`` entry.

    Parameters
    ----------
    doc : mapping
        ``{"name": ..., "params": {...}}`` as in a model file.
    where : str
        The file and the entry, for messages (``"model.json: effects[0]"``).

    Returns
    -------
    PlantEffect
        The checked effect.

    Raises
    ------
    ValueError
        Naming ``where``: an unknown effect or parameter (with a suggestion), a missing parameter, a value that
        is not a finite number, or one outside its physical range (:data:`PARAMETER_RANGES`, quoted).
    """
    if not isinstance(doc, Mapping) or "name" not in doc or not isinstance(doc["name"], str):
        raise ValueError(f"{where}: expected {{\"name\": ..., \"params\": {{...}}}}, got {doc!r}")
    name = str(doc["name"])
    if name not in CATALOGUE:
        raise ValueError(f"{where}: unknown effect {name!r}{_suggest(name, CATALOGUE)}; known: "
                         f"{', '.join(EFFECT_NAMES)}")
    kind = CATALOGUE[name]
    where = where if where.endswith(f"({name})") else f"{where} ({name})"
    raw = doc.get("params", {}) or {}
    if not isinstance(raw, Mapping):
        raise ValueError(f"{where}.params: expected an object of numbers, got {raw!r}")
    params = {}
    for key, value in raw.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(float(value)):
            raise ValueError(f"{where}.params.{key}: expected a finite number, got {value!r}")
        params[str(key)] = float(value)
    sets = (kind.parameters,) + kind.alternatives
    allowed = set(kind.optional).union(*sets)
    for key in params:
        if key not in allowed:
            raise ValueError(f"{where}: effect {name!r} has no parameter {key!r}{_suggest(key, allowed)}; "
                             f"expected {', '.join(kind.parameters) or ', '.join(kind.optional[:4]) + ', ...'}")
    if name == "tether_drag" and set(TETHER_ANCHOR) & set(params) and set(TETHER_FIXED_DIRECTION) & set(params):
        raise ValueError(f"{where}: effect 'tether_drag' takes either an anchor ({', '.join(TETHER_ANCHOR)}) or a "
                         f"fixed cable direction ({', '.join(TETHER_FIXED_DIRECTION)}), not both")
    if name == "tether_drag" and set(TETHER_WALK) & set(params):
        if not set(TETHER_ANCHOR) <= set(params) or not set(TETHER_WALK) <= set(params):
            raise ValueError(f"{where}: effect 'tether_drag' with a walking top end needs an anchor "
                             f"({', '.join(TETHER_ANCHOR)}) and both of {', '.join(TETHER_WALK)}")
        if not 0.0 <= params["walk_fraction"] <= 1.0:
            raise ValueError(f"{where}.params.walk_fraction: must be in [0, 1], got {params['walk_fraction']}")
    if name == "tether_drag" and TETHER_TAUT in params:
        if not set(TETHER_ANCHOR) <= set(params):
            raise ValueError(f"{where}: effect 'tether_drag' with {TETHER_TAUT} needs an anchor "
                             f"({', '.join(TETHER_ANCHOR)}): a fixed direction has no length")
        if not 0.0 <= params[TETHER_TAUT] <= 1.0:
            raise ValueError(f"{where}.params.{TETHER_TAUT}: must be in [0, 1] (0 slack, 1 taut), got "
                             f"{params[TETHER_TAUT]:g}")
    if not any(set(s) <= set(params) for s in sets):
        closest = max(sets, key=lambda c: len(set(c) & set(params)))  # the set the entry started to give
        missing = sorted(set(closest) - set(params))
        raise ValueError(f"{where}: effect {name!r} misses parameter(s) {', '.join(missing)}")
    if name == "thruster_lag" and params["T_lag_s"] <= 0:
        raise ValueError(f"{where}.params.T_lag_s: must be > 0 s, got {params['T_lag_s']}")
    for key, meaning in EXPONENT_MEANING.items():
        if key in params and not EXPONENT_RANGE[0] <= params[key] <= EXPONENT_RANGE[1]:
            raise ValueError(f"{where}.params.{key}: must be within [{EXPONENT_RANGE[0]:g}, {EXPONENT_RANGE[1]:g}] "
                             f"({meaning}), got {params[key]:g}")
    if name == "quadratic_damping_error" and not 0.0 <= params.get("norm_weight", 0.0) <= 1.0:
        raise ValueError(f"{where}.params.norm_weight: must be within [0, 1] (0: per-axis drag |nu_i| nu_i, 1: drag "
                         f"on the speed |nu_g| nu_i), got {params['norm_weight']:g}")
    if name == "wall_effect" and params["decay_length_m"] <= 0:
        raise ValueError(f"{where}.params.decay_length_m: must be > 0 m, got {params['decay_length_m']}")
    if name == "wall_effect":
        _check_walls(params, where)
    _check_ranges(name, params, where)
    return PlantEffect(name, params)


def _check_ranges(name, params, where):
    """Each parameter within :data:`PARAMETER_RANGES` (a finite, physical value)."""
    ranges = PARAMETER_RANGES[name]
    for key, value in params.items():
        lo, hi, unit = ranges[key]
        if not lo <= value <= hi:
            raise ValueError(f"{where}.params.{key} = {value:g} is outside its physical range [{lo:g}, {hi:g}] "
                             f"({unit})")


def _check_walls(params, where):
    """A wall_effect names at least one plane; each wall gives all six numbers and a non-zero normal."""
    walls = 0
    for i in range(1, WALL_SLOTS + 1):
        given = [k for k in WALL_KEYS if f"wall{i}_{k}" in params]
        if given and len(given) < len(WALL_KEYS):
            missing = ", ".join(f"wall{i}_{k}" for k in WALL_KEYS if k not in given)
            raise ValueError(f"{where}: wall {i} of effect 'wall_effect' misses {missing} (a wall is a point "
                             f"wall{i}_point_n_m/_e_m/_d_m and a normal wall{i}_normal_n/_e/_d into the water)")
        if given:
            if math.hypot(*(params[f"wall{i}_normal_{c}"] for c in "ned")) < 1e-9:
                raise ValueError(f"{where}.params: wall{i}_normal_n/_e/_d is zero; give the normal into the water")
            walls += 1
    if walls == 0 and "seabed_depth_m" not in params:
        raise ValueError(f"{where}: effect 'wall_effect' needs a plane: seabed_depth_m (NED z of the seabed, m) "
                         f"and/or a wall (wall1_point_n_m ... wall1_normal_d)")


def wall_parameters(walls, first: int = 1) -> dict:
    """Flat ``wall<i>_...`` parameters of walls given as ``{"point": [n, e, d], "normal": [n, e, d]}`` (the run-log
    sidecar's form), numbered from ``first``; at most :data:`WALL_SLOTS` walls in all."""
    out = {}
    for j, wall in enumerate(walls):
        i = first + j
        if i > WALL_SLOTS:
            raise ValueError(f"wall_effect holds at most {WALL_SLOTS} walls, got {first - 1 + len(walls)}")
        for c, v in zip("ned", wall["point"]):
            out[f"wall{i}_point_{c}_m"] = float(v)
        for c, v in zip("ned", wall["normal"]):
            out[f"wall{i}_normal_{c}"] = float(v)
    return out


def parse_effects(docs, source: str = "<model>") -> tuple:
    """The ``effects`` list of a model document as :class:`PlantEffect` objects (each name at most once).

    Parameters
    ----------
    docs : list of mapping or None
        The document's ``effects`` entries (``{"name": ..., "params": {...}}``); None or empty for none.
    source : str
        The file, for the error messages.

    Returns
    -------
    tuple of PlantEffect
        The checked effects (:func:`plant_effect`), in the document's order.
    """
    if docs is None:
        return ()
    if not isinstance(docs, (list, tuple)):
        raise ValueError(f"{source}: field 'effects' must be a list, got {type(docs).__name__}")
    out = tuple(plant_effect(d, f"{source}: effects[{i}]") for i, d in enumerate(docs))
    names = [e.name for e in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{source}: effect(s) listed twice: {', '.join(dup)} (merge their parameters)")
    return out


def vehicle_size(thruster_positions=None) -> float:
    """The vehicle's size (m): the largest distance of a thruster from the CO (thrusters are mounted on the hull,
    at its extremities on the usual ROV frames: 0.25 m on the BlueROV2), or :data:`ASSUMED_VEHICLE_SIZE_M` for a
    model without thrusters. A centre of pressure or a tether attachment lies within it on each body axis."""
    pos = np.asarray(thruster_positions if thruster_positions is not None else [], float).reshape(-1, 3)
    size = float(np.linalg.norm(pos, axis=1).max()) if len(pos) else 0.0
    return size if size > 1e-3 else ASSUMED_VEHICLE_SIZE_M


def check_against_model(effects, *, linear_damping, quadratic_damping, buoyancy, weight, r_g=(0, 0, 0),
                        r_b=(0, 0, 0), source="<model>", thruster_positions=None):
    """Refuse effects that give the model impossible physics, as the loader refuses it in the base fields.

    Parameters
    ----------
    effects : sequence of PlantEffect
    linear_damping, quadratic_damping : (6, 6) array_like
        The base model's D_L and Q.
    buoyancy, weight : float
        The base model's B and W, N.
    r_g, r_b : (3,) array_like
        Centres of gravity and buoyancy, m: a ``dBG_z_Nm`` may remove up to 90 % of the righting moment
        z_g W - z_b B (the diagnoser's bound) even where that exceeds 0.1 W.
    source : str
        The file, for messages.
    thruster_positions : (n, 3) array_like, optional
        The thrusters' positions (m, body frame): the vehicle's size (:func:`vehicle_size`) bounds a
        ``drag_centre_offset`` and a tether's attachment point on each axis.

    Raises
    ------
    ValueError
        Naming the file, the effect, the parameter and the accepted range: a centre of pressure or a tether
        attachment farther from the CO than the vehicle's size on some axis; a total linear or quadratic damping
        (base plus ``linear_damping``, ``quadratic_damping_error``, ``cross_coupled_damping``) with a negative
        diagonal or a symmetric part that is not positive semidefinite (some motion would gain energy); a
        ``buoyancy_offset`` beyond +-0.5 W or making the total buoyancy negative; a ``cg_cb_offset`` beyond
        +-0.1 W N m.
    """
    D = np.array(linear_damping, float)
    Q = np.array(quadratic_damping, float)
    where = {e.name: f"{source}: effects[{i}]" for i, e in enumerate(effects)}
    size = vehicle_size(thruster_positions)
    how = "assumed: the model has no thrusters" if thruster_positions is None or not len(thruster_positions) else \
        "the largest distance of a thruster from the CO"
    for e in effects:
        q, at = e.params, where[e.name]
        for k in (DRAG_CENTRE if e.name == "drag_centre_offset" else TETHER_ATTACH if e.name == "tether_drag" else ()):
            if abs(q.get(k, 0.0)) > size * (1.0 + _REL_TOL):
                raise ValueError(f"{at}: effect {e.name!r} parameter {k} = {q[k]:g} is outside [{-size:g}, {size:g}] "
                                 f"m (a point of the hull: within the vehicle's size, {how})")
        if e.name == "linear_damping":
            for i, (d, v) in enumerate(zip(DOF, VEL)):
                if D[i, i] + q[f"d_{d}{v}"] < -_REL_TOL * max(abs(D[i, i]), 1.0):  # the diagnoser's bound: -D_ii
                    raise ValueError(f"{at}: effect 'linear_damping' parameter d_{d}{v} = {q[f'd_{d}{v}']:g} makes the "
                                     f"total linear damping {D[i, i] + q[f'd_{d}{v}']:g} < 0 (negative damping feeds "
                                     f"energy into the motion); accepted range [{-D[i, i]:g}, {_DAMPING[1]:g}]")
            D[np.diag_indices(6)] += [q[f"d_{d}{v}"] for d, v in zip(DOF, VEL)]
        elif e.name == "quadratic_damping_error":
            Q[np.diag_indices(6)] *= 1.0 + np.array([q[f"scale_{d}{v}|{v}|"] for d, v in zip(DOF, VEL)])
        elif e.name == "cross_coupled_damping":
            for i, j in CROSS_PAIRS:
                D[i, j] += q.get(f"D_{DOF[i]}{VEL[j]}", 0.0)
                Q[i, j] += q.get(f"Q_{DOF[i]}{VEL[j]}|{VEL[j]}|", 0.0)
        elif e.name == "buoyancy_offset":
            lim = BUOYANCY_OFFSET_OF_WEIGHT * weight
            lo = max(-lim, -buoyancy)
            if not lo - _REL_TOL * weight <= q["dB_N"] <= lim + _REL_TOL * weight:
                raise ValueError(f"{at}: effect 'buoyancy_offset' parameter dB_N = {q['dB_N']:g} is outside "
                                 f"[{lo:g}, {lim:g}] N (within +-{BUOYANCY_OFFSET_OF_WEIGHT:g} W = {lim:g} N of the "
                                 f"weight, and the total buoyancy B + dB = {buoyancy + q['dB_N']:g} N must be >= 0)")
        elif e.name == "cg_cb_offset":
            lim = CG_CB_OFFSET_OF_WEIGHT * weight
            bgz = float(r_g[2]) * weight - float(r_b[2]) * buoyancy
            for k in ("dBG_x_Nm", "dBG_y_Nm", "dBG_z_Nm"):
                lo = min(-lim, -0.9 * bgz) if k == "dBG_z_Nm" else -lim
                if not lo - _REL_TOL * weight <= q[k] <= lim + _REL_TOL * weight:
                    raise ValueError(f"{at}: effect 'cg_cb_offset' parameter {k} = {q[k]:g} is outside [{lo:g}, "
                                     f"{lim:g}] N m (+-{CG_CB_OFFSET_OF_WEIGHT:g} W: a 10 cm shift of the centre of "
                                     f"gravity)")
    names = [n for n in ("linear_damping", "quadratic_damping_error", "cross_coupled_damping") if n in where]
    for label, M in (("linear", D), ("quadratic", Q)):
        scale = max(float(np.abs(M).max()), 1.0)
        if names and (np.diag(M).min() < 0 or np.linalg.eigvalsh(0.5 * (M + M.T)).min() < -1e-9 * scale):
            raise ValueError(f"{source}: effect(s) {', '.join(names)} make the total {label} damping generate energy "
                             f"for some motion (expected a non-negative diagonal and (D + D^T)/2 positive "
                             f"semidefinite, as for the base field); effect parameters within "
                             f"{', '.join(where[n] for n in names)}")


# ----------------------------------------------------------------------------------------- parameters
def fold_parameters(p, effects):
    """Plant parameters with the *parameters* effects of ``effects`` folded in; the others are kept on ``p``.

    Parameters
    ----------
    p : udrobot_ctrl.dynamics.plant.PlantParameters
        Nominal parameters (single vehicle) with ``M_A`` set.
    effects : sequence of PlantEffect

    Returns
    -------
    PlantParameters
        M, M_inv, M_A, D_L, Q, buoyancy and r_b corrected; ``effects`` holds the effects that enter as thrust,
        lag or force (evaluated at run time).
    """
    M_A = np.array(p.M_A if p.M_A is not None else np.zeros((6, 6)), float)
    M_RB = np.asarray(p.M, float) - M_A
    D_L, Q = np.array(p.D_L, float), np.array(p.Q, float)
    buoyancy = float(p.buoyancy)
    dBG = np.zeros(3)
    runtime = []
    for e in effects:
        q = e.params
        if e.name == "linear_damping":
            D_L[np.diag_indices(6)] += [q[f"d_{d}{v}"] for d, v in zip(DOF, VEL)]
        elif e.name == "quadratic_damping_error":
            scale = np.array([q[f"scale_{d}{v}|{v}|"] for d, v in zip(DOF, VEL)])
            a = float(q.get("norm_weight", OPTIONAL_DEFAULTS["norm_weight"]))
            if a > 0:  # the part on the speed norm is a run-time force on the nominal coefficients
                runtime.append(replace(e, params={**q, **dict(zip(NOMINAL_Q, np.diag(Q).tolist()))}))
            Q[np.diag_indices(6)] *= 1.0 + (1.0 - a) * scale
        elif e.name == "added_mass_error":
            M_A[np.diag_indices(6)] *= 1.0 + np.array([q[f"scale_{d}d{v}"] for d, v in zip(DOF, VEL)])
        elif e.name == "cross_coupled_damping":
            for i, j in CROSS_PAIRS:
                D_L[i, j] += q.get(f"D_{DOF[i]}{VEL[j]}", 0.0)
                Q[i, j] += q.get(f"Q_{DOF[i]}{VEL[j]}|{VEL[j]}|", 0.0)
        elif e.name == "buoyancy_offset":
            buoyancy += q["dB_N"]
        elif e.name == "cg_cb_offset":
            dBG += [q["dBG_x_Nm"], q["dBG_y_Nm"], q["dBG_z_Nm"]]
        elif e.name == "drag_centre_offset":  # on the base model's translational damping (the diagnoser's replay)
            runtime.append(replace(e, params={**q, **drag_block(p.D_L, p.Q)}))
        else:
            runtime.append(e)
    r_b = np.array(p.r_b, float)
    if np.any(dBG):
        if buoyancy <= 0:
            raise ValueError(f"model {p.name!r}: cg_cb_offset needs a positive buoyancy to move the centre of "
                             f"buoyancy (B = {buoyancy:g} N)")
        r_b = r_b - dBG / buoyancy  # (r_g W - r_b B) grows by dBG
    M = M_RB + M_A
    eig = np.linalg.eigvalsh(0.5 * (M + M.T))
    if eig.min() <= 1e-9 * eig.max():
        raise ValueError(f"model {p.name!r}: the effects make M_RB + M_A not positive definite "
                         f"(smallest eigenvalue {eig.min():.3g}); check added_mass_error")
    return replace(p, M=M, M_inv=np.linalg.inv(M), M_A=M_A, D_L=D_L, Q=Q, buoyancy=buoyancy, r_b=r_b,
                   effects=tuple(runtime))


def drag_block(D_L, Q) -> dict:
    """The translational damping block (rows and columns u v w of D_L and Q) as the run-time parameters of a
    ``drag_centre_offset`` (:data:`DRAG_BLOCK_D`, :data:`DRAG_BLOCK_Q`)."""
    D_L, Q = np.asarray(D_L, float), np.asarray(Q, float)
    return {**dict(zip(DRAG_BLOCK_D, D_L[:3, :3].ravel().tolist())),
            **dict(zip(DRAG_BLOCK_Q, Q[:3, :3].ravel().tolist()))}


# ----------------------------------------------------------------------------------------- backends
@dataclass(frozen=True)
class Backend:
    """Elementary functions of one array backend (numpy or casadi)."""

    sin: Callable
    cos: Callable
    sqrt: Callable
    exp: Callable
    where: Callable  # where(condition, a, b)
    sign: Callable
    fmax: Callable


NUMPY = Backend(np.sin, np.cos, np.sqrt, np.exp, np.where, np.sign, np.maximum)
CASADI = Backend(ca.sin, ca.cos, ca.sqrt, ca.exp, ca.if_else, ca.sign, ca.fmax)


def _rotation(be, eta):
    cf, sf = be.cos(eta[3]), be.sin(eta[3])
    ct, st = be.cos(eta[4]), be.sin(eta[4])
    cp, sp = be.cos(eta[5]), be.sin(eta[5])
    return ((cp * ct, -sp * cf + cp * st * sf, sp * sf + cp * cf * st),
            (sp * ct, cp * cf + sf * st * sp, -cp * sf + st * sp * cf),
            (-st, ct * sf, ct * cf))


def _to_ned(R, v):
    return tuple(R[i][0] * v[0] + R[i][1] * v[1] + R[i][2] * v[2] for i in range(3))


def _to_body(R, v):
    return tuple(R[0][i] * v[0] + R[1][i] * v[1] + R[2][i] * v[2] for i in range(3))


# ----------------------------------------------------------------------------------------- thrust
def _per_actuator(params, key, n_actuators):
    """One value per actuator: the per-DOF parameters of a commanded wrench (six virtual actuators), or the
    shared one."""
    if f"{key}_X" in params:
        if n_actuators != 6:
            raise ValueError(f"per-DOF {key}_X ... parameters need the six virtual actuators of a commanded wrench, "
                             f"not {n_actuators} thrusters")
        return [params[f"{key}_{d}"] for d in DOF]
    return [params.get(key, 0.0)] * n_actuators


def deadband_terms(be, f, f_ref, width_fraction, command_exponent=1.0, capacities=None):
    """The deadband's threshold and the thrust its shift removes, per unit of ``shift``, beyond it.

    A deadband sits in the ESC's command (PWM) domain: with the normalised command u = (|f| / F)^(1/p) (p the
    ``command_exponent``: the nominal thrust curve is F u^p), commands u < w = ``width_fraction`` produce no
    thrust, i.e. |f| < d = w^p F. Beyond it the delivered thrust is
    f - c ``unit`` = sign(f) F [(1 - c) u^p + c g(u)], a blend, linear in the shift c, of the hard deadband
    (c = 0: the nominal curve, cut below w) and the continuous one (c = 1) that starts from zero at w:

        g(u) = (u - w)^p / (1 - w)^(2(p - 1)),    unit = sign(f) (|f| - F g(u)),
        F = f_ref^(2 - p) C^(p - 1),  C the capacity in the direction of f (forward or reverse).

    * p = 1: a deadband of the thrust, symmetric in thrust: F = f_ref, g = u - w, unit = d sign(f) -- today's
      shifted deadband f - c d sign(f), d = w f_ref, exactly (computed as such).
    * p = 2: the ESC's deadband of the PWM domain, symmetric in PWM, with thrust ~ (PWM offset beyond it)^2 in
      each direction up to that direction's capacity C at full command (u = 1): g = ((u - w) / (1 - w))^2 -- a
      thrust curve measured with the deadband in it, as a vendor's chart is; reverse commands are normalised by
      the reverse capacity, as the thrust-to-PWM conversion of an asymmetric thruster does.
    * in between, the normaliser and the full-command thrust F (1 - w)^(2 - p) move geometrically from the p = 1
      form to the p = 2 one. The shift stays a linear amplitude (the diagnoser fits it by least squares), which
      rules out the u-domain shift u - c w inside the power.

    Parameters
    ----------
    be : Backend
    f : array_like or casadi expression
        Commanded thrust of one actuator (or of several, numpy), N (or N m).
    f_ref : float or array_like
        The actuator's reference capacity max(forward, reverse), N.
    width_fraction, command_exponent : float
        w (of the normalised command) and p (1 to 2).
    capacities : (forward, reverse) of floats or arrays, optional
        The actuator's capacity in each direction, N (positive); default f_ref both ways (a commanded wrench).

    Returns
    -------
    d : float or like ``f``
        Threshold on |f|, N: w^p F.
    unit : like ``f``
        Thrust removed per unit shift where |f| >= d, N (meaningless inside the deadband).
    """
    w, p = float(width_fraction), float(command_exponent)
    if p == 1.0:
        d = w * f_ref
        return d, d * be.sign(f)
    fwd, rev = (f_ref, f_ref) if capacities is None else capacities
    F = be.where(f < 0, f_ref ** (2.0 - p) * rev ** (p - 1.0), f_ref ** (2.0 - p) * fwd ** (p - 1.0))
    d = w ** p * F
    # |f| floored at the threshold: the same value beyond it, a finite slope at f = 0 (casadi's Jacobians)
    u = (be.fmax(abs(f), be.fmax(d, 1e-12 * f_ref)) / F) ** (1.0 / p)
    g = be.fmax(u - w, 0.0) ** p / (1.0 - w) ** (2.0 * (p - 1.0))
    return d, be.sign(f) * (abs(f) - F * g)


STATIC_MAP_ORDER = {"thruster_deadband": 0, "thruster_asymmetry": 1}  # the order the static maps act in


def static_thrust(be, f, effects, f_ref, capacities=None):
    """Thrust after the static maps (deadband, then reverse loss) of the commanded, clipped thrusts ``f``.

    Parameters
    ----------
    be : Backend
    f : sequence of n components (N; or N, N m for a commanded wrench)
    effects : sequence of PlantEffect
    f_ref : (n,) array_like
        Reference magnitude of each actuator (its capacity max(forward, reverse)), N.
    capacities : ((n,), (n,)) array_like, optional
        Forward and reverse capacity of each thruster, N (positive: ``f_max``, ``-f_min``); default f_ref both ways
        (a commanded wrench). The deadband's normalised command uses them (:func:`deadband_terms`).
    """
    out = list(f)
    n = len(out)
    # deadband (the ESC's) before the reverse loss (the propeller's), whatever the order of the model's list: the
    # two maps do not commute
    for e in sorted((e for e in effects if e.name in STATIC_MAP_ORDER), key=lambda e: STATIC_MAP_ORDER[e.name]):
        if e.name == "thruster_deadband":
            shift = _per_actuator(e.params, "shift", n)
            w = e.params["width_fraction"]
            p = e.params.get("command_exponent", OPTIONAL_DEFAULTS["command_exponent"])
            for i in range(n):
                cap = None if capacities is None else (float(capacities[0][i]), float(capacities[1][i]))
                d, unit = deadband_terms(be, out[i], float(f_ref[i]), w, p, cap)
                out[i] = be.where(abs(out[i]) < d, 0.0 * out[i], out[i] - shift[i] * unit)
        elif e.name == "thruster_asymmetry":
            loss = _per_actuator(e.params, "reverse_loss", n)
            for i in range(n):
                out[i] = be.where(out[i] < 0, (1.0 - loss[i]) * out[i], out[i])
    return out


def inflow_loss(be, f, nu, effects, inflow, f_ref):
    """Thrust after the inflow loss: f - (k1 |f| + k2 sqrt(|f| f_ref)) u_a, never reversing f.

    ``inflow`` (6, n): actuator j's axial advance speed is ``inflow[:, j] . nu`` (m/s).
    """
    out = list(f)
    for e in effects:
        if e.name != "thrust_inflow_loss":
            continue
        k1, k2 = e.params["k1_per_mps"], e.params["k2_per_mps"]
        for j in range(len(out)):
            col = np.asarray(inflow)[:, j]
            ua = sum(float(col[i]) * nu[i] for i in range(6) if col[i] != 0.0)
            fj = out[j]
            loss = k1 * abs(fj)
            if k2:  # sqrt(|f| f_ref) with a floor of (1e-3 f_ref)^2 under the root: its slope stays finite at f = 0
                ref = float(f_ref[j])  # (linearisation, Jacobians), the value changes by at most 1e-3 f_ref k2 |u_a|
                loss = loss + k2 * be.sqrt(abs(fj) * ref + (1e-3 * ref) ** 2)
            fa = fj - loss * ua
            out[j] = be.where(fa * fj < 0, 0.0 * fj, fa)
    return out


def thrust_effects(effects) -> tuple:
    """The effects that change the delivered thrust (static maps and inflow loss)."""
    return tuple(e for e in effects if CATALOGUE[e.name].enters == "thrust")


@dataclass(frozen=True)
class ThrusterLag:
    """The ``thruster_lag`` of a model: time constant ``T_s`` (s) and ``thrust_exponent`` k (1 to 2)."""

    T_s: float
    thrust_exponent: float = OPTIONAL_DEFAULTS["thrust_exponent"]


def thruster_lag(effects) -> ThrusterLag | None:
    """The :class:`ThrusterLag` of a ``thruster_lag`` effect in ``effects`` (an absent exponent is 1), or None."""
    for e in effects:
        if e.name == "thruster_lag":
            return ThrusterLag(float(e.params["T_lag_s"]),
                               float(e.params.get("thrust_exponent", OPTIONAL_DEFAULTS["thrust_exponent"])))
    return None


def lag_time_constant(effects) -> float | None:
    """T_lag_s of a ``thruster_lag`` effect, or None."""
    lag = thruster_lag(effects)
    return None if lag is None else lag.T_s


def lag_pole(dt, T) -> float:
    """exp(-dt / T): the exact zero-order-hold discretisation of T y' + y = f over a step of ``dt`` s."""
    return math.exp(-dt / max(T, 1e-9))


def lag_state(f, thrust_exponent=1.0):
    """The lagged state s = sign(f) |f|^(1/k) of a thrust ``f`` (N) for the thrust exponent k: the thrust itself for
    k = 1, a quantity proportional to the rotor speed for k = 2 (thrust ~ n|n|)."""
    f = np.asarray(f, float)
    if thrust_exponent == 1.0:
        return f
    return np.sign(f) * np.abs(f) ** (1.0 / thrust_exponent)


def lag_thrust(s, thrust_exponent=1.0):
    """The thrust sign(s) |s|^k (N) of a lagged state ``s``: the inverse of :func:`lag_state`."""
    s = np.asarray(s, float)
    if thrust_exponent == 1.0:
        return s
    return np.sign(s) * np.abs(s) ** thrust_exponent


def first_order_lag_step(f_prev, f_cmd, dt, T, thrust_exponent=1.0):
    """One step of the lag from the delivered thrust ``f_prev`` with the command ``f_cmd`` held over ``dt`` s (arrays
    or scalars, N): T s' + s = sign(f_cmd) |f_cmd|^(1/k) on the state s of :func:`lag_state`, the thrust
    :func:`lag_thrust` of it. The state is a one-to-one function of the thrust, so the thrust is all a simulator
    keeps; k = 1 (the default) is the lag of the thrust itself."""
    a = lag_pole(dt, T)
    k = thrust_exponent
    return lag_thrust(a * lag_state(f_prev, k) + (1.0 - a) * lag_state(f_cmd, k), k)


def first_order_lag(f, dt, T, f0=None, thrust_exponent=1.0):
    """The lag over a whole uniform command sequence f (n, k) held per step of ``dt`` s, from the delivered thrust
    ``f0`` (default the first command): the same recursion as :func:`first_order_lag_step`, on the state of
    :func:`lag_state`, run by ``scipy.signal.lfilter``."""
    a = lag_pole(dt, T)
    k = thrust_exponent
    s = lag_state(f, k)
    zi = ((s[0] if f0 is None else lag_state(f0, k)) * a)[None, :]
    y, _ = lfilter([1 - a], [1, -a], s, axis=0, zi=zi)
    return lag_thrust(y, k)


# ----------------------------------------------------------------------------------------- forces
TETHER_SPEED_FLOOR = 1e-4  # m/s
ANCHOR_DISTANCE_FLOOR = 1e-6  # m


def cable_direction(azimuth, elevation):
    """Unit NED vector from the vehicle along its tether: azimuth (rad, from north towards east) and elevation
    (rad, above the horizontal; pi/2 is a cable straight up to the surface)."""
    ce = math.cos(elevation)
    return (ce * math.cos(azimuth), ce * math.sin(azimuth), -math.sin(elevation))


def anchor_distance(be, position, anchor):
    """Straight-line distance (m) from the vehicle at ``position`` (NED, m) to the tether's ``anchor``, with a floor
    of ``ANCHOR_DISTANCE_FLOOR`` under the root (finite derivatives with the vehicle on the anchor)."""
    d = tuple(anchor[i] - position[i] for i in range(3))
    return be.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + ANCHOR_DISTANCE_FLOOR ** 2)


def anchor_direction(be, position, anchor):
    """Unit NED vector (3 components) from the vehicle at ``position`` (NED, m) towards the tether's ``anchor``.

    The distance (:func:`anchor_distance`) carries a floor under the root, so the direction stays finite with
    the vehicle on the anchor (a zero vector there: the drag then opposes the whole velocity); its length is
    short of 1 by 5e-13 at 1 m.
    """
    inv = 1.0 / anchor_distance(be, position, anchor)
    return tuple((anchor[i] - position[i]) * inv for i in range(3))


def walking(q) -> bool:
    """Whether the tether parameters ``q`` describe a top end that walks with the vehicle (``walk_fraction`` > 0)."""
    return TETHER_ANCHOR[0] in q and float(q.get("walk_fraction", 0.0)) > 0.0


def tether_top_end(be, eta, nu, q):
    """Position (NED, m) and velocity (NED, m/s) of the tether's top end for the parameters ``q``: the anchor
    A = (``anchor_north_m anchor_east_m anchor_down_m``), moved along the horizontal unit vector d at
    ``walk_azimuth_rad`` by ``walk_fraction`` f of the vehicle's own motion along d: a = A + f (p.d) d, with velocity
    f (V.d) d (V the vehicle's NED velocity). With f = 0 (or no walk parameters) it is a fixed anchor."""
    f = float(q.get("walk_fraction", 0.0))
    chi = float(q.get("walk_azimuth_rad", 0.0))
    d = (math.cos(chi), math.sin(chi), 0.0)
    v = _to_ned(_rotation(be, eta), nu)
    along_p = eta[0] * d[0] + eta[1] * d[1]
    along_v = v[0] * d[0] + v[1] * d[1]
    anchor = tuple(q[k] + f * along_p * d[i] for i, k in enumerate(TETHER_ANCHOR))
    return anchor, tuple(f * along_v * d[i] for i in range(3))


def tether_direction(be, eta, q, nu=None):
    """Unit NED vector from the vehicle along its tether for the parameters ``q`` of a ``tether_drag`` effect:
    towards the anchor (``anchor_north_m anchor_east_m anchor_down_m``; it turns as the vehicle moves; a walking
    top end, :func:`tether_top_end`, needs ``nu``) or, without an anchor, the fixed direction
    (``cable_azimuth_rad cable_elevation_rad``: an anchor infinitely far away)."""
    if walking(q):
        return anchor_direction(be, eta[:3], tether_top_end(be, eta, nu, q)[0])
    if TETHER_ANCHOR[0] in q:
        return anchor_direction(be, eta[:3], tuple(q[k] for k in TETHER_ANCHOR))
    return cable_direction(q["cable_azimuth_rad"], q["cable_elevation_rad"])


def _normal(v, e):
    along = v[0] * e[0] + v[1] * e[1] + v[2] * e[2]
    return tuple(v[i] - along * e[i] for i in range(3))


def _norm(be, vn):
    return be.sqrt(vn[0] * vn[0] + vn[1] * vn[1] + vn[2] * vn[2] + TETHER_SPEED_FLOOR ** 2)


def tether_cross_flow(be, eta, nu, q):
    """The rotation R (body to NED), the vehicle's NED velocity normal to the cable V_n = V - (V.e) e (3 components,
    m/s; e from :func:`tether_direction`) and |V_n| (m/s) with a floor of ``TETHER_SPEED_FLOOR`` under the root:
    smooth at rest (a finite Jacobian for linearisation); the force changes by less than 1e-8 relative at 1 m/s."""
    e = tether_direction(be, eta, q, nu)
    R = _rotation(be, eta)
    vn = _normal(_to_ned(R, nu), e)
    return R, vn, _norm(be, vn)


#: Gauss-Legendre nodes and weights on [0, 1] (3 points: exact for polynomials of degree 5)
CABLE_NODES = (0.5 - math.sqrt(15.0) / 10.0, 0.5, 0.5 + math.sqrt(15.0) / 10.0)
CABLE_WEIGHTS = (5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0)


def _walking_unit_forces(be, eta, nu, q):
    """NED unit forces (quadratic, linear) of a cable whose top end moves: the cable point at s (0 top, 1 vehicle)
    moves at V(s) = a' + s (V - a'); the water's normal drag on it, shared with the vehicle in proportion to s,
    integrates to 4 int s |V_n(s)| V_n(s) ds and 3 int s V_n(s) ds (3-point Gauss-Legendre): the fixed anchor's
    |V_n| V_n and V_n when a' = 0."""
    top, top_v = tether_top_end(be, eta, nu, q)
    e = anchor_direction(be, eta[:3], top)
    R = _rotation(be, eta)
    v = _to_ned(R, nu)
    fq, fl = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    for s, w in zip(CABLE_NODES, CABLE_WEIGHTS):
        vn = _normal(tuple(top_v[i] + s * (v[i] - top_v[i]) for i in range(3)), e)
        speed = _norm(be, vn)
        for i in range(3):
            fq[i] = fq[i] - 4.0 * w * s * speed * vn[i]
            fl[i] = fl[i] - 3.0 * w * s * vn[i]
    return R, tuple(fq), tuple(fl)


def cable_length_factor(be, eta, nu, q):
    """How the cable's drag scales with the vehicle's place (dimensionless): (1 - t) + t L / (1 m), t =
    ``cable_taut`` (0 when absent), L the straight-line distance (m) from the vehicle to the top end
    (:func:`tether_top_end`). A slack cable (t = 0) has a fixed paid-out length: the factor is 1 and the amplitudes
    are lumped. A taut one (t = 1, a handler keeping it tight) is as long as that distance, and its drag grows with
    it: the amplitudes are then per metre of cable."""
    t = float(q.get(TETHER_TAUT, 0.0))
    if t == 0.0:
        return 1.0
    return (1.0 - t) + t * anchor_distance(be, eta[:3], tether_top_end(be, eta, nu, q)[0])


def _cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _attached(q) -> bool:
    """Whether the tether parameters ``q`` tie the cable off the CO (a non-zero ``attach_*_m``)."""
    return any(float(q.get(k, 0.0)) != 0.0 for k in TETHER_ATTACH)


def _at_point(be, eta, nu, r):
    """The pose and velocity of the hull point ``r`` (body, m): its NED position eta[:3] + R r with the vehicle's
    attitude, and its body velocity v + omega x r with the vehicle's rotation rate."""
    dp = _to_ned(_rotation(be, eta), r)
    wr = _cross((nu[3], nu[4], nu[5]), r)
    return (tuple(eta[i] + dp[i] for i in range(3)) + (eta[3], eta[4], eta[5]),
            tuple(nu[i] + wr[i] for i in range(3)) + (nu[3], nu[4], nu[5]))


def tether_unit_forces(be, eta, nu, q):
    """The tether force per unit of each amplitude (two 6-component body wrenches, N per N s^2/m^2 and per N s/m):
    R^T (-|V_n| V_n) and R^T (-V_n), from :func:`tether_cross_flow`; for a walking top end
    (:func:`tether_top_end`) the cable's drag integrated over its length (:func:`_walking_unit_forces`); both times
    :func:`cable_length_factor` (a taut cable's drag grows with its length). The force is linear in the
    amplitudes, so these are its derivatives: the diagnoser's regressors.

    A cable tied at r_a = (``attach_x_m attach_y_m attach_z_m``) off the CO drags with the position and velocity of
    that point (:func:`_at_point`) and adds the moment r_a x F (its power F . (v + omega x r_a) <= 0)."""
    r_a = tuple(float(q.get(k, 0.0)) for k in TETHER_ATTACH)
    if _attached(q):
        eta, nu = _at_point(be, eta, nu, r_a)
    if walking(q):
        R, fq, fl = _walking_unit_forces(be, eta, nu, q)
        ned = (fq, fl)
    else:
        R, vn, speed = tether_cross_flow(be, eta, nu, q)
        ned = tuple(tuple(-k * vn[i] for i in range(3)) for k in (speed, 1.0))
    if float(q.get(TETHER_TAUT, 0.0)) != 0.0:  # a taut cable (an anchor: plant_effect refuses it without one)
        scale = cable_length_factor(be, eta, nu, q)
        ned = tuple(tuple(scale * c for c in f) for f in ned)
    out = []
    for f in ned:
        fb = _to_body(R, f)
        m = _cross(r_a, fb) if _attached(q) else (0.0 * fb[0], 0.0 * fb[0], 0.0 * fb[0])
        out.append((fb[0], fb[1], fb[2], m[0], m[1], m[2]))
    return tuple(out)


def tether_force(be, eta, nu, q):
    """Cross-flow drag of the tether (6 components, N, body frame, at the body origin).

    F_ned = -(k_q |V_n| + k_l) V_n with V_n the vehicle's NED velocity normal to the cable
    (:func:`tether_cross_flow`): the water resists motion across the cable, not along it; k_q =
    ``k_quadratic_N_s2_per_m2``, k_l = ``k_linear_N_s_per_m`` times :func:`tether_unit_forces` (which also
    integrates the drag along a cable whose top end walks with the vehicle).
    """
    dq, dl = tether_unit_forces(be, eta, nu, q)
    kq, kl = q["k_quadratic_N_s2_per_m2"], q["k_linear_N_s_per_m"]
    return tuple(kq * a + kl * b for a, b in zip(dq, dl))


SEABED_NORMAL = (0.0, 0.0, -1.0)  # NED; the seabed's normal points up, into the water


def surface_terms(be, eta, nu, h, normal_ned, decay_length):
    """exp(-h / lam), the surface normal in body axes and the speed^2 along the surface, for a plane at distance
    ``h`` (m, >= 0 in the water) with unit normal ``normal_ned`` pointing into the water."""
    nb = _to_body(_rotation(be, eta), normal_ned)
    decay = be.exp(-be.fmax(h, 0.0) / decay_length)
    vn = nu[0] * nb[0] + nu[1] * nb[1] + nu[2] * nb[2]
    vt2 = be.fmax(nu[0] * nu[0] + nu[1] * nu[1] + nu[2] * nu[2] - vn * vn, 0.0)
    return decay, nb, vt2


def surface_action(be, eta, nu, h, normal_ned, q):
    """What a plane does to the vehicle: its suction (6 components, N), -a_s exp(-h/lam) |V_t|^2 n, and its extra
    added mass as the rank-one term a n n^T on the translations, given as the scale a = a_m exp(-h/lam) (kg) and the
    body normal n (3 components); :func:`surface_suction` and :func:`surface_added_mass` are its parts."""
    decay, nb, vt2 = surface_terms(be, eta, nu, h, normal_ned, q["decay_length_m"])
    s = -q["suction_N_s2_per_m2"] * decay * vt2
    return (s * nb[0], s * nb[1], s * nb[2], 0.0 * s, 0.0 * s, 0.0 * s), q["added_mass_at_contact_kg"] * decay, nb


def surface_suction(be, eta, nu, h, normal_ned, q):
    """Suction towards a plane (6 components, N): -a_s exp(-h/lam) |V_t|^2 n (:func:`surface_action`)."""
    return surface_action(be, eta, nu, h, normal_ned, q)[0]


def surface_added_mass(be, eta, nu, h, normal_ned, q):
    """Extra added mass of a plane (6 x 6 nested tuples, kg): a_m exp(-h/lam) n n^T on the translations
    (:func:`surface_action`)."""
    _, a, nb = surface_action(be, eta, nu, h, normal_ned, q)
    zero = 0.0 * a
    return tuple(tuple(a * nb[i] * nb[j] if i < 3 and j < 3 else zero for j in range(6)) for i in range(6))


def wall_planes(q) -> list:
    """The planes of a wall_effect's parameters ``q``: (point (3,), unit normal (3,)) in NED, m; the seabed first
    (point (0, 0, seabed_depth_m), normal up), then the walls in their order."""
    out = []
    if "seabed_depth_m" in q:
        out.append(((0.0, 0.0, q["seabed_depth_m"]), SEABED_NORMAL))
    for i in range(1, WALL_SLOTS + 1):
        if f"wall{i}_normal_n" in q:
            n = [q[f"wall{i}_normal_{c}"] for c in "ned"]
            norm = math.sqrt(sum(c * c for c in n))
            out.append((tuple(q[f"wall{i}_point_{c}_m"] for c in "ned"), tuple(c / norm for c in n)))
    return out


def plane_distance(eta, point, normal):
    """Distance (m) of the body origin from a plane, positive on the water side: (eta[:3] - point) . normal."""
    return sum((eta[k] - point[k]) * normal[k] for k in range(3) if normal[k] != 0.0)


def added_mass_increment(be, eta, nu, effects):
    """Extra added mass (6 x 6 nested tuples, kg) of the position-dependent effects, or None."""
    total = None
    for e in effects:
        if e.name == "wall_effect":
            for point, normal in wall_planes(e.params):
                term = surface_added_mass(be, eta, nu, plane_distance(eta, point, normal), normal, e.params)
                total = term if total is None else tuple(tuple(a + b for a, b in zip(ra, rb))
                                                         for ra, rb in zip(total, term))
    return total


def relative_velocity(be, eta, nu, effects):
    """nu_r = nu - [R^T v_c ; 0] for a ``water_current`` effect (else ``nu``)."""
    for e in effects:
        if e.name == "water_current":
            q = e.params
            c = _to_body(_rotation(be, eta), (q["current_north_mps"], q["current_east_mps"], q["current_down_mps"]))
            return (nu[0] - c[0], nu[1] - c[1], nu[2] - c[2], nu[3], nu[4], nu[5])
    return nu


def speed_norm_drag(be, nu, params):
    """The speed-norm part of a ``quadratic_damping_error`` (6 components, N and N m, body frame):
    -a s_i Q_ii |nu_g| nu_i, |nu_g| the norm of the translational or rotational velocity, Q_ii the nominal
    coefficients :func:`fold_parameters` stored (``NOMINAL_Q``). The norm is sqrt(|nu_g|^2 + 1e-12): smooth at
    rest, so that a linearisation there exists (the term and its derivative vanish)."""
    a = params.get("norm_weight", OPTIONAL_DEFAULTS["norm_weight"])
    out = []
    for g in ((nu[0], nu[1], nu[2]), (nu[3], nu[4], nu[5])):
        speed = be.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2] + 1e-12)
        out += [speed * v for v in g]
    return tuple(-a * params[f"scale_{d}{v}|{v}|"] * params[qn] * t for d, v, qn, t in zip(DOF, VEL, NOMINAL_Q, out))


def translational_drag(v, q):
    """The drag (3 components, N, body frame; a force on the vehicle) of the translational damping block carried
    by a ``drag_centre_offset``'s parameters ``q`` at the body velocity ``v`` (3 components, m/s):
    -(D v + Q_ij |v_j| v_j), D and Q the u v w rows and columns of D_L and Q (:func:`drag_block`)."""
    out = []
    for i in range(3):
        acc = 0.0 * v[0]
        for j in range(3):
            acc = acc - q[DRAG_BLOCK_D[3 * i + j]] * v[j] - q[DRAG_BLOCK_Q[3 * i + j]] * abs(v[j]) * v[j]
        out.append(acc)
    return tuple(out)


def drag_centre_force(be, nu, q):
    """What a centre of pressure off the CO changes (6 components, N and N m, body frame; a force on the vehicle).

    The translational drag F(v) = -(D v + Q |v| v) of the base model (:func:`translational_drag`) acts at r_cp =
    (``x_cp_m y_cp_m z_cp_m``), evaluated with the velocity of that point, v_cp = v + omega x r_cp, and makes the
    moment r_cp x F(v_cp). The nominal equations apply F(v) at the CO; this term is the difference:
    [F(v_cp) - F(v); r_cp x F(v_cp)]. With the nominal drag it replaces, its power is
    F(v_cp) . v + (r_cp x F(v_cp)) . omega = F(v_cp) . v_cp <= 0 for a dissipative D and Q: no energy is created.

    Parameters
    ----------
    be : Backend
        Unused (the term needs only ``abs``, ``+ - *``); kept for the signature of the other terms.
    nu : sequence of 6 components
        Body velocity relative to the water (m/s, rad/s): a current's :func:`relative_velocity`.
    q : mapping
        ``x_cp_m y_cp_m z_cp_m`` (m) and the damping block of :func:`drag_block` (:func:`fold_parameters`).
    """
    r = tuple(q[k] for k in DRAG_CENTRE)
    v = (nu[0], nu[1], nu[2])
    wr = _cross((nu[3], nu[4], nu[5]), r)
    f_cp = translational_drag(tuple(v[i] + wr[i] for i in range(3)), q)
    f_co = translational_drag(v, q)
    m = _cross(r, f_cp)
    return (f_cp[0] - f_co[0], f_cp[1] - f_co[1], f_cp[2] - f_co[2], m[0], m[1], m[2])


def external_force(be, eta, nu, effects):
    """Sum of the tether and wall suction forces, the speed-norm part of a quadratic damping error and a drag centre
    off the CO (6 components, N and N m, body frame)."""
    total = None
    for e in effects:
        if e.name == "drag_centre_offset":
            term = drag_centre_force(be, relative_velocity(be, eta, nu, effects), e.params)
        elif e.name == "quadratic_damping_error":
            term = speed_norm_drag(be, nu, e.params)
        elif e.name == "tether_drag":
            term = tether_force(be, eta, nu, e.params)
        elif e.name == "wall_effect":
            term = None
            for point, normal in wall_planes(e.params):
                one = surface_suction(be, eta, nu, plane_distance(eta, point, normal), normal, e.params)
                term = one if term is None else tuple(a + b for a, b in zip(term, one))
        else:
            continue
        total = term if total is None else tuple(a + b for a, b in zip(total, term))
    return total
