"""Scale-model -> full-size similitude (Cely 2019: 30 % spring model, Table 2; 22 % pendulum model, Table 3).

``scale`` is the model/full-size length ratio lambda (0.30, 0.22). Laws per quantity:

==================  ==========================  =================================================
quantity            full-size value             law
==================  ==========================  =================================================
C_m, C_D            unchanged                   geometric similitude; the coefficients are
                                                dimensionless (strictly also Re/KC dependent: the
                                                model tests run at Re lambda^1.5 below full size)
added mass m_a      C_m x rho V_ref             proportional to the displaced volume (lambda^-3
                                                with the geometric V_ref = V_model / lambda^3)
K_Q (1/2 rho C_D A) K_Q,model / lambda^2        proportional to the projected area
K_L                 K_L,model / lambda          viscous (skin-friction) linear damping, force
                                                ~ mu u L: Reynolds law, proportional to length.
                                                Chosen here; the alternative Froude law
                                                (lambda^-2.5) is available as ``KL_law="froude"``.
==================  ==========================  =================================================

Reference displaced mass for the added mass. Three choices, reported in the output:

* ``"geometric"`` (default of :func:`reference_displaced_mass` when ``choice`` is None): rho V_model /
  lambda^3, the strict similitude law.
* ``"vehicle"`` (default of ``udrobot-ctrl identify`` and :class:`identification.identify.RigOptions`):
  rho V of the full-size vehicle, a :class:`FullSizeVehicle` given by the caller (``udrobot-ctrl identify``
  passes the description ``models/udrobot.toml``: 9.38 kg, itself assumed, see that file), so that the
  identified added mass is consistent with the buoyancy of the plant it is used in. This package never reads
  the vehicle itself: the vehicle models are built from its results (udrobot_ctrl.vehicle), not the reverse.
* a number in kg: e.g. 9.20 reproduces the paper, whose full-size added masses are C_m x 9.20 kg
  (7.5187 = 0.8172 x 9.20; 8.3027 = 0.9024 x 9.20), i.e. referred to the robot's mass, not to a
  scaled volume (Table 2's model would give 12.8 kg, Table 3's 10.1 kg).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LAWS = {
    "Cm": "unchanged (dimensionless, geometric similitude)",
    "CD": "unchanged (dimensionless, geometric similitude)",
    "added_mass_kg": "C_m x reference displaced mass (volume law, lambda^-3 for the geometric reference)",
    "KQ": "K_Q,model / lambda^2 (projected-area law, 1/2 rho C_D A)",
    "KL": "K_L,model / lambda (viscous/Reynolds law, force ~ mu u L)",
}
KL_EXPONENTS = {"reynolds": 1.0, "froude": 2.5}


@dataclass(frozen=True)
class FullSizeVehicle:
    """Facts of the full-size vehicle that scale-model results are referred to, given by the caller.

    Attributes
    ----------
    projected_area : dict
        ``{"surge"|"sway"|"heave": area}``, m^2: default areas for C_D (times lambda^2 on the model).
    displaced_volume : float
        Full-size displaced volume, m^3: the ``"vehicle"`` reference displaced mass is rho times it.
    source : str
        Where the facts come from (e.g. ``models/udrobot.toml``), written into the provenance.
    area_provenance, volume_provenance : str
        Provenance of the areas and of the volume in that source (measured / estimated / assumed ...).
    """

    projected_area: dict
    displaced_volume: float
    source: str
    area_provenance: str = ""
    volume_provenance: str = ""


def reference_displaced_mass(choice, model_volume, scale, rho=1000.0,
                             vehicle: FullSizeVehicle | None = None) -> tuple[float, str]:
    """Full-size displaced mass (kg) used for the added mass, and a description of its origin.

    Parameters
    ----------
    choice : {'geometric', 'vehicle'}, float or None
        See the module docstring; None is ``geometric``.
    model_volume : float
        Displaced volume of the tested model, m^3.
    scale : float
        Model/full-size length ratio lambda.
    rho : float
        Water density, kg/m^3.
    vehicle : FullSizeVehicle, optional
        Required for ``choice="vehicle"``.
    """
    if choice is None or choice == "geometric":
        v = rho * model_volume / scale ** 3
        return v, f"geometric: rho V_model / lambda^3 = {rho:g} x {model_volume:.6g} / {scale:g}^3"
    if choice == "vehicle":
        if vehicle is None:
            raise ValueError("reference mass 'vehicle' needs the full-size vehicle's displaced volume: pass a "
                             "FullSizeVehicle (e.g. udrobot_ctrl.vehicle.full_size_vehicle()), or choose "
                             "'geometric' or a mass in kg")
        vol = float(vehicle.displaced_volume)
        return rho * vol, f"vehicle: rho V of {vehicle.source} ({vol:g} m^3; {vehicle.volume_provenance})"
    try:
        v = float(choice)
    except (TypeError, ValueError):
        raise ValueError(f"reference mass {choice!r}: expected 'geometric', 'vehicle' or a mass in kg") from None
    if not v > 0:
        raise ValueError(f"reference mass must be positive, got {v}")
    return v, f"given: {v:g} kg"


def full_scale_factor(quantity, scale, KL_law="reynolds") -> float:
    """Multiplier model -> full size for K_L, K_Q, C_m, C_D (added mass: use :func:`full_scale`)."""
    if not 0 < scale <= 10:
        raise ValueError(f"scale (model/full-size length ratio) must be in (0, 10], got {scale}")
    if quantity in ("Cm", "CD"):
        return 1.0
    if quantity == "KQ":
        return scale ** -2
    if quantity == "KL":
        if KL_law not in KL_EXPONENTS:
            raise ValueError(f"K_L law must be one of {sorted(KL_EXPONENTS)}")
        return scale ** -KL_EXPONENTS[KL_law]
    raise ValueError(f"no scaling law for {quantity!r}")


def full_scale(aggregate: dict, scale, reference_mass, KL_law="reynolds") -> dict:
    """Scale an aggregate ``{coef: {"value", "ci95", ...}}`` to full size.

    Parameters
    ----------
    aggregate : dict
        Model-scale aggregate (``Cm``, ``CD``, ``KL``, ``KQ``, ``added_mass_kg``).
    scale : float
        Model/full-size length ratio lambda.
    reference_mass : float
        Full-size reference displaced mass, kg (see :func:`reference_displaced_mass`).
    KL_law : {'reynolds', 'froude'}
        Similitude law of K_L.

    Returns
    -------
    dict
        Quantity -> ``{"value", "ci95", "law"}`` at full size (``added_mass_kg`` = C_m x the reference mass, kg;
        K_L N s/m, K_Q N s^2/m^2, C_m and C_D dimensionless); quantities without a value are left out.
    """
    out = {}
    for q, entry in aggregate.items():
        if not isinstance(entry, dict) or entry.get("value") is None:
            continue
        if q == "added_mass_kg":
            cm = aggregate.get("Cm")
            if not cm or cm.get("value") is None:
                continue
            f, base = reference_mass, cm
        elif q in ("Cm", "CD", "KQ", "KL"):
            f, base = full_scale_factor(q, scale, KL_law), entry
        else:
            continue
        ci = base.get("ci95")
        out[q] = {"value": float(base["value"]) * f,
                  "ci95": [float(c) * f for c in ci] if ci else None,
                  "law": LAWS[q] if q != "KL" else f"K_L,model / lambda^{KL_EXPONENTS[KL_law]:g} ({KL_law} law)"}
    return out


def scale_values(values, quantity, scale, KL_law="reynolds"):
    """Vectorised model -> full-size for ``Cm``/``CD``/``KQ``/``KL``."""
    return np.asarray(values, float) * full_scale_factor(quantity, scale, KL_law)
