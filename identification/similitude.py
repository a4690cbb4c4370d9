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
  rho V of the full-size description ``models/udrobot.toml`` (9.38 kg, itself assumed, see that file),
  so that the identified added mass is consistent with the buoyancy of the plant it is used in.
* a number in kg: e.g. 9.20 reproduces the paper, whose full-size added masses are C_m x 9.20 kg
  (7.5187 = 0.8172 x 9.20; 8.3027 = 0.9024 x 9.20), i.e. referred to the robot's mass, not to a
  scaled volume (Table 2's model would give 12.8 kg, Table 3's 10.1 kg).
"""
from __future__ import annotations

import numpy as np

LAWS = {
    "Cm": "unchanged (dimensionless, geometric similitude)",
    "CD": "unchanged (dimensionless, geometric similitude)",
    "added_mass_kg": "C_m x reference displaced mass (volume law, lambda^-3 for the geometric reference)",
    "KQ": "K_Q,model / lambda^2 (projected-area law, 1/2 rho C_D A)",
    "KL": "K_L,model / lambda (viscous/Reynolds law, force ~ mu u L)",
}
KL_EXPONENTS = {"reynolds": 1.0, "froude": 2.5}


def reference_displaced_mass(choice, model_volume, scale, rho=1000.0) -> tuple[float, str]:
    """Full-size displaced mass (kg) used for the added mass, and a description of its origin."""
    if choice is None or choice == "geometric":
        v = rho * model_volume / scale ** 3
        return v, f"geometric: rho V_model / lambda^3 = {rho:g} x {model_volume:.6g} / {scale:g}^3"
    if choice == "vehicle":
        from udrobot_ctrl.vehicle import vehicle_description

        d = vehicle_description()
        vol = float(d["displaced_volume"]["value"])
        return rho * vol, f"vehicle: rho V of models/udrobot.toml ({vol:g} m^3; {d['displaced_volume']['provenance']})"
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
