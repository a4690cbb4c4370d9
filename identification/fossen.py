"""Coefficient sets -> Fossen-form added mass M_A and damping D(nu) = D_L + D_n(nu).

The UDrobot identification (Cely 2019) measures only the translational diagonal
(surge, sway, heave). The rotational entries are *estimated* by strip theory on the
box of Table 1 (length L along x, width W along y, height H along z), assuming each
translational coefficient is spread uniformly over the faces it acts on:

* added inertia: a yaw rate r moves a strip at x with sway speed x r, so
  N_rdot = Y_vdot L^2/12 + X_udot W^2/12 (and cyclically for roll and pitch);
* linear damping: N_r = Y_v L^2/12 + X_u W^2/12;
* quadratic damping: the moment of 1/2 rho C_D h |x r| x r over the strip is
  K_Q L^3/32, so N_r|r| = (Y_v|v| L^3 + X_u|u| W^3)/32.

These are order-of-magnitude estimates, tagged ``estimated`` in the provenance.
All returned numbers are positive (M_A = diag(-X_udot, ...), Fossen sign convention).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXES = ("surge", "sway", "heave")
FORMS = ("chin", "morison")

# (rotational DOF index, [(translational axis index, arm dimension index)...]) where the arm
# dimension is the body extent along which that translational motion is induced by the rotation.
# dims = (L, W, H) along (x, y, z).
_ROTATION_STRIPS = {
    3: ((1, 2), (2, 1)),  # roll p: sway flow over the height, heave flow over the width
    4: ((0, 2), (2, 0)),  # pitch q: surge flow over the height, heave flow over the length
    5: ((1, 0), (0, 1)),  # yaw r: sway flow over the length, surge flow over the width
}


@dataclass(frozen=True)
class CoefficientSet:
    """Translational hydrodynamic coefficients of one identification method (full scale).

    Attributes
    ----------
    name : str
        Set name (``cfd``, ``free_decay``, ``pendulum`` or a user's).
    added_mass : dict
        ``{form or 'default': (3,) array}`` added mass per axis, kg.
    KL : (3,) ndarray or None
        Linear damping K_L per axis, N s/m (None when the method gives none).
    KQ : (3,) ndarray or None
        Quadratic damping K_Q per axis, N s^2/m^2.
    CD : (3,) ndarray or None
        Morison drag coefficient per axis, dimensionless.
    forms : tuple of str
        Damping forms this set supports.
    description : str
        What the set is (method, source).
    provenance : dict
        ``{"surge.KL": "measured: ...", ...}``.
    """

    name: str
    added_mass: dict
    KL: np.ndarray | None = None
    KQ: np.ndarray | None = None
    CD: np.ndarray | None = None
    forms: tuple = FORMS
    description: str = ""
    provenance: dict = field(default_factory=dict)

    def added_mass_for(self, form: str) -> np.ndarray:
        """Added mass per axis (kg) used with damping ``form``."""
        return np.asarray(self.added_mass.get(form, self.added_mass["default"]), dtype=float)


def quadratic_from_drag_coefficient(CD, area, rho=1000.0):
    """Morison quadratic damping K_D = 1/2 rho C_D A.

    Parameters
    ----------
    CD : array_like
        Drag coefficient, dimensionless.
    area : array_like
        Projected area the coefficient refers to, m^2.
    rho : float
        Water density, kg/m^3.

    Returns
    -------
    ndarray
        K_D in N s^2/m^2.
    """
    return 0.5 * rho * np.asarray(CD, dtype=float) * np.asarray(area, dtype=float)


def translational_damping(coeffs: CoefficientSet, form: str, area, rho=1000.0):
    """Linear (N s/m) and quadratic (N s^2/m^2) translational damping for a damping form.

    ``chin`` uses K_L and K_Q; ``morison`` uses only 1/2 rho C_D A (no linear term).
    """
    if form not in FORMS:
        raise ValueError(f"damping form must be one of {FORMS}, got {form!r}")
    if form not in coeffs.forms:
        raise ValueError(
            f"coefficient set {coeffs.name!r} has no {form!r} form (available: {', '.join(coeffs.forms)})"
        )
    if form == "chin":
        if coeffs.KL is None or coeffs.KQ is None:
            raise ValueError(f"coefficient set {coeffs.name!r} lacks K_L/K_Q needed by the chin form")
        return np.asarray(coeffs.KL, float), np.asarray(coeffs.KQ, float)
    if coeffs.CD is None:
        raise ValueError(f"coefficient set {coeffs.name!r} lacks C_D needed by the morison form")
    return np.zeros(3), quadratic_from_drag_coefficient(coeffs.CD, area, rho)


def strip_theory_rotational(translational, dims, power=2):
    """Estimate rotational coefficients from translational ones by strip theory.

    Parameters
    ----------
    translational : (3,) array_like
        Surge, sway, heave coefficient (added mass kg, or damping).
    dims : (3,) array_like
        Body extents (L, W, H) along x, y, z, m.
    power : {2, 3}
        2 for added mass and linear damping (arm^2/12), 3 for quadratic damping (arm^3/32).

    Returns
    -------
    ndarray, shape (3,)
        Roll, pitch, yaw coefficients (kg m^2, N m s, N m s^2).
    """
    t = np.asarray(translational, dtype=float)
    d = np.asarray(dims, dtype=float)
    factor = {2: 1.0 / 12.0, 3: 1.0 / 32.0}[power]
    out = np.zeros(3)
    for k, dof in enumerate((3, 4, 5)):
        out[k] = sum(t[axis] * factor * d[arm] ** power for axis, arm in _ROTATION_STRIPS[dof])
    return out


def added_mass_matrix(coeffs: CoefficientSet, form: str, dims) -> np.ndarray:
    """6x6 added-mass matrix M_A (kg, kg m^2), diagonal, translational part identified.

    Parameters
    ----------
    coeffs : CoefficientSet
        The identified set.
    form : {'chin', 'morison'}
        Damping form (a set may give a different added mass per form).
    dims : (3,) array_like
        Body extents (L, W, H) along x, y, z, m, for the strip-theory rotational terms (estimated).

    Returns
    -------
    (6, 6) ndarray
        diag(surge, sway, heave in kg; roll, pitch, yaw in kg m^2), positive (Fossen sign convention).
    """
    trans = coeffs.added_mass_for(form)
    return np.diag(np.concatenate([trans, strip_theory_rotational(trans, dims, 2)]))


def damping_matrices(coeffs: CoefficientSet, form: str, dims, area, rho=1000.0):
    """Linear damping D_L and quadratic coefficient matrix Q (D_n(nu)_ij = Q_ij |nu_j|).

    The rotational entries are strip-theory estimates from the translational ones (module notes).

    Parameters
    ----------
    coeffs : CoefficientSet
        The identified set.
    form : {'chin', 'morison'}
        ``chin``: K_L and K_Q; ``morison``: only 1/2 rho C_D A (no linear term).
    dims : (3,) array_like
        Body extents (L, W, H) along x, y, z, m.
    area : (3,) array_like
        Projected areas for C_D per axis, m^2.
    rho : float
        Water density, kg/m^3.

    Returns
    -------
    D_L : ndarray, (6, 6)
        N s/m and N m s.
    Q : ndarray, (6, 6)
        N s^2/m^2 and N m s^2.
    """
    kl, kq = translational_damping(coeffs, form, area, rho)
    D_L = np.diag(np.concatenate([kl, strip_theory_rotational(kl, dims, 2)]))
    Q = np.diag(np.concatenate([kq, strip_theory_rotational(kq, dims, 3)]))
    return D_L, Q


def damping_force(nu, D_L, Q):
    """Damping force D_L nu + D_n(nu) nu (N, N m); ``nu`` may carry leading batch axes."""
    nu = np.asarray(nu, dtype=float)
    return nu @ D_L.T + (np.abs(nu) * nu) @ Q.T


def provenance_entries(coeffs: CoefficientSet, form: str) -> dict:
    """Provenance of every nonzero M_A / D entry, keyed as in udrobot-model/1."""
    out = {}
    keys = {"added_mass": f"added_mass_{form}" if f"added_mass_{form}" in _avail(coeffs) else "added_mass"}
    for i, axis in enumerate(AXES):
        am = coeffs.provenance.get(f"{axis}.{keys['added_mass']}") or coeffs.provenance.get(f"{axis}.added_mass", "")
        out[f"added_mass[{i}][{i}]"] = am
        if form == "chin":
            out[f"linear_damping[{i}][{i}]"] = coeffs.provenance.get(f"{axis}.KL", "")
            out[f"quadratic_damping[{i}][{i}]"] = coeffs.provenance.get(f"{axis}.KQ", "")
        else:
            out[f"quadratic_damping[{i}][{i}]"] = (
                "derived: 1/2 rho C_D A with " + coeffs.provenance.get(f"{axis}.CD", "")
            )
    rot = "estimated: strip theory on the Table 1 box from the translational values (identification.fossen)"
    for i in range(3, 6):
        out[f"added_mass[{i}][{i}]"] = rot
        if form == "chin":
            out[f"linear_damping[{i}][{i}]"] = rot
        out[f"quadratic_damping[{i}][{i}]"] = rot
    return out


def _avail(coeffs):
    return {k.split(".", 1)[1] for k in coeffs.provenance}
